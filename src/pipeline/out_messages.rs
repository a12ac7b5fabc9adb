//! Messages out: depth, confidence and cost maps as `32FC1` images, the selection as `rgb8`,
//! point clouds as `sensor_msgs/PointCloud2`. No DDS, unit-tested.

use glam::DVec2;

use crate::geometry::{CameraModel, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};
use crate::msgs::{Header, Image, PointCloud2, PointField};
use crate::sweep::gpu::{copies, HostCopies};

/// A `32FC1` little-endian image message (step = 4 * width).
pub fn f32_image_msg(header: &Header, image: &ImageF32) -> Image {
    let size = (image.width, image.height);
    f32_values_msg(header, size, &image.data, HostCopies::Auto)
}

/// [`f32_image_msg`] of a `width` x `height` map's `values` (a map lent out of the engine's
/// readback buffer: `sweep::gpu::LentMaps`), the copy split over rayon's threads as
/// `copies` says (`HostCopies::Auto`: on a host of 8+ threads, a megapixel map).
pub fn f32_values_msg(
    header: &Header,
    (width, height): (u32, u32),
    values: &[f32],
    copies: HostCopies,
) -> Image {
    // On a little-endian host the floats' bytes as they lie: one copy (a value at a time took
    // 3-4 times as long; a megapixel map is 4.9 MB, and depth and confidence go out every set).
    let data = if cfg!(target_endian = "little") {
        let bytes = bytemuck::cast_slice::<f32, u8>(values);
        copies::to_vec(bytes, copies.split(bytes.len()))
    } else {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    };
    Image {
        header: header.clone(),
        height,
        width,
        encoding: "32FC1".to_string(),
        is_bigendian: 0,
        step: width.saturating_mul(4),
        data,
    }
}

/// A reference's depth and confidence as `32FC1` messages ([`f32_image_msg`]), built at once on
/// two of rayon's threads (every set makes both; at a megapixel each is a 4.9 MB copy).
pub fn depth_and_confidence_msgs(
    header: &Header,
    depth: &ImageF32,
    confidence: &ImageF32,
) -> (Image, Image) {
    rayon::join(
        || f32_image_msg(header, depth),
        || f32_image_msg(header, confidence),
    )
}

/// [`depth_and_confidence_msgs`] of a reference's maps lent out of the WGSL engine's readback
/// buffer: the messages' bytes copied straight from where the GPU put them.
pub fn lent_depth_and_confidence_msgs(
    header: &Header,
    maps: &crate::sweep::gpu::LentMaps,
    copies: HostCopies,
) -> (Image, Image) {
    let size = (maps.width(), maps.height());
    rayon::join(
        || f32_values_msg(header, size, maps.depth_m(), copies),
        || f32_values_msg(header, size, maps.confidence(), copies),
    )
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

/// An organised `sensor_msgs/PointCloud2` (height x width of `depth`) in the header's frame:
/// fields x, y, z (FLOAT32, metres) and rgb (FLOAT32, [`pack_rgb_f32`]) from `colour` (same
/// size as `depth`, else black). Invalid depths (NaN, non-positive) give NaN x, y, z. `model`
/// back-projects the pixel centres (integer coordinates, as in ROS) into its camera, which
/// `frame_from_cam` places in the header's frame (a rectified reference: R, and P's
/// translation; identity for a raw one).
pub fn point_cloud_msg(
    header: &Header,
    depth: &ImageF32,
    colour: Option<&Rgba8Image>,
    model: &CameraModel,
    frame_from_cam: &RigidTransform,
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
    // The model's rays, shared from set to set (a distorted model's are a Newton solve each);
    // without distortion, or for a depth image of another size than the model's, each pixel is
    // unprojected here.
    let (mw, mh) = (model.intrinsics.width_px, model.intrinsics.height_px);
    let grid = (mw == width && mh == height)
        .then(|| model.distorted_pixel_rays())
        .flatten();
    for (i, &z) in depth.data.iter().enumerate() {
        let u = (i % width.max(1) as usize) as f64;
        let v = (i / width.max(1) as usize) as f64;
        let ray = (z.is_finite() && z > 0.0)
            .then(|| match &grid {
                Some(rays) => rays.get(i).copied().flatten(),
                None => model.unproject_z1(DVec2::new(u, v)),
            })
            .flatten();
        let [x, y, z] = match ray {
            Some(ray) if *frame_from_cam == RigidTransform::IDENTITY => {
                let z64 = f64::from(z);
                [(ray.x * z64) as f32, (ray.y * z64) as f32, z]
            }
            Some(ray) => {
                let p = frame_from_cam.transform_point(ray * f64::from(z));
                [p.x as f32, p.y as f32, p.z as f32]
            }
            None => [f32::NAN; 3],
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
        assert_eq!(m.data.len(), 8);
        assert!(f32::from_le_bytes([m.data[4], m.data[5], m.data[6], m.data[7]]).is_nan());
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
        let m = point_cloud_msg(
            &header,
            &depth,
            Some(&colour),
            &model,
            &RigidTransform::IDENTITY,
        );
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
