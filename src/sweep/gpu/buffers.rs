//! The device buffers of one shape of work, their bind groups (made by binding name from the
//! stage registry), and the upload of a plan's arrays into them.

use super::super::gpu_types::*;
use super::super::plan::SweepPlan;
use super::super::schedule::{
    sgm_lines, sgm_together_lines, SGM_ALL_PASS, SGM_DIRECTIONS, SGM_REST_PASS,
};
use super::super::stages::{Stage, STAGES};
use super::super::SweepError;
use super::shape::ShapeKey;

/// Strides of the uniform arrays bound at offsets (the adapter's offset alignment).
#[derive(Debug, Clone, Copy)]
pub(super) struct Alignments {
    /// Of the `batches` array.
    pub batch: u64,
    /// Of the `sgm_passes` and `bands` arrays.
    pub pass: u64,
}

impl Alignments {
    pub fn of(device: &wgpu::Device) -> Self {
        let align = u64::from(device.limits().min_uniform_buffer_offset_alignment).max(16);
        Self {
            batch: (std::mem::size_of::<GpuBatch>() as u64).next_multiple_of(align),
            pass: (std::mem::size_of::<GpuSgmPass>() as u64)
                .max(std::mem::size_of::<GpuBand>() as u64)
                .next_multiple_of(align),
        }
    }
}

/// Buffers for one shape of work.
pub(super) struct Buffers {
    pub key: ShapeKey,
    params: wgpu::Buffer,
    batches: wgpu::Buffer,
    cameras: wgpu::Buffer,
    pub images: wgpu::Buffer,
    rays: wgpu::Buffer,
    planes: wgpu::Buffer,
    pub plane_ranges: wgpu::Buffer,
    /// The raw depth of the level below (coarse to fine on the device: `plane_spans.wgsl`),
    /// half the width and height.
    pub coarse_depth: wgpu::Buffer,
    pairs: wgpu::Buffer,
    sgm_passes: wgpu::Buffer,
    bands: wgpu::Buffer,
    pub maps: wgpu::Buffer,
    pub zbuffer: wgpu::Buffer,
    /// SGM's path sums, one buffer per row band (cleared before the directions walk side by
    /// side: `SgmWalks::Together`).
    pub sgm_sums: Vec<wgpu::Buffer>,
    pub readback: wgpu::Buffer,
    /// The reference model whose rays are in `rays` (`SweepPlan::ray_model`).
    rays_of: std::cell::Cell<Option<crate::geometry::CameraModel>>,
    /// Per stage (registry order), one bind group per row band of the SGM volume for the
    /// stages that bind it, else one.
    bind_groups: Vec<Vec<wgpu::BindGroup>>,
    pub timestamps: Option<Timestamps>,
}

pub(super) struct Timestamps {
    pub query_set: wgpu::QuerySet,
    pub resolve: wgpu::Buffer,
    pub count: u32,
}

/// Where a frame set's timestamps go in the `readback` buffer of its last level: right after
/// the `maps_bytes` of maps read back, at the next multiple of 8 (one readback, one mapping
/// per frame set).
pub(super) fn timestamps_offset(maps_bytes: u64) -> u64 {
    maps_bytes.div_ceil(8) * 8
}

/// Room in a `readback` buffer for the timestamps of the levels below it in a coarse-to-fine
/// frame set (read back with the last level's): 8 levels of 8 phases, 2 timestamps each (the
/// deepest sweep has 7 levels below its last: `coarse::levels` is at most 8).
const LOWER_LEVEL_TIMESTAMP_BYTES: u64 = 8 * 8 * 2 * 8;

/// A binding that depends on the row band.
fn per_band(name: &str) -> bool {
    matches!(name, "volume" | "sums" | "band")
}

