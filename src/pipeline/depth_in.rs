//! Depth from any source into fusion (`sweepdepth fuse`): REP 118 depth images (`32FC1`
//! metres or `16UC1` millimetres, 0 or NaN invalid) with their `camera_info`, placed in
//! `world_frame` at their stamps by `/tf` + `/tf_static` (tf2's rules, `ros/tf_history.rs`).
//!
//! Each depth image waits, in arrival order, until `/tf` reaches its stamp, for at most
//! `tf_timeout` (the caller's clock: receive time live); an image behind a waiting one waits
//! behind it. What cannot be fused is a [`DepthSkip`] with the reason, counted by label: no
//! camera_info yet, a size or encoding that does not fit, a CameraInfo that describes no
//! camera, a pose that cannot come.
//!
//! With colour topics ([`DepthSources::with_colour`]), each depth image takes the colour image
//! of its source with its stamp (the last [`COLOUR_KEPT`] of each are kept, compressed ones as
//! they came: only those a depth image takes are decoded). A placed depth image whose colour
//! has not come yet waits for it (a RealSense sends its two streams in either order), until
//! its colour topic passes its stamp or for at most `tf_timeout`; one whose colour does not
//! come, or does not fit, is fused without colour and counted in [`DepthSources::uncoloured`].

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use super::counts::SkipCounts;
use super::fuser::FusionInput;
use super::pose_queue::{PoseQueue, Posed};
use crate::image::{ImageF32, Rgba8Image};
use crate::msgs::{CameraInfo, CompressedImage, Image, TFMessage, Time};
use crate::ros::camera_info::{camera_from_info, check_image_size, ImageKind};
use crate::ros::tf_history::TfInsertError;

/// Why a depth image was not fused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DepthSkip {
    #[error("{topic}: no camera_info received yet for this depth image")]
    NoCameraInfo { topic: String },
    #[error("{topic}: {reason}")]
    Image { topic: String, reason: String },
    #[error("{topic}: camera_info: {reason}")]
    Camera { topic: String, reason: String },
    #[error("{topic}: no pose of '{frame}' in '{world}' at its stamp: {reason}")]
    NoWorldPose {
        topic: String,
        frame: String,
        world: String,
        reason: String,
    },
}

impl DepthSkip {
    /// A short label for counters.
    pub fn label(&self) -> &'static str {
        match self {
            DepthSkip::NoCameraInfo { .. } => "no camera_info",
            DepthSkip::Image { .. } => "bad depth image",
            DepthSkip::Camera { .. } => "bad camera_info",
            DepthSkip::NoWorldPose { .. } => "no world pose",
        }
    }
}

/// The depth sources of a `fuse` node: their latest camera_info, the transforms, and the
/// depth images that wait for them.
#[derive(Debug)]
pub struct DepthSources {
    topics: Vec<String>,
    infos: Vec<Option<CameraInfo>>,
    world_frame: String,
    tf_timeout_ns: u64,
    /// The transforms, and each depth image (with its source) waiting for the pose of its
    /// frame (the image's `header.frame_id`).
    queue: PoseQueue<(usize, FusionInput)>,
    /// Depth images refused, by reason.
    pub skipped: SkipCounts,
    /// Per source, the colour image topic (empty: no colour) and its last images.
    colour_topics: Vec<String>,
    colours: Vec<VecDeque<ColourImage>>,
    /// Placed depth images waiting for their colour image, in order: source, image, and the
    /// time after which they go without.
    awaiting_colour: VecDeque<(usize, FusionInput, u64)>,
    /// Depth images fused without their colour, by reason.
    pub uncoloured: SkipCounts,
}

/// Why a depth image has no colour when its colour topic has not reached its stamp yet.
const NO_COLOUR_YET: &str = "no colour image at its stamp";
/// Why a depth image waited for its colour in vain.
const COLOUR_LATE: &str = "its colour image did not come within tf_timeout";

/// The colour images kept per source, newest last, for the depth images that come after them.
pub const COLOUR_KEPT: usize = 8;

