//! `sweepdepth bag IN OUT`: a recorded bag through the node's own pipeline
//! ([`crate::pipeline`]: the same synchronisation, extrinsics, engine and output messages as
//! the live node), every frame set processed (nothing dropped for speed), the outputs written
//! to OUT under the node's topic names.

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::fusion::FusionParams;
use crate::msgs::{from_cdr, CameraInfo, CompressedImage, Image, TFMessage};
use crate::pipeline::{fusion_gpu, Asked, Fuser, FusionHost, Publishers};
use crate::pipeline::{ConfigError, EngineHost, HostError, Input, Pipeline, PipelineConfig};
use crate::viewer::{Viewer, ViewerConfig, ViewerError};

use super::interrupt;
use super::pace::{Pacer, ViewRate};
use super::reader::TopicInfo;
use super::report::BagReport;
use super::schemas::{CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, MARKER_ARRAY, TF_MESSAGE};
use super::sink::{BagFusion, Sink};
use super::{writer, BagError, BagReader, BagWriter};

/// `sweepdepth bag` arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct BagArgs {
    /// Input bag: a `.mcap` file, a `.db3` file, or a rosbag2 directory (metadata.yaml + files).
    pub input: PathBuf,
    /// Output: a `.mcap` file when the name ends in .mcap, else a rosbag2 directory.
    pub output: PathBuf,
    /// Node parameter file(s) (as `--ros-args --params-file`), applied in order.
    #[arg(long = "params-file", value_name = "FILE")]
    pub params_files: Vec<PathBuf>,
    /// One parameter, `name:=value` (as `--ros-args -p`), after the files.
    #[arg(short = 'p', long = "param", value_name = "NAME:=VALUE")]
    pub params: Vec<String>,
    /// A topic remapping, `from:=to` (as `--ros-args -r`).
    #[arg(short = 'r', long = "remap", value_name = "FROM:=TO")]
    pub remaps: Vec<String>,
    /// Also copy the input messages into OUT.
    #[arg(long)]
    pub copy_inputs: bool,
    /// Replace OUT if it exists.
    #[arg(long)]
    pub force: bool,
    /// Serve the outputs live while processing: a Foxglove WebSocket server (for Foxglove and
    /// Lichtblick) on `foxglove_port` (8765 when not set) and the built-in page on the next
    /// port, at `foxglove_address`. When done it keeps serving the last set until Ctrl-C.
    #[arg(long)]
    pub view: bool,
    /// With --view: the pace, a multiple of the recording's rate (1 = as recorded), or `max`
    /// (as fast as it goes).
    #[arg(long, value_name = "RATE|max", default_value = "1", requires = "view")]
    pub view_rate: ViewRate,
    /// Exit non-zero when the bag is damaged even if usable sets were processed (by default a
    /// damaged bag is reported, the rest processed, and only a bag with nothing usable fails).
    #[arg(long)]
    pub strict: bool,
    /// Fuse every reference's depth of every set into one coloured mesh, written at the end
    /// as a binary PLY (MeshLab, Blender): in the world frame on a moving rig (`world_frame`),
    /// else in the first reference camera's optical frame. An existing FILE is replaced only
    /// with --force, and only if it is a PLY.
    #[arg(long, value_name = "FILE.ply")]
    pub mesh: Option<PathBuf>,
    /// With --mesh: the voxel size, metres, 0.001 to 10 (the truncation distance is 4 voxels;
    /// default 0.05, or the `voxel_size` parameter with `fusion:=true`).
    #[arg(long, value_name = "M", requires = "mesh")]
    pub voxel_size: Option<f32>,
    /// On the WGSL engine, the sets left running on the device while the host reads the one
    /// before back and writes it (0: each set read back before the next is submitted).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub sets_ahead: usize,
}

impl BagArgs {
    /// The equivalent `--ros-args` block of the live node.
    pub fn ros_args(&self) -> Vec<String> {
        let mut v = vec!["--ros-args".to_string()];
        for f in &self.params_files {
            v.push("--params-file".into());
            v.push(f.display().to_string());
        }
        for p in &self.params {
            v.push("-p".into());
            v.push(p.clone());
        }
        for r in &self.remaps {
            v.push("-r".into());
            v.push(r.clone());
        }
        v
    }
}

