//! The matching images of real cameras (issue 52): what the colour term of the cost compares.
//!
//! Real rig cameras differ in gain, offset and exposure, vignette, and carry sensor noise; a
//! colour SSD truncated at `tau` on the raw images then saturates at random and drowns the
//! census half. With `prefilter = gradient` (the default `auto`'s choice for every rig of real
//! cameras) the colour term compares, instead of
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
use crate::image::{CameraImage, PackedFormat, Rgba8Image, SetImages};

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

/// `Prefilter::Auto` on a rig of three cameras or more takes the gradient from the first frame
/// set whose brightest camera's mean grey is more than this times the darkest's: cameras that
/// each meter their own exposure (docs/quality.md: gains only 5 % apart took Laundry from 10.81
/// to 19.72 % bad>1 on the raw colours, 11.70 % on the gradient; their ratios 1.11-1.15). The
/// lab rigs' views, one exposure, differ by 1.01-1.03, Teddy's nine by 1.11 (each sees another
/// part of its scene; it does better on the gradient: 4.69 against 4.98 %).
pub const AUTO_BRIGHTNESS_RATIO: f64 = 1.06;

/// Every `BRIGHTNESS_STEP`-th row and column is read for a camera's mean grey.
const BRIGHTNESS_STEP: usize = 8;

/// The brightest camera's mean grey over the darkest's (1 for fewer than two cameras; a black
/// camera counts as the darkest grey above zero).
pub fn brightness_ratio(images: SetImages<'_>) -> f64 {
    let means: Vec<f64> = images.iter().map(mean_grey).collect();
    let lo = means.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = means.iter().copied().fold(0.0, f64::max);
    if means.len() < 2 || hi <= 0.0 {
        return 1.0;
    }
    hi / lo.max(1.0)
}

/// The mean grey (`luma`, 1/256 levels) of every `BRIGHTNESS_STEP`-th row and column.
fn mean_grey(image: CameraImage<'_>) -> f64 {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let (mut sum, mut count) = (0u64, 0u64);
    for y in (0..h).step_by(BRIGHTNESS_STEP) {
        for x in (0..w).step_by(BRIGHTNESS_STEP) {
            if let Some(grey) = grey_at(image, y * w + x) {
                sum += u64::from(grey);
                count += 1;
            }
        }
    }
    sum as f64 / count.max(1) as f64
}

/// The grey (`luma`, 1/256 levels) of pixel `i` (row-major); `None` past the image's bytes.
fn grey_at(image: CameraImage<'_>, i: usize) -> Option<u32> {
    match image {
        CameraImage::Rgba(rgba) => rgba.pixels.get(i).map(|&p| luma(p)),
        CameraImage::Packed(packed) => {
            let n = packed.format.bytes_per_pixel();
            packed
                .bytes
                .get(i * n..(i + 1) * n)
                .map(|b| match packed.format {
                    PackedFormat::Rgb8 => luma(Rgba8Image::pack(b[0], b[1], b[2])),
                    PackedFormat::Bgr8 => luma(Rgba8Image::pack(b[2], b[1], b[0])),
                    PackedFormat::Mono8 => luma(Rgba8Image::pack(b[0], b[0], b[0])),
                })
        }
    }
}

/// `Prefilter::Auto` on a rig of three cameras or more keeps the raw colours for images whose
/// median horizontal grey step ([`median_step`]) is above this many grey levels: texture that
/// changes by many levels from every pixel to the next, as renders of high-contrast noise
/// textures have (the engine's synthetic scenes: 9.5). There the derivative's differences
/// exceed what the colour term's truncation at `tau` lets through at any shift off the match,
/// and the raw colours keep the depth between the planes (a fronto-parallel wall: 92 % of
/// pixels within 1 % against 76 %). Every real camera measured steps far less (docs/quality.md:
/// the 17 real pairs 1.0-2.5, Tsukuba, Teddy and Laundry 1.3-2.0, ICL-NUIM and the rings 0.5),
/// and there the gradient is the better cost.
pub const AUTO_RENDER_STEP: f64 = 5.0;

/// Rows and columns between the samples of [`median_step`].
const STEP_SAMPLE_ROWS: usize = 16;
const STEP_SAMPLE_COLUMNS: usize = 4;

