//! Compressed images (`sensor_msgs/CompressedImage`) as image_transport's `compressed` plugin
//! publishes them on `<camera>/<image_topic>/compressed`: `format` is
//! `<encoding>; <jpeg|png> compressed <target>` (`rgb8; jpeg compressed bgr8`,
//! `mono8; jpeg compressed mono8`, `bgr8; png compressed bgr8`, ...) or, from older plugins, a
//! bare `jpeg` / `png`.
//!
//! A compressed image goes through the roster and the synchroniser as it came
//! ([`InputImage::Compressed`]), so images the synchroniser drops are never decoded. When a set is complete the calibration
//! decodes its images ([`decode_set`]) in parallel across cameras (rayon), before anything
//! else looks at their sizes: on the thread that pushes inputs (the node's event loop, `bag`'s
//! loop), never the engine's, and before the set can take another one's place in the node's
//! queue for the engine. A set whose image cannot be decoded (corrupt or truncated data, a
//! format that lies about the codec or the channels) is skipped ([`SkipKind::Decode`]) with the
//! reason; one whose decoded size differs from its camera_info is skipped by the calibration's
//! own size check, as a raw image would be.

use std::io::Cursor;

use rayon::prelude::*;

use super::convert::MAX_IMAGE_SIDE;
use super::outcome::{Input, InputImage, Skip, SkipKind};
use crate::msgs::{CompressedImage, Image};
use crate::ros::sync::SyncedSet;

impl Input {
    /// A compressed image of camera `camera` (a `sensor_msgs/CompressedImage`).
    pub fn compressed(camera: usize, image: CompressedImage) -> Self {
        Input::Compressed { camera, image }
    }
}

/// The codecs of image_transport's `compressed` plugin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    Jpeg,
    Png,
}

impl Codec {
    pub fn name(self) -> &'static str {
        match self {
            Codec::Jpeg => "JPEG",
            Codec::Png => "PNG",
        }
    }

    /// The codec whose signature starts `data`, if one of ours.
    fn sniff(data: &[u8]) -> Option<Codec> {
        if data.starts_with(&[0xFF, 0xD8, 0xFF]) {
            Some(Codec::Jpeg)
        } else if data.starts_with(&[0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A]) {
            Some(Codec::Png)
        } else {
            None
        }
    }
}

/// A parsed `format` string.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Format {
    pub codec: Codec,
    /// The encoding of the image before compression (`rgb8` of `rgb8; jpeg compressed bgr8`);
    /// None for a bare `jpeg` / `png`.
    pub original: Option<String>,
}

/// Whether an encoding is colour (Some(true)), grey (Some(false)) or neither we know of.
fn is_colour(encoding: &str) -> Option<bool> {
    match encoding {
        "rgb8" | "bgr8" | "rgba8" | "bgra8" | "rgb16" | "bgr16" | "rgba16" | "bgra16" => Some(true),
        "mono8" | "mono16" | "8UC1" | "16UC1" => Some(false),
        _ => None,
    }
}

/// Parses a `format` as image_transport's `compressed` plugin writes it.
pub fn parse_format(format: &str) -> Option<Format> {
    let codec = |word: &str| match word.to_ascii_lowercase().as_str() {
        "jpeg" | "jpg" => Some(Codec::Jpeg),
        "png" => Some(Codec::Png),
        _ => None,
    };
    match format.split_once(';') {
        None => Some(Format {
            codec: codec(format.trim())?,
            original: None,
        }),
        Some((original, rest)) => {
            let mut words = rest.split_whitespace();
            let codec = codec(words.next()?)?;
            (words.next()? == "compressed").then_some(())?;
            let original = original.trim();
            Some(Format {
                codec,
                original: (!original.is_empty()).then(|| original.to_string()),
            })
        }
    }
}

