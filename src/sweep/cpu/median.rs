//! Twin of `shaders/median.wgsl`.

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

pub fn run(plan: &SweepPlan, maps: &mut [f32]) {
    let params = &plan.params;
    let (width, height) = (params.ref_size[0] as i32, params.ref_size[1] as i32);
    let npix = plan.pixel_count();
    for gy in 0..height {
        for gx in 0..width {
            let pix = (gy * width + gx) as usize;
            let centre = maps[MAP_DEPTH_RAW * npix + pix];
            if centre.is_nan() || params.window[3] == 0 {
                maps[MAP_DEPTH_MEDIAN * npix + pix] = centre;
                continue;
            }
            let mut values = [0.0f32; 9];
            let mut count = 0usize;
            for dy in -1..=1 {
                let y = gy + dy;
                if y < 0 || y >= height {
                    continue;
                }
                for dx in -1..=1 {
                    let x = gx + dx;
                    if x < 0 || x >= width {
                        continue;
                    }
                    let v = maps[MAP_DEPTH_RAW * npix + (y * width + x) as usize];
                    if v.is_nan() {
                        continue;
                    }
                    let mut i = count;
                    while i > 0 && values[i - 1] > v {
                        values[i] = values[i - 1];
                        i -= 1;
                    }
                    values[i] = v;
                    count += 1;
                }
            }
            maps[MAP_DEPTH_MEDIAN * npix + pix] = values[(count - 1) / 2];
        }
    }
}
