//! Real cameras' radiometry given to a lab rig (`eval --radiometry`).
//!
//! The lab sets are shot with one camera, equal exposures and clean images; a rig's cameras are
//! not: each has its own exposure (auto exposure runs per camera), its lens darkens the
//! corners, its sensor adds noise. No public multi-view set with ground truth carries that, so
//! `eval` can give it to any set, camera by camera, before the sweep, and say how much depth a
//! setting keeps ([`Radiometry`]; docs/quality.md has the figures the defaults were chosen on).
//! The changes are fixed (no seed to pass): the same folder gives the same images everywhere.

use crate::image::Rgba8Image;

/// What `eval --radiometry` changes in each camera's image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Radiometry {
    /// The images as the set has them.
    #[default]
    None,
    /// Each camera its own exposure: a gain of 0.6-1.5 (clipped at white) and a gamma of
    /// 0.9-1.1, by its index in the rig ([`EXPOSURES`]).
    Exposure,
    /// Every lens darkens towards the corners: `1 - 0.45 r^2`, `r` the distance from the image
    /// centre over the half-diagonal (a point seen near one camera's centre and another's
    /// corner differs by up to 45 %).
    Vignette,
    /// Sensor noise: Gaussian-like, 3 levels (of 255) standard deviation, per channel.
    Noise,
    /// All three, in that order.
    All,
}

/// Per camera (its index in the rig, cycling): (gain, gamma), applied as
/// `255 (min(1, gain v / 255))^gamma`. Camera 0 keeps its exposure; the others alternate
/// darker and brighter, as cameras metering different parts of a scene do.
pub const EXPOSURES: [(f32, f32); 9] = [
    (1.0, 1.0),
    (0.6, 1.1),
    (1.5, 0.9),
    (0.75, 1.05),
    (1.3, 0.95),
    (0.65, 1.1),
    (1.4, 0.9),
    (0.8, 1.0),
    (1.2, 1.05),
];

/// The vignette's darkening at the corners ([`Radiometry::Vignette`]).
pub const VIGNETTE: f32 = 0.45;

/// The noise's standard deviation in levels ([`Radiometry::Noise`]).
pub const NOISE_SIGMA: f32 = 3.0;

impl Radiometry {
    /// The images of a rig (`images[i]`: camera `i`) as `self` makes them.
    pub fn apply(self, images: &mut [Rgba8Image]) {
        if self == Radiometry::None {
            return;
        }
        let exposure = matches!(self, Radiometry::Exposure | Radiometry::All);
        let vignette = matches!(self, Radiometry::Vignette | Radiometry::All);
        let noise = matches!(self, Radiometry::Noise | Radiometry::All);
        for (camera, image) in images.iter_mut().enumerate() {
            let (gain, gamma) = EXPOSURES[camera % EXPOSURES.len()];
            let (w, h) = (image.width as usize, image.height as usize);
            let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
            let half_diagonal_sq = (cx * cx + cy * cy).max(1.0);
            for (i, pixel) in image.pixels.iter_mut().enumerate() {
                let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                let r_sq = ((x - cx).powi(2) + (y - cy).powi(2)) / half_diagonal_sq;
                let rgba = Rgba8Image::unpack(*pixel);
                let channel = |c: usize| {
                    let mut v = f32::from(rgba[c]);
                    if exposure {
                        v = 255.0 * (gain * v / 255.0).min(1.0).powf(gamma);
                    }
                    if vignette {
                        v *= 1.0 - VIGNETTE * r_sq;
                    }
                    if noise {
                        v += NOISE_SIGMA * unit_normal(camera, i, c);
                    }
                    v.round().clamp(0.0, 255.0) as u8
                };
                let alpha = u32::from(rgba[3]) << 24;
                *pixel = Rgba8Image::pack(channel(0), channel(1), channel(2)) & 0x00ff_ffff | alpha;
            }
        }
    }
}

/// A fixed draw of zero mean and unit variance for (camera, pixel, channel): the sum of four
/// uniform draws of a hash (Irwin-Hall, near Gaussian), integer arithmetic only, so every
/// machine makes the same noise.
fn unit_normal(camera: usize, pixel: usize, channel: usize) -> f32 {
    let key = ((camera as u64) << 40) ^ ((pixel as u64) << 2) ^ channel as u64;
    let bits = splitmix64(key);
    let sum: u32 = (0..4).map(|k| ((bits >> (16 * k)) & 0xffff) as u32).sum();
    // Four uniforms on [0, 1): mean 2, variance 4 / 12.
    (sum as f32 / 65536.0 - 2.0) * 3.0f32.sqrt()
}

/// Steele, Lea and Flood's SplitMix64 finaliser: a well-mixed 64-bit hash of `key`.
fn splitmix64(key: u64) -> u64 {
    let mut z = key.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(w: u32, h: u32, v: u8) -> Rgba8Image {
        Rgba8Image {
            width: w,
            height: h,
            pixels: vec![Rgba8Image::pack(v, v, v); (w * h) as usize],
        }
    }

    #[test]
    fn none_leaves_the_images_alone() {
        let mut images = vec![grey(8, 6, 100), grey(8, 6, 200)];
        let before = images.clone();
        Radiometry::None.apply(&mut images);
        assert_eq!(images, before);
    }

    #[test]
    fn exposure_differs_per_camera_and_keeps_camera_zero() {
        let mut images = vec![grey(4, 4, 100); 3];
        Radiometry::Exposure.apply(&mut images);
        let value = |i: usize| Rgba8Image::unpack(images[i].pixels[5])[0];
        assert_eq!(value(0), 100);
        // 0.6 x 100 / 255 = 0.235, ^1.1 = 0.203: 52; 1.5 x 100 / 255 = 0.588, ^0.9 = 0.620: 158.
        assert_eq!(value(1), 52);
        assert_eq!(value(2), 158);
    }

    #[test]
    fn vignette_darkens_the_corners_not_the_centre() {
        let mut images = vec![grey(101, 81, 200)];
        Radiometry::Vignette.apply(&mut images);
        let at = |x: usize, y: usize| Rgba8Image::unpack(images[0].pixels[y * 101 + x])[0];
        assert!(at(50, 40) >= 199, "centre {}", at(50, 40));
        // The corner texel's centre lies 0.98 of the half-diagonal out: 200 (1 - 0.45 x 0.97).
        assert!((110..=115).contains(&at(0, 0)), "corner {}", at(0, 0));
        assert_eq!(at(0, 0), at(100, 80));
    }

    #[test]
    fn noise_has_the_stated_spread_and_no_offset() {
        let mut images = vec![grey(200, 100, 128)];
        Radiometry::Noise.apply(&mut images);
        let values: Vec<f64> = images[0]
            .pixels
            .iter()
            .map(|&p| f64::from(Rgba8Image::unpack(p)[1]))
            .collect();
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!((mean - 128.0).abs() < 0.1, "mean {mean}");
        assert!((sd - 3.0).abs() < 0.15, "standard deviation {sd}");
        // The same draw every time.
        let mut again = vec![grey(200, 100, 128)];
        Radiometry::Noise.apply(&mut again);
        assert_eq!(again, images);
    }
}
