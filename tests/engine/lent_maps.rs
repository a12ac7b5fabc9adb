//! Issue 56, item 3: a caller that keeps no maps as floats (the node without fusion) gets a
//! reference's depth and confidence lent out of the WGSL engine's mapped readback buffer
//! instead of copied out of it (`sweep::gpu::LentMaps`). lavapipe is a real wgpu adapter.

use sweepdepth::engine::Sweeper;
use sweepdepth::geometry::CameraModel;
use sweepdepth::image::Rgba8Image;
use sweepdepth::sweep::gpu::GpuEngine;
use sweepdepth::sweep::references::{ReferenceDepth, ReferenceMaps};
use sweepdepth::sweep::{SweepError, SweepParams, WantedMaps};
use sweepdepth::synthetic::{self, Scene};

type Results = Vec<Result<ReferenceDepth, SweepError>>;

/// One engine's run of the set with the maps wanted and the parameters.
type Run<'a> = dyn FnMut(WantedMaps, &SweepParams) -> Results + 'a;

/// Each reference's depth and confidence bits, however the engine handed them out.
fn bits(results: &Results) -> Vec<(Vec<u32>, Vec<u32>)> {
    let to_bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    results
        .iter()
        .map(|r| match &r.as_ref().expect("a reference").maps {
            ReferenceMaps::Owned(m) => (to_bits(&m.depth_m.data), to_bits(&m.confidence.data)),
            ReferenceMaps::Lent(l) => (to_bits(l.depth_m()), to_bits(l.confidence())),
        })
        .collect()
}

fn lent(results: &Results) -> usize {
    let is_lent = |r: &Result<ReferenceDepth, SweepError>| {
        matches!(r.as_ref().map(|d| &d.maps), Ok(ReferenceMaps::Lent(_)))
    };
    results.iter().filter(|r| is_lent(r)).count()
}

/// Two references of a four-camera row. Lent maps are the very bits the engine copies out for
/// a caller that keeps its floats, and the copy a caller may still make of them
/// (`into_owned`) is the engine's own maps again; maps held while later sets run stay as they
/// were (those sets take other buffers); once dropped, their buffers go back to the engine and
/// a later set makes none; a caller that asks for the cost (or keeps its floats) gets maps of
/// its own.
#[test]
fn maps_lent_out_of_the_readback_are_the_copied_maps_and_their_buffers_come_back() {
    let model = CameraModel::pinhole(synthetic::intrinsics(96, 64));
    let rig = synthetic::row_rig(4, 0.1, model, 1).expect("rig");
    let fx = model.intrinsics.fx_px;
    let render = |scene: &Scene| synthetic::render_rig(scene, &rig);
    let near: Vec<Rgba8Image> = render(&Scene::wall_and_box(3.0, Some((1.5, 0.3)), fx));
    let far: Vec<Rgba8Image> = render(&Scene::wall_and_box(5.0, Some((2.5, 0.4)), fx));
    let params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: 16,
        ..SweepParams::default()
    };
    let references = [1, 2];
    let gpu = crate::common::gpu();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let depth_only = WantedMaps {
        cost: false,
        selection: false,
        diagnostics: false,
        floats: true,
    };
    let mut run = |images: &[Rgba8Image], wanted: WantedMaps| {
        engine.set_wanted_maps(wanted);
        let results = engine.run_references(&rig.cameras, images, &references, &params);
        (results, engine.take_set_counts())
    };
    let (copied, _) = run(&near, depth_only);
    assert_eq!(lent(&copied), 0, "a caller that keeps its floats owns them");
    let no_floats = WantedMaps {
        floats: false,
        ..depth_only
    };
    let (first, _) = run(&near, no_floats);
    assert_eq!(lent(&first), references.len(), "both references lent");
    assert_eq!(bits(&first), bits(&copied), "the same bits as the copies");
    let held = bits(&first);
    let (second, _) = run(&far, no_floats);
    assert_eq!(lent(&second), references.len());
    assert_ne!(bits(&second), held, "other images, other depths");
    assert_eq!(
        bits(&first),
        held,
        "maps held are not written by later sets"
    );
    // As the caller's own: the engine's own copy, bit for bit.
    let owned: Results = first
        .into_iter()
        .map(|r| {
            r.map(|d| ReferenceDepth {
                maps: ReferenceMaps::Owned(d.maps.into_owned()),
                ..d
            })
        })
        .collect();
    assert_eq!(bits(&owned), held);
    drop(second);
    // Every buffer lent is back: the next sets make none.
    for images in [&near, &far, &near] {
        let (again, counts) = run(images, no_floats);
        assert_eq!(lent(&again), references.len());
        assert_eq!(counts.readback_buffers, 0, "{counts:?}");
    }
    let (third, _) = run(&near, no_floats);
    assert_eq!(
        bits(&third),
        held,
        "a buffer given back holds the new set's maps"
    );
    let (with_cost, _) = run(
        &near,
        WantedMaps {
            cost: true,
            ..no_floats
        },
    );
    assert_eq!(
        lent(&with_cost),
        0,
        "the cost is read as the engine's own maps"
    );
    assert_eq!(bits(&with_cost), held);
}

