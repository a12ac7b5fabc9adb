//! Every reference's depth of every set into one mesh (issue 28): the node's live fusion
//! (`fusion`, run beside the engine by [`super::fuser_thread`]), `bag --mesh` and the `fuse`
//! node. Each depth map comes as a [`FusionInput`]: its depth, colour and camera placed in the
//! map's frame (`world_frame` on a moving rig, else the frame of the set's first reference
//! image); the [`Fuser`] integrates it into `src/fusion`'s [`Mapper`] and hands the mesh out per
//! block as `visualization_msgs/MarkerArray` (one `TRIANGLE_LIST` marker per block, stable ids,
//! only the blocks that changed) or as a PLY file.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;

use super::counts::SkipCounts;
use super::outputs::FrameMaps;
use crate::fusion::{
    BlockIndex, BlockMesh, DepthView, FusionError, FusionParams, IntegrationStats, Mapper,
    MeshStats, Weighting,
};
use crate::geometry::{CameraModel, RigidTransform};
use crate::gpu_context::GpuContext;
use crate::image::{ImageF32, Rgba8Image};
use crate::msgs::{ColorRGBA, Header, Marker, MarkerArray, Point, Pose, Time, Vector3};

/// The marker namespace of the mesh's blocks.
pub const MESH_NAMESPACE: &str = "sweepdepth_mesh";

/// One depth map to fuse, placed in the map's frame.
#[derive(Debug, Clone)]
pub struct FusionInput {
    pub stamp: Time,
    /// The frame the camera is placed in: the map's frame.
    pub frame: String,
    /// z along the optical axis in metres, NaN (or non-finite, or not positive) invalid.
    pub depth: ImageF32,
    /// The colour of the depth's pixels (same size), if any.
    pub colour: Option<Arc<Rgba8Image>>,
    pub model: CameraModel,
    /// The camera (ROS optical frame) in `frame`.
    pub map_from_cam: RigidTransform,
    /// The depth's confidence (0 .. 1, same size), where the source has one (our engine).
    pub confidence: Option<ImageF32>,
    /// The depth's baseline over the largest of its set's references, where known.
    pub baseline_ratio: Option<f32>,
    /// Where the depth map came from (the reference camera's frame, or the `fuse` node's
    /// depth topic), for the per-source counts in `/diagnostics`.
    pub source: String,
}

impl FusionInput {
    /// One reference's maps (moved, not copied): in `world_frame` on a moving rig (its world
    /// pose), else in the frame of the set's first reference image.
    pub fn from_maps(maps: FrameMaps, world_frame: Option<&str>) -> Self {
        let (frame, map_from_frame) = match (world_frame, maps.world_from_frame) {
            (Some(world), Some(pose)) => (world.to_string(), pose),
            _ => (maps.anchor_frame.clone(), maps.anchor_from_frame),
        };
        let with_confidence = maps.confidence_map().is_some();
        Self {
            stamp: maps.header.stamp,
            frame,
            depth: maps.depth_m,
            colour: maps.colour,
            model: maps.model,
            map_from_cam: map_from_frame.compose(&maps.frame_from_cam),
            confidence: with_confidence.then_some(maps.confidence),
            baseline_ratio: maps.baseline_ratio,
            source: maps.header.frame_id,
        }
    }
}

/// Why a depth map was not fused (counted by reason: `/diagnostics`, the bag summary).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FuseSkip {
    #[error(
        "depth in frame '{got}' but the map is in '{map}' (the rig's first reference changed \
         frame, or a source publishes in another world frame; clear the map to start again)"
    )]
    Frame { got: String, map: String },
    #[error(transparent)]
    Fusion(#[from] FusionError),
}

impl FuseSkip {
    /// A short label for counters.
    pub fn label(&self) -> &'static str {
        match self {
            FuseSkip::Frame { .. } => "fusion: other frame",
            FuseSkip::Fusion(FusionError::ImageSize { .. }) => "fusion: image size",
            FuseSkip::Fusion(FusionError::Camera(_)) => "fusion: camera",
            FuseSkip::Fusion(FusionError::Pose(_)) => "fusion: pose",
            FuseSkip::Fusion(FusionError::Gpu(_)) => "fusion: GPU",
            FuseSkip::Fusion(_) => "fusion: parameters",
        }
    }
}

