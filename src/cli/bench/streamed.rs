//! `bench --sets-ahead N`: the timed sets back to back, N of them left on the WGSL engine's
//! device while the one before is read back, as `bag` runs a recording and the node's GPU
//! thread runs sets that queue up: the wall time per set of such a stream, where the host's
//! share of a set runs beside the device's work on the next.

use std::collections::VecDeque;
use std::time::Instant;

use crate::engine::{Engine, StartedSet, Sweeper};
use crate::geometry::Rig;
use crate::image::{Rgba8Image, SetImages};
use crate::sweep::{SweepError, SweepParams};

/// A stream's timings: the wall ms per set, each set's stage timings, and the engine's counts
/// over the stream.
pub(super) struct Stream {
    pub ms_per_set: f64,
    pub stages: Vec<Vec<(String, f64)>>,
    pub counts: Option<crate::sweep::gpu::SetCounts>,
}

/// `repeats` sets of `references` (none: the rig's camera reference) run back to back with
/// `ahead` sets left in flight; None where the engine runs each set to the end when it starts
/// it (the CPU engine) or the rig's reference is virtual (one sweep, nothing to start).
pub(super) fn run_stream(
    engine: &mut Engine,
    rig: &Rig,
    images: &[Rgba8Image],
    params: &SweepParams,
    references: &[usize],
    repeats: usize,
    ahead: usize,
) -> Result<Option<Stream>, SweepError> {
    let references: Vec<usize> = match references {
        [] => rig.reference_index().into_iter().collect(),
        some => some.to_vec(),
    };
    if references.is_empty() || !engine.starts_without_waiting() {
        return Ok(None);
    }
    let set = SetImages::All(images);
    let mut stages = Vec::with_capacity(repeats);
    let mut finish = |engine: &mut Engine, started: StartedSet| -> Result<(), SweepError> {
        for result in engine.finish_references_set(started, set, params) {
            result?;
        }
        stages.push(engine.last_timings().stages.clone());
        Ok(())
    };
    engine.take_gpu_counts();
    let started_at = Instant::now();
    let mut in_flight = VecDeque::new();
    for _ in 0..repeats.max(1) {
        in_flight.push_back(engine.start_references_set(&rig.cameras, set, &references, params));
        while in_flight.len() > ahead {
            if let Some(oldest) = in_flight.pop_front() {
                finish(engine, oldest)?;
            }
        }
    }
    while let Some(oldest) = in_flight.pop_front() {
        finish(engine, oldest)?;
    }
    let ms_per_set = started_at.elapsed().as_secs_f64() * 1e3 / repeats.max(1) as f64;
    Ok(Some(Stream {
        ms_per_set,
        stages,
        counts: engine.take_gpu_counts(),
    }))
}

/// A stream's counts over `sets` sets as one set's (the most in flight and the staging buffers
/// made as they are).
pub(super) fn per_set(
    mut counts: crate::sweep::gpu::SetCounts,
    sets: usize,
) -> crate::sweep::gpu::SetCounts {
    let n = u32::try_from(sets.max(1)).unwrap_or(u32::MAX);
    counts.levels /= n;
    counts.submissions /= n;
    counts.sgm_dispatches /= n;
    counts.sweep_dispatches /= n;
    counts.readbacks /= n;
    counts.waits /= n;
    counts.readback_bytes /= u64::from(n);
    counts.image_bytes /= u64::from(n);
    counts.host_ms /= f64::from(n);
    counts.wait_ms /= f64::from(n);
    counts.submit_ms /= f64::from(n);
    counts
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::Device;
    use crate::geometry::CameraModel;
    use crate::synthetic::{self, Scene};

    /// On the WGSL engine (lavapipe is fine) a stream keeps `ahead` sets on the device besides
    /// the one it starts, and gives each set's timings; the CPU engine, which runs a set when it
    /// starts it, has no stream.
    #[test]
    fn a_stream_keeps_sets_on_the_device_and_the_cpu_engine_has_none() {
        let model = CameraModel::pinhole(synthetic::intrinsics(96, 64));
        let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
        let scene = Scene::wall_and_box(3.0, Some((1.5, 0.3)), model.intrinsics.fx_px);
        let images = synthetic::render_rig(&scene, &rig);
        let params = SweepParams {
            min_depth_m: 1.0,
            max_depth_m: 8.0,
            num_planes: 8,
            ..SweepParams::default()
        };
        let mut cpu = Engine::new(Device::Cpu).expect("CPU engine");
        let none = run_stream(&mut cpu, &rig, &images, &params, &[], 3, 1).expect("runs");
        assert!(none.is_none());
        let mut gpu = Engine::new(Device::Gpu).expect("an adapter (lavapipe is fine)");
        for (ahead, most) in [(1, 2), (2, 3), (0, 1)] {
            let stream = run_stream(&mut gpu, &rig, &images, &params, &[], 4, ahead)
                .expect("runs")
                .expect("a stream");
            let counts = stream.counts.expect("the WGSL engine's counts");
            assert_eq!(counts.most_in_flight, most, "ahead {ahead}: {counts:?}");
            assert_eq!((counts.submissions, counts.waits), (4, 4));
            assert_eq!(stream.stages.len(), 4);
            assert!(stream.ms_per_set > 0.0);
            let per_set = per_set(counts, 4);
            assert_eq!((per_set.submissions, per_set.most_in_flight), (1, most));
        }
    }
}
