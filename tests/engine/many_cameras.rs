//! Issue 53: every camera helps, whatever their number. A dense trajectory (21 frames, a
//! slowly moving camera) runs with the defaults and its depth is at least as good as every
//! fifth frame's, because each reference takes the views with the widest triangulation angles
//! (`geometry::neighbours`), not the nearest; a 32-camera dome runs with the defaults, and a
//! 160-camera one (more cameras than one sweep holds) on both engines; asking for more views
//! than the engine holds is a clear error.

use sweepdepth::engine::{Engine, Sweeper};
use sweepdepth::geometry::{CameraModel, Reference, Rig};
use sweepdepth::image::{ImageF32, Rgba8Image};
use sweepdepth::sweep::cpu::CpuEngine;
use sweepdepth::sweep::{SweepError, SweepParams};
use sweepdepth::synthetic::{self, Scene};

/// Mean |depth - truth| / truth over the pixels with both, and the share of all pixels with
/// truth that are valid and within 1 %.
fn errors(depth: &ImageF32, truth: &ImageF32) -> (f64, f64) {
    let (mut sum, mut valid, mut within, mut total) = (0.0f64, 0usize, 0usize, 0usize);
    for (&d, &t) in depth.data.iter().zip(&truth.data) {
        if !t.is_finite() {
            continue;
        }
        total += 1;
        if d.is_finite() {
            let rel = f64::from(((d - t) / t).abs());
            sum += rel;
            valid += 1;
            if rel <= 0.01 {
                within += 1;
            }
        }
    }
    assert!(valid * 2 > total, "{valid} of {total} pixels valid");
    (sum / valid as f64, within as f64 / total as f64)
}

/// The defaults over 1-8 m with 64 planes.
fn params() -> SweepParams {
    SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: 64,
        ..SweepParams::default()
    }
}

/// A 32-camera capture dome of 160x120 views 4 m from a wall with a box, its scene and images.
fn dome() -> (Rig, Scene, Vec<Rgba8Image>) {
    let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
    let rig = synthetic::dome_rig(32, 35f64.to_radians(), 4.0, model, 0).expect("dome");
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    (rig, scene, images)
}

/// The frames `keep` of `rig` (the reference among them), with their images.
fn subset(rig: &Rig, images: &[Rgba8Image], keep: &[usize]) -> (Rig, Vec<Rgba8Image>) {
    let reference = rig.reference_index().expect("a camera reference");
    let position = keep.iter().position(|&i| i == reference).expect("kept");
    let cameras = keep.iter().map(|&i| rig.cameras[i].clone()).collect();
    let rig = Rig::new(cameras, Reference::Camera(position)).expect("rig");
    (rig, keep.iter().map(|&i| images[i].clone()).collect())
}

/// 21 frames 1 cm apart along a row (a camera moving slowly past a wall at 4 m with a box at
/// 2 m: ICL-NUIM's living room trajectory has 0.2-5 cm between frames), the middle one the
/// reference. With the defaults (more cameras than the 8 views a reference takes) the depth
/// is at least as good as every fifth frame's (the same widest baselines), and better than the
/// 8 nearest frames' (what nearest-first chose): more frames do not make it worse.
#[test]
fn a_dense_trajectory_with_every_frame_is_no_worse_than_every_fifth() {
    let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
    let rig = synthetic::row_rig(21, 0.01, model, 10).expect("rig");
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let truth = synthetic::reference_depth(&scene, &rig);
    let p = params();
    let mut engine = Engine::Cpu(CpuEngine::new());
    // Every frame, the defaults: no limit on the number of cameras.
    let all = engine
        .run_views(&rig, &images, &p)
        .expect("21 frames, defaults");
    let (all_rel, all_within) = errors(&all.depth_m, &truth);
    let (rig5, images5) = subset(&rig, &images, &[0, 5, 10, 15, 20]);
    let fifth = engine.run_views(&rig5, &images5, &p).expect("every fifth");
    let (fifth_rel, fifth_within) = errors(&fifth.depth_m, &truth);
    let (rig8, images8) = subset(&rig, &images, &[6, 7, 8, 9, 10, 11, 12, 13, 14]);
    let near = engine.run_views(&rig8, &images8, &p).expect("8 nearest");
    let (near_rel, near_within) = errors(&near.depth_m, &truth);
    let report = format!(
        "mean relative error / within 1 %: all 21 {all_rel:.4} / {:.1} %, every fifth \
         {fifth_rel:.4} / {:.1} %, 8 nearest {near_rel:.4} / {:.1} %",
        all_within * 100.0,
        fifth_within * 100.0,
        near_within * 100.0
    );
    eprintln!("{report}");
    assert!(all_rel <= fifth_rel * 1.02, "{report}");
    assert!(all_within >= fifth_within * 0.98, "{report}");
    assert!(
        near_rel > all_rel * 1.2,
        "the 8 nearest are worse: {report}"
    );
}