/// A colour image as it came: a `sensor_msgs/Image`, or a `sensor_msgs/CompressedImage` (JPEG
/// or PNG as image_transport's compressed plugin publishes it), decoded when a depth takes it.
#[derive(Debug, Clone)]
pub enum ColourImage {
    Raw(Image),
    Compressed(CompressedImage),
}

impl ColourImage {
    fn stamp(&self) -> Time {
        match self {
            ColourImage::Raw(image) => image.header.stamp,
            ColourImage::Compressed(image) => image.header.stamp,
        }
    }

    fn to_rgba8(&self, topic: &str) -> Option<Rgba8Image> {
        match self {
            ColourImage::Raw(image) => super::convert::image_to_rgba8(topic, image).ok(),
            ColourImage::Compressed(image) => {
                let decoded = super::compressed::decode(topic, image).ok()?;
                super::convert::image_to_rgba8(topic, &decoded).ok()
            }
        }
    }
}

impl DepthSources {
    /// `topics`: the depth image topics (for messages); poses in `world_frame`.
    pub fn new(topics: Vec<String>, world_frame: String, tf_timeout: Duration) -> Self {
        Self {
            infos: vec![None; topics.len()],
            topics,
            world_frame,
            tf_timeout_ns: u64::try_from(tf_timeout.as_nanos()).unwrap_or(u64::MAX),
            queue: PoseQueue::default(),
            skipped: SkipCounts::default(),
            colour_topics: Vec::new(),
            colours: Vec::new(),
            awaiting_colour: VecDeque::new(),
            uncoloured: SkipCounts::default(),
        }
    }

    /// Colour for the depth: per source (in the order of the depth topics), its colour image
    /// topic, whose pixels are the depth's.
    pub fn with_colour(mut self, topics: Vec<String>) -> Self {
        self.colours = vec![VecDeque::new(); topics.len()];
        self.colour_topics = topics;
        self
    }

    /// A colour image of source `i`; returns the depth images that waited for it (or for a
    /// colour image past their stamp: they go without).
    pub fn push_colour(
        &mut self,
        i: usize,
        image: ColourImage,
    ) -> Vec<Result<FusionInput, DepthSkip>> {
        let stamp = image.stamp();
        let Some(kept) = self.colours.get_mut(i) else {
            return Vec::new();
        };
        if kept.len() == COLOUR_KEPT {
            kept.pop_front();
        }
        kept.push_back(image);
        let (due, waiting) = std::mem::take(&mut self.awaiting_colour)
            .into_iter()
            .partition(|(source, input, _)| *source == i && input.stamp <= stamp);
        self.awaiting_colour = waiting;
        due.into_iter()
            .map(|(source, input, _)| Ok(self.coloured(source, input)))
            .collect()
    }

    /// `input` with the colour of source `i` at its stamp, or without it (counted).
    fn coloured(&mut self, i: usize, mut input: FusionInput) -> FusionInput {
        match self.colour_for(i, &input) {
            Ok(colour) => input.colour = Some(colour),
            Err(reason) => self.uncoloured.add(reason),
        }
        input
    }

    /// Whether the colour topic of source `i` has passed `stamp` (a colour image newer than it
    /// came): a depth image with that stamp waits no longer for its own.
    fn colour_passed(&self, i: usize, stamp: Time) -> bool {
        self.colours
            .get(i)
            .and_then(VecDeque::back)
            .is_some_and(|newest| newest.stamp() > stamp)
    }

    /// Whether the depth images take colour (colour topics were given).
    pub fn has_colour(&self) -> bool {
        !self.colours.is_empty()
    }

    /// Depth images placed and waiting for their colour image.
    pub fn awaiting_colour(&self) -> usize {
        self.awaiting_colour.len()
    }

