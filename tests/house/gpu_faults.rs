//! GPU faults: a lost device (simulated with `Device::destroy`) is recreated and the set still
//! processed; a configuration larger than the adapter's limits is refused up front, naming the
//! limit. And the node's pipeline on the WGSL engine: the messages' own bytes unpacked on the
//! device give the outputs of converted images.

use std::path::PathBuf;
use std::sync::Arc;

use sweepdepth::bag::BagReader;
use sweepdepth::fusion::FusionParams;
use sweepdepth::geometry::CameraModel;
use sweepdepth::gpu_context::GpuContext;
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, TFMessage};
use sweepdepth::pipeline::{
    EngineHost, Fuser, FuserThread, FusionInput, Input, Job, Pipeline, PipelineConfig,
    VirtualCamera, Wanted,
};
use sweepdepth::sweep::gpu::GpuEngine;
use sweepdepth::sweep::{SweepError, SweepParams};
use sweepdepth::synthetic::{self, Scene};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The first job of the Tsukuba bag fixture, through the node's pipeline.
fn fixture_job(config: &PipelineConfig) -> Job {
    let mut pipeline = Pipeline::new(config).expect("pipeline");
    let bag = BagReader::open(&root().join("tests/fixtures/bags/tsukuba_half.mcap")).unwrap();
    for m in bag {
        let m = m.unwrap();
        let input = if m.topic == "/tf_static" {
            Input::TfStatic(from_cdr::<TFMessage>(&m.data).unwrap())
        } else if let Some(camera) = config.info_topics.iter().position(|t| *t == m.topic) {
            let info = Box::new(from_cdr::<CameraInfo>(&m.data).unwrap());
            Input::CameraInfo { camera, info }
        } else if let Some(camera) = config.image_topics.iter().position(|t| *t == m.topic) {
            let image: Image = from_cdr(&m.data).unwrap();
            Input::Image { camera, image }
        } else {
            continue;
        };
        let outcome = pipeline.push(input, m.log_time_ns);
        assert!(outcome.notices.is_empty(), "{:?}", outcome.notices);
        if let Some(set) = outcome.sets.into_iter().next() {
            return set.expect("a job");
        }
    }
    panic!("no complete set in the fixture");
}

/// The Tsukuba bag fixture's configuration and first job.
fn fixture() -> (PipelineConfig, Job) {
    fixture_with(&[])
}

/// [`fixture`] with the parameters `extra` (`-p name:=value` pairs) after its own.
fn fixture_with(extra: &[&str]) -> (PipelineConfig, Job) {
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let args: Vec<String> = ["--ros-args", "--params-file", params.to_str().unwrap()]
        .iter()
        .chain(extra)
        .map(|s| s.to_string())
        .collect();
    let config = PipelineConfig::from_args(&args).expect("config");
    let job = fixture_job(&config);
    (config, job)
}

#[test]
fn lost_device_is_recreated_and_the_set_processed() {
    let (config, job) = fixture();
    let mut host = EngineHost::new(sweepdepth::engine::Device::Gpu).expect("GPU");
    let before = host
        .process(&job, &config.sweep, Wanted::all(false))
        .expect("first run");
    host.device()
        .expect("the WGSL engine has a device")
        .destroy();
    let after = host
        .process(&job, &config.sweep, Wanted::all(false))
        .expect("the run after the loss succeeds on a new device");
    assert_eq!(host.recreated, 1);
    assert!(!host.is_lost());
    assert!(before.skipped.is_empty() && after.skipped.is_empty());
    assert_eq!(
        before.outputs[0].messages.depth.data, after.outputs[0].messages.depth.data,
        "same depth on the new device"
    );
    // And it keeps working.
    host.process(&job, &config.sweep, Wanted::all(false))
        .expect("third run");
    assert_eq!(host.recreated, 1);
}

