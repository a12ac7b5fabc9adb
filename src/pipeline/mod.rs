//! The DDS-free pipeline that the live node (`node`) and the offline bag processor (`bag`)
//! both run, so that a bag and the same bag played live give the same depth. It never imports
//! `node` or `bag`: they drive it through one small API.
//!
//! * [`Pipeline::push`] takes one input message ([`Input`]: an image, a CameraInfo, a
//!   `/tf_static` message) and says what it gave ([`Outcome`]): the sets it completed, each a
//!   [`Job`] for the engine or a [`Skip`] that says why not; the synchroniser's verdict on an
//!   image ([`SyncVerdict`]); problems with the input ([`Notice`]); cameras that left or
//!   rejoined the rig ([`RigEvent`]). [`Pipeline::finish`] ends the input (a bag's end).
//! * [`EngineHost::process`] runs a job through the engine and builds the output messages
//!   ([`FrameOutputs`], published or recorded under [`OutputTopics`]).
//!
//! The path of an image, room by room: `roster` (is its camera in the rig? a silent camera
//! leaves it after `camera_timeout`) → the synchroniser (`crate::ros::sync`: the time rules'
//! verdict, then exact or approximate matching over the cameras in the rig) → [`calibration`]
//! (each image of a complete set gets its camera model from its CameraInfo or the rig file,
//! its pose from `/tf_static` or the rig file; the image headers are checked: a set that fails
//! is skipped here, before it can take another set's place in the node's GPU queue) →
//! [`EngineHost`] ([`convert`] into the engine's images, the sweep, the output messages).

pub mod calibration;
pub mod compressed;
pub mod config;
pub mod convert;
mod counts;
pub mod depth_in;
pub mod engine_host;
pub mod fuser;
pub mod fuser_thread;
pub mod fusion_device;
pub mod out_messages;
pub mod outcome;
pub mod output_list;
pub mod outputs;
mod pose_queue;
mod roster;
pub mod why;
mod world;

pub use calibration::intrinsics_info;
pub use config::{
    ConfigError, FusionConfig, PipelineConfig, SyncPolicy, VirtualConfig, WorldConfig,
};
pub use counts::{Counts, SkipCounts};
pub use depth_in::{ColourImage, DepthSkip, DepthSources};
pub use engine_host::{EngineHost, Finished, HostError};
pub use fuser::{FuseSkip, Fuser, FusionInput, SavedMesh};
pub use fuser_thread::{FuserThread, FusionStats};
pub use fusion_device::{fusion_gpu, FusionHost, FusionPlacement};
pub use outcome::{
    Degraded, Input, InputImage, Job, JobReference, Notice, NoticeKind, Outcome, RigEvent, Skip,
    SkipKind, SyncVerdict, VirtualCamera,
};
pub use output_list::{MsgType, Output, OutputMsg, OutputRef, OutputSpec, OutputTopics, OUTPUTS};
pub use outputs::{process_job, FrameMaps, FrameMessages, FrameOutputs, SetOutputs, Wanted};
pub use why::{Asked, Publishers, Why, WhyKind};

use crate::msgs::Time;
use crate::ros::sync::{time_to_ns, Admission, Discarded, SyncError, Synchronizer};

use calibration::Calibration;
use roster::Roster;
use world::WorldPoses;

/// The input side: calibration state, which cameras are in the rig, the synchroniser.
pub struct Pipeline<'a> {
    config: &'a PipelineConfig,
    calibration: Calibration,
    /// A moving rig (`world_frame`): the transforms and the sets waiting for their pose.
    world: Option<WorldPoses>,
    roster: Roster,
    sync: Box<dyn Synchronizer<InputImage> + Send>,
    /// While no set can be formed (the reference or the second camera silent): the images of
    /// the cameras in the rig, the newest `queue_size` of each camera, for the synchroniser
    /// once sets can be formed again (the camera that comes back costs no set).
    held: Vec<(usize, InputImage)>,
    /// What came in and what it gave, for [`Pipeline::why_no_depth`].
    seen: why::Seen,
}

impl<'a> Pipeline<'a> {
    pub fn new(config: &'a PipelineConfig) -> Result<Self, SyncError> {
        let n = config.cameras.len();
        Ok(Self {
            config,
            calibration: Calibration::new(n),
            world: config.world.as_ref().map(|_| WorldPoses::default()),
            roster: Roster::new(
                config.cameras.clone(),
                config.references.iter().map(|(r, _)| *r).collect(),
                config.camera_timeout,
            ),
            sync: config.synchronizer(n)?,
            held: Vec::new(),
            seen: why::Seen::new(n),
        })
    }

    pub fn config(&self) -> &PipelineConfig {
        self.config
    }

