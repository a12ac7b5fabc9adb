//! Which cameras of a rig a reference camera sweeps with: its *neighbours*, chosen from the
//! rig's geometry alone, so that one reference and each of several (`references`) take the
//! cameras that see what it sees, with the baselines that give depth.
//!
//! A camera is a candidate when it sees at least [`MIN_OVERLAP`] of the reference's view over
//! the depth range: a grid of reference pixels, each at the nearest, the farthest and the
//! middle (in inverse depth) depth of the sweep, projected into the camera (in front of it and
//! inside its image). A camera that faces away (a surround rig's back cameras) or sees a
//! sliver only is left out; it would cost a sweep and give nothing but noise. So is a camera
//! too close to the reference to give [`MIN_PARALLAX_PX`] across the depth range.
//!
//! When there are more candidates than the reference may take, they are chosen as multi-view
//! stereo chooses source views (MVSNet's view score; COLMAP and ACMM score alike): each
//! candidate scores the sum, over the sampled points it sees, of a weight of the triangulation
//! angle between its ray and the reference's ([`angle_weight`]: rising to 5 degrees, then
//! falling slowly), so a view with a wider baseline (more depth precision) and more overlap
//! scores higher, and a view far off to the side (a changed appearance) lower. The best are
//! taken alternately from the two halves of the best half-sequence split, so that both halves
//! keep views for the occlusion rule, and within a half a view whose baseline points the way of
//! one already taken (as seen in the reference image) counts for less, so that a dome's
//! reference gets a spread of directions. Nearest-first would take the shortest baselines: on
//! a dense trajectory, the least depth.

use glam::{DVec2, DVec3};

use super::{Reference, Rig, RigCamera};

/// The share of the reference's sampled view a camera must see to be a neighbour.
pub const MIN_OVERLAP: f64 = 0.1;

/// The least parallax (pixels of the reference, across the whole depth range) a camera must
/// give to be a neighbour: a camera at the reference's centre (a rig file with no
/// translations, a mirror camera) sees all of its view and cannot tell one depth from another.
pub const MIN_PARALLAX_PX: f64 = 1.0;

/// The most parallax `camera` can give reference `reference` across `[min_depth_m,
/// max_depth_m]`: `fx * baseline * (1 / min - 1 / max)`, pixels (a baseline across the view).
pub fn parallax_px(
    reference: &RigCamera,
    camera: &RigCamera,
    min_depth_m: f64,
    max_depth_m: f64,
) -> f64 {
    let centre = |c: &RigCamera| c.cam_from_rig.inverse().translation;
    let baseline = (centre(camera) - centre(reference)).length();
    let k = reference.model.intrinsics;
    k.fx_px.max(k.fy_px) * baseline * (1.0 / min_depth_m - 1.0 / max_depth_m)
}

/// Samples across and down the reference image.
const GRID: (u32, u32) = (16, 12);

/// The triangulation angle (degrees) a view scores best at, and the spreads below and above it
/// (MVSNet's θ0, σ1, σ2).
const ANGLE_BEST_DEG: f64 = 5.0;
const ANGLE_SPREAD_BELOW_DEG: f64 = 1.0;
const ANGLE_SPREAD_ABOVE_DEG: f64 = 10.0;

/// Within a half, a candidate whose baseline direction (in the reference image) is within
/// this angle of a view already taken counts for less, down to [`SAME_DIRECTION_FACTOR`].
const DIRECTION_SPREAD_DEG: f64 = 30.0;
const SAME_DIRECTION_FACTOR: f64 = 0.2;

/// What one camera sees of the reference's view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewScore {
    /// The share of the sampled view it sees (0 to 1).
    pub overlap: f64,
    /// The sum of [`angle_weight`] over the samples it sees, over all samples (0 to 1).
    pub score: f64,
    /// Its baseline's direction in the reference image (unit, or zero when it lies along the
    /// optical axis).
    pub direction: DVec2,
}