/// What a saved mesh holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SavedMesh {
    pub triangles: usize,
    pub vertices: usize,
}

/// The map (its depth maps' pixels weighed by [`Weighting::DEPTH_MAPS`]), the markers' ids
/// and what went in.
#[derive(Debug)]
pub struct Fuser {
    mapper: Mapper,
    /// The map's frame: that of the first input since the last clear.
    frame: Option<String>,
    /// The newest stamp integrated.
    stamp: Time,
    /// Each block's marker id, for as long as its marker is out.
    ids: HashMap<BlockIndex, i32>,
    next_id: i32,
    /// Depth maps integrated.
    pub integrated: u64,
    /// Depth maps integrated, by [`FusionInput::source`].
    pub integrated_by_source: BTreeMap<String, u64>,
    /// Depth maps refused, by reason.
    pub skipped: SkipCounts,
    /// Blocks dropped to stay within `max_blocks` (the farthest from the newest camera).
    pub blocks_dropped: u64,
    /// Why the map left its GPU for the CPU ([`Fuser::left_gpu`]).
    left_gpu: Option<String>,
}

impl Fuser {
    pub fn new(params: FusionParams) -> Result<Self, FusionError> {
        Self::with_mapper(Mapper::new(params, Weighting::DEPTH_MAPS)?)
    }

    /// A fuser that integrates on `gpu`'s device ([`Mapper::on_gpu`]). When the device fails
    /// later ([`FusionError::Gpu`]: lost, reset, out of room), the map goes on on the CPU from
    /// its host copy (at most [`crate::fusion::mapper::MIRROR_PERIOD`] old; its mesh made again
    /// from it), the failed depth map integrated there ([`Fuser::left_gpu`] says why).
    pub fn on_gpu(params: FusionParams, gpu: &GpuContext) -> Result<Self, FusionError> {
        let mapper = Mapper::on_gpu(params, Weighting::DEPTH_MAPS, &gpu.device, &gpu.queue)?;
        Self::with_mapper(mapper)
    }

    /// On `gpu`'s device when given ([`Fuser::on_gpu`]), else on the CPU; a device that
    /// refuses the fusion ([`FusionError::Gpu`]) leaves it on the CPU, with the reason in
    /// [`Fuser::left_gpu`]. Refuses only bad parameters.
    pub fn on(params: FusionParams, gpu: Option<&GpuContext>) -> Result<Self, FusionError> {
        match gpu.map(|gpu| Self::on_gpu(params, gpu)) {
            None => Self::new(params),
            Some(Err(FusionError::Gpu(reason))) => {
                let mut fuser = Self::new(params)?;
                fuser.left_gpu = Some(format!("the GPU refused the fusion: {reason}"));
                Ok(fuser)
            }
            Some(other) => other,
        }
    }

    fn with_mapper(mapper: Mapper) -> Result<Self, FusionError> {
        Ok(Self {
            mapper,
            frame: None,
            stamp: Time::default(),
            ids: HashMap::new(),
            next_id: 0,
            integrated: 0,
            integrated_by_source: BTreeMap::new(),
            skipped: SkipCounts::default(),
            blocks_dropped: 0,
            left_gpu: None,
        })
    }

    pub fn params(&self) -> &FusionParams {
        self.mapper.params()
    }

    /// Whether it integrates on a GPU ([`Fuser::on_gpu`]).
    pub fn is_on_gpu(&self) -> bool {
        self.mapper.is_on_gpu()
    }

    /// Why the map left the GPU it was made on for the CPU (None: it never did; it stays
    /// said after [`Fuser::move_to_gpu`]).
    pub fn left_gpu(&self) -> Option<&str> {
        self.left_gpu.as_deref()
    }

