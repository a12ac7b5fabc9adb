//! Items that wait, in arrival order, for the pose of their frame in a world frame at their
//! stamp: `/tf` and `/tf_static` in a [`TfHistory`] (tf2's rules: interpolation between the
//! two nearest transforms of a dynamic link, static links at any time, no extrapolation), each
//! item until its deadline on the caller's clock. An item behind a waiting one waits behind
//! it, so items leave in the order they came. The depth node's moving rig (`world.rs`: frame
//! sets) and the `fuse` node (`depth_in.rs`: depth images) both wait here.

use std::collections::VecDeque;

use crate::geometry::RigidTransform;
use crate::msgs::{TFMessage, Time};
use crate::ros::tf_history::{TfHistory, TfInsertError, TfLookupError};

/// An item waiting for its pose.
#[derive(Debug)]
struct Pending<T> {
    item: T,
    frame: String,
    stamp: Time,
    deadline_ns: u64,
}

/// What left the queue.
#[derive(Debug)]
pub(super) enum Posed<T> {
    /// The pose of the item's frame in the world frame at its stamp.
    Ready(T, RigidTransform),
    /// No pose: the lookup's error; `gave_up` when the pose might still have come (the
    /// deadline passed, or the input ended), false when it cannot (a broken chain, a stamp
    /// older than the history).
    Failed {
        item: T,
        frame: String,
        stamp: Time,
        error: TfLookupError,
        gave_up: bool,
    },
}

/// The transforms and the items that wait for them.
#[derive(Debug)]
pub(super) struct PoseQueue<T> {
    tf: TfHistory,
    waiting: VecDeque<Pending<T>>,
}

impl<T> Default for PoseQueue<T> {
    fn default() -> Self {
        Self {
            tf: TfHistory::new(),
            waiting: VecDeque::new(),
        }
    }
}

impl<T> PoseQueue<T> {
    /// Adds the transforms of a `/tf` (`is_static` false) or `/tf_static` message; returns the
    /// rejected ones, and whether a `/tf` stamp well before the newest (time going back: a bag
    /// played again) cleared the dynamic transforms first.
    pub fn add_tf(&mut self, msg: &TFMessage, is_static: bool) -> (Vec<TfInsertError>, bool) {
        let mut cleared = false;
        if !is_static {
            if let Some(stamp) = msg
                .transforms
                .iter()
                .map(|t| t.header.stamp)
                .min_by_key(|t| t.to_nanos())
            {
                cleared = self.tf.note_time(stamp);
            }
        }
        (self.tf.insert_message(msg, is_static), cleared)
    }

    /// Time went back: the dynamic transforms go, as in tf2.
    pub fn clear_dynamic(&mut self) {
        self.tf.clear_dynamic();
    }

    /// A new item: it waits behind the others for the pose of `frame` at `stamp`, until
    /// `deadline_ns`.
    pub fn push(&mut self, item: T, frame: String, stamp: Time, deadline_ns: u64) {
        self.waiting.push_back(Pending {
            item,
            frame,
            stamp,
            deadline_ns,
        });
    }

    /// The items done waiting, in order: posed in `world`, or failed with the reason.
    /// `flush`: no more transforms will come, so nothing waits any longer.
    pub fn ready(&mut self, world: &str, now_ns: u64, flush: bool) -> Vec<Posed<T>> {
        let mut done = Vec::new();
        while let Some(front) = self.waiting.front() {
            let result = self.tf.lookup_at(world, &front.frame, front.stamp);
            if let Err(e) = &result {
                if e.may_resolve_by_waiting() && !flush && now_ns < front.deadline_ns {
                    break;
                }
            }
            let Some(pending) = self.waiting.pop_front() else {
                break;
            };
            done.push(match result {
                Ok(world_from_frame) => Posed::Ready(pending.item, world_from_frame),
                Err(error) => Posed::Failed {
                    gave_up: error.may_resolve_by_waiting(),
                    item: pending.item,
                    frame: pending.frame,
                    stamp: pending.stamp,
                    error,
                },
            });
        }
        done
    }

    /// Items waiting for their pose.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, Transform, TransformStamped, Vector3};

    /// `world -> cam` at `sec`, `x` metres along x (also the fuse node's tests').
    pub(crate) fn tf(sec: i32, x: f64) -> TFMessage {
        TFMessage {
            transforms: vec![TransformStamped {
                header: Header {
                    stamp: Time { sec, nanosec: 0 },
                    frame_id: "world".into(),
                },
                child_frame_id: "cam".into(),
                transform: Transform {
                    translation: Vector3 { x, y: 0.0, z: 0.0 },
                    rotation: Quaternion::default(),
                },
            }],
        }
    }

    fn at(sec: i32) -> Time {
        Time { sec, nanosec: 0 }
    }

    /// Items leave in order, each posed at its own stamp once /tf has passed it; one behind a
    /// waiting item waits behind it; past its deadline an item fails as given up, and a frame
    /// the tree does not hold fails at the end of the input.
    #[test]
    fn items_wait_in_order_for_their_pose() {
        let mut queue = PoseQueue::default();
        queue.add_tf(&tf(1, 0.0), false);
        queue.push("a", "cam".to_string(), at(2), 100);
        queue.push("b", "cam".to_string(), at(1), 100);
        // /tf has not reached 2 s: "a" waits, and "b" (posable) behind it.
        assert!(queue.ready("world", 10, false).is_empty());
        assert_eq!(queue.waiting(), 2);
        queue.add_tf(&tf(3, 2.0), false);
        let done = queue.ready("world", 20, false);
        let poses: Vec<(&str, f64)> = done
            .iter()
            .map(|p| match p {
                Posed::Ready(item, pose) => (*item, pose.translation.x),
                Posed::Failed { .. } => panic!("{p:?}"),
            })
            .collect();
        // "a" at 2 s, halfway between 0 m (1 s) and 2 m (3 s); "b" at 1 s.
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[0].0, "a");
        assert!((poses[0].1 - 1.0).abs() < 1e-9, "{poses:?}");
        assert_eq!(poses[1], ("b", 0.0));
        // Beyond /tf: waits until its deadline, then gives up.
        queue.push("c", "cam".to_string(), at(5), 30);
        assert!(queue.ready("world", 29, false).is_empty());
        match queue.ready("world", 30, false).pop() {
            Some(Posed::Failed { item, gave_up, .. }) => assert!(item == "c" && gave_up),
            other => panic!("{other:?}"),
        }
        // A frame that is not in the tree: flushed at the end of the input.
        queue.push("d", "elsewhere".to_string(), at(2), u64::MAX);
        match queue.ready("world", 40, true).pop() {
            Some(Posed::Failed { item, frame, .. }) => {
                assert!(item == "d" && frame == "elsewhere")
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(queue.waiting(), 0);
    }
}
