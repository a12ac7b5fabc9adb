//! Which of the outputs that cost work to make (cost, selection, points) anyone subscribes to,
//! as DDS discovery sees it. image_pipeline's nodes make an output only while it has
//! subscribers; so does this node for these three (depth, its camera info and confidence are
//! always made: fusion and `fuse` read them). The WGSL engine then leaves the maps nobody reads
//! on the device (at a megapixel, 5 MB of readback per set for each). The diagnostics thread
//! refreshes the demand a few times a second; the GPU thread reads it before each set.

use std::sync::atomic::{AtomicBool, Ordering};

use ros2_client::dds::rustdds::DomainParticipant;

use super::why::dds_topic_name;
use crate::pipeline::{Output, Wanted};

/// The optional outputs, in the order [`Demand`] keeps them.
const OPTIONAL: [Output; 3] = [Output::Cost, Output::Selection, Output::Points];

/// Whether each optional output of any reference has a subscriber.
pub(super) struct Demand {
    /// Each published optional output's DDS topic name (`rt/rig/cost/image`).
    topics: Vec<(Output, String)>,
    subscribed: [AtomicBool; 3],
}

impl Demand {
    /// For the outputs published, each with its topic (nothing subscribed until
    /// [`Demand::refresh`]).
    pub fn new<'a>(topics: impl Iterator<Item = (Output, &'a str)>) -> Self {
        let topics = topics
            .filter(|(output, _)| OPTIONAL.contains(output))
            .map(|(output, topic)| (output, dds_topic_name(topic)))
            .collect();
        Self {
            topics,
            subscribed: Default::default(),
        }
    }

    /// Brings the demand up to date with the readers discovery knows; returns whether it
    /// changed.
    pub fn refresh(&self, participant: &DomainParticipant) -> bool {
        let readers = participant.discovered_readers();
        self.update(&readers, |r| r.subscription_topic_data.topic_name.as_str())
    }

    /// [`Demand::refresh`] from the readers discovered, `topic` naming each one's topic.
    fn update<R>(&self, readers: &[R], topic: impl Fn(&R) -> &str) -> bool {
        let mut changed = false;
        for (i, output) in OPTIONAL.iter().enumerate() {
            let subscribed = self
                .topics
                .iter()
                .any(|(o, name)| o == output && readers.iter().any(|r| topic(r) == name.as_str()));
            changed |= self.subscribed[i].swap(subscribed, Ordering::Relaxed) != subscribed;
        }
        changed
    }

    /// The outputs to make for the next set.
    pub fn wanted(&self) -> Wanted {
        let on = |i: usize| self.subscribed[i].load(Ordering::Relaxed);
        Wanted {
            cost: on(0),
            selection: on(1),
            points: on(2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An output is made while a reader of any reference's topic of it is discovered, and
    /// only an output that is published (`points` without `publish_points` never).
    #[test]
    fn outputs_follow_their_readers() {
        let demand = Demand::new(
            [
                (Output::Depth, "/rig/a/depth/image"),
                (Output::Cost, "/rig/a/cost/image"),
                (Output::Selection, "/rig/a/selection/image"),
                (Output::Cost, "/rig/b/cost/image"),
                (Output::Selection, "/rig/b/selection/image"),
            ]
            .into_iter(),
        );
        let none = Wanted::NONE;
        assert_eq!(demand.wanted(), none);
        assert_eq!(demand.wanted().describe(), "none");
        let readers = |names: &[&str]| names.iter().map(|n| n.to_string()).collect::<Vec<_>>();
        // Depth readers change nothing; a reader of b's cost turns the cost on.
        assert!(!demand.update(&readers(&["rt/rig/a/depth/image"]), String::as_str));
        assert!(demand.update(
            &readers(&["rt/rig/a/depth/image", "rt/rig/b/cost/image"]),
            String::as_str
        ));
        assert_eq!(demand.wanted(), Wanted { cost: true, ..none });
        assert_eq!(demand.wanted().describe(), "cost");
        assert!(!demand.update(&readers(&["rt/rig/b/cost/image"]), String::as_str));
        // Points are not published here: their readers are not a demand.
        assert!(demand.update(
            &readers(&["rt/rig/a/selection/image", "rt/rig/a/points", "rt/points"]),
            String::as_str
        ));
        assert_eq!(
            demand.wanted(),
            Wanted {
                selection: true,
                ..none
            }
        );
        // A reader gone: the output stops.
        assert!(demand.update(&[], String::as_str));
        assert_eq!(demand.wanted(), none);
    }
}