/// Errors that end a bag run.
#[derive(Debug, thiserror::Error)]
pub enum BagRunError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("GPU: {0}")]
    Gpu(#[from] HostError),
    #[error("live view: {0}")]
    Viewer(#[from] ViewerError),
    #[error("{bag}: none of the image topics [{}] is in the bag (set `cameras`/`image_topic` or remap); the bag has: {}", wanted.join(", "), found.join(", "))]
    NoInput {
        bag: String,
        wanted: Vec<String>,
        /// `topic (type)` of every topic in the bag.
        found: Vec<String>,
    },
    #[error("the bag is damaged ({count} read errors, the first: {first}); {}", if *sets == 0 { "no set could be processed: nothing written".to_string() } else { format!("the {sets} sets that could be read are in {output}") })]
    Damaged {
        count: usize,
        first: String,
        sets: u64,
        output: String,
    },
    #[error("--mesh: {0}")]
    Fusion(#[from] crate::fusion::FusionError),
    #[error("stopped by Ctrl-C after {sets} frame sets: {output} holds them{}", mesh.as_ref().map_or(String::new(), |m| format!(", {m} their mesh")))]
    Interrupted {
        sets: u64,
        output: String,
        mesh: Option<String>,
    },
    #[error("--voxel-size must be in [0.001, 10] m (as the voxel_size parameter), got {0}")]
    VoxelSize(f32),
    #[error("--mesh: cannot write {path}: {source}")]
    MeshFile {
        path: String,
        source: std::io::Error,
    },
    #[error("no frame set could be processed ({found} found{}{}){}", if reasons.is_empty() { "" } else { "; skipped for: " }, reasons.join(", "), why.as_ref().map_or(String::new(), |w| format!(": {w}")))]
    NothingProcessed {
        found: u64,
        reasons: Vec<String>,
        /// The first thing the sets lacked ([`crate::pipeline::Pipeline::why_no_depth`]).
        why: Option<String>,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Route {
    Image(usize),
    /// image_transport's `<image topic>/compressed` (`sensor_msgs/CompressedImage`).
    Compressed(usize),
    Info(usize),
    Tf,
    /// `/tf` (a moving rig, `world_frame`).
    TfDynamic,
}

fn expected_type(r: Route) -> &'static str {
    match r {
        Route::Image(_) => IMAGE,
        Route::Compressed(_) => COMPRESSED_IMAGE,
        Route::Info(_) => CAMERA_INFO,
        Route::Tf | Route::TfDynamic => TF_MESSAGE,
    }
}

/// Camera `i`'s image topic in the bag and its route: `<image topic>` (raw) or
/// `<image topic>/compressed`, the one `image_transport` names unless only the other is in
/// the bag with its type.
fn image_route(config: &PipelineConfig, known: &[TopicInfo], i: usize) -> (String, Route) {
    let raw = (config.image_topics[i].clone(), Route::Image(i));
    let compressed = (config.compressed_topics()[i].clone(), Route::Compressed(i));
    let in_bag = |(topic, route): &(String, Route)| {
        known
            .iter()
            .any(|t| &t.name == topic && t.msg_type == expected_type(*route))
    };
    let (first, second) = if config.compressed_inputs {
        (compressed, raw)
    } else {
        (raw, compressed)
    };
    if !in_bag(&first) && in_bag(&second) {
        second
    } else {
        first
    }
}

fn progress_bar(total: Option<u64>) -> ProgressBar {
    let bar = match total {
        Some(n) => ProgressBar::with_draw_target(Some(n), ProgressDrawTarget::stderr()),
        None => ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr()),
    };
    let style = if total.is_some() {
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} reference images, {msg} [{elapsed_precise}, ETA {eta}]",
        )
    } else {
        ProgressStyle::with_template("{spinner} {pos} reference images, {msg} [{elapsed_precise}]")
    };
    if let Ok(style) = style {
        bar.set_style(style);
    }
    bar
}

/// Runs `args` through the pipeline. Progress goes to stderr when it is a terminal; warnings
/// through `tracing`. Returns the report also when reading stopped at a damaged part of the
/// bag (then `read_errors` says where, and everything readable is in OUT).
pub fn process_bag(args: &BagArgs) -> Result<BagReport, BagRunError> {
    process_bag_viewing(args).map(|(report, _viewer)| report)
}

