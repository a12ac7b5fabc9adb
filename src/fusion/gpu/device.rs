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

/// How long one poll of a wait holds [`device_poll_lock`].
const POLL_SLICE: std::time::Duration = std::time::Duration::from_millis(50);

/// Submits `commands` under [`device_poll_lock`] (the device may be the engine's, polled
/// from its thread).
pub(super) fn submit(queue: &wgpu::Queue, commands: wgpu::CommandBuffer) {
    let _poll = device_poll_lock();
    queue.submit([commands]);
}

/// Maps the first `bytes` of a buffer (after the last submission), waits, and copies them out.
pub(super) fn read_buffer<T: Pod>(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<T>, GpuFusionError> {
    let gpu = |e: &dyn std::fmt::Display| GpuFusionError::Gpu(format!("reading back: {e}"));
    let (sender, receiver) = mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
        let _ = sender.send(r);
    });
    // One short poll at a time: the engine may share the device.
    crate::gpu_context::wait_for_device(device, POLL_SLICE, || Ok::<(), GpuFusionError>(()))?;
    receiver.recv().map_err(|e| gpu(&e))?.map_err(|e| gpu(&e))?;
    let out = {
        let range = buffer.get_mapped_range(..bytes).map_err(|e| gpu(&e))?;
        bytemuck::pod_collect_to_vec(&range)
    };
    buffer.unmap();
    Ok(out)
}
