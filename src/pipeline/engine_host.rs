//! The engine side of the pipeline ([`EngineHost`]): the CPU engine, or the WGSL engine with
//! its device, made anew when the device is lost (a driver reset, a GPU that fell off the bus,
//! `Device::destroy`).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use super::outcome::{Job, Skip, SkipKind};
use super::outputs::{finish_job, process_job, start_job, SetOutputs, StartedJob, Wanted};
use crate::engine::{Device, Engine, EngineError, Sweeper};
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
    /// Jobs started and not finished, oldest first ([`EngineHost::start`]).
    in_flight: VecDeque<InFlight>,
    /// Whether the outputs' depth and confidence maps are kept as floats
    /// ([`EngineHost::set_keep_floats`]).
    keep_floats: bool,
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
            in_flight: VecDeque::new(),
            keep_floats: true,
        })
    }

    /// Whether the caller reads the outputs' depth and confidence as floats
    /// ([`super::FrameMaps`]: fusion does), the default. Without, the WGSL engine lends them
    /// out of its readback buffer to make their messages from, and the outputs' maps are left
    /// empty (the node without fusion: one copy of both maps fewer per reference).
    pub fn set_keep_floats(&mut self, keep: bool) {
        self.keep_floats = keep;
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

    /// The WGSL engine's submissions, readbacks, waits and sets in flight since the last
    /// call (`None` for the CPU engine).
    pub fn take_gpu_counts(&mut self) -> Option<crate::sweep::gpu::SetCounts> {
        self.engine.take_gpu_counts()
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
            return Err(cancelled());
        }
        if !self.is_lost() {
            self.engine.set_wanted_maps(wanted.maps(self.keep_floats));
            let result = process_job(&mut self.engine, job, sweep, wanted);
            if !self.lost_in(&result) {
                return result;
            }
        }
        self.recreate(wanted)?;
        process_job(&mut self.engine, job, sweep, wanted)
    }

    /// Whether [`EngineHost::start`] leaves the job's work on the device (the WGSL engine):
    /// the caller may then start the next job before it finishes this one, and the device
    /// runs one while the host reads the other back and makes its messages. Otherwise
    /// `start` runs the job to the end.
    pub fn starts_without_waiting(&self) -> bool {
        !self.is_lost() && self.engine.starts_without_waiting()
    }

    /// Whether [`EngineHost::finish`] would find the oldest job's work done on the device (no
    /// wait for it); true with none in flight.
    pub fn oldest_done(&self) -> bool {
        self.in_flight.is_empty() || self.is_lost() || self.engine.oldest_done()
    }

    /// Jobs started and not finished.
    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Starts `job` ([`EngineHost::process`] up to its submission to the device); its
    /// outputs come with [`EngineHost::finish`], in the order the jobs started.
    pub fn start(&mut self, job: Job, sweep: &SweepParams, wanted: Wanted) {
        self.start_since(job, sweep, wanted, Instant::now());
    }

    fn start_since(&mut self, job: Job, sweep: &SweepParams, wanted: Wanted, since: Instant) {
        let started = if self.is_cancelled() {
            StartedJob::done(Err(cancelled()))
        } else if self.is_lost() {
            StartedJob::done(
                self.recreate(wanted)
                    .and_then(|()| process_job(&mut self.engine, &job, sweep, wanted)),
            )
        } else {
            self.engine.set_wanted_maps(wanted.maps(self.keep_floats));
            start_job(&mut self.engine, &job, sweep, wanted)
        };
        self.in_flight.push_back(InFlight {
            job,
            sweep: sweep.clone(),
            wanted,
            started,
            since,
        });
    }

    /// The oldest job started and not finished, with its outputs (None: no job in flight).
    /// When the device was lost under it, the device and engine are made anew, the job runs
    /// once more, and the jobs started after it are started again on the new device.
    pub fn finish(&mut self) -> Option<Finished> {
        let InFlight {
            job,
            sweep,
            wanted,
            started,
            since,
        } = self.in_flight.pop_front()?;
        let mut result = finish_job(&mut self.engine, started, &job, &sweep, wanted);
        if self.lost_in(&result) {
            result = self.process(&job, &sweep, wanted);
            let later: Vec<InFlight> = self.in_flight.drain(..).collect();
            for f in later {
                self.start_since(f.job, &f.sweep, f.wanted, f.since);
            }
        }
        Some(Finished { job, result, since })
    }

    /// Whether `result` failed for a device lost under it (the failures logged).
    fn lost_in(&self, result: &Result<SetOutputs, Skip>) -> bool {
        let failed = match result {
            Err(skip) => skip.kind == SkipKind::Engine,
            Ok(set) => set.skipped.iter().any(|s| s.kind == SkipKind::Engine),
        };
        if !failed {
            return false;
        }
        // A destroyed device says it is lost at the first poll that finds its queue empty (a
        // later set may still be on it): waited for, a few seconds at most.
        if let (false, Some(gpu)) = (self.is_lost(), self.engine.gpu()) {
            let deadline = Instant::now() + std::time::Duration::from_secs(10);
            let _ = crate::gpu_context::wait_for_device(&gpu.device, || {
                if Instant::now() < deadline {
                    Ok(())
                } else {
                    Err(())
                }
            });
        }
        if !self.is_lost() {
            return false;
        }
        match result {
            Err(skip) if skip.kind == SkipKind::Engine => {
                tracing::warn!("{skip}");
                true
            }
            Ok(set) if set.skipped.iter().any(|s| s.kind == SkipKind::Engine) => {
                for skip in &set.skipped {
                    tracing::warn!("{skip}");
                }
                true
            }
            _ => false,
        }
    }

    /// A new device and engine after a loss (told to `on_new_device`).
    fn recreate(&mut self, wanted: Wanted) -> Result<(), Skip> {
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
        engine.set_wanted_maps(wanted.maps(self.keep_floats));
        self.engine = engine;
        self.recreated += 1;
        tracing::info!("engine recreated: {}", self.engine.label());
        if let (Some(hook), Some(gpu)) = (self.on_new_device.as_mut(), self.engine.gpu()) {
            hook(gpu);
        }
        Ok(())
    }
}

/// A job that was cancelled.
fn cancelled() -> Skip {
    Skip::new(SkipKind::Engine, None, "the engine was cancelled".into())
}

/// A job started by [`EngineHost::start`] and not finished.
struct InFlight {
    job: Job,
    sweep: SweepParams,
    wanted: Wanted,
    started: StartedJob,
    since: Instant,
}

/// A job [`EngineHost::finish`] finished: the job, its outputs (or why none), and when it
/// started.
pub struct Finished {
    pub job: Job,
    pub result: Result<SetOutputs, Skip>,
    pub since: Instant,
}
