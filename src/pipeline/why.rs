//! Why no depth comes out (issue 34): from what the pipeline has seen (per camera: images and
//! when, their stamps and frame ids, camera_info; `/tf_static`; the synchroniser's sets; the
//! sets skipped and why; the sets waiting for a world pose), the first thing a set is missing,
//! in the order a set needs them, as one short sentence naming the topic or camera and the
//! cause ([`Why`]). The node adds what only DDS discovery knows (a topic with no publisher, or
//! none whose QoS can match: [`Publishers`]); `bag` asks once at the end of a bag that gave no
//! depth.
//!
//! The order: every camera's images → their camera_info (unless the rig file has the
//! intrinsics) → the extrinsics (`/tf_static` from the reference camera's frame to each
//! camera's, unless a rig file places them) → complete sets (approximate sync: one camera's
//! stamps too far from the others' for `sync_max_interval`; exact sync: stamps that never
//! match) → sets skipped (the last reason) → sets waiting for their pose in `world_frame`.

use std::collections::VecDeque;
use std::fmt;

use super::config::{PipelineConfig, SyncPolicy};
use super::outcome::{Outcome, Skip, SkipKind};
use crate::msgs::Header;
use crate::ros::sync::time_to_ns;
use crate::ros::tf::{TfBuffer, TfError};

/// Recent stamps kept per camera for the synchronisation diagnosis.
const STAMPS: usize = 16;

/// What DDS discovery knows of the publishers of an input topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Publishers {
    /// Not known (a bag; a node without discovery data).
    Unknown,
    /// No publisher discovered on the topic.
    None,
    /// Publishers discovered, but none whose QoS can match the subscription: why, naming both
    /// QoS.
    Incompatible(String),
    /// This many publishers whose QoS matches.
    Matched(usize),
}

/// What a [`Why`] is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WhyKind {
    /// An input topic has no publisher.
    NoPublisher,
    /// An input topic's publishers offer a QoS the subscription cannot match.
    IncompatibleQos,
    /// No image of a camera yet.
    NoImage,
    /// A camera's images stopped.
    ImagesStopped,
    /// Images arrive, but no camera_info.
    NoCameraInfo,
    /// `/tf_static` lacks the link from the reference camera's frame to a camera's.
    NoTransform,
    /// An image frame id tf2 refuses to look up.
    FrameId,
    /// Approximate sync: one camera's stamps are too far from the others'.
    SyncOffset,
    /// Exact sync: the stamps never match.
    ExactSyncUnequal,
    /// Every input arrives but no set completes (no simpler cause found).
    NoCompleteSet,
    /// Sets complete but are skipped.
    Skipped,
    /// Sets wait for `/tf` to reach their stamp (`world_frame`).
    WaitingForPose,
}

/// Why no depth comes out: the first missing thing, as a sentence.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Why {
    pub kind: WhyKind,
    /// The camera it is about (an index into the configuration's cameras), if one.
    pub camera: Option<usize>,
    pub message: String,
}

impl fmt::Display for Why {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

/// What the pipeline saw of one camera.
#[derive(Debug, Clone, Default)]
struct CameraSeen {
    images: u64,
    last_image_ns: Option<u64>,
    /// The newest stamps (nanoseconds), oldest first.
    stamps: VecDeque<i64>,
    /// The frame id of the newest image.
    frame_id: String,
    infos: u64,
}

/// What the pipeline saw, for the diagnosis (fed by `Pipeline::push`).
#[derive(Debug, Clone, Default)]
pub(super) struct Seen {
    cameras: Vec<CameraSeen>,
    tf_static: u64,
    tf: u64,
    /// When the synchroniser last completed a set.
    last_set_ns: Option<u64>,
    /// When a set last became a job.
    last_job_ns: Option<u64>,
    last_skip: Option<Skip>,
}

/// The moment of the question and the clock's meaning.
#[derive(Debug, Clone, Copy)]
pub struct Asked {
    /// The pipeline's clock now (receive time live, the last log time in a bag).
    pub now_ns: u64,
    /// Live: what happened longer ago than this does not count as happening now (images,
    /// sets). None: a bag, where anything seen counts.
    pub window_ns: Option<u64>,
}

impl Asked {
    fn recent(&self, at: Option<u64>) -> bool {
        match (at, self.window_ns) {
            (None, _) => false,
            (Some(_), None) => true,
            (Some(t), Some(w)) => self.now_ns.saturating_sub(t) <= w,
        }
    }

