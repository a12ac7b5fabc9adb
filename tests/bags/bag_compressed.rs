//! Compressed images in bags, as people record them: `sweepdepth pack --compressed` (JPEG of
//! quality 95 on `/camN/image_raw/compressed`, as image_transport's compressed plugin) of the
//! Tsukuba fixture's dataset, run through `sweepdepth bag`, gives the raw bag's depth within
//! JPEG's noise; so does a compressed bag written independently, by the Python tools (OpenCV's
//! `imencode` as image_transport's compressed plugin, rosbags' writer:
//! `tools/rosbags_compress.py`); a recorded bag with other topics beside the cameras (IMU, logs)
//! and a corrupt JPEG is processed, the other topics named once and the bad set counted by its
//! reason.

use super::util::{messages, ok, root, scratch, sweepdepth};
use crate::common::python;

use std::path::Path;
use std::process::{Command, Stdio};

use sweepdepth::bag::{BagMessage, BagWriter};
use sweepdepth::msgs::{from_cdr, to_cdr, CompressedImage, Image};

fn run_bag(input: &Path, output: &Path) -> String {
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    ok(
        &sweepdepth(&[
            "bag",
            input.to_str().unwrap(),
            output.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
        ]),
        "sweepdepth bag",
    )
}

/// `bag --mesh` on `input`: the mesh's mean vertex colour (R, G, B).
fn mesh_mean_colour(input: &Path, output: &Path, mesh: &Path) -> [f64; 3] {
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    ok(
        &sweepdepth(&[
            "bag",
            input.to_str().unwrap(),
            output.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
            "--mesh",
            mesh.to_str().unwrap(),
        ]),
        "sweepdepth bag --mesh",
    );
    let colours = crate::common::mesh::ply_colours(&std::fs::read(mesh).expect("the PLY"));
    assert!(colours.len() > 1000, "{} vertices", colours.len());
    let mut sum = [0.0f64; 3];
    for colour in &colours {
        for (total, &c) in sum.iter_mut().zip(colour) {
            *total += f64::from(c);
        }
    }
    sum.map(|total| total / colours.len() as f64)
}

/// The depth (metres) of every `/depth/image` message, in order.
fn depths(path: &Path) -> Vec<Vec<f32>> {
    messages(path)
        .into_iter()
        .filter(|m| m.topic == "/depth/image")
        .map(|m| {
            let image: Image = from_cdr(&m.data).expect("decode depth");
            image
                .data
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect()
        })
        .collect()
}

/// Packs the built-in Tsukuba as the committed fixture (half size, 3 sets), compressed.
fn pack_compressed(out: &Path) {
    let stderr = ok(
        &sweepdepth(&[
            "pack",
            root().join("data/tsukuba").to_str().unwrap(),
            out.to_str().unwrap(),
            "--frames",
            "3",
            "--scale",
            "0.5",
            "--compressed",
        ]),
        "sweepdepth pack --compressed",
    );
    assert!(stderr.contains("5 cameras"), "{stderr}");
}

#[test]
fn compressed_bag_gives_the_raw_bags_depth_within_jpeg_noise() {
    let dir = scratch("depth");
    let packed = dir.join("tsukuba_jpeg.mcap");
    pack_compressed(&packed);
    let images: Vec<BagMessage> = messages(&packed)
        .into_iter()
        .filter(|m| m.topic.ends_with("/image_raw/compressed"))
        .collect();
    assert_eq!(images.len(), 5 * 3);
    for m in &images {
        assert_eq!(m.msg_type, "sensor_msgs/msg/CompressedImage");
        let msg: CompressedImage = from_cdr(&m.data).unwrap();
        assert_eq!(msg.format, "rgb8; jpeg compressed bgr8");
        assert!(msg.data.starts_with(&[0xFF, 0xD8, 0xFF]));
    }
    let raw_out = dir.join("raw_out");
    let jpeg_out = dir.join("jpeg_out");
    run_bag(
        &root().join("tests/fixtures/bags/tsukuba_half.mcap"),
        &raw_out,
    );
    let stderr = run_bag(&packed, &jpeg_out);
    assert!(
        stderr.contains("3 frame sets found, 3 processed, 0 incomplete, 0 skipped"),
        "{stderr}"
    );
    assert_within_jpeg_noise(&depths(&raw_out), &depths(&jpeg_out));
}

