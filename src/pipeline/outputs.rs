//! One job through the engine ([`process_job`]) and what it gives per reference
//! ([`FrameOutputs`]): the maps as floats, and the messages, all with the reference camera's
//! header.

use super::convert::{packed_view, set_to_rgba8, some_to_rgba8, ConvertError};
use super::out_messages::{
    depth_and_confidence_msgs, f32_image_msg, lent_depth_and_confidence_msgs, point_cloud_msg,
    selection_msg,
};
use super::outcome::{Job, JobReference, Skip, SkipKind, VirtualCamera};
use crate::engine::{StartedSet, Sweeper};
use crate::fusion::rms_baseline_m;
use crate::geometry::{CameraModel, Reference, Rig, RigidTransform};
use crate::image::{CameraImage, ImageF32, Rgba8Image, SetImages};
use crate::msgs::{CameraInfo, Header, Image, PointCloud2};
use crate::sweep::gpu::HostCopies;
use crate::sweep::references::{ReferenceDepth, ReferenceMaps};
use crate::sweep::{DepthMaps, SweepError, SweepParams, WantedMaps};
use std::sync::Arc;

/// What one reference of a frame set gives: its depth maps as floats, with where its camera
/// is ([`FrameMaps`], what fusion and the pose bookkeeping read), and its messages
/// ([`FrameMessages`], what is published or recorded on [`super::OutputTopics`], `output` of
/// the configuration's `references`). Kept apart so that nothing decodes a message back.
#[derive(Debug, Clone)]
pub struct FrameOutputs {
    /// Which of the configuration's `references` (its topics).
    pub output: usize,
    pub maps: FrameMaps,
    pub messages: FrameMessages,
}

/// One reference's depth and confidence as the engine gave them, and its camera's place.
#[derive(Debug, Clone)]
pub struct FrameMaps {
    /// The messages' header: the reference camera's stamp; its frame_id, or the virtual
    /// camera's.
    pub header: Header,
    /// z along the optical axis in metres, NaN where invalid (the `depth` message's values;
    /// 0 x 0 where the engine's host was told no floats are kept: `EngineHost::set_keep_floats`).
    pub depth_m: ImageF32,
    /// In [0, 1], 0 where invalid (the `confidence` message's values; 0 x 0 as `depth_m`).
    pub confidence: ImageF32,
    /// A moving rig (`world_frame`): the pose of the header's frame in the world frame at the
    /// header's stamp (what tf2 gives a ROS user for the same stamp).
    pub world_from_frame: Option<RigidTransform>,
    /// The pose of the header's frame in the rig frame (the frame the set's cameras are placed
    /// in: the first reference image's frame, or the rig file's).
    pub rig_from_frame: RigidTransform,
    /// Where a rig that stands still is fused: the frame of the set's first reference image
    /// (`Job::ref_frame`), named, and the header's frame in it.
    pub anchor_frame: String,
    pub anchor_from_frame: RigidTransform,
    /// The camera the depth is in (its model and its pose in the header's frame: a rectified
    /// camera is its frame rotated by R), for consumers that unproject it (fusion).
    pub model: CameraModel,
    pub frame_from_cam: RigidTransform,
    /// The reference camera's image (None for a virtual reference), shared, not copied.
    pub colour: Option<Arc<Rgba8Image>>,
    /// This reference's baseline (`fusion::rms_baseline_m`) over the largest of its set's
    /// references, for fusion's weights (None for a virtual reference).
    pub baseline_ratio: Option<f32>,
}

impl FrameMaps {
    /// The confidence, None where it is not the depth's size.
    pub fn confidence_map(&self) -> Option<&ImageF32> {
        let same = self.confidence.width == self.depth_m.width
            && self.confidence.height == self.depth_m.height;
        same.then_some(&self.confidence)
    }
}

/// The messages of one reference, all with the same header ([`FrameMaps::header`]).
#[derive(Debug, Clone)]
pub struct FrameMessages {
    pub depth: Image,
    pub depth_info: CameraInfo,
    pub confidence: Image,
    /// None where the set was not asked for it ([`Wanted`]).
    pub cost: Option<Image>,
    pub selection: Option<Image>,
    pub points: Option<PointCloud2>,
}