/// A capture dome: 32 cameras on a 35-degree cap around the scene, the reference at the pole.
/// With the defaults it runs (8 views chosen of 31) and finds the wall and box.
#[test]
fn a_32_camera_dome_runs_with_the_defaults() {
    let (rig, scene, images) = dome();
    let truth = synthetic::reference_depth(&scene, &rig);
    let p = params();
    let mut engine = Engine::Cpu(CpuEngine::new());
    let chosen = engine
        .run_references(&rig.cameras, &images, &[0], &p)
        .pop()
        .expect("one result")
        .expect("the dome with the defaults");
    assert_eq!(chosen.cameras.len(), 9, "8 views and the reference");
    let (rel, within) = errors(&chosen.maps.owned().expect("owned maps").depth_m, &truth);
    assert!(
        rel < 0.01 && within > 0.7,
        "dome: mean relative error {rel:.4}, {:.1} % within 1 %",
        within * 100.0
    );
    // More views than per-pair aggregation holds (16 pairs): refused with the limit named,
    // not a panic and not a silent cut.
    let too_many = SweepParams {
        max_neighbours: 20,
        ..p.clone()
    };
    match engine.run_views(&rig, &images, &too_many) {
        Err(SweepError::InvalidParams(m)) => {
            assert!(
                m.contains("max_neighbours 20") && m.contains("at most 16"),
                "{m}"
            );
        }
        other => panic!("max_neighbours 20 is refused: {:?}", other.map(|_| ())),
    }
}

/// A 160-camera dome: more cameras than one sweep holds (`MAX_RIG_CAMERAS`, 128), as a large
/// capture stage has. Each reference sweeps with its own 8 views, so any number of cameras runs
/// with the defaults: on the CPU engine three references, on the WGSL engine every camera a
/// reference, whose views together are more cameras than one upload holds (each reference
/// then uploads its own). Every reference finds the wall and box (64x48 views: over the 160
/// references a mean relative error of 0.7-3.1 %, 51-99 % of pixels within 1 %).
#[test]
fn a_160_camera_dome_runs_with_the_defaults_on_both_engines() {
    use sweepdepth::gpu_context::GpuContext;
    use sweepdepth::sweep::gpu_types::MAX_RIG_CAMERAS;
    use sweepdepth::sweep::references::{reference_rig, ReferenceDepth};
    const CAMERAS: usize = 160;
    assert!(CAMERAS > MAX_RIG_CAMERAS as usize);
    let model = CameraModel::pinhole(synthetic::intrinsics(64, 48));
    let rig = synthetic::dome_rig(CAMERAS, 35f64.to_radians(), 4.0, model, 0).expect("dome");
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let p = params();
    let check = |engine: &str, references: &[usize], results: Vec<Result<ReferenceDepth, _>>| {
        assert_eq!(results.len(), references.len(), "{engine}");
        for (&r, result) in references.iter().zip(results) {
            let result: ReferenceDepth =
                result.unwrap_or_else(|e: SweepError| panic!("{engine}: reference cam{r}: {e}"));
            assert_eq!(result.reference, r);
            assert_eq!(
                result.cameras.len(),
                9,
                "{engine}: cam{r}'s 8 views and itself"
            );
            let as_reference = Rig::new(rig.cameras.clone(), Reference::Camera(r)).expect("rig");
            let truth = synthetic::reference_depth(&scene, &as_reference);
            let (rel, within) = errors(&result.maps.owned().expect("owned").depth_m, &truth);
            assert!(
                rel < 0.05 && within > 0.4,
                "{engine}: cam{r}: mean relative error {rel:.4}, {:.1} % within 1 %",
                within * 100.0
            );
        }
    };
    let references = [0, 80, CAMERAS - 1];
    let mut cpu = Engine::Cpu(CpuEngine::new());
    check(
        "CPU",
        &references,
        cpu.run_references(&rig.cameras, &images, &references, &p),
    );
    // Every camera a reference, as a capture stage has it: their views are more cameras than
    // one upload holds.
    let references: Vec<usize> = (0..CAMERAS).collect();
    let mut used: Vec<usize> = references
        .iter()
        .flat_map(|&r| reference_rig(&rig.cameras, r, &p).expect("its rig").cameras)
        .collect();
    used.sort_unstable();
    used.dedup();
    assert!(
        used.len() > MAX_RIG_CAMERAS as usize,
        "{} cameras in the references' views",
        used.len()
    );
    let shared = crate::common::gpu();
    let mut gpu = Engine::on_gpu(GpuContext {
        adapter: shared.adapter.clone(),
        device: shared.device.clone(),
        queue: shared.queue.clone(),
    })
    .expect("WGSL engine");
    check(
        "WGSL",
        &references,
        gpu.run_references(&rig.cameras, &images, &references, &p),
    );
}

