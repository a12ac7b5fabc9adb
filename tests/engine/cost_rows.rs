//! Issue 56: the WGSL engine sums the matching costs along rows in the stage that makes them
//! (`cost_rows.wgsl`, `CostRows::Fused`, the default on a GPU: no cost slab, one dispatch fewer
//! per batch). It must give the very floats of the cost slab and its row-sum pass
//! (`CostRows::Apart`, the default on CPU adapters, which `gpu_vs_cpu` holds to the CPU
//! engine) in every shape the fused stage meets: groups of 64 columns with windows reaching
//! 0 to 32 columns into the group before, batches of one plane, rows narrowed to a range of
//! planes, coarse-to-fine levels, the fine sweep's hypotheses, lens distortion.

use super::gpu_vs_cpu::{coarse_to_fine_case, distorted_arc_case, tsukuba_crop};
use crate::common;

use sweepdepth::geometry::Rig;
use sweepdepth::image::Rgba8Image;
use sweepdepth::sweep::gpu::{CostRows, GpuEngine, SetCounts};
use sweepdepth::sweep::plan::{range_tiles, SweepPlan};
use sweepdepth::sweep::{Aggregation, SweepParams, WindowMode};

fn bits(maps: &[f32]) -> Vec<u32> {
    maps.iter().map(|v| v.to_bits()).collect()
}

/// One plan run both ways (with a slab budget, `None`: the engine's): the raw maps' bits and
/// the counts of each.
fn both_ways(
    plan: &SweepPlan,
    rig: &Rig,
    images: &[Rgba8Image],
    budget: Option<u64>,
) -> [(Vec<u32>, SetCounts, u32); 2] {
    let gpu = common::gpu();
    [CostRows::Fused, CostRows::Apart].map(|rows| {
        let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
        engine.set_cost_rows(rows);
        engine.set_slab_bytes(budget);
        let maps = engine.run_plan_raw(plan, rig, images).expect("run");
        (bits(&maps), engine.take_set_counts(), engine.batches())
    })
}

/// A named plan, its rig and images, and a slab budget (`None`: the engine's).
type Case<'a> = (
    &'static str,
    SweepPlan,
    &'a Rig,
    &'a [Rgba8Image],
    Option<u64>,
);

fn differing(a: &[u32], b: &[u32]) -> usize {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).filter(|(x, y)| x != y).count()
}

/// The two ways' values are the same bits on a CPU adapter (lavapipe: the host's arithmetic,
/// the same operations in both shaders). A hardware GPU's compiler may contract the two
/// shaders' multiply-adds differently: there a few values may differ (SGM spreads a changed
/// score along its paths), at most 5 %; a wrong window or a lost column changes most.
fn assert_same(what: &str, a: &[u32], b: &[u32]) {
    let n = differing(a, b);
    let exact = common::gpu().adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let allowed = if exact { 0 } else { a.len() / 20 };
    assert!(n <= allowed, "{what}: {n} of {} values differ", a.len());
}

