//! The CPU twin of the GPU pipeline: one module per shader, written to read like it, on the same
//! packed [`SweepPlan`]. Slow (single-threaded) and meant for tests and for tracing a wrong result
//! to one stage, not for production.

pub mod aggregate;
pub mod boxes;
pub mod common;
pub mod cost;
pub mod finalize;
pub mod median;
pub mod occlusion;
pub mod select;
pub mod sgm;

use super::gpu::{sgm_lines, SGM_DIRECTIONS};
use super::gpu_types::MAP_COUNT;
use super::plan::SweepPlan;
use super::{DepthMaps, SweepError, SweepParams};
use crate::geometry::Rig;
use crate::image::Rgba8Image;

/// Intermediate results of a CPU run, for stage-by-stage comparison with the GPU.
pub struct CpuTrace {
    /// The `maps` buffer: MAP_COUNT sections of one reference image each.
    pub maps: Vec<f32>,
    pub zbuffer: Vec<u32>,
}

#[derive(Debug, Default)]
pub struct CpuEngine;

impl CpuEngine {
    pub fn run(
        &self,
        rig: &Rig,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        let plan = SweepPlan::new(rig, params)?;
        let trace = self.run_plan(&plan, rig, images)?;
        Ok(plan.depth_maps(&trace.maps))
    }

    pub fn run_plan(
        &self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<CpuTrace, SweepError> {
        let mut packed = Vec::new();
        plan.pack_images(rig, images, &mut packed)?;
        let npix = plan.pixel_count();
        let channels = plan.channels();
        let n_planes = plan.num_planes();
        let batch = 8u32.min(n_planes);
        let mut cost_slab = vec![0.0f32; batch as usize * channels * npix];
        let (padded_w, padded_h) = plan.padded_size();
        let slices = batch as usize * channels;
        let mut row_sums = vec![[0.0f32; 2]; slices * padded_w as usize * plan.height as usize];
        let mut box_sums = vec![[0.0f32; 2]; slices * padded_w as usize * padded_h as usize];
        let mut state = vec![select::initial(); npix];
        let sgm_paths = plan.sgm_paths();
        let volume_len = if sgm_paths > 0 {
            npix * plan.volume_words()
        } else {
            0
        };
        let mut volume = vec![0u32; volume_len];
        let mut first = 0;
        while first < n_planes {
            let count = batch.min(n_planes - first);
            cost::run(plan, &packed, first, count, &mut cost_slab);
            boxes::box_h(plan, count, &cost_slab, &mut row_sums);
            boxes::box_v(plan, count, &row_sums, &mut box_sums);
            let volume_out = (sgm_paths > 0).then_some(volume.as_mut_slice());
            aggregate::run(
                plan, first, count, &box_sums, &cost_slab, &mut state, volume_out,
            );
            first += count;
        }
        if sgm_paths > 0 {
            let mut sums = vec![0u32; volume_len];
            for (r, &(dx, dy)) in SGM_DIRECTIONS.iter().enumerate().take(sgm_paths as usize) {
                let lines = sgm_lines(dx, dy, plan.width, plan.height);
                sgm::pass(plan, &packed, dx, dy, lines, r == 0, &volume, &mut sums);
            }
            sgm::select(plan, &sums, &mut state);
        }
        let mut maps = vec![0.0f32; MAP_COUNT * npix];
        finalize::run(plan, &state, &mut maps);
        median::run(plan, &mut maps);
        let mut zbuffer = vec![0u32; plan.total_camera_pixels];
        occlusion::splat(plan, &maps, &mut zbuffer);
        occlusion::visibility(plan, &zbuffer, &mut maps);
        Ok(CpuTrace { maps, zbuffer })
    }
}
