//! "How to run it": the wgpu engine. It takes a device and queue from its caller, builds its
//! pipelines once, and keeps its buffers across frame sets of the same shape; a new rig or new
//! parameters re-plan, a new shape re-allocates.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::mpsc;
use std::time::Instant;

use super::gpu_types::*;
use super::plan::SweepPlan;
use super::{DepthMaps, StageTimings, SweepError, SweepParams};
use crate::geometry::Rig;
use crate::image::Rgba8Image;

/// Stage names in pipeline order (also the shader file names).
pub const STAGES: [&str; 8] = [
    "cost",
    "box_h",
    "box_v",
    "aggregate",
    "finalize",
    "median",
    "splat",
    "visibility",
];

const SHADERS: [&str; 8] = [
    include_str!(concat!(env!("OUT_DIR"), "/cost.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/box_h.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/box_v.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/aggregate.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/finalize.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/median.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/splat.wgsl")),
    include_str!(concat!(env!("OUT_DIR"), "/visibility.wgsl")),
];

/// Binding kinds of each stage, in binding order (must match the shaders' declarations).
#[derive(Clone, Copy)]
enum Slot {
    Uniform,
    BatchUniform,
    Read,
    ReadWrite,
}

const LAYOUTS: [&[Slot]; 8] = {
    use Slot::*;
    [
        &[Uniform, BatchUniform, Read, Read, Read, Read, ReadWrite], // cost
        &[Uniform, BatchUniform, Read, ReadWrite],                   // box_h
        &[Uniform, BatchUniform, Read, ReadWrite],                   // box_v
        &[Uniform, BatchUniform, Read, ReadWrite, Read, Read],       // aggregate
        &[Uniform, Read, Read, Read, ReadWrite],                     // finalize
        &[Uniform, ReadWrite],                                       // median
        &[Uniform, Read, Read, Read, ReadWrite],                     // splat
        &[Uniform, Read, Read, Read, ReadWrite],                     // visibility
    ]
};

/// Largest cost + aggregate slab we allocate for one batch of planes.
const SLAB_BUDGET_BYTES: u64 = 192 << 20;

/// Buffers for one shape of work.
struct Buffers {
    key: ShapeKey,
    params: wgpu::Buffer,
    batches: wgpu::Buffer,
    cameras: wgpu::Buffer,
    images: wgpu::Buffer,
    rays: wgpu::Buffer,
    planes: wgpu::Buffer,
    pairs: wgpu::Buffer,
    maps: wgpu::Buffer,
    zbuffer: wgpu::Buffer,
    readback: wgpu::Buffer,
    bind_groups: Vec<wgpu::BindGroup>,
    timestamps: Option<Timestamps>,
}

struct Timestamps {
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
    count: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ShapeKey {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
    cameras: u32,
    camera_pixels: usize,
    planes: u32,
    channels: u32,
    batch: u32,
    /// Windows of at most 2x2 are summed straight from the cost slab (no box passes).
    direct_windows: bool,
}

impl ShapeKey {
    fn batches(&self) -> u32 {
        self.planes.div_ceil(self.batch)
    }
    fn passes(&self) -> u32 {
        let per_batch = if self.direct_windows { 2 } else { 4 };
        per_batch * self.batches() + 4
    }
}

/// The values of the shaders' override constants for one plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Specialisation {
    distorted: bool,
    scoring: u32,
    pairs: u32,
    best_n: u32,
    window_w: u32,
    window_h: u32,
    channels: u32,
    aggregation: u32,
    window_mode: u32,
    half_best_n: u32,
}

impl Specialisation {
    fn of(plan: &SweepPlan) -> Self {
        let p = &plan.params;
        Self {
            distorted: plan.cameras.iter().any(|c| c.size[3] != DIST_NONE),
            scoring: p.modes[0],
            pairs: p.modes[1],
            best_n: p.modes[2],
            window_w: p.window[0],
            window_h: p.window[1],
            channels: p.counts[2],
            aggregation: p.modes[3],
            window_mode: p.extra[1],
            half_best_n: p.counts[3],
        }
    }
}

