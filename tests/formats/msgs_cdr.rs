//! Byte-for-byte CDR compatibility of `sweepdepth::msgs` with the ROS 2 reference serializer.
//!
//! The fixtures in `tests/fixtures/cdr/` were produced by `tools/gen_cdr_fixtures.py` with the
//! Python `rosbags` package (see `tests/fixtures/cdr/README.md`); every message below must be
//! built with exactly the same values as in that script. No Python is needed at test time.

use std::fmt::Debug;
use std::path::PathBuf;

use serde::de::DeserializeOwned;
use serde::Serialize;
use sweepdepth::msgs::*;

fn fixture(name: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/cdr")
        .join(format!("{name}.bin"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

/// Serialising `msg` gives the fixture's bytes, and parsing the fixture gives `msg` back.
fn check<T: Serialize + DeserializeOwned + PartialEq + Debug>(name: &str, msg: &T) {
    let expected = fixture(name);
    let bytes = to_cdr(msg).unwrap();
    assert_eq!(
        bytes, expected,
        "{name}: to_cdr differs from the rosbags fixture\n ours: {bytes:02x?}\n want: {expected:02x?}"
    );
    let back: T = from_cdr(&expected).unwrap();
    assert_eq!(&back, msg, "{name}: from_cdr(fixture) differs");
    assert_truncation_is_an_error::<T>(name, &expected);
}

/// Every strict prefix of a fixture must give `Err`, never a panic or a bogus `Ok`, except
/// prefixes that only drop trailing bytes a value cannot need (none here: every fixture ends
/// in data, not padding).
fn assert_truncation_is_an_error<T: DeserializeOwned + Debug>(name: &str, full: &[u8]) {
    for len in 0..full.len() {
        let r = std::panic::catch_unwind(|| from_cdr::<T>(&full[..len]));
        match r {
            Ok(Err(_)) => {}
            Ok(Ok(v)) => panic!("{name}: {len}-byte prefix parsed as {v:?}"),
            Err(_) => panic!("{name}: {len}-byte prefix panicked"),
        }
    }
}

fn header(sec: i32, nanosec: u32, frame_id: &str) -> Header {
    Header {
        stamp: Time { sec, nanosec },
        frame_id: frame_id.into(),
    }
}

fn transform_stamped(i: u32) -> TransformStamped {
    let f = f64::from(i);
    TransformStamped {
        header: header(1_700_000_000 + i as i32, 250_000_000 * i + 7, "world"),
        child_frame_id: format!("cam{i}_optical"),
        transform: Transform {
            translation: Vector3 {
                x: 0.5 * f,
                y: -1.25,
                z: 3.0 + f,
            },
            rotation: Quaternion {
                x: 0.0,
                y: 0.5,
                z: -0.5,
                w: std::f64::consts::FRAC_1_SQRT_2, // 0.7071067811865476 in the script
            },
        },
    }
}

fn status(i: u32, level: u8) -> DiagnosticStatus {
    DiagnosticStatus {
        level,
        name: format!("sweepdepth: cam{i}"),
        message: if level == DiagnosticStatus::OK {
            "ok"
        } else {
            "late frame"
        }
        .into(),
        hardware_id: "gpu0".into(),
        values: vec![
            KeyValue {
                key: "fps".into(),
                value: format!("{:.1}", 29.5 + f64::from(i)),
            },
            KeyValue {
                key: "dropped".into(),
                value: (3 * i + 1).to_string(),
            },
        ],
    }
}

#[test]
fn time() {
    check(
        "time",
        &Time {
            sec: -2,
            nanosec: 999_999_999,
        },
    );
}

#[test]
fn std_header() {
    check("header", &header(1_700_000_123, 456_789, "base_link"));
}

#[test]
fn image() {
    check(
        "image",
        &Image {
            header: header(12, 34, "cam0"),
            height: 1,
            width: 1,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3,
            data: vec![1, 2, 255],
        },
    );
}

#[test]
fn region_of_interest() {
    check(
        "region_of_interest",
        &RegionOfInterest {
            x_offset: 10,
            y_offset: 20,
            height: 240,
            width: 320,
            do_rectify: true,
        },
    );
}

#[test]
fn camera_info() {
    check(
        "camera_info",
        &CameraInfo {
            header: header(100, 200, "cam1_optical"),
            height: 480,
            width: 640,
            distortion_model: "plumb_bob".into(),
            d: vec![-0.28, 0.07, 0.001, -0.0005, 0.0],
            k: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                525.0, 0.0, 319.5, -37.5, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            binning_x: 2,
            binning_y: 2,
            roi: RegionOfInterest {
                x_offset: 8,
                y_offset: 4,
                height: 200,
                width: 300,
                do_rectify: true,
            },
        },
    );
}

#[test]
fn point_field() {
    check(
        "point_field",
        &PointField {
            name: "rgb".into(),
            offset: 12,
            datatype: PointField::UINT32,
            count: 1,
        },
    );
}

#[test]
fn point_cloud2() {
    check(
        "point_cloud2",
        &PointCloud2 {
            header: header(5, 6, "map"),
            height: 1,
            width: 2,
            fields: vec![
                PointField {
                    name: "z".into(),
                    offset: 0,
                    datatype: PointField::FLOAT32,
                    count: 1,
                },
                PointField {
                    name: "intensity".into(),
                    offset: 4,
                    datatype: PointField::UINT16,
                    count: 1,
                },
            ],
            is_bigendian: false,
            point_step: 6,
            row_step: 12,
            data: vec![0, 0, 128, 63, 7, 0, 0, 0, 0, 64, 9, 1],
            is_dense: true,
        },
    );
}

#[test]
fn vector3() {
    check(
        "vector3",
        &Vector3 {
            x: 1.5,
            y: -2.25,
            z: 1e-9,
        },
    );
}

#[test]
fn quaternion() {
    check(
        "quaternion",
        &Quaternion {
            x: 0.1,
            y: -0.2,
            z: 0.3,
            w: 0.9273618495495703,
        },
    );
}

#[test]
fn transform() {
    check("transform", &transform_stamped(1).transform);
}

#[test]
fn transform_stamped_msg() {
    check("transform_stamped", &transform_stamped(1));
}

#[test]
fn tf_message() {
    check(
        "tf_message",
        &TFMessage {
            transforms: vec![transform_stamped(0), transform_stamped(1)],
        },
    );
}

#[test]
fn key_value() {
    check(
        "key_value",
        &KeyValue {
            key: "temperature".into(),
            value: "41.5C".into(),
        },
    );
}

#[test]
fn diagnostic_status() {
    check("diagnostic_status", &status(0, DiagnosticStatus::WARN));
}

#[test]
fn diagnostic_array() {
    check(
        "diagnostic_array",
        &DiagnosticArray {
            header: header(77, 88, ""),
            status: vec![
                status(0, DiagnosticStatus::OK),
                status(1, DiagnosticStatus::ERROR),
            ],
        },
    );
}

#[test]
fn encapsulation_header_is_cdr_le() {
    let bytes = to_cdr(&Time::default()).unwrap();
    assert_eq!(&bytes[..4], &[0x00, 0x01, 0x00, 0x00]);
}

#[test]
fn truncated_and_malformed_input_is_an_error() {
    // Empty / header-only input.
    assert!(matches!(
        from_cdr::<Image>(&[]),
        Err(MsgError::MissingHeader { len: 0 })
    ));
    assert!(from_cdr::<Image>(&[0, 1, 0, 0]).is_err());
    // A huge declared length in the middle of an otherwise valid payload.
    let mut bytes = fixture("image");
    let data_len_at = bytes.len() - 3 - 4;
    bytes[data_len_at..data_len_at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
    let err = from_cdr::<Image>(&bytes).unwrap_err();
    assert!(matches!(err, MsgError::Cdr(_)), "{err}");
    // Huge sequence count of structs: must fail fast on EOF, not allocate 4G elements.
    let mut bytes = fixture("tf_message");
    bytes[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(from_cdr::<TFMessage>(&bytes).is_err());
    // Bad bool.
    let mut bytes = fixture("region_of_interest");
    let last = bytes.len() - 1;
    bytes[last] = 2;
    assert!(matches!(
        from_cdr::<RegionOfInterest>(&bytes),
        Err(MsgError::Cdr(_))
    ));
    // Payload of another type: trailing bytes are reported.
    assert!(matches!(
        from_cdr::<Time>(&fixture("header")),
        Err(MsgError::TrailingBytes(_))
    ));
    // Error messages are human-readable.
    let msg = from_cdr::<CameraInfo>(&fixture("camera_info")[..40])
        .unwrap_err()
        .to_string();
    assert!(msg.contains("end of input"), "{msg}");
}
