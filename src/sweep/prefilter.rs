//! The matching images of real cameras (issue 52): what the colour term of the cost compares.
//!
//! Real rig cameras differ in gain, offset and exposure, vignette, and carry sensor noise; a
//! colour SSD truncated at `tau` on the raw images then saturates at random and drowns the
//! census half. With `prefilter = gradient` (the default `auto`'s choice for a pair of cameras)
//! the colour term compares, instead of
//! the colours, each image's horizontal Sobel derivative of its grey, as OpenCV's StereoSGBM
//! prefilters: `128 + clamp(SCALE * sobel_x(grey), -127, 127)`, blind to offsets (exposure,
//! vignetting, a dark corner), nearly blind to small gain differences, and with no noise blown
//! up on flat surfaces. It rides in the alpha byte of each pixel (`Params.colour_in_alpha`: the
//! cost's texels read it in all three channels); the RGB stay the camera's, so the census half,
//! SGM's edge-aware P2 and the joint median see exactly what they see without the prefilter.
//!
//! A host step of the CPU engine (`coarse::run`, before the levels); the WGSL engine makes the
//! same bytes on the device from the caller's images (`shaders/prefilter.wgsl`, in its image
//! pyramid before the halvings), so both sweep the same images.

use rayon::prelude::*;

use std::borrow::Cow;

use super::census::luma;
use super::plan::SweepPlan;
use crate::image::Rgba8Image;

/// Output levels per unit of the Sobel derivative (a one-level step between two columns is 4
/// units: 2 levels). Chosen on real-camera pairs and the lab sets together (docs/quality.md):
/// smaller loses the lab sets' precision, larger lets the truncation at `tau` bite on real
/// cameras again.
pub const SCALE: f32 = 0.5;

/// The caller's images as a plan sweeps them: prefiltered when the plan's colour term reads
/// the alpha byte (`Params.colour_in_alpha`), else borrowed. For the engines' `run_plan`
/// entry points, which take the caller's images as `run` does.
pub fn for_plan<'a>(plan: &SweepPlan, images: &'a [Rgba8Image]) -> Cow<'a, [Rgba8Image]> {
    if plan.params.colour_in_alpha != 0 {
        Cow::Owned(gradient_all(images))
    } else {
        Cow::Borrowed(images)
    }
}

/// Each image prefiltered ([`gradient`]).
pub fn gradient_all(images: &[Rgba8Image]) -> Vec<Rgba8Image> {
    images.par_iter().map(gradient).collect()
}

/// The image with its grey's horizontal Sobel derivative, `128 + clamp(SCALE d, -127, 127)`
/// rounded, in the alpha byte (edge texels repeated); the RGB unchanged.
pub fn gradient(image: &Rgba8Image) -> Rgba8Image {
    let (w, h) = (image.width as usize, image.height as usize);
    if w == 0 || h == 0 {
        return image.clone();
    }
    let src = &image.pixels;
    let mut pixels = vec![0u32; w * h];
    // Per row: the vertical [1, 2, 1] sum of the greys (`sums`), then its central difference
    // (the Sobel response), each a loop that vectorises. The byte is `round` of a positive
    // value with few fractional bits, i.e. `floor(v + 0.5)` exactly (no libm call per pixel).
    pixels.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0i32; w],
        |sums, (y, out)| {
            let rows = [y.saturating_sub(1), y, (y + 1).min(h - 1)];
            let [up, mid, down] = rows.map(|r| &src[r * w..(r + 1) * w]);
            for (((s, &u), &m), &d) in sums.iter_mut().zip(up).zip(mid).zip(down) {
                *s = (luma(u) + 2 * luma(m) + luma(d)) as i32;
            }
            let byte = |d: i32| {
                let v = 128.0 + (d as f32 * (SCALE / 256.0)).clamp(-127.0, 127.0);
                (v + 0.5).floor() as u32
            };
            // Columns 1..w - 1 from their neighbours (a loop that vectorises), then the two
            // edge columns, whose missing neighbour is the edge column itself.
            if w >= 3 {
                let inner = out[1..w - 1].iter_mut().zip(&mid[1..w - 1]);
                for ((o, &m), (&r, &l)) in inner.zip(sums[2..].iter().zip(&sums[..w - 2])) {
                    *o = (m & 0x00ff_ffff) | (byte(r - l) << 24);
                }
            }
            for x in [0, w - 1] {
                let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
                out[x] = (mid[x] & 0x00ff_ffff) | (byte(sums[r] - sums[l]) << 24);
            }
        },
    );
    Rgba8Image {
        width: image.width,
        height: image.height,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey_image(w: u32, h: u32, f: impl Fn(u32, u32) -> f64) -> Rgba8Image {
        let pixels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let v = f(x, y).round().clamp(0.0, 255.0) as u8;
                Rgba8Image::pack(v, v, v)
            })
            .collect();
        Rgba8Image {
            width: w,
            height: h,
            pixels,
        }
    }

    /// The same texture under another offset and a slow vignette prefilters to nearly the same
    /// alpha, where the raw images differ by tens of levels; the RGB are kept.
    #[test]
    fn offsets_and_vignetting_drop_out_and_the_colours_stay() {
        let texture = |x: u32, y: u32| {
            let t = ((x * 7919 + y * 104_729) % 97) as f64 / 96.0;
            40.0 + 120.0 * t
        };
        let (w, h) = (40u32, 30u32);
        let a = grey_image(w, h, texture);
        let b = grey_image(w, h, |x, y| {
            let r2 = (f64::from(x) / 40.0 - 0.5).powi(2) + (f64::from(y) / 30.0 - 0.5).powi(2);
            texture(x, y) + 40.0 - 10.0 * r2
        });
        let raw_diff = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .map(|(&p, &q)| ((p & 0xff) as i32 - (q & 0xff) as i32).abs())
            .min()
            .unwrap();
        assert!(raw_diff >= 35, "raw images differ by at least {raw_diff}");
        let (ga, gb) = (gradient(&a), gradient(&b));
        for (&p, &q) in ga.pixels.iter().zip(&gb.pixels) {
            let d = ((p >> 24) as i32 - (q >> 24) as i32).abs();
            // The vignette's own slope (up to 0.25 levels per pixel here) and rounding.
            assert!(d <= 3, "prefiltered images differ by {d}");
        }
        for (&raw, &g) in a.pixels.iter().zip(&ga.pixels) {
            assert_eq!(g & 0x00ff_ffff, raw & 0x00ff_ffff);
        }
        // The texture survives: derivatives both ways, not one flat value.
        let distinct: std::collections::BTreeSet<u32> = ga.pixels.iter().map(|p| p >> 24).collect();
        assert!(distinct.len() > 5, "{distinct:?}");
        assert!(distinct.iter().any(|&v| v < 100) && distinct.iter().any(|&v| v > 156));
    }

    /// A vertical step edge of 40 levels: 160 grey levels of Sobel, 80 above 128 on both
    /// columns next to it; flat elsewhere.
    #[test]
    fn a_step_edge_by_hand() {
        let a = grey_image(6, 3, |x, _| if x < 3 { 50.0 } else { 90.0 });
        let g = gradient(&a);
        let row: Vec<u32> = (0..6).map(|x| g.pixels[6 + x] >> 24).collect();
        // luma of grey v is 256 v: the step is 40 levels.
        assert_eq!(row, vec![128, 128, 208, 208, 128, 128]);
    }
}
