//! Twin of `shaders/cost.wgsl`.
// The `!(x > 0.0)` tests mirror the shaders and are NaN-safe on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::common::*;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

#[derive(Default)]
struct Acc {
    sum: f32,
    count: u32,
    left_sum: f32,
    left_count: u32,
    right_sum: f32,
    right_count: u32,
    n_best: u32,
    best: [f32; MAX_BEST_N as usize],
}

fn texel(images: &[u32], cam: &GpuCamera, x: u32, y: u32) -> Vec3 {
    let p = images[(cam.size[2] + y * cam.size[0] + x) as usize].to_le_bytes();
    [
        f32::from(p[0]) / 255.0 * 255.0,
        f32::from(p[1]) / 255.0 * 255.0,
        f32::from(p[2]) / 255.0 * 255.0,
    ]
}

fn mix3(a: Vec3, b: Vec3, t: f32) -> Vec3 {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn sample_bilinear(images: &[u32], cam: &GpuCamera, pixel: Vec2) -> Vec3 {
    let bx = pixel[0].floor();
    let by = pixel[1].floor();
    let (fx, fy) = (pixel[0] - bx, pixel[1] - by);
    let (x0, y0) = (bx as u32, by as u32);
    let x1 = (x0 + 1).min(cam.size[0] - 1);
    let y1 = (y0 + 1).min(cam.size[1] - 1);
    let top = mix3(texel(images, cam, x0, y0), texel(images, cam, x1, y0), fx);
    let bottom = mix3(texel(images, cam, x0, y1), texel(images, cam, x1, y1), fx);
    mix3(top, bottom, fy)
}

fn tssd(tau: f32, a: Vec3, b: Vec3) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    tau.min(dot3(d, d))
}

fn add_pair(acc: &mut Acc, params: &GpuParams, cost: f32, half: u32) {
    acc.sum += cost;
    acc.count += 1;
    if half == HALF_LEFT {
        acc.left_sum += cost;
        acc.left_count += 1;
    } else if half == HALF_RIGHT {
        acc.right_sum += cost;
        acc.right_count += 1;
    }
    let n = params.best_n;
    if params.scoring == SCORING_BEST_N {
        let kept = acc.n_best;
        if kept == n && cost >= acc.best[(n - 1) as usize] {
            return;
        }
        let mut i = kept.min(n - 1) as usize;
        while i > 0 && acc.best[i - 1] > cost {
            acc.best[i] = acc.best[i - 1];
            i -= 1;
        }
        acc.best[i] = cost;
        acc.n_best = (kept + 1).min(n);
    }
}

fn mean_or_invalid(sum: f32, count: u32) -> f32 {
    if count == 0 {
        INVALID
    } else {
        sum / count as f32
    }
}

fn pair_half(a: u32, b: u32) -> u32 {
    if a == HALF_REFERENCE {
        return b;
    }
    if b == HALF_REFERENCE || a == b {
        return a;
    }
    HALF_REFERENCE
}

/// Fills `cost_slab` (channels x pixels per plane) for planes `first_plane ..
/// first_plane + plane_count`.
pub fn run(
    plan: &SweepPlan,
    images: &[u32],
    first_plane: u32,
    plane_count: u32,
    cost_slab: &mut [f32],
) {
    let params = &plan.params;
    let (width, height, npix) = (params.width, params.height, params.pixel_count as usize);
    let channels = params.channels as usize;
    let ref_index = params.reference;
    let n_cameras = params.cameras;
    let tau = params.tau;
    for z in 0..plane_count {
        for y in 0..height {
            for x in 0..width {
                let pix = (y * width + x) as usize;
                let slot = z as usize * channels * npix + pix;
                let ray = xyz(plan.rays[pix]);
                let depth = plane_depth(plan.planes[(first_plane + z) as usize], ray);
                if !(depth > 0.0) {
                    for ch in 0..channels {
                        cost_slab[slot + ch * npix] = INVALID;
                    }
                    continue;
                }
                let point_in_ref = [ray[0] * depth, ray[1] * depth, ray[2] * depth];
                let per_pair = params.aggregation == AGG_PER_PAIR;
                let mut acc = Acc::default();
                if params.pair_mode == PAIRS_REFERENCE {
                    let ref_cam = &plan.cameras[ref_index as usize];
                    let ref_colour = texel(images, ref_cam, x, y);
                    let mut p = 0;
                    for i in 0..n_cameras {
                        if i == ref_index {
                            continue;
                        }
                        let cam = &plan.cameras[i as usize];
                        let projected = project(cam, point_in_ref);
                        let visible =
                            projected[2] > 0.0 && inside(cam, [projected[0], projected[1]]);
                        let cost = || {
                            tssd(
                                tau,
                                ref_colour,
                                sample_bilinear(images, cam, [projected[0], projected[1]]),
                            )
                        };
                        if per_pair {
                            cost_slab[slot + p * npix] = if visible { cost() } else { INVALID };
                            p += 1;
                        } else if visible {
                            add_pair(&mut acc, params, cost(), cam.info[0]);
                        }
                    }
                    if per_pair {
                        continue;
                    }
                } else {
                    let mut colours = [[0.0f32; 3]; MAX_CAMERAS as usize];
                    let mut visible = [false; MAX_CAMERAS as usize];
                    for i in 0..n_cameras as usize {
                        let cam = &plan.cameras[i];
                        if i as u32 == ref_index {
                            colours[i] = texel(images, cam, x, y);
                            visible[i] = true;
                            continue;
                        }
                        let projected = project(cam, point_in_ref);
                        visible[i] =
                            projected[2] > 0.0 && inside(cam, [projected[0], projected[1]]);
                        if visible[i] {
                            colours[i] = sample_bilinear(images, cam, [projected[0], projected[1]]);
                        }
                    }
                    let mut p = 0;
                    for i in 0..n_cameras as usize {
                        for j in i + 1..n_cameras as usize {
                            let both = visible[i] && visible[j];
                            if per_pair {
                                cost_slab[slot + p * npix] = if both {
                                    tssd(tau, colours[i], colours[j])
                                } else {
                                    INVALID
                                };
                                p += 1;
                            } else if both {
                                let half =
                                    pair_half(plan.cameras[i].info[0], plan.cameras[j].info[0]);
                                add_pair(&mut acc, params, tssd(tau, colours[i], colours[j]), half);
                            }
                        }
                    }
                    if per_pair {
                        continue;
                    }
                }
                let scoring = params.scoring;
                if scoring == SCORING_HALF {
                    let left = mean_or_invalid(acc.left_sum, acc.left_count);
                    let right = mean_or_invalid(acc.right_sum, acc.right_count);
                    cost_slab[slot] = left;
                    cost_slab[slot + npix] = right;
                    if channels == 3 {
                        let mut m = left;
                        if left < 0.0 || (right >= 0.0 && right < left) {
                            m = right;
                        }
                        cost_slab[slot + 2 * npix] = m;
                    }
                } else if scoring == SCORING_BEST_N {
                    let s: f32 = acc.best[..acc.n_best as usize].iter().sum();
                    cost_slab[slot] = mean_or_invalid(s, acc.n_best);
                } else {
                    cost_slab[slot] = mean_or_invalid(acc.sum, acc.count);
                }
            }
        }
    }
}
