//! A frame set's images on the device across its references (issue 56, item 3). Where a set
//! sweeps several references ([`crate::engine::Sweeper::run_references_set`]), each reference
//! is a sweep of its own views, and each wrote its views' images up again: the 9-camera rig
//! with three references uploaded every image three times. While such a set runs, each camera's
//! image goes up (and is unpacked) once, at the first reference that sweeps with it, into level
//! 0 of a pyramid of the whole set's cameras; every reference's views are then copied from
//! there on the device into its own pyramid (`Pyramid::record_copy_from`), where the prefilter
//! and the half-size levels are made as before. The bytes each reference sweeps are the same.

use super::pyramid::Pyramid;
use super::upload::Part;
use crate::image::{CameraImage, SetImages};
use crate::sweep::SweepError;

/// Where one camera's image of the held set is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Not written yet.
    Absent,
    /// Its write and unpacking recorded into a command buffer not submitted yet.
    Recorded,
    /// On the device (a submission wrote it).
    OnDevice,
}

/// The held frame set's images on the device.
#[derive(Default)]
pub(super) struct SetOnDevice {
    /// The set being swept (`SetImages::set_id`); None between sets.
    set: Option<(usize, usize)>,
    /// Level 0 of the set's cameras (kept from set to set while their sizes and formats stay).
    pyramid: Option<Pyramid>,
    cameras: Vec<State>,
    /// The cameras every reference of the set sweeps with together (`hold`).
    used: Vec<usize>,
}

impl SetOnDevice {
    /// Holds the frame set `images` (all of a set's cameras) until [`Self::release`]; the
    /// cameras `used` are written up together, with the first run that writes any.
    pub fn hold(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        layouts: (&wgpu::BindGroupLayout, &wgpu::BindGroupLayout),
        images: SetImages<'_>,
        used: &[usize],
    ) -> Result<(), SweepError> {
        self.release();
        let (half_layout, unpack_layout) = layouts;
        let whole = images.whole_set();
        if !self.pyramid.as_ref().is_some_and(|p| p.fits(whole, 0)) {
            self.pyramid = None;
            self.pyramid = Some(Pyramid::new(device, queue, half_layout, whole, 0)?);
        }
        if let (true, Some(pyramid)) = (whole.has_packed(), self.pyramid.as_mut()) {
            pyramid.ensure_packed(device, queue, unpack_layout, whole, false)?;
        }
        self.set = Some(whole.set_id());
        self.cameras = vec![State::Absent; whole.len()];
        self.used = used.to_vec();
        Ok(())
    }

    /// Lets the set go (the images stay allocated for the next set).
    pub fn release(&mut self) {
        self.set = None;
        self.cameras.clear();
        self.used.clear();
    }

    /// Whether `images` are picked from the held set.
    pub fn holds(&self, images: &SetImages<'_>) -> bool {
        self.set.is_some_and(|id| id == images.set_id()) && self.pyramid.is_some()
    }

    /// The cameras of the held set that `images` (picked from it) sweep with and that are not
    /// on the device yet, with every other camera of the set's references not there yet (one
    /// staging write for the set): marked as recorded (`submitted` or `abandoned` settles them).
    pub fn take_missing(&mut self, images: &SetImages<'_>) -> Vec<usize> {
        let mut missing = Vec::new();
        let own = (0..images.len()).filter_map(|i| images.set_index(i));
        for s in own.chain(self.used.iter().copied()) {
            if let Some(state @ State::Absent) = self.cameras.get_mut(s) {
                *state = State::Recorded;
                missing.push(s);
            }
        }
        missing
    }

    /// The writes of the set's cameras `which` (`take_missing`), from the set `images` picked
    /// from it.
    pub fn uploads<'a>(
        &'a self,
        images: SetImages<'a>,
        which: &[usize],
    ) -> Result<Vec<Part<'a>>, SweepError> {
        let (whole, pyramid) = (images.whole_set(), self.pyramid()?);
        which
            .iter()
            .map(|&s| {
                let image = whole.get(s).ok_or_else(|| {
                    SweepError::Gpu("internal: a camera outside the held set".into())
                })?;
                pyramid.upload(s, image, false)
            })
            .collect()
    }

    /// Records the set's packed images unpacked where `which` (just written) holds one, then
    /// `images`' cameras copied into level 0 of `target` (or, `raw`, its prefilter input).
    pub fn record(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        unpack: &wgpu::ComputePipeline,
        (images, which): (SetImages<'_>, &[usize]),
        target: &Pyramid,
        raw: bool,
    ) -> Result<(), SweepError> {
        let pyramid = self.pyramid()?;
        let whole = images.whole_set();
        let packed = |&s: &usize| matches!(whole.get(s), Some(CameraImage::Packed(_)));
        if which.iter().any(packed) {
            pyramid.record_unpack(encoder, unpack);
        }
        target.record_copy_from(encoder, pyramid, |c| images.set_index(c), raw)
    }

    /// The recorded writes were submitted: those images are on the device.
    pub fn submitted(&mut self) {
        self.settle(State::OnDevice);
    }

    /// The recorded writes were dropped unsubmitted (a run that failed before its submission).
    pub fn abandoned(&mut self) {
        self.settle(State::Absent);
    }

    fn settle(&mut self, to: State) {
        for state in &mut self.cameras {
            if *state == State::Recorded {
                *state = to;
            }
        }
    }

    fn pyramid(&self) -> Result<&Pyramid, SweepError> {
        self.pyramid
            .as_ref()
            .ok_or_else(|| SweepError::Gpu("internal: no images of the held set".into()))
    }
}
