//! Twins of `shaders/splat.wgsl` and `shaders/visibility.wgsl`. The z-buffer keeps the nearest
//! depth as the max of the inverted bits, as the shader's atomic max does, so the order of the
//! writes does not matter: splat runs cameras in parallel, visibility rows in parallel.

use rayon::prelude::*;

use super::common::vectorised_fn;
use super::common::*;
use super::Maps;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Where every reference pixel's median depth lands in each camera (rig order; empty for the
/// reference): the texel index (NONE: not seen) and the depth there. The splat makes them
/// and the visibility stage reads them again instead of projecting twice (the shaders project
/// in both stages; the floats are the same). Kept across frame sets.
#[derive(Debug, Default)]
pub struct Projections {
    cameras: Vec<CameraProjections>,
}

/// One camera's texel index and depth of every reference pixel.
type CameraProjections = (Vec<u32>, Vec<f32>);

/// Splats the median depth into every other camera's z-buffer (cleared to 0 = empty).
/// Cameras in parallel, each writing only its own section: the nearest depth kept with a plain
/// max of the inverted bits, so the result is the shader's atomic max without atomics.
pub fn splat(plan: &SweepPlan, maps: &Maps, zbuffer: &mut [u32], projections: &mut Projections) {
    let ref_index = plan.params.reference;
    let median = maps.section(MAP_DEPTH_MEDIAN);
    let npix = plan.pixel_count();
    projections
        .cameras
        .resize_with(plan.cameras.len(), Default::default);
    let mut slots = projections.cameras.iter_mut();
    let mut sections: Vec<(&GpuCamera, &mut [u32], &mut CameraProjections)> =
        Vec::with_capacity(plan.cameras.len());
    let mut rest = zbuffer;
    let mut offset = 0usize;
    for (i, cam) in plan.cameras.iter().enumerate() {
        let start = cam.size[2] as usize;
        let len = cam.size[0] as usize * cam.size[1] as usize;
        // Sections lie in camera order (plan.rs); skip any gap before this one.
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(start.saturating_sub(offset));
        let (section, tail) = tail.split_at_mut(len.min(tail.len()));
        rest = tail;
        offset = start + section.len();
        let Some(slot) = slots.next() else { break };
        if i as u32 == ref_index {
            slot.0.clear();
            slot.1.clear();
        } else {
            slot.0.resize(npix, NONE);
            slot.1.resize(npix, 0.0);
            sections.push((cam, section, slot));
        }
    }
    if sections.len() >= rayon::current_num_threads() {
        sections
            .into_par_iter()
            .for_each(|(cam, section, (index, z))| {
                splat_camera(plan, cam, median, section, index, z)
            });
        return;
    }
    // Fewer cameras than threads (a stereo pair splats into one): every camera's rows
    // projected in parallel, then each camera's scatter (the max is the same in any order).
    let width = plan.width as usize;
    let rows = PROJECT_ROWS * width.max(1);
    for (cam, _, (index, z)) in &mut sections {
        let cam = &**cam;
        median
            .par_chunks(rows)
            .zip(plan.rays.par_chunks(rows))
            .zip(index.par_chunks_mut(rows).zip(z.par_chunks_mut(rows)))
            .for_each(|((depths, rays), (index, z))| {
                project_rows(width, cam, depths, rays, index, z)
            });
    }
    sections
        .into_par_iter()
        .for_each(|(cam, section, (index, z))| scatter(cam, section, index, z));
}

/// Reference rows per parallel task when [`splat`] projects a camera's rows in parallel.
const PROJECT_ROWS: usize = 16;

/// "Not seen" in a row of texel indices.
const NONE: u32 = u32::MAX;

/// The nearest texel of camera `cam` (its index in the image buffer, NONE when outside,
/// behind or the depth is NaN) and the depth in that camera of every pixel of a reference
/// row: the projections of a whole row in one loop the compiler vectorises (`nearest_texel`'s
/// arithmetic, the same floats), so that only the z-buffer's scatter or gather stays scalar.
#[inline(always)]
fn project_row(
    cam: &GpuCamera,
    rays: &[[f32; 4]],
    depths: &[f32],
    index: &mut [u32],
    z: &mut [f32],
) {
    match cam.size[3] {
        DIST_NONE => lens_row(cam, rays, depths, index, z, |n| n),
        DIST_PLUMB_BOB => lens_row(cam, rays, depths, index, z, |n| plumb_bob(cam, n)),
        _ => {
            // The equidistant lens (an arctangent per pixel) as `project` does it.
            let rows = rays.iter().zip(depths).zip(index).zip(z);
            for (((&ray, &depth), index), z) in rows {
                let projected = project(cam, [ray[0] * depth, ray[1] * depth, ray[2] * depth]);
                let seen = projected[2] > 0.0;
                *index = nearest_texel(cam, [projected[0], projected[1]], depth, seen);
                *z = projected[2];
            }
        }
    }
}