    /// Names of the cameras currently out of the rig.
    pub fn inactive_cameras(&self) -> Vec<String> {
        self.roster.inactive()
    }

    /// Why no set is formed while the cameras out of the rig leave no reference or fewer than
    /// two cameras; None while the rig can publish.
    pub fn halted(&self) -> Option<String> {
        (!self.roster.publishing()).then(|| self.degraded().message)
    }

    /// One input message, received at `now_ns` (any monotonic clock in nanoseconds: receive
    /// time live, log time in a bag; it times camera dropout).
    pub fn push(&mut self, input: Input, now_ns: u64) -> Outcome {
        match &input {
            Input::Image { camera, image } => self.seen.image(*camera, &image.header, now_ns),
            Input::Compressed { camera, image } => self.seen.image(*camera, &image.header, now_ns),
            Input::CameraInfo { camera, .. } => self.seen.info(*camera),
            Input::TfStatic(_) => self.seen.tf_static(),
            Input::Tf(_) => self.seen.tf(),
        }
        let outcome = self.push_input(input, now_ns);
        self.seen.outcome(&outcome, now_ns);
        outcome
    }

    /// Why no depth comes out, as of `asked` (the first thing a set is missing; None when
    /// sets are ready for the engine): `peers` says what DDS discovery knows of an input
    /// topic's publishers ([`Publishers::Unknown`] without DDS).
    pub fn why_no_depth(&self, asked: Asked, peers: &dyn Fn(&str) -> Publishers) -> Option<Why> {
        self.seen.diagnose(
            self.config,
            self.calibration.tf(),
            self.waiting_for_pose(),
            asked,
            peers,
        )
    }

    fn push_input(&mut self, input: Input, now_ns: u64) -> Outcome {
        let n = self.config.cameras.len();
        let out_of_range = |what: &str, camera: usize| {
            Outcome::notice(
                NoticeKind::Input,
                None,
                format!("{what} of camera index {camera}, but the rig has {n} cameras; ignored"),
            )
        };
        match input {
            Input::Image { camera, image } => {
                if camera >= n {
                    return out_of_range("an image", camera);
                }
                self.on_image(camera, InputImage::Raw(image), now_ns)
            }
            Input::Compressed { camera, image } => {
                if camera >= n {
                    return out_of_range("an image", camera);
                }
                self.on_image(camera, InputImage::Compressed(image), now_ns)
            }
            Input::CameraInfo { camera, info } => {
                if camera >= n {
                    return out_of_range("a camera_info", camera);
                }
                self.calibration.set_info(camera, *info);
                Outcome::default()
            }
            Input::TfStatic(msg) => {
                let mut outcome = Outcome {
                    notices: self
                        .calibration
                        .add_tf(&msg)
                        .into_iter()
                        .map(|e| Notice {
                            kind: NoticeKind::Transform,
                            camera: None,
                            message: format!("{}: {e}", self.config.tf_static_topic),
                        })
                        .collect(),
                    ..Outcome::default()
                };
                if let Some(world) = &mut self.world {
                    // (Its complaints about the message are the calibration's, above.)
                    let _ = world.add(&msg, true);
                }
                self.posed(&mut outcome, now_ns, false);
                outcome
            }
            Input::Tf(msg) => {
                let mut outcome = Outcome::default();
                let (Some(world), Some(world_config)) = (&mut self.world, &self.config.world)
                else {
                    return outcome;
                };
                let (rejected, cleared) = world.add(&msg, false);
                if cleared {
                    outcome.notices.push(Notice {
                        kind: NoticeKind::TimeReset,
                        camera: None,
                        message: format!(
                            "{}: time went back; the transforms of /tf received so far are cleared (as tf2 does)",
                            world_config.tf_topic
                        ),
                    });
                }
                outcome.notices.extend(rejected.into_iter().map(|e| Notice {
                    kind: NoticeKind::Transform,
                    camera: None,
                    message: format!("{}: {e}", world_config.tf_topic),
                }));
                self.posed(&mut outcome, now_ns, false);
                outcome
            }
        }
    }

    /// A moving rig: the completed sets of `outcome` wait for their pose; those done waiting
    /// (`flush`: all of them) take their place, in order.
    fn posed(&mut self, outcome: &mut Outcome, now_ns: u64, flush: bool) {
        let (Some(world), Some(config)) = (&mut self.world, &self.config.world) else {
            return;
        };
        let mut sets = Vec::with_capacity(outcome.sets.len());
        for set in outcome.sets.drain(..) {
            match set {
                Ok(job) => world.push(job, now_ns, config),
                Err(skip) => sets.push(Err(skip)),
            }
        }
        sets.extend(world.ready(now_ns, config, flush));
        outcome.sets = sets;
    }