/// The WGSL engine sweeps a reference's views where they lie in the set's images
/// (`SetImages::Picked`, no copy): on the 32-camera dome (9 of 32 picked, not the first 9) its
/// maps equal, to the bit, a run on the picked images copied into a rig of their own.
#[test]
fn picked_views_sweep_as_their_copies_on_the_wgsl_engine() {
    use sweepdepth::gpu_context::GpuContext;
    use sweepdepth::sweep::references::reference_rig;
    let (rig, scene, images) = dome();
    let p = params();
    let shared = crate::common::gpu();
    let gpu = || {
        Engine::on_gpu(GpuContext {
            adapter: shared.adapter.clone(),
            device: shared.device.clone(),
            queue: shared.queue.clone(),
        })
        .expect("WGSL engine")
    };
    let picked = gpu()
        .run_references(&rig.cameras, &images, &[0], &p)
        .pop()
        .expect("one result")
        .expect("the dome on the WGSL engine");
    let chosen = reference_rig(&rig.cameras, 0, &p).expect("its rig");
    assert_eq!(picked.cameras, chosen.cameras);
    assert_eq!(chosen.cameras.len(), 9);
    assert_ne!(
        chosen.cameras,
        (0..9).collect::<Vec<_>>(),
        "not the first nine"
    );
    let copies: Vec<Rgba8Image> = chosen.cameras.iter().map(|&i| images[i].clone()).collect();
    let copied = gpu().run(&chosen.rig, &copies, &p).expect("the copies");
    let bits = |m: &ImageF32| m.data.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    assert_eq!(
        bits(&picked.maps.owned().expect("owned maps").depth_m),
        bits(&copied.depth_m)
    );
    assert_eq!(
        bits(&picked.maps.owned().expect("owned maps").confidence),
        bits(&copied.confidence)
    );
    let (rel, within) = errors(
        &picked.maps.owned().expect("owned maps").depth_m,
        &synthetic::reference_depth(&scene, &rig),
    );
    assert!(rel < 0.01 && within > 0.7, "{rel:.4} / {within:.3}");
}