/// Why a compressed image cannot be used. Every variant names the camera.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error("camera '{camera}': compressed image format '{format}' is not one this node decodes ('<encoding>; jpeg compressed <encoding>', '<encoding>; png compressed <encoding>', 'jpeg' or 'png', as image_transport's compressed plugin writes them)")]
    UnsupportedFormat { camera: String, format: String },
    #[error("camera '{camera}': the format '{format}' says {says}, but the data is {is}")]
    FormatLies {
        camera: String,
        format: String,
        says: String,
        is: String,
    },
    #[error("camera '{camera}': the {codec}'s header says {width}x{height} pixels, more than the {MAX_DECODED_MEGAPIXELS} megapixels this node decodes (refused before decoding)")]
    TooLarge {
        camera: String,
        codec: &'static str,
        width: u32,
        height: u32,
    },
    #[error("camera '{camera}': corrupt or truncated {codec} ({len} bytes, format '{format}'): {reason}")]
    Corrupt {
        camera: String,
        format: String,
        codec: &'static str,
        len: usize,
        reason: String,
    },
}

/// The most pixels a compressed image may decode to, in megapixels (2^20 pixels): a few bytes
/// of JPEG can claim 16384 x 16384 (256 MP, 800 MB of RGB); the largest machine-vision
/// sensors are about 150 MP.
pub const MAX_DECODED_MEGAPIXELS: u64 = 200;

/// Decodes a compressed image into an `rgb8` (colour) or `mono8` (grey)
/// [`Image`] with the same header. A header that claims more than [`MAX_IMAGE_SIDE`] per side
/// or [`MAX_DECODED_MEGAPIXELS`] in all is refused before the pixels are allocated; a JPEG must end with its end-of-image marker (a truncated one is
/// refused, not shown half grey).
pub fn decode(camera: &str, image: &CompressedImage) -> Result<Image, DecodeError> {
    let format = image.format.as_str();
    let data = &image.data;
    let parsed = parse_format(format).ok_or_else(|| DecodeError::UnsupportedFormat {
        camera: camera.to_string(),
        format: format.to_string(),
    })?;
    let lies = |says: String, is: String| DecodeError::FormatLies {
        camera: camera.to_string(),
        format: format.to_string(),
        says,
        is,
    };
    let corrupt = |reason: String| DecodeError::Corrupt {
        camera: camera.to_string(),
        format: format.to_string(),
        codec: parsed.codec.name(),
        len: data.len(),
        reason,
    };
    match Codec::sniff(data) {
        Some(codec) if codec == parsed.codec => {}
        Some(codec) => {
            return Err(lies(
                parsed.codec.name().to_string(),
                format!("a {}", codec.name()),
            ))
        }
        None => {
            return Err(corrupt(format!(
                "no {} signature at the start",
                parsed.codec.name()
            )))
        }
    }
    if parsed.codec == Codec::Jpeg {
        // The end-of-image marker, perhaps followed by padding.
        let end = data.iter().rposition(|&b| b != 0).unwrap_or(0);
        if end < 1 || data[end - 1..=end] != [0xFF, 0xD9] {
            return Err(corrupt("no end-of-image marker (truncated)".into()));
        }
    }
    let image_format = match parsed.codec {
        Codec::Jpeg => image::ImageFormat::Jpeg,
        Codec::Png => image::ImageFormat::Png,
    };
    // The header alone first: the size it claims, before anything is allocated for it.
    let (width, height) =
        image::ImageReader::with_format(Cursor::new(data.as_slice()), image_format)
            .into_dimensions()
            .map_err(|e| corrupt(e.to_string()))?;
    if u64::from(width) * u64::from(height) > MAX_DECODED_MEGAPIXELS << 20 {
        return Err(DecodeError::TooLarge {
            camera: camera.to_string(),
            codec: parsed.codec.name(),
            width,
            height,
        });
    }
    let mut reader = image::ImageReader::with_format(Cursor::new(data.as_slice()), image_format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    reader.limits(limits);
    // A decoder that panics on a malformed stream is a corrupt image, not a crash: zune-jpeg
    // 0.5.15 multiplies a coefficient past i32 on some damaged JPEGs (a panic where overflow
    // checks are on; tests/fixtures/fuzz/README.md).
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.decode()))
        .map_err(|_| corrupt("the decoder failed on the stream (it panicked)".into()))?
        .map_err(|e| corrupt(e.to_string()))?;
    let colour = decoded.color().has_color();
    if let Some(original) = &parsed.original {
        if let Some(says_colour) = is_colour(original) {
            if says_colour != colour {
                let kind = |c: bool| if c { "colour" } else { "grey" };
                return Err(lies(
                    format!("{original} ({})", kind(says_colour)),
                    format!("a {} {}", kind(colour), parsed.codec.name()),
                ));
            }
        }
    }
    let (width, height) = (decoded.width(), decoded.height());
    let (encoding, step, data) = if colour {
        ("rgb8", width * 3, decoded.into_rgb8().into_raw())
    } else {
        ("mono8", width, decoded.into_luma8().into_raw())
    };
    Ok(Image {
        header: image.header.clone(),
        height,
        width,
        encoding: encoding.to_string(),
        is_bigendian: 0,
        step,
        data,
    })
}