/// [`process_bag`], also returning the live view of `--view` (still serving the last set).
fn process_bag_viewing(args: &BagArgs) -> Result<(BagReport, Option<Viewer>), BagRunError> {
    let mut reader = BagReader::open(&args.input)?;
    let config = PipelineConfig::from_args(&args.ros_args())?;
    for note in &config.notes {
        tracing::info!("{note}");
    }
    writer::check_bag_output(&args.output, args.force, &[&args.input])?;
    check_fusion_early(&config, args)?;

    let known = reader.topics().to_vec();
    let (routes, image_topics) = routes(&config, &known);
    let mut report = BagReport::default();
    let wrong_type = check_topics(args, &known, &routes, &image_topics, &mut report)?;
    let ref_topic = &image_topics[config.reference()];
    let total = known
        .iter()
        .find(|t| &t.name == ref_topic)
        .and_then(|t| t.count);

    let mut host = EngineHost::new(config.device())?;
    tracing::info!("engine: {}", host.adapter_label());

    let mut writer = BagWriter::create(&args.output, args.force)?;
    for (_, outputs) in &config.references {
        for (spec, topic) in outputs.iter() {
            writer.add_topic(topic, spec.msg_type.schema_name(), None)?;
        }
    }
    let fusion = bag_fusion(&config, args);
    if let Some(f) = &fusion {
        if f.mesh_rate_hz > 0.0 {
            writer.add_topic(&config.mesh_topic, MARKER_ARRAY, None)?;
        }
    }

    let viewer = if args.view {
        Some(start_viewer(&config, fusion.as_ref())?)
    } else {
        None
    };
    let mut pacer = if args.view {
        Pacer::new(args.view_rate)
    } else {
        None
    };

    let fuser = match &fusion {
        Some(f) => Some(bag_fusion_sink(&config, f, &host)?),
        None => None,
    };
    // Only fusion reads the depths as floats: without `--mesh` the WGSL engine lends them out
    // of its readback and the messages written are copied from there.
    host.set_keep_floats(fuser.is_some());
    let mut pipeline = Pipeline::new(&config).map_err(ConfigError::from)?;
    let mut sink = Sink {
        config: &config,
        host,
        writer,
        report,
        seen: HashSet::new(),
        busy: Duration::ZERO,
        bar: progress_bar(total),
        viewer,
        fuser,
        sets_ahead: args.sets_ahead,
        log_times: VecDeque::new(),
    };
    let started = Instant::now();
    let mut last_log_ns = 0u64;
    // `reader` also answers inside the loop: the copied topics' recorded QoS.
    while let Some(item) = reader.next() {
        if interrupt::interrupted() {
            sink.report.interrupted = true;
            break;
        }
        let msg = match item {
            Ok(m) => m,
            Err(e) => {
                let e = e.to_string();
                sink.bar.suspend(|| tracing::error!("{e}"));
                sink.report.read_errors.push(e);
                continue;
            }
        };
        sink.report.messages += 1;
        last_log_ns = last_log_ns.max(msg.log_time_ns);
        if args.copy_inputs {
            let schema = known
                .iter()
                .find(|t| t.name == msg.topic)
                .and_then(|t| t.schema.as_deref());
            let qos = reader.offered_qos(&msg.topic);
            sink.writer
                .add_topic_with_qos(&msg.topic, &msg.msg_type, schema, qos)?;
            sink.writer
                .write(&msg.topic, msg.log_time_ns, msg.publish_time_ns, &msg.data)?;
        }
        let Some(&route) = routes.get(&msg.topic) else {
            continue;
        };
        if wrong_type.contains(&msg.topic) {
            sink.report.bad_messages.add(msg.topic.clone());
            continue;
        }
        if matches!(route, Route::Image(c) | Route::Compressed(c) if c == config.reference()) {
            sink.bar.inc(1);
        }
        if let Some(pacer) = &mut pacer {
            pacer.wait(msg.log_time_ns);
        }
        let input = decode_input(route, &msg);
        let input = match input {
            Ok(input) => input,
            Err(message) => {
                sink.bad_message(&msg.topic, &message);
                continue;
            }
        };
        sink.outcome(pipeline.push(input, msg.log_time_ns), msg.log_time_ns)?;
        if matches!(route, Route::Image(_) | Route::Compressed(_)) {
            let done = sink.report.sets_processed;
            let rate = done as f64 / started.elapsed().as_secs_f64().max(1e-9);
            sink.bar
                .set_message(format!("{done} sets, {rate:.2} sets/s"));
        }
    }
    if let Some(steps) = reader.log_times_back() {
        let note = super::report::log_times_back_note(&args.input, steps);
        sink.bar.suspend(|| tracing::warn!("{note}"));
    }
    // The sets the synchroniser held back waiting for later messages that never came (none
    // after Ctrl-C: the user wants out).
    if !sink.report.interrupted {
        sink.outcome(pipeline.finish(), last_log_ns)?;
    }
    sink.finish_all()?;
    // No depth at all: the first thing the sets lacked, as the live node says it.
    if sink.report.sets_processed == 0 {
        sink.report.no_depth = no_depth(&pipeline, last_log_ns, sink.report.last_skip.as_deref());
    }
    finish_outputs(sink, args, last_log_ns)
}

