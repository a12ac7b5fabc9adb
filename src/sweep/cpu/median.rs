//! Twin of `shaders/median.wgsl`. Rows in parallel.

use rayon::prelude::*;

use super::common::vectorised_fn;
use super::Maps;

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// The shader's 25-comparator sorting network of nine values.
const NETWORK: [(usize, usize); 25] = [
    (0, 1),
    (3, 4),
    (6, 7),
    (1, 2),
    (4, 5),
    (7, 8),
    (0, 1),
    (3, 4),
    (6, 7),
    (0, 3),
    (3, 6),
    (0, 3),
    (1, 4),
    (4, 7),
    (1, 4),
    (2, 5),
    (5, 8),
    (2, 5),
    (1, 3),
    (5, 7),
    (2, 6),
    (4, 6),
    (2, 4),
    (2, 3),
    (5, 6),
];

fn sort9(v: &mut [f32; 9]) {
    for (a, b) in NETWORK {
        let (lo, hi) = (v[a].min(v[b]), v[a].max(v[b]));
        v[a] = lo;
        v[b] = hi;
    }
}

pub fn run(plan: &SweepPlan, maps: &mut Maps) {
    let params = &plan.params;
    let (width, height) = (params.width as usize, params.height as usize);
    let enabled = params.median != 0;
    let [raw, median, ..] = maps.sections_mut();
    let raw = &*raw;
    median
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(gy, out)| {
            if enabled {
                median_row(raw, width, height, gy, out);
            } else {
                out.copy_from_slice(&raw[gy * width..(gy + 1) * width]);
            }
        });
}

/// The median of pixel (gx, gy): the shader's loop, for the border pixels.
fn median_at(raw: &[f32], width: usize, height: usize, gx: usize, gy: usize) -> f32 {
    let centre = raw[gy * width + gx];
    if centre.is_nan() {
        return centre;
    }
    let mut v = [BIG; 9];
    let mut count = 0usize;
    for (i, value) in v.iter_mut().enumerate() {
        let x = gx as isize + (i % 3) as isize - 1;
        let y = gy as isize + (i / 3) as isize - 1;
        if x >= 0 && y >= 0 && (x as usize) < width && (y as usize) < height {
            let d = raw[y as usize * width + x as usize];
            if !d.is_nan() {
                *value = d;
                count += 1;
            }
        }
    }
    sort9(&mut v);
    v[(count - 1) / 2]
}

/// Pixels per step of the interior loop (one AVX2 register of f32).
const LANES: usize = 8;

vectorised_fn! {
/// Row `gy` of the median: interior pixels LANES at a time (the nine neighbours as nine
/// vectors, NaN as BIG, the same sorting network on whole vectors, the median picked by each
/// lane's count of valid neighbours: the same values as `median_at`), the border by `median_at`.
fn median_row(raw: &[f32], width: usize, height: usize, gy: usize, out: &mut [f32]) {
    if gy == 0 || gy + 1 >= height || width < 3 {
        for (gx, o) in out.iter_mut().enumerate() {
            *o = median_at(raw, width, height, gx, gy);
        }
        return;
    }
    let rows = [
        &raw[(gy - 1) * width..gy * width],
        &raw[gy * width..(gy + 1) * width],
        &raw[(gy + 1) * width..(gy + 2) * width],
    ];
    let mut x = 1;
    while x + LANES < width {
        let mut v = [[0.0f32; LANES]; 9];
        let mut count = [0u32; LANES];
        for (i, lanes) in v.iter_mut().enumerate() {
            let src = &rows[i / 3][x - 1 + i % 3..][..LANES];
            for l in 0..LANES {
                let valid = !src[l].is_nan();
                lanes[l] = if valid { src[l] } else { BIG };
                count[l] += u32::from(valid);
            }
        }
        sort9_lanes(&mut v);
        let centre = &rows[1][x..x + LANES];
        for l in 0..LANES {
            let index = count[l].max(1).wrapping_sub(1) / 2;
            let mut m = v[0][l];
            for (i, lanes) in v.iter().enumerate().skip(1) {
                m = if index == i as u32 { lanes[l] } else { m };
            }
            out[x + l] = if centre[l].is_nan() { centre[l] } else { m };
        }
        x += LANES;
    }
    out[0] = median_at(raw, width, height, 0, gy);
    for (gx, o) in out.iter_mut().enumerate().take(width).skip(x) {
        *o = median_at(raw, width, height, gx, gy);
    }
}
}

#[inline(always)]
fn sort2_lanes(v: &mut [[f32; LANES]; 9], a: usize, b: usize) {
    let (x, y) = (v[a], v[b]);
    v[a] = std::array::from_fn(|l| x[l].min(y[l]));
    v[b] = std::array::from_fn(|l| x[l].max(y[l]));
}

/// `sort9`'s network on LANES pixels at once.
#[inline(always)]
fn sort9_lanes(v: &mut [[f32; LANES]; 9]) {
    for (a, b) in NETWORK {
        sort2_lanes(v, a, b);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vector rows give exactly the per-pixel loop's values, NaN holes and borders included.
    #[test]
    fn rows_match_the_per_pixel_median() {
        for (width, height) in [(1, 1), (2, 5), (3, 3), (9, 4), (10, 3), (37, 11)] {
            let mut seed = 12345u32 + width as u32;
            let raw: Vec<f32> = (0..width * height)
                .map(|_| {
                    seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    if seed >> 29 == 0 {
                        f32::NAN
                    } else {
                        (seed >> 8) as f32 / 65536.0
                    }
                })
                .collect();
            for gy in 0..height {
                let mut out = vec![0.0; width];
                median_row(&raw, width, height, gy, &mut out);
                for (gx, &got) in out.iter().enumerate() {
                    let want = median_at(&raw, width, height, gx, gy);
                    assert!(
                        got.to_bits() == want.to_bits(),
                        "{width}x{height} ({gx}, {gy}): {got} vs {want}"
                    );
                }
            }
        }
    }
}