/// The weight of a triangulation angle (degrees): 1 at 5 degrees, a Gaussian of spread 1 below
/// and 10 above. Rises steadily with the angle for the small angles of a dense trajectory.
pub fn angle_weight(angle_deg: f64) -> f64 {
    let spread = if angle_deg <= ANGLE_BEST_DEG {
        ANGLE_SPREAD_BELOW_DEG
    } else {
        ANGLE_SPREAD_ABOVE_DEG
    };
    let d = (angle_deg - ANGLE_BEST_DEG) / spread;
    (-0.5 * d * d).exp()
}

/// What `camera` sees of the reference camera's view over `[min_depth_m, max_depth_m]`.
pub fn score_view(
    reference: &RigCamera,
    camera: &RigCamera,
    min_depth_m: f64,
    max_depth_m: f64,
) -> ViewScore {
    let cam_from_ref = camera
        .cam_from_rig
        .compose(&reference.cam_from_rig.inverse());
    // The camera's centre in the reference frame.
    let centre = cam_from_ref.inverse().transform_point(DVec3::ZERO);
    let k = reference.model.intrinsics;
    let middle = 2.0 / (1.0 / min_depth_m + 1.0 / max_depth_m);
    let depths = [min_depth_m, middle, max_depth_m];
    let (mut seen, mut total, mut score) = (0u32, 0u32, 0.0f64);
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
                let in_ref = ray * depth;
                let point = cam_from_ref.transform_point(in_ref);
                if camera
                    .model
                    .project(point)
                    .is_some_and(|p| camera.model.contains(p))
                {
                    seen += 1;
                    let angle = in_ref.angle_between(in_ref - centre).to_degrees();
                    if angle.is_finite() {
                        score += angle_weight(angle);
                    }
                }
            }
        }
    }
    let total = f64::from(total.max(1));
    ViewScore {
        overlap: f64::from(seen) / total,
        score: score / total,
        direction: DVec2::new(centre.x, centre.y).normalize_or_zero(),
    }
}

/// The share of the reference camera's view (over `[min_depth_m, max_depth_m]`) that
/// `camera` sees: 0 to 1.
pub fn view_overlap(
    reference: &RigCamera,
    camera: &RigCamera,
    min_depth_m: f64,
    max_depth_m: f64,
) -> f64 {
    score_view(reference, camera, min_depth_m, max_depth_m).overlap
}

/// The cameras reference camera `reference` of `cameras` sweeps with, itself included, in rig
/// order: of the cameras that see at least [`MIN_OVERLAP`] of its view, all when they are at
/// most `count` (or `count` is 0), else the `count` best (the module's rule).
pub fn neighbours(
    cameras: &[RigCamera],
    reference: usize,
    min_depth_m: f64,
    max_depth_m: f64,
    count: usize,
) -> Vec<usize> {
    let Some(ref_camera) = cameras.get(reference) else {
        return Vec::new();
    };
    let seeing: Vec<(usize, ViewScore)> = (0..cameras.len())
        .filter(|&i| i != reference)
        .map(|i| {
            let score = score_view(ref_camera, &cameras[i], min_depth_m, max_depth_m);
            (i, score)
        })
        .filter(|(_, s)| s.overlap >= MIN_OVERLAP)
        .filter(|&(i, _)| {
            parallax_px(ref_camera, &cameras[i], min_depth_m, max_depth_m) >= MIN_PARALLAX_PX
        })
        .collect();
    let mut chosen: Vec<usize> = if count == 0 || seeing.len() <= count {
        seeing.iter().map(|(i, _)| *i).collect()
    } else {
        best_by_half(cameras, reference, &seeing, count)
    };
    chosen.push(reference);
    chosen.sort_unstable();
    chosen
}

