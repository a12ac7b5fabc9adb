//! Several references per frame set (`references`): each reference camera sweeps with its
//! own neighbours ([`crate::geometry::neighbours`]) and its own best half-sequence split, on
//! a rig of those cameras with itself as the reference ([`reference_rig`]). The set's work on
//! its images (conversion before the engine, census words and half-size images in it:
//! `frame_memo.rs`) is done once for all of them ([`crate::engine::Sweeper::run_references`]);
//! each reference keeps its own plans (`coarse::PlanSets`). One reference is the same sweep:
//! the depth of a reference is the same whether it runs alone or beside others.

use crate::geometry::{neighbours::neighbours, Reference, Rig, RigCamera};

use super::gpu::LentMaps;
use super::{DepthMaps, SweepError, SweepParams};

/// The rig one reference sweeps: its neighbours and itself.
#[derive(Debug, Clone)]
pub struct ReferenceRig {
    /// The reference, as an index into the set's cameras.
    pub reference: usize,
    /// The set's cameras in this rig, in set order (the reference among them).
    pub cameras: Vec<usize>,
    /// The rig itself (cameras in the order of `cameras`).
    pub rig: Rig,
}

/// The rig of reference `reference` of the set's `cameras`: the cameras that see its view
/// (at most [`SweepParams::neighbour_count`] of them, the best for depth), with it as the
/// reference.
pub fn reference_rig(
    cameras: &[RigCamera],
    reference: usize,
    params: &SweepParams,
) -> Result<ReferenceRig, SweepError> {
    if reference >= cameras.len() {
        return Err(SweepError::NoSuchReference {
            index: reference,
            cameras: cameras.len(),
        });
    }
    // A range that is none would read as "no camera sees it" below.
    params.check_depth_range()?;
    let chosen = neighbours(
        cameras,
        reference,
        params.min_depth_m,
        params.max_depth_m,
        params.neighbour_count(),
    );
    if chosen.len() < 2 {
        return Err(SweepError::NoNeighbours {
            reference: cameras[reference].name.clone(),
            min_depth_m: params.min_depth_m,
            max_depth_m: params.max_depth_m,
        });
    }
    say_views(cameras, reference, &chosen, params);
    let position = chosen.iter().position(|&i| i == reference).unwrap_or(0);
    let rig = Rig::new(
        chosen.iter().map(|&i| cameras[i].clone()).collect(),
        Reference::Camera(position),
    )?;
    say_plane_step(&rig, params);
    Ok(ReferenceRig {
        reference,
        cameras: chosen,
        rig,
    })
}

/// Above this shift between neighbouring planes in the widest view, a texture's match falls
/// between planes: the ETH3D terrace pair (15 px of disparity over its range) had 8.1 % bad>1
/// with planes 1 px apart, 10.1 % 2 px apart, 32.9 % 3.8 px apart, 60.0 % 5 px apart
/// (`eval --device cpu --planes`, 2026-12-01).
pub const MAX_PLANE_STEP_PX: f64 = 2.0;

/// The warning for a reference whose planes lie more than [`MAX_PLANE_STEP_PX`] apart in its
/// widest view, with the `num_planes` that would put them a pixel apart.
pub fn plane_step_warning(rig: &Rig, params: &SweepParams) -> Option<String> {
    let planes = params.num_planes as usize;
    let (view, step) =
        rig.widest_shift_per_plane(params.min_depth_m, params.max_depth_m, planes)?;
    if step <= MAX_PLANE_STEP_PX {
        return None;
    }
    let span = step * planes.saturating_sub(1) as f64;
    let one_px = ((span.ceil() as usize) + 1).min(4096);
    let reference = rig
        .reference_index()
        .map_or("the reference", |i| rig.cameras[i].name.as_str());
    Some(format!(
        "reference {reference}: its planes lie {step:.1} px apart in {} (num_planes {planes} \
         over {}..{} m), so texture matches between planes and much of its depth comes out \
         wrong; num_planes {one_px} puts them 1 px apart (or narrow min_depth / \
         max_depth to the scene)",
        rig.cameras[view].name,
        crate::geometry::metres(params.min_depth_m),
        crate::geometry::metres(params.max_depth_m),
    ))
}

