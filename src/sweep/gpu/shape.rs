//! The shape of work of one plan on one adapter: image and slab sizes, batches of planes, row
//! bands of the SGM volume (what the buffers are allocated for), checked against the adapter's
//! limits up front.

use super::super::gpu_types::*;
use super::super::plan::SweepPlan;
use super::super::schedule::{Schedule, ScheduleShape};
use super::super::SweepError;

/// Invocations per workgroup of the subgroup SGM where several lines share one.
const SGM_GROUP_INVOCATIONS: u32 = 128;

/// Path lines per workgroup of the subgroup SGM on `info`'s adapter: enough subgroups for
/// [`SGM_GROUP_INVOCATIONS`] invocations where every subgroup has the same size (NVIDIA 32,
/// lavapipe 8: several walks resident per workgroup hide each one's latency); one where the
/// size varies (a subgroup could then span two lines).
pub(super) fn sgm_lines_for(info: &wgpu::AdapterInfo) -> u32 {
    let (least, most) = (info.subgroup_min_size, info.subgroup_max_size);
    if least == most && least > 0 {
        (SGM_GROUP_INVOCATIONS / least).max(1)
    } else {
        1
    }
}

/// Where the window sums run (per-pair aggregation over the reference's pairs, windows larger
/// than 2x2 or centred: `SweepPlan::cost_rows`): the costs into the cost slab, then their row
/// sums in a pass of their own (`cost.wgsl`, `box_h.wgsl`), or both in one stage that keeps
/// the costs in workgroup memory (`cost_rows.wgsl`: no cost slab, one dispatch fewer per batch,
/// about 1.5x the planes per batch). The same floats either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum CostRows {
    /// The adapter's: `fused` on GPUs, `apart` on CPU adapters (on lavapipe the fused stage,
    /// a workgroup barrier per pair and block of planes, made the demo's sweep 1.7x slower).
    #[default]
    Auto,
    /// One stage (`cost_rows.wgsl`).
    Fused,
    /// Cost slab, then the row sums.
    Apart,
}

impl CostRows {
    /// Whether the stages run fused on an adapter that is a GPU (`gpu`) or not.
    pub fn fused(self, gpu: bool) -> bool {
        match self {
            Self::Auto => gpu,
            Self::Fused => true,
            Self::Apart => false,
        }
    }
}

/// How SGM's selection (`sgm_select.wgsl`) reads each pixel's sums and matching costs: a
/// workgroup copies its 64 pixels' words into workgroup memory a chunk at a time, neighbouring
/// invocations reading neighbouring words, or each invocation reads its own pixel's in place
/// (neighbours' loads a pixel's words apart). The same maps either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum SelectReads {
    /// The adapter's: `chunked` on GPUs, `in-place` on CPU adapters (on lavapipe, where a
    /// barrier is a coroutine switch, the chunked selection took 3x as long on the ring).
    #[default]
    Auto,
    /// Through workgroup memory.
    Chunked,
    /// Each invocation its own pixel's words.
    InPlace,
}

impl SelectReads {
    /// Whether the selection reads through workgroup memory on a GPU (`gpu`) or not.
    pub fn chunked(self, gpu: bool) -> bool {
        match self {
            Self::Auto => gpu,
            Self::Chunked => true,
            Self::InPlace => false,
        }
    }
}

/// Largest cost slab + window sums we allocate for one batch of planes on a CPU adapter
/// (lavapipe: its 128 MiB bindings cap it anyway).
pub(super) const SLAB_BUDGET_BYTES: u64 = 192 << 20;

/// The same on a GPU: fewer, larger batches. Every batch runs its dispatches over the whole
/// reference and reads and writes each pixel's winner-take-all state (48 bytes a pixel each
/// way): at 1 MP with the default windows 22 batches at 192 MiB, 8 at 512 MiB.
pub(super) const GPU_SLAB_BUDGET_BYTES: u64 = 512 << 20;

/// The bytes of one batch of planes on an adapter that is a GPU or not.
pub(super) fn slab_budget(gpu: bool) -> u64 {
    if gpu {
        GPU_SLAB_BUDGET_BYTES
    } else {
        SLAB_BUDGET_BYTES
    }
}

/// Hypotheses of the fine sweep per pixel (`subpixel_refine`).
pub(super) const REFINE_HYPOTHESES: u32 = 2 * super::super::cpu::refine::REACH as u32 + 1;