/// `count` of `candidates`, taken alternately from each half of the half-sequence split (of
/// the reference and the candidates), the half with the best view first; within a half the
/// best score, less for a direction already taken.
fn best_by_half(
    cameras: &[RigCamera],
    reference: usize,
    candidates: &[(usize, ViewScore)],
    count: usize,
) -> Vec<usize> {
    // The split of the reference with its candidates (the rig's own rule); the reference
    // has no score.
    let mut members: Vec<(usize, Option<ViewScore>)> =
        candidates.iter().map(|&(i, s)| (i, Some(s))).collect();
    members.push((reference, None));
    members.sort_unstable_by_key(|(i, _)| *i);
    let sub_cameras: Vec<RigCamera> = members.iter().map(|(i, _)| cameras[*i].clone()).collect();
    let ref_pos = members
        .iter()
        .position(|(i, _)| *i == reference)
        .unwrap_or(0);
    let split = Rig {
        cameras: sub_cameras,
        reference: Reference::Camera(ref_pos),
    }
    .half_sequence_split();
    let mut halves: [Vec<(usize, ViewScore)>; 2] = [Vec::new(), Vec::new()];
    for (side, (index, score)) in split.iter().zip(&members) {
        if let (Some(right), Some(score)) = (side, score) {
            halves[usize::from(*right)].push((*index, *score));
        }
    }
    let best = |half: &[(usize, ViewScore)]| half.iter().map(|(_, s)| s.score).fold(0.0, f64::max);
    let mut side = match (halves[0].is_empty(), halves[1].is_empty()) {
        (true, false) => 1,
        (false, false) if best(&halves[1]) > best(&halves[0]) => 1,
        _ => 0,
    };
    let mut taken: Vec<usize> = Vec::with_capacity(count);
    let mut directions: [Vec<DVec2>; 2] = [Vec::new(), Vec::new()];
    while taken.len() < count && !(halves[0].is_empty() && halves[1].is_empty()) {
        if let Some(pick) = pick_best(&halves[side], &directions[side]) {
            let (index, score) = halves[side].remove(pick);
            taken.push(index);
            directions[side].push(score.direction);
        }
        side = 1 - side;
    }
    taken
}

