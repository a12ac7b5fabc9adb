//! Which cameras of a rig a reference camera sweeps with: its *neighbours*, chosen from the
//! rig's geometry alone, so that each of several references of one rig (`references`) takes
//! the cameras that see what it sees.
//!
//! A camera is a neighbour when it sees at least [`MIN_OVERLAP`] of the reference's view over
//! the depth range: a grid of reference pixels, each at the nearest, the farthest and the
//! middle (in inverse depth) depth of the sweep, projected into the camera (in front of it and
//! inside its image). A camera that faces away (a surround rig's back cameras) or sees a
//! sliver only is left out; it would cost a sweep and give nothing but noise. With
//! `max_neighbours` > 0 the nearest cameras (camera centres) are kept, taken alternately from
//! the two halves of the rig's best half-sequence split, so that both halves keep their
//! nearest views.

use glam::DVec2;

use super::{Reference, Rig, RigCamera};

/// The share of the reference's sampled view a camera must see to be a neighbour.
pub const MIN_OVERLAP: f64 = 0.1;

/// Samples across and down the reference image.
const GRID: (u32, u32) = (16, 12);

/// The share of the reference camera's view (over `[min_depth_m, max_depth_m]`) that
/// `camera` sees: 0 to 1.
pub fn view_overlap(
    reference: &RigCamera,
    camera: &RigCamera,
    min_depth_m: f64,
    max_depth_m: f64,
) -> f64 {
    let cam_from_ref = camera
        .cam_from_rig
        .compose(&reference.cam_from_rig.inverse());
    let k = reference.model.intrinsics;
    let middle = 2.0 / (1.0 / min_depth_m + 1.0 / max_depth_m);
    let depths = [min_depth_m, middle, max_depth_m];
    let (mut seen, mut total) = (0u32, 0u32);
    for gy in 0..GRID.1 {
        for gx in 0..GRID.0 {
            let pixel = DVec2::new(
                (f64::from(gx) + 0.5) / f64::from(GRID.0) * f64::from(k.width_px) - 0.5,
                (f64::from(gy) + 0.5) / f64::from(GRID.1) * f64::from(k.height_px) - 0.5,
            );
            let Some(ray) = reference.model.unproject_z1(pixel) else {
                continue;
            };
            for depth in depths {
                total += 1;
                let point = cam_from_ref.transform_point(ray * depth);
                if camera
                    .model
                    .project(point)
                    .is_some_and(|p| camera.model.contains(p))
                {
                    seen += 1;
                }
            }
        }
    }
    if total == 0 {
        0.0
    } else {
        f64::from(seen) / f64::from(total)
    }
}

/// The cameras reference camera `reference` of `cameras` sweeps with, itself included, in rig
/// order: every camera that sees at least [`MIN_OVERLAP`] of its view, and of those at most
/// `max_neighbours` (0: all) nearest, alternately from each half of the rig.
pub fn neighbours(
    cameras: &[RigCamera],
    reference: usize,
    min_depth_m: f64,
    max_depth_m: f64,
    max_neighbours: usize,
) -> Vec<usize> {
    let Some(ref_camera) = cameras.get(reference) else {
        return Vec::new();
    };
    let seeing: Vec<usize> = (0..cameras.len())
        .filter(|&i| {
            i != reference
                && view_overlap(ref_camera, &cameras[i], min_depth_m, max_depth_m) >= MIN_OVERLAP
        })
        .collect();
    let mut chosen = if max_neighbours == 0 || seeing.len() <= max_neighbours {
        seeing
    } else {
        nearest_by_half(cameras, reference, &seeing, max_neighbours)
    };
    chosen.push(reference);
    chosen.sort_unstable();
    chosen
}

