//! Images in: ROS image messages checked ([`check_image`]) and converted into the engine's
//! images ([`image_to_rgba8`]). (The messages out: `out_messages.rs`.) No DDS, unit-tested.

use rayon::prelude::*;

use crate::image::{PackedFormat, PackedImage, Rgba8Image};
use crate::msgs::Image;

/// The largest image side accepted from a message, pixels (as `virtual_width`'s range). A
/// larger claim is refused before any size arithmetic or allocation.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Why an input image cannot be used. Every variant names the camera.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    #[error("camera '{camera}': unsupported image encoding '{encoding}' (supported: rgb8, bgr8, rgba8, bgra8, mono8, mono16, and 8UC1, 8UC3, 8UC4, 16UC1 read as mono8, bgr8, bgra8, mono16)")]
    UnsupportedEncoding { camera: String, encoding: String },
    #[error("camera '{camera}': empty image ({width}x{height})")]
    Empty {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}': image of {width}x{height} is larger than the {MAX_IMAGE_SIDE} pixels per side this node accepts")]
    TooLarge {
        camera: String,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}': step {step} is smaller than one row ({width} pixels x {bytes_per_pixel} bytes of {encoding} = {row_bytes})")]
    StepTooSmall {
        camera: String,
        encoding: String,
        width: u32,
        bytes_per_pixel: u32,
        step: u32,
        row_bytes: u64,
    },
    #[error("camera '{camera}': {len} data bytes, but {width}x{height} {encoding} with step {step} needs at least {needed}")]
    DataTooShort {
        camera: String,
        encoding: String,
        width: u32,
        height: u32,
        step: u32,
        len: usize,
        needed: u64,
    },
}

/// Bytes per pixel of a supported encoding.
fn bytes_per_pixel(encoding: &str) -> Option<u32> {
    match encoding {
        // 8UC3 and 8UC4: OpenCV's BGR order, as cv_bridge hands a cv::Mat over.
        "rgb8" | "bgr8" | "8UC3" => Some(3),
        "rgba8" | "bgra8" | "8UC4" => Some(4),
        "mono8" | "8UC1" => Some(1),
        "mono16" | "16UC1" => Some(2),
        _ => None,
    }
}

/// The layout of a valid image message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageLayout {
    pub bytes_per_pixel: u32,
    /// Bytes of pixels in one row (without padding).
    pub row_bytes: u64,
}

/// Checks the header of an image message against its data, as [`image_to_rgba8`] needs it:
/// a supported encoding, a size that is non-zero and at most [`MAX_IMAGE_SIDE`] per side,
/// `step` at least one row, and at least `step * (height - 1) + row` data bytes (computed in
/// `u64`). The pipeline checks this when a set is formed; nothing is allocated.
pub fn check_image(camera: &str, msg: &Image) -> Result<ImageLayout, ConvertError> {
    let bpp = bytes_per_pixel(&msg.encoding).ok_or_else(|| ConvertError::UnsupportedEncoding {
        camera: camera.to_string(),
        encoding: msg.encoding.clone(),
    })?;
    let (width, height, step) = (msg.width, msg.height, msg.step);
    if width == 0 || height == 0 {
        return Err(ConvertError::Empty {
            camera: camera.to_string(),
            width,
            height,
        });
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(ConvertError::TooLarge {
            camera: camera.to_string(),
            width,
            height,
        });
    }
    // u32 x u32 products cannot overflow u64.
    let row_bytes = u64::from(width) * u64::from(bpp);
    if u64::from(step) < row_bytes {
        return Err(ConvertError::StepTooSmall {
            camera: camera.to_string(),
            encoding: msg.encoding.clone(),
            width,
            bytes_per_pixel: bpp,
            step,
            row_bytes,
        });
    }
    let needed = u64::from(step) * u64::from(height - 1) + row_bytes;
    if (msg.data.len() as u64) < needed {
        return Err(ConvertError::DataTooShort {
            camera: camera.to_string(),
            encoding: msg.encoding.clone(),
            width,
            height,
            step,
            len: msg.data.len(),
            needed,
        });
    }
    Ok(ImageLayout {
        bytes_per_pixel: bpp,
        row_bytes,
    })
}

