//! Conversions between ROS image messages and the engine's images (no DDS, unit-tested).

use glam::DVec2;

use crate::geometry::CameraModel;
use crate::image::{ImageF32, Rgba8Image};
use crate::msgs::{Header, Image, PointCloud2, PointField};

/// Why an input image cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    #[error("camera '{camera}': unsupported image encoding '{encoding}' (supported: rgb8, bgr8, rgba8, bgra8, mono8, mono16)")]
    UnsupportedEncoding { camera: String, encoding: String },
    #[error("camera '{camera}': malformed image ({width}x{height}, step {step}, {len} data bytes): {reason}")]
    Malformed {
        camera: String,
        width: u32,
        height: u32,
        step: u32,
        len: usize,
        reason: String,
    },
}

/// Bytes per pixel of a supported encoding.
fn bytes_per_pixel(encoding: &str) -> Option<usize> {
    match encoding {
        "rgb8" | "bgr8" => Some(3),
        "rgba8" | "bgra8" => Some(4),
        "mono8" | "8UC1" => Some(1),
        "mono16" | "16UC1" => Some(2),
        _ => None,
    }
}

/// Converts a `sensor_msgs/Image` (rgb8, bgr8, rgba8, bgra8, mono8, mono16) into an
/// [`Rgba8Image`], honouring `step` and, for mono16, `is_bigendian` (scaled to 8 bits by the
/// high byte). Never panics on malformed messages.
pub fn image_to_rgba8(camera: &str, msg: &Image) -> Result<Rgba8Image, ConvertError> {
    let bpp = bytes_per_pixel(&msg.encoding).ok_or_else(|| ConvertError::UnsupportedEncoding {
        camera: camera.to_string(),
        encoding: msg.encoding.clone(),
    })?;
    let malformed = |reason: String| ConvertError::Malformed {
        camera: camera.to_string(),
        width: msg.width,
        height: msg.height,
        step: msg.step,
        len: msg.data.len(),
        reason,
    };
    if msg.width == 0 || msg.height == 0 {
        return Err(malformed("zero width or height".into()));
    }
    let width = msg.width as usize;
    let height = msg.height as usize;
    let step = msg.step as usize;
    let row_bytes = width
        .checked_mul(bpp)
        .ok_or_else(|| malformed("width overflows".into()))?;
    if step < row_bytes {
        return Err(malformed(format!(
            "step is smaller than width * {bpp} = {row_bytes}"
        )));
    }
    let needed = step
        .checked_mul(height - 1)
        .and_then(|v| v.checked_add(row_bytes))
        .ok_or_else(|| malformed("size overflows".into()))?;
    if msg.data.len() < needed {
        return Err(malformed(format!("needs at least {needed} data bytes")));
    }
    let mut pixels = Vec::with_capacity(width * height);
    let big_endian = msg.is_bigendian != 0;
    for y in 0..height {
        let row = &msg.data[y * step..y * step + row_bytes];
        match msg.encoding.as_str() {
            "rgb8" => pixels.extend(
                row.chunks_exact(3)
                    .map(|p| Rgba8Image::pack(p[0], p[1], p[2])),
            ),
            "bgr8" => pixels.extend(
                row.chunks_exact(3)
                    .map(|p| Rgba8Image::pack(p[2], p[1], p[0])),
            ),
            "rgba8" => pixels.extend(
                row.chunks_exact(4)
                    .map(|p| Rgba8Image::pack(p[0], p[1], p[2])),
            ),
            "bgra8" => pixels.extend(
                row.chunks_exact(4)
                    .map(|p| Rgba8Image::pack(p[2], p[1], p[0])),
            ),
            "mono8" | "8UC1" => pixels.extend(row.iter().map(|&v| Rgba8Image::pack(v, v, v))),
            _ => pixels.extend(row.chunks_exact(2).map(|p| {
                let v = if big_endian {
                    u16::from_be_bytes([p[0], p[1]])
                } else {
                    u16::from_le_bytes([p[0], p[1]])
                };
                let g = (v >> 8) as u8;
                Rgba8Image::pack(g, g, g)
            })),
        }
    }
    Ok(Rgba8Image {
        width: msg.width,
        height: msg.height,
        pixels,
    })
}

/// A `32FC1` little-endian image message (step = 4 * width).
pub fn f32_image_msg(header: &Header, image: &ImageF32) -> Image {
    let mut data = Vec::with_capacity(image.data.len() * 4);
    for v in &image.data {
        data.extend_from_slice(&v.to_le_bytes());
    }
    Image {
        header: header.clone(),
        height: image.height,
        width: image.width,
        encoding: "32FC1".to_string(),
        is_bigendian: 0,
        step: image.width.saturating_mul(4),
        data,
    }
}

