//! `sweepdepth pack DIR OUT`: a dataset folder (any layout `eval` reads, see
//! [`crate::datasets`]), or a folder of images plus a rig file, into a bag with
//! `/camN/image_raw` (rgb8; with `--compressed` `/camN/image_raw/compressed`, JPEG),
//! `/camN/camera_info` and `/tf_static`, and a parameter file for the node next to it
//! (`<OUT without .mcap>.params.yaml`).

use std::path::{Path, PathBuf};

use crate::datasets::{load_dataset, Layout};
use crate::geometry::{CameraModel, Distortion, RigCamera, RigidTransform};
use crate::image::Rgba8Image;
use crate::msgs::{
    CameraInfo, Header, Image, Quaternion, TFMessage, Transform, TransformStamped, Vector3,
};
use crate::rig_file::load_rig_file;

use super::schemas::{CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, TF_MESSAGE};
use super::{ns_time, writer, BagError, BagWriter};
use crate::pipeline::compressed::{compress, Codec};

/// `sweepdepth pack` arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct PackArgs {
    /// A dataset folder (Middlebury 2001/2003/2005-6, Middlebury multi-view ring, ICL-NUIM, a
    /// rectified pair as Middlebury 2014 / ETH3D give it: im0.png, im1.png, calib.txt), or a
    /// folder of images plus a rig file (`rig.yaml`, or --rig).
    pub dir: PathBuf,
    /// Output: a `.mcap` file when the name ends in .mcap, else a rosbag2 directory.
    pub output: PathBuf,
    /// Rig file (our YAML or a Kalibr camchain) for a folder of images: images are
    /// `<camera>.<png|jpg|ppm>`, or a folder `<camera>/` of frames in name order.
    #[arg(long, value_name = "FILE")]
    pub rig: Option<PathBuf>,
    /// Frame sets to write; a dataset of still images repeats its one set.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Frame rate of the stamps, Hz.
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    /// Scale the images (and the intrinsics) by this factor, e.g. 0.5 for small fixtures.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// Stamp of the first set, seconds since the epoch.
    #[arg(long, default_value_t = 1_700_000_000.0)]
    pub start: f64,
    /// Keep only this many cameras: the reference and the ones nearest to it in the dataset's
    /// order (0 = all).
    #[arg(long, default_value_t = 0)]
    pub cameras: usize,
    /// Replace OUT (and the parameter file) if they exist.
    #[arg(long)]
    pub force: bool,
    /// Images as recorded bags usually have them: `sensor_msgs/CompressedImage` on
    /// `/camN/image_raw/compressed`, JPEG of quality 95 (image_transport's compressed plugin).
    #[arg(long)]
    pub compressed: bool,
}

