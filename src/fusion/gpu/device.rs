//! The GPU integration's traffic with its device: buffers made, submissions and readbacks,
//! each submission and poll under [`device_poll_lock`] (the device may be the engine's, used
//! from its own thread).

use std::sync::mpsc;

use bytemuck::Pod;

use super::GpuFusionError;
use crate::gpu_context::device_poll_lock;

/// An unmapped buffer.
pub(super) fn make_buffer(
    device: &wgpu::Device,
    label: &str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage,
        mapped_at_creation: false,
    })
}

/// What one binding of a fusion shader's bind group holds.
#[derive(Debug, Clone, Copy)]
pub(super) enum Binding {
    Uniform,
    /// A storage buffer the shader only reads.
    Read,
    /// A storage buffer the shader writes.
    ReadWrite,
}

/// The compute pipeline of `source`'s entry point `entry` with one bind group whose bindings
/// 0, 1, ... are `bindings`, and that group's layout; what the device refuses comes back as
/// an error. Built with the default options, which zero workgroup memory (the integration's
/// block counter relies on it).
pub(super) fn compute_pipeline(
    device: &wgpu::Device,
    label: &str,
    source: &'static str,
    entry: &str,
    bindings: &[Binding],
) -> Result<(wgpu::ComputePipeline, wgpu::BindGroupLayout), GpuFusionError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
        .iter()
        .enumerate()
        .map(|(i, binding)| wgpu::BindGroupLayoutEntry {
            binding: i as u32,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: match binding {
                    Binding::Uniform => wgpu::BufferBindingType::Uniform,
                    Binding::Read => wgpu::BufferBindingType::Storage { read_only: true },
                    Binding::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
                },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect();
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    });
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(std::borrow::Cow::Borrowed(source)),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: Some(&pipeline_layout),
        module: &module,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions::default(),
        cache: None,
    });
    if let Some(error) = futures::executor::block_on(scope.pop()) {
        return Err(GpuFusionError::Gpu(format!(
            "building the {label} pipeline: {error}"
        )));
    }
    Ok((pipeline, layout))
}

/// The most workgroups along one dimension of a dispatch (WebGPU's limit).
const MAX_GROUPS_PER_DIMENSION: u32 = 65_535;

/// Records one compute pass of `pipeline` with `bind_group`, one workgroup per item of
/// `items` (laid out over x and y within WebGPU's limit; the shader flattens them back).
pub(super) fn dispatch_items(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
    items: u32,
) {
    let x = items.clamp(1, MAX_GROUPS_PER_DIMENSION);
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind_group, &[]);
    pass.dispatch_workgroups(x, items.div_ceil(x), 1);
}

/// Submits `commands` under [`device_poll_lock`] (the device may be the engine's, polled
/// from its thread).
pub(super) fn submit(queue: &wgpu::Queue, commands: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
    let _poll = device_poll_lock();
    queue.submit([commands])
}

/// Maps the first `bytes` of a buffer that `submitted` last used, waits for that submission
/// alone (the engine's sets submitted after it go on running), and copies them out.
pub(super) fn read_buffer<T: Pod>(
    device: &wgpu::Device,
    submitted: wgpu::SubmissionIndex,
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<T>, GpuFusionError> {
    let gpu = |e: &dyn std::fmt::Display| GpuFusionError::Gpu(format!("reading back: {e}"));
    let (sender, receiver) = mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
        let _ = sender.send(r);
    });
    // One short poll at a time: the engine may share the device.
    crate::gpu_context::wait_for_submission(device, Some(submitted), || {
        Ok::<(), GpuFusionError>(())
    })?;
    receiver.recv().map_err(|e| gpu(&e))?.map_err(|e| gpu(&e))?;
    let out = {
        let range = buffer.get_mapped_range(..bytes).map_err(|e| gpu(&e))?;
        bytemuck::pod_collect_to_vec(&range)
    };
    buffer.unmap();
    Ok(out)
}

/// A device buffer that grows (to a power of two of bytes) when a frame needs more.
pub(super) struct Grown {
    pub(super) buffer: wgpu::Buffer,
    label: &'static str,
    usage: wgpu::BufferUsages,
}

impl Grown {
    pub(super) fn new(
        device: &wgpu::Device,
        label: &'static str,
        usage: wgpu::BufferUsages,
    ) -> Self {
        Self {
            buffer: make_buffer(device, label, 256, usage),
            label,
            usage,
        }
    }

    /// Makes room for `bytes` (the contents are not kept), in a buffer of at most `limit`
    /// bytes unless `bytes` is more.
    pub(super) fn reserve(&mut self, device: &wgpu::Device, bytes: u64, limit: u64) {
        if bytes > self.buffer.size() {
            let size = bytes.next_power_of_two().min(limit).max(bytes).max(256);
            self.buffer = make_buffer(device, self.label, size, self.usage);
        }
    }
}
