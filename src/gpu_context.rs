//! Making a wgpu device for the binaries and tests. The engine itself never makes one: it takes
//! the device and queue it is given.

/// One device poll or queue submission at a time in this process. wgpu-core 30.0.1 can panic
/// when two threads poll (or one polls while another submits) on one device at once ("If the
/// queue is empty, the current submission index ... should be at least the wait submission
/// index", gfx-rs/wgpu#9958, fixed later): the tests share one device across threads, a CI
/// run met it once, and the node's fusion thread shares the engine's device. Held for one
/// submission or one poll of at most [`POLL_SLICE`], never for a whole wait, and handed to a
/// thread waiting for it after each slice (a waiting engine may submit its next set while
/// fusion waits for its own readback, and the other way round).
static DEVICE_POLL: parking_lot::Mutex<()> = parking_lot::const_mutex(());

/// How long one poll of a wait holds the device lock: another thread that shares the device
/// waits at most this long to submit or poll.
pub const POLL_SLICE: std::time::Duration = std::time::Duration::from_millis(2);

/// Takes the process's device lock (one device poll or queue submission at a time; see
/// `DEVICE_POLL`).
pub fn device_poll_lock() -> parking_lot::MutexGuard<'static, ()> {
    DEVICE_POLL.lock()
}

/// Waits until `device` has finished its last submission, polling under [`device_poll_lock`]
/// for at most [`POLL_SLICE`] at a time (another thread may share the device) and calling
/// `between` after each slice that timed out (a cancel check or a deadline; its error ends the
/// wait). A submission that failed (a lost device, a validation error) has nothing to wait
/// for: the wait ends, and the error scope or the read that follows says why.
pub fn wait_for_device<E>(
    device: &wgpu::Device,
    between: impl FnMut() -> Result<(), E>,
) -> Result<(), E> {
    wait_for_submission(device, None, between)
}

/// [`wait_for_device`] until `submission` alone has finished (None: the last one); the
/// submissions after it may still run.
pub fn wait_for_submission<E>(
    device: &wgpu::Device,
    submission: Option<wgpu::SubmissionIndex>,
    between: impl FnMut() -> Result<(), E>,
) -> Result<(), E> {
    poll_in_slices(
        || {
            device.poll(wgpu::PollType::Wait {
                submission_index: submission.clone(),
                timeout: Some(POLL_SLICE),
            })
        },
        between,
    )
}

/// The loop of [`wait_for_submission`]: `poll` (one slice) under the device lock until it
/// says done, the lock handed fairly to a waiting thread after each slice: a plain unlock
/// lets this thread take it straight back, and a thread that polls or submits beside a long
/// wait would wait with it.
fn poll_in_slices<E>(
    mut poll: impl FnMut() -> Result<wgpu::PollStatus, wgpu::PollError>,
    mut between: impl FnMut() -> Result<(), E>,
) -> Result<(), E> {
    loop {
        let lock = device_poll_lock();
        let polled = poll();
        parking_lot::MutexGuard::unlock_fair(lock);
        match polled {
            Ok(_) | Err(wgpu::PollError::WrongSubmissionIndex(..)) => return Ok(()),
            Err(wgpu::PollError::Timeout) => between()?,
        }
    }
}

/// An adapter, device and queue. A clone is another handle to the same device (wgpu's
/// handles are reference-counted), e.g. for the fusion thread beside the engine.
#[derive(Clone)]
pub struct GpuContext {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

#[derive(Debug, thiserror::Error)]
pub enum GpuContextError {
    #[error("no GPU adapter found ({0}). On a machine without a GPU install Mesa's software Vulkan driver: `apt-get install -y mesa-vulkan-drivers libvulkan1`")]
    NoAdapter(String),
    #[error("the adapter '{adapter}' refused a device: {reason}")]
    NoDevice { adapter: String, reason: String },
}

impl GpuContext {
    /// Picks the adapter named by `WGPU_ADAPTER_NAME` / `WGPU_BACKEND` if set, else the default
    /// high-performance one of the primary backends (Vulkan, Metal, DX12); asks for timestamp queries when the adapter has them and for the
    /// adapter's own storage-buffer limits (large cost slabs), nothing else.
    pub fn new() -> Result<Self, GpuContextError> {
        futures::executor::block_on(Self::new_async())
    }

    pub async fn new_async() -> Result<Self, GpuContextError> {
        Self::create(None).await
    }