#[test]
fn fused_row_sums_give_the_cost_slabs_floats_in_fewer_dispatches() {
    let (crop_rig, crop_images, crop) = tsukuba_crop();
    let (arc_rig, arc_images) = distorted_arc_case();
    let with = |p: SweepParams| SweepPlan::new(&crop_rig, &p).expect("plan");
    let defaults = with(crop.clone());
    // Rows narrowed to ranges of planes (as coarse to fine makes them), some tiles whole.
    let planes = defaults.num_planes();
    let tiles = range_tiles(defaults.width);
    let ranges = (0..defaults.height * tiles)
        .map(|i| {
            if (i / tiles) % 20 < 10 || (i % tiles).is_multiple_of(3) {
                [0, planes - 1]
            } else {
                [planes / 4, planes / 2]
            }
        })
        .collect();
    let cases: Vec<Case> = vec![
        ("defaults", defaults.clone(), &crop_rig, &crop_images, None),
        (
            "one_plane_per_batch",
            defaults.clone(),
            &crop_rig,
            &crop_images,
            Some(1),
        ),
        (
            "narrowed",
            defaults.narrow_planes(ranges).expect("narrowed"),
            &crop_rig,
            &crop_images,
            None,
        ),
        (
            "window_33x3",
            with(SweepParams {
                window_width: 33,
                window_height: 3,
                ..crop.clone()
            }),
            &crop_rig,
            &crop_images,
            None,
        ),
        (
            "window_1x1",
            with(SweepParams {
                window_width: 1,
                window_height: 1,
                ..crop.clone()
            }),
            &crop_rig,
            &crop_images,
            None,
        ),
        (
            "shiftable_4x4",
            with(SweepParams {
                window_width: 4,
                window_height: 4,
                window_mode: WindowMode::Shiftable,
                ..crop.clone()
            }),
            &crop_rig,
            &crop_images,
            None,
        ),
        (
            "fine_sweep",
            with(SweepParams {
                subpixel_refine: true,
                ..crop.clone()
            }),
            &crop_rig,
            &crop_images,
            None,
        ),
        (
            "distorted_arc",
            SweepPlan::new(&arc_rig, &SweepParams::default()).expect("plan"),
            &arc_rig,
            &arc_images,
            None,
        ),
    ];
    for (name, plan, rig, images, budget) in cases {
        assert!(plan.cost_rows(), "{name}: the fused stage applies");
        let [(fused, f, f_batches), (apart, a, a_batches)] = both_ways(&plan, rig, images, budget);
        assert_same(name, &fused, &apart);
        // Each batch runs one dispatch fewer (and the fused batches hold more planes).
        assert!(f_batches <= a_batches, "{name}: {f_batches} > {a_batches}");
        assert!(
            f.sweep_dispatches + a_batches <= a.sweep_dispatches,
            "{name}: fused {} dispatches, apart {} in {a_batches} batches",
            f.sweep_dispatches,
            a.sweep_dispatches
        );
    }
    // Where the plan does not allow it (the scored cost's channels are not camera pairs) both
    // ways run the cost slab and the row sums.
    let scored = with(SweepParams {
        aggregation: Aggregation::Scored,
        ..crop.clone()
    });
    assert!(!scored.cost_rows());
    let [(fused, f, _), (apart, a, _)] = both_ways(&scored, &crop_rig, &crop_images, None);
    assert_same("scored", &fused, &apart);
    assert_eq!(f.sweep_dispatches, a.sweep_dispatches);
}

/// A coarse-to-fine set (320x240, 96 planes: two levels, five groups of columns per row) run
/// both ways gives the same maps, the level below included (its depths narrow the rows of the
/// level above).
#[test]
fn fused_row_sums_give_the_same_coarse_to_fine_set() {
    let (rig, images, params) = coarse_to_fine_case(320, 240);
    assert_eq!(sweepdepth::sweep::coarse::levels(&rig, &params), 2);
    let gpu = common::gpu();
    let [(fused, f), (apart, a)] = [CostRows::Fused, CostRows::Apart].map(|rows| {
        let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
        engine.set_cost_rows(rows);
        let maps = engine.run(&rig, &images, &params).expect("run");
        (maps, engine.take_set_counts())
    });
    assert!(fused.invalid_fraction() < 0.5);
    for (what, f, a) in [
        ("depth", &fused.depth_m.data, &apart.depth_m.data),
        ("confidence", &fused.confidence.data, &apart.confidence.data),
        ("cost", &fused.cost.data, &apart.cost.data),
    ] {
        assert_same(what, &bits(f), &bits(a));
    }
    let as_words = |v: &[u8]| v.iter().map(|&b| u32::from(b)).collect::<Vec<u32>>();
    assert_same(
        "selection",
        &as_words(&fused.selection),
        &as_words(&apart.selection),
    );
    assert!(
        f.sweep_dispatches < a.sweep_dispatches,
        "{} >= {}",
        f.sweep_dispatches,
        a.sweep_dispatches
    );
}