/// A frame set of several references on the WGSL engine writes each camera's image up once
/// (`GpuEngine::hold_set`): the dome's three references sweep 9 views each, 27 images, of
/// fewer distinct cameras, and the set writes exactly those; every reference is submitted
/// before the first is read back (`GpuEngine::submit_set`), and the staging buffers are kept
/// from set to set; every reference's maps equal, to the bit, the same reference swept alone
/// (its own uploads). With the cameras but the
/// references handed over as their messages' packed bytes (unpacked on the device, once) the
/// maps are the same again.
#[test]
fn a_set_of_several_references_writes_each_image_once_on_the_wgsl_engine() {
    use std::collections::BTreeSet;
    use sweepdepth::image::{CameraImage, PackedFormat, PackedImage, SetImages};
    use sweepdepth::sweep::gpu::GpuEngine;
    use sweepdepth::sweep::references::{reference_rig, ReferenceDepth};
    let (rig, scene, images) = dome();
    let p = params();
    let gpu = crate::common::gpu();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let references = [0, 5, 17];
    let views: Vec<Vec<usize>> = references
        .iter()
        .map(|&r| reference_rig(&rig.cameras, r, &p).expect("its rig").cameras)
        .collect();
    let distinct: BTreeSet<usize> = views.iter().flatten().copied().collect();
    let picked: usize = views.iter().map(Vec::len).sum();
    assert!(
        distinct.len() < picked,
        "{distinct:?}: the references share views"
    );
    let image_bytes = 160 * 120 * 4;
    let bits = |m: &ImageF32| m.data.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    let mut alone = Vec::new();
    for &r in &references {
        engine.take_set_counts();
        let depth = engine
            .run_references(&rig.cameras, &images, &[r], &p)
            .pop()
            .expect("one result")
            .expect("one reference");
        let views = reference_rig(&rig.cameras, r, &p).expect("its rig").cameras;
        assert_eq!(
            engine.take_set_counts().image_bytes,
            (views.len() * image_bytes) as u64,
            "a reference alone writes its views"
        );
        alone.push(depth);
    }
    engine.take_set_counts();
    let together = engine.run_references(&rig.cameras, &images, &references, &p);
    let counts = engine.take_set_counts();
    assert_eq!(
        counts.image_bytes,
        (distinct.len() * image_bytes) as u64,
        "each camera of the set once ({} images picked)",
        picked
    );
    // Every reference submitted before the first is read back, each read back after its own
    // submission.
    assert_eq!(
        (counts.submissions, counts.most_in_flight, counts.waits),
        (3, 3, 3),
        "{counts:?}"
    );
    // A set of other images, then these again: the staging buffers are kept from set to set
    // (at most one per submission in flight at once, the three references', over the three
    // sets; one per submission would be nine), and no set reads another's bytes. (How many
    // the first set makes depends on how soon lavapipe ends a submission: a reference may
    // find the one before's buffer free again, or not.)
    let fx = rig.cameras[0].model.intrinsics.fx_px;
    let other_scene = Scene::wall_and_box(3.0, Some((1.5, 0.3)), fx);
    let other_images = synthetic::render_rig(&other_scene, &rig);
    let other = engine.run_references(&rig.cameras, &other_images, &references, &p);
    let again = engine.run_references(&rig.cameras, &images, &references, &p);
    let later = engine.take_set_counts();
    assert!(
        counts.staging_buffers + later.staging_buffers <= references.len() as u32,
        "{counts:?} then {later:?}"
    );
    let depth_bits = |d: &Result<ReferenceDepth, _>| {
        bits(
            &d.as_ref()
                .expect("a reference")
                .maps
                .owned()
                .expect("owned maps")
                .depth_m,
        )
    };
    for ((a, b), o) in together.iter().zip(&again).zip(&other) {
        assert_eq!(depth_bits(a), depth_bits(b), "the same images again");
        assert_ne!(depth_bits(a), depth_bits(o), "other images, other depths");
    }
    // The same set with every camera but the references as packed rgb8 bytes.
    let bytes: Vec<Vec<u8>> = images
        .iter()
        .map(|i| {
            i.pixels
                .iter()
                .flat_map(|&p| Rgba8Image::unpack(p)[..3].to_vec())
                .collect()
        })
        .collect();
    let cameras: Vec<CameraImage<'_>> = (0..images.len())
        .map(|c| match references.contains(&c) {
            true => CameraImage::Rgba(&images[c]),
            false => CameraImage::Packed(PackedImage {
                width: 160,
                height: 120,
                format: PackedFormat::Rgb8,
                bytes: &bytes[c],
            }),
        })
        .collect();
    let set = SetImages::Cameras {
        set: &cameras,
        picked: None,
    };
    // A fresh engine: nothing of the set above on its device.
    let mut fresh = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let packed = fresh.run_references_set(&rig.cameras, set, &references, &p);
    assert_eq!(
        fresh.take_set_counts().image_bytes,
        distinct
            .iter()
            .map(|c| match references.contains(c) {
                true => image_bytes,
                false => image_bytes / 4 * 3,
            })
            .sum::<usize>() as u64,
        "the packed cameras' bytes as they came"
    );
    for (one, (a, b)) in alone.iter().zip(together.iter().zip(&packed)) {
        for other in [a, b] {
            let other = other.as_ref().expect("each reference of the set");
            assert_eq!(other.reference, one.reference);
            assert_eq!(other.cameras, one.cameras);
            assert_eq!(
                bits(&other.maps.owned().expect("owned maps").depth_m),
                bits(&one.maps.owned().expect("owned maps").depth_m)
            );
            assert_eq!(
                bits(&other.maps.owned().expect("owned maps").confidence),
                bits(&one.maps.owned().expect("owned maps").confidence)
            );
        }
        let (rel, within) = errors(
            &one.maps.owned().expect("owned maps").depth_m,
            &synthetic::reference_depth(
                &scene,
                &Rig::new(rig.cameras.clone(), Reference::Camera(one.reference)).expect("rig"),
            ),
        );
        assert!(rel < 0.02 && within > 0.5, "{rel:.4} / {within:.3}");
    }
}

