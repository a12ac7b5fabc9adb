//! Step 0 of the GPU integration on the device for a pinhole camera
//! (`shaders/tsdf_samples.wgsl`, the twin of `integrate::pinhole_samples`): the host uploads
//! the raw depth map (and the colour image and the caller's pixel weights where the frame has
//! them, 4 bytes a pixel each) instead of the 12-byte samples, and of step 0 makes only the
//! valid depths that step 1 reads. A distorted camera's samples are still made on the host
//! (its rays come from the CPU's ray grid).

use bytemuck::{Pod, Zeroable};

use super::device::{compute_pipeline, dispatch_items, make_buffer, Binding, Grown};
use super::{entry, GpuFusionError};
use crate::fusion::integrate::PixelSample;
use crate::image::{ImageF32, Rgba8Image};

const SHADER: &str = include_str!("../../../shaders/tsdf_samples.wgsl");

/// Pixels per workgroup (the shader's `@workgroup_size`).
const PIXELS_PER_GROUP: u32 = 64;

/// WGSL `SampleParams`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SampleUniform {
    width: u32,
    height: u32,
    has_colour: u32,
    has_weights: u32,
    intrinsics: [f32; 4],
    truncation_m: f32,
    min_depth_m: f32,
    max_depth_m: f32,
    min_weight: f32,
}

/// A frame's samples: made by the host, or to be made on the device from its inputs.
pub(super) enum Samples<'a> {
    Host(&'a [PixelSample]),
    Device(SampleInput<'a>),
}

/// What the device's step 0 reads of a frame.
pub(super) struct SampleInput<'a> {
    pub(super) depth: &'a ImageF32,
    pub(super) colour: Option<&'a Rgba8Image>,
    pub(super) weights: Option<&'a ImageF32>,
    /// fx, fy, cx, cy in pixels, as the host's pinhole step 0 takes them (f32).
    pub(super) intrinsics: [f32; 4],
    pub(super) truncation_m: f32,
    /// The depths integrated, metres.
    pub(super) depth_range_m: [f32; 2],
}

/// The pipeline of step 0 and the buffers of a frame's inputs.
pub(super) struct SampleStage {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    uniform: wgpu::Buffer,
    depth: Grown,
    colour: Grown,
    weights: Grown,
}

impl SampleStage {
    pub(super) fn new(device: &wgpu::Device) -> Result<Self, GpuFusionError> {
        use Binding::{Read, ReadWrite, Uniform};
        let (pipeline, layout) = compute_pipeline(
            device,
            "tsdf_samples",
            SHADER,
            "make_samples",
            &[Uniform, Read, Read, Read, ReadWrite],
        )?;
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        Ok(Self {
            pipeline,
            layout,
            uniform: make_buffer(
                device,
                "tsdf sample params",
                std::mem::size_of::<SampleUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            depth: Grown::new(device, "tsdf depth", usage),
            colour: Grown::new(device, "tsdf colour", usage),
            weights: Grown::new(device, "tsdf weights", usage),
        })
    }

    /// Uploads `input` and records the pass that writes its samples into `samples` (12 bytes
    /// a pixel; the caller checked them against `limit`, the largest buffer bound).
    pub(super) fn record(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        input: &SampleInput<'_>,
        samples: &wgpu::Buffer,
        limit: u64,
    ) {
        let depth = input.depth;
        let pixels = depth.data.len();
        let bytes = (pixels * 4) as u64;
        self.depth.reserve(device, bytes, limit);
        queue.write_buffer(&self.depth.buffer, 0, bytemuck::cast_slice(&depth.data));
        if let Some(colour) = input.colour {
            self.colour.reserve(device, bytes, limit);
            queue.write_buffer(&self.colour.buffer, 0, bytemuck::cast_slice(&colour.pixels));
        }
        if let Some(weights) = input.weights {
            self.weights.reserve(device, bytes, limit);
            queue.write_buffer(&self.weights.buffer, 0, bytemuck::cast_slice(&weights.data));
        }
        let [min_depth_m, max_depth_m] = input.depth_range_m;
        let uniform = SampleUniform {
            width: depth.width,
            height: depth.height,
            has_colour: u32::from(input.colour.is_some()),
            has_weights: u32::from(input.weights.is_some()),
            intrinsics: input.intrinsics,
            truncation_m: input.truncation_m,
            min_depth_m,
            max_depth_m,
            min_weight: crate::fusion::integrate::MIN_OBSERVATION_WEIGHT,
        };
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tsdf samples"),
            layout: &self.layout,
            entries: &[
                entry(0, &self.uniform),
                entry(1, &self.depth.buffer),
                entry(2, &self.colour.buffer),
                entry(3, &self.weights.buffer),
                entry(4, samples),
            ],
        });
        let groups = (pixels as u32).div_ceil(PIXELS_PER_GROUP);
        dispatch_items(encoder, "tsdf samples", &self.pipeline, &bind_group, groups);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::integrate::{prepare, FrameInput, IntegrationScratch, Projector};
    use crate::fusion::test_scenes::camera;
    use crate::fusion::FusionParams;
    use crate::geometry::RigidTransform;

