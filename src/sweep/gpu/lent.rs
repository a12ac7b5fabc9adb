//! Depth and confidence lent out of the readback buffer they came back in (issue 56, item 3):
//! the caller reads them where the GPU copied them (the node makes its `32FC1` messages from
//! them) instead of the engine first copying them into maps of its own. The buffer stays
//! mapped while the [`LentMaps`] lives and goes back to the engine's pool of readback buffers
//! when it is dropped, for a later set. Lent only where the caller keeps no maps as floats and
//! reads nothing but depth and confidence ([`crate::sweep::WantedMaps::floats`]).

use std::sync::Arc;

use parking_lot::Mutex;

use crate::image::ImageF32;
use crate::sweep::DepthMaps;

/// Readback buffers given back by dropped [`LentMaps`], for the engine's next sets.
pub(super) type ReturnedBuffers = Arc<Mutex<Vec<wgpu::Buffer>>>;

/// A reference's depth and confidence in a mapped readback buffer (depth then confidence, each
/// `width * height` floats).
pub struct LentMaps {
    /// The mapped bytes (dropped before the buffer is unmapped).
    view: Option<wgpu::BufferView>,
    buffer: wgpu::Buffer,
    back: std::sync::Weak<Mutex<Vec<wgpu::Buffer>>>,
    width: u32,
    height: u32,
}

impl LentMaps {
    /// `view` (of `buffer`, mapped) as a `width` x `height` reference's depth and confidence;
    /// the view back where it is too short or its floats are not aligned (then the caller
    /// copies them as before).
    pub(super) fn new(
        view: wgpu::BufferView,
        buffer: wgpu::Buffer,
        back: &ReturnedBuffers,
        (width, height): (u32, u32),
    ) -> Result<Self, wgpu::BufferView> {
        let bytes = 2 * 4 * width as usize * height as usize;
        let fits = view
            .get(..bytes)
            .is_some_and(|b| bytemuck::try_cast_slice::<u8, f32>(b).is_ok());
        if !fits {
            return Err(view);
        }
        Ok(Self {
            view: Some(view),
            buffer,
            back: Arc::downgrade(back),
            width,
            height,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Depth then confidence.
    fn floats(&self) -> &[f32] {
        let pixels = self.width as usize * self.height as usize;
        let bytes = self.view.as_ref().and_then(|v| v.get(..2 * 4 * pixels));
        // Checked in `new`: always the maps' floats.
        bytes
            .and_then(|b| bytemuck::try_cast_slice(b).ok())
            .unwrap_or(&[])
    }

    /// z along the reference optical axis, metres, NaN where invalid ([`DepthMaps::depth_m`]).
    pub fn depth_m(&self) -> &[f32] {
        let floats = self.floats();
        &floats[..floats.len() / 2]
    }

    /// In [0, 1], 0 where invalid ([`DepthMaps::confidence`]).
    pub fn confidence(&self) -> &[f32] {
        let floats = self.floats();
        &floats[floats.len() / 2..]
    }

    /// The maps copied out (the other maps empty, as the engine leaves them when they are not
    /// wanted).
    pub fn to_maps(&self) -> DepthMaps {
        let image = |data: &[f32]| ImageF32 {
            width: self.width,
            height: self.height,
            data: data.to_vec(),
        };
        DepthMaps {
            depth_m: image(self.depth_m()),
            confidence: image(self.confidence()),
            ..DepthMaps::empty()
        }
    }
}

impl Drop for LentMaps {
    fn drop(&mut self) {
        drop(self.view.take());
        self.buffer.unmap();
        // An engine dropped meanwhile takes nothing back.
        if let Some(back) = self.back.upgrade() {
            back.lock().push(self.buffer.clone());
        }
    }
}

impl std::fmt::Debug for LentMaps {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LentMaps")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}
