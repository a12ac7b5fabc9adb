//! Image containers the engine consumes and produces.

/// An RGBA8 image, one `u32` per pixel packed little-endian (r | g << 8 | b << 16 | a << 24), the
/// layout WGSL's `unpack4x8unorm` reads. Rows are contiguous, top row first.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rgba8Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u32>,
}

impl Rgba8Image {
    pub fn pack(r: u8, g: u8, b: u8) -> u32 {
        u32::from(r) | (u32::from(g) << 8) | (u32::from(b) << 16) | (0xff << 24)
    }

    pub fn unpack(p: u32) -> [u8; 4] {
        p.to_le_bytes()
    }

    /// From tightly packed RGB8 bytes.
    pub fn from_rgb8(width: u32, height: u32, rgb: &[u8]) -> Option<Self> {
        if rgb.len() != width as usize * height as usize * 3 {
            return None;
        }
        let pixels = rgb
            .chunks_exact(3)
            .map(|c| Self::pack(c[0], c[1], c[2]))
            .collect();
        Some(Self {
            width,
            height,
            pixels,
        })
    }

    pub fn from_image(img: &image::DynamicImage) -> Self {
        let rgb = img.to_rgb8();
        let (width, height) = rgb.dimensions();
        let pixels = rgb
            .pixels()
            .map(|p| Self::pack(p.0[0], p.0[1], p.0[2]))
            .collect();
        Self {
            width,
            height,
            pixels,
        }
    }

    pub fn to_rgb_image(&self) -> image::RgbImage {
        image::RgbImage::from_fn(self.width, self.height, |x, y| {
            let [r, g, b, _] = Self::unpack(self.pixels[(y * self.width + x) as usize]);
            image::Rgb([r, g, b])
        })
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// A 16-bit image whose values all lie below 4096 (10- or 12-bit data in the low bits) is read
/// by its high byte as at most 16 grey levels, nearly black: its matching fails. The warning for
/// `source` (a camera, a file) from the image's largest value `max`; None for a value of 4096
/// or more, or an image dark in any case (all below 256: a covered lens, a black frame).
pub fn narrow_mono16_warning(source: &str, max: u16) -> Option<String> {
    if !(256..4096).contains(&max) {
        return None;
    }
    Some(format!(
        "{source}: every 16-bit value is below 4096 (at most {max}: 10- or 12-bit data in the \
         low bits?); read by its high byte the image is at most 16 grey levels, nearly black, \
         and its depth fails: have the camera or driver scale it to 16 bits (the data in the \
         high bits) or send 8 bits"
    ))
}

/// A camera image's bytes as its message carries them, rows without padding, for an engine
/// that unpacks them itself (the WGSL engine's `unpack` stage): fewer bytes to upload than an
/// [`Rgba8Image`] and no conversion on the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PackedFormat {
    Rgb8 = 1,
    Bgr8 = 2,
    Mono8 = 3,
}

impl PackedFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgb8 | Self::Bgr8 => 3,
            Self::Mono8 => 1,
        }
    }
}

/// [`PackedFormat`] bytes of a `width` x `height` image (`bytes.len()` is `width * height *
/// bytes_per_pixel`, checked by `sweep::check_images`).
#[derive(Debug, Clone, Copy)]
pub struct PackedImage<'a> {
    pub width: u32,
    pub height: u32,
    pub format: PackedFormat,
    pub bytes: &'a [u8],
}

impl PackedImage<'_> {
    /// The same pixels as an [`Rgba8Image`] (what the `unpack` stage makes on the device).
    pub fn to_rgba8(&self) -> Rgba8Image {
        let pixels = match self.format {
            PackedFormat::Rgb8 => self
                .bytes
                .chunks_exact(3)
                .map(|p| Rgba8Image::pack(p[0], p[1], p[2]))
                .collect(),
            PackedFormat::Bgr8 => self
                .bytes
                .chunks_exact(3)
                .map(|p| Rgba8Image::pack(p[2], p[1], p[0]))
                .collect(),
            PackedFormat::Mono8 => self
                .bytes
                .iter()
                .map(|&v| Rgba8Image::pack(v, v, v))
                .collect(),
        };
        Rgba8Image {
            width: self.width,
            height: self.height,
            pixels,
        }
    }
}

/// One camera's image for a sweep: packed RGBA, or its message's own bytes.
#[derive(Debug, Clone, Copy)]
pub enum CameraImage<'a> {
    Rgba(&'a Rgba8Image),
    Packed(PackedImage<'a>),
}

impl<'a> CameraImage<'a> {
    pub fn width(&self) -> u32 {
        match self {
            Self::Rgba(image) => image.width,
            Self::Packed(image) => image.width,
        }
    }

    pub fn height(&self) -> u32 {
        match self {
            Self::Rgba(image) => image.height,
            Self::Packed(image) => image.height,
        }
    }

    /// Whether it holds exactly `width * height` pixels.
    pub fn is_whole(&self) -> bool {
        let pixels = self.width() as usize * self.height() as usize;
        match self {
            Self::Rgba(image) => image.pixels.len() == pixels,
            Self::Packed(image) => image.bytes.len() == pixels * image.format.bytes_per_pixel(),
        }
    }

    /// As an [`Rgba8Image`]: itself, or its bytes converted.
    pub fn rgba(&self) -> std::borrow::Cow<'a, Rgba8Image> {
        match *self {
            Self::Rgba(image) => std::borrow::Cow::Borrowed(image),
            Self::Packed(image) => std::borrow::Cow::Owned(image.to_rgba8()),
        }
    }
}