/// Logs [`plane_step_warning`] when it first comes for a reference and whenever it changes.
fn say_plane_step(rig: &Rig, params: &SweepParams) {
    /// What a warning said: the planes, the range, the widest view and its step (0.1 px).
    type Said = (u32, u64, u64, usize, i64);
    static SAID: parking_lot::Mutex<Vec<(String, Said)>> = parking_lot::const_mutex(Vec::new());
    let planes = params.num_planes as usize;
    let Some((view, step)) =
        rig.widest_shift_per_plane(params.min_depth_m, params.max_depth_m, planes)
    else {
        return;
    };
    let Some(reference) = rig.reference_index().map(|i| &rig.cameras[i].name) else {
        return;
    };
    if step <= MAX_PLANE_STEP_PX {
        return;
    }
    // Compared without allocating: a rig over the limit is checked every set.
    let key: Said = (
        params.num_planes,
        params.min_depth_m.to_bits(),
        params.max_depth_m.to_bits(),
        view,
        (step * 10.0).round() as i64,
    );
    {
        let mut said = SAID.lock();
        match said.iter().position(|(r, _)| r == reference) {
            Some(at) if said[at].1 == key => return,
            Some(at) => said[at].1 = key,
            // A bounded memory, as `say_views`'.
            None if said.len() < 4096 => said.push((reference.clone(), key)),
            None => return,
        }
    }
    if let Some(warning) = plane_step_warning(rig, params) {
        tracing::warn!("{warning}");
    }
}

/// Logs which cameras a reference sweeps with, and why the others are left out, when that
/// first comes and whenever it changes (per reference camera name, for the process).
fn say_views(cameras: &[RigCamera], reference: usize, chosen: &[usize], params: &SweepParams) {
    use crate::geometry::neighbours::{parallax_px, view_overlap, MIN_OVERLAP, MIN_PARALLAX_PX};
    static SAID: parking_lot::Mutex<Vec<(String, Vec<String>)>> =
        parking_lot::const_mutex(Vec::new());
    let name = |i: usize| cameras[i].name.clone();
    // Per set: compared in place (no allocation unless the views are new).
    let same = |said: &[String]| said.iter().eq(chosen.iter().map(|&i| &cameras[i].name));
    let views = || chosen.iter().map(|&i| name(i)).collect::<Vec<String>>();
    {
        let mut said = SAID.lock();
        let known = said.iter().position(|(r, _)| *r == cameras[reference].name);
        match known {
            Some(at) if same(&said[at].1) => return,
            Some(at) => said[at].1 = views(),
            // A bounded memory: the rigs of one process name a few hundred references at most.
            None if said.len() < 4096 => said.push((name(reference), views())),
            None => return,
        }
    }
    let (views, reference_name) = (views(), name(reference));
    let (near, far) = (params.min_depth_m, params.max_depth_m);
    // The cameras left out, by reason.
    let mut left: Vec<(String, Vec<String>)> = Vec::new();
    for i in (0..cameras.len()).filter(|i| !chosen.contains(i)) {
        let why = if view_overlap(&cameras[reference], &cameras[i], near, far) < MIN_OVERLAP {
            "seeing under 10 % of its view".to_string()
        } else if parallax_px(&cameras[reference], &cameras[i], near, far) < MIN_PARALLAX_PX {
            "too near it for a pixel of parallax".to_string()
        } else {
            format!("beyond its {} best views", params.neighbour_count())
        };
        match left.iter_mut().find(|(w, _)| *w == why) {
            Some((_, names)) => names.push(name(i)),
            None => left.push((why, vec![name(i)])),
        }
    }
    let others: Vec<&str> = views
        .iter()
        .filter(|v| **v != reference_name)
        .map(String::as_str)
        .collect();
    let left: Vec<String> = left
        .iter()
        .map(|(why, names)| format!("{} ({why})", names.join(", ")))
        .collect();
    tracing::info!(
        "reference {reference_name} sweeps with {}{}",
        others.join(", "),
        if left.is_empty() {
            String::new()
        } else {
            format!("; left out: {}", left.join("; "))
        }
    );
}