/// Converts a `sensor_msgs/Image` (rgb8, bgr8, rgba8, bgra8, mono8, mono16; 8UC1, 8UC3, 8UC4,
/// 16UC1 as mono8, bgr8, bgra8, mono16) into an
/// [`Rgba8Image`], honouring `step` and, for mono16, `is_bigendian` (any non-zero value is
/// big-endian; scaled to 8 bits by the high byte). The last row may omit its padding.
///
/// Never panics and never allocates more than the message's data justifies: the header is
/// checked first ([`check_image`]).
pub fn image_to_rgba8(camera: &str, msg: &Image) -> Result<Rgba8Image, ConvertError> {
    let ImageLayout { row_bytes, .. } = check_image(camera, msg)?;
    let (width, height, step) = (msg.width, msg.height, msg.step);
    // From here every row lies inside `data` (checked above), so the sizes fit in usize.
    let (width_px, row_bytes) = (width as usize, row_bytes as usize);
    let fill = row_filler(&msg.encoding, msg.is_bigendian != 0);
    let mut pixels = Vec::with_capacity(width_px * height as usize);
    for row in msg.data.chunks(step.max(1) as usize).take(height as usize) {
        fill(row.get(..row_bytes).unwrap_or(&[]), &mut pixels);
    }
    if matches!(msg.encoding.as_str(), "mono16" | "16UC1") {
        say_narrow_mono16(camera, msg, row_bytes);
    }
    Ok(Rgba8Image {
        width,
        height,
        pixels,
    })
}

/// Logs [`crate::image::narrow_mono16_warning`] once per camera (a healthy image is read up to its first
/// value of 4096 or more; nothing allocated per frame).
fn say_narrow_mono16(camera: &str, msg: &Image, row_bytes: usize) {
    static SAID: parking_lot::Mutex<Vec<String>> = parking_lot::const_mutex(Vec::new());
    if SAID.lock().iter().any(|c| c == camera) {
        return;
    }
    let Some(max) = narrow_mono16_max(msg, row_bytes) else {
        return;
    };
    if let Some(warning) = crate::image::narrow_mono16_warning(&format!("camera '{camera}'"), max) {
        let mut said = SAID.lock();
        if !said.iter().any(|c| c == camera) && said.len() < 4096 {
            said.push(camera.to_string());
            tracing::warn!("{warning}");
        }
    }
}

/// The largest value of a 16-bit image whose values all lie below 4096; None as soon as one
/// does not (a healthy image is read no further than its first bright pixel).
fn narrow_mono16_max(msg: &Image, row_bytes: usize) -> Option<u16> {
    let big_endian = msg.is_bigendian != 0;
    let rows = msg
        .data
        .chunks(msg.step.max(1) as usize)
        .take(msg.height as usize);
    let mut max = 0u16;
    for row in rows {
        for p in row.get(..row_bytes).unwrap_or(&[]).chunks_exact(2) {
            let v = if big_endian {
                u16::from_be_bytes([p[0], p[1]])
            } else {
                u16::from_le_bytes([p[0], p[1]])
            };
            if v >= 4096 {
                return None;
            }
            max = max.max(v);
        }
    }
    Some(max)
}

/// A set's images converted ([`image_to_rgba8`]), the cameras in parallel on rayon's threads
/// (the engine's thread waits for them); `name(i)` is image `i`'s camera. The first image that
/// cannot be converted fails the set.
pub fn set_to_rgba8<'n>(
    images: &[Image],
    name: impl Fn(usize) -> &'n str + Sync,
) -> Result<Vec<Rgba8Image>, ConvertError> {
    images
        .par_iter()
        .enumerate()
        .map(|(i, msg)| image_to_rgba8(name(i), msg))
        .collect()
}

/// [`set_to_rgba8`] of the images `wanted` (the others None).
pub fn some_to_rgba8<'n>(
    images: &[Image],
    name: impl Fn(usize) -> &'n str + Sync,
    wanted: impl Fn(usize) -> bool + Sync,
) -> Result<Vec<Option<Rgba8Image>>, ConvertError> {
    images
        .par_iter()
        .enumerate()
        .map(|(i, msg)| wanted(i).then(|| image_to_rgba8(name(i), msg)).transpose())
        .collect()
}

/// The message's bytes as an engine that unpacks on the device takes them
/// ([`PackedImage`]): `rgb8`, `bgr8` or `mono8`, rows without padding, a whole number of 4-byte
/// words (every even-sized image). None for anything else (converted on the host instead).
pub fn packed_view(msg: &Image) -> Option<PackedImage<'_>> {
    let format = match msg.encoding.as_str() {
        "rgb8" => PackedFormat::Rgb8,
        "bgr8" | "8UC3" => PackedFormat::Bgr8,
        "mono8" | "8UC1" => PackedFormat::Mono8,
        _ => return None,
    };
    let row = msg.width as usize * format.bytes_per_pixel();
    let len = row * msg.height as usize;
    let bytes = msg.data.get(..len)?;
    (msg.step as usize == row && len.is_multiple_of(4) && len > 0).then_some(PackedImage {
        width: msg.width,
        height: msg.height,
        format,
        bytes,
    })
}