/// The median over every camera of `|grey(x + 1) - grey(x - 1)| / 2`, grey levels (0..255),
/// sampled on every `STEP_SAMPLE_ROWS`-th row and `STEP_SAMPLE_COLUMNS`-th column; 0 for
/// images under three columns wide.
pub fn median_step(images: SetImages<'_>) -> f64 {
    let mut steps: Vec<u32> = Vec::new();
    for image in images.iter() {
        let (w, h) = (image.width() as usize, image.height() as usize);
        for y in (0..h).step_by(STEP_SAMPLE_ROWS) {
            for x in (1..w.saturating_sub(1)).step_by(STEP_SAMPLE_COLUMNS) {
                let (l, r) = (grey_at(image, y * w + x - 1), grey_at(image, y * w + x + 1));
                if let (Some(l), Some(r)) = (l, r) {
                    steps.push(l.abs_diff(r));
                }
            }
        }
    }
    if steps.is_empty() {
        return 0.0;
    }
    let middle = steps.len() / 2;
    let (_, &mut median, _) = steps.select_nth_unstable(middle);
    f64::from(median) / (2.0 * 256.0)
}

/// Rows of an image one task of [`gradient`] makes: each band computes its rows' greys once
/// (and the row above and below it), so 32 rows cost 34 rows of greys, not 96.
const BAND_ROWS: usize = 32;

/// The image with its grey's horizontal Sobel derivative, `128 + clamp(SCALE d, -127, 127)`
/// rounded, in the alpha byte (edge texels repeated); the RGB unchanged.
pub fn gradient(image: &Rgba8Image) -> Rgba8Image {
    let (w, h) = (image.width as usize, image.height as usize);
    if w == 0 || h == 0 {
        return image.clone();
    }
    let src = &image.pixels;
    let mut pixels = vec![0u32; w * h];
    // Per band of rows: each row's greys once (a ring of three rows), then per row the vertical
    // [1, 2, 1] sum of the greys (`sums`) and its central difference (the Sobel response), each
    // a loop that vectorises.
    pixels
        .par_chunks_mut(w * BAND_ROWS)
        .enumerate()
        .for_each_init(
            || ([vec![0i32; w], vec![0i32; w], vec![0i32; w]], vec![0i32; w]),
            |(greys, sums), (band, out)| {
                let first = band * BAND_ROWS;
                let grey_row = |r: usize, into: &mut [i32]| {
                    for (g, &p) in into.iter_mut().zip(&src[r * w..(r + 1) * w]) {
                        *g = luma(p) as i32;
                    }
                };
                let [up, mid, down] = greys;
                grey_row(first.saturating_sub(1), up);
                grey_row(first, mid);
                for (i, out) in out.chunks_mut(w).enumerate() {
                    let y = first + i;
                    grey_row((y + 1).min(h - 1), down);
                    for (((s, &u), &m), &d) in sums.iter_mut().zip(&*up).zip(&*mid).zip(&*down) {
                        *s = u + 2 * m + d;
                    }
                    sobel_row(&src[y * w..(y + 1) * w], sums, out);
                    // The ring turns: this row's greys are the next one's above, and so on.
                    std::mem::swap(up, mid);
                    std::mem::swap(mid, down);
                }
            },
        );
    Rgba8Image {
        width: image.width,
        height: image.height,
        pixels,
    }
}

/// One output row: the pixels of `row` with the byte of the central difference of `sums` (the
/// row's vertical Sobel sums) in alpha; the edge columns take their own sum for the missing
/// neighbour.
#[inline(always)]
fn sobel_row(row: &[u32], sums: &[i32], out: &mut [u32]) {
    let w = row.len();
    // Columns 1..w - 1 from their neighbours (a loop that vectorises), then the two edge
    // columns, whose missing neighbour is the edge column itself.
    if w >= 3 {
        let inner = out[1..w - 1].iter_mut().zip(&row[1..w - 1]);
        for ((o, &m), (&r, &l)) in inner.zip(sums[2..].iter().zip(&sums[..w - 2])) {
            *o = (m & 0x00ff_ffff) | (byte(r - l) << 24);
        }
    }
    for x in [0, w - 1] {
        let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
        out[x] = (row[x] & 0x00ff_ffff) | (byte(sums[r] - sums[l]) << 24);
    }
}