/// One reference's depth of a frame set.
#[derive(Debug)]
pub struct ReferenceDepth {
    /// The reference, as an index into the set's cameras.
    pub reference: usize,
    /// The set's cameras it swept with (itself included), in set order.
    pub cameras: Vec<usize>,
    pub maps: ReferenceMaps,
}

/// A reference's maps: the engine's own, or its depth and confidence lent out of the WGSL
/// engine's readback buffer (only to a caller that said it keeps no floats:
/// [`crate::sweep::WantedMaps::floats`]).
#[derive(Debug)]
pub enum ReferenceMaps {
    Owned(DepthMaps),
    Lent(LentMaps),
}

impl ReferenceMaps {
    /// The engine's own maps (None where they are lent).
    pub fn owned(&self) -> Option<&DepthMaps> {
        match self {
            Self::Owned(maps) => Some(maps),
            Self::Lent(_) => None,
        }
    }

    /// The maps as the caller's own (lent ones copied out).
    pub fn into_owned(self) -> DepthMaps {
        match self {
            Self::Owned(maps) => maps,
            Self::Lent(lent) => lent.to_maps(),
        }
    }
}

impl From<DepthMaps> for ReferenceMaps {
    fn from(maps: DepthMaps) -> Self {
        Self::Owned(maps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;

    /// A pair 30 cm apart, f = 139 px, 1-6 m: 34.8 px of disparity over the range, 0.55 px per
    /// plane over 64 planes (said nothing), 5 px over 8 (said, with 36 planes for 1 px).
    #[test]
    fn planes_many_pixels_apart_are_said_with_the_count_that_closes_them() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(160, 120));
        let cameras = crate::synthetic::row_rig(2, 0.3, model, 0)
            .expect("rig")
            .cameras;
        let params = |planes| SweepParams {
            min_depth_m: 1.0,
            max_depth_m: 6.0,
            num_planes: planes,
            ..SweepParams::default()
        };
        let rig = reference_rig(&cameras, 0, &params(64)).expect("rig").rig;
        let (view, step) = rig.widest_shift_per_plane(1.0, 6.0, 64).expect("a view");
        assert_eq!(rig.cameras[view].name, cameras[1].name);
        assert!((step - 34.8 / 63.0).abs() < 0.05, "{step}");
        assert_eq!(plane_step_warning(&rig, &params(64)), None);
        assert_eq!(plane_step_warning(&rig, &params(19)), None);
        let said = plane_step_warning(&rig, &params(8)).expect("said");
        assert!(said.contains("5.0 px apart"), "{said}");
        assert!(said.contains(&format!("in {}", cameras[1].name)), "{said}");
        assert!(
            said.contains("num_planes 36 puts them 1 px apart"),
            "{said}"
        );
        // Both engines' uniqueness radius reads the same shift.
        let plan = crate::sweep::plan::SweepPlan::new(&rig, &params(8)).expect("plan");
        assert_eq!(plan.params.uniqueness_radius, 1);
    }

    #[test]
    fn a_reference_rig_holds_its_neighbours_with_itself_as_reference() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(64, 48));
        let rig = crate::synthetic::row_rig(5, 0.1, model, 2).expect("rig");
        let params = SweepParams {
            min_depth_m: 1.0,
            max_depth_m: 8.0,
            max_neighbours: 2,
            ..SweepParams::default()
        };
        // 1-8 m, 0.1 m apart: 0.2 m (up to 11 degrees) scores best, then 0.3 m, 0.1 m, 0.4 m.
        let r = reference_rig(&rig.cameras, 0, &params).expect("reference 0");
        assert_eq!(r.cameras, vec![0, 2, 3]);
        assert_eq!(r.rig.reference, Reference::Camera(0));
        let r = reference_rig(&rig.cameras, 3, &params).expect("reference 3");
        assert_eq!(r.cameras, vec![1, 3, 4]);
        assert_eq!(r.rig.reference, Reference::Camera(1));
        assert_eq!(r.rig.cameras[1].name, rig.cameras[3].name);
        assert!(matches!(
            reference_rig(&rig.cameras, 5, &params),
            Err(SweepError::NoSuchReference { index: 5, .. })
        ));
    }
}