    /// Sets waiting for their pose in the world frame (`world_frame`).
    pub fn waiting_for_pose(&self) -> usize {
        self.world.as_ref().map_or(0, WorldPoses::waiting)
    }

    /// End of input (the end of a bag): the sets the synchroniser still held back.
    pub fn finish(&mut self) -> Outcome {
        let outcome = self.finish_input();
        self.seen.outcome(&outcome, u64::MAX);
        outcome
    }

    fn finish_input(&mut self) -> Outcome {
        if !self.roster.publishing() {
            let mut outcome = Outcome::default();
            self.posed(&mut outcome, u64::MAX, true);
            return outcome;
        }
        let flushed = self.sync.flush();
        let mut outcome = Outcome {
            sync: Some(SyncVerdict {
                camera: None,
                stamp: Time::default(),
                admission: None,
                sets: flushed.sets.len(),
                discarded: flushed.discarded,
            }),
            sets: flushed
                .sets
                .into_iter()
                .map(|set| self.calibration.job(self.config, self.roster.active(), set))
                .collect(),
            ..Outcome::default()
        };
        self.posed(&mut outcome, u64::MAX, true);
        outcome
    }

    /// The rig changed (`before`: the cameras in it until now): the synchroniser is rebuilt
    /// over the cameras in it now, and what the old one held carries over, so that a camera
    /// that leaves or comes back costs no set: the sets it only waited to prove are emitted
    /// (over `before`), and the images it still held (with those held while no set could be
    /// formed) are pushed again, in stamp order, into the new one, or held while no set can be
    /// formed. The old synchroniser counted its images when they came, so only what becomes
    /// of them now counts (into `carried`: sets, and the images dropped, such as those of a
    /// camera that left). Below 2 cameras the old synchroniser is kept, empty.
    fn rebuild(&mut self, before: &[usize], outcome: &mut Outcome, carried: &mut SyncVerdict) {
        let config = self.config;
        let drained = self.sync.drain();
        carried.sets += drained.sets.len();
        carried.discarded.messages += drained.discarded.messages;
        carried.discarded.partial_sets += drained.discarded.partial_sets;
        for set in drained.sets {
            outcome.sets.push(self.calibration.job(config, before, set));
        }
        if self.roster.active().len() >= 2 {
            match config.synchronizer(self.roster.active().len()) {
                Ok(sync) => self.sync = sync,
                Err(e) => outcome.notices.push(Notice {
                    kind: NoticeKind::Input,
                    camera: None,
                    message: format!("cannot make the synchroniser: {e}"),
                }),
            }
        }
        // By camera, in stamp order (each camera's images in the order they came).
        let mut images: Vec<(usize, i64, InputImage)> = drained
            .buffered
            .into_iter()
            .map(|(stream, t, image)| (before.get(stream).copied().unwrap_or(stream), t, image))
            .chain(
                self.held
                    .drain(..)
                    .map(|(c, image)| (c, time_to_ns(&image.header().stamp), image)),
            )
            .collect();
        images.sort_by_key(|&(c, t, _)| (t, c));
        let open =
            self.roster.publishing() && self.sync.num_streams() == self.roster.active().len();
        let mut dropped = 0;
        for (camera, stamp_ns, image) in images {
            let Some(stream) = self.roster.stream_of(camera) else {
                dropped += 1;
                continue;
            };
            if !open {
                self.hold(camera, image);
                continue;
            }
            match self.sync.push(stream, stamp_ns, image) {
                Ok(pushed) => {
                    if matches!(pushed.admission, Admission::Dropped(_)) {
                        dropped += 1;
                    }
                    carried.sets += pushed.sets.len();
                    carried.discarded.messages += pushed.discarded.messages;
                    carried.discarded.partial_sets += pushed.discarded.partial_sets;
                    for set in pushed.sets {
                        let job = self.calibration.job(config, self.roster.active(), set);
                        outcome.sets.push(job);
                    }
                }
                Err(_) => dropped += 1,
            }
        }
        if dropped > 0 {
            carried.discarded.messages += dropped;
            carried.discarded.partial_sets += 1;
        }
    }

    /// Holds `image` of `camera` while no set can be formed (the camera's oldest held image
    /// goes beyond `queue_size`).
    fn hold(&mut self, camera: usize, image: InputImage) {
        self.held.push((camera, image));
        if self.held.iter().filter(|(c, _)| *c == camera).count() > self.config.queue_size {
            if let Some(oldest) = self.held.iter().position(|(c, _)| *c == camera) {
                self.held.remove(oldest);
            }
        }
    }