/// The run's end: the last markers, the bag (only when some set was processed: a run with
/// none fails, `run`, and leaves no bag: the writer's partial file goes with it, a bag that
/// `--force` would replace stays), then the mesh (after the bag: a mesh that cannot be
/// written loses no depth; none without a set).
fn finish_outputs(
    sink: Sink,
    args: &BagArgs,
    last_log_ns: u64,
) -> Result<(BagReport, Option<Viewer>), BagRunError> {
    let Sink {
        mut writer,
        mut report,
        busy,
        bar,
        viewer,
        mut fuser,
        ..
    } = sink;
    bar.finish_and_clear();
    if let Some(fusion) = &mut fuser {
        fusion.write_markers(&mut writer, viewer.as_ref(), last_log_ns, true)?;
    }
    if report.sets_processed > 0 {
        report.mean_time_per_set = Some(busy / report.sets_processed as u32);
        report.output = Some(writer.finish()?);
    }
    if let Some(mut fusion) = fuser {
        let mesh = args.mesh.as_deref().filter(|_| report.sets_processed > 0);
        report.mesh = Some(mesh_summary(&mut fusion, mesh)?);
    }
    Ok((report, viewer))
}

/// Which of the bag's topics go where (every camera's image topic, raw or compressed, its
/// camera_info, `/tf_static` and `/tf` as the configuration reads them), and each camera's image
/// topic.
fn routes(config: &PipelineConfig, known: &[TopicInfo]) -> (HashMap<String, Route>, Vec<String>) {
    let mut routes: HashMap<String, Route> = HashMap::new();
    // Per camera, the image topic read: raw or image_transport's compressed one.
    let mut image_topics = Vec::with_capacity(config.cameras.len());
    for i in 0..config.cameras.len() {
        let (topic, route) = image_route(config, known, i);
        routes.insert(topic.clone(), route);
        image_topics.push(topic);
        routes.insert(config.info_topics[i].clone(), Route::Info(i));
    }
    if config.rig_file.is_none() || config.world.is_some() {
        routes.insert(config.tf_static_topic.clone(), Route::Tf);
    }
    if let Some(world) = &config.world {
        routes.insert(world.tf_topic.clone(), Route::TfDynamic);
    }
    (routes, image_topics)
}

/// The topics of the bag against `routes`: those of another type than the pipeline reads
/// (returned; their messages are left out, loudly), those it does not read (in `report`), and
/// an error when no camera's image topic is there at all.
fn check_topics(
    args: &BagArgs,
    known: &[TopicInfo],
    routes: &HashMap<String, Route>,
    image_topics: &[String],
    report: &mut BagReport,
) -> Result<HashSet<String>, BagRunError> {
    // Topics with a type other than the one the pipeline reads are left out, loudly.
    let mut wrong_type: HashSet<String> = HashSet::new();
    for t in known {
        match routes.get(&t.name) {
            Some(&r) if !t.msg_type.is_empty() && t.msg_type != expected_type(r) => {
                tracing::error!(
                "topic {} has type {} in the bag, but the node reads {} there; its messages are ignored",
                t.name,
                t.msg_type,
                expected_type(r)
            );
                wrong_type.insert(t.name.clone());
            }
            Some(&r) if !t.encoding.is_empty() && t.encoding != "cdr" => {
                tracing::error!(
                    "topic {} has message encoding '{}' in the bag, but the node reads ROS 2's 'cdr' {} there; its messages are ignored",
                    t.name,
                    t.encoding,
                    expected_type(r)
                );
                wrong_type.insert(t.name.clone());
            }
            Some(_) => {}
            None => report.ignored_topics.push(t.name.clone()),
        }
    }
    if !known.is_empty() {
        let missing: Vec<&String> = image_topics
            .iter()
            .filter(|t| !known.iter().any(|k| &k.name == *t) || wrong_type.contains(*t))
            .collect();
        if missing.len() == image_topics.len() {
            return Err(BagRunError::NoInput {
                bag: args.input.display().to_string(),
                wanted: image_topics.to_vec(),
                found: known
                    .iter()
                    .map(|t| format!("{} ({})", t.name, t.msg_type))
                    .collect(),
            });
        }
        for m in missing {
            tracing::warn!("image topic {m} is not in the bag; sets need every camera");
        }
    }
    Ok(wrong_type)
}