/// Which of a reference's outputs that cost work to make a set makes (depth, its camera info
/// and confidence always): the node asks for those that have subscribers, `bag` for what it
/// writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wanted {
    pub cost: bool,
    pub selection: bool,
    pub points: bool,
}

impl Wanted {
    /// Depth, its camera info and confidence only.
    pub const NONE: Self = Self {
        cost: false,
        selection: false,
        points: false,
    };

    /// Cost and selection, and the points as `points` says.
    pub fn all(points: bool) -> Self {
        Self {
            cost: true,
            selection: true,
            points,
        }
    }

    /// Each output either wants.
    pub fn or(self, other: Self) -> Self {
        Self {
            cost: self.cost || other.cost,
            selection: self.selection || other.selection,
            points: self.points || other.points,
        }
    }

    /// The outputs `messages` has.
    pub fn made(messages: &FrameMessages) -> Self {
        Self {
            cost: messages.cost.is_some(),
            selection: messages.selection.is_some(),
            points: messages.points.is_some(),
        }
    }

    /// "cost, selection", or "none" (`/diagnostics`, the log).
    pub fn describe(self) -> String {
        let names: Vec<&str> = [
            (self.cost, "cost"),
            (self.selection, "selection"),
            (self.points, "points"),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect();
        if names.is_empty() {
            "none".into()
        } else {
            names.join(", ")
        }
    }

    /// The engine's maps for these outputs (never the diagnostic ones); depth and confidence
    /// as floats of the caller's own where `keep_floats` (fusion reads them) or the points
    /// are made from them, else they may come lent out of the WGSL engine's readback buffer.
    pub fn maps(self, keep_floats: bool) -> WantedMaps {
        WantedMaps {
            cost: self.cost,
            selection: self.selection,
            diagnostics: false,
            floats: keep_floats || self.points,
        }
    }
}

/// What one frame set gives: each reference's outputs, and the references that failed.
#[derive(Debug, Clone, Default)]
pub struct SetOutputs {
    pub outputs: Vec<FrameOutputs>,
    /// One per reference that gave nothing, with why.
    pub skipped: Vec<Skip>,
}

/// Runs one job through the engine with the given parameters and builds its output messages
/// (those `wanted`; the engine is told which maps that needs by its caller,
/// `EngineHost::process`): every reference of the job, the set's images
/// converted once. Fails as a whole only when its images cannot be read.
pub fn process_job(
    engine: &mut impl Sweeper,
    job: &Job,
    sweep: &SweepParams,
    wanted: Wanted,
) -> Result<SetOutputs, Skip> {
    let started = start_job(engine, job, sweep, wanted);
    finish_job(engine, started, job, sweep, wanted)
}

/// A job [`start_job`] started, for [`finish_job`].
pub struct StartedJob(Started);

impl StartedJob {
    /// A job run to the end already, or that could not start.
    pub fn done(result: Result<SetOutputs, Skip>) -> Self {
        Self(Started::Done(result))
    }
}

enum Started {
    /// Run to the end already (the CPU engine, a virtual camera, images that cannot be read).
    Done(Result<SetOutputs, Skip>),
    /// Its references started on an engine that unpacks on the device
    /// ([`Sweeper::start_references_set`]), with the images it took converted.
    Engine {
        converted: Vec<Option<Rgba8Image>>,
        started: StartedSet,
    },
}

/// [`process_job`] up to the engine's start of the set: on an engine that starts without
/// waiting ([`Sweeper::starts_without_waiting`]), the set is on the device when this returns
/// and the caller may start the next before it finishes this one with [`finish_job`] (jobs
/// finish in the order they started, each with the same job, parameters and outputs).
pub fn start_job(
    engine: &mut impl Sweeper,
    job: &Job,
    sweep: &SweepParams,
    wanted: Wanted,
) -> StartedJob {
    let name = |i| camera_name(job, i);
    let packed = |i| packed_image(job, i);
    let first_virtual = job
        .references
        .first()
        .and_then(|r| Some((r, r.virtual_camera.as_ref()?)));
    if let Some((first, virtual_camera)) = first_virtual {
        let done = virtual_outputs(engine, job, (first, virtual_camera), sweep, wanted);
        return StartedJob(Started::Done(done));
    }
    let indices: Vec<usize> = job.references.iter().map(|r| r.index).collect();
    if !engine.unpacks_on_device() {
        let done = set_to_rgba8(&job.images, name)
            .map_err(image_skip)
            .map(|images| {
                let results = engine.run_references(&job.cameras, &images, &indices, sweep);
                let images = images.into_iter().map(Some).collect();
                job_outputs(job, results, images, wanted)
            });
        return StartedJob(Started::Done(done));
    }
    // An engine that unpacks on the device takes the bytes of every camera whose encoding it
    // unpacks as they came (no conversion here, fewer bytes to upload).
    let converted = match some_to_rgba8(&job.images, name, |i| packed(i).is_none()) {
        Ok(converted) => converted,
        Err(e) => return StartedJob(Started::Done(Err(image_skip(e)))),
    };
    let cameras = engine_images(&converted, packed);
    let set = SetImages::Cameras {
        set: &cameras,
        picked: None,
    };
    let started = engine.start_references_set(&job.cameras, set, &indices, sweep);
    drop(cameras);
    StartedJob(Started::Engine { converted, started })
}

/// The outputs of a job [`start_job`] started: the engine's results read back while the
/// references' colour is converted on rayon's threads, then each reference's messages.
pub fn finish_job(
    engine: &mut impl Sweeper,
    started: StartedJob,
    job: &Job,
    sweep: &SweepParams,
    wanted: Wanted,
) -> Result<SetOutputs, Skip> {
    let (converted, started) = match started.0 {
        Started::Done(done) => return done,
        Started::Engine { converted, started } => (converted, started),
    };
    let name = |i| camera_name(job, i);
    let packed = |i| packed_image(job, i);
    let indices: Vec<usize> = job.references.iter().map(|r| r.index).collect();
    // The images go on to the outputs (colour for points and fusion) without a copy.
    let cameras = engine_images(&converted, packed);
    let set = SetImages::Cameras {
        set: &cameras,
        picked: None,
    };
    let colour_of = |i: usize| indices.contains(&i) && packed(i).is_some();
    let mut colour = Ok(Vec::new());
    let results = rayon::in_place_scope(|scope| {
        scope.spawn(|_| colour = some_to_rgba8(&job.images, name, colour_of));
        engine.finish_references_set(started, set, sweep)
    });
    drop(cameras);
    let mut colour = colour.map_err(image_skip)?;
    let mut colour = |i: usize| colour.get_mut(i).and_then(Option::take);
    let images = converted.into_iter().enumerate();
    let images: Vec<_> = images.map(|(i, c)| c.or_else(|| colour(i))).collect();
    Ok(job_outputs(job, results, images, wanted))
}

/// Each reference's outputs from the engine's `results` (in the job's order of references)
/// and the set's `images` (colour for points and fusion).
fn job_outputs(
    job: &Job,
    results: Vec<Result<ReferenceDepth, SweepError>>,
    images: Vec<Option<Rgba8Image>>,
    wanted: Wanted,
) -> SetOutputs {
    let baselines: Vec<f64> = results
        .iter()
        .map(|r| {
            r.as_ref().map_or(0.0, |depth| {
                rms_baseline_m(&job.cameras, depth.reference, &depth.cameras)
            })
        })
        .collect();
    let largest = baselines.iter().copied().fold(0.0, f64::max);
    let images: Vec<Option<Arc<Rgba8Image>>> =
        images.into_iter().map(|i| i.map(Arc::new)).collect();
    let mut set = SetOutputs::default();
    for ((reference, result), baseline) in job.references.iter().zip(results).zip(baselines) {
        let name = job
            .cameras
            .get(reference.index)
            .map_or("?", |c| c.name.as_str());
        let depth = match result {
            Ok(depth) => depth,
            Err(e) => {
                let kind = match e {
                    SweepError::NoNeighbours { .. } => SkipKind::Rig,
                    _ => SkipKind::Engine,
                };
                let hint = match e {
                    SweepError::NoNeighbours { .. } => shared_frame_hint(job, reference.index),
                    _ => String::new(),
                };
                set.skipped.push(Skip::new(
                    kind,
                    Some(reference.index),
                    format!("reference '{name}': sweep failed: {e}{hint}"),
                ));
                continue;
            }
        };
        let header: Header = job
            .images
            .get(reference.index)
            .map(|m| m.header.clone())
            .unwrap_or_default();
        let camera = &job.cameras[reference.index];
        let rig_from_frame = camera
            .cam_from_rig
            .inverse()
            .compose(&reference.cam_from_frame);
        let mut outputs = reference_outputs(
            reference.output,
            header,
            &reference.info,
            depth.maps,
            images.get(reference.index).and_then(Option::as_ref),
            &camera.model,
            &reference.cam_from_frame.inverse(),
            wanted,
            Placement {
                rig_from_frame,
                world_from_rig: job.world_from_rig,
                anchor: (&job.ref_frame, job.ref_frame_from_rig),
            },
        );
        outputs.maps.baseline_ratio = (largest > 0.0).then_some((baseline / largest) as f32);
        set.outputs.push(outputs);
    }
    set
}

/// [`process_job`] of a virtual camera (the job's first reference's): one sweep of every
/// camera, its outputs without colour.
fn virtual_outputs(
    engine: &mut impl Sweeper,
    job: &Job,
    (first, virtual_camera): (&JobReference, &VirtualCamera),
    sweep: &SweepParams,
    wanted: Wanted,
) -> Result<SetOutputs, Skip> {
    let name = |i| camera_name(job, i);
    let packed = |i| packed_image(job, i);
    let mut header: Header = job
        .images
        .get(first.index)
        .map(|m| m.header.clone())
        .unwrap_or_default();
    header.frame_id = virtual_camera.frame_id.clone();
    let reference = Reference::Virtual {
        model: virtual_camera.model,
        cam_from_rig: virtual_camera.cam_from_rig,
    };
    let rig = Rig::new(job.cameras.clone(), reference)
        .map_err(|e| Skip::new(SkipKind::Rig, None, format!("cannot build the rig: {e}")))?;
    // No colour for a virtual camera: an engine that unpacks on the device takes the
    // messages' bytes as they came.
    let maps = if engine.unpacks_on_device() {
        let converted = some_to_rgba8(&job.images, name, |i| packed(i).is_none());
        let converted = converted.map_err(image_skip)?;
        let cameras = engine_images(&converted, packed);
        let set = SetImages::Cameras {
            set: &cameras,
            picked: None,
        };
        engine.run_set(&rig, set, sweep)
    } else {
        let images = set_to_rgba8(&job.images, name).map_err(image_skip)?;
        engine.run(&rig, &images, sweep)
    };
    let maps = maps.map_err(|e| Skip::new(SkipKind::Engine, None, format!("sweep failed: {e}")))?;
    let outputs = reference_outputs(
        first.output,
        header,
        &first.info,
        maps.into(),
        None,
        &rig.reference_model(),
        // A virtual camera's points are in its own frame.
        &RigidTransform::IDENTITY,
        wanted,
        Placement {
            rig_from_frame: virtual_camera.cam_from_rig.inverse(),
            world_from_rig: job.world_from_rig,
            anchor: (&job.ref_frame, job.ref_frame_from_rig),
        },
    );
    Ok(SetOutputs {
        outputs: vec![outputs],
        skipped: Vec::new(),
    })
}

/// Camera `i`'s name in `job` ("?" outside it).
fn camera_name(job: &Job, i: usize) -> &str {
    job.cameras.get(i).map_or("?", |c| c.name.as_str())
}

/// Camera `i`'s message bytes as they came, where the engine may unpack them on the device.
fn packed_image(job: &Job, i: usize) -> Option<crate::image::PackedImage<'_>> {
    job.images.get(i).and_then(packed_view)
}

