//! Twins of `shaders/box_h.wgsl` and `shaders/box_v.wgsl`.

use crate::sweep::plan::SweepPlan;

/// Horizontal window sums (sum, count) for every padded column anchor.
pub fn box_h(plan: &SweepPlan, plane_count: u32, cost_slab: &[f32], row_sums: &mut [[f32; 2]]) {
    let params = &plan.params;
    let (width, height, npix) = (
        params.width as i32,
        params.height as usize,
        plan.pixel_count(),
    );
    let window_w = params.window_w as i32;
    let (padded_w, _) = plan.padded_size();
    let slices = plane_count as usize * plan.channels();
    for zc in 0..slices {
        for y in 0..height {
            let row = zc * npix + y * width as usize;
            for gx in 0..padded_w as usize {
                let ax = gx as i32 - window_w + 1;
                let mut acc = [0.0f32; 2];
                for dx in 0..window_w {
                    let x = ax + dx;
                    if x < 0 || x >= width {
                        continue;
                    }
                    let c = cost_slab[row + x as usize];
                    if c >= 0.0 {
                        acc[0] += c;
                        acc[1] += 1.0;
                    }
                }
                row_sums[(zc * height + y) * padded_w as usize + gx] = acc;
            }
        }
    }
}

/// Vertical sums of the row sums: the w x h window sums for every anchor.
pub fn box_v(plan: &SweepPlan, plane_count: u32, row_sums: &[[f32; 2]], box_sums: &mut [[f32; 2]]) {
    let params = &plan.params;
    let height = params.height as i32;
    let window_h = params.window_h as i32;
    let (padded_w, padded_h) = (plan.padded_size().0 as usize, plan.padded_size().1 as usize);
    let slices = plane_count as usize * plan.channels();
    for zc in 0..slices {
        for gy in 0..padded_h {
            let ay = gy as i32 - window_h + 1;
            for gx in 0..padded_w {
                let mut acc = [0.0f32; 2];
                for dy in 0..window_h {
                    let y = ay + dy;
                    if y < 0 || y >= height {
                        continue;
                    }
                    let s = row_sums[(zc * height as usize + y as usize) * padded_w + gx];
                    acc[0] += s[0];
                    acc[1] += s[1];
                }
                box_sums[(zc * padded_h + gy) * padded_w + gx] = acc;
            }
        }
    }
}