/// What would fail fusion only after the whole bag, refused before it: its parameters, and a
/// `--mesh` file in a folder that does not exist.
fn check_fusion_early(config: &PipelineConfig, args: &BagArgs) -> Result<(), BagRunError> {
    if let Some(v) = args.voxel_size {
        if !(0.001..=10.0).contains(&v) {
            return Err(BagRunError::VoxelSize(v));
        }
    }
    if let Some(fusion) = bag_fusion(config, args) {
        fusion.params.validate()?;
    }
    if let Some(mesh) = &args.mesh {
        let folder = mesh
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(std::path::Path::new("."));
        if !folder.is_dir() || mesh.is_dir() {
            return Err(BagRunError::MeshFile {
                path: mesh.display().to_string(),
                source: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    if mesh.is_dir() {
                        "a folder, not a file name".to_string()
                    } else {
                        format!("no folder {}", folder.display())
                    },
                ),
            });
        }
        check_mesh_target(mesh, args)?;
    }
    Ok(())
}

/// `--mesh FILE` may not be the input bag or OUT (nor inside them), and replaces an existing
/// file only with `--force`, and only a PLY.
fn check_mesh_target(mesh: &std::path::Path, args: &BagArgs) -> Result<(), BagRunError> {
    // A path with its folder resolved (the file itself need not exist).
    let resolved = |p: &std::path::Path| -> Option<std::path::PathBuf> {
        let folder = p.parent().filter(|f| !f.as_os_str().is_empty());
        let folder = folder.unwrap_or(std::path::Path::new("."));
        Some(folder.canonicalize().ok()?.join(p.file_name()?))
    };
    let refuse = |why: String| {
        Err(BagRunError::MeshFile {
            path: mesh.display().to_string(),
            source: std::io::Error::new(std::io::ErrorKind::AlreadyExists, why),
        })
    };
    if let Some(target) = resolved(mesh) {
        for (what, other) in [("the input bag", &args.input), ("OUT", &args.output)] {
            if resolved(other).is_some_and(|o| target.starts_with(&o)) {
                return refuse(format!("it is {what} ({})", other.display()));
            }
        }
    }
    if mesh.exists() {
        let mut magic = [0u8; 4];
        let is_ply = std::fs::File::open(mesh)
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
            .is_ok()
            && &magic == b"ply\n";
        if !is_ply {
            return refuse("the file exists and is not a PLY: not replaced".into());
        }
        if !args.force {
            return refuse("the file exists (pass --force to replace it)".into());
        }
    }
    Ok(())
}

/// Fusion: the `fusion` parameter (its voxel size and mesh rate) or `--mesh` (with
/// `--voxel-size`); the markers go into OUT on `mesh` at the mesh rate in log time.
fn bag_fusion(config: &PipelineConfig, args: &BagArgs) -> Option<crate::pipeline::FusionConfig> {
    // `--voxel-size` wins over the `voxel_size` parameter; `--mesh` alone takes the fusion
    // parameters (`voxel_size`, `max_blocks`, `fusion_device`) with markers once a second.
    let voxel = |f: &crate::pipeline::FusionConfig| crate::pipeline::FusionConfig {
        params: FusionParams {
            voxel_size_m: args.voxel_size.unwrap_or(f.params.voxel_size_m),
            ..f.params
        },
        ..f.clone()
    };
    match (&config.fusion, &args.mesh) {
        (Some(f), _) => Some(voxel(f)),
        (None, Some(_)) => {
            let (min, max) = (config.sweep.min_depth_m, config.sweep.max_depth_m);
            let mut f = match crate::pipeline::FusionConfig::new(&config.node, min, max) {
                Ok(f) => f,
                // Checked again (and said) by `check_fusion_early`.
                Err(_) => crate::pipeline::FusionConfig {
                    params: FusionParams {
                        min_depth_m: min as f32,
                        max_depth_m: max as f32,
                        ..FusionParams::default()
                    },
                    mesh_rate_hz: 1.0,
                    device: Default::default(),
                },
            };
            f.mesh_rate_hz = 1.0;
            Some(voxel(&f))
        }
        (None, None) => None,
    }
}