/// `project_row` for the pinhole and plumb-bob lenses (`distort`: `lens` less its fold test
/// and intrinsics): `project` without its branches, every step for every pixel and the result
/// selected, so the loop vectorises; the same floats. Behind the camera (z <= 1e-6) or past
/// the distortion's fold `project` gives z = -1 and the pixel is not used.
#[inline(always)]
fn lens_row(
    cam: &GpuCamera,
    rays: &[[f32; 4]],
    depths: &[f32],
    index: &mut [u32],
    z: &mut [f32],
    distort: impl Fn(Vec2) -> Vec2,
) {
    let rows = rays.iter().zip(depths).zip(index).zip(z);
    for (((&ray, &depth), index), z) in rows {
        let point = [ray[0] * depth, ray[1] * depth, ray[2] * depth];
        let (pixel, camera_z, projected) = project_unbranched(cam, point, &distort);
        *index = nearest_texel(cam, pixel, depth, projected);
        *z = if projected { camera_z } else { -1.0 };
    }
}

/// The image-buffer index of the texel nearest to `pixel` in camera `cam`, or NONE when the
/// point was not `projected`, the depth is NaN or the texel is outside the image.
#[inline(always)]
fn nearest_texel(cam: &GpuCamera, pixel: Vec2, depth: f32, projected: bool) -> u32 {
    let texel = [(pixel[0] + 0.5).floor(), (pixel[1] + 0.5).floor()];
    let seen = !depth.is_nan() && projected && inside(cam, texel);
    let at = cam.size[2]
        .wrapping_add((texel[1] as u32).wrapping_mul(cam.size[0]))
        .wrapping_add(texel[0] as u32);
    if seen {
        at
    } else {
        NONE
    }
}

vectorised_fn! {
/// [`project_row`] of every row of `depths` (`width` pixels each).
fn project_rows(width: usize, cam: &GpuCamera, depths: &[f32], rays: &[[f32; 4]], index: &mut [u32], z: &mut [f32]) {
    let rows = depths
        .chunks_exact(width)
        .zip(rays.chunks_exact(width))
        .zip(index.chunks_exact_mut(width).zip(z.chunks_exact_mut(width)));
    for ((depths, rays), (index, z)) in rows {
        project_row(cam, rays, depths, index, z);
    }
}
}

/// The nearest depths of a camera's projected pixels (`index`, `z`) into its z-buffer
/// `section`: the max of the inverted bits.
#[inline(always)]
fn scatter_row(first: usize, section: &mut [u32], index: &[u32], z: &[f32]) {
    for (&at, &z) in index.iter().zip(z) {
        if at != NONE {
            if let Some(stored) = section.get_mut(at as usize - first) {
                *stored = (*stored).max(!z.to_bits());
            }
        }
    }
}

/// [`scatter_row`] of every projected pixel of camera `cam`.
fn scatter(cam: &GpuCamera, section: &mut [u32], index: &[u32], z: &[f32]) {
    scatter_row(cam.size[2] as usize, section, index, z);
}

vectorised_fn! {
/// Splats every reference depth into one camera's z-buffer section, a row at a time.
fn splat_camera(
    plan: &SweepPlan,
    cam: &GpuCamera,
    median: &[f32],
    section: &mut [u32],
    index: &mut [u32],
    z: &mut [f32],
) {
    let first = cam.size[2] as usize;
    let width = plan.width as usize;
    let rows = median
        .chunks_exact(width)
        .zip(plan.rays.chunks_exact(width))
        .zip(index.chunks_exact_mut(width).zip(z.chunks_exact_mut(width)));
    for ((depths, rays), (index, z)) in rows {
        project_row(cam, rays, depths, index, z);
        scatter_row(first, section, index, z);
    }
}
}

/// Counts the cameras that see each pixel and invalidates those seen by too few.
pub fn visibility(plan: &SweepPlan, zbuffer: &[u32], projections: &Projections, maps: &mut Maps) {
    let width = plan.width as usize;
    let [_, median, depth_out, confidence, _, selection, visible] = maps.sections_mut();
    let median = &*median;
    depth_out
        .par_chunks_mut(width)
        .zip(confidence.par_chunks_mut(width))
        .zip(selection.par_chunks_mut(width))
        .zip(visible.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (((depth_out, confidence), selection), visible))| {
            let row = VisibilityRow {
                depth_out,
                confidence,
                selection,
                visible,
            };
            visibility_row(plan, zbuffer, projections, median, y, row);
        });
}

/// One reference row's outputs of the visibility stage.
struct VisibilityRow<'a> {
    depth_out: &'a mut [f32],
    confidence: &'a mut [f32],
    selection: &'a mut [f32],
    visible: &'a mut [f32],
}