/// The stated tolerance of compressed input (JPEG quality 95) against raw, on the Tsukuba
/// fixture: per set, under 8 % of the pixels valid in both differ by more than 5 %, and at least
/// 90 % as many pixels are valid. Returns the worst share off (for the message).
fn assert_within_jpeg_noise(raw: &[Vec<f32>], jpeg: &[Vec<f32>]) -> f64 {
    assert_eq!((raw.len(), jpeg.len()), (3, 3));
    let mut worst = 0.0f64;
    for (r, j) in raw.iter().zip(jpeg) {
        assert_eq!(r.len(), j.len());
        // Pixels valid in both, and whose depths differ by more than 5 %.
        let both: Vec<(f32, f32)> = r
            .iter()
            .zip(j)
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .map(|(a, b)| (*a, *b))
            .collect();
        let valid_raw = r.iter().filter(|v| v.is_finite()).count();
        let valid_jpeg = j.iter().filter(|v| v.is_finite()).count();
        let off = both
            .iter()
            .filter(|(a, b)| (a - b).abs() > 0.05 * a)
            .count() as f64
            / both.len() as f64;
        eprintln!(
            "valid: raw {valid_raw}, jpeg {valid_jpeg}, both {}; off by > 5 %: {:.2} %",
            both.len(),
            off * 100.0
        );
        // JPEG's noise (quality 95) moves some depths of this 192x144 scene by a plane or
        // more at weak texture; most pixels keep the raw depth. Measured: 3.78 % off by more
        // than 5 % (`pack --compressed`), valid pixels 27624 against the raw bag's 27622;
        // 4.00 % and 27617 with OpenCV's JPEGs (tools/rosbags_compress.py).
        assert!(
            off < 0.08,
            "{:.2} % of the depths off by > 5 %",
            off * 100.0
        );
        assert!(
            (valid_jpeg as f64) > 0.9 * valid_raw as f64,
            "valid pixels: raw {valid_raw}, jpeg {valid_jpeg}"
        );
        worst = worst.max(off);
    }
    worst
}