/// The fuser, on a GPU as `fusion_device` decides beside the engine (`fusion::GpuTsdf`), and
/// whether that is the engine's device.
/// The bag's fusion as its sink runs it: the fuser, and when its markers go into OUT.
fn bag_fusion_sink(
    config: &PipelineConfig,
    fusion: &crate::pipeline::FusionConfig,
    host: &EngineHost,
) -> Result<BagFusion, BagRunError> {
    let (fuser, follows_engine) = bag_fuser(fusion, host)?;
    Ok(BagFusion {
        fuser,
        follows_engine,
        devices_seen: host.recreated,
        topic: config.mesh_topic.clone(),
        period_ns: (fusion.mesh_rate_hz > 0.0).then(|| (1e9 / fusion.mesh_rate_hz) as u64),
        next_ns: 0,
    })
}

fn bag_fuser(
    fusion: &crate::pipeline::FusionConfig,
    host: &EngineHost,
) -> Result<(Fuser, bool), BagRunError> {
    let placement = fusion_gpu(fusion.device, FusionHost::Engine(host.gpu()))
        .map_err(|e| HostError::Engine(e.into()))?;
    tracing::info!("fusion {}", placement.label());
    let fuser = Fuser::on(fusion.params, placement.gpu.as_ref())?;
    Ok((fuser, placement.engine_device))
}

/// A bag message on a topic routed to `route`, as the pipeline's input (or why it does not
/// decode).
fn decode_input(route: Route, msg: &super::reader::BagMessage) -> Result<Input, String> {
    let position = || format!("{} at log time {} ns", msg.topic, msg.log_time_ns);
    match route {
        Route::Info(camera) => from_cdr::<CameraInfo>(&msg.data)
            .map(|info| Input::CameraInfo {
                camera,
                info: Box::new(info),
            })
            .map_err(|e| format!("cannot decode CameraInfo on {}: {e}", position())),
        Route::Tf => from_cdr::<TFMessage>(&msg.data)
            .map(Input::TfStatic)
            .map_err(|e| format!("cannot decode TFMessage on {}: {e}", position())),
        Route::TfDynamic => from_cdr::<TFMessage>(&msg.data)
            .map(Input::Tf)
            .map_err(|e| format!("cannot decode TFMessage on {}: {e}", position())),
        Route::Image(camera) => from_cdr::<Image>(&msg.data)
            .map(|image| Input::Image { camera, image })
            .map_err(|e| format!("cannot decode Image on {}: {e}", position())),
        // Decoded (in parallel) when its set is complete.
        Route::Compressed(camera) => from_cdr::<CompressedImage>(&msg.data)
            .map(|image| Input::compressed(camera, image))
            .map_err(|e| format!("cannot decode CompressedImage on {}: {e}", position())),
    }
}