vectorised_fn! {
/// The visibility of reference row `y` (compiled for AVX2+FMA where the CPU has it: the
/// projections are most of the stage).
fn visibility_row(
    plan: &SweepPlan,
    zbuffer: &[u32],
    projections: &Projections,
    median: &[f32],
    y: usize,
    row: VisibilityRow<'_>,
) {
    let params = &plan.params;
    let width = plan.width as usize;
    let ref_index = params.reference;
    let tolerance = params.occlusion_tolerance;
    let inverse_depth = params.occlusion_inverse_depth;
    let VisibilityRow {
        depth_out,
        confidence,
        selection,
        visible,
    } = row;
    let depths = &median[y * width..(y + 1) * width];
    let mut seen = vec![u32::from(ref_index != NO_CAMERA); width];
    for (i, (index, z)) in projections.cameras.iter().enumerate() {
        if i as u32 == ref_index {
            continue;
        }
        let range = y * width..(y + 1) * width;
        for ((&at, &z), seen) in index[range.clone()].iter().zip(&z[range]).zip(seen.iter_mut()) {
            if at != NONE {
                let stored = zbuffer[at as usize];
                if stored == 0 || seen_past(z, f32::from_bits(!stored), tolerance, inverse_depth) {
                    *seen += 1;
                }
            }
        }
    }
    for x in 0..width {
        let depth = depths[x];
        if depth.is_nan() {
            depth_out[x] = depth;
            visible[x] = 0.0;
            continue;
        }
        visible[x] = seen[x] as f32;
        if seen[x] < params.min_visible {
            depth_out[x] = f32::NAN;
            confidence[x] = 0.0;
            selection[x] = 3.0;
        } else {
            depth_out[x] = depth;
        }
    }
}
}

/// Whether a point at depth `z` in a camera is seen past the nearest surface `nearest` there:
/// it is not behind it by more than `tolerance` of its depth, or not by more than
/// `inverse_depth` in inverse depth (`1 / nearest - 1 / z`, multiplied out: no division, the
/// shader's twin compares the same products).
#[inline(always)]
fn seen_past(z: f32, nearest: f32, tolerance: f32, inverse_depth: f32) -> bool {
    z <= nearest * (1.0 + tolerance) || z - nearest <= inverse_depth * (z * nearest)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branch-free rows (pinhole, plumb-bob) give `project`'s texel for every pixel (seen,
    /// outside, behind the camera, past the fold, no depth) and its camera depth for every seen
    /// one, bit for bit.
    #[test]
    fn lens_rows_are_project_bit_for_bit() {
        for plan in converging_test_plans() {
            let n = plan.rays.len();
            let distorted = plan.cameras.iter().any(|cam| cam.size[3] != DIST_NONE);
            // Far, near (side cameras see points far off their axes: past the fold), behind,
            // and missing depths.
            let depths: Vec<f32> = (0..n)
                .map(|i| match i % 6 {
                    0 => 2.0 + (i % 13) as f32 * 0.1,
                    1 => 0.15 + (i % 5) as f32 * 0.02,
                    2 => -1.0,
                    3 => f32::NAN,
                    4 => 0.4,
                    _ => 8.0,
                })
                .collect();
            let (mut seen, mut folded) = (0, 0);
            for (c, cam) in plan.cameras.iter().enumerate() {
                if c as u32 == plan.params.reference {
                    continue;
                }
                let (mut index, mut z) = (vec![0; n], vec![0.0; n]);
                project_row(cam, &plan.rays, &depths, &mut index, &mut z);
                for (i, (&ray, &depth)) in plan.rays.iter().zip(&depths).enumerate() {
                    let point = [ray[0] * depth, ray[1] * depth, ray[2] * depth];
                    let projected = project(cam, point);
                    let ok = projected[2] > 0.0;
                    let expected = nearest_texel(cam, [projected[0], projected[1]], depth, ok);
                    assert_eq!(index[i], expected, "camera {c} pixel {i} depth {depth}");
                    // The depth is read only where the texel is (`visibility_row`).
                    if expected != NONE {
                        assert_eq!(
                            z[i].to_bits(),
                            projected[2].to_bits(),
                            "camera {c} pixel {i}"
                        );
                        seen += 1;
                    }
                    let p =
                        [cam.row0, cam.row1, cam.row2].map(|row| dot3(xyz(row), point) + row[3]);
                    let n2 = (p[0] / p[2]).powi(2) + (p[1] / p[2]).powi(2);
                    folded += usize::from(distorted && p[2] > 1e-6 && n2 > cam.dist_b[1]);
                }
            }
            assert!(seen > n / 10, "{seen} seen");
            if distorted {
                assert!(folded > 0, "no pixel past the fold");
            }
        }
    }
}