    fn live(&self) -> bool {
        self.window_ns.is_some()
    }
}

impl Seen {
    pub fn new(cameras: usize) -> Self {
        Self {
            cameras: vec![CameraSeen::default(); cameras],
            ..Self::default()
        }
    }

    pub fn image(&mut self, camera: usize, header: &Header, now_ns: u64) {
        if let Some(c) = self.cameras.get_mut(camera) {
            c.images += 1;
            c.last_image_ns = Some(now_ns);
            c.stamps.push_back(time_to_ns(&header.stamp));
            if c.stamps.len() > STAMPS {
                c.stamps.pop_front();
            }
            if c.frame_id != header.frame_id {
                c.frame_id.clone_from(&header.frame_id);
            }
        }
    }

    pub fn info(&mut self, camera: usize) {
        if let Some(c) = self.cameras.get_mut(camera) {
            c.infos += 1;
        }
    }

    pub fn tf_static(&mut self) {
        self.tf_static += 1;
    }

    pub fn tf(&mut self) {
        self.tf += 1;
    }

    /// What one input gave.
    pub fn outcome(&mut self, outcome: &Outcome, now_ns: u64) {
        if outcome.sync.is_some_and(|v| v.sets > 0) {
            self.last_set_ns = Some(now_ns);
        }
        for set in &outcome.sets {
            match set {
                Ok(_) => self.last_job_ns = Some(now_ns),
                Err(skip) => self.last_skip = Some(skip.clone()),
            }
        }
    }

    /// The first thing missing for depth, or None when sets are ready for the engine.
    pub fn diagnose(
        &self,
        config: &PipelineConfig,
        tf: &TfBuffer,
        waiting_for_pose: usize,
        asked: Asked,
        peers: &dyn Fn(&str) -> Publishers,
    ) -> Option<Why> {
        if asked.recent(self.last_job_ns) {
            return None;
        }
        self.images(config, asked, peers)
            .or_else(|| self.infos(config, asked, peers))
            .or_else(|| self.extrinsics(config, tf, asked, peers))
            .or_else(|| self.sets(config, asked))
            .or_else(|| self.later(config, waiting_for_pose, asked, peers))
    }

    /// Every camera's images.
    fn images(
        &self,
        config: &PipelineConfig,
        asked: Asked,
        peers: &dyn Fn(&str) -> Publishers,
    ) -> Option<Why> {
        let missing: Vec<usize> = (0..self.cameras.len())
            .filter(|&i| !asked.recent(self.cameras[i].last_image_ns))
            .collect();
        let &first = missing.first()?;
        let topic = &config.input_image_topic(first);
        let seen = &self.cameras[first];
        let (kind, mut message) = match (peers(topic), seen.last_image_ns) {
            (Publishers::None, _) => {
                // The other transport's topic has a publisher: the parameter, not the graph.
                let (other, transport) = if config.compressed_inputs {
                    (config.image_topics[first].clone(), "raw")
                } else {
                    (format!("{topic}/compressed"), "compressed")
                };
                let there = matches!(
                    peers(&other),
                    Publishers::Matched(_) | Publishers::Incompatible(_)
                );
                let message = if !there {
                    no_publisher(topic)
                } else {
                    format!(
                        "no publisher on {topic}, but one on {other}: set image_transport \
                         to {transport}"
                    )
                };
                (WhyKind::NoPublisher, message)
            }
            (Publishers::Incompatible(why), _) => {
                (WhyKind::IncompatibleQos, incompatible(topic, &why))
            }
            (peers, None) => (
                WhyKind::NoImage,
                if asked.live() {
                    format!("no image on {topic} yet{}", matched(&peers))
                } else {
                    format!(
                        "no image of camera '{}' in the bag ({topic})",
                        config.cameras[first]
                    )
                },
            ),
            (peers, Some(t)) => (
                WhyKind::ImagesStopped,
                format!(
                    "no image on {topic} for {:.1} s{}",
                    asked.now_ns.saturating_sub(t) as f64 / 1e9,
                    match peers {
                        Publishers::Matched(n) =>
                            format!(" ({n} matched publisher(s) still there)"),
                        _ => String::new(),
                    }
                ),
            ),
        };
        if missing.len() > 1 {
            message += &format!(
                " (nor from {} other camera{})",
                missing.len() - 1,
                if missing.len() > 2 { "s" } else { "" }
            );
        }
        Some(Why {
            kind,
            camera: Some(first),
            message,
        })
    }

