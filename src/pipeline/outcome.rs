//! What goes into the pipeline ([`Input`]) and what one input gives ([`Outcome`]): the sets it
//! completed, each a [`Job`] for the engine or a [`Skip`] that says why not; the
//! synchroniser's verdict on an image ([`SyncVerdict`]); problems with the input itself
//! ([`Notice`]); cameras leaving or rejoining the rig ([`RigEvent`]).

use std::fmt;

use crate::geometry::{CameraModel, RigCamera, RigidTransform};
use crate::msgs::{CameraInfo, CompressedImage, Header, Image, TFMessage, Time};
use crate::ros::sync::{Admission, Discarded, DropReason, SyncStats};

/// One input message of the pipeline.
#[derive(Debug, Clone)]
pub enum Input {
    /// An image of camera `camera` (an index into the configuration's cameras).
    Image { camera: usize, image: Image },
    /// A compressed image of camera `camera` (image_transport's `compressed` plugin): carried
    /// through the synchroniser as it came, decoded once its set is complete
    /// (`compressed::decode_set`).
    Compressed {
        camera: usize,
        image: CompressedImage,
    },
    /// The latest calibration of camera `camera`.
    CameraInfo {
        camera: usize,
        info: Box<CameraInfo>,
    },
    /// A `/tf_static` message.
    TfStatic(TFMessage),
    /// A `/tf` message (read only with `world_frame`: a moving rig).
    Tf(TFMessage),
}

/// A camera image as the synchroniser holds it: raw, or still compressed (decoded only when its
/// set is complete, so images the synchroniser drops are never decoded).
#[derive(Debug, Clone)]
pub enum InputImage {
    Raw(Image),
    Compressed(CompressedImage),
}

impl InputImage {
    pub fn header(&self) -> &Header {
        match self {
            InputImage::Raw(image) => &image.header,
            InputImage::Compressed(image) => &image.header,
        }
    }
}

/// One synchronised set with its calibration, ready for the engine.
#[derive(Debug, Clone)]
pub struct Job {
    /// The images, one per camera in the rig (the cameras of `cameras`), headers checked.
    pub images: Vec<Image>,
    pub cameras: Vec<RigCamera>,
    /// Every reference of the set that is in the rig (`references`; one entry with one
    /// reference, a virtual camera included), in the order of the configuration.
    pub references: Vec<JobReference>,
    /// The names of the configured references out of the rig in this set (no depth for them).
    pub absent_references: Vec<String>,
    /// The frame of the reference's image (`header.frame_id`) and its pose in the rig frame
    /// (the cameras' `cam_from_rig` are relative to the rig frame).
    pub ref_frame: String,
    pub ref_frame_from_rig: RigidTransform,
    /// A moving rig (`world_frame`): the pose of the rig frame in the world frame at the set's
    /// stamp.
    pub world_from_rig: Option<RigidTransform>,
}

/// One reference of a [`Job`].
#[derive(Debug, Clone)]
pub struct JobReference {
    /// Its camera, as an index into the job's `cameras` and `images`.
    pub index: usize,
    /// Its entry in the configuration's `references` (its output topics).
    pub output: usize,
    /// The CameraInfo of its outputs.
    pub info: CameraInfo,
    /// Its camera (the one its model describes: rotated by R for a rectified image) in the
    /// frame its image's `header.frame_id` names; the points are published in that frame.
    /// Identity for a raw image and for a virtual camera.
    pub cam_from_frame: RigidTransform,
    /// The virtual camera that stands in for this reference (`virtual_reference`): the depth
    /// is for it, and `index` names the real camera whose image header its outputs carry.
    pub virtual_camera: Option<VirtualCamera>,
}

/// The virtual reference camera of a [`JobReference`]: its model, its pose in the rig and
/// the frame_id of its outputs.
#[derive(Debug, Clone)]
pub struct VirtualCamera {
    pub model: CameraModel,
    pub cam_from_rig: RigidTransform,
    pub frame_id: String,
}

impl Job {
    /// Index into `images` of the image whose frame anchors the rig (`ref_frame`) and whose
    /// header stamps the set: the first configured reference's, or the first image when
    /// that reference is out of the rig.
    pub fn anchor(&self) -> usize {
        self.references
            .first()
            .filter(|r| r.output == 0)
            .map_or(0, |r| r.index)
    }
}

