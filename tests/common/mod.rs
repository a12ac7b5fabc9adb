//! Shared test helpers: one GPU context per test process, result comparison with images written
//! on failure; and, as submodules, the DDS safety guard ([`netns`]), the DDS peer side of the
//! node tests ([`dds`]), fusion's mesh service and PLY files ([`mesh`]), a Foxglove WebSocket client ([`foxglove`]), a bag player ([`player`]), the Python with the test tools ([`python`]), the rclpy peers ([`rclpy`])
//! and the shared datasets ([`shared_data`]). Each test binary uses a part of it.
#![allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]

pub mod dds;
pub mod foxglove;
pub mod mesh;
pub mod netns;
pub mod player;
pub mod python;
pub mod rclpy;
pub mod shared_data;
pub mod timeout;

use std::path::PathBuf;
use std::sync::OnceLock;

use sweepdepth::gpu_context::GpuContext;
use sweepdepth::image::ImageF32;

pub fn gpu() -> &'static GpuContext {
    static GPU: OnceLock<GpuContext> = OnceLock::new();
    GPU.get_or_init(|| match GpuContext::new() {
        Ok(ctx) => {
            eprintln!("test GPU adapter: {}", ctx.adapter_label());
            ctx
        }
        Err(e) => panic!("GPU tests need an adapter (lavapipe is fine): {e}"),
    })
}

/// Where failing tests write their images.
pub fn failure_dir(test: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("failures")
        .join(test);
    let _ = std::fs::create_dir_all(&dir);
    dir
}

/// Writes a depth image as a grey PNG (near = bright), NaN black.
pub fn save_depth_png(image: &ImageF32, path: &std::path::Path) {
    let valid: Vec<f32> = image
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let lo = valid.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = valid.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let img = image::GrayImage::from_fn(image.width, image.height, |x, y| {
        let v = image.get(x, y);
        if !v.is_finite() || hi <= lo {
            image::Luma([0])
        } else {
            image::Luma([(255.0 - 235.0 * (v - lo) / (hi - lo)) as u8])
        }
    });
    let _ = img.save(path);
}

/// Fraction of pixels valid in `estimate` whose relative error against `truth` is within `rel`.
pub fn fraction_within(estimate: &ImageF32, truth: &ImageF32, rel: f32) -> (f64, f64) {
    let mut valid = 0usize;
    let mut good = 0usize;
    for (e, t) in estimate.data.iter().zip(&truth.data) {
        if e.is_finite() && t.is_finite() {
            valid += 1;
            if ((e - t) / t).abs() <= rel {
                good += 1;
            }
        }
    }
    let n = estimate.data.len().max(1) as f64;
    (good as f64 / n, valid as f64 / n)
}
