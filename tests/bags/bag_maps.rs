//! What `sweepdepth bag` writes on `/cost/image` and `/selection/image`: each set's maps as the
//! CPU engine makes them from that set's images, run here in the test process (the input side
//! of the pipeline forms the sets; the engine is called directly, not through the code that
//! makes the output messages), and the selection coloured as the paper's Fig. 7 colours its
//! codes (a table of the test's own, not `selection::colour`).

use super::util::{messages, ok, root, scratch, sweepdepth};

use sweepdepth::engine::Sweeper;
use sweepdepth::msgs::{from_cdr, Image, Time};
use sweepdepth::pipeline::convert::set_to_rgba8;
use sweepdepth::pipeline::{Input, Job, Pipeline, PipelineConfig};
use sweepdepth::sweep::cpu::CpuEngine;
use sweepdepth::sweep::{selection, DepthMaps};

/// The paper's Fig. 7 colours, written out here so that a change to the module's own table is
/// seen: no clear half white, left half red, right half green, invalid black.
fn fig7_colour(code: u8) -> [u8; 3] {
    match code {
        selection::NONE => [255, 255, 255],
        selection::LEFT => [255, 0, 0],
        selection::RIGHT => [0, 255, 0],
        selection::INVALID => [0, 0, 0],
        other => panic!("the engine made selection code {other}"),
    }
}

/// The `/cost/image` or `/selection/image` messages of a bag, in order.
fn images_on(path: &std::path::Path, topic: &str) -> Vec<Image> {
    messages(path)
        .into_iter()
        .filter(|m| m.topic == topic)
        .map(|m| from_cdr(&m.data).expect("decode an Image"))
        .collect()
}

/// The fixture's sets as the pipeline's input side forms them from the bag's messages, with
/// the parameters `bag` is given (`--params-file` and `-p device:=cpu`).
fn fixture_jobs(config: &PipelineConfig, bag: &std::path::Path) -> Vec<Job> {
    let mut pipeline = Pipeline::new(config).expect("pipeline");
    let mut jobs = Vec::new();
    for m in messages(bag) {
        let image = config.image_topics.iter().position(|t| *t == m.topic);
        let info = config.info_topics.iter().position(|t| *t == m.topic);
        let input = match (image, info) {
            (Some(camera), _) => Input::Image {
                camera,
                image: from_cdr(&m.data).expect("image"),
            },
            (_, Some(camera)) => Input::CameraInfo {
                camera,
                info: Box::new(from_cdr(&m.data).expect("camera info")),
            },
            _ if m.topic == config.tf_static_topic => {
                Input::TfStatic(from_cdr(&m.data).expect("tf_static"))
            }
            _ => continue,
        };
        jobs.extend(pipeline.push(input, m.log_time_ns).jobs());
    }
    jobs.extend(pipeline.finish().jobs());
    jobs
}

/// The CPU engine's maps of the reference of each of `jobs`, with the set's stamp.
fn engine_maps(config: &PipelineConfig, jobs: &[Job]) -> Vec<(Time, DepthMaps)> {
    let mut engine = CpuEngine::new();
    jobs.iter()
        .map(|job| {
            assert_eq!(job.references.len(), 1, "one reference (cam2)");
            let reference = job.references[0].index;
            let images = set_to_rgba8(&job.images, |i| job.cameras[i].name.as_str())
                .expect("the fixture's images convert");
            let mut results =
                engine.run_references(&job.cameras, &images, &[reference], &config.sweep);
            let depth = results.pop().expect("one result").expect("the sweep");
            (job.images[reference].header.stamp, depth.maps.into_owned())
        })
        .collect()
}

/// Outcome checked: every set's `/cost/image` is, to the bit, the cost map the CPU engine makes
/// of that set's images (not its confidence, nor any other map), and every `/selection/image`
/// pixel is the Fig. 7 colour of the engine's selection code for it (both half codes occur, so
/// red and green swapped are seen).
#[test]
fn cost_and_selection_images_are_the_engines_maps() {
    let dir = scratch("maps");
    let out = dir.join("out.mcap");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            fixture.to_str().unwrap(),
            out.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
            "-p",
            "device:=cpu",
        ]),
        "sweepdepth bag",
    );
    assert!(
        stderr.contains("3 frame sets found, 3 processed"),
        "{stderr}"
    );

    let args: Vec<String> = [
        "--ros-args",
        "--params-file",
        params.to_str().unwrap(),
        "-p",
        "device:=cpu",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let config = PipelineConfig::from_args(&args).expect("config");
    let jobs = fixture_jobs(&config, &fixture);
    assert_eq!(jobs.len(), 3, "three sets in the fixture");
    let expected = engine_maps(&config, &jobs);

    let costs = images_on(&out, "/cost/image");
    let selections = images_on(&out, "/selection/image");
    assert_eq!(costs.len(), 3);
    assert_eq!(selections.len(), 3);
    for (set, ((stamp, maps), (cost, sel))) in expected
        .iter()
        .zip(costs.iter().zip(&selections))
        .enumerate()
    {
        let (w, h) = (maps.width(), maps.height());
        assert_eq!((w, h), (192, 144), "set {set}");
        assert_eq!(cost.header.stamp, *stamp, "set {set}: cost stamp");
        assert_eq!(sel.header.stamp, *stamp, "set {set}: selection stamp");

        // Cost: the engine's cost map, bit for bit (NaN where no hypothesis was valid).
        assert_eq!((cost.width, cost.height, cost.step), (w, h, w * 4));
        assert_eq!(cost.encoding, "32FC1");
        let want: Vec<u8> = maps
            .cost
            .data
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert_eq!(want.len(), cost.data.len(), "set {set}: cost size");
        let differing = want
            .chunks_exact(4)
            .zip(cost.data.chunks_exact(4))
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(
            differing,
            0,
            "set {set}: {differing} of {} cost pixels are not the engine's cost",
            w * h
        );
        // The cost is its own map: it is not the confidence (what a mix-up would write).
        let same_as_confidence = maps
            .cost
            .data
            .iter()
            .zip(&maps.confidence.data)
            .filter(|(c, k)| c.to_bits() == k.to_bits())
            .count();
        assert!(
            same_as_confidence * 10 < (w * h) as usize,
            "set {set}: the engine's cost equals its confidence at {same_as_confidence} pixels"
        );

        // Selection: the Fig. 7 colour of the engine's code at every pixel.
        assert_eq!((sel.width, sel.height, sel.step), (w, h, w * 3));
        assert_eq!(sel.encoding, "rgb8");
        assert_eq!(maps.selection.len(), (w * h) as usize);
        let count = |code| maps.selection.iter().filter(|&&c| c == code).count();
        let (left, right) = (count(selection::LEFT), count(selection::RIGHT));
        assert!(
            left > 0 && right > 0,
            "set {set}: the engine chose the left half at {left} pixels and the right at {right}"
        );
        let wrong: Vec<(usize, u8, &[u8])> = maps
            .selection
            .iter()
            .zip(sel.data.chunks_exact(3))
            .enumerate()
            .filter(|(_, (&code, rgb))| fig7_colour(code) != **rgb)
            .map(|(i, (&code, rgb))| (i, code, rgb))
            .collect();
        assert!(
            wrong.is_empty(),
            "set {set}: {} of {} selection pixels are not their code's colour, first (pixel, \
             code, rgb): {:?}",
            wrong.len(),
            w * h,
            wrong.first()
        );
    }
}