/// The maps a frame set reads back, then its levels' timestamps: one buffer, mapped once.
fn make_readback(
    device: &wgpu::Device,
    maps_size: u64,
    timestamps: Option<&Timestamps>,
) -> wgpu::Buffer {
    let timestamp_bytes =
        timestamps.map_or(0, |t| u64::from(t.count) * 8 + LOWER_LEVEL_TIMESTAMP_BYTES);
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: timestamps_offset(maps_size) + timestamp_bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Each stage's bind groups (one per row band where it binds a band's buffers), its bindings
/// found by name through `resource`.
fn make_bind_groups<'a>(
    device: &wgpu::Device,
    layouts: &[wgpu::BindGroupLayout],
    key: ShapeKey,
    resource: &dyn Fn(&str, u32) -> Option<wgpu::BindingResource<'a>>,
) -> Result<Vec<Vec<wgpu::BindGroup>>, SweepError> {
    let mut bind_groups = Vec::with_capacity(STAGES.len());
    for (stage, layout) in STAGES.iter().zip(layouts) {
        if [Stage::Half, Stage::Prefilter, Stage::Unpack]
            .iter()
            .any(|s| s.name() == stage.name)
        {
            // Binds the image pyramid's levels (`pyramid.rs`), not this shape's buffers.
            bind_groups.push(Vec::new());
            continue;
        }
        let banded = stage.bindings.iter().any(|b| per_band(b.name));
        let groups = if banded { key.bands() } else { 1 };
        let mut per_stage = Vec::with_capacity(groups as usize);
        for band in 0..groups {
            let entries = stage
                .bindings
                .iter()
                .enumerate()
                .map(|(number, binding)| {
                    resource(binding.name, band)
                        .map(|resource| wgpu::BindGroupEntry {
                            binding: number as u32,
                            resource,
                        })
                        .ok_or_else(|| {
                            SweepError::Gpu(format!(
                                "internal: no buffer for binding `{}` of stage {}",
                                binding.name, stage.name
                            ))
                        })
                })
                .collect::<Result<Vec<_>, SweepError>>()?;
            per_stage.push(device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(stage.name),
                layout,
                entries: &entries,
            }));
        }
        bind_groups.push(per_stage);
    }
    Ok(bind_groups)
}

/// Two timestamps per phase of the schedule (one compute pass each), when the adapter has
/// them.
fn make_timestamps(device: &wgpu::Device, key: ShapeKey) -> Option<Timestamps> {
    let count = 2 * key.schedule().phases().len() as u32;
    device
        .features()
        .contains(wgpu::Features::TIMESTAMP_QUERY)
        .then(|| {
            let bytes = u64::from(count) * 8;
            Timestamps {
                query_set: device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("stage timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count,
                }),
                resolve: device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamp resolve"),
                    size: bytes,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                count,
            }
        })
}

/// SGM's buffers: the cost volume and the path sums, one buffer each per row band, and per
/// direction and line two rows of path costs and the minimum of the previous one (one
/// invocation per line on CPU adapters and in bands).
fn sgm_buffers(
    storage: &dyn Fn(&str, u64, wgpu::BufferUsages) -> wgpu::Buffer,
    key: ShapeKey,
) -> (Vec<wgpu::Buffer>, Vec<wgpu::Buffer>, wgpu::Buffer) {
    let none = wgpu::BufferUsages::empty();
    // The cost volume and the path sums, one buffer per row band.
    let band_bytes = |b: u32| {
        u64::from(key.band(b).rows) * u64::from(key.width) * u64::from(key.volume_words) * 4
    };
    let volumes: Vec<wgpu::Buffer> = (0..key.bands())
        .map(|b| storage("sgm volume", band_bytes(b), none))
        .collect();
    let sums: Vec<wgpu::Buffer> = (0..key.bands())
        .map(|b| storage("sgm sums", band_bytes(b), none))
        .collect();
    // Per direction and line: two rows of path costs and the minimum of the previous one
    // (one invocation per line on CPU adapters and in bands).
    let line_costs = storage(
        "sgm line costs",
        if key.sgm_paths > 0 {
            u64::from(key.sgm_paths)
                * u64::from(key.width + key.height)
                * (u64::from(key.volume_words) * 4 + 1)
                * 4
        } else {
            0
        },
        none,
    );
    (volumes, sums, line_costs)
}

