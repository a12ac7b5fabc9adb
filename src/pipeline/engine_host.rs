//! The engine side of the pipeline ([`EngineHost`]): the CPU engine, or the WGSL engine with
//! its device, made anew when the device is lost (a driver reset, a GPU that fell off the bus,
//! `Device::destroy`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use super::outcome::{Job, Skip, SkipKind};
use super::outputs::{process_job, SetOutputs, Wanted};
use crate::engine::{Device, Engine, EngineError};
use crate::gpu_context::GpuContext;
use crate::sweep::{CancelFlag, SweepParams, WantedMaps};

/// Why no engine could be made (the device, or the engine on it).
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    #[error(transparent)]
    Engine(#[from] EngineError),
}

/// What is told each device made anew.
type NewDeviceHook = Box<dyn FnMut(&GpuContext) + Send>;

/// The engine, and for the WGSL engine whether its device was lost.
pub struct EngineHost {
    engine: Engine,
    /// Set by the device-lost callback of the WGSL engine's device (never for the CPU engine).
    lost: Arc<AtomicBool>,
    /// How many times the device was lost and the engine recreated.
    pub recreated: u64,
    /// Stops a run between passes (given to every engine made here).
    cancel: CancelFlag,
    /// Told each new device (fusion on the engine's device follows it).
    on_new_device: Option<NewDeviceHook>,
}

impl EngineHost {
    /// The engine for `device` (parameter `device`; `auto`: a hardware GPU, else the CPU engine).
    pub fn new(device: Device) -> Result<Self, HostError> {
        let mut engine = Engine::new(device)?;
        // The outputs publish neither the raw depth nor the visible cameras.
        engine.set_wanted_maps(WantedMaps::OUTPUTS);
        let lost = Self::watch(&engine);
        Ok(Self {
            engine,
            lost,
            recreated: 0,
            cancel: CancelFlag::new(),
            on_new_device: None,
        })
    }

    /// Runs stop at their next pass boundary once `cancel` is set (the job is then skipped
    /// with [`SkipKind::Engine`] and [`EngineHost::is_cancelled`] says why).
    pub fn set_cancel(&mut self, cancel: CancelFlag) {
        self.engine.set_cancel(cancel.clone());
        self.cancel = cancel;
    }

    /// `hook` gets each device made anew after a loss (the node's fusion thread, when it
    /// fuses on the engine's device, goes onto it: [`super::FuserThread::follow_device`]).
    pub fn on_new_device(&mut self, hook: impl FnMut(&GpuContext) + Send + 'static) {
        self.on_new_device = Some(Box::new(hook));
    }

    pub fn is_cancelled(&self) -> bool {
        self.cancel.is_cancelled()
    }

    /// A flag the device-lost callback sets (the WGSL engine's device only).
    fn watch(engine: &Engine) -> Arc<AtomicBool> {
        let lost = Arc::new(AtomicBool::new(false));
        if let Some(gpu) = engine.gpu() {
            let flag = Arc::clone(&lost);
            gpu.device.set_device_lost_callback(move |reason, message| {
                flag.store(true, Ordering::SeqCst);
                tracing::error!("GPU device lost ({reason:?}): {message}");
            });
        }
        lost
    }

    /// "WGSL engine on \<adapter\>" or "CPU engine (N threads)".
    pub fn adapter_label(&self) -> String {
        self.engine.label()
    }

    /// The wgpu device of the WGSL engine, e.g. to simulate a loss in tests
    /// (`device().destroy()`); None for the CPU engine.
    pub fn device(&self) -> Option<&wgpu::Device> {
        self.engine.gpu().map(|gpu| &gpu.device)
    }

    /// The WGSL engine's adapter, device and queue (e.g. for fusion on the same GPU); None
    /// for the CPU engine.
    pub fn gpu(&self) -> Option<&crate::gpu_context::GpuContext> {
        self.engine.gpu()
    }

    pub fn is_lost(&self) -> bool {
        self.lost.load(Ordering::SeqCst)
    }

    /// Runs `job` for the outputs `wanted` (the engine makes only the maps they need); when
    /// the device is lost (before or during the run) the device and engine are made anew and
    /// the job runs once more.
    pub fn process(
        &mut self,
        job: &Job,
        sweep: &SweepParams,
        wanted: Wanted,
    ) -> Result<SetOutputs, Skip> {
        if self.is_cancelled() {
            return Err(Skip::new(
                SkipKind::Engine,
                None,
                "the engine was cancelled".into(),
            ));
        }
        if !self.is_lost() {
            self.engine.set_wanted_maps(wanted.maps());
            match process_job(&mut self.engine, job, sweep, wanted) {
                Err(skip) if skip.kind == SkipKind::Engine && self.is_lost() => {
                    tracing::warn!("{skip}");
                }
                Ok(set)
                    if self.is_lost() && set.skipped.iter().any(|s| s.kind == SkipKind::Engine) =>
                {
                    for skip in &set.skipped {
                        tracing::warn!("{skip}");
                    }
                }
                other => return other,
            }
        }
        tracing::warn!("the GPU device was lost: recreating the device and the engine");
        let mut engine = GpuContext::new()
            .map_err(EngineError::from)
            .and_then(Engine::on_gpu)
            .map_err(|e| {
                Skip::new(
                    SkipKind::GpuLost,
                    None,
                    format!("the GPU device was lost and cannot be recreated: {e}"),
                )
            })?;
        self.lost = Self::watch(&engine);
        engine.set_cancel(self.cancel.clone());
        engine.set_wanted_maps(wanted.maps());
        self.engine = engine;
        self.recreated += 1;
        tracing::info!("engine recreated: {}", self.engine.label());
        if let (Some(hook), Some(gpu)) = (self.on_new_device.as_mut(), self.engine.gpu()) {
            hook(gpu);
        }
        process_job(&mut self.engine, job, sweep, wanted)
    }
}