    /// Like [`GpuContext::new`], with the storage-buffer binding and buffer size limits capped
    /// at `max_bytes` (to keep a budget on a shared GPU, and to test the up-front refusal of
    /// configurations larger than an adapter allows).
    pub fn with_max_storage_binding(max_bytes: u64) -> Result<Self, GpuContextError> {
        futures::executor::block_on(Self::create(Some(max_bytes)))
    }

    async fn create(max_storage_binding: Option<u64>) -> Result<Self, GpuContextError> {
        // The primary backends (Vulkan, Metal, DX12), the only ones built (Cargo.toml: wgpu
        // without `gles`); WGPU_BACKEND can narrow them. The GL backend's EGL probe logged
        // errors on machines without a GL driver ("eglInitialize DRI2: failed to load driver")
        // and had nothing the engine needs.
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(descriptor.with_env());
        let adapter = wgpu::util::initialize_adapter_from_env_or_default(&instance, None)
            .await
            .map_err(|e| GpuContextError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let supported = adapter.features();
        let mut features = wgpu::Features::empty();
        if supported.contains(wgpu::Features::TIMESTAMP_QUERY) {
            features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        // SGM in subgroups (`shaders/sgm_subgroup.wgsl`) where the adapter has them.
        if supported.contains(wgpu::Features::SUBGROUP) {
            features |= wgpu::Features::SUBGROUP;
        }
        let adapter_limits = adapter.limits();
        let cap = max_storage_binding.unwrap_or(u64::MAX);
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: adapter_limits
                .max_storage_buffer_binding_size
                .min(cap),
            max_buffer_size: adapter_limits.max_buffer_size.min(cap),
            max_storage_buffers_per_shader_stage: adapter_limits
                .max_storage_buffers_per_shader_stage
                .min(8),
            ..wgpu::Limits::downlevel_defaults()
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("sweepdepth"),
                required_features: features,
                required_limits: limits,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuContextError::NoDevice {
                adapter: info.name.clone(),
                reason: e.to_string(),
            })?;
        tracing::info!(
            "GPU adapter: {} ({:?}, {:?}), timestamps: {}, subgroups: {} (sizes {}-{})",
            info.name,
            info.backend,
            info.device_type,
            features.contains(wgpu::Features::TIMESTAMP_QUERY),
            features.contains(wgpu::Features::SUBGROUP),
            info.subgroup_min_size,
            info.subgroup_max_size
        );
        Ok(Self {
            adapter,
            device,
            queue,
        })
    }

    /// "name (backend, driver)" for reports.
    pub fn adapter_label(&self) -> String {
        let info = self.adapter.get_info();
        format!(
            "{} ({:?}, {} {})",
            info.name, info.backend, info.driver, info.driver_info
        )
        .trim()
        .to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;

    /// A thread that submits or polls beside a long wait (the engine beside fusion's readback)
    /// gets the device lock between the wait's slices, not when the wait ends: the wait here
    /// ends only once the other thread has held the lock, so a lock held over the whole wait
    /// (or never handed over) runs into its 60 s limit.
    #[test]
    fn a_thread_beside_a_long_wait_gets_the_device_lock_between_its_slices() {
        let waiting = Arc::new(AtomicBool::new(false));
        let other_held = Arc::new(AtomicBool::new(false));
        let waiter = {
            let (waiting, other_held) = (waiting.clone(), other_held.clone());
            std::thread::spawn(move || {
                let limit = std::time::Instant::now() + std::time::Duration::from_secs(60);
                let mut slices = 0u32;
                let waited = poll_in_slices(
                    || {
                        // One slice of a device wait, under the lock.
                        slices += 1;
                        waiting.store(true, Ordering::SeqCst);
                        std::thread::sleep(POLL_SLICE);
                        if other_held.load(Ordering::SeqCst) {
                            Ok(wgpu::PollStatus::WaitSucceeded)
                        } else {
                            Err(wgpu::PollError::Timeout)
                        }
                    },
                    || {
                        if std::time::Instant::now() < limit {
                            Ok(())
                        } else {
                            Err(())
                        }
                    },
                );
                (waited, slices)
            })
        };
        while !waiting.load(Ordering::SeqCst) {
            std::thread::yield_now();
        }
        {
            let _lock = device_poll_lock();
            other_held.store(true, Ordering::SeqCst);
        }
        let (waited, slices) = waiter.join().expect("the waiting thread");
        assert!(
            waited.is_ok(),
            "the other thread did not get the device lock in 60 s of the wait ({slices} slices)"
        );
        assert!(
            slices >= 2,
            "the wait ended after the other thread held the lock"
        );
    }
}
