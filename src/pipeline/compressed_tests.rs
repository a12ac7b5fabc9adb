//! Unit tests of compressed inputs: formats, decoding, bad input, and sets through
//! `Pipeline::push` as the node and `bag` feed it.

use super::*;
use crate::msgs::{Header, TFMessage, Time, Transform, TransformStamped, Vector3};
use crate::pipeline::{intrinsics_info, Pipeline, PipelineConfig};

const W: u32 = 32;
const H: u32 = 24;

/// A smooth colour gradient (JPEG's noise on it is small), or its grey.
fn raw(encoding: &str, w: u32, h: u32) -> Image {
    let bpp = if encoding == "mono8" { 1 } else { 3 };
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (r, g, b) = ((x * 255 / w) as u8, (y * 255 / h) as u8, 100u8);
            if bpp == 1 {
                data.push(r / 2 + g / 2);
            } else if encoding == "bgr8" {
                data.extend_from_slice(&[b, g, r]);
            } else {
                data.extend_from_slice(&[r, g, b]);
            }
        }
    }
    Image {
        header: Header {
            stamp: Time { sec: 5, nanosec: 0 },
            frame_id: "cam".into(),
        },
        height: h,
        width: w,
        encoding: encoding.into(),
        is_bigendian: 0,
        step: w * bpp,
        data,
    }
}

fn carried(encoding: &str, codec: Codec) -> CompressedImage {
    compress(&raw(encoding, W, H), codec, 95).unwrap()
}

fn max_diff(a: &[u8], b: &[u8]) -> u8 {
    a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap()
}

#[test]
fn formats_as_the_plugin_writes_them() {
    let f = |s: &str| parse_format(s);
    let jpeg = |o: &str| {
        Some(Format {
            codec: Codec::Jpeg,
            original: Some(o.into()),
        })
    };
    assert_eq!(f("rgb8; jpeg compressed bgr8"), jpeg("rgb8"));
    assert_eq!(f("mono8; jpeg compressed mono8"), jpeg("mono8"));
    assert_eq!(f("mono8; jpeg compressed "), jpeg("mono8"));
    assert_eq!(
        f("bgr8; png compressed bgr8"),
        Some(Format {
            codec: Codec::Png,
            original: Some("bgr8".into())
        })
    );
    for bare in ["jpeg", "png", "JPEG"] {
        assert_eq!(f(bare).unwrap().original, None, "{bare}");
    }
    for refused in [
        "16UC1; compressedDepth png",
        "rgb8; tiff compressed",
        "",
        "h264",
    ] {
        assert_eq!(f(refused), None, "{refused}");
    }
}

#[test]
fn jpeg_and_png_decode_to_the_raw_image() {
    for encoding in ["rgb8", "bgr8"] {
        let original = raw("rgb8", W, H);
        let jpeg = decode("a", &carried(encoding, Codec::Jpeg)).unwrap();
        assert_eq!(
            (jpeg.width, jpeg.height, jpeg.encoding.as_str(), jpeg.step),
            (W, H, "rgb8", 3 * W)
        );
        assert_eq!(jpeg.header, original.header);
        // bgr8 comes back as rgb8: the same colours.
        assert!(max_diff(&jpeg.data, &original.data) <= 12, "{encoding}");
        let png = decode("a", &carried(encoding, Codec::Png)).unwrap();
        assert_eq!(png.data, original.data, "{encoding}: PNG is lossless");
    }
    let mono = decode("a", &carried("mono8", Codec::Jpeg)).unwrap();
    assert_eq!((mono.encoding.as_str(), mono.step), ("mono8", W));
    assert!(max_diff(&mono.data, &raw("mono8", W, H).data) <= 8);
    let mut bare = compress(&raw("rgb8", W, H), Codec::Png, 95).unwrap();
    bare.format = "png".into();
    assert_eq!(decode("a", &bare).unwrap().data, raw("rgb8", W, H).data);
}

fn decode_err(image: &CompressedImage) -> DecodeError {
    decode("a", image).unwrap_err()
}

