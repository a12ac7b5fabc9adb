//! ROS 2 message types the engine reads and writes (mirrors of the standard `.msg` definitions).
//!
//! Field names and order follow the ROS 2 (Humble/Jazzy) definitions so that these structs
//! serialise to the same CDR bytes as the originals, both through `ros2-client`/`rustdds` and
//! through [`to_cdr`] / [`from_cdr`] (the full serialized payload as found on the wire and in
//! rosbag2 / MCAP files: 4-byte encapsulation header followed by the CDR body).
//!
//! Type mapping: `uint8`/`byte` → `u8`, `bool` → `bool`, `uint32` → `u32`, `int32` → `i32`,
//! `float64` → `f64`, `string` → `String`, `T[]` → `Vec<T>`, `T[N]` → `[T; N]`, and `uint8[]`
//! bulk data → `Vec<u8>` with `#[serde(with = "serde_bytes")]` (one length + one memcpy instead
//! of element by element).

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

// ---------------------------------------------------------------------------------------------
// builtin_interfaces / std_msgs
// ---------------------------------------------------------------------------------------------

/// `builtin_interfaces/msg/Time`.
///
/// `nanosec` is always in `0..1_000_000_000` for well-formed values; negative times are
/// represented with a negative `sec` and a positive `nanosec` (e.g. -0.5 s is
/// `{ sec: -1, nanosec: 500_000_000 }`), as in `rclcpp::Time`.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize,
)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    const NANOS_PER_SEC: i64 = 1_000_000_000;

    /// The smallest representable time (`sec = i32::MIN`, `nanosec = 0`).
    pub const MIN: Time = Time {
        sec: i32::MIN,
        nanosec: 0,
    };
    /// The largest representable time (`sec = i32::MAX`, `nanosec = 999_999_999`).
    pub const MAX: Time = Time {
        sec: i32::MAX,
        nanosec: 999_999_999,
    };

    /// Converts signed nanoseconds since the epoch, or `None` if `sec` would not fit in `i32`.
    ///
    /// Uses floor division, so `-1` ns becomes `{ sec: -1, nanosec: 999_999_999 }`.
    pub fn checked_from_nanos(nanos: i64) -> Option<Time> {
        let sec = i32::try_from(nanos.div_euclid(Self::NANOS_PER_SEC)).ok()?;
        let nanosec = u32::try_from(nanos.rem_euclid(Self::NANOS_PER_SEC)).ok()?;
        Some(Time { sec, nanosec })
    }

    /// Converts signed nanoseconds since the epoch, saturating to [`Time::MIN`] / [`Time::MAX`]
    /// outside the representable range (about ±68 years around 1970).
    pub fn from_nanos(nanos: i64) -> Time {
        match Self::checked_from_nanos(nanos) {
            Some(t) => t,
            None if nanos < 0 => Time::MIN,
            None => Time::MAX,
        }
    }

    /// Signed nanoseconds since the epoch. Never overflows: even a malformed
    /// `nanosec > 999_999_999` is simply added.
    pub fn to_nanos(self) -> i64 {
        i64::from(self.sec) * Self::NANOS_PER_SEC + i64::from(self.nanosec)
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

// ---------------------------------------------------------------------------------------------
// sensor_msgs
// ---------------------------------------------------------------------------------------------

/// `sensor_msgs/msg/Image`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    /// `uint8` in the `.msg` (unlike `PointCloud2::is_bigendian`, which is `bool`).
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `sensor_msgs/msg/RegionOfInterest`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

/// `sensor_msgs/msg/CameraInfo`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [f64; 9],
    pub r: [f64; 9],
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}

/// `sensor_msgs/msg/PointField`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    /// One of the associated constants [`PointField::INT8`] .. [`PointField::FLOAT64`].
    pub datatype: u8,
    pub count: u32,
}