/// Why a set was not processed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SkipKind {
    /// The reference camera is out of the rig, or fewer than 2 cameras remain.
    DegradedRig,
    /// A CameraInfo that cannot describe its image.
    CameraInfo,
    /// No CameraInfo yet (and no intrinsics in the rig file).
    WaitingForCameraInfo,
    /// A transform of `/tf_static` not known yet.
    WaitingForTransform,
    /// A frame id tf2 would refuse to look up (empty, or starting with '/'): no `/tf_static`
    /// can cure it.
    FrameId,
    /// The rig file's intrinsics do not fit the image, or it lacks the camera.
    RigFile,
    /// An image header the engine cannot take (encoding, size, step, data length).
    Image,
    /// A compressed image that cannot be decoded: corrupt or truncated data, a format that
    /// lies about the codec or the channels, a format not decoded here.
    Decode,
    /// The cameras do not make a rig.
    Rig,
    /// The engine refused or failed.
    Engine,
    /// The GPU device was lost and could not be made anew.
    GpuLost,
    /// A moving rig (`world_frame`): no pose of the set in the world frame at its stamp.
    NoWorldPose,
}

impl SkipKind {
    /// A short stable label (the bag summary counts skips by it).
    pub fn label(self) -> &'static str {
        match self {
            SkipKind::DegradedRig => "degraded rig",
            SkipKind::CameraInfo => "camera_info",
            SkipKind::WaitingForCameraInfo => "waiting for camera_info",
            SkipKind::WaitingForTransform => "waiting for transform",
            SkipKind::FrameId => "frame_id",
            SkipKind::RigFile => "rig file",
            SkipKind::Image => "image",
            SkipKind::Decode => "decode",
            SkipKind::Rig => "rig",
            SkipKind::Engine => "engine",
            SkipKind::GpuLost => "gpu lost",
            SkipKind::NoWorldPose => "no world pose",
        }
    }
}

impl fmt::Display for SkipKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.label())
    }
}

/// A set that was not processed, and precisely why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Skip {
    pub kind: SkipKind,
    /// The camera (an index into the configuration's cameras) it is about, if one.
    pub camera: Option<usize>,
    pub message: String,
}

impl Skip {
    pub fn new(kind: SkipKind, camera: Option<usize>, message: String) -> Self {
        Self {
            kind,
            camera,
            message,
        }
    }

    /// Unique per kind and camera: repeats of the same problem share it (rate-limited logs).
    pub fn key(&self) -> String {
        key(self.kind.label(), self.camera)
    }
}

impl fmt::Display for Skip {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

/// What a [`Notice`] is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NoticeKind {
    /// The time rules dropped an image: its stamp repeats the camera's previous one.
    DuplicateStamp,
    /// ... is older than the camera's previous one, or from before a reset.
    LateStamp,
    /// ... is far ahead of every other camera.
    FutureStamp,
    /// A camera's time went back: the synchroniser was reset.
    TimeReset,
    /// A transform of a `/tf_static` message was rejected.
    Transform,
    /// An input the pipeline cannot place (a camera index out of range) or a synchroniser
    /// that cannot be made.
    Input,
    /// A camera sends so rarely that `camera_timeout` takes it out of the rig at a late image.
    SlowCamera,
    /// An image with an empty `frame_id` placed by the rig file: its outputs carry none.
    EmptyFrameId,
}

impl NoticeKind {
    /// A short stable label.
    pub fn label(self) -> &'static str {
        match self {
            NoticeKind::DuplicateStamp => "duplicate stamp",
            NoticeKind::LateStamp => "late stamp",
            NoticeKind::FutureStamp => "future stamp",
            NoticeKind::TimeReset => "time reset",
            NoticeKind::Transform => "transform",
            NoticeKind::Input => "input",
            NoticeKind::SlowCamera => "slow camera",
            NoticeKind::EmptyFrameId => "empty frame_id",
        }
    }
}

/// A problem with one input that is not a set's, for the log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Notice {
    pub kind: NoticeKind,
    /// The camera it is about, if one.
    pub camera: Option<usize>,
    pub message: String,
}

impl Notice {
    /// Unique per kind and camera (rate-limited logs).
    pub fn key(&self) -> String {
        key(self.kind.label(), self.camera)
    }
}

impl fmt::Display for Notice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

fn key(label: &str, camera: Option<usize>) -> String {
    match camera {
        Some(i) => format!("{label}/{i}"),
        None => label.to_string(),
    }
}

/// A camera left the rig or came back (camera dropout).
#[derive(Debug, Clone, PartialEq)]
pub enum RigEvent {
    /// Silent for `quiet_s` seconds, longer than `timeout_s`.
    Left {
        camera: String,
        quiet_s: f64,
        timeout_s: f64,
        /// What the rig does without it.
        then: Degraded,
    },
    /// Sending again: back in the rig, which now has `active` of `total` cameras.
    Rejoined {
        camera: String,
        active: usize,
        total: usize,
    },
}

/// What the rig does after a camera left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degraded {
    /// It was the reference: nothing is published until it is back.
    ReferenceLost,
    /// It was not a reference, and no reference is in the rig either (one left before).
    ReferenceStillOut,
    /// Fewer than 2 cameras remain: nothing is published.
    TooFew,
    /// Depth goes on with the other `n` cameras.
    GoingOn(usize),
}