#[test]
fn corrupt_and_truncated_data_are_refused() {
    for codec in [Codec::Jpeg, Codec::Png] {
        let good = carried("rgb8", codec);
        let mut truncated = good.clone();
        truncated.data.truncate(good.data.len() * 2 / 3);
        assert!(
            matches!(decode_err(&truncated), DecodeError::Corrupt { .. }),
            "{codec:?}"
        );
        // The signature kept, the header after it garbage.
        let mut garbled = good.clone();
        for b in &mut garbled.data[8..40] {
            *b = 0x5A;
        }
        let e = decode_err(&garbled);
        assert!(matches!(e, DecodeError::Corrupt { .. }), "{codec:?}: {e}");
        assert!(e
            .to_string()
            .starts_with("camera 'a': corrupt or truncated"));
        let mut empty = good.clone();
        empty.data.clear();
        assert!(matches!(decode_err(&empty), DecodeError::Corrupt { .. }));
    }
}

/// A JPEG whose frame header claims 16384 x 16384 (a few hundred bytes that would decode to
/// 800 MB of RGB) is refused from its header, naming the size, before any pixel is decoded.
#[test]
fn a_jpeg_claiming_a_huge_size_is_refused_before_decoding() {
    let good = carried("rgb8", Codec::Jpeg);
    // The baseline frame header (SOF0, FF C0): length (2), precision (1), height (2), width (2).
    let sof = good
        .data
        .windows(2)
        .position(|w| w == [0xFF, 0xC0])
        .expect("a baseline JPEG");
    let claim = |width: u16, height: u16| {
        let mut huge = good.clone();
        huge.data[sof + 5..sof + 7].copy_from_slice(&height.to_be_bytes());
        huge.data[sof + 7..sof + 9].copy_from_slice(&width.to_be_bytes());
        huge
    };
    let e = decode_err(&claim(16384, 16384));
    assert!(
        matches!(
            e,
            DecodeError::TooLarge {
                width: 16384,
                height: 16384,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("16384x16384 pixels"), "{e}");
}

#[test]
fn a_format_that_lies_is_refused() {
    let mut png_said_jpeg = carried("rgb8", Codec::Png);
    png_said_jpeg.format = "rgb8; jpeg compressed bgr8".into();
    let e = decode_err(&png_said_jpeg);
    assert!(matches!(e, DecodeError::FormatLies { .. }), "{e}");
    assert!(
        e.to_string().contains("says JPEG, but the data is a PNG"),
        "{e}"
    );
    let mut colour_said_mono = carried("rgb8", Codec::Jpeg);
    colour_said_mono.format = "mono8; jpeg compressed mono8".into();
    let e = decode_err(&colour_said_mono);
    assert!(e.to_string().contains("mono8 (grey)"), "{e}");
    let mut depth = carried("mono8", Codec::Png);
    depth.format = "16UC1; compressedDepth png".into();
    assert!(matches!(
        decode_err(&depth),
        DecodeError::UnsupportedFormat { .. }
    ));
}

fn config() -> PipelineConfig {
    let args: Vec<String> = [
        "--ros-args",
        "-p",
        "cameras:=[a, b]",
        "-p",
        "reference_camera:=a",
        "-p",
        "camera_timeout:=0.0",
        "-p",
        "image_transport:=compressed",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    PipelineConfig::from_args(&args).unwrap()
}

fn calibrated(p: &mut Pipeline<'_>) {
    for camera in 0..2 {
        let info = intrinsics_info(&crate::synthetic::intrinsics(W, H));
        p.push(
            Input::CameraInfo {
                camera,
                info: Box::new(info),
            },
            0,
        );
    }
    p.push(
        Input::TfStatic(TFMessage {
            transforms: (0..2)
                .map(|i| TransformStamped {
                    header: Header {
                        stamp: Time::default(),
                        frame_id: "rig".into(),
                    },
                    child_frame_id: ["a", "b"][i].into(),
                    transform: Transform {
                        translation: Vector3 {
                            x: 0.1 * i as f64,
                            y: 0.0,
                            z: 0.0,
                        },
                        ..Transform::default()
                    },
                })
                .collect(),
        }),
        0,
    );
}

/// One set at second `sec`: each camera's compressed image, `spoil` applied to camera b's.
fn push_set(
    p: &mut Pipeline<'_>,
    sec: i32,
    size: (u32, u32),
    spoil: impl Fn(&mut CompressedImage),
) -> Vec<Result<crate::pipeline::Job, Skip>> {
    let mut sets = Vec::new();
    for camera in 0..2 {
        let mut image = raw("rgb8", size.0, size.1);
        image.header = Header {
            stamp: Time { sec, nanosec: 0 },
            frame_id: ["a", "b"][camera].into(),
        };
        let mut msg = compress(&image, Codec::Jpeg, 95).unwrap();
        if camera == 1 {
            spoil(&mut msg);
        }
        sets.extend(
            p.push(Input::compressed(camera, msg), sec as u64 * 1_000_000_000)
                .sets,
        );
    }
    sets
}

#[test]
fn bad_sets_are_skipped_with_the_reason_and_the_pipeline_goes_on() {
    let config = config();
    assert!(config.compressed_inputs);
    assert_eq!(config.compressed_topics()[1], "/b/image_raw/compressed");
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let skip = |sets: Vec<Result<crate::pipeline::Job, Skip>>| match sets.as_slice() {
        [Err(skip)] => skip.clone(),
        other => panic!("one skipped set expected: {other:?}"),
    };
    let truncated = skip(push_set(&mut p, 1, (W, H), |m| m.data.truncate(100)));
    assert_eq!(
        (truncated.kind, truncated.camera),
        (SkipKind::Decode, Some(1))
    );
    assert!(truncated
        .message
        .contains("camera 'b': corrupt or truncated JPEG"));
    let lies = skip(push_set(&mut p, 2, (W, H), |m| {
        m.format = "rgb8; png compressed bgr8".into()
    }));
    assert_eq!(lies.kind, SkipKind::Decode);
    assert!(lies.message.contains("says PNG, but the data is a JPEG"));
    // Decoded at another size than its camera_info: the calibration's size check.
    let size = skip(push_set(&mut p, 3, (W / 2, H / 2), |_| {}));
    assert_eq!((size.kind, size.camera), (SkipKind::CameraInfo, Some(0)));
    assert!(size.message.contains("16x12"), "{}", size.message);
    // Good input again: a job with the decoded images.
    let sets = push_set(&mut p, 4, (W, H), |_| {});
    let [Ok(job)] = sets.as_slice() else {
        panic!("one job expected: {sets:?}");
    };
    for image in &job.images {
        assert_eq!(
            (image.width, image.height, image.encoding.as_str()),
            (W, H, "rgb8")
        );
    }
}

/// What decoding a 9-camera 640x480 JPEG set (quality 95, a textured synthetic scene) costs,
/// printed (no timing asserted): the figure of docs/node.md.
#[test]
fn nine_camera_vga_jpeg_set_decodes() {
    use crate::geometry::CameraModel;
    use crate::synthetic::{self, Scene};
    let model = CameraModel::pinhole(synthetic::intrinsics(640, 480));
    let rig = synthetic::row_rig(9, 0.1, model, 4).unwrap();
    let scene = Scene::wall_and_box(2.0, None, model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let compressed: Vec<CompressedImage> = images
        .iter()
        .map(|im| {
            let mut data = Vec::with_capacity(im.pixels.len() * 3);
            for &p in &im.pixels {
                data.extend_from_slice(&crate::image::Rgba8Image::unpack(p)[..3]);
            }
            let raw = Image {
                height: im.height,
                width: im.width,
                encoding: "rgb8".into(),
                step: im.width * 3,
                data,
                ..Image::default()
            };
            compress(&raw, Codec::Jpeg, 95).unwrap()
        })
        .collect();
    let bytes: usize = compressed.iter().map(|m| m.data.len()).sum();
    let set = SyncedSet {
        stamps_ns: vec![0; 9],
        messages: compressed
            .iter()
            .cloned()
            .map(InputImage::Compressed)
            .collect(),
    };
    // Once to warm up (allocations, the thread pool), then timed.
    decode_set(set.clone(), |k| (k, "cam")).unwrap();
    let t0 = std::time::Instant::now();
    let decoded = decode_set(set.clone(), |k| (k, "cam")).unwrap();
    let parallel = t0.elapsed();
    let t0 = std::time::Instant::now();
    for m in &compressed {
        decode("cam", m).unwrap();
    }
    let serial = t0.elapsed();
    eprintln!(
        "9 x 640x480 JPEG (q95, {} KiB): decoded in {:.1} ms in parallel ({} threads), {:.1} ms one by one",
        bytes / 1024,
        parallel.as_secs_f64() * 1e3,
        rayon::current_num_threads(),
        serial.as_secs_f64() * 1e3
    );
    assert!(decoded
        .messages
        .iter()
        .all(|m| (m.width, m.height, m.encoding.as_str()) == (640, 480, "rgb8")));
}