impl PointField {
    pub const INT8: u8 = 1;
    pub const UINT8: u8 = 2;
    pub const INT16: u8 = 3;
    pub const UINT16: u8 = 4;
    pub const INT32: u8 = 5;
    pub const UINT32: u8 = 6;
    pub const FLOAT32: u8 = 7;
    pub const FLOAT64: u8 = 8;
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointCloud2 {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}

// ---------------------------------------------------------------------------------------------
// geometry_msgs / tf2_msgs
// ---------------------------------------------------------------------------------------------

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
///
/// `Default` is the identity rotation (`w = 1`), matching the ROS 2 `.msg` default values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/msg/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

// ---------------------------------------------------------------------------------------------
// visualization_msgs (Jazzy's layout: `Marker` with texture, uv_coordinates and mesh_file)
// ---------------------------------------------------------------------------------------------

/// `std_msgs/msg/ColorRGBA`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRGBA {
    pub r: f32,
    pub g: f32,
    pub b: f32,
    pub a: f32,
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/UVCoordinate`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UVCoordinate {
    pub u: f32,
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeshFile {
    pub filename: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker` (ROS 2 Iron and later; Humble's lacks the fields from
/// `texture_resource` to `mesh_file`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    pub header: Header,
    pub ns: String,
    pub id: i32,
    /// [`Marker::TRIANGLE_LIST`], ...
    pub r#type: i32,
    /// [`Marker::ADD`], [`Marker::DELETE`], [`Marker::DELETEALL`].
    pub action: i32,
    pub pose: Pose,
    pub scale: Vector3,
    pub color: ColorRGBA,
    pub lifetime: Duration,
    pub frame_locked: bool,
    pub points: Vec<Point>,
    pub colors: Vec<ColorRGBA>,
    pub texture_resource: String,
    pub texture: CompressedImage,
    pub uv_coordinates: Vec<UVCoordinate>,
    pub text: String,
    pub mesh_resource: String,
    pub mesh_file: MeshFile,
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    pub const TRIANGLE_LIST: i32 = 11;
    pub const ADD: i32 = 0;
    pub const DELETE: i32 = 2;
    pub const DELETEALL: i32 = 3;
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    pub markers: Vec<Marker>,
}

// ---------------------------------------------------------------------------------------------
// diagnostic_msgs
// ---------------------------------------------------------------------------------------------

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// `byte` in the `.msg`: one of [`DiagnosticStatus::OK`] .. [`DiagnosticStatus::STALE`].
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

/// `rosgraph_msgs/msg/Clock`: simulated time on `/clock` (a simulator, `ros2 bag play --clock`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}

// ---------------------------------------------------------------------------------------------
// CDR payloads
// ---------------------------------------------------------------------------------------------

/// Encapsulation header written by [`to_cdr`]: representation `CDR_LE` (`0x0001`), options 0.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Errors from [`to_cdr`] / [`from_cdr`].
#[derive(Debug, thiserror::Error)]
pub enum MsgError {
    /// Fewer than 4 bytes: not even an encapsulation header.
    #[error("CDR payload too short for the 4-byte encapsulation header ({len} bytes)")]
    MissingHeader { len: usize },
    /// The representation identifier is not plain CDR (`00 00` big-endian / `00 01` little-endian).
    #[error(
        "unsupported CDR encapsulation {0:02x} {1:02x} (expected 00 01 = CDR_LE or 00 00 = CDR_BE)"
    )]
    BadEncapsulation(u8, u8),
    /// More bytes than alignment padding are left after the message.
    #[error("{0} unexpected trailing bytes after the CDR message (wrong message type?)")]
    TrailingBytes(usize),
    /// The body does not decode as this message type (truncated, bad bool or string, ...), or
    /// the message cannot be encoded.
    #[error("CDR: {0}")]
    Cdr(#[from] cdr_encoding::Error),
}

