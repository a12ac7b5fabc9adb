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

/// The images of one sweep, one per camera of its rig, in the rig's order: a slice of the
/// caller's, or the cameras `picked` from a frame set's images (a reference's views, as
/// [`crate::engine::Sweeper::run_references`] picks them) without copying a pixel.
#[derive(Debug, Clone, Copy)]
pub enum SetImages<'a> {
    All(&'a [Rgba8Image]),
    Picked {
        set: &'a [Rgba8Image],
        picked: &'a [usize],
    },
}

impl<'a> SetImages<'a> {
    /// The images `picked` (indices into `set`); None when an index is outside it.
    pub fn picked(set: &'a [Rgba8Image], picked: &'a [usize]) -> Option<Self> {
        if picked.len() == set.len() && picked.iter().enumerate().all(|(k, &i)| k == i) {
            return Some(Self::All(set));
        }
        picked
            .iter()
            .all(|&i| i < set.len())
            .then_some(Self::Picked { set, picked })
    }

    pub fn len(&self) -> usize {
        match self {
            Self::All(images) => images.len(),
            Self::Picked { picked, .. } => picked.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Camera `i`'s image.
    pub fn get(&self, i: usize) -> Option<&'a Rgba8Image> {
        match *self {
            Self::All(images) => images.get(i),
            Self::Picked { set, picked } => picked.get(i).and_then(|&k| set.get(k)),
        }
    }

    pub fn iter(self) -> impl Iterator<Item = &'a Rgba8Image> {
        (0..self.len()).filter_map(move |i| self.get(i))
    }

    /// The images as one slice where they are one (`All`).
    pub fn as_slice(&self) -> Option<&'a [Rgba8Image]> {
        match *self {
            Self::All(images) => Some(images),
            Self::Picked { .. } => None,
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