    /// Every camera's camera_info, unless the rig file has its intrinsics.
    fn infos(
        &self,
        config: &PipelineConfig,
        asked: Asked,
        peers: &dyn Fn(&str) -> Publishers,
    ) -> Option<Why> {
        let i = (0..self.cameras.len()).find(|&i| {
            let in_file = config
                .rig_file
                .as_ref()
                .and_then(|f| f.camera_for(&config.cameras[i]))
                .is_some_and(|c| c.model.is_some());
            self.cameras[i].infos == 0 && !in_file
        })?;
        let topic = &config.info_topics[i];
        let name = &config.cameras[i];
        let (kind, message) = match peers(topic) {
            Publishers::None => (
                WhyKind::NoPublisher,
                format!("images arrive but {}", no_publisher(topic)),
            ),
            Publishers::Incompatible(why) => (
                WhyKind::IncompatibleQos,
                format!("images arrive but {}", incompatible(topic, &why)),
            ),
            peers @ Publishers::Matched(_) if asked.live() => (
                WhyKind::NoCameraInfo,
                // A driver that latches one camera_info (transient-local) before the node
                // starts: a volatile reader, as image_transport's, never gets it.
                format!(
                    "images arrive but no camera_info on {topic}{}: the node reads camera_info \
                     as image_transport does (volatile), so one sent only before it started is \
                     not received; the driver should send it with every image",
                    matched(&peers)
                ),
            ),
            peers if asked.live() => (
                WhyKind::NoCameraInfo,
                format!(
                    "images arrive but no camera_info on {topic}{}",
                    matched(&peers)
                ),
            ),
            _ => (
                WhyKind::NoCameraInfo,
                format!("camera_info never recorded for {name} ({topic})"),
            ),
        };
        Some(Why {
            kind,
            camera: Some(i),
            message,
        })
    }

    /// The extrinsics from `/tf_static`: the reference camera's frame to each camera's.
    fn extrinsics(
        &self,
        config: &PipelineConfig,
        tf: &TfBuffer,
        asked: Asked,
        peers: &dyn Fn(&str) -> Publishers,
    ) -> Option<Why> {
        if config.rig_file.is_some() {
            return None;
        }
        let ref_frame = &self.cameras.get(config.reference())?.frame_id;
        let topic = &config.tf_static_topic;
        for (i, seen) in self.cameras.iter().enumerate() {
            let frame = &seen.frame_id;
            let error = match tf.lookup(frame, ref_frame) {
                Ok(_) => continue,
                Err(e) => e,
            };
            let name = &config.cameras[i];
            if let TfError::InvalidLookupFrame { .. } = error {
                return Some(Why {
                    kind: WhyKind::FrameId,
                    camera: Some(i),
                    message: format!(
                        "camera '{name}': its images' frame ids cannot be looked up in /tf_static: {error}"
                    ),
                });
            }
            let link = format!("no transform from '{ref_frame}' to '{frame}' in {topic}");
            let (kind, message) = match (self.tf_static, peers(topic)) {
                (0, Publishers::None) => (
                    WhyKind::NoPublisher,
                    format!("{link}: {}", no_publisher(topic)),
                ),
                (0, Publishers::Incompatible(why)) => (
                    WhyKind::IncompatibleQos,
                    format!("{link}: {}", incompatible(topic, &why)),
                ),
                (0, _) if asked.live() => (
                    WhyKind::NoTransform,
                    format!("{link}: nothing received on {topic} yet"),
                ),
                (0, _) => (
                    WhyKind::NoTransform,
                    format!("{link}: {topic} never recorded"),
                ),
                _ => (
                    WhyKind::NoTransform,
                    format!("{link} (camera '{name}'): {}", tf_reason(&error)),
                ),
            };
            return Some(Why {
                kind,
                camera: Some(i),
                message,
            });
        }
        None
    }