impl fmt::Display for RigEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RigEvent::Left {
                camera,
                quiet_s,
                timeout_s,
                then,
            } => {
                write!(f, "camera '{camera}' has sent nothing for {quiet_s:.2} s (camera_timeout {timeout_s} s) and leaves the rig; ")?;
                match then {
                    Degraded::ReferenceLost => f.write_str(
                        "it is the reference camera: no depth is published until it is back",
                    ),
                    Degraded::ReferenceStillOut => f.write_str(
                        "the reference camera is out of the rig too: no depth is published \
                         until it is back",
                    ),
                    Degraded::TooFew => {
                        f.write_str("fewer than 2 cameras remain: no depth is published")
                    }
                    Degraded::GoingOn(n) => write!(f, "going on with the other {n}"),
                }
            }
            RigEvent::Rejoined {
                camera,
                active,
                total,
            } => write!(
                f,
                "camera '{camera}' is sending again and is back in the rig ({active} of {total} cameras)"
            ),
        }
    }
}

/// What the synchroniser did with one image (or, at the end of the input, with what it held).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncVerdict {
    /// The camera of the image (None at the end of the input).
    pub camera: Option<usize>,
    pub stamp: Time,
    /// The time rules' verdict on the image (a reset's stream is a camera index); None at
    /// the end of the input.
    pub admission: Option<Admission>,
    /// Sets completed.
    pub sets: usize,
    /// Buffered images discarded without being used.
    pub discarded: Discarded,
}

impl SyncVerdict {
    /// Counts this verdict into running totals (`/diagnostics`, the bag summary).
    pub fn count(&self, stats: &mut SyncStats) {
        stats.count(self.admission, self.sets, self.discarded);
    }

    /// The notice for the log when the time rules dropped the image or reset the
    /// synchroniser; `cameras` names the cameras, `future_window_s` is `sync_future_window`.
    pub(super) fn notice(&self, cameras: &[String], future_window_s: f64) -> Option<Notice> {
        let name = |i: usize| cameras.get(i).map_or("?", String::as_str);
        let secs = |ns: i64| ns as f64 / 1e9;
        let t = secs(self.stamp.to_nanos());
        let camera = self.camera?;
        let dropped = |kind: NoticeKind, what: String| Notice {
            kind,
            camera: Some(camera),
            message: format!(
                "camera '{}': image stamped {t:.3} s {what}; dropped",
                name(camera)
            ),
        };
        match self.admission? {
            Admission::Accepted => None,
            Admission::Reset(jump) => {
                let (from, to) = (secs(jump.from_ns), secs(jump.to_ns));
                Some(Notice {
                    kind: NoticeKind::TimeReset,
                    camera: None,
                    message: format!(
                        "camera '{}': time went backwards from {from:.3} s to {to:.3} s (by {:.3} s, more than sync_reset_backwards; a bag played in a loop?): the synchroniser was reset and the queued images dropped",
                        name(jump.stream),
                        from - to
                    ),
                })
            }
            Admission::Dropped(DropReason::Duplicate) => Some(dropped(
                NoticeKind::DuplicateStamp,
                "repeats the camera's previous stamp".into(),
            )),
            Admission::Dropped(DropReason::Late) => Some(dropped(
                NoticeKind::LateStamp,
                "is older than the camera's previous image".into(),
            )),
            Admission::Dropped(DropReason::BeforeReset) => Some(dropped(
                NoticeKind::LateStamp,
                "is from before the last reset (the old timeline, still in flight)".into(),
            )),
            Admission::Dropped(DropReason::Future) => Some(dropped(
                NoticeKind::FutureStamp,
                format!(
                    "is more than {future_window_s} s (sync_future_window) ahead of every other camera"
                ),
            )),
        }
    }
}

/// What one input gave.
#[derive(Debug, Clone, Default)]
pub struct Outcome {
    /// The sets it completed, in order: each ready for the engine, or skipped and why.
    pub sets: Vec<Result<Job, Skip>>,
    /// What the synchroniser did with it (images pushed into it, and the end of the input).
    pub sync: Option<SyncVerdict>,
    /// Problems with the input itself, for the log (rate-limited by [`Notice::key`]).
    pub notices: Vec<Notice>,
    /// Cameras that left or rejoined the rig.
    pub rig_events: Vec<RigEvent>,
}

impl Outcome {
    /// An outcome with one notice and nothing else.
    pub(super) fn notice(kind: NoticeKind, camera: Option<usize>, message: String) -> Self {
        Self {
            notices: vec![Notice {
                kind,
                camera,
                message,
            }],
            ..Self::default()
        }
    }

    /// The jobs, in order (the skipped sets dropped).
    pub fn jobs(self) -> impl Iterator<Item = Job> {
        self.sets.into_iter().filter_map(Result::ok)
    }

    /// The skipped sets.
    pub fn skips(&self) -> impl Iterator<Item = &Skip> {
        self.sets.iter().filter_map(|s| s.as_ref().err())
    }
}
