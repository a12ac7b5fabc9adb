//! The frame set's images on the device: the caller's images written once into level 0 (each
//! straight from its pixels: no packing on the host), the half-size levels of coarse to fine
//! made from the level above by the `half` stage (`shaders/half.wgsl`, one compute pass in the
//! command buffer of the set's first level), and a level's pixels copied into its shape's
//! `images` buffer, where the `census` stage adds the census words (`shaders/census.wgsl`).
//! A pair's matching images (`sweep/prefilter.rs`) are made here too: the caller's images are
//! then written into `raw`, and the `prefilter` stage writes level 0 from them
//! (`shaders/prefilter.wgsl`) before the halvings.
//! Every level packs its cameras in rig order, as the plan's `size.z` offsets do.

use super::super::gpu_types::MAX_RIG_CAMERAS;
use super::super::plan::SweepPlan;
use super::super::SweepError;
use super::record::tiles_of;
use super::upload::Part;
use crate::image::{CameraImage, SetImages};

/// The uniform block of a pass over one level's cameras, WGSL `Halving` (`shaders/half.wgsl`)
/// and `PrefilterCameras` (`shaders/prefilter.wgsl`): the camera count (and, for the prefilter,
/// the scale's bits), then per camera its width and height, its word of pixel (0, 0) in the
/// buffer read and in the buffer written.
const PASS_BYTES: u64 = 16 + 16 * MAX_RIG_CAMERAS as u64;

/// A pass over one level's cameras (`half`, `prefilter`): one invocation per texel of the
/// widest and tallest camera, the cameras in z.
struct CameraPass {
    group: wgpu::BindGroup,
    workgroups: (u32, u32, u32),
    /// The uniform block (kept alive with its bind group).
    _uniform: wgpu::Buffer,
}

impl CameraPass {
    /// `head`: the block's first two words after the camera count; `cameras`: per camera its
    /// width, height and words of pixel (0, 0) in `from` and in `to`.
    #[allow(clippy::too_many_arguments)]
    fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        layout: &wgpu::BindGroupLayout,
        label: &'static str,
        head: u32,
        cameras: &[[u32; 4]],
        from: &wgpu::Buffer,
        to: &wgpu::Buffer,
    ) -> Self {
        let mut block = vec![0u32; (PASS_BYTES / 4) as usize];
        block[0] = cameras.len() as u32;
        block[1] = head;
        for (c, camera) in cameras.iter().enumerate() {
            block[4 + 4 * c..8 + 4 * c].copy_from_slice(camera);
        }
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: PASS_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(&uniform, 0, bytemuck::cast_slice(&block));
        fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry {
                binding,
                resource: buffer.as_entire_binding(),
            }
        }
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout,
            entries: &[entry(0, &uniform), entry(1, from), entry(2, to)],
        });
        let widest = cameras.iter().map(|c| c[0]).max().unwrap_or(0);
        let tallest = cameras.iter().map(|c| c[1]).max().unwrap_or(0);
        let (x, y, _) = tiles_of(widest, tallest);
        Self {
            group,
            workgroups: (x, y, cameras.len() as u32),
            _uniform: uniform,
        }
    }

    /// Records the pass into `pass`.
    fn dispatch(&self, pass: &mut wgpu::ComputePass<'_>) {
        let (x, y, z) = self.workgroups;
        pass.set_bind_group(0, &self.group, &[]);
        pass.dispatch_workgroups(x, y, z);
    }
}

/// One level: each camera's size and word of pixel (0, 0), and the buffer holding them.
struct Level {
    sizes: Vec<[u32; 2]>,
    offsets: Vec<u32>,
    buffer: wgpu::Buffer,
    /// How this level is made from the one above (None for level 0): its `half` pass.
    made: Option<CameraPass>,
}

impl Level {
    fn words(&self) -> u64 {
        self.sizes
            .iter()
            .map(|[w, h]| u64::from(*w) * u64::from(*h))
            .sum()
    }
}

/// The caller's images before the prefilter, and the `prefilter` pass that makes level 0 from
/// them.
struct Raw {
    buffer: wgpu::Buffer,
    pass: CameraPass,
}