/// Maps lent from a device that is then lost (destroyed) are still read and dropped without a
/// panic (their buffer unmapped on a lost device), and outlive their engine.
#[test]
fn lent_maps_outlive_a_lost_device_and_their_engine() {
    let model = CameraModel::pinhole(synthetic::intrinsics(64, 48));
    let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(3.0, Some((1.5, 0.3)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: 8,
        ..SweepParams::default()
    };
    let gpu = sweepdepth::gpu_context::GpuContext::new().expect("an adapter (lavapipe is fine)");
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    engine.set_wanted_maps(WantedMaps {
        cost: false,
        selection: false,
        diagnostics: false,
        floats: false,
    });
    let results = engine.run_references(&rig.cameras, &images, &[0, 1], &params);
    assert_eq!(lent(&results), 2);
    let before = bits(&results);
    gpu.device.destroy();
    assert_eq!(bits(&results), before, "still readable");
    drop(engine);
    drop(results);
}

/// The joint median reaches every caller on both engines: with `joint_median_radius` the
/// depth of a reference is the filter (`JointMedian::apply`, guided by the reference's image)
/// run on the engine's unfiltered depth, bit for bit, for the WGSL engine also where the
/// caller keeps no floats (its maps then come back owned, not lent out of the readback
/// unfiltered; two references, so that the WGSL engine submits them ahead, the path that
/// lends); the filter changes the box's fattened edges, so it is not a no-op here.
#[test]
fn the_joint_median_reaches_every_caller_on_both_engines() {
    use sweepdepth::sweep::cpu::CpuEngine;
    use sweepdepth::sweep::joint_median::{Bins, JointMedian};
    let model = CameraModel::pinhole(synthetic::intrinsics(96, 64));
    let rig = synthetic::row_rig(4, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(3.0, Some((1.5, 0.3)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let plain = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: 24,
        ..SweepParams::default()
    };
    let filtered = SweepParams {
        joint_median_radius: 4,
        ..plain.clone()
    };
    let references = [1, 2];
    let expected = |reference: usize, depth: &[u32]| {
        let depth: Vec<f32> = depth.iter().map(|&b| f32::from_bits(b)).collect();
        let mut depth = sweepdepth::image::ImageF32 {
            width: 96,
            height: 64,
            data: depth,
        };
        let bins = Bins::of_params(&filtered).expect("bins");
        JointMedian::of_params(&filtered).apply(&mut depth, &images[reference], &bins);
        depth.data.iter().map(|x| x.to_bits()).collect::<Vec<u32>>()
    };
    let gpu = crate::common::gpu();
    let mut gpu_engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let mut cpu_engine = CpuEngine::new();
    let runs: [(&str, &mut Run<'_>); 2] = [
        ("wgsl", &mut |wanted, params| {
            gpu_engine.set_wanted_maps(wanted);
            gpu_engine.run_references(&rig.cameras, &images, &references, params)
        }),
        ("cpu", &mut |_, params| {
            cpu_engine.run_references(&rig.cameras, &images, &references, params)
        }),
    ];
    let keeps_floats = WantedMaps {
        cost: false,
        selection: false,
        diagnostics: false,
        floats: true,
    };
    let no_floats = WantedMaps {
        floats: false,
        ..keeps_floats
    };
    for (name, run) in runs {
        let unfiltered = bits(&run(keeps_floats, &plain));
        let want: Vec<Vec<u32>> = references
            .iter()
            .zip(&unfiltered)
            .map(|(&r, (depth, _))| expected(r, depth))
            .collect();
        for (want, (depth, _)) in want.iter().zip(&unfiltered) {
            let changed = want.iter().zip(depth).filter(|(a, b)| a != b).count();
            assert!(changed >= 20, "{name}: the filter moves {changed} pixels");
        }
        for wanted in [keeps_floats, no_floats] {
            let results = run(wanted, &filtered);
            assert_eq!(
                lent(&results),
                0,
                "{name}: filtered maps are the caller's own"
            );
            let got: Vec<Vec<u32>> = bits(&results).into_iter().map(|(d, _)| d).collect();
            assert!(
                got == want,
                "{name} (floats kept: {}): not the joint median of the unfiltered depth",
                wanted.floats
            );
        }
    }
}