    /// The colour of source `i` at the depth's stamp, or why there is none.
    fn colour_for(&self, i: usize, input: &FusionInput) -> Result<Arc<Rgba8Image>, &'static str> {
        let image = self
            .colours
            .get(i)
            .and_then(|kept| kept.iter().rev().find(|c| c.stamp() == input.stamp))
            .ok_or(NO_COLOUR_YET)?;
        let topic = self.colour_topics.get(i).map_or("", String::as_str);
        let colour = image.to_rgba8(topic).ok_or("colour image not readable")?;
        if (colour.width, colour.height) != (input.depth.width, input.depth.height) {
            return Err("colour image of another size");
        }
        Ok(Arc::new(colour))
    }

    pub fn world_frame(&self) -> &str {
        &self.world_frame
    }

    /// Depth images waiting for `/tf`.
    pub fn waiting(&self) -> usize {
        self.queue.waiting()
    }

    /// The latest camera_info of source `i`.
    pub fn push_info(&mut self, i: usize, info: CameraInfo) {
        if let Some(slot) = self.infos.get_mut(i) {
            *slot = Some(info);
        }
    }

    /// A `/tf` or `/tf_static` message; returns the transforms refused. A `/tf` stamp well
    /// before the newest (a bag played again) clears the dynamic transforms first.
    pub fn push_tf(&mut self, msg: &TFMessage, is_static: bool) -> Vec<TfInsertError> {
        self.queue.add_tf(msg, is_static).0
    }

    /// A depth image of source `i`, received at `now_ns`; returns what is now ready (this
    /// image, or those waiting before it) or refused.
    pub fn push_depth(
        &mut self,
        i: usize,
        image: &Image,
        now_ns: u64,
    ) -> Vec<Result<FusionInput, DepthSkip>> {
        let mut out = Vec::new();
        match self.convert(i, image) {
            Ok(input) => {
                let stamp = input.stamp;
                self.queue.push(
                    (i, input),
                    image.header.frame_id.clone(),
                    stamp,
                    now_ns.saturating_add(self.tf_timeout_ns),
                );
            }
            Err(skip) => {
                self.skipped.add(skip.label());
                out.push(Err(skip));
            }
        }
        out.extend(self.poll(now_ns));
        out
    }

    /// The waiting images whose pose has come (or that waited too long), in order, and those
    /// that waited for their colour long enough (fused without).
    pub fn poll(&mut self, now_ns: u64) -> Vec<Result<FusionInput, DepthSkip>> {
        let done = self.queue.ready(&self.world_frame, now_ns, false);
        let mut out = Vec::with_capacity(done.len());
        while let Some((_, _, deadline)) = self.awaiting_colour.front() {
            if *deadline > now_ns {
                break;
            }
            if let Some((_, input, _)) = self.awaiting_colour.pop_front() {
                self.uncoloured.add(COLOUR_LATE);
                out.push(Ok(input));
            }
        }
        for posed in done {
            match posed {
                Posed::Ready((source, mut input), world_from_frame) => {
                    input.map_from_cam = world_from_frame.compose(&input.map_from_cam);
                    if self.colours.is_empty() {
                        out.push(Ok(input));
                        continue;
                    }
                    match self.colour_for(source, &input) {
                        Ok(colour) => {
                            input.colour = Some(colour);
                            out.push(Ok(input));
                        }
                        // Its colour may still come (after the depth made beside it).
                        Err(NO_COLOUR_YET) if !self.colour_passed(source, input.stamp) => {
                            let deadline = now_ns.saturating_add(self.tf_timeout_ns);
                            self.awaiting_colour.push_back((source, input, deadline));
                        }
                        Err(reason) => {
                            self.uncoloured.add(reason);
                            out.push(Ok(input));
                        }
                    }
                }
                Posed::Failed {
                    item: (source, _),
                    frame,
                    error,
                    ..
                } => {
                    let skip = DepthSkip::NoWorldPose {
                        topic: self.topic(source),
                        frame,
                        world: self.world_frame.clone(),
                        reason: error.to_string(),
                    };
                    self.skipped.add(skip.label());
                    out.push(Err(skip));
                }
            }
        }
        out
    }

    fn topic(&self, i: usize) -> String {
        self.topics.get(i).cloned().unwrap_or_default()
    }

    /// The image in metres with its camera (placed in its own frame: `map_from_cam` is
    /// `frame_from_cam` until the pose comes).
    fn convert(&self, i: usize, image: &Image) -> Result<FusionInput, DepthSkip> {
        let topic = self.topic(i);
        let info =
            self.infos
                .get(i)
                .and_then(Option::as_ref)
                .ok_or_else(|| DepthSkip::NoCameraInfo {
                    topic: topic.clone(),
                })?;
        let kind = ImageKind::from_topic(&topic).unwrap_or(ImageKind::Raw);
        let camera = |e: crate::geometry::GeometryError| DepthSkip::Camera {
            topic: topic.clone(),
            reason: e.to_string(),
        };
        let calibration = camera_from_info(&topic, info, kind).map_err(camera)?;
        check_image_size(&topic, info, image.width, image.height).map_err(|e| {
            DepthSkip::Image {
                topic: topic.clone(),
                reason: e.to_string(),
            }
        })?;
        let depth = depth_metres(image).map_err(|reason| DepthSkip::Image {
            topic: topic.clone(),
            reason,
        })?;
        if (depth.width, depth.height)
            != (
                calibration.model.intrinsics.width_px,
                calibration.model.intrinsics.height_px,
            )
        {
            return Err(DepthSkip::Image {
                topic,
                reason: format!(
                    "{}x{} but its camera_info describes {}x{}",
                    depth.width,
                    depth.height,
                    calibration.model.intrinsics.width_px,
                    calibration.model.intrinsics.height_px
                ),
            });
        }
        Ok(FusionInput {
            stamp: image.header.stamp,
            frame: self.world_frame.clone(),
            depth,
            colour: None,
            model: calibration.model,
            map_from_cam: calibration.cam_from_frame(false).inverse(),
            // Other sources' depth carries neither: fusion weighs it by its discontinuities
            // and viewing angles alone.
            confidence: None,
            baseline_ratio: None,
            source: topic,
        })
    }
}