/// The images of a complete set with every compressed image decoded, in parallel across
/// cameras; `name(k)` is the camera (index into the configuration's cameras, and its name) of
/// message `k`. The first image that cannot be decoded skips the set.
pub fn decode_set<'n>(
    set: SyncedSet<InputImage>,
    name: impl Fn(usize) -> (usize, &'n str) + Sync,
) -> Result<SyncedSet<Image>, Skip> {
    let SyncedSet {
        stamps_ns,
        messages,
    } = set;
    let compressed = messages
        .iter()
        .any(|m| matches!(m, InputImage::Compressed(_)));
    let decode_one = |(k, image): (usize, InputImage)| match image {
        InputImage::Raw(image) => Ok(image),
        InputImage::Compressed(image) => {
            let (i, camera) = name(k);
            decode(camera, &image).map_err(|e| Skip::new(SkipKind::Decode, Some(i), e.to_string()))
        }
    };
    let messages = if compressed {
        messages
            .into_par_iter()
            .enumerate()
            .map(decode_one)
            .collect::<Result<Vec<Image>, Skip>>()?
    } else {
        messages
            .into_iter()
            .enumerate()
            .map(decode_one)
            .collect::<Result<Vec<Image>, Skip>>()?
    };
    Ok(SyncedSet {
        stamps_ns,
        messages,
    })
}

/// Why an image cannot be compressed ([`compress`]).
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("cannot compress a {0} image (rgb8, bgr8 or mono8, rows without padding)")]
    Layout(String),
    #[error(transparent)]
    Image(#[from] image::ImageError),
}

/// `image` (rgb8, bgr8 or mono8 without row padding) compressed as image_transport's
/// `compressed` plugin does it: colour as a 3-channel JPEG (`jpeg_quality`, the plugin's
/// default 95) or PNG, grey as a 1-channel one, `format` `<encoding>; jpeg compressed bgr8`
/// (`mono8` for grey).
pub fn compress(
    image: &Image,
    codec: Codec,
    jpeg_quality: u8,
) -> Result<CompressedImage, EncodeError> {
    let (w, h) = (image.width, image.height);
    let (colour, bpp) = match image.encoding.as_str() {
        "rgb8" | "bgr8" => (true, 3),
        "mono8" => (false, 1),
        other => return Err(EncodeError::Layout(other.to_string())),
    };
    let len = w as usize * h as usize * bpp;
    if image.step as usize != w as usize * bpp || image.data.len() < len {
        return Err(EncodeError::Layout(image.encoding.clone()));
    }
    let mut pixels = image.data[..len].to_vec();
    if image.encoding == "bgr8" {
        for p in pixels.chunks_exact_mut(3) {
            p.swap(0, 2);
        }
    }
    let colour_type = if colour {
        image::ExtendedColorType::Rgb8
    } else {
        image::ExtendedColorType::L8
    };
    let mut data = Vec::new();
    match codec {
        Codec::Jpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, jpeg_quality)
            .encode(&pixels, w, h, colour_type)?,
        Codec::Png => image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut data),
            &pixels,
            w,
            h,
            colour_type,
        )?,
    }
    let word = match codec {
        Codec::Jpeg => "jpeg",
        Codec::Png => "png",
    };
    let target = if colour { "bgr8" } else { "mono8" };
    Ok(CompressedImage {
        header: image.header.clone(),
        format: format!("{}; {word} compressed {target}", image.encoding),
        data,
    })
}

#[cfg(test)]
#[path = "compressed_tests.rs"]
mod tests;