/// `round(128 + clamp(SCALE d / 256, -127, 127))` of a Sobel response `d` (greys in 1/256
/// levels), in integers: `SCALE / 256` is 2^-9, so the rounding is `floor((d + 256) / 2^9)`,
/// exactly what the float form gives (`byte_is_the_float_rounding`; the shader's twin in
/// `prefilter.wgsl` reads the float form).
#[inline(always)]
fn byte(d: i32) -> u32 {
    (128 + ((d + 256) >> 9)).clamp(1, 255) as u32
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

    /// The integer byte equals the float form `128 + clamp(SCALE d / 256, -127, 127)` rounded
    /// half up, for every Sobel response a grey image can give (and beyond).
    #[test]
    fn byte_is_the_float_rounding() {
        assert_eq!(SCALE, 0.5, "byte() divides by 2^9");
        for d in -300_000..=300_000 {
            let v = 128.0 + (d as f32 * (SCALE / 256.0)).clamp(-127.0, 127.0);
            assert_eq!(byte(d), (v + 0.5).floor() as u32, "d = {d}");
        }
    }

    /// Bands of rows make what one pass over the rows makes: every size around the band's
    /// height, colours with all three channels apart, a seeded texture.
    #[test]
    fn bands_equal_a_pass_row_by_row() {
        let by_rows = |image: &Rgba8Image| -> Vec<u32> {
            let (w, h) = (image.width as usize, image.height as usize);
            let grey = |x: usize, y: usize| luma(image.pixels[y * w + x]) as i32;
            let sum = |x: usize, y: usize| {
                grey(x, y.saturating_sub(1)) + 2 * grey(x, y) + grey(x, (y + 1).min(h - 1))
            };
            (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| {
                    let d = sum((x + 1).min(w - 1), y) - sum(x.saturating_sub(1), y);
                    let v = 128.0 + (d as f32 * (SCALE / 256.0)).clamp(-127.0, 127.0);
                    (image.pixels[y * w + x] & 0x00ff_ffff) | (((v + 0.5).floor() as u32) << 24)
                })
                .collect()
        };
        for (w, h) in [
            (1, 1),
            (2, 1),
            (1, 5),
            (3, 3),
            (17, 31),
            (40, 32),
            (33, 33),
            (9, 65),
            (64, 97),
        ] {
            let pixels = (0..w * h)
                .map(|i: u32| {
                    let z = i.wrapping_mul(2_654_435_761) ^ (i >> 3).wrapping_mul(40_503);
                    Rgba8Image::pack(z as u8, (z >> 8) as u8, (z >> 16) as u8)
                })
                .collect();
            let image = Rgba8Image {
                width: w,
                height: h,
                pixels,
            };
            assert_eq!(gradient(&image).pixels, by_rows(&image), "{w}x{h}");
        }
    }

    /// The brightness ratio reads packed messages as their RGBA twins, and a black camera is
    /// the darkest, not a division by zero.
    #[test]
    fn brightness_ratio_of_packed_and_black_images() {
        use crate::image::PackedImage;
        let (w, h) = (9u32, 7u32);
        let grey = |v: u8| grey_image(w, h, |_, _| f64::from(v));
        let rgb: Vec<u8> = (0..w * h).flat_map(|_| [150u8, 150, 150]).collect();
        let mono = vec![100u8; (w * h) as usize];
        // Channel order: blue bytes read as bgr8 are blue, as rgb8 red, each as its RGBA
        // twin's grey.
        let blue_first: Vec<u8> = (0..w * h).flat_map(|_| [255u8, 0, 0]).collect();
        for (format, twin) in [
            (PackedFormat::Bgr8, Rgba8Image::pack(0, 0, 255)),
            (PackedFormat::Rgb8, Rgba8Image::pack(255, 0, 0)),
        ] {
            let set = [
                packed(&blue_first, format, w, h),
                packed(&mono, PackedFormat::Mono8, w, h),
            ];
            let ratio = brightness_ratio(SetImages::Cameras {
                set: &set,
                picked: None,
            });
            let expected = f64::from(luma(Rgba8Image::pack(100, 100, 100))) / f64::from(luma(twin));
            assert!(
                (ratio - expected).abs() < 1e-9,
                "{format:?}: {ratio} against {expected}"
            );
        }
        fn packed(bytes: &[u8], format: PackedFormat, w: u32, h: u32) -> CameraImage<'_> {
            CameraImage::Packed(PackedImage {
                width: w,
                height: h,
                format,
                bytes,
            })
        }
        let set = [
            packed(&rgb, PackedFormat::Bgr8, w, h),
            packed(&mono, PackedFormat::Mono8, w, h),
        ];
        let ratio = brightness_ratio(SetImages::Cameras {
            set: &set,
            picked: None,
        });
        assert!((ratio - 1.5).abs() < 1e-9, "{ratio}");
        let (a, b) = (grey(100), grey(120));
        let two = [a.clone(), b];
        assert!((brightness_ratio(SetImages::All(&two)) - 1.2).abs() < 1e-9);
        let black = [a.clone(), grey(0)];
        assert!(brightness_ratio(SetImages::All(&black)) > 100.0);
        assert_eq!(brightness_ratio(SetImages::All(&[a])), 1.0);
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