    /// Complete sets: every input arrives; do the stamps allow a set?
    fn sets(&self, config: &PipelineConfig, asked: Asked) -> Option<Why> {
        if asked.recent(self.last_set_ns) {
            return None;
        }
        let name = |i: usize| config.cameras[i].as_str();
        match config.sync {
            SyncPolicy::Exact => {
                let pairs = (0..self.cameras.len())
                    .filter(|&c| c != config.reference())
                    .map(|c| (config.reference(), c))
                    .chain(
                        (0..self.cameras.len())
                            .flat_map(|a| (a + 1..self.cameras.len()).map(move |b| (a, b))),
                    );
                for (a, b) in pairs {
                    let (sa, sb) = (&self.cameras[a].stamps, &self.cameras[b].stamps);
                    if sa.iter().any(|t| sb.contains(t)) {
                        continue;
                    }
                    let (Some(&ta), Some(&tb)) = (sa.back(), sb.back()) else {
                        continue;
                    };
                    let (fa, fb) = stamps_pair(ta, tb);
                    return Some(Why {
                        kind: WhyKind::ExactSyncUnequal,
                        camera: Some(b),
                        message: format!(
                            "exact sync: stamps never equal ({} {fa}, {} {fb}); use sync:=approximate with sync_max_interval for cameras that are not hardware-synchronised",
                            name(a),
                            name(b)
                        ),
                    });
                }
            }
            SyncPolicy::Approximate {
                max_interval_ns, ..
            } => {
                if let Some((c, offset)) = self.worst_offset(config.reference()) {
                    if offset.abs() > max_interval_ns {
                        return Some(Why {
                            kind: WhyKind::SyncOffset,
                            camera: Some(c),
                            message: format!(
                                "{} is {:.0} ms {} the others; sync_max_interval is {:.0} ms",
                                name(c),
                                offset.abs() as f64 / 1e6,
                                if offset < 0 { "behind" } else { "ahead of" },
                                max_interval_ns as f64 / 1e6
                            ),
                        });
                    }
                }
            }
        }
        let latest: Vec<String> = self
            .cameras
            .iter()
            .enumerate()
            .filter_map(|(i, c)| c.stamps.back().map(|t| format!("{} {}", name(i), secs(*t))))
            .collect();
        Some(Why {
            kind: WhyKind::NoCompleteSet,
            camera: None,
            message: format!(
                "every camera sends but no set completes (latest stamps: {}); see the warnings above",
                latest.join(", ")
            ),
        })
    }

