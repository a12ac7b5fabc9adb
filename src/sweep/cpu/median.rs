//! Twin of `shaders/median.wgsl`.

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

pub fn run(plan: &SweepPlan, maps: &mut [f32]) {
    let params = &plan.params;
    let (width, height) = (params.width as i32, params.height as i32);
    let npix = plan.pixel_count();
    for gy in 0..height {
        for gx in 0..width {
            let pix = (gy * width + gx) as usize;
            let centre = maps[MAP_DEPTH_RAW * npix + pix];
            if centre.is_nan() || params.median == 0 {
                maps[MAP_DEPTH_MEDIAN * npix + pix] = centre;
                continue;
            }
            let mut v = [BIG; 9];
            let mut count = 0usize;
            for (i, value) in v.iter_mut().enumerate() {
                let x = gx + (i % 3) as i32 - 1;
                let y = gy + (i / 3) as i32 - 1;
                if x >= 0 && y >= 0 && x < width && y < height {
                    let d = maps[MAP_DEPTH_RAW * npix + (y * width + x) as usize];
                    if !d.is_nan() {
                        *value = d;
                        count += 1;
                    }
                }
            }
            sort9(&mut v);
            maps[MAP_DEPTH_MEDIAN * npix + pix] = v[(count - 1) / 2];
        }
    }
}
