//! File formats: PFM (read/write), image loading, and the colour PNGs `eval --save` writes.
//!
//! PFM follows the Middlebury convention: a single-channel `Pf` header, a negative scale for
//! little-endian data, and rows stored **bottom to top**. In memory ([`ImageF32`]) rows are top
//! first; the reader and writer flip.

use std::path::{Path, PathBuf};

use image::{GrayImage, RgbImage};

use crate::image::{ImageF32, Rgba8Image};

/// Errors of this module; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: cannot write: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: cannot decode image: {source}")]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: cannot encode image: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: bad PFM: {source}")]
    Pfm { path: PathBuf, source: PfmError },
    #[error("{path}: {reason}")]
    Unsupported { path: PathBuf, reason: String },
    #[error("{path}: image data does not match its size: {reason}")]
    Size { path: PathBuf, reason: String },
}

// ---------------------------------------------------------------------------------------------
// PFM

/// Encodes a single-channel PFM in memory (little-endian, rows bottom to top, NaN kept).
pub fn encode_pfm(image: &ImageF32) -> Result<Vec<u8>, String> {
    let (w, h) = (image.width as usize, image.height as usize);
    if image.data.len() != w * h {
        return Err(format!(
            "{}x{} image holds {} values",
            image.width,
            image.height,
            image.data.len()
        ));
    }
    let header = format!("Pf\n{} {}\n-1.0\n", image.width, image.height);
    let mut out = Vec::with_capacity(header.len() + w * h * 4);
    out.extend_from_slice(header.as_bytes());
    for y in (0..h).rev() {
        for v in &image.data[y * w..(y + 1) * w] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes a single-channel PFM: `Pf`, scale -1.0 (little-endian), rows bottom to top as in
/// Middlebury's files. NaN stays NaN.
pub fn write_pfm(path: &Path, image: &ImageF32) -> Result<(), IoError> {
    let bytes = encode_pfm(image).map_err(|reason| IoError::Size {
        path: path.to_path_buf(),
        reason,
    })?;
    std::fs::write(path, bytes).map_err(|source| IoError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Why bytes are not a single-channel PFM.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PfmError {
    #[error("header field '{0}' is too long (not a PFM?)")]
    FieldTooLong(&'static str),
    #[error("header ends before '{0}'")]
    HeaderEnds(&'static str),
    #[error("header field '{0}' is not text")]
    NotText(&'static str),
    #[error("'PF' is a 3-channel (colour) PFM; only single-channel 'Pf' is supported")]
    Colour,
    #[error("magic is '{0}', expected 'Pf'")]
    Magic(String),
    #[error("{field}: {reason}")]
    Number { field: &'static str, reason: String },
    #[error("scale must be finite and non-zero, got {0}")]
    Scale(f64),
    #[error("no whitespace after the scale")]
    NoSeparator,
    #[error("size {width}x{height} is too large")]
    TooLarge { width: u32, height: u32 },
    #[error("{width}x{height} needs {needed} data bytes, the file has {got}")]
    ShortData {
        width: u32,
        height: u32,
        needed: usize,
        got: usize,
    },
}

/// Decodes a single-channel PFM held in memory; rows are returned top first.
pub fn decode_pfm(bytes: &[u8]) -> Result<ImageF32, PfmError> {
    // Header: three whitespace-separated fields ("Pf", "W H", scale), then exactly one
    // whitespace byte before the binary data.
    let mut pos = 0usize;
    let mut next_token = |what: &'static str| -> Result<String, PfmError> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
            if pos - start > 64 {
                return Err(PfmError::FieldTooLong(what));
            }
        }
        if start == pos {
            return Err(PfmError::HeaderEnds(what));
        }
        String::from_utf8(bytes[start..pos].to_vec()).map_err(|_| PfmError::NotText(what))
    };
    let magic = next_token("magic")?;
    match magic.as_str() {
        "Pf" => {}
        "PF" => return Err(PfmError::Colour),
        other => return Err(PfmError::Magic(other.escape_default().to_string())),
    }
    let number = |field: &'static str, e: &dyn std::fmt::Display| PfmError::Number {
        field,
        reason: e.to_string(),
    };
    let width: u32 = next_token("width")?
        .parse()
        .map_err(|e| number("width", &e))?;
    let height: u32 = next_token("height")?
        .parse()
        .map_err(|e| number("height", &e))?;
    let scale: f64 = next_token("scale")?
        .parse()
        .map_err(|e| number("scale", &e))?;
    if !scale.is_finite() || scale == 0.0 {
        return Err(PfmError::Scale(scale));
    }
    let little_endian = scale < 0.0;
    // One whitespace byte ends the header.
    if pos >= bytes.len() || !bytes[pos].is_ascii_whitespace() {
        return Err(PfmError::NoSeparator);
    }
    pos += 1;
    let (w, h) = (width as usize, height as usize);
    let count = w
        .checked_mul(h)
        .filter(|&n| n.checked_mul(4).is_some())
        .ok_or(PfmError::TooLarge { width, height })?;
    let data_bytes = &bytes[pos..];
    if data_bytes.len() < count * 4 {
        return Err(PfmError::ShortData {
            width,
            height,
            needed: count * 4,
            got: data_bytes.len(),
        });
    }
    let mut data = vec![0f32; count];
    for (i, chunk) in data_bytes[..count * 4].chunks_exact(4).enumerate() {
        let raw = [chunk[0], chunk[1], chunk[2], chunk[3]];
        let v = if little_endian {
            f32::from_le_bytes(raw)
        } else {
            f32::from_be_bytes(raw)
        };
        // File row r (0 = first stored = bottom) goes to image row h - 1 - r.
        let (r, x) = (i / w, i % w);
        data[(h - 1 - r) * w + x] = v;
    }
    Ok(ImageF32 {
        width,
        height,
        data,
    })
}

/// Reads a single-channel PFM (either endianness, chosen by the scale's sign); rows are
/// returned top first.
pub fn read_pfm(path: &Path) -> Result<ImageF32, IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    decode_pfm(&bytes).map_err(|source| IoError::Pfm {
        path: path.to_path_buf(),
        source,
    })
}

// ---------------------------------------------------------------------------------------------
// Loading images

fn open_image(path: &Path) -> Result<image::DynamicImage, IoError> {
    let reader = image::ImageReader::open(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let reader = reader
        .with_guessed_format()
        .map_err(|source| IoError::Read {
            path: path.to_path_buf(),
            source,
        })?;
    reader.decode().map_err(|source| IoError::Decode {
        path: path.to_path_buf(),
        source,
    })
}

/// Loads any PNG/PPM/PGM (8- or 16-bit; 16-bit is reduced to 8-bit by the `image` crate) as
/// RGBA8. The format is detected from the content, not the extension.
pub fn load_rgba8(path: &Path) -> Result<Rgba8Image, IoError> {
    let image = open_image(path)?;
    let max = match &image {
        image::DynamicImage::ImageLuma16(i) => i.as_raw().iter().max().copied(),
        image::DynamicImage::ImageLumaA16(i) => i.pixels().map(|p| p.0[0]).max(),
        image::DynamicImage::ImageRgb16(i) => i.as_raw().iter().max().copied(),
        image::DynamicImage::ImageRgba16(i) => i.pixels().flat_map(|p| &p.0[..3]).max().copied(),
        _ => None,
    };
    let warning =
        max.and_then(|max| crate::image::narrow_mono16_warning(&path.display().to_string(), max));
    if let Some(warning) = warning {
        tracing::warn!("{warning}");
    }
    Ok(Rgba8Image::from_image(&image))
}

/// Loads an 8-bit grey image (ground-truth disparity PGM/PNG) with its raw values.
///
/// 16-bit images are refused rather than rescaled (rescaling would silently change disparity
/// values). Colour images are accepted only when every pixel is grey (r = g = b).
pub fn load_gray_u8(path: &Path) -> Result<GrayImage, IoError> {
    let img = open_image(path)?;
    match img {
        image::DynamicImage::ImageLuma8(g) => Ok(g),
        image::DynamicImage::ImageLumaA8(_)
        | image::DynamicImage::ImageRgb8(_)
        | image::DynamicImage::ImageRgba8(_) => {
            let rgb = img.to_rgb8();
            if rgb.pixels().any(|p| p.0[0] != p.0[1] || p.0[1] != p.0[2]) {
                return Err(IoError::Unsupported {
                    path: path.to_path_buf(),
                    reason: "expected a grey (single-channel) 8-bit image, got colour".into(),
                });
            }
            Ok(image::GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                image::Luma([rgb.get_pixel(x, y).0[0]])
            }))
        }
        other => Err(IoError::Unsupported {
            path: path.to_path_buf(),
            reason: format!(
                "expected an 8-bit grey image, got {:?} (16-bit or float ground truth is not supported)",
                other.color()
            ),
        }),
    }
}

// ---------------------------------------------------------------------------------------------
// Colour images

/// Google's "turbo" colour map, polynomial approximation (Mikhailov 2019), `t` in [0, 1].
pub fn turbo(t: f64) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let t2 = t * t;
    let t3 = t2 * t;
    let t4 = t3 * t;
    let t5 = t4 * t;
    let r = 0.13572138 + 4.61539260 * t - 42.66032258 * t2 + 132.13108234 * t3 - 152.94239396 * t4
        + 59.28637943 * t5;
    let g = 0.09140261 + 2.19418839 * t + 4.84296658 * t2 - 14.18503333 * t3
        + 4.27729857 * t4
        + 2.82956604 * t5;
    let b = 0.10667330 + 12.64194608 * t - 60.58204836 * t2 + 110.36276771 * t3 - 89.90310912 * t4
        + 27.34824973 * t5;
    let c = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [c(r), c(g), c(b)]
}

/// The `q`-quantile (0..1) of `sorted` (ascending, non-empty), nearest rank.
fn quantile(sorted: &[f32], q: f64) -> f32 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// Depth as a colour image: turbo map of inverse depth (near = red, far = blue), normalised
/// between the 2nd and 98th percentile of the valid values; invalid (NaN, <= 0) = black.
pub fn depth_png(depth_m: &ImageF32) -> RgbImage {
    let inv: Vec<f32> = depth_m
        .data
        .iter()
        .map(|&d| {
            if d.is_finite() && d > 0.0 {
                1.0 / d
            } else {
                f32::NAN
            }
        })
        .collect();
    let mut valid: Vec<f32> = inv.iter().copied().filter(|v| v.is_finite()).collect();
    valid.sort_by(f32::total_cmp);
    let (lo, hi) = if valid.is_empty() {
        (0.0, 1.0)
    } else {
        (quantile(&valid, 0.02), quantile(&valid, 0.98))
    };
    let span = f64::from(hi - lo);
    let width = depth_m.width;
    RgbImage::from_fn(depth_m.width, depth_m.height, |x, y| {
        let v = inv
            .get((y as usize) * width as usize + x as usize)
            .copied()
            .unwrap_or(f32::NAN);
        if !v.is_finite() {
            return image::Rgb([0, 0, 0]);
        }
        let t = if span > 0.0 {
            f64::from(v - lo) / span
        } else {
            0.5
        };
        image::Rgb(turbo(t))
    })
}

/// Confidence in [0, 1] as grey 0..255 (NaN = 0).
pub fn confidence_png(confidence: &ImageF32) -> GrayImage {
    let width = confidence.width;
    GrayImage::from_fn(confidence.width, confidence.height, |x, y| {
        let v = confidence
            .data
            .get((y as usize) * width as usize + x as usize)
            .copied()
            .unwrap_or(0.0);
        let v = if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        };
        image::Luma([(v * 255.0).round() as u8])
    })
}

/// Half-sequence selection codes coloured with [`crate::sweep::selection::colour`]; missing
/// entries (a short slice) are drawn as invalid.
pub fn selection_png(width: u32, height: u32, selection: &[u8]) -> RgbImage {
    RgbImage::from_fn(width, height, |x, y| {
        let code = selection
            .get((y as usize) * width as usize + x as usize)
            .copied()
            .unwrap_or(crate::sweep::selection::INVALID);
        image::Rgb(crate::sweep::selection::colour(code))
    })
}

/// Saves an `image` buffer as PNG (format chosen from the extension by the `image` crate).
pub fn save_image<P, C>(path: &Path, image: &image::ImageBuffer<P, C>) -> Result<(), IoError>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    image.save(path).map_err(|source| IoError::Encode {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pfm_round_trip_in_memory() {
        let img = ImageF32 {
            width: 3,
            height: 2,
            data: vec![1.0, 2.0, f32::NAN, 4.0, 5.0, 6.0],
        };
        let bytes = encode_pfm(&img).unwrap();
        let back = decode_pfm(&bytes).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.data[..2], [1.0, 2.0]);
        assert!(back.data[2].is_nan());
        assert_eq!(back.data[3..], [4.0, 5.0, 6.0]);
    }

    #[test]
    fn pfm_big_endian_and_bad_headers() {
        let mut bytes = b"Pf\n2 1\n1.0\n".to_vec();
        bytes.extend_from_slice(&1.5f32.to_be_bytes());
        bytes.extend_from_slice(&(-2.0f32).to_be_bytes());
        let img = decode_pfm(&bytes).unwrap();
        assert_eq!(img.data, vec![1.5, -2.0]);
        assert_eq!(
            decode_pfm(b"PF\n1 1\n-1.0\n\0\0\0\0\0\0\0\0\0\0\0\0"),
            Err(PfmError::Colour)
        );
        assert!(decode_pfm(b"P5\n1 1\n255\n\0").is_err());
        assert!(decode_pfm(b"Pf\n2 2\n-1.0\n\0\0\0\0").is_err());
        assert!(decode_pfm(b"Pf\nx 2\n-1.0\n").is_err());
        assert!(decode_pfm(b"").is_err());
    }

    #[test]
    fn turbo_ends() {
        let lo = turbo(0.15);
        let hi = turbo(0.9);
        assert!(lo[2] > lo[0], "low end is blue-ish: {lo:?}");
        assert!(hi[0] > hi[2], "high end is red-ish: {hi:?}");
    }

    #[test]
    fn depth_png_marks_invalid_black() {
        let img = ImageF32 {
            width: 3,
            height: 1,
            data: vec![1.0, f32::NAN, 2.0],
        };
        let png = depth_png(&img);
        assert_eq!(png.get_pixel(1, 0).0, [0, 0, 0]);
        assert_ne!(png.get_pixel(0, 0).0, png.get_pixel(2, 0).0);
    }
}