/// What fusion made of the bag: the PLY written to `mesh_path` (or the markers' topic) and the
/// grid.
fn mesh_summary(
    fusion: &mut BagFusion,
    mesh_path: Option<&std::path::Path>,
) -> Result<String, BagRunError> {
    let fuser = &mut fusion.fuser;
    let (blocks, bytes) = fuser.blocks();
    let on = match (fuser.is_on_gpu(), fuser.left_gpu()) {
        (true, _) => " on the GPU".to_string(),
        (false, None) => String::new(),
        (false, Some(reason)) => format!(" (on the CPU after leaving the GPU: {reason})"),
    };
    // Blocks dropped by `max_blocks` take their part of the surface with them: said.
    let dropped = match fuser.blocks_dropped {
        0 => String::new(),
        n => format!(
            "; {n} blocks dropped at max_blocks {} (the farthest from the camera: raise it, or \
             a coarser voxel, for the whole scene)",
            fuser.params().max_blocks
        ),
    };
    let grid = format!(
        "{blocks} blocks of 8^3 voxels of {} m, {:.1} MiB{dropped}",
        fuser.params().voxel_size_m,
        bytes as f64 / (1 << 20) as f64
    );
    Ok(match mesh_path {
        Some(path) => {
            let saved = fuser.save(path).map_err(|source| BagRunError::MeshFile {
                path: path.display().to_string(),
                source,
            })?;
            let empty = if saved.triangles == 0 && fuser.integrated > 0 && dropped.is_empty() {
                format!(
                    "; no surface came out of {} depth maps: a voxel of {} m may be too coarse \
                     for the scene (try --voxel-size near a hundredth of its depth)",
                    fuser.integrated,
                    fuser.params().voxel_size_m
                )
            } else {
                String::new()
            };
            format!(
                "{} depth maps fused{on} into {} ({} triangles, {} vertices; {grid}){empty}",
                fuser.integrated,
                path.display(),
                saved.triangles,
                saved.vertices,
            )
        }
        None => format!(
            "{} depth maps fused{on} ({} triangles on {}; {grid})",
            fuser.integrated,
            fuser.triangles(),
            fusion.topic,
        ),
    })
}

/// `--view`: the live view of the bag's outputs (and, with fusion's markers, the mesh on its
/// own channel).
fn start_viewer(
    config: &PipelineConfig,
    fusion: Option<&crate::pipeline::FusionConfig>,
) -> Result<Viewer, BagRunError> {
    // With fusion (and markers), the mesh on its own channel.
    let mesh_topic = fusion
        .filter(|f| f.mesh_rate_hz > 0.0)
        .map(|_| config.mesh_topic.as_str());
    let viewer = Viewer::start_with_mesh(
        &ViewerConfig::for_bag(&config.node)?,
        config.outputs(),
        mesh_topic,
    )?;
    tracing::info!(
        "live view: Foxglove/Lichtblick at {}, the page at {}",
        viewer.websocket_url(),
        viewer.page_url()
    );
    Ok(viewer)
}

/// Why a bag gave no depth: the first thing its sets lacked (as the live node says it), else
/// the last skip.
fn no_depth(pipeline: &Pipeline, last_log_ns: u64, last_skip: Option<&str>) -> Option<String> {
    let asked = Asked {
        now_ns: last_log_ns,
        window_ns: None,
    };
    pipeline
        .why_no_depth(asked, &|_| Publishers::Unknown)
        .map(|why| why.message)
        .or_else(|| last_skip.map(|s| format!("sets are skipped: {s}")))
}

/// The `bag` subcommand: prints the summary; fails when the bag is damaged (with `--strict`,
/// or when nothing could be read) or nothing usable was in it.
pub fn run(args: &BagArgs) -> Result<(), BagRunError> {
    let interrupts = interrupt::handle_interrupts();
    let (report, viewer) = process_bag_viewing(args)?;
    eprintln!("{}", report.summary_line());
    if let Some(mesh) = &report.mesh {
        eprintln!("mesh: {mesh}");
    }
    if report.interrupted {
        return Err(BagRunError::Interrupted {
            sets: report.sets_processed,
            output: args.output.display().to_string(),
            mesh: (args.mesh.as_ref())
                .filter(|_| report.sets_processed > 0)
                .map(|m| m.display().to_string()),
        });
    }
    if let Some(viewer) = viewer {
        interrupt::hold_view(&viewer, interrupts);
    }
    if !report.ignored_topics.is_empty() {
        tracing::info!("topics not read: {}", report.ignored_topics.join(", "));
    }
    if let Some(first) = report.read_errors.first() {
        let damaged = BagRunError::Damaged {
            count: report.read_errors.len(),
            first: first.clone(),
            sets: report.sets_processed,
            output: args.output.display().to_string(),
        };
        if args.strict || report.sets_processed == 0 {
            return Err(damaged);
        }
        tracing::warn!("{damaged}");
    }
    if report.sets_processed == 0 {
        return Err(BagRunError::NothingProcessed {
            found: report.sets_found,
            reasons: report.skipped.keys().map(|k| k.to_string()).collect(),
            why: report.no_depth.clone(),
        });
    }
    Ok(())
}
