//! A moving rig (`world_frame`): every set's pose in the world frame at its stamp, from `/tf`
//! and `/tf_static` with tf2's rules (`ros/tf_history.rs`: interpolation between the two
//! nearest transforms of a dynamic link, static links at any time, no extrapolation).
//!
//! A set whose stamp `/tf` has not reached yet waits, in arrival order, for at most
//! `tf_timeout` (on the clock the pipeline is given: receive time live, log time in a bag);
//! a set behind a waiting one waits behind it, so sets leave in the order they came. A set
//! whose pose cannot come (a broken chain, a stamp older than the history, the timeout) is
//! skipped with the reason ([`SkipKind::NoWorldPose`]). Time going back (a bag played in a
//! loop) clears the dynamic transforms, as tf2 does on a time jump.

use std::collections::VecDeque;

use super::config::WorldConfig;
use super::outcome::{Job, Skip, SkipKind};
use crate::msgs::TFMessage;
use crate::ros::tf_history::{TfHistory, TfInsertError};

/// A set waiting for its pose.
#[derive(Debug)]
struct Waiting {
    job: Job,
    /// When it stops waiting (the pipeline's clock).
    deadline_ns: u64,
}

/// The transforms and the sets that wait for them.
#[derive(Debug, Default)]
pub(super) struct WorldPoses {
    tf: TfHistory,
    waiting: VecDeque<Waiting>,
}

impl WorldPoses {
    /// Adds the transforms of a `/tf` (`is_static` false) or `/tf_static` message; returns the
    /// rejected ones. A `/tf` stamp well before the newest (time going back) clears the
    /// dynamic transforms first.
    pub fn add(&mut self, msg: &TFMessage, is_static: bool) -> (Vec<TfInsertError>, bool) {
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

    /// Time went back (the synchroniser reset): the dynamic transforms go, as in tf2.
    pub fn clear_dynamic(&mut self) {
        self.tf.clear_dynamic();
    }

    /// A new set: it waits behind the others for its pose.
    pub fn push(&mut self, job: Job, now_ns: u64, config: &WorldConfig) {
        let timeout_ns = u64::try_from(config.tf_timeout.as_nanos()).unwrap_or(u64::MAX);
        self.waiting.push_back(Waiting {
            job,
            deadline_ns: now_ns.saturating_add(timeout_ns),
        });
    }

    /// The sets that are done waiting, in order: posed, or skipped with why. `flush`: no more
    /// transforms will come (the end of a bag), so nothing waits any longer.
    pub fn ready(
        &mut self,
        now_ns: u64,
        config: &WorldConfig,
        flush: bool,
    ) -> Vec<Result<Job, Skip>> {
        let mut done = Vec::new();
        while let Some(front) = self.waiting.front_mut() {
            let stamp = front
                .job
                .images
                .get(front.job.reference)
                .map(|m| m.header.stamp)
                .unwrap_or_default();
            let frame = front.job.ref_frame.clone();
            match self.tf.lookup_at(&config.frame, &frame, stamp) {
                Ok(world_from_ref_frame) => {
                    let mut job = match self.waiting.pop_front() {
                        Some(w) => w.job,
                        None => break,
                    };
                    job.world_from_rig =
                        Some(world_from_ref_frame.compose(&job.ref_frame_from_rig));
                    done.push(Ok(job));
                }
                Err(e) if e.may_resolve_by_waiting() && !flush && now_ns < front.deadline_ns => {
                    break;
                }
                Err(e) => {
                    self.waiting.pop_front();
                    let why = if e.may_resolve_by_waiting() {
                        if flush {
                            "and the input ended".to_string()
                        } else {
                            format!(
                                "within tf_timeout ({:.3} s)",
                                config.tf_timeout.as_secs_f64()
                            )
                        }
                    } else {
                        String::new()
                    };
                    done.push(Err(Skip::new(
                        SkipKind::NoWorldPose,
                        None,
                        format!(
                            "no pose of '{frame}' in world_frame '{}' at the set's stamp {}.{:09} {why}: {e}",
                            config.frame, stamp.sec, stamp.nanosec
                        ),
                    )));
                }
            }
        }
        done
    }

    /// Sets waiting for their pose.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }
}