/// The caller's packed images (`image::PackedImage`) and the `unpack` passes (one per format)
/// that write them into level 0 or into `raw`.
struct Packed {
    /// Per camera: its format (0: not packed), and whether the passes write `raw`.
    key: (Vec<u8>, bool),
    /// Per camera: the word of its first byte in `buffer`.
    offsets: Vec<u32>,
    buffer: wgpu::Buffer,
    passes: Vec<CameraPass>,
}

/// The levels of one rig's image sizes, 0 (full resolution) to `depth`.
pub(super) struct Pyramid {
    levels: Vec<Level>,
    /// Made at the first prefiltered frame set.
    raw: Option<Raw>,
    /// Made at the first frame set with packed images (anew when their formats change).
    packed: Option<Packed>,
}

/// Each camera's word of pixel (0, 0), the cameras packed in order.
fn offsets(sizes: &[[u32; 2]]) -> Vec<u32> {
    sizes
        .iter()
        .scan(0u32, |next, [w, h]| {
            let at = *next;
            *next += w * h;
            Some(at)
        })
        .collect()
}

impl Pyramid {
    /// Levels 0 to `depth` for images of the sizes of `images`.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        half_layout: &wgpu::BindGroupLayout,
        images: SetImages<'_>,
        depth: usize,
    ) -> Result<Self, SweepError> {
        if images.len() > MAX_RIG_CAMERAS as usize {
            return Err(SweepError::InvalidParams(format!(
                "{} cameras: the WGSL engine takes at most {MAX_RIG_CAMERAS}",
                images.len()
            )));
        }
        let buffer = |words: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("image pyramid"),
                size: (words * 4).max(16),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let mut sizes: Vec<[u32; 2]> = images.iter().map(|i| [i.width(), i.height()]).collect();
        let mut levels: Vec<Level> = Vec::with_capacity(depth + 1);
        let first_offsets = offsets(&sizes);
        let first_words = sizes
            .iter()
            .map(|[w, h]| u64::from(*w) * u64::from(*h))
            .sum();
        levels.push(Level {
            sizes: sizes.clone(),
            offsets: first_offsets,
            buffer: buffer(first_words),
            made: None,
        });
        for _ in 0..depth {
            let finer = levels
                .last()
                .ok_or_else(|| SweepError::Gpu("internal: no level".into()))?;
            sizes = sizes.iter().map(|[w, h]| [w / 2, h / 2]).collect();
            let coarse_offsets = offsets(&sizes);
            let cameras: Vec<[u32; 4]> = finer
                .sizes
                .iter()
                .zip(&finer.offsets)
                .zip(&coarse_offsets)
                .map(|(([w, h], at), coarse_at)| [*w, *h, *at, *coarse_at])
                .collect();
            let words: u64 = sizes
                .iter()
                .map(|[w, h]| u64::from(*w) * u64::from(*h))
                .sum();
            let coarser = buffer(words);
            let half = CameraPass::new(
                device,
                queue,
                half_layout,
                "half",
                0,
                &cameras,
                &finer.buffer,
                &coarser,
            );
            levels.push(Level {
                offsets: coarse_offsets,
                sizes: sizes.clone(),
                buffer: coarser,
                made: Some(half),
            });
        }
        Ok(Self {
            levels,
            raw: None,
            packed: None,
        })
    }

    /// Makes the buffer of the caller's images before the prefilter and the `prefilter` pass
    /// into level 0 (once).
    pub fn ensure_raw(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        layout: &wgpu::BindGroupLayout,
    ) {
        if self.raw.is_some() {
            return;
        }
        let level = &self.levels[0];
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raw images"),
            size: (level.words() * 4).max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let cameras: Vec<[u32; 4]> = level
            .sizes
            .iter()
            .zip(&level.offsets)
            .map(|([w, h], at)| [*w, *h, *at, *at])
            .collect();
        let pass = CameraPass::new(
            device,
            queue,
            layout,
            "prefilter",
            (super::super::prefilter::SCALE / 256.0).to_bits(),
            &cameras,
            &buffer,
            &level.buffer,
        );
        self.raw = Some(Raw { buffer, pass });
    }

    /// Makes the buffer of `images`' packed bytes and the `unpack` passes into level 0 (or,
    /// `into_raw`, into the buffer the prefilter reads: `ensure_raw` first), unless those of
    /// the same formats are there. Each camera's bytes must be a whole number of words.
    pub fn ensure_packed(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        layout: &wgpu::BindGroupLayout,
        images: SetImages<'_>,
        into_raw: bool,
    ) -> Result<(), SweepError> {
        let formats: Vec<u8> = images
            .iter()
            .map(|image| match image {
                CameraImage::Packed(p) => p.format as u8,
                CameraImage::Rgba(_) => 0,
            })
            .collect();
        let key = (formats, into_raw);
        if self.packed.as_ref().is_some_and(|p| p.key == key) {
            return Ok(());
        }
        let mut offsets = Vec::with_capacity(key.0.len());
        let mut words = 0u64;
        for image in images.iter() {
            offsets.push(u32::try_from(words).map_err(|_| {
                SweepError::InvalidParams("packed images of more than 16 GiB".into())
            })?);
            if let CameraImage::Packed(p) = image {
                if !p.bytes.len().is_multiple_of(4) {
                    return Err(SweepError::InvalidParams(format!(
                        "a packed {}x{} image of {} bytes: a whole number of 4-byte words is needed",
                        p.width,
                        p.height,
                        p.bytes.len()
                    )));
                }
                words += p.bytes.len() as u64 / 4;
            }
        }
        let level = &self.levels[0];
        let target = match (&self.raw, into_raw) {
            (Some(r), true) => &r.buffer,
            (None, true) => {
                return Err(SweepError::Gpu(
                    "internal: no buffer for the raw images".into(),
                ))
            }
            _ => &level.buffer,
        };
        self.packed = None;
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("packed images"),
            size: (words * 4).max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut passes = Vec::new();
        for format in 1..=3u8 {
            let cameras: Vec<[u32; 4]> = (0..key.0.len())
                .filter(|&c| key.0[c] == format)
                .filter_map(|c| {
                    let ([w, h], at) = (level.sizes.get(c)?, level.offsets.get(c)?);
                    Some([*w, *h, offsets[c], *at])
                })
                .collect();
            if !cameras.is_empty() {
                let head = u32::from(format);
                let pass = CameraPass::new(
                    device, queue, layout, "unpack", head, &cameras, &buffer, target,
                );
                passes.push(pass);
            }
        }
        self.packed = Some(Packed {
            key,
            offsets,
            buffer,
            passes,
        });
        Ok(())
    }

    /// Records the packed images unpacked into level 0 or `raw` (`ensure_packed` first).
    pub fn record_unpack(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        unpack: &wgpu::ComputePipeline,
    ) {
        let Some(packed) = &self.packed else {
            return;
        };
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("unpack"),
            timestamp_writes: None,
        });
        pass.set_pipeline(unpack);
        for camera_pass in &packed.passes {
            camera_pass.dispatch(&mut pass);
        }
    }

    /// Records level 0 made from the caller's images in `raw` (`ensure_raw` first).
    pub fn record_prefilter(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        prefilter: &wgpu::ComputePipeline,
    ) -> Result<(), SweepError> {
        let raw = self
            .raw
            .as_ref()
            .ok_or_else(|| SweepError::Gpu("internal: no buffer for the raw images".into()))?;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("prefilter"),
            timestamp_writes: None,
        });
        pass.set_pipeline(prefilter);
        raw.pass.dispatch(&mut pass);
        Ok(())
    }

    /// Whether the pyramid holds levels 0 to `depth` of images of these sizes.
    pub fn fits(&self, images: SetImages<'_>, depth: usize) -> bool {
        self.levels.len() > depth
            && self.levels[0].sizes.len() == images.len()
            && self.levels[0]
                .sizes
                .iter()
                .zip(images.iter())
                .all(|([w, h], i)| *w == i.width() && *h == i.height())
    }

    /// Level `level`'s buffer and the bytes of its pixels.
    pub fn level_buffer(&self, level: usize) -> Option<(&wgpu::Buffer, u64)> {
        self.levels.get(level).map(|l| (&l.buffer, l.words() * 4))
    }

    /// The writes of the caller's images into level 0 (or, `raw`, into the buffer the
    /// prefilter reads: `ensure_raw` first), each from its own pixels; packed images' bytes
    /// into the packed buffer (`ensure_packed` first), which `record_unpack` unpacks.
    pub fn uploads<'a>(
        &'a self,
        images: SetImages<'a>,
        raw: bool,
    ) -> Result<Vec<Part<'a>>, SweepError> {
        images
            .iter()
            .enumerate()
            .map(|(c, image)| self.upload(c, image, raw))
            .collect()
    }

    /// The write of camera `c`'s `image` (as [`Self::uploads`]).
    pub fn upload<'a>(
        &'a self,
        c: usize,
        image: CameraImage<'a>,
        raw: bool,
    ) -> Result<Part<'a>, SweepError> {
        let level = &self.levels[0];
        let at = level
            .offsets
            .get(c)
            .ok_or_else(|| SweepError::Gpu("internal: an image without its place".into()))?;
        Ok(match image {
            CameraImage::Rgba(image) => Part {
                target: self.first_target(raw),
                offset: u64::from(*at) * 4,
                data: bytemuck::cast_slice(&image.pixels),
            },
            CameraImage::Packed(p) => {
                let packed = self.packed.as_ref().ok_or_else(|| {
                    SweepError::Gpu("internal: no buffer for the packed images".into())
                })?;
                let at = packed.offsets.get(c).ok_or_else(|| {
                    SweepError::Gpu("internal: a packed image without its place".into())
                })?;
                Part {
                    target: &packed.buffer,
                    offset: u64::from(*at) * 4,
                    data: p.bytes,
                }
            }
        })
    }

    /// Where the caller's images go: level 0, or (`raw`, once `ensure_raw` made it) the buffer
    /// the prefilter reads.
    fn first_target(&self, raw: bool) -> &wgpu::Buffer {
        match (&self.raw, raw) {
            (Some(r), true) => &r.buffer,
            _ => &self.levels[0].buffer,
        }
    }

    /// Records level 0's images (or, `raw`, the prefilter's input) copied on the device from
    /// level 0 of `from`, a pyramid of a whole frame set's images: camera `c` from its camera
    /// `set_index(c)` (`set_images.rs`).
    pub fn record_copy_from(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        from: &Pyramid,
        set_index: impl Fn(usize) -> Option<usize>,
        raw: bool,
    ) -> Result<(), SweepError> {
        let (ours, theirs) = (&self.levels[0], &from.levels[0]);
        let target = self.first_target(raw);
        for (c, (size, at)) in ours.sizes.iter().zip(&ours.offsets).enumerate() {
            let source = set_index(c)
                .and_then(|s| Some((theirs.sizes.get(s)?, theirs.offsets.get(s)?)))
                .filter(|(their_size, _)| *their_size == size);
            let Some((_, from_at)) = source else {
                return Err(SweepError::Gpu(
                    "internal: a reference's image is not in its set's images".into(),
                ));
            };
            let bytes = u64::from(size[0]) * u64::from(size[1]) * 4;
            let (from_at, at) = (u64::from(*from_at) * 4, u64::from(*at) * 4);
            encoder.copy_buffer_to_buffer(&theirs.buffer, from_at, target, at, bytes);
        }
        Ok(())
    }

    /// Records levels 1 to `depth`, each from the one above, in one compute pass.
    pub fn record_halvings(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        half: &wgpu::ComputePipeline,
        depth: usize,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("half"),
            timestamp_writes: None,
        });
        pass.set_pipeline(half);
        for level in self.levels.iter().take(depth + 1) {
            if let Some(half) = &level.made {
                half.dispatch(&mut pass);
            }
        }
    }

    /// Records the copy of level `level`'s pixels to the start of `images` (a shape's buffer,
    /// whose plan packs the cameras as the level does: checked).
    pub fn record_copy(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        level: usize,
        plan: &SweepPlan,
        images: &wgpu::Buffer,
    ) -> Result<(), SweepError> {
        let level = self
            .levels
            .get(level)
            .ok_or_else(|| SweepError::Gpu("internal: no such image level".into()))?;
        let same = level.sizes.len() == plan.cameras.len()
            && plan
                .cameras
                .iter()
                .zip(level.sizes.iter().zip(&level.offsets))
                .all(|(c, ([w, h], at))| c.size[0] == *w && c.size[1] == *h && c.size[2] == *at);
        if !same {
            return Err(SweepError::Gpu(
                "internal: a level's images are not packed as its plan's cameras".into(),
            ));
        }
        encoder.copy_buffer_to_buffer(&level.buffer, 0, images, 0, level.words() * 4);
        Ok(())
    }
}