    /// Goes on on `gpu`'s device, the map's blocks uploaded from its host copy: the engine's
    /// device was lost and made anew, and the map, which left the old one for the CPU (or is
    /// still on it: it leaves it now with what it still gives back), follows
    /// ([`Mapper::move_to_gpu`]). The device refusing the map leaves it on the CPU, and says
    /// why.
    /// Follows `host`'s engine onto the device it made anew since it had made `seen` (its
    /// [`super::EngineHost::recreated`] when this fuser last looked, brought up to date):
    /// [`Self::move_to_gpu`] when there is a new device, true once moved. `bag` calls it after
    /// each set; the node's GPU thread hands its fuser thread the device instead
    /// ([`super::EngineHost::on_new_device`]).
    pub fn follow_engine(
        &mut self,
        host: &super::EngineHost,
        seen: &mut u64,
    ) -> Result<bool, String> {
        if host.recreated == *seen {
            return Ok(false);
        }
        *seen = host.recreated;
        match host.gpu() {
            Some(gpu) => self.move_to_gpu(gpu).map(|()| true),
            None => Ok(false),
        }
    }

    pub fn move_to_gpu(&mut self, gpu: &GpuContext) -> Result<(), String> {
        if self.mapper.is_on_gpu() {
            self.left_gpu
                .get_or_insert_with(|| "its device was replaced".into());
        }
        self.mapper
            .move_to_gpu(&gpu.device, &gpu.queue)
            .map(|_| ())
            .map_err(|e| format!("the new GPU refused the map: {e}"))
    }

    /// The map's frame (None before the first depth map).
    pub fn frame(&self) -> Option<&str> {
        self.frame.as_deref()
    }

    /// Integrates one depth map; a refused one is counted under its reason and changes nothing.
    pub fn add(&mut self, input: &FusionInput) -> Result<IntegrationStats, FuseSkip> {
        let result = self.try_add(input);
        if let Err(skip) = &result {
            self.skipped.add(skip.label());
        }
        result
    }

    fn try_add(&mut self, input: &FusionInput) -> Result<IntegrationStats, FuseSkip> {
        if let Some(map) = &self.frame {
            if *map != input.frame {
                return Err(FuseSkip::Frame {
                    got: input.frame.clone(),
                    map: map.clone(),
                });
            }
        }
        let view = DepthView {
            depth: &input.depth,
            confidence: input.confidence.as_ref(),
            baseline_ratio: input.baseline_ratio,
            colour: input.colour.as_deref(),
            model: &input.model,
            map_from_cam: &input.map_from_cam,
        };
        let stats = match self.mapper.integrate(&view) {
            // The device failed: the map goes on on the CPU, this depth map first (the
            // failed integration changed nothing of the map's grid).
            Err(FusionError::Gpu(reason)) if self.mapper.leave_gpu() => {
                self.left_gpu = Some(reason);
                self.mapper.integrate(&view)
            }
            other => other,
        }?;
        if self.frame.is_none() {
            self.frame = Some(input.frame.clone());
        }
        self.stamp = self.stamp.max(input.stamp);
        self.integrated += 1;
        self.blocks_dropped += stats.blocks_dropped as u64;
        match self.integrated_by_source.get_mut(&input.source) {
            Some(count) => *count += 1,
            None => {
                self.integrated_by_source.insert(input.source.clone(), 1);
            }
        }
        Ok(stats)
    }

    /// Meshes the blocks that changed since the last call (a map on a GPU whose device fails
    /// here goes on on the CPU, as after a failed integration).
    pub fn update_mesh(&mut self) -> MeshStats {
        let stats = self.mapper.update_mesh();
        if let Some(reason) = self.mapper.take_gpu_error() {
            if self.mapper.leave_gpu() {
                self.left_gpu = Some(reason);
            }
        }
        stats
    }

    /// The whole mesh, up to date.
    pub fn mesh(&mut self) -> BlockMesh {
        self.update_mesh();
        self.mapper.mesh().collect()
    }