/// An `rgb8` image of the selection codes, coloured with [`crate::sweep::selection::colour`].
pub fn selection_msg(header: &Header, width: u32, height: u32, codes: &[u8]) -> Image {
    let mut data = Vec::with_capacity(codes.len() * 3);
    for &code in codes {
        data.extend_from_slice(&crate::sweep::selection::colour(code));
    }
    Image {
        header: header.clone(),
        height,
        width,
        encoding: "rgb8".to_string(),
        is_bigendian: 0,
        step: width.saturating_mul(3),
        data,
    }
}

/// Bytes per point of [`point_cloud_msg`]: x, y, z, rgb (4 x FLOAT32).
pub const POINT_STEP: u32 = 16;

/// The PCL packing of a colour into a FLOAT32 field: the little-endian bytes b, g, r, 0 of a
/// `u32`, reinterpreted.
pub fn pack_rgb_f32(r: u8, g: u8, b: u8) -> f32 {
    f32::from_bits(u32::from_le_bytes([b, g, r, 0]))
}

/// An organised `sensor_msgs/PointCloud2` (height x width of `depth`) in the reference optical
/// frame: fields x, y, z (FLOAT32, metres) and rgb (FLOAT32, [`pack_rgb_f32`]) from `colour`
/// (same size as `depth`, else black). Invalid depths (NaN, non-positive) give NaN x, y, z.
/// `model` back-projects the pixel centres (integer coordinates, as in ROS).
pub fn point_cloud_msg(
    header: &Header,
    depth: &ImageF32,
    colour: Option<&Rgba8Image>,
    model: &CameraModel,
) -> PointCloud2 {
    let (width, height) = (depth.width, depth.height);
    let colour = colour
        .filter(|c| c.width == width && c.height == height && c.pixels.len() == depth.data.len());
    let field = |name: &str, offset: u32| PointField {
        name: name.to_string(),
        offset,
        datatype: PointField::FLOAT32,
        count: 1,
    };
    let mut data = Vec::with_capacity(depth.data.len() * POINT_STEP as usize);
    for (i, &z) in depth.data.iter().enumerate() {
        let u = (i % width.max(1) as usize) as f64;
        let v = (i / width.max(1) as usize) as f64;
        let [x, y, z] = if z.is_finite() && z > 0.0 {
            let ray = model.unproject_z1(DVec2::new(u, v));
            let z64 = f64::from(z);
            [(ray.x * z64) as f32, (ray.y * z64) as f32, z]
        } else {
            [f32::NAN; 3]
        };
        let [r, g, b, _] = colour.map_or([0; 4], |c| Rgba8Image::unpack(c.pixels[i]));
        for value in [x, y, z, pack_rgb_f32(r, g, b)] {
            data.extend_from_slice(&value.to_le_bytes());
        }
    }
    PointCloud2 {
        header: header.clone(),
        height,
        width,
        fields: vec![
            field("x", 0),
            field("y", 4),
            field("z", 8),
            field("rgb", 12),
        ],
        is_bigendian: false,
        point_step: POINT_STEP,
        row_step: width.saturating_mul(POINT_STEP),
        data,
        is_dense: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(encoding: &str, width: u32, height: u32, step: u32, data: Vec<u8>) -> Image {
        Image {
            encoding: encoding.into(),
            width,
            height,
            step,
            data,
            ..Image::default()
        }
    }

    #[test]
    fn colour_encodings_with_padding() {
        // 2x2 with a 1-byte row padding.
        let rgb = msg(
            "rgb8",
            2,
            2,
            7,
            vec![1, 2, 3, 4, 5, 6, 99, 7, 8, 9, 10, 11, 12, 99],
        );
        let out = image_to_rgba8("c", &rgb).unwrap();
        assert_eq!(out.pixels[0], Rgba8Image::pack(1, 2, 3));
        assert_eq!(out.pixels[3], Rgba8Image::pack(10, 11, 12));
        let bgr = msg("bgr8", 1, 1, 3, vec![1, 2, 3]);
        assert_eq!(
            image_to_rgba8("c", &bgr).unwrap().pixels[0],
            Rgba8Image::pack(3, 2, 1)
        );
        let bgra = msg("bgra8", 1, 1, 4, vec![1, 2, 3, 4]);
        assert_eq!(
            image_to_rgba8("c", &bgra).unwrap().pixels[0],
            Rgba8Image::pack(3, 2, 1)
        );
        let rgba = msg("rgba8", 1, 1, 4, vec![1, 2, 3, 4]);
        assert_eq!(
            image_to_rgba8("c", &rgba).unwrap().pixels[0],
            Rgba8Image::pack(1, 2, 3)
        );
        let mono = msg("mono8", 1, 1, 1, vec![9]);
        assert_eq!(
            image_to_rgba8("c", &mono).unwrap().pixels[0],
            Rgba8Image::pack(9, 9, 9)
        );
    }

    #[test]
    fn mono16_endianness() {
        let mut le = msg("mono16", 1, 1, 2, vec![0x34, 0x12]);
        assert_eq!(
            image_to_rgba8("c", &le).unwrap().pixels[0],
            Rgba8Image::pack(0x12, 0x12, 0x12)
        );
        le.is_bigendian = 1;
        assert_eq!(
            image_to_rgba8("c", &le).unwrap().pixels[0],
            Rgba8Image::pack(0x34, 0x34, 0x34)
        );
    }

    #[test]
    fn malformed_and_unsupported_are_errors() {
        let e = image_to_rgba8("left", &msg("yuv422", 1, 1, 2, vec![0, 0])).unwrap_err();
        assert!(e.to_string().contains("left") && e.to_string().contains("yuv422"));
        assert!(image_to_rgba8("c", &msg("rgb8", 2, 2, 5, vec![0; 100])).is_err());
        assert!(image_to_rgba8("c", &msg("rgb8", 2, 2, 6, vec![0; 11])).is_err());
        assert!(image_to_rgba8("c", &msg("rgb8", 0, 2, 6, vec![])).is_err());
        assert!(image_to_rgba8("c", &msg("rgb8", u32::MAX, u32::MAX, u32::MAX, vec![])).is_err());
        // Last row may omit its padding.
        assert!(image_to_rgba8("c", &msg("mono8", 2, 2, 4, vec![0; 6])).is_ok());
    }

    #[test]
    fn f32_message_layout() {
        let img = ImageF32 {
            width: 2,
            height: 1,
            data: vec![1.5, f32::NAN],
        };
        let m = f32_image_msg(&Header::default(), &img);
        assert_eq!(m.step, 8);
        assert_eq!(m.encoding, "32FC1");
        assert_eq!(&m.data[0..4], &1.5f32.to_le_bytes());
    }

    #[test]
    fn point_cloud_layout_and_values() {
        use crate::geometry::PinholeIntrinsics;
        let model = CameraModel::pinhole(PinholeIntrinsics {
            width_px: 2,
            height_px: 1,
            fx_px: 2.0,
            fy_px: 2.0,
            cx_px: 0.0,
            cy_px: 0.0,
        });
        let depth = ImageF32 {
            width: 2,
            height: 1,
            data: vec![f32::NAN, 4.0],
        };
        let colour = Rgba8Image {
            width: 2,
            height: 1,
            pixels: vec![Rgba8Image::pack(1, 2, 3), Rgba8Image::pack(10, 20, 30)],
        };
        let header = Header {
            frame_id: "cam".into(),
            ..Header::default()
        };
        let m = point_cloud_msg(&header, &depth, Some(&colour), &model);
        assert_eq!(
            (m.width, m.height, m.point_step, m.row_step),
            (2, 1, 16, 32)
        );
        assert_eq!(m.header, header);
        assert!(!m.is_dense && !m.is_bigendian);
        let names: Vec<_> = m
            .fields
            .iter()
            .map(|f| (f.name.as_str(), f.offset))
            .collect();
        assert_eq!(names, [("x", 0), ("y", 4), ("z", 8), ("rgb", 12)]);
        assert_eq!(m.data.len(), 32);
        let f =
            |o: usize| f32::from_le_bytes([m.data[o], m.data[o + 1], m.data[o + 2], m.data[o + 3]]);
        assert!(f(0).is_nan() && f(4).is_nan() && f(8).is_nan());
        assert_eq!(&m.data[12..16], &[3, 2, 1, 0]);
        // Pixel (1, 0) at z = 4: x = (1 - 0) / 2 * 4 = 2.
        assert_eq!((f(16), f(20), f(24)), (2.0, 0.0, 4.0));
        assert_eq!(&m.data[28..32], &[30, 20, 10, 0]);
        assert_eq!(pack_rgb_f32(10, 20, 30).to_bits(), 0x000a141e);
    }
}
