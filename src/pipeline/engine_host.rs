//! The GPU side of the pipeline ([`EngineHost`]): the device and the engine, made anew when
//! the device is lost (a driver reset, a GPU that fell off the bus, `Device::destroy`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use super::outcome::{Job, Skip, SkipKind};
use super::outputs::{process_job, FrameOutputs};
use crate::gpu_context::{GpuContext, GpuContextError};
use crate::sweep::gpu::GpuEngine;
use crate::sweep::{SweepError, SweepParams};

/// Why no engine could be made.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    #[error(transparent)]
    Context(#[from] GpuContextError),
    #[error(transparent)]
    Engine(#[from] SweepError),
}

/// The device and the engine, and whether the device was lost.
pub struct EngineHost {
    gpu: GpuContext,
    engine: GpuEngine,
    lost: Arc<AtomicBool>,
    /// How many times the device was lost and the engine recreated.
    pub recreated: u64,
}

impl EngineHost {
    pub fn new() -> Result<Self, HostError> {
        let (gpu, engine, lost) = Self::create()?;
        Ok(Self {
            gpu,
            engine,
            lost,
            recreated: 0,
        })
    }

    fn create() -> Result<(GpuContext, GpuEngine, Arc<AtomicBool>), HostError> {
        let gpu = GpuContext::new()?;
        let lost = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&lost);
        gpu.device.set_device_lost_callback(move |reason, message| {
            flag.store(true, Ordering::SeqCst);
            tracing::error!("GPU device lost ({reason:?}): {message}");
        });
        let engine = GpuEngine::new(&gpu.device, &gpu.queue)?;
        Ok((gpu, engine, lost))
    }

    pub fn adapter_label(&self) -> String {
        self.gpu.adapter_label()
    }

    /// The device, e.g. to simulate a loss in tests (`device().destroy()`).
    pub fn device(&self) -> &wgpu::Device {
        &self.gpu.device
    }

    pub fn is_lost(&self) -> bool {
        self.lost.load(Ordering::SeqCst)
    }

    /// Runs `job` (`with_points`: the point cloud too); when the device is lost (before or
    /// during the run) the device and engine are made anew and the job runs once more.
    pub fn process(
        &mut self,
        job: &Job,
        sweep: &SweepParams,
        with_points: bool,
    ) -> Result<FrameOutputs, Skip> {
        if !self.is_lost() {
            match process_job(&mut self.engine, job, sweep, with_points) {
                Err(skip) if skip.kind == SkipKind::Engine && self.is_lost() => {
                    tracing::warn!("{skip}");
                }
                other => return other,
            }
        }
        tracing::warn!("the GPU device was lost: recreating the device and the engine");
        let (gpu, engine, lost) = Self::create().map_err(|e| {
            Skip::new(
                SkipKind::GpuLost,
                None,
                format!("the GPU device was lost and cannot be recreated: {e}"),
            )
        })?;
        self.gpu = gpu;
        self.engine = engine;
        self.lost = lost;
        self.recreated += 1;
        tracing::info!("GPU engine recreated on {}", self.gpu.adapter_label());
        process_job(&mut self.engine, job, sweep, with_points)
    }
}
