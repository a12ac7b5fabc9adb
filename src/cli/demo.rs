//! `sweepdepth demo`: the main job on the built-in sample data (Middlebury Tsukuba, 5 views,
//! shipped in `data/tsukuba` and embedded in the binary): runs the engine, writes depth,
//! confidence and selection PNGs plus the disparity PFM, and prints a quality line.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;

use crate::datasets;
use crate::engine::{Engine, Sweeper};
use crate::eval::{self, Metrics};
use crate::params::EngineOptions;

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Where to write the images.
    #[arg(long, default_value = "sweepdepth-demo")]
    pub out: PathBuf,
    /// Which engine runs the sweep: a hardware GPU if there is one, else the CPU engine
    /// (auto); the WGSL engine on the wgpu adapter, lavapipe included (gpu); the CPU engine.
    #[arg(long, value_enum, default_value_t = crate::engine::Device::Auto)]
    pub device: crate::engine::Device,
    /// Engine options.
    #[command(flatten)]
    pub params: EngineOptions,
}

/// The sample data, embedded so the demo runs from any directory.
const SAMPLE: [(&str, &[u8]); 6] = [
    (
        "scene1.row3.col1.png",
        include_bytes!("../../data/tsukuba/scene1.row3.col1.png"),
    ),
    (
        "scene1.row3.col2.png",
        include_bytes!("../../data/tsukuba/scene1.row3.col2.png"),
    ),
    (
        "scene1.row3.col3.png",
        include_bytes!("../../data/tsukuba/scene1.row3.col3.png"),
    ),
    (
        "scene1.row3.col4.png",
        include_bytes!("../../data/tsukuba/scene1.row3.col4.png"),
    ),
    (
        "scene1.row3.col5.png",
        include_bytes!("../../data/tsukuba/scene1.row3.col5.png"),
    ),
    (
        "truedisp.row3.col3.png",
        include_bytes!("../../data/tsukuba/truedisp.row3.col3.png"),
    ),
];

/// Writes the embedded sample into `dir/tsukuba` and returns that folder.
pub fn extract_sample(dir: &Path) -> anyhow::Result<PathBuf> {
    let folder = dir.join("tsukuba");
    std::fs::create_dir_all(&folder).with_context(|| format!("creating {}", folder.display()))?;
    for (name, bytes) in SAMPLE {
        let path = folder.join(name);
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(folder)
}

pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let input = extract_sample(&args.out.join("input"))?;
    let mut dataset = datasets::load_dataset(&input)?;
    args.params.apply(&mut dataset.params);
    let mut engine = Engine::new(args.device)?;
    let adapter = engine.label();
    let (w, h) = dataset.reference_size();
    eprintln!(
        "demo: Middlebury Tsukuba, {} views {w}x{h}, {} planes, on {adapter}",
        dataset.rig.cameras.len(),
        dataset.params.num_planes
    );
    // The first run builds the pipelines (GPU) and the plan; time the second, as a live node
    // would see it.
    engine.run_views(&dataset.rig, &dataset.images, &dataset.params)?;
    let started = Instant::now();
    let maps = engine.run_views(&dataset.rig, &dataset.images, &dataset.params)?;
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let metrics = eval::metrics_for(&dataset, &maps)?;
    let out = args.out.join("tsukuba");
    eval::save_outputs(&out, &dataset, &maps)?;
    for name in [
        "depth.png",
        "confidence.png",
        "selection.png",
        "disparity.pfm",
        "confidence.pfm",
    ] {
        println!("wrote {}", out.join(name).display());
    }
    println!("(the input views and ground truth: {})", input.display());
    match metrics {
        Some(Metrics::Disparity(m)) => println!(
            "quality: bad>1 {:.2} %, bad>2 {:.2} %, invalid {:.2} % (Tsukuba ground truth, 18 px border); {ms:.0} ms per frame set on {adapter}",
            m.bad1, m.bad2, m.invalid
        ),
        _ => println!("quality: no ground truth; {ms:.0} ms per frame set on {adapter}"),
    }
    Ok(())
}