/// The images of one sweep, one per camera of its rig, in the rig's order: a slice of the
/// caller's, the cameras `picked` from a frame set's images (a reference's views, as
/// [`crate::engine::Sweeper::run_references`] picks them) without copying a pixel, or a set's
/// [`CameraImage`]s (some of them packed), all or picked.
#[derive(Debug, Clone, Copy)]
pub enum SetImages<'a> {
    All(&'a [Rgba8Image]),
    Picked {
        set: &'a [Rgba8Image],
        picked: &'a [usize],
    },
    Cameras {
        set: &'a [CameraImage<'a>],
        picked: Option<&'a [usize]>,
    },
}

impl<'a> SetImages<'a> {
    /// The images `picked` (indices into `set`); None when an index is outside it.
    pub fn picked(set: &'a [Rgba8Image], picked: &'a [usize]) -> Option<Self> {
        Self::All(set).pick(picked)
    }

    /// The images `picked` of these (indices into them; all of them: these); None when an index
    /// is outside them or these are picked already.
    pub fn pick(self, picked: &'a [usize]) -> Option<Self> {
        let len = self.len();
        if picked.len() == len && picked.iter().enumerate().all(|(k, &i)| k == i) {
            return Some(self);
        }
        if picked.iter().any(|&i| i >= len) {
            return None;
        }
        match self {
            Self::All(set) => Some(Self::Picked { set, picked }),
            Self::Cameras { set, picked: None } => Some(Self::Cameras {
                set,
                picked: Some(picked),
            }),
            _ => None,
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Self::All(images) => images.len(),
            Self::Picked { picked, .. } => picked.len(),
            Self::Cameras { set, picked } => picked.map_or(set.len(), <[usize]>::len),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Camera `i`'s image.
    pub fn get(&self, i: usize) -> Option<CameraImage<'a>> {
        match *self {
            Self::All(images) => images.get(i).map(CameraImage::Rgba),
            Self::Picked { set, picked } => picked
                .get(i)
                .and_then(|&k| set.get(k))
                .map(CameraImage::Rgba),
            Self::Cameras { set, picked: None } => set.get(i).copied(),
            Self::Cameras {
                set,
                picked: Some(picked),
            } => picked.get(i).and_then(|&k| set.get(k)).copied(),
        }
    }

    pub fn iter(self) -> impl Iterator<Item = CameraImage<'a>> {
        (0..self.len()).filter_map(move |i| self.get(i))
    }

    /// Camera `i`'s index in the frame set it was picked from (itself when nothing was picked).
    pub fn set_index(&self, i: usize) -> Option<usize> {
        match *self {
            Self::All(images) => (i < images.len()).then_some(i),
            Self::Cameras { set, picked: None } => (i < set.len()).then_some(i),
            Self::Picked { picked, .. }
            | Self::Cameras {
                picked: Some(picked),
                ..
            } => picked.get(i).copied(),
        }
    }

    /// The frame set these images were picked from, as itself: every image of it, none picked.
    pub fn whole_set(&self) -> Self {
        match *self {
            Self::All(images) | Self::Picked { set: images, .. } => Self::All(images),
            Self::Cameras { set, .. } => Self::Cameras { set, picked: None },
        }
    }

    /// Which frame set these images were picked from: the address and length of its slice of
    /// images (equal for every pick from one set while it lives; compared, never followed).
    pub fn set_id(&self) -> (usize, usize) {
        fn id<T>(s: &[T]) -> (usize, usize) {
            (s.as_ptr() as usize, s.len())
        }
        match *self {
            Self::All(images) | Self::Picked { set: images, .. } => id(images),
            Self::Cameras { set, .. } => id(set),
        }
    }

    /// Whether any image is packed.
    pub fn has_packed(&self) -> bool {
        self.iter().any(|c| matches!(c, CameraImage::Packed(_)))
    }

    /// The images as one slice where they are one (`All`).
    pub fn as_slice(&self) -> Option<&'a [Rgba8Image]> {
        match *self {
            Self::All(images) => Some(images),
            _ => None,
        }
    }
}

impl<'a> From<&'a [Rgba8Image]> for SetImages<'a> {
    fn from(images: &'a [Rgba8Image]) -> Self {
        Self::All(images)
    }
}

/// A single-channel f32 image, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn get(&self, x: u32, y: u32) -> f32 {
        self.data[(y * self.width + x) as usize]
    }
}
