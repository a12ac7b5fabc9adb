//! `bench`'s decode line (issue 31): what decoding a 9-camera 640x480 JPEG set costs beside the
//! sweep. The set is the synthetic 9-camera row's images at 640x480, each compressed as
//! image_transport's compressed plugin does (`compress`: JPEG quality 95, `rgb8; jpeg compressed
//! bgr8`) and decoded as the pipeline decodes a complete set (`decode_set`: in parallel across
//! cameras on rayon's pool, on the thread that pushes inputs, not the engine's); also one image
//! alone on one thread.

use std::time::Instant;

use serde::Serialize;

use crate::geometry::CameraModel;
use crate::image::Rgba8Image;
use crate::msgs::{CompressedImage, Header, Image};
use crate::pipeline::compressed::{self, Codec};
use crate::pipeline::InputImage;
use crate::ros::sync::SyncedSet;
use crate::synthetic::{self, Scene};

pub const CAMERAS: usize = 9;
pub const WIDTH: u32 = 640;
pub const HEIGHT: u32 = 480;
pub const JPEG_QUALITY: u8 = 95;

#[derive(Debug, Serialize)]
pub struct DecodeResult {
    pub decode: &'static str,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    pub jpeg_quality: u8,
    /// The set's compressed size.
    pub bytes_per_set: usize,
    /// Median ms to decode the whole set as the pipeline does (in parallel across cameras).
    pub set_ms: f64,
    /// Median ms to decode one image on one thread.
    pub image_ms: f64,
    /// rayon's threads (the set's decoding runs on them).
    pub threads: usize,
    pub runs: usize,
}

pub(super) fn rgb8(image: &Rgba8Image) -> Image {
    let mut data = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        let [r, g, b, _] = Rgba8Image::unpack(p);
        data.extend_from_slice(&[r, g, b]);
    }
    Image {
        header: Header::default(),
        height: image.height,
        width: image.width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: image.width * 3,
        data,
    }
}

pub(super) fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(|a, b| a.total_cmp(b));
    values[values.len() / 2]
}

/// Compresses the set once, then times `repeats` decodings of it (after one warm-up).
pub fn run(repeats: usize) -> anyhow::Result<DecodeResult> {
    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, CAMERAS / 2)?;
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let carried: Vec<CompressedImage> = synthetic::render_rig(&scene, &rig)
        .iter()
        .map(|image| compressed::compress(&rgb8(image), Codec::Jpeg, JPEG_QUALITY))
        .collect::<Result<_, _>>()?;
    let bytes_per_set = carried.iter().map(|m| m.data.len()).sum();
    let names: Vec<String> = (0..CAMERAS).map(|i| format!("cam{i}")).collect();
    let decode_set = || -> anyhow::Result<()> {
        let set = SyncedSet {
            stamps_ns: vec![0; CAMERAS],
            messages: carried
                .iter()
                .cloned()
                .map(InputImage::Compressed)
                .collect(),
        };
        let decoded = compressed::decode_set(set, |k| (k, names[k].as_str()))
            .map_err(|skip| anyhow::anyhow!("decoding the bench's set: {}", skip.message))?;
        anyhow::ensure!(decoded.messages.iter().all(|m| m.width == WIDTH));
        Ok(())
    };
    decode_set()?;
    let runs = repeats.max(1);
    let mut set_ms = Vec::with_capacity(runs);
    let mut image_ms = Vec::with_capacity(runs);
    for _ in 0..runs {
        let started = Instant::now();
        decode_set()?;
        set_ms.push(started.elapsed().as_secs_f64() * 1e3);
        let started = Instant::now();
        compressed::decode("cam0", &carried[0])?;
        image_ms.push(started.elapsed().as_secs_f64() * 1e3);
    }
    let round3 = |v: f64| (v * 1000.0).round() / 1000.0;
    Ok(DecodeResult {
        decode: "jpeg",
        cameras: CAMERAS,
        width: WIDTH,
        height: HEIGHT,
        jpeg_quality: JPEG_QUALITY,
        bytes_per_set,
        set_ms: round3(median(set_ms)),
        image_ms: round3(median(image_ms)),
        threads: rayon::current_num_threads(),
        runs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_the_nine_camera_set() {
        let result = run(1).unwrap();
        assert_eq!((result.cameras, result.width, result.height), (9, 640, 480));
        // Nine JPEGs of the textured scene: far smaller than the raw 9 x 640 x 480 x 3 bytes.
        assert!(result.bytes_per_set > 9 * 10_000, "{result:?}");
        assert!(result.bytes_per_set < 9 * 640 * 480 * 3, "{result:?}");
        assert!(result.set_ms > 0.0 && result.image_ms > 0.0, "{result:?}");
        assert!(result.threads >= 1);
    }
}