    fn on_image(&mut self, camera: usize, image: InputImage, now_ns: u64) -> Outcome {
        let config = self.config;
        let before = self.roster.active().to_vec();
        let mut outcome = Outcome {
            rig_events: self.roster.track(camera, now_ns),
            ..Outcome::default()
        };
        if image.header().frame_id.is_empty() && config.rig_file.is_some() {
            // Placed by the rig file, the set goes on; but its outputs carry the frame_id,
            // and tf (RViz, fusion in another node) cannot place an empty one. Without the
            // rig file the lookup refuses it (SkipKind::FrameId).
            outcome.notices.push(Notice {
                kind: NoticeKind::EmptyFrameId,
                camera: Some(camera),
                message: format!(
                    "camera '{}': its images carry an empty frame_id, and so do the outputs \
                     made in its view: tf and RViz cannot place them; set the driver's \
                     frame_id (e.g. {}_optical_frame)",
                    config.cameras[camera], config.cameras[camera]
                ),
            });
        }
        if let Some((period_s, timeout_s)) = self.roster.too_slow(camera) {
            outcome.notices.push(Notice {
                kind: NoticeKind::SlowCamera,
                camera: Some(camera),
                message: format!(
                    "camera '{}' sends an image every {period_s:.2} s, more than half of \
                     camera_timeout ({timeout_s} s): an image that comes late takes it out of \
                     the rig; set camera_timeout to three frame periods or more",
                    self.config.cameras[camera]
                ),
            });
        }
        // What a rebuild of the synchroniser carried over (no image of its own).
        let mut carried = SyncVerdict {
            camera: None,
            stamp: Time::default(),
            admission: None,
            sets: 0,
            discarded: Discarded::default(),
        };
        // The synchroniser runs over the cameras in the rig; below 2 nothing is pushed.
        if !outcome.rig_events.is_empty() {
            self.rebuild(&before, &mut outcome, &mut carried);
        }
        if carried.sets > 0 || carried.discarded != Discarded::default() {
            outcome.sync = Some(carried);
        }
        if !self.roster.publishing() {
            // Once per round of images (at the first active camera), not once per image.
            let active = self.roster.active();
            if active.first() == Some(&camera) || active.len() <= 1 {
                outcome.sets.push(Err(self.degraded()));
            }
            self.hold(camera, image);
            if outcome.sets.iter().any(Result::is_ok) {
                // Sets of the rig before it changed.
                self.posed(&mut outcome, now_ns, false);
            }
            return outcome;
        }
        let Some(stream) = self.roster.stream_of(camera) else {
            return outcome;
        };
        let stamp = image.header().stamp;
        let pushed = match self.sync.push_stamped(stream, &stamp, image) {
            Ok(pushed) => pushed,
            Err(e) => {
                outcome.notices.push(Notice {
                    kind: NoticeKind::Input,
                    camera: Some(camera),
                    message: format!("synchroniser: {e}"),
                });
                return outcome;
            }
        };
        // The synchroniser counts streams (the cameras in the rig); the verdict names cameras.
        let admission = match pushed.admission {
            Admission::Reset(mut jump) => {
                jump.stream = self.roster.camera_of(jump.stream);
                Admission::Reset(jump)
            }
            other => other,
        };
        let reset = matches!(admission, Admission::Reset(_));
        // With what a rebuild carried over, if any.
        let verdict = SyncVerdict {
            camera: Some(camera),
            stamp,
            admission: Some(admission),
            sets: carried.sets + pushed.sets.len(),
            discarded: Discarded {
                messages: carried.discarded.messages + pushed.discarded.messages,
                partial_sets: carried.discarded.partial_sets + pushed.discarded.partial_sets,
            },
        };
        let future_window_s = config.time_rules.future_window_ns as f64 / 1e9;
        outcome
            .notices
            .extend(verdict.notice(&config.cameras, future_window_s));
        outcome.sync = Some(verdict);
        outcome.sets.extend(
            pushed
                .sets
                .into_iter()
                .map(|set| self.calibration.job(config, self.roster.active(), set)),
        );
        if reset {
            if let Some(world) = &mut self.world {
                world.clear_dynamic();
            }
        }
        self.posed(&mut outcome, now_ns, false);
        outcome
    }

    /// Why no set is formed while the rig is degraded.
    fn degraded(&self) -> Skip {
        let references: Vec<&str> = self
            .config
            .references
            .iter()
            .map(|(r, _)| self.config.cameras[*r].as_str())
            .collect();
        let silent = self.roster.inactive().join(", ");
        let why = if !self
            .config
            .references
            .iter()
            .any(|(r, _)| self.roster.active().contains(r))
        {
            match references.as_slice() {
                [one] => format!("the reference camera '{one}' is silent"),
                all => format!("every reference camera ({}) is silent", all.join(", ")),
            }
        } else {
            "fewer than 2 cameras are sending".to_string()
        };
        Skip::new(
            SkipKind::DegradedRig,
            None,
            format!("{why} (out of the rig: {silent}); not publishing"),
        )
    }
}
