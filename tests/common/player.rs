//! A rosbag2 player for tests: publishes the messages of a bag over DDS (ros2-client) with
//! their original relative timing, like `ros2 bag play`. Images, camera infos and `/tf_static`
//! (reliable, transient local, as static transform broadcasters publish it) are supported.
//! Only for use inside the private network namespace of tests/common/netns.rs.
#![allow(dead_code)]

use std::collections::HashMap;
use std::time::{Duration, Instant};

use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{MessageTypeName, Name, Node, Publisher, QosProfile};
use sweepdepth::bag::BagMessage;
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, TFMessage};

enum TypedPublisher {
    Image(Publisher<Image>),
    Info(Publisher<CameraInfo>),
    Tf(Publisher<TFMessage>),
}

pub struct Player {
    publishers: HashMap<String, TypedPublisher>,
}

impl Player {
    /// Publishers on `node` for every topic of `messages` with a supported type.
    pub fn new(node: &mut Node, messages: &[BagMessage]) -> Player {
        let reliable = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .history(History::KeepLast { depth: 10 });
        let latched = reliable.clone().durability(Durability::TransientLocal);
        let mut publishers = HashMap::new();
        for m in messages {
            if publishers.contains_key(&m.topic) {
                continue;
            }
            let name = Name::parse(&m.topic).expect("topic name");
            let typed = match m.msg_type.as_str() {
                "sensor_msgs/msg/Image" => {
                    let t = node
                        .create_topic(
                            &name,
                            MessageTypeName::new("sensor_msgs", "Image"),
                            &reliable,
                        )
                        .unwrap();
                    TypedPublisher::Image(
                        node.create_publisher(&t, Some(reliable.clone())).unwrap(),
                    )
                }
                "sensor_msgs/msg/CameraInfo" => {
                    let t = node
                        .create_topic(
                            &name,
                            MessageTypeName::new("sensor_msgs", "CameraInfo"),
                            &reliable,
                        )
                        .unwrap();
                    TypedPublisher::Info(node.create_publisher(&t, Some(reliable.clone())).unwrap())
                }
                "tf2_msgs/msg/TFMessage" => {
                    let t = node
                        .create_topic(
                            &name,
                            MessageTypeName::new("tf2_msgs", "TFMessage"),
                            &latched,
                        )
                        .unwrap();
                    TypedPublisher::Tf(node.create_publisher(&t, Some(latched.clone())).unwrap())
                }
                other => panic!("the test player cannot publish {other} ({})", m.topic),
            };
            publishers.insert(m.topic.clone(), typed);
        }
        Player { publishers }
    }

    /// Waits until every publisher has a matched subscription (the node under test), polling
    /// discovery; panics after `limit`.
    pub fn wait_for_subscribers(&self, node: &Node, limit: Duration) {
        let started = Instant::now();
        loop {
            let missing: Vec<&String> = self
                .publishers
                .iter()
                .filter(|(_, p)| {
                    let n = match p {
                        TypedPublisher::Image(p) => p.get_subscription_count(node),
                        TypedPublisher::Info(p) => p.get_subscription_count(node),
                        TypedPublisher::Tf(p) => p.get_subscription_count(node),
                    };
                    n == 0
                })
                .map(|(t, _)| t)
                .collect();
            if missing.is_empty() {
                return;
            }
            assert!(
                started.elapsed() < limit,
                "no subscriber within {limit:?} on {missing:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Publishes `messages` in order, each at its log time relative to the first one.
    pub fn play(&self, messages: &[BagMessage]) {
        let Some(first) = messages.first().map(|m| m.log_time_ns) else {
            return;
        };
        let started = Instant::now();
        for m in messages {
            let due = Duration::from_nanos(m.log_time_ns.saturating_sub(first));
            if let Some(wait) = due.checked_sub(started.elapsed()) {
                std::thread::sleep(wait);
            }
            let Some(p) = self.publishers.get(&m.topic) else {
                continue;
            };
            let r = match p {
                TypedPublisher::Image(p) => p
                    .publish(from_cdr::<Image>(&m.data).expect("image"))
                    .map_err(|e| format!("{e:?}")),
                TypedPublisher::Info(p) => p
                    .publish(from_cdr::<CameraInfo>(&m.data).expect("camera info"))
                    .map_err(|e| format!("{e:?}")),
                TypedPublisher::Tf(p) => p
                    .publish(from_cdr::<TFMessage>(&m.data).expect("tf"))
                    .map_err(|e| format!("{e:?}")),
            };
            r.unwrap_or_else(|e| panic!("publish on {}: {e}", m.topic));
        }
    }
}