impl Buffers {
    pub fn new(
        device: &wgpu::Device,
        layouts: &[wgpu::BindGroupLayout],
        align: Alignments,
        key: ShapeKey,
    ) -> Result<Self, SweepError> {
        let npix = u64::from(key.width) * u64::from(key.height);
        let storage = |label: &str, size: u64, extra: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16).next_multiple_of(4),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
                mapped_at_creation: false,
            })
        };
        let uniform = |label: &str, size: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let none = wgpu::BufferUsages::empty();
        let params = uniform("params", std::mem::size_of::<GpuParams>() as u64);
        let batches = uniform(
            "batches",
            u64::from(key.batches() + key.refine_batches) * align.batch,
        );
        let cameras = uniform(
            "cameras",
            u64::from(MAX_RIG_CAMERAS) * std::mem::size_of::<GpuCamera>() as u64,
        );
        // COPY_SRC: tests read the census words back (`GpuEngine::device_images`).
        let images = storage(
            "images",
            key.image_words as u64 * 4,
            wgpu::BufferUsages::COPY_SRC,
        );
        let rays = storage("rays", npix * 16, none);
        let planes = storage("planes", u64::from(key.planes) * 16, none);
        // COPY_SRC: tests read the device's ranges back (`GpuEngine::device_plane_ranges`).
        let tiles = u64::from(crate::sweep::plan::range_tiles(key.width));
        let plane_ranges = storage(
            "plane_ranges",
            u64::from(key.height) * tiles * 16,
            wgpu::BufferUsages::COPY_SRC,
        );
        let coarse_depth = storage(
            "coarse depth",
            u64::from(key.width / 2) * u64::from(key.height / 2) * 4,
            none,
        );
        // Per half-resolution row: its tiles' spans, then (after all of them) its own.
        let spans = storage(
            "plane spans",
            u64::from(key.height / 2) * (tiles + 1) * 8,
            none,
        );
        let pairs = uniform("pairs", u64::from(MAX_PAIRS) * 16);
        // Without box passes (2x2 shiftable windows) the sums are never used: 16 bytes each.
        let [cost_bytes, row_bytes] = key.batch_bytes();
        let cost_slab = storage("cost_slab", cost_bytes, none);
        let row_sums = storage("row_sums", row_bytes, none);
        let state = storage("state", npix * 48, none);
        // The fine sweep's base surface (`refine_base.wgsl`), only where it runs.
        let hypotheses = storage(
            "refine hypotheses",
            if key.refine_batches > 0 { npix * 8 } else { 0 },
            none,
        );
        let (volumes, sums, line_costs) = sgm_buffers(&storage, key);
        // Each direction's pass, then the pass of directions 1 .. paths - 1 together.
        let sgm_passes = uniform("sgm passes", (SGM_REST_PASS as u64 + 1) * align.pass);
        let bands = uniform("sgm bands", u64::from(key.bands()) * align.pass);
        let maps = storage(
            "maps",
            npix * 4 * MAP_COUNT as u64,
            wgpu::BufferUsages::COPY_SRC,
        );
        let zbuffer = storage("zbuffer", key.camera_pixels as u64 * 4, none);
        // One element of an array bound at a (dynamic or fixed) offset.
        fn element(buffer: &wgpu::Buffer, offset: u64, size: usize) -> wgpu::BindingResource<'_> {
            wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer,
                offset,
                size: wgpu::BufferSize::new(size as u64),
            })
        }
        fn whole(buffer: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
            buffer.as_entire_binding()
        }
        // The resources by the names the shaders (and the registry) give them.
        let resource = |name: &str, band: u32| -> Option<wgpu::BindingResource<'_>> {
            Some(match name {
                "params" => whole(&params),
                "batch" => element(&batches, 0, std::mem::size_of::<GpuBatch>()),
                "sgm_pass" => element(&sgm_passes, 0, std::mem::size_of::<GpuSgmPass>()),
                "band" => element(
                    &bands,
                    u64::from(band) * align.pass,
                    std::mem::size_of::<GpuBand>(),
                ),
                "cameras" => whole(&cameras),
                "images" => whole(&images),
                "rays" => whole(&rays),
                "planes" => whole(&planes),
                "plane_ranges" => whole(&plane_ranges),
                "coarse_depth" => whole(&coarse_depth),
                "spans" => whole(&spans),
                "pairs" => whole(&pairs),
                "cost_slab" => whole(&cost_slab),
                "row_sums" => whole(&row_sums),
                "state" => whole(&state),
                "hypotheses" => whole(&hypotheses),
                "volume" => whole(volumes.get(band as usize)?),
                "sums" => whole(sums.get(band as usize)?),
                "line_costs" => whole(&line_costs),
                "maps" => whole(&maps),
                "zbuffer" => whole(&zbuffer),
                _ => return None,
            })
        };
        let bind_groups = make_bind_groups(device, layouts, key, &resource)?;
        let timestamps = make_timestamps(device, key);
        let readback = make_readback(device, maps.size(), timestamps.as_ref());
        Ok(Self {
            key,
            params,
            batches,
            cameras,
            images,
            rays,
            planes,
            plane_ranges,
            coarse_depth,
            pairs,
            sgm_passes,
            bands,
            maps,
            zbuffer,
            sgm_sums: sums,
            readback,
            rays_of: std::cell::Cell::new(None),
            bind_groups,
            timestamps,
        })
    }

    /// The bind group of `stage` for row band `band` (band 0 for the stages not banded).
    pub fn bind_group(&self, stage: Stage, band: u32) -> &wgpu::BindGroup {
        let groups = &self.bind_groups[stage as usize];
        &groups[(band as usize).min(groups.len() - 1)]
    }

    /// Writes the plan's arrays: parameters, cameras, planes, rays, pairs, batches of planes,
    /// SGM directions and row bands.
    pub fn upload_plan(&self, queue: &wgpu::Queue, align: Alignments, plan: &SweepPlan) {
        let key = self.key;
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&plan.params));
        queue.write_buffer(&self.cameras, 0, bytemuck::cast_slice(&plan.cameras));
        queue.write_buffer(&self.planes, 0, bytemuck::cast_slice(&plan.planes));
        // The rays depend on the reference model alone: several references of one rig with
        // equal intrinsics share them (2.7 MB at 450x375, per reference and set before).
        if self.rays_of.get() != Some(plan.ray_model) {
            queue.write_buffer(&self.rays, 0, bytemuck::cast_slice(&plan.rays));
            self.rays_of.set(Some(plan.ray_model));
        }
        // Only per-pair aggregation reads the pair table, and it has at most MAX_PAIRS pairs.
        let pairs = &plan.pairs[..plan.pairs.len().min(MAX_PAIRS as usize)];
        queue.write_buffer(&self.pairs, 0, bytemuck::cast_slice(pairs));
        let mut batches = vec![0u8; self.batches.size() as usize];
        // The sweep's batches of planes, then the fine sweep's batches of its hypotheses 0 ..
        // 2 REACH (numbered after the sweep's; their planes unused: each pixel's own
        // hypotheses are in `hypotheses`).
        let sweep = (0..key.batches()).map(|b| (b, key.planes, 0));
        let fine = (0..key.refine_batches).map(|b| (b, super::shape::REFINE_HYPOTHESES, 1));
        for (slot, (b, total, refine)) in sweep.chain(fine).enumerate() {
            let first = b * key.batch;
            let count = key.batch.min(total - first);
            let mut batch = GpuBatch {
                first_plane: first,
                plane_count: count,
                is_first: u32::from(b == 0),
                refine,
                planes: [[0.0; 4]; MAX_BATCH_PLANES as usize],
            };
            if refine == 0 {
                batch.planes[..count as usize]
                    .copy_from_slice(&plan.planes[first as usize..(first + count) as usize]);
            }
            let at = slot * align.batch as usize;
            batches[at..at + std::mem::size_of::<GpuBatch>()]
                .copy_from_slice(bytemuck::bytes_of(&batch));
        }
        queue.write_buffer(&self.batches, 0, &batches);
        let mut passes = vec![0u8; self.sgm_passes.size() as usize];
        for (r, &(dx, dy)) in SGM_DIRECTIONS
            .iter()
            .enumerate()
            .take(key.sgm_paths as usize)
        {
            let pass = GpuSgmPass {
                direction: [
                    dx,
                    dy,
                    sgm_lines(dx, dy, key.width, key.height) as i32,
                    r as i32,
                ],
            };
            let at = (r as u64 * align.pass) as usize;
            passes[at..at + std::mem::size_of::<GpuSgmPass>()]
                .copy_from_slice(bytemuck::bytes_of(&pass));
        }
        if key.sgm_paths > 1 {
            for (first, slot) in [(0, SGM_ALL_PASS), (1, SGM_REST_PASS)] {
                let together = GpuSgmPass {
                    direction: [
                        key.sgm_paths as i32,
                        first as i32,
                        sgm_together_lines(first, key.sgm_paths, key.width, key.height) as i32,
                        SGM_TOGETHER,
                    ],
                };
                let at = (slot as u64 * align.pass) as usize;
                passes[at..at + std::mem::size_of::<GpuSgmPass>()]
                    .copy_from_slice(bytemuck::bytes_of(&together));
            }
        }
        queue.write_buffer(&self.sgm_passes, 0, &passes);
        let mut bands = vec![0u8; self.bands.size() as usize];
        for b in 0..key.bands() {
            let at = (u64::from(b) * align.pass) as usize;
            bands[at..at + std::mem::size_of::<GpuBand>()]
                .copy_from_slice(bytemuck::bytes_of(&key.band(b)));
        }
        queue.write_buffer(&self.bands, 0, &bands);
    }
}
