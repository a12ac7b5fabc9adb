//! How a level's images get to the device (`GpuEngine::record_level`): the caller's, written
//! straight into the level's `images` buffer, or through the image pyramid (`pyramid.rs`): the
//! set's first level uploads the caller's images into level 0 and makes every half-size level
//! below on the GPU, the others copy theirs. A pair's matching images are made on the device
//! from the caller's (`prefilter` stage), in level 0 (a one-level sweep too); packed images
//! are unpacked on the device into level 0 (or the prefilter's input); a held set's images
//! (`set_images.rs`) are copied there from the set's, each camera written up once per set.

use super::super::coarse::LevelImages;
use super::super::stages::Stage;
use super::super::SweepError;
use super::pyramid::Pyramid;
use super::GpuEngine;
use crate::geometry::Rig;
use crate::image::SetImages;

/// What a level's images need (`GpuEngine::level_input`).
pub(super) struct LevelInput {
    /// The prefilter makes level 0 from the caller's images.
    pub prefilter: bool,
    /// Some images are packed and unpacked into this run's own pyramid.
    pub packed: bool,
    /// The images are a held set's (`set_images.rs`).
    pub held: bool,
    /// Half-size levels below level 0.
    pub halvings: usize,
    /// This level fills the pyramid (the run's first level).
    pub fill: bool,
    /// The level's images come from the pyramid (else straight into `images`).
    pub from_pyramid: bool,
    /// The held set's cameras this level writes up (`SetOnDevice::take_missing`).
    pub missing: Vec<usize>,
}

impl GpuEngine {
    /// Keeps the images of the frame set `images` on the device for the runs of its references
    /// until [`Self::release_set`]: each camera's image goes up once (`set_images.rs`), those
    /// of `used` (the cameras the references sweep with) all with the first reference.
    pub fn hold_set(&mut self, images: SetImages<'_>, used: &[usize]) -> Result<(), SweepError> {
        let layouts = &self.pipelines.layouts;
        let layouts = (
            &layouts[Stage::Half as usize],
            &layouts[Stage::Unpack as usize],
        );
        let held = self
            .set_images
            .hold(&self.device, &self.queue, layouts, images, used);
        if held.is_err() {
            self.set_images.release();
        }
        held
    }

    /// Ends [`Self::hold_set`]: each run uploads its own images again.
    pub fn release_set(&mut self) {
        self.set_images.release();
    }

    /// How this level's `images` reach the device (`prefilter`: the plan's), with the pyramid
    /// fitted to them where it is filled.
    pub(super) fn level_input(
        &mut self,
        rig: &Rig,
        images: LevelImages<'_>,
        prefilter: bool,
    ) -> Result<LevelInput, SweepError> {
        let full = images.full();
        let held = self.set_images.holds(&full);
        let packed = !held && full.has_packed();
        let halvings = images.halvings();
        let from_pyramid = halvings > 0 || prefilter || packed || held;
        let fill = from_pyramid && self.pyramid_filled.is_none_or(|d| d < halvings);
        if fill {
            self.fit_pyramid(full, halvings, (prefilter, packed))?;
        }
        let from_pyramid = from_pyramid || self.pyramid_filled.is_some();
        let missing = match fill && held {
            true => self.set_images.take_missing(&full),
            false => Vec::new(),
        };
        if halvings == 0 && (fill || !from_pyramid) {
            super::super::check_images(rig, full)?;
        }
        Ok(LevelInput {
            prefilter,
            packed,
            held,
            halvings,
            fill,
            from_pyramid,
            missing,
        })
    }

    /// An image pyramid that holds `full` and `halvings` levels below it (made anew when the
    /// one there does not), with the prefilter's input (`prefilter`) and the buffer and passes
    /// of `full`'s packed images where they are needed.
    fn fit_pyramid(
        &mut self,
        full: SetImages<'_>,
        halvings: usize,
        (prefilter, packed): (bool, bool),
    ) -> Result<(), SweepError> {
        if !self
            .pyramid
            .as_ref()
            .is_some_and(|p| p.fits(full, halvings))
        {
            self.pyramid = None;
            self.pyramid = Some(Pyramid::new(
                &self.device,
                &self.queue,
                &self.pipelines.layouts[Stage::Half as usize],
                full,
                halvings,
            )?);
        }
        let Some(pyramid) = self.pyramid.as_mut() else {
            return Err(SweepError::Gpu("internal: no image pyramid".into()));
        };
        let layouts = &self.pipelines.layouts;
        if prefilter {
            pyramid.ensure_raw(
                &self.device,
                &self.queue,
                &layouts[Stage::Prefilter as usize],
            );
        }
        if packed {
            let layout = &layouts[Stage::Unpack as usize];
            pyramid.ensure_packed(&self.device, &self.queue, layout, full, prefilter)?;
        }
        Ok(())
    }
}
