//! Fusion's memory soak (issue 28): a camera moving without end down a synthetic corridor (two
//! walls, a floor and a ceiling, textured in depth by posts every metre) is fused for
//! `SWEEPDEPTH_SOAK_SECONDS` (default 600) with `max_blocks` far below what the corridor needs,
//! the mesh's markers taken every few frames as the node does. Resident memory must stay flat
//! after the first minute (the last 9 minutes within 10 % + 8 MiB of the first minute's peak),
//! the grid within `max_blocks`, the markers' ids within the blocks kept.
//!
//! Ignored by `cargo test` (it runs for minutes); `sh scripts/soak.sh fusion` runs it on a
//! release build. Nothing here depends on the machine's speed: a slower machine fuses fewer
//! frames in the same time, and the check is on memory.

use std::time::{Duration, Instant};

use glam::DVec3;
use sweepdepth::fusion::FusionParams;
use sweepdepth::geometry::{CameraModel, PinholeIntrinsics, RigidTransform};
use sweepdepth::image::ImageF32;
use sweepdepth::msgs::{Marker, Time};
use sweepdepth::pipeline::{Fuser, FusionInput};

const WIDTH: u32 = 160;
const HEIGHT: u32 = 120;

fn resident_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// The depth a camera at `x` along the corridor (looking down +x, the ROS optical frame turned
/// so that z is +x) sees: walls at y = +-1.5, floor and ceiling at z = -1 / +1.5 (world), and a
/// post (a bump of 0.2 m) on each wall every metre.
fn corridor_depth(model: &CameraModel, x: f64) -> ImageF32 {
    let k = model.intrinsics;
    let mut data = Vec::with_capacity((WIDTH * HEIGHT) as usize);
    for v in 0..HEIGHT {
        for u in 0..WIDTH {
            // Ray in the optical frame (x right, y down, z forward) -> world (x forward,
            // y left, z up).
            let d_cam = DVec3::new(
                (f64::from(u) - k.cx_px) / k.fx_px,
                (f64::from(v) - k.cy_px) / k.fy_px,
                1.0,
            );
            let d = DVec3::new(d_cam.z, -d_cam.x, -d_cam.y);
            let mut t = f64::INFINITY;
            for (axis, plane) in [(1usize, 1.5), (1, -1.5), (2, 1.5), (2, -1.0)] {
                let c = d[axis];
                if c.abs() > 1e-9 {
                    let s = plane / c;
                    if s > 0.0 {
                        t = t.min(s);
                    }
                }
            }
            // Posts: the wall comes 0.2 m nearer within 0.1 m of every whole metre.
            let hit_x = x + d.x * t;
            if (hit_x - hit_x.round()).abs() < 0.1 && d.y.abs() > 1e-9 {
                let s = (1.3 * d.y.signum()) / d.y;
                if s > 0.0 {
                    t = t.min(s);
                }
            }
            // z along the optical axis = t (d_cam.z = 1).
            data.push(if t.is_finite() && t < 8.0 {
                t as f32
            } else {
                f32::NAN
            });
        }
    }
    ImageF32 {
        width: WIDTH,
        height: HEIGHT,
        data,
    }
}

#[test]
#[ignore = "a soak of minutes: sh scripts/soak.sh fusion"]
fn fusion_memory_stays_flat_on_an_endless_corridor() {
    let seconds: u64 = std::env::var("SWEEPDEPTH_SOAK_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(600);
    let max_blocks = 2_000;
    let mut fuser = Fuser::new(FusionParams {
        voxel_size_m: 0.05,
        max_blocks,
        ..FusionParams::default()
    })
    .unwrap();
    let model = CameraModel::pinhole(PinholeIntrinsics {
        width_px: WIDTH,
        height_px: HEIGHT,
        fx_px: 100.0,
        fy_px: 100.0,
        cx_px: 79.5,
        cy_px: 59.5,
    });
    // Optical frame -> world: z forward = world x, x right = world -y, y down = world -z.
    let rotation = glam::DQuat::from_mat3(&glam::DMat3::from_cols(
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(0.0, 0.0, -1.0),
        DVec3::new(1.0, 0.0, 0.0),
    ));
    let started = Instant::now();
    let mut first_minute_peak = 0u64;
    let mut later_peak = 0u64;
    let mut frames = 0u64;
    let mut live_ids = std::collections::HashSet::new();
    while started.elapsed() < Duration::from_secs(seconds) {
        let x = frames as f64 * 0.05;
        let input = FusionInput {
            stamp: Time::from_nanos(frames as i64 * 100_000_000),
            frame: "odom".into(),
            depth: corridor_depth(&model, x),
            colour: None,
            model,
            map_from_cam: RigidTransform {
                rotation,
                translation: DVec3::new(x, 0.0, 0.0),
            },
            confidence: None,
            baseline_ratio: None,
            source: "corridor".into(),
        };
        fuser.add(&input).unwrap();
        if frames.is_multiple_of(5) {
            for m in fuser.markers().markers {
                match m.action {
                    Marker::DELETE => {
                        live_ids.remove(&m.id);
                    }
                    _ => {
                        live_ids.insert(m.id);
                    }
                }
            }
        }
        let (blocks, _) = fuser.blocks();
        assert!(
            blocks <= max_blocks,
            "{blocks} blocks > max_blocks {max_blocks}"
        );
        assert!(
            live_ids.len() <= max_blocks,
            "{} markers out for at most {max_blocks} blocks",
            live_ids.len()
        );
        let rss = resident_bytes();
        if started.elapsed() < Duration::from_secs(seconds.min(60)) {
            first_minute_peak = first_minute_peak.max(rss);
        } else {
            later_peak = later_peak.max(rss);
        }
        frames += 1;
        if frames.is_multiple_of(500) {
            eprintln!(
                "{:>4.0} s: {frames} frames, {:.1} m down the corridor, {blocks} blocks, {} markers, RSS {:.1} MiB",
                started.elapsed().as_secs_f64(),
                x,
                live_ids.len(),
                rss as f64 / f64::from(1 << 20)
            );
        }
    }
    let mib = |b: u64| b as f64 / f64::from(1 << 20);
    eprintln!(
        "{frames} frames ({:.0} m) in {seconds} s: RSS peak {:.1} MiB in the first minute, {:.1} MiB after",
        frames as f64 * 0.05,
        mib(first_minute_peak),
        mib(later_peak)
    );
    assert!(
        frames as f64 * 0.05 > 10.0,
        "the camera moved only {:.1} m: the corridor did not outgrow max_blocks",
        frames as f64 * 0.05
    );
    if seconds > 60 {
        assert!(
            later_peak <= first_minute_peak + first_minute_peak / 10 + (8 << 20),
            "resident memory grew: {:.1} MiB after the first minute against {:.1} MiB in it",
            mib(later_peak),
            mib(first_minute_peak)
        );
    }
}