/// Fusion on the engine's device follows the engine onto the device it makes after a loss
/// (`EngineHost::on_new_device`, as the node's GPU thread wires it): the map, still on the lost
/// device, leaves it for its host copy and goes onto the new one with every block, and fuses on
/// there.
#[test]
fn fusion_follows_the_engine_onto_its_new_device() {
    let (config, job) = fixture();
    let mut host = EngineHost::new(sweepdepth::engine::Device::Gpu).expect("GPU");
    let fusion_params = FusionParams {
        voxel_size_m: 0.05,
        ..FusionParams::default()
    };
    let fusion = Arc::new(FuserThread::spawn(fusion_params, host.gpu(), 0.0, |_| {}).unwrap());
    let follower = Arc::clone(&fusion);
    host.on_new_device(move |gpu| follower.follow_device(gpu.clone()));
    let fuse = |set: sweepdepth::pipeline::SetOutputs| {
        let inputs = set.outputs.into_iter();
        fusion.offer(
            inputs
                .map(|o| FusionInput::from_maps(o.maps, None))
                .collect(),
        );
        fusion.flush();
        fusion.stats()
    };
    let wanted = Wanted::all(false);
    let first = fuse(
        host.process(&job, &config.sweep, wanted)
            .expect("first run"),
    );
    assert!(
        first.on_gpu && first.integrated == 1 && first.blocks > 0,
        "{first:?}"
    );
    let old = host.device().expect("the WGSL engine's device").clone();
    old.destroy();
    let after = host
        .process(&job, &config.sweep, wanted)
        .expect("the run after the loss");
    assert_eq!(host.recreated, 1);
    fusion.flush();
    let moved = fusion.stats();
    assert!(moved.on_gpu, "fusion did not follow the engine: {moved:?}");
    assert!(moved.left_gpu.is_some(), "the loss is told: {moved:?}");
    assert_eq!(moved.blocks, first.blocks, "the blocks went along");
    let last = fuse(after);
    assert!(last.on_gpu && last.integrated == 2, "{last:?}");
    assert!(last.skipped.is_empty(), "{:?}", last.skipped);
}

/// `bag`'s fusion (a `Fuser` on the engine's device, no thread) follows the engine onto the
/// device it makes after a loss (`Fuser::follow_engine`, which `bag` calls after each set):
/// nothing to follow before the loss; after it the map goes onto the new device with every
/// block and fuses on there; once followed, the next set has nothing to follow again.
#[test]
fn a_bags_fusion_follows_the_engine_onto_its_new_device() {
    let (config, job) = fixture();
    let mut host = EngineHost::new(sweepdepth::engine::Device::Gpu).expect("GPU");
    let params = FusionParams {
        voxel_size_m: 0.05,
        ..FusionParams::default()
    };
    let mut fuser = Fuser::on(params, host.gpu()).expect("a fuser on the engine's device");
    let mut seen = host.recreated;
    let wanted = Wanted::all(false);
    let fuse = |fuser: &mut Fuser, set: sweepdepth::pipeline::SetOutputs| {
        for out in set.outputs {
            fuser
                .add(&FusionInput::from_maps(out.maps, None))
                .expect("fused");
        }
    };
    let first = host
        .process(&job, &config.sweep, wanted)
        .expect("first run");
    assert_eq!(fuser.follow_engine(&host, &mut seen), Ok(false));
    fuse(&mut fuser, first);
    let blocks = fuser.blocks().0;
    assert!(fuser.is_on_gpu() && blocks > 0, "{blocks} blocks");
    let old = host.device().expect("the WGSL engine's device").clone();
    old.destroy();
    let after = host
        .process(&job, &config.sweep, wanted)
        .expect("the run after the loss");
    assert_eq!(host.recreated, 1);
    assert_eq!(fuser.follow_engine(&host, &mut seen), Ok(true));
    assert!(fuser.is_on_gpu(), "fusion did not follow the engine");
    assert!(fuser.left_gpu().is_some(), "the loss is told");
    assert_eq!(fuser.blocks().0, blocks, "the blocks went along");
    fuse(&mut fuser, after);
    assert_eq!(fuser.integrated, 2);
    assert!(fuser.is_on_gpu());
    let third = host
        .process(&job, &config.sweep, wanted)
        .expect("third run");
    assert_eq!(fuser.follow_engine(&host, &mut seen), Ok(false));
    fuse(&mut fuser, third);
    assert!(fuser.is_on_gpu() && fuser.integrated == 3);
}