/// A REP 118 depth image in metres: `32FC1` (metres; NaN, inf and 0 invalid) or `16UC1` /
/// `mono16` (millimetres; 0 invalid), either byte order.
pub fn depth_metres(image: &Image) -> Result<ImageF32, String> {
    let (w, h) = (image.width as usize, image.height as usize);
    let bytes_per = match image.encoding.as_str() {
        "32FC1" => 4,
        "16UC1" | "mono16" => 2,
        other => {
            return Err(format!(
                "encoding '{other}' is not a depth encoding (32FC1 metres or 16UC1 millimetres)"
            ))
        }
    };
    let row = w
        .checked_mul(bytes_per)
        .ok_or_else(|| "the image is too large".to_string())?;
    let step = image.step as usize;
    if step < row {
        return Err(format!(
            "step {step} is less than width x {bytes_per} = {row}"
        ));
    }
    let needed = step
        .checked_mul(h.saturating_sub(1))
        .and_then(|n| n.checked_add(row))
        .ok_or_else(|| "the image is too large".to_string())?;
    if h > 0 && image.data.len() < needed {
        return Err(format!(
            "{} bytes of data, {needed} needed for {w}x{h} with step {step}",
            image.data.len()
        ));
    }
    let big = image.is_bigendian != 0;
    let mut data = Vec::with_capacity(w * h);
    for y in 0..h {
        let line = &image.data[y * step..y * step + row];
        for px in line.chunks_exact(bytes_per) {
            let metres = if bytes_per == 4 {
                let b = [px[0], px[1], px[2], px[3]];
                if big {
                    f32::from_be_bytes(b)
                } else {
                    f32::from_le_bytes(b)
                }
            } else {
                let b = [px[0], px[1]];
                let mm = if big {
                    u16::from_be_bytes(b)
                } else {
                    u16::from_le_bytes(b)
                };
                if mm == 0 {
                    f32::NAN
                } else {
                    f32::from(mm) * 1e-3
                }
            };
            data.push(if metres.is_finite() && metres > 0.0 {
                metres
            } else {
                f32::NAN
            });
        }
    }
    Ok(ImageF32 {
        width: image.width,
        height: image.height,
        data,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::msgs::{Header, Time};

    pub(crate) fn info(w: u32, h: u32) -> CameraInfo {
        CameraInfo {
            header: Header {
                stamp: Time::default(),
                frame_id: "cam".into(),
            },
            width: w,
            height: h,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [50.0, 0.0, 15.5, 0.0, 50.0, 11.5, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                50.0, 0.0, 15.5, 0.0, 0.0, 50.0, 11.5, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            ..CameraInfo::default()
        }
    }

    pub(crate) fn depth_mm(w: u32, h: u32, mm: u16, sec: i32) -> Image {
        Image {
            header: Header {
                stamp: Time { sec, nanosec: 0 },
                frame_id: "cam".into(),
            },
            width: w,
            height: h,
            encoding: "16UC1".into(),
            is_bigendian: 0,
            step: w * 2,
            data: (0..w * h).flat_map(|_| mm.to_le_bytes()).collect(),
        }
    }

    pub(crate) use crate::pipeline::pose_queue::tests::tf;

    const S: u64 = 1_000_000_000;

    fn sources() -> DepthSources {
        DepthSources::new(
            vec!["/a/depth/image".into()],
            "world".into(),
            Duration::from_secs(1),
        )
    }

    #[test]
    fn millimetres_become_metres_and_zero_is_invalid() {
        let mut image = depth_mm(4, 2, 1500, 1);
        image.data[0] = 0;
        image.data[1] = 0;
        let d = depth_metres(&image).unwrap();
        assert!(d.data[0].is_nan());
        assert!((d.data[1] - 1.5).abs() < 1e-6);
        image.encoding = "rgb8".into();
        assert!(depth_metres(&image).unwrap_err().contains("rgb8"));
        let mut short = depth_mm(4, 2, 1500, 1);
        short.data.truncate(10);
        assert!(depth_metres(&short).unwrap_err().contains("bytes"));
    }

    #[test]
    fn a_depth_waits_for_its_pose_and_is_placed_at_its_stamp() {
        let mut s = sources();
        s.push_info(0, info(32, 24));
        s.push_tf(&tf(1, 0.0), false);
        // Stamp 2: /tf has only reached 1: it waits.
        assert!(s.push_depth(0, &depth_mm(32, 24, 2000, 2), 0).is_empty());
        assert_eq!(s.waiting(), 1);
        s.push_tf(&tf(3, 2.0), false);
        let out = s.poll(S / 10);
        assert_eq!(out.len(), 1);
        let input = out[0].as_ref().unwrap();
        assert_eq!(input.frame, "world");
        // Halfway between x = 0 at 1 s and x = 2 at 3 s.
        assert!((input.map_from_cam.translation.x - 1.0).abs() < 1e-9);
        assert!((input.depth.data[0] - 2.0).abs() < 1e-6);
    }

    #[test]
    fn what_cannot_be_fused_is_refused_with_its_reason() {
        let mut s = sources();
        // No camera_info yet.
        let out = s.push_depth(0, &depth_mm(32, 24, 2000, 1), 0);
        assert!(matches!(out[0], Err(DepthSkip::NoCameraInfo { .. })));
        // A size that is not its camera_info's.
        s.push_info(0, info(32, 24));
        let out = s.push_depth(0, &depth_mm(16, 24, 2000, 1), 0);
        assert_eq!(out[0].as_ref().unwrap_err().label(), "bad depth image");
        // No /tf within tf_timeout.
        assert!(s.push_depth(0, &depth_mm(32, 24, 2000, 5), 0).is_empty());
        let out = s.poll(2 * S);
        let err = out[0].as_ref().unwrap_err();
        assert_eq!(err.label(), "no world pose", "{err}");
        assert!(err.to_string().contains("'world'"), "{err}");
        assert_eq!(s.skipped.get("no world pose"), 1);
        assert_eq!(s.skipped.get("no camera_info"), 1);
    }

    fn rgb_image(w: u32, h: u32, value: u8, sec: i32) -> Image {
        Image {
            encoding: "rgb8".into(),
            step: w * 3,
            data: vec![value; (w * h * 3) as usize],
            ..depth_mm(w, h, 0, sec)
        }
    }

    pub(crate) fn rgb(w: u32, h: u32, value: u8, sec: i32) -> ColourImage {
        ColourImage::Raw(rgb_image(w, h, value, sec))
    }

    /// Each depth image takes its source's colour image with its stamp, waiting for it when
    /// it comes after the depth; one without (none with its stamp, another size, none in
    /// time) is fused without colour and counted.
    #[test]
    fn a_depth_takes_the_colour_with_its_stamp() {
        let mut s = sources().with_colour(vec!["/a/image_raw".into()]);
        s.push_info(0, info(32, 24));
        s.push_tf(&tf(0, 0.0), true);
        s.push_colour(0, rgb(32, 24, 90, 1));
        s.push_colour(0, rgb(32, 24, 200, 2));
        s.push_colour(0, rgb(16, 12, 50, 3));
        let colour_of = |out: Vec<Result<FusionInput, DepthSkip>>| {
            let input = out.into_iter().next().unwrap().unwrap();
            input.colour.map(|c| Rgba8Image::unpack(c.pixels[0]))
        };
        let c = colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 1), 0));
        assert_eq!(c.map(|p| p[0]), Some(90));
        assert_eq!(
            colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 2), 0)).map(|p| p[1]),
            Some(200)
        );
        assert!(colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 3), 0)).is_none());
        assert_eq!(s.uncoloured.get("colour image of another size"), 1);
        // A depth before its colour waits for it; one whose colour topic passes its stamp
        // goes without.
        assert!(s.push_depth(0, &depth_mm(32, 24, 2000, 4), 0).is_empty());
        assert!(s.push_depth(0, &depth_mm(32, 24, 2000, 5), 0).is_empty());
        assert_eq!(s.awaiting_colour(), 2);
        assert!(s.poll(S / 2).is_empty(), "tf_timeout (1 s) not reached");
        let out = s.push_colour(0, rgb(32, 24, 120, 5));
        assert_eq!(out.len(), 2, "both released");
        let colours: Vec<_> = out
            .into_iter()
            .map(|r| {
                let input = r.unwrap();
                (
                    input.stamp.sec,
                    input.colour.map(|c| Rgba8Image::unpack(c.pixels[0])[0]),
                )
            })
            .collect();
        assert_eq!(colours, [(4, None), (5, Some(120))]);
        assert_eq!(s.uncoloured.get("no colour image at its stamp"), 1);
        // One whose colour never comes goes without after tf_timeout.
        assert!(s.push_depth(0, &depth_mm(32, 24, 2000, 6), S).is_empty());
        assert!(s.poll(S + S / 2).is_empty());
        let late = s.poll(2 * S + 1);
        assert_eq!(late.len(), 1);
        assert!(late[0].as_ref().unwrap().colour.is_none());
        assert_eq!(
            s.uncoloured
                .get("its colour image did not come within tf_timeout"),
            1
        );
        assert_eq!(s.awaiting_colour(), 0);
        // Only the last COLOUR_KEPT are kept.
        for k in 0..COLOUR_KEPT as i32 {
            s.push_colour(0, rgb(32, 24, 10, 10 + k));
        }
        assert!(colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 1), 0)).is_none());
        // Compressed (PNG: lossless), decoded when taken; a corrupt one is counted.
        let png = super::super::compressed::compress(
            &rgb_image(32, 24, 77, 30),
            super::super::compressed::Codec::Png,
            95,
        )
        .unwrap();
        let mut corrupt = png.clone();
        corrupt.header.stamp.sec = 31;
        corrupt.data.truncate(40);
        s.push_colour(0, ColourImage::Compressed(png));
        s.push_colour(0, ColourImage::Compressed(corrupt));
        let c = colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 30), 0));
        assert_eq!(c.map(|p| p[0]), Some(77));
        assert!(colour_of(s.push_depth(0, &depth_mm(32, 24, 2000, 31), 0)).is_none());
        assert_eq!(s.uncoloured.get("colour image not readable"), 1);
        // Without colour topics nothing is counted.
        let mut plain = sources();
        plain.push_info(0, info(32, 24));
        plain.push_tf(&tf(0, 0.0), true);
        assert!(colour_of(plain.push_depth(0, &depth_mm(32, 24, 2000, 1), 0)).is_none());
        assert!(plain.uncoloured.is_empty());
    }
}