/// Serialises a message to a full CDR payload: the encapsulation header `00 01 00 00`
/// (`CDR_LE`) followed by the little-endian CDR body, exactly as on the wire and in
/// rosbag2 / MCAP. Alignment is relative to the start of the body (after the header); no
/// trailing padding is appended (rosbags does the same; DDS implementations may pad to 4).
pub fn to_cdr<T: Serialize>(msg: &T) -> Result<Vec<u8>, MsgError> {
    // The body is encoded on its own so that alignment counts from its start.
    let body = cdr_encoding::to_vec::<T, byteorder::LittleEndian>(msg)?;
    let mut payload = Vec::with_capacity(4 + body.len());
    payload.extend_from_slice(&CDR_LE_HEADER);
    payload.extend_from_slice(&body);
    Ok(payload)
}

/// Parses a full CDR payload (encapsulation header + body) as produced by [`to_cdr`], a DDS
/// writer or a rosbag2 / MCAP file.
///
/// Accepts `CDR_LE` and `CDR_BE`; the two option bytes are ignored. Up to 3 trailing bytes
/// (the padding DDS implementations add to reach a multiple of 4) are allowed; more is an
/// error, which usually means the payload is of a different message type.
pub fn from_cdr<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, MsgError> {
    let (header, body) = match bytes.split_first_chunk::<4>() {
        Some(split) => split,
        None => return Err(MsgError::MissingHeader { len: bytes.len() }),
    };
    let (value, used) = match (header[0], header[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body)?,
        (0x00, 0x00) => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body)?,
        (a, b) => return Err(MsgError::BadEncapsulation(a, b)),
    };
    let rest = body.len().saturating_sub(used);
    if rest >= 4 {
        return Err(MsgError::TrailingBytes(rest));
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_nanos_round_trip_and_negative() {
        for n in [
            0i64,
            1,
            -1,
            999_999_999,
            -999_999_999,
            -1_000_000_000,
            -1_500_000_000,
            1_700_000_000_123_456_789,
        ] {
            assert_eq!(Time::from_nanos(n).to_nanos(), n, "{n}");
        }
        assert_eq!(
            Time::from_nanos(-1),
            Time {
                sec: -1,
                nanosec: 999_999_999
            }
        );
        assert_eq!(
            Time::from_nanos(-1_500_000_000),
            Time {
                sec: -2,
                nanosec: 500_000_000
            }
        );
        assert_eq!(Time::from_nanos(i64::MAX), Time::MAX);
        assert_eq!(Time::from_nanos(i64::MIN), Time::MIN);
        assert_eq!(Time::checked_from_nanos(i64::MAX), None);
        assert_eq!(Time::MIN.to_nanos(), i64::from(i32::MIN) * 1_000_000_000);
    }

    #[test]
    fn big_endian_payload_is_accepted() {
        // Time { sec: 1, nanosec: 2 } as CDR_BE.
        let be = [0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 2];
        let t: Time = from_cdr(&be).unwrap();
        assert_eq!(t, Time { sec: 1, nanosec: 2 });
    }

    #[test]
    fn rejects_bad_header_and_trailing_bytes() {
        assert!(matches!(
            from_cdr::<Time>(&[0, 1]),
            Err(MsgError::MissingHeader { len: 2 })
        ));
        assert!(matches!(
            from_cdr::<Time>(&[0, 7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]),
            Err(MsgError::BadEncapsulation(0, 7))
        ));
        let mut bytes = to_cdr(&Time { sec: 3, nanosec: 4 }).unwrap();
        bytes.extend_from_slice(&[0, 0, 0]); // DDS-style padding: fine
        assert!(from_cdr::<Time>(&bytes).is_ok());
        bytes.push(0);
        assert!(matches!(
            from_cdr::<Time>(&bytes),
            Err(MsgError::TrailingBytes(4))
        ));
    }

    #[test]
    fn quaternion_default_is_identity() {
        assert_eq!(Quaternion::default().w, 1.0);
    }
}