/// The position in `half` of the best candidate given the directions already taken there
/// (ties: the lower camera index).
fn pick_best(half: &[(usize, ViewScore)], taken: &[DVec2]) -> Option<usize> {
    let spread_cos = DIRECTION_SPREAD_DEG.to_radians().cos();
    let value = |s: &ViewScore| {
        let nearest = taken
            .iter()
            .map(|d| d.dot(s.direction))
            .fold(-1.0f64, f64::max);
        if taken.is_empty() || nearest < spread_cos {
            s.score
        } else {
            // Within DIRECTION_SPREAD_DEG of a taken direction: down to the factor at 0 degrees.
            let angle = nearest.clamp(-1.0, 1.0).acos();
            let t = angle / DIRECTION_SPREAD_DEG.to_radians();
            s.score * (SAME_DIRECTION_FACTOR + (1.0 - SAME_DIRECTION_FACTOR) * t)
        }
    };
    half.iter()
        .enumerate()
        .max_by(|(_, (ia, a)), (_, (ib, b))| value(a).total_cmp(&value(b)).then(ib.cmp(ia)))
        .map(|(pos, _)| pos)
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

    /// A camera at the reference's centre (a rig file with no translations) sees all of its
    /// view but gives no parallax: not a neighbour; one 5 cm away (1.6 px here) still is.
    #[test]
    fn a_camera_at_the_reference_centre_is_no_neighbour() {
        let rig = vec![
            camera("a", 0.0, 0.0),
            camera("b", 0.0, 0.0),
            camera("c", 0.05, 0.0),
        ];
        assert!(view_overlap(&rig[0], &rig[1], 2.0, 10.0) > 0.9);
        assert_eq!(parallax_px(&rig[0], &rig[1], 2.0, 10.0), 0.0);
        assert!(parallax_px(&rig[0], &rig[2], 2.0, 10.0) >= MIN_PARALLAX_PX);
        assert_eq!(neighbours(&rig, 0, 2.0, 10.0, 0), vec![0, 2]);
        assert_eq!(neighbours(&rig[..2], 0, 2.0, 10.0, 0), vec![0]);
    }

    #[test]
    fn at_most_n_by_triangulation_angle_alternately_from_both_halves() {
        let row: Vec<RigCamera> = (0..9)
            .map(|i| camera(&format!("c{i}"), 0.1 * i as f64, 0.0))
            .collect();
        // 2-10 m: a 0.1 m baseline makes 0.6-2.9 degrees, 0.2 m 1.1-5.7, 0.3 m 1.7-8.6,
        // 0.4 m 2.3-11.4: the best score (most samples near 5 degrees) is 0.3-0.4 m away.
        let score = |i: usize| score_view(&row[4], &row[i], 2.0, 10.0).score;
        assert!(
            score(3) < score(2) && score(2) < score(1),
            "wider scores more"
        );
        assert!(
            (score(3) - score(5)).abs() < 1e-9,
            "the same baseline either side"
        );
        let two = neighbours(&row, 4, 2.0, 10.0, 2);
        assert_eq!(two.len(), 3);
        assert!(two[0] < 4 && two[2] > 4, "one view from each half: {two:?}");
        assert!(
            !two.contains(&3) && !two.contains(&5),
            "not the nearest: {two:?}"
        );
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 4).len(), 5);
        // At an end of the row there is one half only: its best, not its nearest.
        let end = neighbours(&row, 0, 2.0, 10.0, 2);
        assert!(!end.contains(&1), "{end:?}");
        // More than there are: all of them.
        assert_eq!(neighbours(&row, 4, 2.0, 10.0, 20).len(), 9);
    }

    #[test]
    fn a_dense_arc_takes_its_widest_views() {
        // A slowly moving camera (21 frames, 5 mm apart, 1-8 m: ICL-NUIM's living room
        // trajectory): every triangulation angle is under 3 degrees, so wider is better, and
        // the 8 views are the 4 widest on each side, not the 8 nearest.
        let arc: Vec<RigCamera> = (0..21)
            .map(|i| camera(&format!("c{i}"), 0.005 * i as f64, 0.0))
            .collect();
        assert_eq!(
            neighbours(&arc, 10, 1.0, 8.0, 8),
            vec![0, 1, 2, 3, 10, 17, 18, 19, 20]
        );
    }

    #[test]
    fn a_dome_reference_takes_a_spread_of_directions() {
        // 32 cameras on a 35-degree cap around a point 4 m ahead of the reference (the pole).
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(160, 120));
        let dome = crate::synthetic::dome_rig(32, 35f64.to_radians(), 4.0, model, 0).expect("dome");
        let chosen = neighbours(&dome.cameras, 0, 3.0, 5.0, 8);
        assert_eq!(chosen.len(), 9, "{chosen:?}");
        let reference = &dome.cameras[0];
        let mut azimuths: Vec<f64> = chosen[1..]
            .iter()
            .map(|&i| {
                let s = score_view(reference, &dome.cameras[i], 3.0, 5.0);
                s.direction.y.atan2(s.direction.x).to_degrees()
            })
            .collect();
        azimuths.sort_by(f64::total_cmp);
        let mut gaps: Vec<f64> = azimuths.windows(2).map(|w| w[1] - w[0]).collect();
        gaps.push(360.0 + azimuths[0] - azimuths[azimuths.len() - 1]);
        let widest = gaps.iter().copied().fold(0.0, f64::max);
        assert!(
            widest < 100.0,
            "directions {azimuths:?}: a gap of {widest} degrees"
        );
        // Triangulation angles near the weight's best (5 degrees, falling slowly above): the
        // views between 5 and 25 degrees, none of the cap's outer ring (30-35).
        for &i in &chosen[1..] {
            let c = dome.cameras[i].centre_in_rig();
            let target = glam::DVec3::new(0.0, 0.0, 4.0);
            let angle = (target - c).angle_between(target).to_degrees();
            assert!(
                (5.0..25.0).contains(&angle),
                "view {i} at {angle:.1} degrees"
            );
        }
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