    /// The mesh's changes since the last call as markers (after meshing the changed blocks):
    /// a `TRIANGLE_LIST` (`ADD`, which replaces) for each block whose surface was made again,
    /// a `DELETE` for each block whose surface went, under [`MESH_NAMESPACE`] with one id per
    /// block for as long as it has a surface, stamped with the newest depth's stamp, in the
    /// map's frame. Empty when nothing changed.
    pub fn markers(&mut self) -> MarkerArray {
        self.update_mesh();
        let header = Header {
            stamp: self.stamp,
            frame_id: self.frame.clone().unwrap_or_default(),
        };
        let mut markers = Vec::new();
        for index in self.mapper.mesh_mut().take_dirty() {
            match self.mapper.mesh().block(index) {
                Some(block) => {
                    let id = *self.ids.entry(index).or_insert_with(|| {
                        self.next_id = self.next_id.wrapping_add(1);
                        self.next_id
                    });
                    markers.push(block_marker(&header, id, block));
                }
                None => {
                    if let Some(id) = self.ids.remove(&index) {
                        markers.push(Marker {
                            header: header.clone(),
                            ns: MESH_NAMESPACE.into(),
                            id,
                            r#type: Marker::TRIANGLE_LIST,
                            action: Marker::DELETE,
                            ..Marker::default()
                        });
                    }
                }
            }
        }
        MarkerArray { markers }
    }

    /// Writes the whole mesh as a binary PLY file.
    pub fn save(&mut self, path: &Path) -> std::io::Result<SavedMesh> {
        let mesh = self.mesh();
        crate::fusion::write_ply_file(&mesh, path)?;
        Ok(SavedMesh {
            triangles: mesh.triangles.len(),
            vertices: mesh.vertices.len(),
        })
    }

    /// Empties the map (and forgets its frame); returns the blocks dropped and the marker that
    /// deletes every block's marker (`DELETEALL` in [`MESH_NAMESPACE`]).
    pub fn clear(&mut self) -> (usize, MarkerArray) {
        let blocks = self.mapper.clear();
        self.ids.clear();
        let marker = Marker {
            header: Header {
                stamp: self.stamp,
                frame_id: self.frame.take().unwrap_or_default(),
            },
            ns: MESH_NAMESPACE.into(),
            action: Marker::DELETEALL,
            ..Marker::default()
        };
        (
            blocks,
            MarkerArray {
                markers: vec![marker],
            },
        )
    }

    /// Blocks allocated and their memory, for reports.
    pub fn blocks(&self) -> (usize, usize) {
        (self.mapper.block_count(), self.mapper.grid().memory_bytes())
    }

    /// Triangles in the mesh as last meshed.
    pub fn triangles(&self) -> usize {
        self.mapper.mesh().triangle_count()
    }
}

