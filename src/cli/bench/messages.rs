//! `bench`'s messages line (issue 56, item 3): the host work the node does on its GPU thread
//! for every set besides the engine's own, at the `sxga` size (4 x 1280x960). In: the set's
//! `rgb8` image messages into the engine's images (`convert::set_to_rgba8`, as the node's
//! `process_job` does: the cameras in parallel on rayon's threads). Out: the reference's depth
//! and confidence as `32FC1` messages (`depth_and_confidence_msgs`, every set). The WGSL engine's own host
//! time is the table's `host ms`. (For the WGSL engine, which unpacks the messages' bytes on
//! the device, the node converts only the references' colour, beside the sweep: this line's
//! conversion is the CPU engine's case.)

use std::time::Instant;

use serde::Serialize;

use super::decode::{median, rgb8};
use crate::geometry::CameraModel;
use crate::image::ImageF32;
use crate::msgs::{Header, Image};
use crate::pipeline::convert::set_to_rgba8;
use crate::pipeline::out_messages::depth_and_confidence_msgs;
use crate::synthetic::{self, Scene};

pub const CAMERAS: usize = 4;
pub const WIDTH: u32 = 1280;
pub const HEIGHT: u32 = 960;

#[derive(Debug, Serialize)]
pub struct MessagesResult {
    pub messages: &'static str,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    /// Median ms to convert the set's `rgb8` messages into the engine's images.
    pub images_in_ms: f64,
    /// Median ms to build the depth and confidence messages of one reference.
    pub maps_out_ms: f64,
    /// rayon's threads (the conversion runs on them).
    pub threads: usize,
    pub runs: usize,
}

/// Renders the set once, then times `repeats` conversions and message builds (after one
/// warm-up, as a live node's memory is warm).
pub fn run(repeats: usize) -> anyhow::Result<MessagesResult> {
    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, CAMERAS / 2)?;
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let rendered = synthetic::render_rig(&scene, &rig);
    let messages: Vec<Image> = rendered.iter().map(rgb8).collect();
    let names: Vec<String> = (0..CAMERAS).map(|i| format!("cam{i}")).collect();
    let map = |v: f32| ImageF32 {
        width: WIDTH,
        height: HEIGHT,
        data: vec![v; (WIDTH * HEIGHT) as usize],
    };
    let (depth, confidence) = (map(2.5), map(0.75));
    let header = Header::default();
    let images_in = || -> anyhow::Result<()> {
        let images = set_to_rgba8(&messages, |i| names[i].as_str())?;
        anyhow::ensure!(
            images
                .iter()
                .zip(&rendered)
                .all(|(a, b)| a.pixels == b.pixels),
            "the converted images differ from the rendered ones"
        );
        Ok(())
    };
    let maps_out = || -> usize {
        let (depth, confidence) = depth_and_confidence_msgs(&header, &depth, &confidence);
        depth.data.len() + confidence.data.len()
    };
    images_in()?;
    anyhow::ensure!(maps_out() == 2 * 4 * (WIDTH * HEIGHT) as usize);
    let runs = repeats.max(1);
    let (mut in_ms, mut out_ms) = (Vec::with_capacity(runs), Vec::with_capacity(runs));
    for _ in 0..runs {
        let started = Instant::now();
        let images = set_to_rgba8(&messages, |i| names[i].as_str())?;
        in_ms.push(started.elapsed().as_secs_f64() * 1e3);
        drop(images);
        let started = Instant::now();
        std::hint::black_box(maps_out());
        out_ms.push(started.elapsed().as_secs_f64() * 1e3);
    }
    let round3 = |v: f64| (v * 1000.0).round() / 1000.0;
    Ok(MessagesResult {
        messages: "rgb8 in, 32FC1 out",
        cameras: CAMERAS,
        width: WIDTH,
        height: HEIGHT,
        images_in_ms: round3(median(in_ms)),
        maps_out_ms: round3(median(out_ms)),
        threads: rayon::current_num_threads(),
        runs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converts_and_builds_the_megapixel_set() {
        // `run` itself checks the converted images against the rendered ones and the
        // messages' sizes; a conversion that changed a pixel fails it.
        let result = run(1).unwrap();
        assert_eq!(
            (result.cameras, result.width, result.height),
            (4, 1280, 960)
        );
        assert!(
            result.images_in_ms > 0.0 && result.maps_out_ms > 0.0,
            "{result:?}"
        );
        assert!(result.threads >= 1);
    }
}
