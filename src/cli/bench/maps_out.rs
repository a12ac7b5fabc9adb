//! `bench --maps-out` (issue 56, item 3): what a reference's depth and confidence cost the
//! node's GPU thread on the WGSL engine at the `sxga` size (4 x 1280x960), from the set's
//! readback to their `32FC1` messages, both ways in one run, alternated: **copied** (the
//! engine copies them out of its readback into maps of its own, the messages are copied from
//! those: the node with fusion on, which keeps the floats) and **lent** (the messages copied
//! straight out of the mapped readback, `sweep::gpu::LentMaps`: the node without fusion). Each
//! way's figure is the engine's host ms of the set plus the messages' build.

use std::time::Instant;

use anyhow::Context;
use serde::Serialize;

use super::decode::median;
use super::messages::{CAMERAS, HEIGHT, WIDTH};
use super::BenchArgs;
use crate::engine::{Device, Engine, Sweeper};
use crate::geometry::CameraModel;
use crate::image::SetImages;
use crate::msgs::{Header, Image};
use crate::pipeline::out_messages::{f32_values_msg, lent_depth_and_confidence_msgs};
use crate::sweep::gpu::HostCopies;
use crate::sweep::references::ReferenceMaps;
use crate::sweep::{SweepParams, WantedMaps};
use crate::synthetic::{self, Scene};

#[derive(Debug, Serialize)]
pub struct MapsOutResult {
    pub maps_out: &'static str,
    pub engine: String,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    /// Median ms per set: the engine's host ms plus the messages, the maps copied out first.
    pub copied_ms: f64,
    /// The same with the maps lent out of the readback.
    pub lent_ms: f64,
    /// Of those, the messages' build alone (medians).
    pub copied_messages_ms: f64,
    pub lent_messages_ms: f64,
    /// `--host-copies`: the engine's copies and the messages' (auto: split on a host of 8+
    /// threads).
    pub host_copies: String,
    pub runs: usize,
}

/// Runs the line and prints it (text, or one JSON object with `--json`).
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let repeats = if args.quick { 3 } else { args.repeats.max(1) };
    let mut engine = Engine::new(Device::Gpu).context("--maps-out needs the WGSL engine")?;
    let result = measure(&mut engine, repeats, args.gpu.host_copies)?;
    if args.json {
        println!("{}", serde_json::to_string(&result)?);
        return Ok(());
    }
    println!(
        "maps out: {} x {}x{} on {}: readback to depth and confidence 32FC1 messages {:.2} ms \
         per set copied out first (messages {:.2}), {:.2} ms lent (messages {:.2}) \
         (engine host ms + messages, medians of {}, alternated; host copies {})",
        result.cameras,
        result.width,
        result.height,
        result.engine,
        result.copied_ms,
        result.copied_messages_ms,
        result.lent_ms,
        result.lent_messages_ms,
        result.runs,
        result.host_copies
    );
    Ok(())
}

/// One set of each way per run (after one of each untimed), `runs` runs.
pub fn measure(
    engine: &mut Engine,
    runs: usize,
    copies: HostCopies,
) -> anyhow::Result<MapsOutResult> {
    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, CAMERAS / 2)?;
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    // The host's work does not depend on the planes: few, so that lavapipe runs it in seconds.
    let params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: 8,
        ..SweepParams::default()
    };
    let header = Header::default();
    let f32_image_with = |image: &crate::image::ImageF32| {
        f32_values_msg(&header, (image.width, image.height), &image.data, copies)
    };
    engine.set_host_copies(copies);
    let one = |engine: &mut Engine, lend: bool| -> anyhow::Result<(f64, f64, Vec<Image>)> {
        engine.set_wanted_maps(WantedMaps {
            cost: false,
            selection: false,
            diagnostics: false,
            floats: !lend,
        });
        engine.take_gpu_counts();
        // As the node's GPU thread runs a set: started (submitted), then finished.
        let set = SetImages::All(&images);
        let started = engine.start_references_set(&rig.cameras, set, &[CAMERAS / 2], &params);
        let results = engine.finish_references_set(started, set, &params);
        let host_ms = engine.take_gpu_counts().map_or(0.0, |c| c.host_ms);
        let started = Instant::now();
        let mut messages = Vec::new();
        for result in results {
            let (depth, confidence) = match result?.maps {
                ReferenceMaps::Lent(maps) if lend => {
                    lent_depth_and_confidence_msgs(&header, &maps, copies)
                }
                ReferenceMaps::Owned(maps) if !lend => rayon::join(
                    || f32_image_with(&maps.depth_m),
                    || f32_image_with(&maps.confidence),
                ),
                _ => anyhow::bail!("the engine did not hand the maps out as asked (lent: {lend})"),
            };
            messages.extend([depth, confidence]);
        }
        let messages_ms = started.elapsed().as_secs_f64() * 1e3;
        Ok((host_ms + messages_ms, messages_ms, messages))
    };
    let (_, _, copied) = one(engine, false)?;
    let (_, _, lent) = one(engine, true)?;
    anyhow::ensure!(
        copied.len() == 2 && copied == lent,
        "the lent maps' messages differ from the copied maps'"
    );
    let (mut copied_ms, mut lent_ms) = (Vec::new(), Vec::new());
    let (mut copied_msgs, mut lent_msgs) = (Vec::new(), Vec::new());
    for run in 0..runs.max(1) {
        for lend in [run % 2 == 1, run % 2 == 0] {
            let (ms, messages_ms, _) = one(engine, lend)?;
            let (all, msgs) = match lend {
                true => (&mut lent_ms, &mut lent_msgs),
                false => (&mut copied_ms, &mut copied_msgs),
            };
            all.push(ms);
            msgs.push(messages_ms);
        }
    }
    let round3 = |v: f64| (v * 1000.0).round() / 1000.0;
    Ok(MapsOutResult {
        maps_out: "readback to 32FC1",
        engine: engine.label(),
        cameras: CAMERAS,
        width: WIDTH,
        height: HEIGHT,
        copied_ms: round3(median(copied_ms)),
        lent_ms: round3(median(lent_ms)),
        copied_messages_ms: round3(median(copied_msgs)),
        lent_messages_ms: round3(median(lent_msgs)),
        host_copies: format!("{copies:?}").to_lowercase(),
        runs: runs.max(1),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On lavapipe: both ways make the same messages (`measure` checks them) and each is timed.
    #[test]
    fn the_maps_out_line_times_both_ways_with_the_same_messages() {
        let mut engine = Engine::new(Device::Gpu).expect("an adapter (lavapipe is fine)");
        let result = measure(&mut engine, 1, HostCopies::Parallel).expect("runs");
        assert_eq!((result.width, result.height), (1280, 960));
        assert!(result.copied_ms > 0.0 && result.lent_ms > 0.0, "{result:?}");
        assert!(result.lent_messages_ms > 0.0 && result.copied_messages_ms > 0.0);
    }
}
