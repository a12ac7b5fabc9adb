//! Twin of `shaders/median.wgsl`. Rows in parallel.

use rayon::prelude::*;

use super::Maps;

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

fn sort2(v: &mut [f32; 9], a: usize, b: usize) {
    let (lo, hi) = (v[a].min(v[b]), v[a].max(v[b]));
    v[a] = lo;
    v[b] = hi;
}

/// The shader's 25-comparator sorting network.
fn sort9(v: &mut [f32; 9]) {
    sort2(v, 0, 1);
    sort2(v, 3, 4);
    sort2(v, 6, 7);
    sort2(v, 1, 2);
    sort2(v, 4, 5);
    sort2(v, 7, 8);
    sort2(v, 0, 1);
    sort2(v, 3, 4);
    sort2(v, 6, 7);
    sort2(v, 0, 3);
    sort2(v, 3, 6);
    sort2(v, 0, 3);
    sort2(v, 1, 4);
    sort2(v, 4, 7);
    sort2(v, 1, 4);
    sort2(v, 2, 5);
    sort2(v, 5, 8);
    sort2(v, 2, 5);
    sort2(v, 1, 3);
    sort2(v, 5, 7);
    sort2(v, 2, 6);
    sort2(v, 4, 6);
    sort2(v, 2, 4);
    sort2(v, 2, 3);
    sort2(v, 5, 6);
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
            for gx in 0..width {
                let centre = raw[gy * width + gx];
                if centre.is_nan() || !enabled {
                    out[gx] = centre;
                    continue;
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
                out[gx] = v[(count - 1) / 2];
            }
        });
}