/// Bytes per plane of the cost slab (0 where `cost_rows.wgsl` sums the costs as it makes
/// them) and the row sums (0 without the box pass): what `buffers.rs` allocates per plane of a
/// batch. The vertical sums are made where they are read (`aggregate.wgsl`), so they take no
/// memory.
fn slice_bytes(
    npix: u64,
    channels: u64,
    padded_w: u32,
    height: u32,
    box_passes: bool,
    cost_rows: bool,
) -> [u64; 2] {
    let cost = if cost_rows { 0 } else { npix * 4 * channels };
    if !box_passes {
        return [cost, 0];
    }
    let row = u64::from(padded_w) * u64::from(height) * 8 * channels;
    [cost, row]
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct ShapeKey {
    pub width: u32,
    pub height: u32,
    pub padded_width: u32,
    pub padded_height: u32,
    pub cameras: u32,
    pub camera_pixels: usize,
    /// Words of the `images` buffer (pixels, and census words with a census cost).
    pub image_words: usize,
    pub planes: u32,
    pub channels: u32,
    /// Planes per batch.
    pub batch: u32,
    /// Windows of at most 2x2 are summed straight from the cost slab (no box passes).
    pub direct_windows: bool,
    /// Cost and row sums in one stage, no cost slab (`SweepPlan::cost_rows`).
    pub cost_rows: bool,
    /// SGM path directions (0 = winner-take-all: no cost volume).
    pub sgm_paths: u32,
    /// u32 words per pixel of the cost volume (0 without SGM).
    pub volume_words: u32,
    /// Rows per band of the cost volume and the path sums (the height when one binding holds
    /// them; fewer when the adapter's storage binding limit does not).
    pub band_rows: u32,
    /// Batches of the fine sweep's hypotheses (`subpixel_refine`; 0 without it).
    pub refine_batches: u32,
}

impl ShapeKey {
    pub fn batches(&self) -> u32 {
        self.planes.div_ceil(self.batch)
    }

    pub fn bands(&self) -> u32 {
        self.height.div_ceil(self.band_rows)
    }

    /// The band of rows `b`.
    pub fn band(&self, b: u32) -> GpuBand {
        let first_row = b * self.band_rows;
        GpuBand {
            first_row,
            rows: self.band_rows.min(self.height - first_row),
            first_pixel: first_row * self.width,
            _pad: 0,
        }
    }

    /// What runs for this shape.
    pub fn schedule(&self) -> Schedule {
        Schedule::new(ScheduleShape {
            batches: self.batches(),
            box_passes: !self.direct_windows,
            cost_rows: self.cost_rows,
            sgm_paths: self.sgm_paths,
            bands: self.bands(),
            refine_batches: self.refine_batches,
        })
    }

    /// Bytes of one batch's cost slab and row sums (the sums 0 without the box pass).
    pub fn batch_bytes(&self) -> [u64; 2] {
        let npix = u64::from(self.width) * u64::from(self.height);
        slice_bytes(
            npix,
            u64::from(self.channels),
            self.padded_width,
            self.height,
            !self.direct_windows,
            self.cost_rows,
        )
        .map(|bytes| bytes * u64::from(self.batch))
    }

    /// The shape of `plan` on a device with `limits`; `sgm_band_bytes` caps one band of the SGM
    /// volume below the binding limit, `slab_bytes` the bytes of one batch of planes below
    /// SLAB_BUDGET_BYTES (tests force several batches with it), `cost_rows` whether the
    /// engine makes the costs and their row sums in one stage where the plan allows it
    /// (`SweepPlan::cost_rows`, [`super::CostRows`]). Refuses what the adapter cannot hold,
    /// with the sizes.
    pub fn of(
        plan: &SweepPlan,
        limits: &wgpu::Limits,
        sgm_band_bytes: Option<u64>,
        slab_bytes: Option<u64>,
        cost_rows: bool,
    ) -> Result<Self, SweepError> {
        let cost_rows = cost_rows && plan.cost_rows();
        let npix = plan.pixel_count() as u64;
        let channels = plan.channels() as u64;
        let (padded_w, padded_h) = plan.padded_size();
        let box_passes = plan.box_passes();
        let [cost_bytes, row_bytes] =
            slice_bytes(npix, channels, padded_w, plan.height, box_passes, cost_rows);
        // What one plane of a batch allocates: its cost slab, and its row sums only where
        // the box pass runs (2x2 shiftable windows read the slab directly).
        let per_plane = cost_bytes + row_bytes;
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let budget = slab_bytes.unwrap_or(SLAB_BUDGET_BYTES).min(max_binding);
        if row_bytes > max_binding {
            return Err(SweepError::InvalidParams(format!(
                "reference image of {npix} pixels needs {row_bytes} bytes of window sums per plane, more than this adapter's storage binding limit ({max_binding})"
            )));
        }
        let maps_bytes = npix * 4 * MAP_COUNT as u64;
        let image_bytes = plan.image_words() as u64 * 4;
        for (what, bytes) in [("output maps", maps_bytes), ("camera images", image_bytes)] {
            if bytes > max_binding {
                return Err(SweepError::InvalidParams(format!(
                    "{what} need {bytes} bytes, more than this adapter's storage binding limit ({max_binding})"
                )));
            }
        }
        let sgm_paths = plan.sgm_paths();
        let volume_words = if sgm_paths > 0 {
            plan.volume_words() as u32
        } else {
            0
        };
        // The cost volume and the path sums (u16 per pixel and plane each) in row bands that
        // each fit one binding.
        let band_rows = if sgm_paths > 0 {
            let band_limit = sgm_band_bytes.unwrap_or(u64::MAX).min(max_binding);
            let row_bytes = u64::from(plan.width) * u64::from(volume_words) * 4;
            let rows = band_limit / row_bytes.max(1);
            if rows == 0 {
                return Err(SweepError::InvalidParams(format!(
                    "optimizer sgm: one row of the cost volume ({} pixels x {} planes) needs {row_bytes} bytes, more than this adapter's storage binding limit of {band_limit} bytes; use fewer planes or a narrower image, or optimizer wta (no cost volume)",
                    plan.width,
                    plan.num_planes()
                )));
            }
            rows.min(u64::from(plan.height)) as u32
        } else {
            plan.height
        };
        let planes = plan.num_planes();
        let max_z = limits.max_compute_workgroups_per_dimension;
        let max_slices = (budget / per_plane.max(1)).min(u64::from(u32::MAX)) as u32;
        let batch = max_slices
            .clamp(1, planes)
            .min(MAX_BATCH_PLANES)
            .min(max_z / (channels as u32).max(1))
            .max(1);
        Ok(Self {
            width: plan.width,
            height: plan.height,
            padded_width: padded_w,
            padded_height: padded_h,
            cameras: plan.cameras.len() as u32,
            camera_pixels: plan.total_camera_pixels,
            image_words: plan.image_words(),
            planes,
            channels: plan.channels() as u32,
            batch,
            direct_windows: !plan.box_passes(),
            cost_rows,
            sgm_paths,
            volume_words,
            band_rows,
            refine_batches: if super::super::schedule::refines(plan) {
                REFINE_HYPOTHESES.div_ceil(batch)
            } else {
                0
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::{Cost, Scoring, SweepParams, WindowMode};

    fn plan(width: u32, height: u32, shiftable_2x2: bool) -> SweepPlan {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(width, height));
        let rig = crate::synthetic::row_rig(4, 0.1, model, 1).expect("rig");
        let mut params = SweepParams {
            num_planes: 128,
            cost: Cost::Tssd,
            scoring: Scoring::BestHalfSequence,
            ..SweepParams::default()
        };
        if shiftable_2x2 {
            params.window_width = 2;
            params.window_height = 2;
            params.window_mode = WindowMode::Shiftable;
        }
        SweepPlan::new(&rig, &params).expect("plan")
    }

    /// The batch is sized on what the mode allocates: 2x2 shiftable windows (no box passes)
    /// pay for the cost slab alone. At 1280x960 with wgpu's default limits (128 MiB bindings)
    /// this was one plane per batch, the window sums counted though never allocated for use.
    #[test]
    fn batches_count_only_what_the_mode_allocates() {
        let limits = wgpu::Limits::default();
        let direct =
            ShapeKey::of(&plan(1280, 960, true), &limits, None, None, false).expect("shape");
        let [cost, row] = direct.batch_bytes();
        assert_eq!(row, 0);
        let budget = limits.max_storage_buffer_binding_size;
        assert!(cost <= budget, "{cost} > {budget}");
        // One more plane would not fit: the budget is used.
        let per_plane = cost / u64::from(direct.batch);
        assert!(cost + per_plane > budget, "batch {}", direct.batch);
        assert!(direct.batch >= 8, "batch {}", direct.batch);
        // Centred windows run the box passes: their sums are counted.
        let boxed =
            ShapeKey::of(&plan(1280, 960, false), &limits, None, None, false).expect("shape");
        let [cost, row] = boxed.batch_bytes();
        assert!(row > 0);
        assert!(cost + row <= budget);
        assert!(boxed.batch < direct.batch);
    }

    /// A GPU's budget (its bindings as an H200's, 4 GiB) runs a 1-MP rig with the default
    /// windows in a third of the batches a CPU adapter's does: each batch reads and writes
    /// every pixel's winner-take-all state again.
    #[test]
    fn a_gpu_runs_fewer_larger_batches() {
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: 4 << 30,
            max_buffer_size: 4 << 30,
            ..wgpu::Limits::default()
        };
        let p = plan(1280, 960, false);
        let batches = |gpu: bool| {
            let key = ShapeKey::of(&p, &limits, None, Some(slab_budget(gpu)), true);
            key.expect("shape").batches()
        };
        let (gpu, cpu) = (batches(true), batches(false));
        assert!(
            gpu <= 8 && cpu >= 3 * gpu - 2,
            "GPU {gpu} batches, CPU adapter {cpu}"
        );
    }

    #[test]
    fn a_slab_budget_forces_batches() {
        let limits = wgpu::Limits::default();
        let p = plan(320, 240, true);
        let one = ShapeKey::of(&p, &limits, None, None, false).expect("shape");
        assert_eq!(one.batches(), 1);
        let per_plane = one.batch_bytes()[0] / u64::from(one.batch);
        let forced = ShapeKey::of(&p, &limits, None, Some(5 * per_plane), false).expect("shape");
        assert_eq!((forced.batch, forced.batches()), (5, 128u32.div_ceil(5)));
        assert_eq!(forced.schedule().shape.batches, forced.batches());
    }
}
