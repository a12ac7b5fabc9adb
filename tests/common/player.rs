//! A rosbag2 player for tests: publishes messages of a bag over DDS (ros2-client) one at a time,
//! as the test paces them (never on the bag's clock: a test publishes a frame set once the
//! node has answered the previous one). Images, camera infos and `/tf_static` (reliable,
//! transient local, as static transform broadcasters publish it) are supported.
//! Only for use inside the private network namespace of [`super::netns`].

use std::collections::HashMap;
use std::time::{Duration, Instant};

use ros2_client::Publisher;
use sweepdepth::bag::BagMessage;
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, TFMessage, Time};

use super::dds::{self, NodeProcess, Peer};

enum TypedPublisher {
    Image(Publisher<Image>),
    Info(Publisher<CameraInfo>),
    Tf(Publisher<TFMessage>),
}

pub struct Player {
    publishers: HashMap<String, TypedPublisher>,
}

impl Player {
    /// Publishers on `peer` for every topic of `messages` with a supported type: images and
    /// camera infos reliable keep-last 10, `/tf_static` also transient local.
    pub fn new(peer: &mut Peer, messages: &[BagMessage]) -> Player {
        let reliable = dds::reliable(10);
        let latched = dds::latched(10);
        let mut publishers = HashMap::new();
        for m in messages {
            if publishers.contains_key(&m.topic) {
                continue;
            }
            let typed = match m.msg_type.as_str() {
                "sensor_msgs/msg/Image" => {
                    TypedPublisher::Image(peer.publisher(&m.topic, dds::IMAGE, &reliable))
                }
                "sensor_msgs/msg/CameraInfo" => {
                    TypedPublisher::Info(peer.publisher(&m.topic, dds::CAMERA_INFO, &reliable))
                }
                "tf2_msgs/msg/TFMessage" => {
                    TypedPublisher::Tf(peer.publisher(&m.topic, dds::TF_MESSAGE, &latched))
                }
                other => panic!("the test player cannot publish {other} ({})", m.topic),
            };
            publishers.insert(m.topic.clone(), typed);
        }
        Player { publishers }
    }

    /// Waits until every publisher has a matched subscription (the node under test), polling
    /// discovery (the peer must spin, [`Peer::spin_in_background`]).
    pub fn wait_for_subscribers(&self, peer: &Peer, node: &mut NodeProcess) {
        let limit = dds::timeout();
        let started = Instant::now();
        loop {
            let missing: Vec<&String> = self
                .publishers
                .iter()
                .filter(|(_, p)| {
                    let n = match p {
                        TypedPublisher::Image(p) => p.get_subscription_count(&peer.node),
                        TypedPublisher::Info(p) => p.get_subscription_count(&peer.node),
                        TypedPublisher::Tf(p) => p.get_subscription_count(&peer.node),
                    };
                    n == 0
                })
                .map(|(t, _)| t)
                .collect();
            if missing.is_empty() {
                return;
            }
            node.check_alive();
            assert!(
                started.elapsed() < limit,
                "waited {limit:?} in vain for the node to subscribe to {missing:?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Publishes one message of the bag (on a topic of the bag given to [`Player::new`]).
    pub fn publish(&self, m: &BagMessage) {
        self.publish_stamped(m, None);
    }

    /// Publishes one message, its header stamp replaced by `stamp` when given (images and
    /// camera infos).
    pub fn publish_stamped(&self, m: &BagMessage, stamp: Option<Time>) {
        let p = self
            .publishers
            .get(&m.topic)
            .unwrap_or_else(|| panic!("the player has no publisher for {}", m.topic));
        let r = match p {
            TypedPublisher::Image(p) => {
                let mut image: Image = from_cdr(&m.data).expect("an Image");
                if let Some(stamp) = stamp {
                    image.header.stamp = stamp;
                }
                p.publish(image).map_err(|e| format!("{e:?}"))
            }
            TypedPublisher::Info(p) => {
                let mut info: CameraInfo = from_cdr(&m.data).expect("a CameraInfo");
                if let Some(stamp) = stamp {
                    info.header.stamp = stamp;
                }
                p.publish(info).map_err(|e| format!("{e:?}"))
            }
            TypedPublisher::Tf(p) => p
                .publish(from_cdr::<TFMessage>(&m.data).expect("a TFMessage"))
                .map_err(|e| format!("{e:?}")),
        };
        r.unwrap_or_else(|e| panic!("publish on {}: {e}", m.topic));
    }

    /// The start of a live run, while it is not known when the node's subscriptions match the
    /// player's publishers (and `/tf_static` reaches it): publishes copies of one frame set
    /// (`set`: its camera infos and images) stamped `stamp_of(0)`, `stamp_of(1)`, ... until
    /// `answered` returns true, waiting 0.1 s after the first, then twice as long after each
    /// (at most 1.6 s: a slow machine gets fewer sets to work through), for at most
    /// [`dds::timeout`]. Returns the last index published. The test then waits for that set's
    /// depth, after which the node is idle and every later set can be paced on its answers.
    pub fn warm_up(
        &self,
        set: &[&BagMessage],
        stamp_of: impl Fn(u32) -> Time,
        node: &mut NodeProcess,
        mut answered: impl FnMut() -> bool,
    ) -> u32 {
        let limit = dds::timeout();
        let started = Instant::now();
        let mut wait = Duration::from_millis(100);
        for j in 0.. {
            for m in set {
                self.publish_stamped(m, Some(stamp_of(j)));
            }
            let sent = Instant::now();
            while sent.elapsed() < wait {
                if answered() {
                    eprintln!(
                        "warm-up: the node answered after {:?} and {} sets",
                        started.elapsed(),
                        j + 1
                    );
                    return j;
                }
                node.check_alive();
                assert!(
                    started.elapsed() < limit,
                    "waited {limit:?} in vain for the depth of any of {} warm-up sets",
                    j + 1
                );
                std::thread::sleep(Duration::from_millis(5));
            }
            wait = (wait * 2).min(Duration::from_millis(1600));
        }
        unreachable!("the warm-up loop ends by returning or panicking")
    }
}