    /// The device's samples are the host's (`pinhole_samples`): the same valid depths and
    /// colours bit for bit, the same weights to float rounding, the same pixels without one;
    /// on a 67x45 map (a part-empty last workgroup) of a slanted, curved surface with a depth
    /// step, invalid depths of every kind (NaN, infinite, negative, outside the range) and the
    /// caller's weights (some zero, negative or NaN).
    #[test]
    fn the_device_makes_the_hosts_samples() {
        let (context, _one) = super::super::tests::gpu();
        let (device, queue) = (&context.device, &context.queue);
        let (width, height) = (67u32, 45u32);
        let model = camera(width, height, 60.0);
        let params = FusionParams {
            min_depth_m: 0.5,
            max_depth_m: 4.0,
            ..FusionParams::default()
        };
        let depth_at = |col: u32, row: u32| -> f32 {
            let (x, y) = (col as f32, row as f32);
            let surface = 1.5 + 0.01 * x + 0.0004 * y * y + 0.02 * (0.3 * x).sin();
            match (col * 7 + row * 13) % 41 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => -1.0,
                3 => 0.2,
                4 => 9.0,
                _ if col > 40 => surface + 0.8,
                _ => surface,
            }
        };
        let depth = ImageF32 {
            width,
            height,
            data: (0..height)
                .flat_map(|r| (0..width).map(move |c| (c, r)))
                .map(|(c, r)| depth_at(c, r))
                .collect(),
        };
        let colour = Rgba8Image {
            width,
            height,
            pixels: (0..width * height)
                .map(|i| i.wrapping_mul(0x9E37_79B1) | 0xFF00_0000)
                .collect(),
        };
        let weights = ImageF32 {
            width,
            height,
            data: (0..width * height)
                .map(|i| match i % 29 {
                    0 => 0.0,
                    1 => -0.5,
                    2 => f32::NAN,
                    k => 0.2 + k as f32 * 0.05,
                })
                .collect(),
        };
        let pose = RigidTransform::IDENTITY;
        for (with_colour, with_weights) in [(true, true), (false, false)] {
            let colour = with_colour.then_some(&colour);
            let weights = with_weights.then_some(&weights);
            let frame = |samples_on_device| FrameInput {
                depth: &depth,
                weights,
                colour,
                model: &model,
                world_from_cam: &pose,
                samples_on_device,
            };
            let mut scratch = IntegrationScratch::default();
            let (host, _) = prepare(params.voxel_size_m, &mut scratch, &params, &frame(false))
                .expect("host step 0");
            let mut on_device = IntegrationScratch::default();
            let (device_view, _) =
                prepare(params.voxel_size_m, &mut on_device, &params, &frame(true))
                    .expect("the device's step 0 on the host");
            assert!(device_view.samples.is_empty());
            assert_eq!(device_view.pixels_valid, host.pixels_valid);
            let Projector::Pinhole { fx, fy, cx, cy } = host.projector else {
                panic!("a pinhole camera");
            };
            let input = SampleInput {
                depth: &depth,
                colour,
                weights,
                intrinsics: [fx, fy, cx, cy],
                truncation_m: host.truncation_m,
                depth_range_m: [params.min_depth_m, params.max_depth_m],
            };
            let bytes = std::mem::size_of_val(host.samples.as_slice()) as u64;
            let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
            let out = make_buffer(device, "samples", bytes, usage);
            let readback = make_buffer(
                device,
                "samples readback",
                bytes,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            let mut stage = SampleStage::new(device).expect("pipeline");
            let mut encoder = device.create_command_encoder(&Default::default());
            stage.record(device, queue, &mut encoder, &input, &out, u64::MAX);
            encoder.copy_buffer_to_buffer(&out, 0, &readback, 0, bytes);
            let submitted = super::super::device::submit(queue, encoder.finish());
            let words: Vec<u32> =
                super::super::device::read_buffer(device, submitted, &readback, bytes)
                    .expect("readback");
            let (mut weighed, mut without) = (0, 0);
            for (i, (h, d)) in host.samples.iter().zip(words.chunks_exact(3)).enumerate() {
                let at = (i as u32 % width, i as u32 / width);
                let depth_bits = h.depth_m.to_bits();
                let same_depth =
                    depth_bits == d[0] || (h.depth_m.is_nan() && f32::from_bits(d[0]).is_nan());
                assert!(
                    same_depth,
                    "{at:?}: depth {} against {}",
                    h.depth_m,
                    f32::from_bits(d[0])
                );
                assert_eq!(h.rgb, d[2], "{at:?}: colour");
                let w = f32::from_bits(d[1]);
                if h.weight.is_nan() {
                    assert!(w.is_nan(), "{at:?}: weight {w} where the host has none");
                    without += 1;
                    continue;
                }
                let relative = (w - h.weight).abs() / h.weight;
                assert!(relative <= 1e-4, "{at:?}: weight {w} against {}", h.weight);
                weighed += 1;
            }
            // Weights of all kinds: many pixels weighed (at different weights), many without.
            assert!(
                weighed > 1500 && without > 300,
                "{weighed} weighed, {without} without"
            );
            let distinct: std::collections::BTreeSet<u32> = host
                .samples
                .iter()
                .filter(|s| !s.weight.is_nan())
                .map(|s| (s.weight * 1e3) as u32)
                .collect();
            assert!(distinct.len() > 50, "{} distinct weights", distinct.len());
        }
    }
}