    /// The camera whose stamps are farthest from the others': for each pair of cameras the
    /// signed difference of their nearest recent stamps, for each camera the median over the
    /// others; the largest in magnitude (on a tie, not the reference).
    fn worst_offset(&self, reference: usize) -> Option<(usize, i64)> {
        let n = self.cameras.len();
        let nearest = |a: usize, b: usize| -> Option<i64> {
            let (sa, sb) = (&self.cameras[a].stamps, &self.cameras[b].stamps);
            sa.iter()
                .flat_map(|x| sb.iter().map(move |y| x - y))
                .min_by_key(|d| d.unsigned_abs())
        };
        let mut worst: Option<(usize, i64)> = None;
        for c in 0..n {
            let mut diffs: Vec<i64> = (0..n)
                .filter(|&o| o != c)
                .filter_map(|o| nearest(c, o))
                .collect();
            if diffs.is_empty() {
                continue;
            }
            diffs.sort_unstable();
            let median = diffs[(diffs.len() - 1) / 2];
            let better = match worst {
                None => true,
                Some((w, d)) => {
                    median.unsigned_abs() > d.unsigned_abs()
                        || (median.unsigned_abs() == d.unsigned_abs() && w == reference)
                }
            };
            if better {
                worst = Some((c, median));
            }
        }
        worst
    }

    /// Sets complete: skipped, or waiting for their world pose.
    fn later(
        &self,
        config: &PipelineConfig,
        waiting_for_pose: usize,
        asked: Asked,
        peers: &dyn Fn(&str) -> Publishers,
    ) -> Option<Why> {
        if let Some(skip) = &self.last_skip {
            let mut message = format!("sets are skipped: {skip}");
            // Skipped for want of a world pose with nothing ever on /tf and nobody publishing
            // it: that is the cause to name (the skip alone says only what tf2 lacks).
            if let (SkipKind::NoWorldPose, 0, Some(world)) = (skip.kind, self.tf, &config.world) {
                if peers(&world.tf_topic) == Publishers::None {
                    message = format!("{message}; {}", no_publisher(&world.tf_topic));
                }
            }
            return Some(Why {
                kind: WhyKind::Skipped,
                camera: skip.camera,
                message,
            });
        }
        let world = config.world.as_ref()?;
        if waiting_for_pose == 0 {
            return None;
        }
        let topic = &world.tf_topic;
        let why = match (self.tf, peers(topic)) {
            (0, Publishers::None) => no_publisher(topic),
            (0, Publishers::Incompatible(why)) => incompatible(topic, &why),
            (0, _) if asked.live() => format!("nothing received on {topic} yet"),
            (0, _) => format!("{topic} never recorded"),
            _ => format!("{topic} has not reached their stamps yet"),
        };
        Some(Why {
            kind: WhyKind::WaitingForPose,
            camera: None,
            message: format!(
                "{waiting_for_pose} set(s) wait for their pose in world_frame '{}': {why}",
                world.frame
            ),
        })
    }
}

fn no_publisher(topic: &str) -> String {
    format!("no publisher on {topic}: check the namespace, the remaps and ROS_DOMAIN_ID")
}

fn incompatible(topic: &str, why: &str) -> String {
    format!("the publisher on {topic} cannot match: {why}")
}

/// ", 1 publisher matched, nothing received" when discovery knows.
fn matched(peers: &Publishers) -> String {
    match peers {
        Publishers::Matched(n) => format!(
            " ({n} publisher{} matched, nothing received)",
            if *n == 1 { "" } else { "s" }
        ),
        _ => String::new(),
    }
}

/// The reason of a failed lookup without the frames, which the sentence names already.
fn tf_reason(error: &TfError) -> String {
    match error {
        TfError::NotConnected { reason, .. } => reason.clone(),
        other => other.to_string(),
    }
}

/// Seconds with milliseconds.
fn secs(ns: i64) -> String {
    format!("{:.3}", ns as f64 / 1e9)
}

/// Two stamps, with nanoseconds where milliseconds would look equal.
fn stamps_pair(a: i64, b: i64) -> (String, String) {
    let (fa, fb) = (secs(a), secs(b));
    if fa == fb {
        let exact = |ns: i64| {
            format!(
                "{}.{:09}",
                ns.div_euclid(1_000_000_000),
                ns.rem_euclid(1_000_000_000)
            )
        };
        (exact(a), exact(b))
    } else {
        (fa, fb)
    }
}

#[cfg(test)]
mod tests;