#[test]
fn compressed_bag_written_by_the_python_tools_gives_the_raw_bags_depth() {
    let dir = scratch("rosbags-compressed");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let written = dir.join("rosbags_jpeg");
    let py = python::python();
    let out = Command::new(&py)
        .arg(root().join("tools/rosbags_compress.py"))
        .arg(&fixture)
        .arg(&written)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot start {py} ({e}); {}", python::INSTALL_HINT));
    assert!(
        out.status.success(),
        "tools/rosbags_compress.py failed ({}); {}\n{}",
        out.status,
        python::INSTALL_HINT,
        String::from_utf8_lossy(&out.stderr)
    );
    // What the Python side wrote: OpenCV's JPEGs in CompressedImage, as image_transport does.
    let images: Vec<BagMessage> = messages(&written)
        .into_iter()
        .filter(|m| m.topic.ends_with("/image_raw/compressed"))
        .collect();
    assert_eq!(images.len(), 5 * 3);
    for m in &images {
        assert_eq!(m.msg_type, "sensor_msgs/msg/CompressedImage");
        let msg: CompressedImage = from_cdr(&m.data).unwrap();
        assert_eq!(msg.format, "rgb8; jpeg compressed bgr8");
        assert!(msg.data.starts_with(&[0xFF, 0xD8, 0xFF]));
    }
    let raw_out = dir.join("raw_out");
    let jpeg_out = dir.join("jpeg_out");
    run_bag(&fixture, &raw_out);
    let stderr = run_bag(&written, &jpeg_out);
    assert!(
        stderr.contains("3 frame sets found, 3 processed, 0 incomplete, 0 skipped"),
        "{stderr}"
    );
    let worst = assert_within_jpeg_noise(&depths(&raw_out), &depths(&jpeg_out));
    eprintln!(
        "rosbags + OpenCV JPEG: worst set {:.2} % off by > 5 %",
        worst * 100.0
    );
    // Colour, which depth does not see: OpenCV's JPEGs are of BGR arrays ("bgr8"); the fused
    // mesh's colours from them are those from the raw images. Tsukuba is redder than blue
    // (the images' mean R - B is 19 levels), so red and blue swapped anywhere between the JPEG and
    // the mesh would turn the difference round (the mesh's own mean is R - B = 8 levels).
    let raw = mesh_mean_colour(&fixture, &dir.join("raw_mesh_out"), &dir.join("raw.ply"));
    let jpeg = mesh_mean_colour(&written, &dir.join("jpeg_mesh_out"), &dir.join("jpeg.ply"));
    eprintln!("mesh mean colour: raw images {raw:.1?}, OpenCV JPEGs {jpeg:.1?}");
    assert!(raw[0] - raw[2] > 5.0, "raw mesh colour {raw:.1?}");
    for c in 0..3 {
        assert!(
            (raw[c] - jpeg[c]).abs() < 2.5,
            "channel {c}: mesh from the raw images {raw:.1?}, from OpenCV's JPEGs {jpeg:.1?}"
        );
    }
}

#[test]
fn recorded_bag_with_other_topics_and_a_corrupt_jpeg() {
    let dir = scratch("recorded");
    let packed = dir.join("tsukuba_jpeg.mcap");
    pack_compressed(&packed);
    // As recorded: an IMU and the log beside the cameras, the second set's cam1 JPEG cut short.
    let recorded = dir.join("recorded.mcap");
    let mut writer = BagWriter::create(&recorded, false).unwrap();
    let mut cam1 = 0;
    for m in messages(&packed) {
        writer.add_topic(&m.topic, &m.msg_type, None).unwrap();
        let mut data = m.data.clone();
        if m.topic == "/cam1/image_raw/compressed" {
            cam1 += 1;
            if cam1 == 2 {
                let mut msg: CompressedImage = from_cdr(&m.data).unwrap();
                msg.data.truncate(msg.data.len() / 2);
                data = to_cdr(&msg).unwrap();
            }
        }
        writer
            .write(&m.topic, m.log_time_ns, m.publish_time_ns, &data)
            .unwrap();
        for (topic, msg_type) in [
            ("/imu/data", "sensor_msgs/msg/Imu"),
            ("/rosout", "rcl_interfaces/msg/Log"),
        ] {
            writer
                .add_topic(topic, msg_type, Some(b"# not read"))
                .unwrap();
            writer
                .write(
                    topic,
                    m.log_time_ns + 1,
                    m.log_time_ns + 1,
                    &[0, 1, 0, 0, 7],
                )
                .unwrap();
        }
    }
    writer.finish().unwrap();
    let stderr = run_bag(&recorded, &dir.join("out"));
    assert!(
        stderr.contains("3 frame sets found, 2 processed, 0 incomplete, 1 skipped (1 decode)"),
        "{stderr}"
    );
    assert!(
        stderr.contains("camera 'cam1': corrupt or truncated JPEG"),
        "{stderr}"
    );
    // The other topics: named once at the end, not once per message.
    assert_eq!(stderr.matches("/imu/data").count(), 1, "{stderr}");
    assert_eq!(stderr.matches("/rosout").count(), 1, "{stderr}");
    assert_eq!(depths(&dir.join("out")).len(), 2);
}