/// `count` of `candidates`, the nearest to the reference first, alternately from each half of
/// the half-sequence split (of the reference and the candidates), the nearer half first.
fn nearest_by_half(
    cameras: &[RigCamera],
    reference: usize,
    candidates: &[usize],
    count: usize,
) -> Vec<usize> {
    let centre = cameras[reference].centre_in_rig();
    let distance = |i: usize| cameras[i].centre_in_rig().distance(centre);
    // The split of the reference with its candidates (the rig's own rule).
    let mut members: Vec<usize> = candidates.to_vec();
    members.push(reference);
    members.sort_unstable();
    let sub_cameras: Vec<RigCamera> = members.iter().map(|&i| cameras[i].clone()).collect();
    let ref_pos = members.iter().position(|&i| i == reference).unwrap_or(0);
    let split = Rig {
        cameras: sub_cameras,
        reference: Reference::Camera(ref_pos),
    }
    .half_sequence_split();
    let mut halves: [Vec<usize>; 2] = [Vec::new(), Vec::new()];
    for (pos, side) in split.iter().enumerate() {
        if let Some(right) = side {
            halves[usize::from(*right)].push(members[pos]);
        }
    }
    for half in &mut halves {
        half.sort_by(|&a, &b| distance(a).total_cmp(&distance(b)).then(a.cmp(&b)));
    }
    let first = match (halves[0].first(), halves[1].first()) {
        (Some(&l), Some(&r)) if distance(r) < distance(l) => 1,
        (None, Some(_)) => 1,
        _ => 0,
    };
    let mut taken = Vec::with_capacity(count);
    let mut next = [0usize; 2];
    let mut side = first;
    while taken.len() < count && (next[0] < halves[0].len() || next[1] < halves[1].len()) {
        if next[side] < halves[side].len() {
            taken.push(halves[side][next[side]]);
            next[side] += 1;
        }
        side = 1 - side;
    }
    taken
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CameraModel, RigidTransform};
    use glam::{DQuat, DVec3};

    fn model() -> CameraModel {
        CameraModel::pinhole(crate::synthetic::intrinsics(160, 120))
    }

    fn camera(name: &str, x: f64, yaw: f64) -> RigCamera {
        let rig_from_cam = RigidTransform {
            rotation: DQuat::from_rotation_y(yaw),
            translation: DVec3::new(x, 0.0, 0.0),
        };
        RigCamera {
            name: name.into(),
            model: model(),
            cam_from_rig: rig_from_cam.inverse(),
        }
    }

    #[test]
    fn a_row_sees_itself_and_a_camera_facing_away_does_not() {
        let row: Vec<RigCamera> = (0..5)
            .map(|i| camera(&format!("c{i}"), 0.1 * i as f64, 0.0))
            .collect();
        assert!(view_overlap(&row[2], &row[3], 2.0, 10.0) > 0.8);
        assert_eq!(neighbours(&row, 2, 2.0, 10.0, 0), vec![0, 1, 2, 3, 4]);
        // A camera beside the reference that looks backwards sees nothing of its view.
        let mut rig = row.clone();
        rig.push(camera("back", 0.25, std::f64::consts::PI));
        assert_eq!(view_overlap(&rig[2], &rig[5], 2.0, 10.0), 0.0);
        assert_eq!(neighbours(&rig, 2, 2.0, 10.0, 0), vec![0, 1, 2, 3, 4]);
        // Turned 90 degrees: nothing either.
        let side = camera("side", 0.2, std::f64::consts::FRAC_PI_2);
        assert_eq!(view_overlap(&row[2], &side, 2.0, 10.0), 0.0);
    }

    #[test]
    fn at_most_n_nearest_alternately_from_both_halves() {
        let row: Vec<RigCamera> = (0..9)
            .map(|i| camera(&format!("c{i}"), 0.1 * i as f64, 0.0))
            .collect();
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 2), vec![3, 4, 5]);
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 4), vec![2, 3, 4, 5, 6]);
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 3).len(), 4);
        // At an end of the row there is one half only: the nearest of it.
        assert_eq!(neighbours(&row, 0, 2.0, 10.0, 2), vec![0, 1, 2]);
        // More than there are: all of them.
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 20).len(), 9);
    }

    #[test]
    fn surround_rig_references_take_their_own_neighbours() {
        // Eight cameras on a circle facing outwards, 45 degrees apart with 90-degree lenses
        // (fx = width / 2): each sees its two neighbours' views in part, the rest not at all.
        let n = 8;
        let cameras: Vec<RigCamera> = (0..n)
            .map(|i| {
                let yaw = i as f64 * std::f64::consts::TAU / n as f64;
                let rot = DQuat::from_rotation_y(yaw);
                let rig_from_cam = RigidTransform {
                    rotation: rot,
                    translation: rot * DVec3::new(0.0, 0.0, 0.3),
                };
                RigCamera {
                    name: format!("c{i}"),
                    model: CameraModel::pinhole(crate::geometry::PinholeIntrinsics {
                        width_px: 160,
                        height_px: 120,
                        fx_px: 80.0,
                        fy_px: 80.0,
                        cx_px: 79.5,
                        cy_px: 59.5,
                    }),
                    cam_from_rig: rig_from_cam.inverse(),
                }
            })
            .collect();
        for r in 0..n {
            let mut expected = vec![(r + n - 1) % n, r, (r + 1) % n];
            expected.sort_unstable();
            assert_eq!(
                neighbours(&cameras, r, 2.0, 20.0, 0),
                expected,
                "reference {r}"
            );
        }
    }
}