/// One row of a checked encoding into packed pixels (`Rgba8Image::pack`'s layout): the
/// encoding is matched once per image, each loop is one kind of pixel (the compiler vectorises
/// them; a match per pixel cost several times the copy).
fn row_filler(encoding: &str, big_endian: bool) -> fn(&[u8], &mut Vec<u32>) {
    fn rgb(row: &[u8], out: &mut Vec<u32>) {
        out.extend(
            row.chunks_exact(3)
                .map(|p| u32::from_le_bytes([p[0], p[1], p[2], 0xff])),
        );
    }
    fn bgr(row: &[u8], out: &mut Vec<u32>) {
        out.extend(
            row.chunks_exact(3)
                .map(|p| u32::from_le_bytes([p[2], p[1], p[0], 0xff])),
        );
    }
    fn rgba(row: &[u8], out: &mut Vec<u32>) {
        out.extend(
            row.chunks_exact(4)
                .map(|p| u32::from_le_bytes([p[0], p[1], p[2], p[3]]) | 0xff00_0000),
        );
    }
    fn bgra(row: &[u8], out: &mut Vec<u32>) {
        out.extend(row.chunks_exact(4).map(|p| {
            let v = u32::from_le_bytes([p[0], p[1], p[2], p[3]]);
            (v & 0x0000_ff00) | ((v >> 16) & 0xff) | ((v & 0xff) << 16) | 0xff00_0000
        }));
    }
    fn grey(v: u8) -> u32 {
        (u32::from(v) * 0x01_0101) | 0xff00_0000
    }
    fn mono8(row: &[u8], out: &mut Vec<u32>) {
        out.extend(row.iter().map(|v| grey(*v)));
    }
    // 16 bits scaled to 8 by the high byte.
    fn mono16_le(row: &[u8], out: &mut Vec<u32>) {
        out.extend(row.chunks_exact(2).map(|p| grey(p[1])));
    }
    fn mono16_be(row: &[u8], out: &mut Vec<u32>) {
        out.extend(row.chunks_exact(2).map(|p| grey(p[0])));
    }
    match encoding {
        "rgb8" => rgb,
        "bgr8" | "8UC3" => bgr,
        "rgba8" => rgba,
        "bgra8" | "8UC4" => bgra,
        "mono16" | "16UC1" if big_endian => mono16_be,
        "mono16" | "16UC1" => mono16_le,
        // mono8 and 8UC1, the rest of `bytes_per_pixel`'s encodings.
        _ => mono8,
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

    /// Every encoding, odd widths, row padding and a last row without it: each pixel as the
    /// per-pixel rule (`Rgba8Image::pack` of the named channels) says.
    #[test]
    fn every_encoding_matches_the_per_pixel_rule() {
        let encodings = [
            ("rgb8", 3),
            ("bgr8", 3),
            ("rgba8", 4),
            ("bgra8", 4),
            ("8UC3", 3),
            ("8UC4", 4),
            ("mono8", 1),
            ("8UC1", 1),
            ("mono16", 2),
            ("16UC1", 2),
        ];
        for (encoding, bpp) in encodings {
            for big_endian in [0u8, 1] {
                let (width, height, pad) = (37u32, 5u32, 3u32);
                let step = width * bpp + pad;
                let len = (step * height - pad) as usize;
                let data: Vec<u8> = (0..len).map(|i| (i * 31 % 253) as u8).collect();
                let mut m = msg(encoding, width, height, step, data.clone());
                m.is_bigendian = big_endian;
                let out = image_to_rgba8("c", &m).unwrap();
                assert_eq!(out.pixels.len(), (width * height) as usize);
                for y in 0..height as usize {
                    for x in 0..width as usize {
                        let p = &data[y * step as usize + x * bpp as usize..][..bpp as usize];
                        let want = match (encoding, p) {
                            ("rgb8" | "rgba8", [r, g, b, ..]) => Rgba8Image::pack(*r, *g, *b),
                            ("bgr8" | "bgra8" | "8UC3" | "8UC4", [b, g, r, ..]) => {
                                Rgba8Image::pack(*r, *g, *b)
                            }
                            (_, [lo, hi]) => {
                                let v = if big_endian == 1 { *lo } else { *hi };
                                Rgba8Image::pack(v, v, v)
                            }
                            (_, [v]) => Rgba8Image::pack(*v, *v, *v),
                            _ => unreachable!(),
                        };
                        let got = out.pixels[y * width as usize + x];
                        assert_eq!(
                            got, want,
                            "{encoding} big-endian {big_endian} at ({x}, {y})"
                        );
                    }
                }
            }
        }
    }

    /// The messages an engine may unpack itself, and their bytes unpacked on the host
    /// (`PackedImage::to_rgba8`, the `unpack` stage's twin) as `image_to_rgba8` converts them.
    #[test]
    fn packed_views_are_the_messages_bytes_and_unpack_as_converted() {
        let data = |n: usize| (0..n).map(|i| (i * 37 % 251) as u8).collect::<Vec<u8>>();
        for (encoding, bpp) in [("rgb8", 3), ("bgr8", 3), ("mono8", 1), ("8UC1", 1)] {
            let m = msg(encoding, 6, 4, 6 * bpp, data(24 * bpp as usize));
            let view = packed_view(&m).unwrap_or_else(|| panic!("{encoding}"));
            assert_eq!(view.bytes, &m.data[..]);
            assert_eq!(
                view.to_rgba8(),
                image_to_rgba8("c", &m).unwrap(),
                "{encoding}"
            );
        }
        // Row padding, 16 bits, RGBA, and a size that is not a whole number of words: not.
        assert!(packed_view(&msg("rgb8", 6, 4, 20, data(80))).is_none());
        assert!(packed_view(&msg("mono16", 6, 4, 12, data(48))).is_none());
        assert!(packed_view(&msg("rgba8", 6, 4, 24, data(96))).is_none());
        assert!(packed_view(&msg("rgb8", 5, 3, 15, data(45))).is_none());
        // Too few bytes: not a view past the data.
        assert!(packed_view(&msg("rgb8", 6, 4, 18, data(71))).is_none());
    }

    #[test]
    fn twelve_bit_data_in_mono16_is_found_and_said() {
        // 2x1, step 6 (padding never read): 4000 and 300, little- and big-endian.
        let le = msg("mono16", 2, 1, 6, vec![0xa0, 0x0f, 0x2c, 0x01, 0xff, 0xff]);
        assert_eq!(narrow_mono16_max(&le, 4), Some(4000));
        let mut be = msg("mono16", 2, 1, 6, vec![0x0f, 0xa0, 0x01, 0x2c, 0xff, 0xff]);
        be.is_bigendian = 1;
        assert_eq!(narrow_mono16_max(&be, 4), Some(4000));
        // One value of 4096: 16-bit data.
        let wide = msg("mono16", 2, 1, 4, vec![0x00, 0x10, 0x2c, 0x01]);
        assert_eq!(narrow_mono16_max(&wide, 4), None);
        let said = crate::image::narrow_mono16_warning("camera 'c'", 4000).expect("said");
        assert!(said.starts_with("camera 'c': every 16-bit value is below 4096 (at most 4000"));
        // A dark image (a covered lens) is not 12-bit data.
        assert_eq!(crate::image::narrow_mono16_warning("camera 'c'", 255), None);
        assert_eq!(
            crate::image::narrow_mono16_warning("camera 'c'", 4096),
            None
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
    fn mono16_big_and_little_endian_rows_with_padding() {
        // 2x2 mono16, step 6 (2 bytes of padding per row): 0x1234, 0xABCD / 0x0000, 0xFFFF.
        let le = [0x34, 0x12, 0xCD, 0xAB, 9, 9, 0x00, 0x00, 0xFF, 0xFF];
        let be = [0x12, 0x34, 0xAB, 0xCD, 9, 9, 0x00, 0x00, 0xFF, 0xFF];
        let grey = |g: u8| Rgba8Image::pack(g, g, g);
        let expected = vec![grey(0x12), grey(0xAB), grey(0x00), grey(0xFF)];
        let out = image_to_rgba8("c", &msg("mono16", 2, 2, 6, le.to_vec())).unwrap();
        assert_eq!(out.pixels, expected);
        let mut m = msg("16UC1", 2, 2, 6, be.to_vec());
        m.is_bigendian = 1;
        assert_eq!(image_to_rgba8("c", &m).unwrap().pixels, expected);
        // Any non-zero is_bigendian means big-endian.
        m.is_bigendian = 7;
        assert_eq!(image_to_rgba8("c", &m).unwrap().pixels, expected);
    }

    #[test]
    fn unsupported_encoding_names_camera_and_encoding() {
        let e = image_to_rgba8("left", &msg("yuv422", 1, 1, 2, vec![0, 0])).unwrap_err();
        assert_eq!(
            e,
            ConvertError::UnsupportedEncoding {
                camera: "left".into(),
                encoding: "yuv422".into()
            }
        );
        assert!(e.to_string().contains("'left'") && e.to_string().contains("yuv422"));
        for enc in ["", "32FC1", "RGB8", "bayer_rggb8"] {
            assert!(matches!(
                image_to_rgba8("c", &msg(enc, 1, 1, 4, vec![0; 4])),
                Err(ConvertError::UnsupportedEncoding { .. })
            ));
        }
    }

    #[test]
    fn step_smaller_than_a_row_is_an_error() {
        let e = image_to_rgba8("cam1", &msg("rgb8", 2, 2, 5, vec![0; 100])).unwrap_err();
        assert!(
            matches!(
                e,
                ConvertError::StepTooSmall {
                    step: 5,
                    row_bytes: 6,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("'cam1'") && e.to_string().contains("step 5"));
        assert!(matches!(
            image_to_rgba8("c", &msg("mono8", 4, 1, 0, vec![0; 4])),
            Err(ConvertError::StepTooSmall { .. })
        ));
    }

    #[test]
    fn data_shorter_than_the_rows_is_an_error() {
        // 2 rows of step 6: 6 + 6 = 12 bytes needed (the last row's padding may be omitted,
        // here there is none), 11 given.
        let e = image_to_rgba8("cam2", &msg("rgb8", 2, 2, 6, vec![0; 11])).unwrap_err();
        assert!(
            matches!(
                e,
                ConvertError::DataTooShort {
                    len: 11,
                    needed: 12,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("'cam2'"));
        // Last row may omit its padding: step 4, width 2 mono8, 2 rows = 4 + 2 bytes.
        assert!(image_to_rgba8("c", &msg("mono8", 2, 2, 4, vec![0; 6])).is_ok());
        assert!(matches!(
            image_to_rgba8("c", &msg("mono8", 2, 2, 4, vec![0; 5])),
            Err(ConvertError::DataTooShort { needed: 6, .. })
        ));
        // No data at all.
        assert!(matches!(
            image_to_rgba8("c", &msg("mono16", 3, 3, 6, vec![])),
            Err(ConvertError::DataTooShort {
                len: 0,
                needed: 18,
                ..
            })
        ));
    }

    #[test]
    fn zero_width_or_height_is_an_error() {
        for (w, h) in [(0, 2), (2, 0), (0, 0)] {
            let e = image_to_rgba8("cam3", &msg("rgb8", w, h, 6, vec![0; 12])).unwrap_err();
            assert_eq!(
                e,
                ConvertError::Empty {
                    camera: "cam3".into(),
                    width: w,
                    height: h
                }
            );
        }
    }

    #[test]
    fn absurd_sizes_are_refused_without_allocating() {
        // 100000 x 100000 with 16 bytes of data: refused by the side limit.
        let e = image_to_rgba8("cam4", &msg("rgb8", 100_000, 100_000, 300_000, vec![0; 16]))
            .unwrap_err();
        assert!(
            matches!(e, ConvertError::TooLarge { width: 100_000, .. }),
            "{e:?}"
        );
        assert!(e.to_string().contains("'cam4'"));
        assert!(matches!(
            image_to_rgba8("c", &msg("rgba8", u32::MAX, u32::MAX, u32::MAX, vec![])),
            Err(ConvertError::TooLarge { .. })
        ));
        // Within the limit but far more than the data: the u64 size check refuses it.
        let side = MAX_IMAGE_SIDE;
        let e = image_to_rgba8("c", &msg("rgba8", side, side, side * 4, vec![0; 64])).unwrap_err();
        assert_eq!(
            e,
            ConvertError::DataTooShort {
                camera: "c".into(),
                encoding: "rgba8".into(),
                width: side,
                height: side,
                step: side * 4,
                len: 64,
                needed: u64::from(side) * u64::from(side) * 4,
            }
        );
        // A step near u32::MAX on many rows does not overflow.
        assert!(matches!(
            image_to_rgba8("c", &msg("mono8", 1, side, u32::MAX, vec![0; 8])),
            Err(ConvertError::DataTooShort { .. })
        ));
    }
}