/// A set whose images cannot be read.
fn image_skip(e: ConvertError) -> Skip {
    Skip::new(SkipKind::Image, None, e.to_string())
}

/// The set's images as the engine takes them: each converted one, else its message's bytes
/// (`packed`, for an engine that unpacks on the device).
fn engine_images<'a>(
    converted: &'a [Option<Rgba8Image>],
    packed: impl Fn(usize) -> Option<crate::image::PackedImage<'a>>,
) -> Vec<CameraImage<'a>> {
    (0..converted.len())
        .filter_map(|i| match &converted[i] {
            Some(image) => Some(CameraImage::Rgba(image)),
            None => packed(i).map(CameraImage::Packed),
        })
        .collect()
}

/// Where a reference's header frame is: in the rig, and in the world on a moving rig; the
/// anchor frame (the set's first reference image's) and its pose from the rig.
struct Placement<'a> {
    rig_from_frame: RigidTransform,
    world_from_rig: Option<RigidTransform>,
    anchor: (&'a str, RigidTransform),
}

/// One reference's outputs from its depth maps (kept as floats, and made into messages).
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn reference_outputs(
    output: usize,
    header: Header,
    info: &CameraInfo,
    maps: ReferenceMaps,
    colour: Option<&Arc<Rgba8Image>>,
    model: &CameraModel,
    frame_from_cam: &RigidTransform,
    wanted: Wanted,
    placement: Placement<'_>,
) -> FrameOutputs {
    let (anchor_frame, anchor_from_rig) = placement.anchor;
    let world_from_frame = placement
        .world_from_rig
        .map(|w| w.compose(&placement.rig_from_frame));
    let mut depth_info = info.clone();
    depth_info.header = header.clone();
    // Maps lent out of the WGSL engine's readback (a caller that keeps no floats): the
    // messages copied from where the GPU put them, no maps kept. Points are made from owned
    // maps (the engine lends none where they are wanted).
    let (maps, lent) = match maps {
        ReferenceMaps::Lent(lent) if !wanted.points => (DepthMaps::empty(), Some(lent)),
        other => (other.into_owned(), None),
    };
    let points = wanted.points.then(|| {
        point_cloud_msg(
            &header,
            &maps.depth_m,
            colour.map(|c| c.as_ref()),
            model,
            frame_from_cam,
        )
    });
    let (depth, confidence) = match &lent {
        Some(lent) => lent_depth_and_confidence_msgs(&header, lent, HostCopies::Auto),
        None => depth_and_confidence_msgs(&header, &maps.depth_m, &maps.confidence),
    };
    drop(lent);
    let messages = FrameMessages {
        depth,
        depth_info,
        confidence,
        // An engine that made a map not wanted (the CPU engine makes them all) has it dropped.
        cost: (wanted.cost && !maps.cost.data.is_empty())
            .then(|| f32_image_msg(&header, &maps.cost)),
        selection: (wanted.selection && !maps.selection.is_empty())
            .then(|| selection_msg(&header, maps.width(), maps.height(), &maps.selection)),
        points,
    };
    FrameOutputs {
        output,
        maps: FrameMaps {
            header,
            depth_m: maps.depth_m,
            confidence: maps.confidence,
            world_from_frame,
            rig_from_frame: placement.rig_from_frame,
            anchor_frame: anchor_frame.to_string(),
            anchor_from_frame: anchor_from_rig.compose(&placement.rig_from_frame),
            model: *model,
            frame_from_cam: *frame_from_cam,
            colour: colour.cloned(),
            baseline_ratio: None,
        },
        messages,
    }
}

/// Why a reference may have no neighbour though cameras look where it looks: other cameras
/// whose images carry its `frame_id` and sit at its centre (two drivers left at their default
/// frame, no `Tx` in P). Empty when there are none.
fn shared_frame_hint(job: &Job, reference: usize) -> String {
    let frame = |i: usize| job.images.get(i).map(|m| m.header.frame_id.as_str());
    let centre = |c: &crate::geometry::RigCamera| c.cam_from_rig.inverse().translation;
    let Some(ours) = job.cameras.get(reference) else {
        return String::new();
    };
    let together: Vec<&str> = (job.cameras.iter().enumerate())
        .filter(|&(i, c)| {
            i != reference
                && frame(i).is_some()
                && frame(i) == frame(reference)
                && (centre(c) - centre(ours)).length() < 1e-3
        })
        .map(|(_, c)| c.name.as_str())
        .collect();
    if together.is_empty() {
        return String::new();
    }
    format!(
        " (cameras '{}' and '{}' carry one frame_id, '{}', at one place: give each camera its \
         own frame on /tf_static, or the second camera's CameraInfo P its baseline, Tx = -fx * \
         baseline in metres)",
        ours.name,
        together.join("', '"),
        frame(reference).unwrap_or_default()
    )
}
