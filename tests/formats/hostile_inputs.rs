//! Hostile inputs through the node's pipeline (no DDS, no GPU): CameraInfos that cannot
//! describe the image, stamps that repeat, run ahead or go backwards, and parameter sets that
//! do not fit the rig at start-up. Each is refused with a reason naming the camera or the
//! parameter, and the pipeline keeps working.

use sweepdepth::msgs::{CameraInfo, Header, Image, RegionOfInterest, Time};
use sweepdepth::pipeline::{
    ConfigError, Input, Job, NoticeKind, Outcome, Pipeline, PipelineConfig, Skip, SkipKind,
};
use sweepdepth::ros::sync::{SyncStats, TimeRules};

fn config(extra: &[&str]) -> Result<PipelineConfig, ConfigError> {
    let mut args: Vec<String> = ["--ros-args", "-p", "cameras:=[left, mid, right]"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for p in extra {
        args.push("-p".into());
        args.push(p.to_string());
    }
    PipelineConfig::from_args(&args)
}

fn stamp(ms: i64) -> Time {
    Time::from_nanos(ms * 1_000_000)
}

fn image(camera: &str, ms: i64, width: u32, height: u32) -> Image {
    Image {
        header: Header {
            stamp: stamp(ms),
            frame_id: format!("{camera}_optical"),
        },
        width,
        height,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: width,
        data: vec![128; (width * height) as usize],
    }
}

fn info(width: u32, height: u32) -> CameraInfo {
    CameraInfo {
        width,
        height,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [50.0, 0.0, 31.5, 0.0, 50.0, 23.5, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            50.0, 0.0, 31.5, 0.0, 0.0, 50.0, 23.5, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

const CAMERAS: [&str; 3] = ["left", "mid", "right"];

/// The receive clock of the pipeline (camera dropout): 1 ms per image, whatever the stamps say.
fn received_ns() -> u64 {
    static CLOCK: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    CLOCK.fetch_add(1_000_000, std::sync::atomic::Ordering::Relaxed)
}

/// Pushes one image per camera at `ms` and returns the outcomes.
fn push_set_outcomes(p: &mut Pipeline<'_>, ms: i64, width: u32, height: u32) -> Vec<Outcome> {
    CAMERAS
        .iter()
        .enumerate()
        .map(|(i, camera)| {
            let image = image(camera, ms, width, height);
            p.push(Input::Image { camera: i, image }, received_ns())
        })
        .collect()
}

/// Pushes one image per camera at `ms` and returns the results of the sets completed.
fn push_set(p: &mut Pipeline<'_>, ms: i64, width: u32, height: u32) -> Vec<Result<Job, Skip>> {
    push_set_outcomes(p, ms, width, height)
        .into_iter()
        .flat_map(|o| o.sets)
        .collect()
}

fn set_info(p: &mut Pipeline<'_>, camera: usize, info: CameraInfo) {
    let outcome = p.push(
        Input::CameraInfo {
            camera,
            info: Box::new(info),
        },
        0,
    );
    assert!(outcome.sets.is_empty() && outcome.notices.is_empty());
}

fn only_skip(results: Vec<Result<Job, Skip>>) -> Skip {
    assert_eq!(results.len(), 1, "{results:?}");
    match results.into_iter().next() {
        Some(Err(skip)) => skip,
        other => panic!("expected a skip, got {other:?}"),
    }
}

#[test]
fn camera_info_that_does_not_describe_the_image_skips_the_set() {
    let cfg = config(&["sync:=exact"]).unwrap();
    let mut p = Pipeline::new(&cfg).unwrap();
    for i in 0..3 {
        set_info(&mut p, i, info(64, 48));
    }
    // Images of 32x24 against CameraInfos of 64x48 without binning: refused, naming the
    // camera and what the CameraInfo says.
    let skip = only_skip(push_set(&mut p, 100, 32, 24));
    assert_eq!(skip.kind, SkipKind::CameraInfo);
    assert!(
        skip.message.contains("camera 'left'")
            && skip.message.contains("32x24")
            && skip.message.contains("64x48")
            && skip.message.contains("no binning"),
        "{}",
        skip.message
    );
    // Binning 2x2 explains the half-size image: the set gets past the CameraInfo check and
    // now waits for /tf_static, which this test never sends.
    for i in 0..3 {
        let mut binned = info(64, 48);
        binned.binning_x = 2;
        binned.binning_y = 2;
        set_info(&mut p, i, binned);
    }
    let skip = only_skip(push_set(&mut p, 200, 32, 24));
    assert_eq!(skip.kind, SkipKind::WaitingForTransform, "{}", skip.message);
    // So does an ROI of 32x24 (REP 104: the image is the ROI).
    for i in 0..3 {
        let mut roi = info(64, 48);
        roi.roi = RegionOfInterest {
            x_offset: 16,
            y_offset: 12,
            width: 32,
            height: 24,
            do_rectify: false,
        };
        set_info(&mut p, i, roi);
    }
    let skip = only_skip(push_set(&mut p, 300, 32, 24));
    assert_eq!(skip.kind, SkipKind::WaitingForTransform, "{}", skip.message);
}

#[test]
fn uncalibrated_or_non_finite_camera_info_skips_the_set() {
    let cfg = config(&["sync:=exact"]).unwrap();
    let mut p = Pipeline::new(&cfg).unwrap();
    for i in 0..3 {
        set_info(&mut p, i, info(64, 48));
    }
    // (Camera 0 is checked first; the others would then wait for /tf_static.)
    let mut zero = info(64, 48);
    zero.k = [0.0; 9];
    zero.p = [0.0; 12];
    set_info(&mut p, 0, zero);
    let skip = only_skip(push_set(&mut p, 100, 64, 48));
    assert!(
        skip.message.contains("camera 'left'") && skip.message.contains("uncalibrated"),
        "{}",
        skip.message
    );
    let mut nan = info(64, 48);
    nan.d[2] = f64::NAN;
    set_info(&mut p, 0, nan);
    let skip = only_skip(push_set(&mut p, 200, 64, 48));
    assert!(
        skip.message.contains("camera 'left'") && skip.message.contains("D[2] is NaN"),
        "{}",
        skip.message
    );
    let mut unknown = info(64, 48);
    unknown.distortion_model = "kannala_brandt".into();
    unknown.d = vec![0.1; 8];
    set_info(&mut p, 0, unknown);
    let skip = only_skip(push_set(&mut p, 300, 64, 48));
    assert!(
        skip.message.contains("camera 'left'") && skip.message.contains("kannala_brandt"),
        "{}",
        skip.message
    );
}

#[test]
fn time_rules_are_reported_per_camera_and_the_pipeline_recovers() {
    for policy in ["sync:=exact", "sync:=approximate"] {
        let cfg = config(&[policy]).unwrap();
        let mut p = Pipeline::new(&cfg).unwrap();
        let mut stats = SyncStats::default();
        let mut sets = 0;
        let mut notices = Vec::new();
        let mut take = |outcomes: Vec<Outcome>, notices: &mut Vec<_>| {
            let mut n = 0;
            for o in outcomes {
                if let Some(v) = &o.sync {
                    v.count(&mut stats);
                }
                n += o.sets.len();
                notices.extend(o.notices);
            }
            n
        };
        for k in 0..20 {
            sets += take(
                push_set_outcomes(&mut p, 1000 + 100 * k, 8, 8),
                &mut notices,
            );
        }
        assert!(notices.is_empty(), "{policy}");
        // A duplicate on mid, a stamp an hour ahead on right.
        let mid = Input::Image {
            camera: 1,
            image: image("mid", 2900, 8, 8),
        };
        let right = Input::Image {
            camera: 2,
            image: image("right", 3_600_000, 8, 8),
        };
        take(
            vec![p.push(mid, received_ns()), p.push(right, received_ns())],
            &mut notices,
        );
        let kinds: Vec<NoticeKind> = notices.iter().map(|n| n.kind).collect();
        assert_eq!(
            kinds,
            [NoticeKind::DuplicateStamp, NoticeKind::FutureStamp],
            "{policy}"
        );
        assert!(
            notices[0].message.contains("camera 'mid'"),
            "{}",
            notices[0].message
        );
        assert!(
            notices[1].message.contains("camera 'right'")
                && notices[1].message.contains("sync_future_window"),
            "{}",
            notices[1].message
        );
        notices.clear();
        // The bag loops: back to 1000 ms (1.9 s back, more than sync_reset_backwards).
        for k in 0..20 {
            sets += take(
                push_set_outcomes(&mut p, 1000 + 100 * k, 8, 8),
                &mut notices,
            );
        }
        assert_eq!(notices.len(), 1, "{policy}: {notices:?}");
        assert_eq!(notices[0].kind, NoticeKind::TimeReset);
        assert!(
            notices[0].message.contains("camera 'left'")
                && notices[0].message.contains("from 2.900 s to 1.000 s"),
            "{}",
            notices[0].message
        );
        assert_eq!(
            (stats.resets, stats.duplicates, stats.future),
            (1, 1, 1),
            "{policy}"
        );
        // Both loops gave their sets (approximate sync holds the last one back).
        assert!(sets >= 38, "{policy}: {sets} sets");
    }
}

#[test]
fn time_rule_thresholds_come_from_the_parameters() {
    let cfg = config(&[]).unwrap();
    assert_eq!(cfg.time_rules, TimeRules::default());
    let cfg = config(&["sync_future_window:=2.5", "sync_reset_backwards:=0.25"]).unwrap();
    assert_eq!(
        cfg.time_rules,
        TimeRules {
            future_window_ns: 2_500_000_000,
            reset_backwards_ns: 250_000_000
        }
    );
    for bad in ["sync_future_window:=0.5", "sync_reset_backwards:=0.0"] {
        let e = config(&[bad]).unwrap_err().to_string();
        assert!(e.contains("out of range"), "{bad}: {e}");
    }
}

#[test]
fn inconsistent_engine_parameters_are_refused_at_start_up() {
    let e = config(&["min_depth:=20.0"]).unwrap_err().to_string();
    assert!(e.contains("max_depth"), "{e}");
    // 3 cameras, reference pairs: m = 2 (best_n is checked while it is read: best_n_of_m).
    let e = config(&["scoring:=best_n_of_m", "best_n:=3"])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("best_n (3)") && e.contains("2 camera pairs"),
        "{e}"
    );
    assert!(config(&["scoring:=best_n_of_m", "best_n:=3", "pairs:=all"]).is_ok());
    let e = config(&["min_visible_cameras:=4"]).unwrap_err().to_string();
    assert!(e.contains("min_visible_cameras (4)"), "{e}");
    let e = config(&["reference_camera:=centre"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("centre"), "{e}");
    // The defaults on a two-camera rig (best 2 of 1 pair) still start.
    let args: Vec<String> = ["--ros-args", "-p", "cameras:=[a, b]"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert!(PipelineConfig::from_args(&args).is_ok());
}

/// The fuzz inputs that crashed `BagReader` (tests/fixtures/fuzz/README.md): each must now end
/// in a corrupt-file error naming the file, without a panic or an abort.
#[test]
fn fuzz_found_bags_are_errors_not_crashes() {
    use sweepdepth::bag::reader::BagReader;
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/fuzz/bag_reader");
    let tmp = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
    const MAGIC: &[u8] = b"\x89MCAP0\r\n";
    for name in [
        "huge_record_length.bin",
        "length_overflow.bin",
        "record_longer_than_chunk.bin",
        "panic_outside_reader.bin",
        "resume_point_past_the_end.bin",
    ] {
        let input = std::fs::read(dir.join(name)).unwrap();
        let mut bytes = Vec::new();
        if !input.starts_with(MAGIC) {
            bytes.extend_from_slice(MAGIC);
        }
        bytes.extend_from_slice(&input);
        let path = tmp.join(format!("fuzz-{name}.mcap"));
        std::fs::write(&path, &bytes).unwrap();
        let error = match BagReader::open(&path) {
            Err(e) => e.to_string(),
            Ok(reader) => {
                let items: Vec<_> = reader.collect();
                let last = items.last().unwrap_or_else(|| panic!("{name}: no error"));
                last.as_ref()
                    .map(|m| m.topic.clone())
                    .unwrap_err()
                    .to_string()
            }
        };
        assert!(
            error.contains(&format!("fuzz-{name}.mcap")),
            "{name}: {error}"
        );
        assert!(
            error.contains("corrupt") || error.contains("too large") || error.contains("truncated"),
            "{name}: {error}"
        );
    }
}

#[test]
fn image_frame_id_with_a_leading_slash_is_refused_as_tf2_refuses_it() {
    let cfg = config(&["sync:=exact"]).unwrap();
    let mut p = Pipeline::new(&cfg).unwrap();
    for i in 0..3 {
        set_info(&mut p, i, info(64, 48));
    }
    let mut results = Vec::new();
    for (i, camera) in CAMERAS.iter().enumerate() {
        let mut image = image(camera, 100, 64, 48);
        if i == 0 {
            image.header.frame_id = "/left_optical".into();
        }
        results.extend(
            p.push(Input::Image { camera: i, image }, received_ns())
                .sets,
        );
    }
    let skip = only_skip(results);
    assert_eq!(skip.kind, SkipKind::FrameId, "{}", skip.message);
    assert!(
        skip.message.contains("camera 'left'")
            && skip
                .message
                .contains("\"/left_optical\": in tf2 frame_ids cannot start with a '/'"),
        "{}",
        skip.message
    );
}

/// The fuzz input that crashed the compressed-image decoder (tests/fixtures/fuzz/README.md):
/// never a panic, and the outcome each build gives is checked. Where overflow checks are on
/// (the dev profile: the README's `cargo test`, which CI runs; the fuzz target) zune-jpeg
/// panics inside on this stream and `decode` turns that into a corrupt-image error naming the
/// camera. Where they are off (`cargo test --release`, the developers' runs) the same
/// multiplication wraps and the decoder returns a (garbled)
/// picture: `decode` must then hand back exactly what the `image` crate decodes from the bytes,
/// as rgb8 of the JPEG header's size, under the message's own header.
#[test]
fn fuzz_found_compressed_images_are_errors_not_crashes() {
    use sweepdepth::msgs::{CompressedImage, Header};
    use sweepdepth::pipeline::compressed::{decode, DecodeError};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/fuzz/compressed/jpeg_coefficient_overflow.bin");
    let input = std::fs::read(path).unwrap();
    // The fuzz target's first byte chooses the format: 0 = a JPEG of an rgb8 image.
    assert_eq!(input[0], 0);
    let header = Header {
        stamp: stamp(1234),
        frame_id: "cam0_optical".into(),
    };
    let msg = CompressedImage {
        header: header.clone(),
        format: "rgb8; jpeg compressed bgr8".into(),
        data: input[1..].to_vec(),
    };
    let result = decode("cam0", &msg);
    if cfg!(debug_assertions) {
        let error = result.expect_err("a corrupt image");
        assert!(matches!(error, DecodeError::Corrupt { .. }), "{error}");
        let text = error.to_string();
        assert!(text.contains("cam0") && text.contains("panicked"), "{text}");
    } else {
        let image = result.expect("without overflow checks the decoder returns a picture");
        // The size the JPEG header claims, read on its own.
        let (width, height) = image::ImageReader::with_format(
            std::io::Cursor::new(&input[1..]),
            image::ImageFormat::Jpeg,
        )
        .into_dimensions()
        .unwrap();
        assert_eq!((width, height), (1040, 293));
        let expected = image::load_from_memory_with_format(&input[1..], image::ImageFormat::Jpeg)
            .unwrap()
            .into_rgb8();
        assert_eq!(image.header, header);
        assert_eq!(
            (
                image.width,
                image.height,
                image.encoding.as_str(),
                image.step
            ),
            (width, height, "rgb8", 3 * width)
        );
        assert_eq!(image.is_bigendian, 0);
        assert!(
            image.data == expected.as_raw().as_slice(),
            "decoded pixels differ from the image crate's decode of the same bytes"
        );
    }
}