/// One block's surface as a `TRIANGLE_LIST` marker: three points and three colours per
/// triangle, identity pose, unit scale (RViz multiplies the points by it), opaque.
fn block_marker(header: &Header, id: i32, block: &BlockMesh) -> Marker {
    let corners = block.triangles.iter().flatten().map(|&i| i as usize);
    let (points, colors): (Vec<Point>, Vec<ColorRGBA>) = corners
        .filter_map(|i| {
            let v = block.vertices.get(i)?;
            let c = block.colours.get(i)?;
            Some((
                Point {
                    x: f64::from(v[0]),
                    y: f64::from(v[1]),
                    z: f64::from(v[2]),
                },
                ColorRGBA {
                    r: f32::from(c[0]) / 255.0,
                    g: f32::from(c[1]) / 255.0,
                    b: f32::from(c[2]) / 255.0,
                    a: 1.0,
                },
            ))
        })
        .unzip();
    Marker {
        header: header.clone(),
        ns: MESH_NAMESPACE.into(),
        id,
        r#type: Marker::TRIANGLE_LIST,
        action: Marker::ADD,
        pose: Pose::default(),
        scale: Vector3 {
            x: 1.0,
            y: 1.0,
            z: 1.0,
        },
        color: ColorRGBA {
            r: 1.0,
            g: 1.0,
            b: 1.0,
            a: 1.0,
        },
        points,
        colors,
        ..Marker::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PinholeIntrinsics;

    /// A 64x48 camera looking down +z at a wall 2 m away, placed at `x` in `frame`.
    fn wall(frame: &str, x: f64, stamp: i32) -> FusionInput {
        let model = CameraModel::pinhole(PinholeIntrinsics {
            width_px: 64,
            height_px: 48,
            fx_px: 60.0,
            fy_px: 60.0,
            cx_px: 31.5,
            cy_px: 23.5,
        });
        FusionInput {
            stamp: Time {
                sec: stamp,
                nanosec: 0,
            },
            frame: frame.into(),
            depth: ImageF32 {
                width: 64,
                height: 48,
                data: vec![2.0; 64 * 48],
            },
            colour: None,
            model,
            map_from_cam: RigidTransform {
                translation: glam::DVec3::new(x, 0.0, 0.0),
                ..RigidTransform::IDENTITY
            },
            confidence: None,
            baseline_ratio: None,
            source: "cam0_optical".into(),
        }
    }

    fn fuser() -> Fuser {
        Fuser::new(FusionParams {
            voxel_size_m: 0.05,
            ..FusionParams::default()
        })
        .unwrap()
    }

    #[test]
    fn markers_carry_each_changed_block_once_with_a_stable_id() {
        let mut f = fuser();
        f.add(&wall("map", 0.0, 1)).unwrap();
        let first = f.markers();
        assert!(!first.markers.is_empty());
        assert!(first.markers.iter().all(|m| m.action == Marker::ADD
            && m.r#type == Marker::TRIANGLE_LIST
            && m.header.frame_id == "map"
            && m.header.stamp.sec == 1
            && !m.points.is_empty()
            && m.points.len() % 3 == 0
            && m.points.len() == m.colors.len()));
        let mut ids: Vec<i32> = first.markers.iter().map(|m| m.id).collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), first.markers.len(), "one id per block");
        // Nothing new: no markers.
        assert!(f.markers().markers.is_empty());
        // The same wall again: the blocks are re-meshed and keep their ids.
        f.add(&wall("map", 0.0, 2)).unwrap();
        let second = f.markers();
        assert!(!second.markers.is_empty());
        for m in &second.markers {
            assert!(ids.binary_search(&m.id).is_ok(), "id {} is new", m.id);
        }
        // The markers' triangles are the mesh's.
        let triangles: usize = first.markers.iter().map(|m| m.points.len() / 3).sum();
        assert_eq!(triangles, f.triangles());
    }

    #[test]
    fn another_frame_is_refused_and_counted_until_the_map_is_cleared() {
        let mut f = fuser();
        f.add(&wall("map", 0.0, 1)).unwrap();
        let (blocks_before, _) = f.blocks();
        let err = f.add(&wall("odom", 0.0, 2)).unwrap_err();
        assert!(matches!(err, FuseSkip::Frame { .. }), "{err}");
        assert_eq!(f.skipped.get("fusion: other frame"), 1);
        assert_eq!(f.blocks().0, blocks_before);
        let (dropped, clear) = f.clear();
        assert_eq!(dropped, blocks_before);
        assert_eq!(clear.markers.len(), 1);
        assert_eq!(clear.markers[0].action, Marker::DELETEALL);
        assert_eq!(f.blocks().0, 0);
        f.add(&wall("odom", 0.0, 3)).unwrap();
        assert_eq!(f.frame(), Some("odom"));
    }

    #[test]
    fn a_wrong_size_depth_is_refused_without_touching_the_map() {
        let mut f = fuser();
        let mut bad = wall("map", 0.0, 1);
        bad.depth.width = 32;
        bad.depth.data.truncate(32 * 48);
        let err = f.add(&bad).unwrap_err();
        assert_eq!(err.label(), "fusion: image size", "{err}");
        assert_eq!(f.blocks().0, 0);
        assert_eq!(f.frame(), None);
    }

    #[test]
    fn the_saved_mesh_is_the_whole_mesh() {
        let mut f = fuser();
        f.add(&wall("map", 0.0, 1)).unwrap();
        let dir = std::env::temp_dir().join(format!("sweepdepth-fuse-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("wall.ply");
        let saved = f.save(&path).unwrap();
        assert!(saved.triangles > 0);
        let bytes = std::fs::read(&path).unwrap();
        let text = String::from_utf8_lossy(&bytes[..300.min(bytes.len())]).to_string();
        assert!(
            text.contains(&format!("element face {}", saved.triangles)),
            "{text}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