#[test]
fn configuration_beyond_the_adapter_limits_is_refused_up_front() {
    // An adapter that allows only 8 MiB per storage binding.
    let gpu = GpuContext::with_max_storage_binding(8 << 20).expect("GPU");
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("engine");
    let model = CameraModel::pinhole(synthetic::intrinsics(640, 480));
    let rig = synthetic::row_rig(4, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(2.0, None, model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 4.0,
        num_planes: 64,
        ..SweepParams::default()
    };
    let err = engine
        .run(&rig, &images, &params)
        .expect_err("640x480x64 with SGM cannot fit 8 MiB bindings");
    let text = err.to_string();
    assert!(matches!(err, SweepError::InvalidParams(_)), "{text}");
    assert!(text.contains("storage binding limit"), "{text}");
    assert!(text.contains("8388608"), "the limit is named: {text}");
    // The engine is still usable for a configuration that fits.
    let small = SweepParams {
        num_planes: 8,
        ..params
    };
    let rig_small = synthetic::row_rig(
        3,
        0.1,
        CameraModel::pinhole(synthetic::intrinsics(64, 48)),
        1,
    )
    .unwrap();
    let scene = Scene::wall_and_box(2.0, None, synthetic::intrinsics(64, 48).fx_px);
    let images = synthetic::render_rig(&scene, &rig_small);
    engine
        .run(&rig_small, &images, &small)
        .expect("a small set still runs");
}

/// A transform that changes at run time (a re-published /tf_static) is used from the next
/// frame set on; a missing one is reported by name until it arrives.
#[test]
fn transform_changes_apply_from_the_next_set() {
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let args: Vec<String> = ["--ros-args", "--params-file", params.to_str().unwrap()]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let config = PipelineConfig::from_args(&args).expect("config");
    let mut pipeline = Pipeline::new(&config).expect("pipeline");
    let bag: Vec<_> = BagReader::open(&root().join("tests/fixtures/bags/tsukuba_half.mcap"))
        .unwrap()
        .map(|m| m.unwrap())
        .collect();
    let tf_msg: TFMessage =
        from_cdr(&bag.iter().find(|m| m.topic == "/tf_static").unwrap().data).unwrap();
    // The sets of the fixture, one by one; /tf_static only after the first set.
    let mut jobs = Vec::new();
    let mut skips = Vec::new();
    let mut set_index = 0;
    for m in &bag {
        if let Some(camera) = config.info_topics.iter().position(|t| *t == m.topic) {
            let info = Box::new(from_cdr::<CameraInfo>(&m.data).unwrap());
            let _ = pipeline.push(Input::CameraInfo { camera, info }, m.log_time_ns);
        } else if let Some(camera) = config.image_topics.iter().position(|t| *t == m.topic) {
            let image: Image = from_cdr(&m.data).unwrap();
            let outcome = pipeline.push(Input::Image { camera, image }, m.log_time_ns);
            for set in outcome.sets {
                match set {
                    Ok(job) => jobs.push(job),
                    Err(skip) => skips.push(skip),
                }
                set_index += 1;
                if set_index == 1 {
                    let tf = Input::TfStatic(tf_msg.clone());
                    assert!(pipeline.push(tf, m.log_time_ns).notices.is_empty());
                } else if set_index == 2 {
                    // cam4 moves 10 cm further right.
                    let mut moved = tf_msg.clone();
                    for t in &mut moved.transforms {
                        if t.child_frame_id == "cam4_optical_frame" {
                            t.transform.translation.x += 0.1;
                        }
                    }
                    let tf = Input::TfStatic(moved);
                    assert!(pipeline.push(tf, m.log_time_ns).notices.is_empty());
                }
            }
        }
    }
    assert_eq!(skips.len(), 1, "the first set waits for /tf_static");
    assert!(
        skips[0]
            .message
            .contains("waiting for the transform from 'cam2_optical_frame'"),
        "{}",
        skips[0].message
    );
    assert_eq!(jobs.len(), 2);
    let centre = |job: &Job, k: usize| job.cameras[k].cam_from_rig.inverse().translation;
    let (before, after) = (centre(&jobs[0], 4), centre(&jobs[1], 4));
    assert!(
        ((after.x - before.x) - 0.1).abs() < 1e-9,
        "{before:?} -> {after:?}"
    );
    assert!((centre(&jobs[1], 0) - centre(&jobs[0], 0)).length() < 1e-12);
}

/// The node's pipeline hands a WGSL engine the messages' own bytes for every camera, the
/// references and a virtual reference's sweep too (`convert::packed_view`, unpacked on the device by the `unpack` stage; the
/// references' colour converted on the host beside the sweep): depth, confidence and the
/// coloured points equal, to the bit, those of the same engine fed images converted on the
/// host, one reference after the other; three references of one set on the engine itself
/// (each image up once, all submitted before the first is read back) too.
#[test]
fn the_wgsl_engine_takes_the_messages_bytes_and_gives_the_same_outputs() {
    use sweepdepth::engine::Sweeper;
    use sweepdepth::image::{CameraImage, SetImages};
    use sweepdepth::pipeline::convert::packed_view;
    use sweepdepth::sweep::frame_memo::FrameMemo;
    use sweepdepth::sweep::{DepthMaps, StageTimings};
    /// The WGSL engine; `unpacks` says whether it takes packed images, `packed` counts the
    /// sweeps that had some, `all_packed` those that had nothing else.
    struct Probe {
        engine: GpuEngine,
        unpacks: bool,
        packed: usize,
        all_packed: usize,
    }
    impl Sweeper for Probe {
        fn run_set(
            &mut self,
            rig: &sweepdepth::geometry::Rig,
            images: SetImages<'_>,
            params: &SweepParams,
        ) -> Result<DepthMaps, SweepError> {
            self.packed += usize::from(images.has_packed());
            let packed = |c: CameraImage<'_>| matches!(c, CameraImage::Packed(_));
            self.all_packed += usize::from(images.iter().all(packed));
            self.engine.run_set(rig, images, params)
        }
        fn memo(&mut self) -> &mut FrameMemo {
            Sweeper::memo(&mut self.engine)
        }
        fn timings_mut(&mut self) -> &mut StageTimings {
            Sweeper::timings_mut(&mut self.engine)
        }
        fn unpacks_on_device(&self) -> bool {
            self.unpacks
        }
    }
    let (config, job) = fixture();
    assert!(job.images.len() > 2);
    assert!(
        job.images.iter().all(|m| packed_view(m).is_some()),
        "{:?}",
        job.images[0].encoding
    );
    // The same set with a virtual reference where camera 0 is (one sweep of every camera, no
    // colour: nothing converted on the host for the WGSL engine).
    let mut virtual_job = job.clone();
    virtual_job.references.truncate(1);
    virtual_job.references[0].virtual_camera = Some(VirtualCamera {
        model: job.cameras[0].model,
        cam_from_rig: job.cameras[0].cam_from_rig,
        frame_id: "virtual".into(),
    });
    let all_pairs = SweepParams {
        pairs: sweepdepth::sweep::PairSet::All,
        ..config.sweep.clone()
    };
    // The same bag with three references.
    let (three_config, three) = fixture_with(&["-p", "references:=[cam1, cam2, cam3]"]);
    assert_eq!(three.references.len(), 3);
    let gpu = GpuContext::new().expect("GPU");
    for (job, sweep) in [
        (&job, &config.sweep),
        (&virtual_job, &all_pairs),
        (&three, &three_config.sweep),
    ] {
        let run = |unpacks: bool| {
            let engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("engine");
            let mut probe = Probe {
                engine,
                unpacks,
                packed: 0,
                all_packed: 0,
            };
            let wanted = Wanted::all(true);
            let set =
                sweepdepth::pipeline::process_job(&mut probe, job, sweep, wanted).expect("the set");
            (set, probe.packed, probe.all_packed)
        };
        let (probed, sweeps_with_packed, all_packed) = run(true);
        let (converted, none, _) = run(false);
        // The engine itself (its own `run_references_set`).
        let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("engine");
        let wanted = Wanted::all(true);
        let packed =
            sweepdepth::pipeline::process_job(&mut engine, job, sweep, wanted).expect("the set");
        assert_eq!(packed.outputs.len(), job.references.len());
        let counts = engine.take_set_counts();
        assert_eq!(
            counts.most_in_flight as usize,
            job.references.len(),
            "{counts:?}"
        );
        for (a, b) in probed.outputs.iter().zip(&packed.outputs) {
            assert_eq!(a.messages.depth.data, b.messages.depth.data);
        }
        assert!(
            sweeps_with_packed > 0 && all_packed == sweeps_with_packed && none == 0,
            "{sweeps_with_packed} / {all_packed} / {none}"
        );
        assert_eq!(packed.outputs.len(), converted.outputs.len());
        assert!(!packed.outputs.is_empty());
        for (a, b) in packed.outputs.iter().zip(&converted.outputs) {
            assert_eq!(a.messages.depth.data, b.messages.depth.data);
            assert_eq!(a.messages.confidence.data, b.messages.confidence.data);
            let (pa, pb) = (a.messages.points.as_ref(), b.messages.points.as_ref());
            assert_eq!(
                pa.map(|p| &p.data),
                pb.map(|p| &p.data),
                "the points and their colours"
            );
            assert!(pa.is_some_and(|p| !p.data.is_empty()));
        }
    }
    assert_eq!(virtual_job.references.len(), 1);
}

/// Sets started one after the other on the WGSL engine (`EngineHost::start`, as `bag` and the
/// node's GPU thread keep the next set on the device while the host finishes the one before)
/// are all on the device before the first is read back, and each finishes, in order, with the
/// outputs it has alone, to the bit: one reference, three references of the same images, one
/// reference again. A device lost with two sets on it is made anew and both sets still come
/// out whole, in order.
#[test]
fn sets_started_ahead_finish_in_order_with_their_own_outputs_even_after_a_lost_device() {
    let (config, one) = fixture();
    let (three_config, three) = fixture_with(&["-p", "references:=[cam1, cam2, cam3]"]);
    assert_eq!((one.references.len(), three.references.len()), (1, 3));
    let wanted = Wanted::all(true);
    let mut host = EngineHost::new(sweepdepth::engine::Device::Gpu).expect("GPU");
    assert!(host.starts_without_waiting());
    let alone_one = host.process(&one, &config.sweep, wanted).expect("alone");
    let alone_three = host
        .process(&three, &three_config.sweep, wanted)
        .expect("alone");
    let depths = |set: &sweepdepth::pipeline::SetOutputs| -> Vec<Vec<u8>> {
        assert!(set.skipped.is_empty(), "{:?}", set.skipped);
        set.outputs
            .iter()
            .map(|o| o.messages.depth.data.clone())
            .collect()
    };
    let (alone_one, alone_three) = (depths(&alone_one), depths(&alone_three));
    assert_eq!((alone_one.len(), alone_three.len()), (1, 3));
    assert_ne!(
        alone_three[0], alone_three[1],
        "each reference its own depth"
    );
    host.take_gpu_counts();
    host.start(one.clone(), &config.sweep, wanted);
    host.start(three.clone(), &three_config.sweep, wanted);
    host.start(one.clone(), &config.sweep, wanted);
    assert_eq!(host.in_flight(), 3);
    let expected = [&alone_one, &alone_three, &alone_one];
    for (i, expected) in expected.into_iter().enumerate() {
        let finished = host.finish().expect("a set in flight");
        let set = finished.result.expect("the set");
        assert!(depths(&set) == *expected, "set {i}: its own outputs");
    }
    assert!(host.finish().is_none(), "nothing left in flight");
    let counts = host.take_gpu_counts().expect("the WGSL engine");
    // Five references on the device before the first was read back.
    assert_eq!(counts.most_in_flight, 5, "{counts:?}");
    // A device lost under two sets in flight.
    host.start(three.clone(), &three_config.sweep, wanted);
    host.start(one.clone(), &config.sweep, wanted);
    host.device().expect("a device").destroy();
    let first = host.finish().expect("in flight").result.expect("rerun");
    let second = host.finish().expect("in flight").result.expect("rerun");
    assert_eq!(host.recreated, 1);
    assert!(depths(&first) == alone_three && depths(&second) == alone_one);
    assert!(host.finish().is_none());
}

/// The node without fusion (`EngineHost::set_keep_floats(false)`): the WGSL engine lends
/// depth and confidence out of its readback buffer and the messages are made from there, the
/// same bytes as from the maps it copies out otherwise; no maps are kept as floats then, and
/// where the points are made (from the floats) they are kept again.
#[test]
fn messages_made_from_lent_maps_are_those_made_from_copied_ones() {
    let (config, job) = fixture();
    let mut host = EngineHost::new(sweepdepth::engine::Device::Gpu).expect("GPU");
    let kept = host
        .process(&job, &config.sweep, Wanted::NONE)
        .expect("a run keeping floats");
    host.set_keep_floats(false);
    let lent = host
        .process(&job, &config.sweep, Wanted::NONE)
        .expect("a run with lent maps");
    let points = host
        .process(
            &job,
            &config.sweep,
            Wanted {
                points: true,
                ..Wanted::NONE
            },
        )
        .expect("a run making points");
    let (kept, lent, points) = (&kept.outputs[0], &lent.outputs[0], &points.outputs[0]);
    let pixels = (kept.messages.depth.width * kept.messages.depth.height) as usize;
    assert!(pixels > 0);
    assert_eq!(kept.maps.depth_m.data.len(), pixels);
    assert_eq!(kept.maps.confidence.data.len(), pixels);
    assert!(
        lent.maps.depth_m.data.is_empty() && lent.maps.confidence.data.is_empty(),
        "no floats kept"
    );
    for (a, b) in [
        (&kept.messages.depth, &lent.messages.depth),
        (&kept.messages.confidence, &lent.messages.confidence),
        (&kept.messages.depth, &points.messages.depth),
    ] {
        assert_eq!(
            (a.width, a.height, &a.encoding),
            (b.width, b.height, &b.encoding)
        );
        assert_eq!(a.data, b.data);
    }
    assert!(points.messages.points.is_some());
    assert_eq!(
        points.maps.depth_m.data.len(),
        pixels,
        "points keep the floats"
    );
}
