//! Overload soak of `sweepdepth node` (a benchmark run by `scripts/soak.sh [MINUTES]`, ignored by
//! `cargo test`): a synthetic 4-camera rig published faster than the GPU can go, while the
//! node's resident memory is sampled. It fails if the node dies, if it published nothing, or
//! everything, or dropped nothing at the GPU by its own count (then it was not overloaded and
//! the run shows nothing), if its memory cannot be read, or if its memory grows by more than
//! 10 % after the warm-up.
//!
//! DDS only inside a private network namespace (tests/common/netns.rs). Phases:
//! 1. calibration: 20 s at 30 Hz; the node's output rate is the sustainable rate S;
//! 2. soak: MINUTES at 2 S, the node's VmRSS sampled every MINUTES * 2 s (10 s at most, 1 s
//!    at least); the samples of the first fifth of the run (the first minute at most) are the
//!    warm-up; of the others, the highest of the last third may exceed the highest of the first
//!    third by 10 % at most. Short runs check memory too, on a shorter scale.
//!    Prints one line per sample and a summary (RSS first / last / max, inputs, outputs).

use std::time::{Duration, Instant};

use crate::common::dds::{self, Diagnostics, NodeProcess, Peer, RigFeed};
use crate::common::netns;
use sweepdepth::geometry::CameraModel;
use sweepdepth::msgs::{Image, Time};
use sweepdepth::synthetic::{self, Scene};

const DOMAIN: u16 = 47;
const CAMERAS: usize = 4;
const WIDTH: u32 = 320;
const HEIGHT: u32 = 240;
const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";

/// `SWEEPDEPTH_SOAK_MINUTES` (default 10).
#[test]
#[ignore = "a 10-minute benchmark: scripts/soak.sh"]
fn soak() {
    netns::in_private_netns(INNER, "soak::soak", run);
}

/// The resident memory of process `pid` in KiB; panics when it cannot be read (a soak that
/// cannot see memory checks nothing).
fn rss_kib(pid: u32) -> u64 {
    let path = format!("/proc/{pid}/status");
    let status =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("soak: cannot read {path}: {e}"));
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|line| line.split_whitespace().nth(1)?.parse().ok())
        .unwrap_or_else(|| panic!("soak: no VmRSS in {path}:\n{status}"))
}

fn stamp(frame: u64) -> Time {
    dds::time_of_ns(1_000_000_000_000 + frame * 1_000_000)
}