/// A reference that cannot run among several on the WGSL engine (an index outside the rig,
/// between two that can): its error in its place, and the others, submitted ahead around it,
/// each get their own maps (those of the reference swept alone, to the bit).
#[test]
fn a_failing_reference_among_several_leaves_the_others_their_own_maps_on_the_wgsl_engine() {
    use sweepdepth::sweep::gpu::GpuEngine;
    let (rig, _, images) = dome();
    let p = params();
    let gpu = crate::common::gpu();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let bits = |m: &ImageF32| m.data.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    let alone = |engine: &mut GpuEngine, r: usize| {
        let mut results = engine.run_references(&rig.cameras, &images, &[r], &p);
        let depth = results.pop().expect("one").expect("runs alone");
        bits(&depth.maps.owned().expect("owned maps").depth_m)
    };
    let (first, last) = (alone(&mut engine, 17), alone(&mut engine, 5));
    let results = engine.run_references(&rig.cameras, &images, &[17, 99, 5], &p);
    assert_eq!(results.len(), 3);
    let depth = |i: usize| match &results[i] {
        Ok(d) => bits(&d.maps.owned().expect("owned maps").depth_m),
        Err(e) => panic!("reference {i}: {e}"),
    };
    assert!(depth(0) == first, "the first reference's own maps");
    assert!(
        matches!(
            results[1],
            Err(SweepError::NoSuchReference { index: 99, .. })
        ),
        "{:?}",
        results[1].as_ref().err()
    );
    assert!(depth(2) == last, "the last reference's own maps");
    assert_ne!(first, last);
}

/// Both cameras of a stereo pair as references on the WGSL engine: the set's two images go up
/// once, and each reference's prefiltered images (the pair's Sobel byte, made on the device
/// from the set's copies) give the maps of that reference swept alone, to the bit.
#[test]
fn both_cameras_of_a_pair_as_references_sweep_as_alone_on_the_wgsl_engine() {
    use sweepdepth::sweep::gpu::GpuEngine;
    let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
    let rig = synthetic::row_rig(2, 0.12, model, 0).expect("pair");
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let p = params();
    assert!(p.prefilter.applies(2), "a pair sweeps prefiltered images");
    let gpu = crate::common::gpu();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let image_bytes = (160 * 120 * 4) as u64;
    let bits = |m: &ImageF32| m.data.iter().map(|v| v.to_bits()).collect::<Vec<u32>>();
    let mut alone = Vec::new();
    for r in [0, 1] {
        engine.take_set_counts();
        let depth = engine.run_references(&rig.cameras, &images, &[r], &p);
        assert_eq!(engine.take_set_counts().image_bytes, 2 * image_bytes);
        alone.push(depth.into_iter().next().expect("one").expect("alone"));
    }
    // A fresh engine: nothing of the runs above on its device.
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("pipelines");
    let together = engine.run_references(&rig.cameras, &images, &[0, 1], &p);
    assert_eq!(engine.take_set_counts().image_bytes, 2 * image_bytes);
    for (one, other) in alone.iter().zip(&together) {
        let other = other.as_ref().expect("each reference of the pair");
        assert_eq!(other.reference, one.reference);
        assert_eq!(
            bits(&other.maps.owned().expect("owned maps").depth_m),
            bits(&one.maps.owned().expect("owned maps").depth_m)
        );
        assert_eq!(
            bits(&other.maps.owned().expect("owned maps").confidence),
            bits(&one.maps.owned().expect("owned maps").confidence)
        );
        let valid = one
            .maps
            .owned()
            .expect("owned maps")
            .depth_m
            .data
            .iter()
            .filter(|d| d.is_finite())
            .count();
        assert!(
            valid * 2 > one.maps.owned().expect("owned maps").depth_m.data.len(),
            "{valid} valid"
        );
    }
    assert_ne!(
        bits(&alone[0].maps.owned().expect("owned maps").depth_m),
        bits(&alone[1].maps.owned().expect("owned maps").depth_m),
        "two references, two maps"
    );
}