/// Errors of `pack`.
#[derive(Debug, thiserror::Error)]
pub enum PackError {
    #[error(transparent)]
    Bag(#[from] BagError),
    #[error(transparent)]
    Dataset(#[from] crate::datasets::DatasetError),
    #[error(transparent)]
    RigFile(#[from] crate::rig_file::RigFileError),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error("--compressed: {0}")]
    Encode(#[from] crate::pipeline::compressed::EncodeError),
    /// Arguments or inputs that do not fit together, with the reason.
    #[error("{0}")]
    Invalid(String),
}

/// One camera of the bag: its name, model, pose and the frames (images) it contributes.
struct PackCamera {
    name: String,
    model: CameraModel,
    cam_from_rig: RigidTransform,
    frames: Vec<Rgba8Image>,
}

/// What was packed.
#[derive(Debug, Clone, PartialEq)]
pub struct PackReport {
    pub cameras: Vec<String>,
    pub reference: String,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    pub params_file: PathBuf,
    pub messages: u64,
    /// No depth range came with the input: the parameter file holds the node's defaults.
    pub default_depth: bool,
}

/// The parameter file written beside `out`.
pub fn params_path(out: &Path) -> PathBuf {
    let name = out
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("bag")
        .trim_end_matches(".mcap")
        .to_string();
    out.with_file_name(format!("{name}.params.yaml"))
}

fn camera_info(model: &CameraModel, header: &Header) -> CameraInfo {
    let k = &model.intrinsics;
    let (distortion_model, d) = match model.distortion {
        Distortion::None => ("plumb_bob", vec![0.0; 5]),
        Distortion::PlumbBob { k1, k2, p1, p2, k3 } => ("plumb_bob", vec![k1, k2, p1, p2, k3]),
        Distortion::Equidistant { k1, k2, k3, k4 } => ("equidistant", vec![k1, k2, k3, k4]),
    };
    CameraInfo {
        header: header.clone(),
        width: k.width_px,
        height: k.height_px,
        distortion_model: distortion_model.into(),
        d,
        k: [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

fn rgb8_image(image: &Rgba8Image, header: &Header) -> Image {
    let mut data = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        let [r, g, b, _] = Rgba8Image::unpack(p);
        data.extend_from_slice(&[r, g, b]);
    }
    Image {
        header: header.clone(),
        height: image.height,
        width: image.width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: image.width * 3,
        data,
    }
}

fn scale_image(image: &Rgba8Image, width: u32, height: u32) -> Rgba8Image {
    if image.width == width && image.height == height {
        return image.clone();
    }
    let rgb = image.to_rgb_image();
    let resized =
        image::imageops::resize(&rgb, width, height, image::imageops::FilterType::Triangle);
    Rgba8Image::from_image(&image::DynamicImage::ImageRgb8(resized))
}

fn frame_id(camera: &str) -> String {
    format!("{camera}_optical_frame")
}

/// Cameras from a dataset folder (one frame each).
/// Cameras, the reference index, a description of the source, and the depth range and plane
/// count when the source knows them.
type Packed = (Vec<PackCamera>, usize, String, Option<(f64, f64, u32)>);

/// The frame `/tf_static` poses the cameras in: the rig file's `rig_frame` (Kalibr: `cam0`),
/// `rig` for a dataset.
const DATASET_RIG_FRAME: &str = "rig";

fn dataset_cameras(dir: &Path) -> Result<Packed, PackError> {
    let dataset = load_dataset(dir).map_err(|e| match e {
        crate::datasets::DatasetError::UnknownLayout { .. } => PackError::Invalid(format!(
            "{e}; or images of your own cameras: give their poses in a rig file, `rig.yaml` in \
             the folder or --rig FILE (our YAML or a Kalibr camchain; launch_configs/README.md)"
        )),
        e => e.into(),
    })?;
    let reference = dataset.reference_index();
    let cameras = dataset
        .rig
        .cameras
        .iter()
        .zip(&dataset.images)
        .enumerate()
        .map(
            |(i, (c, img)): (usize, (&RigCamera, &Rgba8Image))| PackCamera {
                name: format!("cam{i}"),
                model: c.model,
                cam_from_rig: c.cam_from_rig,
                frames: vec![img.clone()],
            },
        )
        .collect();
    let p = &dataset.params;
    let note = format!("{} ({})", dataset.name, layout_name(dataset.layout));
    Ok((
        cameras,
        reference,
        note,
        Some((p.min_depth_m, p.max_depth_m, p.num_planes)),
    ))
}

fn layout_name(layout: Layout) -> &'static str {
    layout.name()
}

const IMAGE_EXTS: [&str; 5] = ["png", "jpg", "jpeg", "ppm", "pgm"];

fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Cameras from a folder of images and a rig file.
fn rig_folder_cameras(
    dir: &Path,
    rig: &Path,
) -> Result<(Vec<PackCamera>, usize, String, String), PackError> {
    let file = load_rig_file(rig)?;
    // What the node would log on loading it (ignored Kalibr keys, topic order).
    for note in &file.notes {
        tracing::warn!("{note}");
    }
    let mut cameras = Vec::new();
    for c in &file.cameras {
        let model = c.model.ok_or_else(|| {
            PackError::Invalid(format!(
                "{}: camera '{}' has no intrinsics; pack needs them in the rig file",
                rig.display(),
                c.name
            ))
        })?;
        let mut paths: Vec<PathBuf> = Vec::new();
        let sub = dir.join(&c.name);
        if sub.is_dir() {
            let entries = std::fs::read_dir(&sub).map_err(|e| BagError::io(&sub, e))?;
            for entry in entries {
                let p = entry.map_err(|e| BagError::io(&sub, e))?.path();
                if is_image(&p) {
                    paths.push(p);
                }
            }
            // frame_2 before frame_10, as a recorder numbers them.
            paths.sort_by_key(|p| super::reader::natural_key(p));
        } else if let Some(p) = IMAGE_EXTS
            .iter()
            .map(|e| dir.join(format!("{}.{e}", c.name)))
            .find(|p| p.is_file())
        {
            paths.push(p);
        }
        // The camera's topics carry its name: a ROS name, or `bag` refuses the parameter file.
        crate::ros::args::validate_topic_name(&format!("/{}/image_raw", c.name)).map_err(|e| {
            PackError::Invalid(format!(
                "{}: camera name '{}' cannot name ROS topics: {e}",
                rig.display(),
                c.name
            ))
        })?;
        if paths.is_empty() {
            return Err(PackError::Invalid(format!(
                "{}: no image for camera '{}' (expected {}.png or a folder {}/ of frames)",
                dir.display(),
                c.name,
                c.name,
                c.name
            )));
        }
        let mut frames = Vec::new();
        for p in paths {
            let img = crate::io::load_rgba8(&p)?;
            let k = &model.intrinsics;
            if img.width != k.width_px || img.height != k.height_px {
                return Err(PackError::Invalid(format!(
                    "{}: {}x{} but the rig file says camera '{}' is {}x{}",
                    p.display(),
                    img.width,
                    img.height,
                    c.name,
                    k.width_px,
                    k.height_px
                )));
            }
            frames.push(img);
        }
        cameras.push(PackCamera {
            name: c.name.clone(),
            model,
            cam_from_rig: c.cam_from_rig,
            frames,
        });
    }
    if cameras.len() < 2 {
        return Err(PackError::Invalid(format!(
            "{}: a rig needs at least 2 cameras",
            rig.display()
        )));
    }
    // A sequence: every camera with its folder of frames, as many each (a camera with one
    // image repeats it).
    let counts: Vec<(usize, &str)> = cameras
        .iter()
        .map(|c| (c.frames.len(), c.name.as_str()))
        .filter(|(n, _)| *n > 1)
        .collect();
    if let (Some(&(most, a)), Some(&(least, b))) = (
        counts.iter().max_by_key(|(n, _)| *n),
        counts.iter().min_by_key(|(n, _)| *n),
    ) {
        if most != least {
            return Err(PackError::Invalid(format!(
                "{}: camera '{a}' has {most} frames but '{b}' has {least}: a sequence needs as \
                 many frames from every camera (frame k of each camera makes set k)",
                dir.display()
            )));
        }
    }
    // As the node's default (`NodeValues::reference_camera`): a pair's first camera.
    let reference = cameras.len().saturating_sub(1) / 2;
    Ok((
        cameras,
        reference,
        format!("images of {}", rig.display()),
        file.rig_frame,
    ))
}

/// ROS expects positive focal lengths (and our CameraInfo checks refuse others), but some
/// datasets (ICL-NUIM: fy < 0) describe a mirrored image. Mirroring the image back along that
/// axis with `c' = size - 1 - c` gives the same rays from the same pose with a positive focal
/// length.
fn make_focal_positive(c: &mut PackCamera) -> Result<(), PackError> {
    let k = c.model.intrinsics;
    if k.fx_px >= 0.0 && k.fy_px >= 0.0 {
        return Ok(());
    }
    if !c.model.distortion.is_none() {
        return Err(PackError::Invalid(format!(
            "camera '{}': a negative focal length with lens distortion cannot be normalised",
            c.name
        )));
    }
    let (flip_x, flip_y) = (k.fx_px < 0.0, k.fy_px < 0.0);
    let k2 = &mut c.model.intrinsics;
    if flip_x {
        k2.fx_px = -k.fx_px;
        k2.cx_px = f64::from(k.width_px) - 1.0 - k.cx_px;
    }
    if flip_y {
        k2.fy_px = -k.fy_px;
        k2.cy_px = f64::from(k.height_px) - 1.0 - k.cy_px;
    }
    for f in &mut c.frames {
        let (w, h) = (f.width as usize, f.height as usize);
        let src = f.pixels.clone();
        for y in 0..h {
            for x in 0..w {
                let sx = if flip_x { w - 1 - x } else { x };
                let sy = if flip_y { h - 1 - y } else { y };
                f.pixels[y * w + x] = src[sy * w + sx];
            }
        }
    }
    Ok(())
}

/// The reference and the `keep - 1` cameras nearest to it in order (ties: the earlier one).
fn keep_nearest(
    cameras: Vec<PackCamera>,
    reference: usize,
    keep: usize,
) -> Result<(Vec<PackCamera>, usize), PackError> {
    if keep == 0 || keep >= cameras.len() {
        return Ok((cameras, reference));
    }
    if keep < 2 {
        return Err(PackError::Invalid(
            "--cameras must be 0 (all) or at least 2".into(),
        ));
    }
    let mut order: Vec<usize> = (0..cameras.len()).collect();
    order.sort_by_key(|&i| (i.abs_diff(reference), i));
    let mut chosen: Vec<usize> = order.into_iter().take(keep).collect();
    chosen.sort_unstable();
    let new_reference = chosen.iter().position(|&i| i == reference).unwrap_or(0);
    let kept = cameras
        .into_iter()
        .enumerate()
        .filter(|(i, _)| chosen.contains(i))
        .map(|(_, c)| c)
        .collect();
    Ok((kept, new_reference))
}

/// Packs `args.dir` into `args.output`.
pub fn pack(args: &PackArgs) -> Result<PackReport, PackError> {
    check_args(args)?;
    let params_file = params_path(&args.output);
    let rig = args
        .rig
        .clone()
        .or_else(|| Some(args.dir.join("rig.yaml")).filter(|p| p.is_file()));
    let mut inputs = vec![args.dir.as_path()];
    inputs.extend(rig.as_deref());
    writer::check_bag_output(&args.output, args.force, &inputs)?;
    writer::check_output(&params_file, args.force)?;
    let (cameras, reference, source, depth, rig_frame) = match &rig {
        Some(rig) => {
            let (c, r, s, frame) = rig_folder_cameras(&args.dir, rig)?;
            (c, r, s, None, frame)
        }
        None => {
            let (c, r, s, d) = dataset_cameras(&args.dir)?;
            (c, r, s, d, DATASET_RIG_FRAME.to_string())
        }
    };
    let (mut cameras, reference) = keep_nearest(cameras, reference, args.cameras)?;
    for c in &mut cameras {
        make_focal_positive(c)?;
    }
    for (i, c) in cameras.iter_mut().enumerate() {
        if rig.is_none() {
            c.name = format!("cam{i}");
        }
        let k = c.model.intrinsics;
        let w = ((f64::from(k.width_px) * args.scale).round() as u32).max(1);
        let h = ((f64::from(k.height_px) * args.scale).round() as u32).max(1);
        c.model.intrinsics = k.scaled(f64::from(w) / f64::from(k.width_px), w, h);
        for f in &mut c.frames {
            *f = scale_image(f, w, h);
        }
    }

    check_rig_frame(&cameras, &rig_frame)?;
    warn_sequence_frames(&cameras, args);
    let mut writer = BagWriter::create(&args.output, args.force)?;
    let (image_topic, image_type) = if args.compressed {
        ("image_raw/compressed", COMPRESSED_IMAGE)
    } else {
        ("image_raw", IMAGE)
    };
    for c in &cameras {
        writer.add_topic(&format!("/{}/{image_topic}", c.name), image_type, None)?;
        writer.add_topic(&format!("/{}/camera_info", c.name), CAMERA_INFO, None)?;
    }
    writer.add_topic("/tf_static", TF_MESSAGE, None)?;
    let start_ns = (args.start * 1e9).round() as u64;
    let period_ns = (1e9 / args.rate_hz).round() as u64;
    let tf = static_transforms(&cameras, &rig_frame, start_ns);
    writer.write_msg("/tf_static", start_ns.saturating_sub(1_000_000), &tf)?;
    for k in 0..u64::from(args.frames) {
        let stamp_ns = start_ns + k * period_ns;
        for (i, c) in cameras.iter().enumerate() {
            let header = Header {
                stamp: ns_time(stamp_ns),
                frame_id: frame_id(&c.name),
            };
            // Receive times a few microseconds apart, camera_info before its image.
            let log = stamp_ns + 1_000 * i as u64;
            writer.write_msg(
                &format!("/{}/camera_info", c.name),
                log,
                &camera_info(&c.model, &header),
            )?;
            let frame = &c.frames[(k as usize) % c.frames.len()];
            let topic = format!("/{}/{image_topic}", c.name);
            let image = rgb8_image(frame, &header);
            if args.compressed {
                let jpeg = compress(&image, Codec::Jpeg, 95)?;
                writer.write_msg(&topic, log + 500, &jpeg)?;
            } else {
                writer.write_msg(&topic, log + 500, &image)?;
            }
        }
    }
    let summary = writer.finish()?;

    let names: Vec<String> = cameras.iter().map(|c| c.name.clone()).collect();
    let mut yaml = format!(
        "# Written by `sweepdepth pack` for {} from {source}.\n# Use: sweepdepth bag {} OUT --params-file {}\n/**:\n  ros__parameters:\n    cameras: [{}]\n    reference_camera: {}\n",
        args.output.display(),
        args.output.display(),
        params_file.display(),
        names.join(", "),
        names[reference],
    );
    match depth {
        Some((min, max, planes)) => {
            yaml += &format!(
                "    min_depth: {}\n    max_depth: {}\n    num_planes: {planes}\n",
                crate::geometry::metres(min),
                crate::geometry::metres(max)
            );
        }
        None => {
            let d = crate::sweep::SweepParams::default();
            yaml += &format!(
                "    # No depth range came with the images: the node's defaults. Set your scene's\n    # nearest and farthest depth (metres) and the planes between them.\n    min_depth: {}\n    max_depth: {}\n    num_planes: {}\n",
                crate::geometry::metres(d.min_depth_m),
                crate::geometry::metres(d.max_depth_m),
                d.num_planes
            );
        }
    }
    std::fs::write(&params_file, yaml).map_err(|e| BagError::io(&params_file, e))?;
    let k = cameras[reference].model.intrinsics;
    Ok(PackReport {
        reference: names[reference].clone(),
        cameras: names,
        frames: args.frames,
        width: k.width_px,
        height: k.height_px,
        params_file,
        messages: summary.messages,
        default_depth: depth.is_none(),
    })
}

/// The `pack` subcommand.
pub fn run(args: &PackArgs) -> Result<(), PackError> {
    let report = pack(args)?;
    eprintln!(
        "pack: {} cameras [{}] ({}x{} reference {}), {} frame sets, {} messages to {}; parameters in {}",
        report.cameras.len(),
        report.cameras.join(", "),
        report.width,
        report.height,
        report.reference,
        report.frames,
        report.messages,
        args.output.display(),
        report.params_file.display()
    );
    if report.default_depth {
        let d = crate::sweep::SweepParams::default();
        eprintln!(
            "pack: no depth range came with the images: {} sweeps the node's defaults ({}-{} m, {} planes); set min_depth, max_depth and num_planes there to your scene's",
            report.params_file.display(),
            d.min_depth_m,
            d.max_depth_m,
            d.num_planes
        );
    }
    Ok(())
}

/// The cameras' poses in `rig_frame` as `/tf_static` holds them, stamped `start_ns`.
fn static_transforms(cameras: &[PackCamera], rig_frame: &str, start_ns: u64) -> TFMessage {
    TFMessage {
        transforms: cameras
            .iter()
            // A camera whose optical frame is the rig frame itself has no transform of its own
            // (one to itself would be refused by tf2); `check_rig_frame` made sure it is at the
            // origin.
            .filter(|c| frame_id(&c.name) != rig_frame)
            .map(|c| {
                let rig_from_cam = c.cam_from_rig.inverse();
                let (t, q) = (rig_from_cam.translation, rig_from_cam.rotation);
                TransformStamped {
                    header: Header {
                        stamp: ns_time(start_ns),
                        frame_id: rig_frame.to_string(),
                    },
                    child_frame_id: frame_id(&c.name),
                    transform: Transform {
                        translation: Vector3 {
                            x: t.x,
                            y: t.y,
                            z: t.z,
                        },
                        rotation: Quaternion {
                            x: q.x,
                            y: q.y,
                            z: q.z,
                            w: q.w,
                        },
                    },
                }
            })
            .collect(),
    }
}

/// A rig frame that is one of the cameras' optical frames (`cam0_optical_frame`) is that
/// camera's pose: it must be at the origin, unrotated.
fn check_rig_frame(cameras: &[PackCamera], rig_frame: &str) -> Result<(), PackError> {
    let Some(c) = cameras.iter().find(|c| frame_id(&c.name) == rig_frame) else {
        return Ok(());
    };
    let pose = c.cam_from_rig;
    let moved = pose.translation.length() > 1e-9 || pose.rotation.w.abs() < 1.0 - 1e-12;
    if moved {
        return Err(PackError::Invalid(format!(
            "rig_frame '{rig_frame}' is camera '{}''s optical frame, but the rig file does not put              that camera at the rig frame's origin unrotated; name the rig frame otherwise (e.g.              `rig`)",
            c.name
        )));
    }
    Ok(())
}

/// `pack`'s numeric options in their ranges.
fn check_args(args: &PackArgs) -> Result<(), PackError> {
    if !(args.scale > 0.0 && args.scale <= 4.0) {
        return Err(PackError::Invalid(format!(
            "--scale must be in (0, 4], got {}",
            args.scale
        )));
    }
    if !(args.rate_hz > 0.0 && args.rate_hz.is_finite()) {
        return Err(PackError::Invalid(format!(
            "--rate-hz must be > 0, got {}",
            args.rate_hz
        )));
    }
    if args.frames == 0 {
        return Err(PackError::Invalid("--frames must be at least 1".into()));
    }
    if !(args.start >= 0.0 && args.start < 2.0e9) {
        return Err(PackError::Invalid(format!(
            "--start must be in [0, 2e9) s, got {}",
            args.start
        )));
    }
    Ok(())
}

/// A sequence packed short or repeated (`--frames` other than its length) is said.
fn warn_sequence_frames(cameras: &[PackCamera], args: &PackArgs) {
    let sequence = cameras.iter().map(|c| c.frames.len()).max().unwrap_or(1);
    if sequence > 1 && args.frames as usize != sequence {
        tracing::warn!(
            "{}: a sequence of {sequence} frames per camera; --frames {} packs {}",
            args.dir.display(),
            args.frames,
            if (args.frames as usize) < sequence {
                format!("its first {} (--frames {sequence} for all)", args.frames)
            } else {
                format!(
                    "it {:.1} times over, from the start",
                    f64::from(args.frames) / sequence as f64
                )
            }
        );
    }
}
