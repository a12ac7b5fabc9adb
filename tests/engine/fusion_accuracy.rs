//! Issue 28's accuracy bar for the fused model (`eval::fusion`): on a synthetic moving rig with
//! exact geometry, and on the five ICL-NUIM frames of `../shared/data` posed as one rig with
//! every frame a reference (tests/common/shared_data.rs: skipped loudly without them), the
//! fused model ray-cast into each view has at most 0.7x the depth maps' median absolute depth
//! error and covers at least 90 % of the ground-truth pixels they cover; on the synthetic rig
//! at least 95 % of the mesh's vertices lie within 2 voxels of the true surface. Quality only,
//! never timing; the engine is the CPU one unless a hardware GPU is there (`Device::Auto`).

use crate::common;

use sweepdepth::engine::{Device, Engine};
use sweepdepth::eval::fusion::{
    evaluate, icl_nuim, synthetic_moving_rig, synthetic_sweep_params, FusionResult, ViewWeights,
};
use sweepdepth::fusion::Weighting;

// Issue 28's bars, written here rather than read from `eval::fusion` (whose constants `eval`
// prints as its bar): loosening those does not loosen the tests.
const MAX_ERROR_RATIO: f64 = 0.7;
const MIN_COVERAGE: f64 = 0.9;
const MIN_VERTICES_WITHIN: f64 = 0.95;

/// `eval`'s bar is the issue's.
#[test]
fn evals_fusion_bar_is_the_issues() {
    use sweepdepth::eval::fusion as bar;
    assert_eq!(bar::MAX_ERROR_RATIO, MAX_ERROR_RATIO);
    assert_eq!(bar::MIN_COVERAGE, MIN_COVERAGE);
    assert_eq!(bar::MIN_VERTICES_WITHIN, MIN_VERTICES_WITHIN);
}

fn report(result: &FusionResult) {
    let d = &result.depth;
    eprintln!(
        "{}: {} views, voxel {} m: depth maps' median |e| {:.2} mm, fused {:.2} mm \
         (on the covered pixels the maps' is {:.2} mm), ratio {:.3}, coverage {:.1} % of \
         {} px; vertices within 2 voxels: {}; engine {:.0} ms, fusion {:.0} ms",
        result.name,
        result.views,
        result.voxel_size_m,
        d.depth_maps_median_abs_m * 1e3,
        d.fused_median_abs_m * 1e3,
        d.depth_maps_median_abs_covered_m * 1e3,
        d.ratio(),
        100.0 * d.coverage(),
        d.depth_map_px,
        result.vertices.map_or("-".to_string(), |v| format!(
            "{:.1} % of {} (median {:.2} voxels)",
            100.0 * v.fraction(),
            v.vertices,
            v.median_voxels
        )),
        result.engine_ms,
        result.fusion_ms,
    );
}

fn check(result: &FusionResult) {
    report(result);
    let d = &result.depth;
    assert!(
        d.ratio() <= MAX_ERROR_RATIO,
        "{}: fused median error {:.2} mm is {:.3}x the depth maps' {:.2} mm (bar {MAX_ERROR_RATIO})",
        result.name,
        d.fused_median_abs_m * 1e3,
        d.ratio(),
        d.depth_maps_median_abs_m * 1e3
    );
    assert!(
        d.coverage() >= MIN_COVERAGE,
        "{}: the fused model covers {:.1} % of the pixels the depth maps cover",
        result.name,
        100.0 * d.coverage()
    );
    if let Some(v) = result.vertices {
        assert!(
            v.fraction() >= MIN_VERTICES_WITHIN,
            "{}: {:.1} % of the vertices within 2 voxels of the true surface",
            result.name,
            100.0 * v.fraction()
        );
    }
    assert!(result.meets_the_bar());
}

#[test]
fn fused_synthetic_moving_rig_meets_the_accuracy_bar() {
    let mut engine = Engine::new(Device::Auto).expect("engine");
    let case = synthetic_moving_rig(&mut engine, 320, 240, &synthetic_sweep_params())
        .expect("synthetic moving rig");
    assert_eq!(case.views.len(), 12);
    for weights in [
        ViewWeights::Equal,
        ViewWeights::Baseline,
        ViewWeights::Pixels(Weighting::DEPTH_MAPS),
    ] {
        let result = evaluate(&case, weights, None).expect("fusion");
        check(&result);
        let v = result
            .vertices
            .expect("synthetic scenes know their surface");
        assert!(v.vertices > 10_000, "{v:?}");
    }
}

/// ICL-NUIM at half size: the fused model covers the depth maps' pixels and is more accurate
/// than they are, more so with the views weighed by their baselines, and at least as much with
/// the node's weights (`Weighting::DEPTH_MAPS`: baseline, confidence, discontinuities).
#[test]
fn fused_icl_nuim_is_more_accurate_than_its_depth_maps() {
    let Some(dir) = common::shared_data::dataset(
        "fused_icl_nuim_is_more_accurate_than_its_depth_maps",
        "iclnuim_livingroom_traj2_frames",
    ) else {
        return;
    };
    let mut engine = Engine::new(Device::Auto).expect("engine");
    let case = icl_nuim(&mut engine, &dir, true, |_| {}).expect("ICL-NUIM");
    assert_eq!(case.views.len(), 5);
    let equal = evaluate(&case, ViewWeights::Equal, None).expect("fusion");
    let weighted = evaluate(&case, ViewWeights::Baseline, None).expect("fusion");
    let node = evaluate(&case, ViewWeights::Pixels(Weighting::DEPTH_MAPS), None).expect("fusion");
    for r in [&equal, &weighted, &node] {
        report(r);
        assert!(r.depth.coverage() >= MIN_COVERAGE, "{r:?}");
        assert!(r.depth.ratio() <= 0.8, "{r:?}");
    }
    assert!(weighted.depth.ratio() < equal.depth.ratio());
    // At half size the node's weights and baseline² are close (0.717 and 0.720 measured with
    // the CPU engine; 0.67 and 0.76 at full size): no worse, within a hundredth.
    assert!(
        node.depth.ratio() <= weighted.depth.ratio() + 0.01,
        "{node:?}"
    );
}

/// Issue 28's bar on the five ICL-NUIM frames at full size, with the node's weights
/// (`Weighting::DEPTH_MAPS`; equal weights give 0.83, baseline² weights 0.76).
#[test]
fn fused_icl_nuim_meets_the_full_accuracy_bar() {
    let Some(dir) = common::shared_data::dataset(
        "fused_icl_nuim_meets_the_full_accuracy_bar",
        "iclnuim_livingroom_traj2_frames",
    ) else {
        return;
    };
    let mut engine = Engine::new(Device::Auto).expect("engine");
    let case = icl_nuim(&mut engine, &dir, false, |_| {}).expect("ICL-NUIM");
    check(&evaluate(&case, ViewWeights::Pixels(Weighting::DEPTH_MAPS), None).expect("fusion"));
}