/// The GPU plane-sweep engine.
pub struct GpuEngine {
    device: wgpu::Device,
    queue: wgpu::Queue,
    layouts: Vec<wgpu::BindGroupLayout>,
    pipeline_layouts: Vec<wgpu::PipelineLayout>,
    modules: Vec<wgpu::ShaderModule>,
    /// Pipelines specialised (override constants) per mode; built on first use.
    pipelines: HashMap<Specialisation, Vec<wgpu::ComputePipeline>>,
    uniform_align: u64,
    buffers: Option<Buffers>,
    plan: Option<(Rig, SweepParams, SweepPlan)>,
    /// Id of the plan whose arrays are in the buffers.
    uploaded_plan: Option<u64>,
    packed: Vec<u32>,
    timings: StageTimings,
}

fn gpu_err(e: impl std::fmt::Display) -> SweepError {
    SweepError::Gpu(e.to_string())
}

impl GpuEngine {
    /// Builds the pipelines on the caller's device. Shader compilation errors are caught with an
    /// error scope and returned.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, SweepError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut layouts = Vec::new();
        let mut pipeline_layouts = Vec::new();
        let mut modules = Vec::new();
        for (i, stage) in STAGES.iter().enumerate() {
            let entries: Vec<wgpu::BindGroupLayoutEntry> = LAYOUTS[i]
                .iter()
                .enumerate()
                .map(|(binding, slot)| wgpu::BindGroupLayoutEntry {
                    binding: binding as u32,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: match slot {
                            Slot::Uniform | Slot::BatchUniform => wgpu::BufferBindingType::Uniform,
                            Slot::Read => wgpu::BufferBindingType::Storage { read_only: true },
                            Slot::ReadWrite => {
                                wgpu::BufferBindingType::Storage { read_only: false }
                            }
                        },
                        has_dynamic_offset: matches!(slot, Slot::BatchUniform),
                        min_binding_size: None,
                    },
                    count: None,
                })
                .collect();
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(stage),
                entries: &entries,
            });
            modules.push(device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(stage),
                source: wgpu::ShaderSource::Wgsl(Cow::Borrowed(SHADERS[i])),
            }));
            pipeline_layouts.push(
                device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some(stage),
                    bind_group_layouts: &[Some(&layout)],
                    immediate_size: 0,
                }),
            );
            layouts.push(layout);
        }
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(SweepError::Gpu(format!("building pipelines: {error}")));
        }
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            layouts,
            pipeline_layouts,
            modules,
            pipelines: HashMap::new(),
            uniform_align: u64::from(device.limits().min_uniform_buffer_offset_alignment).max(16),
            buffers: None,
            plan: None,
            uploaded_plan: None,
            packed: Vec::new(),
            timings: StageTimings::default(),
        })
    }

    /// Per-stage times of the last frame set.
    pub fn last_timings(&self) -> &StageTimings {
        &self.timings
    }

    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.device.adapter_info()
    }

    /// Runs the sweep on one frame set (one image per rig camera, in rig order).
    pub fn run(
        &mut self,
        rig: &Rig,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        let reuse = matches!(&self.plan, Some((r, p, _)) if r == rig && p == params);
        if !reuse {
            let plan = SweepPlan::new(rig, params)?;
            self.plan = Some((rig.clone(), params.clone(), plan));
        }
        let Some((_, _, plan)) = self.plan.take() else {
            return Err(SweepError::Gpu("internal: no plan".into()));
        };
        let result = self.run_plan(&plan, rig, images);
        self.plan = Some((rig.clone(), params.clone(), plan));
        result
    }

    /// Runs a prepared plan (e.g. with a custom hypothesis family).
    pub fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<DepthMaps, SweepError> {
        let maps = self.run_plan_raw(plan, rig, images)?;
        Ok(plan.depth_maps(&maps))
    }

    /// Runs a plan and returns the raw `maps` buffer (MAP_COUNT sections), for stage comparisons.
    pub fn run_plan_raw(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<Vec<f32>, SweepError> {
        let started = Instant::now();
        let mut packed = std::mem::take(&mut self.packed);
        plan.pack_images(rig, images, &mut packed)?;
        let key = self.shape_key(plan)?;
        if self.buffers.as_ref().map(|b| b.key) != Some(key) {
            self.buffers = Some(self.allocate(key)?);
            self.uploaded_plan = None;
        }
        let specialisation = Specialisation::of(plan);
        if !self.pipelines.contains_key(&specialisation) {
            let built = self.build_pipelines(&specialisation)?;
            self.pipelines.insert(specialisation, built);
        }
        let Some(pipelines) = self.pipelines.get(&specialisation) else {
            return Err(SweepError::Gpu("internal: no pipelines".into()));
        };
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let Some(buffers) = self.buffers.as_ref() else {
            return Err(SweepError::Gpu("internal: no buffers".into()));
        };
        if self.uploaded_plan != Some(plan.id) {
            self.upload_plan(buffers, plan, key);
            self.uploaded_plan = Some(plan.id);
        }
        self.queue
            .write_buffer(&buffers.images, 0, bytemuck::cast_slice(&packed));
        self.packed = packed;

        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("sweep"),
            });
        encoder.clear_buffer(&buffers.zbuffer, 0, None);
        let groups = |w: u32, h: u32, z: u32| (w.div_ceil(8), h.div_ceil(8), z);
        let image_groups = groups(plan.width, plan.height, 1);
        let mut pass_index = 0u32;
        let mut pass_stages: Vec<usize> = Vec::with_capacity(key.passes() as usize);
        let mut run_pass = |encoder: &mut wgpu::CommandEncoder,
                            stage: usize,
                            offset: Option<u32>,
                            (gx, gy, gz): (u32, u32, u32)| {
            let timestamp_writes =
                buffers
                    .timestamps
                    .as_ref()
                    .map(|t| wgpu::ComputePassTimestampWrites {
                        query_set: &t.query_set,
                        beginning_of_pass_write_index: Some(2 * pass_index),
                        end_of_pass_write_index: Some(2 * pass_index + 1),
                    });
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(STAGES[stage]),
                timestamp_writes,
            });
            pass.set_pipeline(&pipelines[stage]);
            match offset {
                Some(o) => pass.set_bind_group(0, &buffers.bind_groups[stage], &[o]),
                None => pass.set_bind_group(0, &buffers.bind_groups[stage], &[]),
            }
            pass.dispatch_workgroups(gx, gy, gz);
            pass_stages.push(stage);
            pass_index += 1;
        };
        for b in 0..key.batches() {
            let offset = Some((u64::from(b) * self.uniform_align) as u32);
            run_pass(&mut encoder, 0, offset, image_groups);
            if !key.direct_windows {
                run_pass(
                    &mut encoder,
                    1,
                    offset,
                    groups(key.padded_width, key.height, 1),
                );
                run_pass(
                    &mut encoder,
                    2,
                    offset,
                    groups(key.padded_width, key.padded_height, 1),
                );
            }
            run_pass(&mut encoder, 3, offset, image_groups);
        }
        for stage in 4..STAGES.len() {
            run_pass(&mut encoder, stage, None, image_groups);
        }
        let maps_bytes = buffers.maps.size();
        encoder.copy_buffer_to_buffer(&buffers.maps, 0, &buffers.readback, 0, maps_bytes);
        if let Some(t) = &buffers.timestamps {
            encoder.resolve_query_set(&t.query_set, 0..t.count, &t.resolve, 0);
            encoder.copy_buffer_to_buffer(&t.resolve, 0, &t.readback, 0, t.resolve.size());
        }
        self.queue.submit([encoder.finish()]);
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(SweepError::Gpu(format!("encoding the sweep: {error}")));
        }

        let maps: Vec<f32> = bytemuck::cast_slice(&self.read_buffer(&buffers.readback)?).to_vec();
        let mut timings = StageTimings::default();
        if let Some(t) = &buffers.timestamps {
            let raw = self.read_buffer(&t.readback)?;
            let ticks: &[u64] = bytemuck::cast_slice(&raw);
            let period_ns = f64::from(self.queue.get_timestamp_period());
            let mut per_stage = [0.0f64; STAGES.len()];
            for (p, &stage) in pass_stages.iter().enumerate() {
                let (begin, end) = (ticks[2 * p], ticks[2 * p + 1]);
                per_stage[stage] += end.saturating_sub(begin) as f64 * period_ns * 1e-6;
            }
            timings.gpu_timestamps = true;
            timings.stages = STAGES
                .iter()
                .zip(per_stage)
                .map(|(s, ms)| (s.to_string(), ms))
                .collect();
        } else {
            timings.stages = vec![("total".to_string(), started.elapsed().as_secs_f64() * 1e3)];
        }
        self.timings = timings;
        Ok(maps)
    }

    fn build_pipelines(
        &self,
        spec: &Specialisation,
    ) -> Result<Vec<wgpu::ComputePipeline>, SweepError> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let distorted = [("DISTORTED", f64::from(u8::from(spec.distorted)))];
        let cost = [
            distorted[0],
            ("SCORING", f64::from(spec.scoring)),
            ("PAIRS", f64::from(spec.pairs)),
            ("BEST_N", f64::from(spec.best_n)),
            ("AGGREGATION", f64::from(spec.aggregation)),
            ("CHANNELS", f64::from(spec.channels)),
        ];
        let aggregate = [
            distorted[0],
            ("WINDOW_W", f64::from(spec.window_w)),
            ("WINDOW_H", f64::from(spec.window_h)),
            ("CHANNELS", f64::from(spec.channels)),
            ("AGGREGATION", f64::from(spec.aggregation)),
            ("SCORING", f64::from(spec.scoring)),
            ("BEST_N", f64::from(spec.best_n)),
            ("WINDOW_MODE", f64::from(spec.window_mode)),
            ("HALF_BEST_N", f64::from(spec.half_best_n)),
        ];
        let box_h = [
            distorted[0],
            ("WINDOW_W", f64::from(spec.window_w)),
            ("CHANNELS", f64::from(spec.channels)),
        ];
        let box_v = [
            distorted[0],
            ("WINDOW_H", f64::from(spec.window_h)),
            ("CHANNELS", f64::from(spec.channels)),
        ];
        let pipelines = STAGES
            .iter()
            .enumerate()
            .map(|(i, stage)| {
                let constants: &[(&str, f64)] = match STAGES[i] {
                    "cost" => &cost,
                    "box_h" => &box_h,
                    "box_v" => &box_v,
                    "aggregate" => &aggregate,
                    _ => &distorted,
                };
                self.device
                    .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(stage),
                        layout: Some(&self.pipeline_layouts[i]),
                        module: &self.modules[i],
                        entry_point: Some("main"),
                        compilation_options: wgpu::PipelineCompilationOptions {
                            constants,
                            zero_initialize_workgroup_memory: false,
                        },
                        cache: None,
                    })
            })
            .collect();
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(SweepError::Gpu(format!(
                "building pipelines for {spec:?}: {error}"
            )));
        }
        Ok(pipelines)
    }

    fn read_buffer(&self, buffer: &wgpu::Buffer) -> Result<Vec<u8>, SweepError> {
        let (sender, receiver) = mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = sender.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(gpu_err)?;
        receiver.recv().map_err(gpu_err)?.map_err(gpu_err)?;
        let data = buffer.get_mapped_range(..).map_err(gpu_err)?.to_vec();
        buffer.unmap();
        Ok(data)
    }

    fn shape_key(&self, plan: &SweepPlan) -> Result<ShapeKey, SweepError> {
        let limits = self.device.limits();
        let npix = plan.pixel_count() as u64;
        let channels = plan.channels() as u64;
        let (padded_w, padded_h) = plan.padded_size();
        let row_bytes = u64::from(padded_w) * u64::from(plan.height) * 8 * channels;
        let box_bytes = u64::from(padded_w) * u64::from(padded_h) * 8 * channels;
        // Cost slab + row sums + box sums + aggregated slab, per plane.
        let per_plane = npix * 4 * channels + row_bytes + box_bytes;
        let max_binding =
            u64::from(limits.max_storage_buffer_binding_size).min(limits.max_buffer_size);
        let budget = SLAB_BUDGET_BYTES.min(max_binding);
        if box_bytes > budget {
            return Err(SweepError::InvalidParams(format!(
                "reference image of {npix} pixels needs {box_bytes} bytes of window sums per plane, more than this adapter's storage binding limit ({budget})"
            )));
        }
        let maps_bytes = npix * 4 * MAP_COUNT as u64;
        let image_bytes = plan.total_camera_pixels as u64 * 4;
        for (what, bytes) in [("output maps", maps_bytes), ("camera images", image_bytes)] {
            if bytes > max_binding {
                return Err(SweepError::InvalidParams(format!(
                    "{what} need {bytes} bytes, more than this adapter's storage binding limit ({max_binding})"
                )));
            }
        }
        let planes = plan.num_planes();
        let max_z = limits.max_compute_workgroups_per_dimension;
        let max_slices = (budget / box_bytes.max(1)).min(budget / per_plane.max(1)) as u32;
        let batch = max_slices
            .clamp(1, planes)
            .min(max_z / (channels as u32).max(1))
            .max(1);
        Ok(ShapeKey {
            width: plan.width,
            height: plan.height,
            padded_width: padded_w,
            padded_height: padded_h,
            cameras: plan.cameras.len() as u32,
            camera_pixels: plan.total_camera_pixels,
            planes,
            channels: plan.channels() as u32,
            batch,
            direct_windows: plan.params.extra[1] == WINDOW_SHIFTABLE
                && plan.params.window[0] <= 2
                && plan.params.window[1] <= 2,
        })
    }

    fn upload_plan(&self, buffers: &Buffers, plan: &SweepPlan, key: ShapeKey) {
        self.queue
            .write_buffer(&buffers.params, 0, bytemuck::bytes_of(&plan.params));
        self.queue
            .write_buffer(&buffers.cameras, 0, bytemuck::cast_slice(&plan.cameras));
        self.queue
            .write_buffer(&buffers.planes, 0, bytemuck::cast_slice(&plan.planes));
        self.queue
            .write_buffer(&buffers.rays, 0, bytemuck::cast_slice(&plan.rays));
        self.queue
            .write_buffer(&buffers.pairs, 0, bytemuck::cast_slice(&plan.pairs));
        let mut batches = vec![0u8; buffers.batches.size() as usize];
        for b in 0..key.batches() {
            let first = b * key.batch;
            let batch = GpuBatch {
                first_plane: first,
                plane_count: key.batch.min(key.planes - first),
                is_first: u32::from(b == 0),
                _pad: 0,
            };
            let at = (u64::from(b) * self.uniform_align) as usize;
            batches[at..at + 16].copy_from_slice(bytemuck::bytes_of(&batch));
        }
        self.queue.write_buffer(&buffers.batches, 0, &batches);
    }

    fn allocate(&self, key: ShapeKey) -> Result<Buffers, SweepError> {
        let device = &self.device;
        let npix = u64::from(key.width) * u64::from(key.height);
        let storage = |label: &str, size: u64, extra: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16).next_multiple_of(4),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
                mapped_at_creation: false,
            })
        };
        let none = wgpu::BufferUsages::empty();
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: std::mem::size_of::<GpuParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let batches = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("batches"),
            size: u64::from(key.batches()) * self.uniform_align,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let cameras = storage("cameras", u64::from(key.cameras) * 128, none);
        let images = storage("images", key.camera_pixels as u64 * 4, none);
        let rays = storage("rays", npix * 16, none);
        let planes = storage("planes", u64::from(key.planes) * 16, none);
        let pair_count = u64::from(key.cameras) * u64::from(key.cameras.saturating_sub(1)) / 2;
        let pairs = storage("pairs", pair_count.max(1) * 16, none);
        let slices = u64::from(key.channels) * u64::from(key.batch);
        let cost_slab = storage("cost_slab", npix * 4 * slices, none);
        let row_sums = storage(
            "row_sums",
            u64::from(key.padded_width) * u64::from(key.height) * 8 * slices,
            none,
        );
        let box_sums = storage(
            "box_sums",
            u64::from(key.padded_width) * u64::from(key.padded_height) * 8 * slices,
            none,
        );
        let state = storage("state", npix * 48, none);
        let maps = storage(
            "maps",
            npix * 4 * MAP_COUNT as u64,
            wgpu::BufferUsages::COPY_SRC,
        );
        let zbuffer = storage("zbuffer", key.camera_pixels as u64 * 4, none);
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: maps.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let batch_binding = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &batches,
            offset: 0,
            size: wgpu::BufferSize::new(16),
        });
        let bind = |stage: usize, resources: Vec<wgpu::BindingResource>| {
            let entries: Vec<wgpu::BindGroupEntry> = resources
                .into_iter()
                .enumerate()
                .map(|(i, resource)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource,
                })
                .collect();
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(STAGES[stage]),
                layout: &self.layouts[stage],
                entries: &entries,
            })
        };
        let bind_groups = vec![
            bind(
                0,
                vec![
                    params.as_entire_binding(),
                    batch_binding.clone(),
                    cameras.as_entire_binding(),
                    images.as_entire_binding(),
                    rays.as_entire_binding(),
                    planes.as_entire_binding(),
                    cost_slab.as_entire_binding(),
                ],
            ),
            bind(
                1,
                vec![
                    params.as_entire_binding(),
                    batch_binding.clone(),
                    cost_slab.as_entire_binding(),
                    row_sums.as_entire_binding(),
                ],
            ),
            bind(
                2,
                vec![
                    params.as_entire_binding(),
                    batch_binding.clone(),
                    row_sums.as_entire_binding(),
                    box_sums.as_entire_binding(),
                ],
            ),
            bind(
                3,
                vec![
                    params.as_entire_binding(),
                    batch_binding.clone(),
                    box_sums.as_entire_binding(),
                    state.as_entire_binding(),
                    pairs.as_entire_binding(),
                    cost_slab.as_entire_binding(),
                ],
            ),
            bind(
                4,
                vec![
                    params.as_entire_binding(),
                    rays.as_entire_binding(),
                    planes.as_entire_binding(),
                    state.as_entire_binding(),
                    maps.as_entire_binding(),
                ],
            ),
            bind(
                5,
                vec![params.as_entire_binding(), maps.as_entire_binding()],
            ),
            bind(
                6,
                vec![
                    params.as_entire_binding(),
                    cameras.as_entire_binding(),
                    rays.as_entire_binding(),
                    maps.as_entire_binding(),
                    zbuffer.as_entire_binding(),
                ],
            ),
            bind(
                7,
                vec![
                    params.as_entire_binding(),
                    cameras.as_entire_binding(),
                    rays.as_entire_binding(),
                    zbuffer.as_entire_binding(),
                    maps.as_entire_binding(),
                ],
            ),
        ];
        let timestamps = if self
            .device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
        {
            let count = 2 * key.passes();
            let query_set = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("stage timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count,
            });
            let bytes = u64::from(count) * 8;
            let resolve = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let readback = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            Some(Timestamps {
                query_set,
                resolve,
                readback,
                count,
            })
        } else {
            None
        };
        Ok(Buffers {
            key,
            params,
            batches,
            cameras,
            images,
            rays,
            planes,
            pairs,
            maps,
            zbuffer,
            readback,
            bind_groups,
            timestamps,
        })
    }
}