fn run() {
    let minutes: f64 = std::env::var("SWEEPDEPTH_SOAK_MINUTES")
        .ok()
        .and_then(|a| a.parse().ok())
        .unwrap_or(10.0);
    assert!(minutes > 0.0, "SWEEPDEPTH_SOAK_MINUTES must be positive");
    let soak_for = Duration::from_secs_f64(minutes * 60.0);
    let sample_every = (soak_for / 30).clamp(Duration::from_secs(1), Duration::from_secs(10));
    let warm_up = (soak_for / 5).min(Duration::from_secs(60));
    let mut command = dds::node_command(
        DOMAIN,
        &[
            "-p",
            "cameras:=[cam0, cam1, cam2, cam3]",
            "-p",
            "reference_camera:=cam1",
            "-p",
            "min_depth:=1.0",
            "-p",
            "max_depth:=4.0",
            "-p",
            "num_planes:=32",
            "-p",
            "sync:=exact",
        ],
    );
    command.env("RUST_LOG", "warn,rustdds=error");
    let mut node = NodeProcess::spawn(command);
    let pid = node.pid();

    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(2.0, Some((1.2, 0.3)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_soak");
    let feed = RigFeed::new(&mut peer, rig, &images, &dds::best_effort(2), None);
    let depth_sub = peer.subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(5));
    let mut diagnostics = Diagnostics::new(&mut peer);
    let publish = |frame: u64| feed.publish_set(&[stamp(frame); CAMERAS]);
    let drain = || dds::take_all(&depth_sub).len() as u64;

    // Phase 1: calibration at 30 Hz (the first 5 s are warm-up and not counted).
    let mut frame: u64 = 0;
    let started = Instant::now();
    let mut outputs = 0u64;
    let mut counted_from = None;
    while started.elapsed() < Duration::from_secs(25) {
        node.check_alive();
        publish(frame);
        frame += 1;
        let got = drain();
        if started.elapsed() >= Duration::from_secs(5) {
            counted_from.get_or_insert(Instant::now());
            outputs += got;
        }
        std::thread::sleep(Duration::from_millis(33));
    }
    let t0 = counted_from.unwrap_or(started);
    let sustainable = outputs as f64 / t0.elapsed().as_secs_f64();
    let rate = (2.0 * sustainable).max(1.0);
    println!("soak: sustainable {sustainable:.2} sets/s at 4 x {WIDTH}x{HEIGHT}, 32 planes; soaking at {rate:.2} sets/s for {minutes} min (memory every {sample_every:?}, warm-up {warm_up:?})");

    // Phase 2: soak at twice the sustainable rate.
    let period = Duration::from_secs_f64(1.0 / rate);
    let soak_start = Instant::now();
    let mut next_sample = soak_start;
    let (mut sent, mut received) = (0u64, 0u64);
    let mut samples: Vec<(Duration, u64)> = Vec::new();
    let mut next_frame = soak_start;
    // The node's first /diagnostics of the soak phase: the counters it starts from (those of
    // the calibration are discarded).
    diagnostics.take();
    let mut soak_start_status = None;
    while soak_start.elapsed() < soak_for {
        node.check_alive();
        let now = Instant::now();
        if now >= next_frame {
            publish(frame);
            frame += 1;
            sent += 1;
            next_frame += period;
        }
        received += drain();
        for status in diagnostics.take() {
            soak_start_status.get_or_insert(status);
        }
        if now >= next_sample {
            let rss = rss_kib(pid);
            let t = soak_start.elapsed();
            samples.push((t, rss));
            println!(
                "t={:>5.0} s  rss={rss:>7} KiB  sent={sent} received={received}",
                t.as_secs_f64()
            );
            next_sample += sample_every;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    node.check_alive();
    // The node's own count of the sets it dropped because the GPU was busy, during the soak.
    let status = diagnostics.wait_after(dds::wall_time_now(), &mut node);
    let start_status = soak_start_status.expect("a /diagnostics status during the soak");
    let gpu_dropped =
        dds::counter(&status, "gpu sets dropped") - dds::counter(&start_status, "gpu sets dropped");
    drop(node);
    let rss: Vec<u64> = samples.iter().map(|(_, r)| *r).collect();
    let first = rss.first().copied().unwrap_or(0);
    let last = rss.last().copied().unwrap_or(0);
    let max = rss.iter().copied().max().unwrap_or(0);
    let settled: Vec<u64> = samples
        .iter()
        .filter(|(t, _)| *t >= warm_up)
        .map(|(_, r)| *r)
        .collect();
    let (smin, smax) = (
        settled.iter().copied().min().unwrap_or(0),
        settled.iter().copied().max().unwrap_or(0),
    );
    // Growth: the highest RSS of the last third of the settled samples against the highest of
    // the first third (memory handed back is no growth).
    let third = settled.len() / 3;
    let early = settled[..third].iter().copied().max().unwrap_or(0);
    let late = settled[settled.len() - third..]
        .iter()
        .copied()
        .max()
        .unwrap_or(0);
    println!(
        "soak summary: {minutes} min at {rate:.2} sets/s (2 x sustainable {sustainable:.2}); sent {sent} sets, received {received} depth images ({:.0} % dropped; the node counts {gpu_dropped} dropped at the GPU); RSS first {first} KiB, last {last} KiB, max {max} KiB; after the warm-up ({} samples) {smin}..{smax} KiB",
        100.0 * (1.0 - received as f64 / sent.max(1) as f64),
        settled.len()
    );
    assert!(
        received > 0,
        "soak: the node published no depth image while {sent} sets were sent"
    );
    assert!(
        received < sent && gpu_dropped > 0,
        "soak: {received} depth images for {sent} sets, {gpu_dropped} dropped at the GPU: the node was not overloaded and the run shows nothing about overload (did the machine get much faster after the calibration?)"
    );
    assert!(
        third >= 2,
        "soak: only {} memory samples after the warm-up",
        settled.len()
    );
    assert!(
        (late as f64) <= 1.10 * early as f64,
        "memory grew after the warm-up: at most {early} KiB in the first third of the samples, {late} KiB in the last"
    );
}
