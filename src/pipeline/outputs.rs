//! One job through the engine ([`process_job`]) and the messages it gives ([`FrameOutputs`]),
//! all with the reference camera's header.

use super::convert::{f32_image_msg, image_to_rgba8, point_cloud_msg, selection_msg};
use super::outcome::{Job, Skip, SkipKind};
use crate::engine::Sweeper;
use crate::geometry::{Reference, Rig};
use crate::msgs::{CameraInfo, Header, Image, PointCloud2};
use crate::sweep::SweepParams;

/// The messages one frame set produces, all with the same header (the reference camera's
/// stamp; its frame_id, or the virtual camera's). Their topics: [`super::OutputTopics`].
#[derive(Debug, Clone)]
pub struct FrameOutputs {
    pub header: Header,
    pub depth: Image,
    pub depth_info: CameraInfo,
    pub confidence: Image,
    pub cost: Image,
    pub selection: Image,
    pub points: Option<PointCloud2>,
}

/// Runs one job through the engine with the given parameters and builds its output messages
/// (`with_points`: the point cloud too).
pub fn process_job(
    engine: &mut impl Sweeper,
    job: &Job,
    sweep: &SweepParams,
    with_points: bool,
) -> Result<FrameOutputs, Skip> {
    let mut images = Vec::with_capacity(job.images.len());
    for (i, msg) in job.images.iter().enumerate() {
        let name = job.cameras.get(i).map_or("?", |c| c.name.as_str());
        images.push(
            image_to_rgba8(name, msg)
                .map_err(|e| Skip::new(SkipKind::Image, None, e.to_string()))?,
        );
    }
    let mut header: Header = job
        .images
        .get(job.reference)
        .map(|m| m.header.clone())
        .unwrap_or_default();
    let reference = match &job.virtual_ref {
        Some((model, cam_from_rig, frame_id)) => {
            header.frame_id = frame_id.clone();
            Reference::Virtual {
                model: *model,
                cam_from_rig: *cam_from_rig,
            }
        }
        None => Reference::Camera(job.reference),
    };
    let colour = if job.virtual_ref.is_some() {
        None
    } else {
        images.get(job.reference)
    };
    let rig = Rig::new(job.cameras.clone(), reference)
        .map_err(|e| Skip::new(SkipKind::Rig, None, format!("cannot build the rig: {e}")))?;
    let maps = engine
        .run(&rig, &images, sweep)
        .map_err(|e| Skip::new(SkipKind::Engine, None, format!("sweep failed: {e}")))?;
    let mut depth_info = job.ref_info.clone();
    depth_info.header = header.clone();
    let points = with_points.then(|| {
        point_cloud_msg(
            &header,
            &maps.depth_m,
            colour,
            &rig.reference_model(),
            &job.ref_cam_from_frame.inverse(),
        )
    });
    Ok(FrameOutputs {
        depth: f32_image_msg(&header, &maps.depth_m),
        depth_info,
        confidence: f32_image_msg(&header, &maps.confidence),
        cost: f32_image_msg(&header, &maps.cost),
        selection: selection_msg(&header, maps.width(), maps.height(), &maps.selection),
        points,
        header,
    })
}
