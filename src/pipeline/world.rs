//! A moving rig (`world_frame`): every set's pose in the world frame at its stamp, from `/tf`
//! and `/tf_static` with tf2's rules (`ros/tf_history.rs`: interpolation between the two
//! nearest transforms of a dynamic link, static links at any time, no extrapolation).
//!
//! A set whose stamp `/tf` has not reached yet waits (`pose_queue.rs`), in arrival order, for at most
//! `tf_timeout` (on the clock the pipeline is given: receive time live, log time in a bag);
//! a set behind a waiting one waits behind it, so sets leave in the order they came. A set
//! whose pose cannot come (a broken chain, a stamp older than the history, the timeout) is
//! skipped with the reason ([`SkipKind::NoWorldPose`]). Time going back (a bag played in a
//! loop) clears the dynamic transforms, as tf2 does on a time jump.

use super::config::WorldConfig;
use super::outcome::{Job, Skip, SkipKind};
use super::pose_queue::{PoseQueue, Posed};
use crate::msgs::TFMessage;
use crate::ros::tf_history::TfInsertError;

/// The transforms and the sets that wait for them (`pose_queue.rs`).
#[derive(Debug, Default)]
pub(super) struct WorldPoses {
    queue: PoseQueue<Job>,
}

impl WorldPoses {
    /// Adds the transforms of a `/tf` (`is_static` false) or `/tf_static` message; returns the
    /// rejected ones. A `/tf` stamp well before the newest (time going back) clears the
    /// dynamic transforms first.
    pub fn add(&mut self, msg: &TFMessage, is_static: bool) -> (Vec<TfInsertError>, bool) {
        self.queue.add_tf(msg, is_static)
    }

    /// Time went back (the synchroniser reset): the dynamic transforms go, as in tf2.
    pub fn clear_dynamic(&mut self) {
        self.queue.clear_dynamic();
    }

    /// A new set: it waits behind the others for its pose.
    pub fn push(&mut self, job: Job, now_ns: u64, config: &WorldConfig) {
        let timeout_ns = u64::try_from(config.tf_timeout.as_nanos()).unwrap_or(u64::MAX);
        let stamp = job
            .images
            .get(job.anchor())
            .map(|m| m.header.stamp)
            .unwrap_or_default();
        let frame = job.ref_frame.clone();
        self.queue
            .push(job, frame, stamp, now_ns.saturating_add(timeout_ns));
    }

    /// The sets that are done waiting, in order: posed, or skipped with why. `flush`: no more
    /// transforms will come (the end of a bag), so nothing waits any longer.
    pub fn ready(
        &mut self,
        now_ns: u64,
        config: &WorldConfig,
        flush: bool,
    ) -> Vec<Result<Job, Skip>> {
        self.queue
            .ready(&config.frame, now_ns, flush)
            .into_iter()
            .map(|posed| match posed {
                Posed::Ready(mut job, world_from_ref_frame) => {
                    job.world_from_rig =
                        Some(world_from_ref_frame.compose(&job.ref_frame_from_rig));
                    Ok(job)
                }
                Posed::Failed {
                    frame,
                    stamp,
                    error,
                    gave_up,
                    ..
                } => {
                    let why = match (gave_up, flush) {
                        (false, _) => String::new(),
                        (true, true) => "and the input ended".to_string(),
                        (true, false) => format!(
                            "within tf_timeout ({:.3} s)",
                            config.tf_timeout.as_secs_f64()
                        ),
                    };
                    Err(Skip::new(
                        SkipKind::NoWorldPose,
                        None,
                        format!(
                            "no pose of '{frame}' in world_frame '{}' at the set's stamp {}.{:09} {why}: {error}",
                            config.frame, stamp.sec, stamp.nanosec
                        ),
                    ))
                }
            })
            .collect()
    }

    /// Sets waiting for their pose.
    pub fn waiting(&self) -> usize {
        self.queue.waiting()
    }
}
