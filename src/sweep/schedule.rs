//! "What runs for this plan": the stage schedule of one frame set, made once per plan and shape
//! and read by both engines. [`Schedule::phases`] is the order of the stages (the CPU engine
//! runs one function per phase); [`Schedule::dispatches`] expands it into the WGSL engine's
//! dispatches (per batch of planes, per row band of the SGM volume, per SGM direction).

use super::gpu_types::{SUBPIXEL_MODE, SUBPIXEL_REFINE};
use super::plan::SweepPlan;
use super::stages::Stage;

/// SGM path directions (dx, dy): the first four for 4 paths, all eight for 8.
pub const SGM_DIRECTIONS: [(i32, i32); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
];

/// The elements of the WGSL engine's `sgm_passes` array after the directions' own: the passes
/// that walk several directions in one dispatch (`SGM_TOGETHER` in `sgm_subgroup.wgsl`), every
/// direction (`SGM_ALL_PASS`: the sums cleared before) or those after the first
/// (`SGM_REST_PASS`: direction 0 writes the sums in a dispatch of its own before).
pub const SGM_ALL_PASS: usize = SGM_DIRECTIONS.len();
pub const SGM_REST_PASS: usize = SGM_DIRECTIONS.len() + 1;

/// Path lines of directions `first` .. `paths` - 1 together (one `SGM_TOGETHER` dispatch).
pub fn sgm_together_lines(first: u32, paths: u32, width: u32, height: u32) -> u32 {
    SGM_DIRECTIONS
        .iter()
        .take(paths as usize)
        .skip(first as usize)
        .map(|&(dx, dy)| sgm_lines(dx, dy, width, height))
        .sum()
}

/// Path lines of direction (dx, dy) over a width x height image.
pub fn sgm_lines(dx: i32, dy: i32, width: u32, height: u32) -> u32 {
    match (dx, dy) {
        (_, 0) => height,
        (0, _) => width,
        _ => width + height - 1,
    }
}

/// Whether `plan` runs the fine sweep (`subpixel_refine`, where `cpu::refine::supported`).
pub fn refines(plan: &SweepPlan) -> bool {
    plan.params.subpixel & SUBPIXEL_MODE == SUBPIXEL_REFINE && super::cpu::refine::supported(plan)
}

/// One step of a frame set, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Costs, window sums, scoring and the streaming winner-take-all over every plane (and the
    /// SGM cost volume).
    Sweep,
    /// Every SGM path direction over the volume, summed.
    Sgm,
    /// Winner-take-all over the summed path costs.
    SgmSelect,
    Finalize,
    /// The fine local sweep between planes (`subpixel_refine`): its base surface, its
    /// hypotheses through the sweep's cost, box and aggregate stages, its result.
    Refine,
    Median,
    Splat,
    Visibility,
}

impl Phase {
    /// The name of its time in `StageTimings` (both engines).
    pub fn name(self) -> &'static str {
        match self {
            Phase::Sweep => "sweep",
            Phase::Sgm => "sgm",
            Phase::SgmSelect => "sgm_select",
            Phase::Finalize => "finalize",
            Phase::Refine => "refine",
            Phase::Median => "median",
            Phase::Splat => "splat",
            Phase::Visibility => "visibility",
        }
    }
}

/// One dispatch of the WGSL engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dispatch {
    pub stage: Stage,
    /// Batch of planes (cost, box passes, aggregate).
    pub batch: u32,
    /// Row band of the SGM volume (aggregate, sgm, sgm_select).
    pub band: u32,
    /// Index into [`SGM_DIRECTIONS`] (sgm).
    pub direction: u32,
}

impl Dispatch {
    fn of(stage: Stage) -> Self {
        Self {
            stage,
            batch: 0,
            band: 0,
            direction: 0,
        }
    }
}

/// The shape of work a schedule is made for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScheduleShape {
    /// Batches of planes the sweep runs in.
    pub batches: u32,
    /// Window sums need the box pass (windows larger than 2x2, or centred ones).
    pub box_passes: bool,
    /// The cost and the box pass run as one stage (`Stage::CostRows`; `SweepPlan::cost_rows`).
    pub cost_rows: bool,
    /// SGM path directions (0: winner-take-all).
    pub sgm_paths: u32,
    /// Row bands of the SGM volume (1 when one binding holds it).
    pub bands: u32,
    /// Batches of the fine sweep's hypotheses (`subpixel_refine`; 0 without it): batch
    /// `batches + b` of the `batches` uniform array.
    pub refine_batches: u32,
}

/// The dispatches of the sweep's batches `batches` (of the `batches` uniform array): cost, the
/// box passes, aggregate once per row band of the volume (which bands the sweep writes; the
/// fine sweep's batches read the bands' rows alike).
fn sweep_batches(
    shape: &ScheduleShape,
    batches: std::ops::Range<u32>,
    dispatches: &mut Vec<Dispatch>,
) {
    for batch in batches {
        let at = |stage| Dispatch {
            batch,
            ..Dispatch::of(stage)
        };
        if shape.cost_rows {
            dispatches.push(at(Stage::CostRows));
        } else {
            dispatches.push(at(Stage::Cost));
            if shape.box_passes {
                dispatches.push(at(Stage::BoxH));
            }
        }
        dispatches.extend((0..shape.bands.max(1)).map(|band| Dispatch {
            band,
            ..at(Stage::Aggregate)
        }));
    }
}

/// The phases and dispatches of one frame set.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Schedule {
    pub shape: ScheduleShape,
    phases: Vec<Phase>,
    dispatches: Vec<Dispatch>,
    /// Where each phase's dispatches end in `dispatches`.
    phase_ends: Vec<usize>,
}

impl Schedule {
    pub fn new(shape: ScheduleShape) -> Self {
        let sgm = shape.sgm_paths > 0;
        let mut phases = vec![Phase::Sweep];
        if sgm {
            phases.extend([Phase::Sgm, Phase::SgmSelect]);
        }
        phases.push(Phase::Finalize);
        if shape.refine_batches > 0 {
            phases.push(Phase::Refine);
        }
        phases.extend([Phase::Median, Phase::Splat, Phase::Visibility]);
        let bands = shape.bands.max(1);
        let mut dispatches = Vec::new();
        let mut phase_ends = Vec::with_capacity(phases.len());
        for phase in &phases {
            match phase {
                Phase::Sweep => {
                    sweep_batches(&shape, 0..shape.batches, &mut dispatches);
                }
                Phase::Sgm => {
                    // The directions going down (and the horizontal ones, among them the first,
                    // which writes the sums) band after band from the top, those going up from
                    // the bottom: each line finds the state it left in the band before.
                    let directions = || 0..shape.sgm_paths.min(SGM_DIRECTIONS.len() as u32);
                    let going_down = |r: &u32| SGM_DIRECTIONS[*r as usize].1 >= 0;
                    for band in 0..bands {
                        for direction in directions().filter(going_down) {
                            dispatches.push(Dispatch {
                                band,
                                direction,
                                ..Dispatch::of(Stage::Sgm)
                            });
                        }
                    }
                    for band in (0..bands).rev() {
                        for direction in directions().filter(|r| !going_down(r)) {
                            dispatches.push(Dispatch {
                                band,
                                direction,
                                ..Dispatch::of(Stage::Sgm)
                            });
                        }
                    }
                }
                Phase::SgmSelect => dispatches.extend((0..bands).map(|band| Dispatch {
                    band,
                    ..Dispatch::of(Stage::SgmSelect)
                })),
                Phase::Finalize => dispatches.push(Dispatch::of(Stage::Finalize)),
                Phase::Refine => {
                    dispatches.push(Dispatch::of(Stage::RefineBase));
                    let first = shape.batches;
                    sweep_batches(&shape, first..first + shape.refine_batches, &mut dispatches);
                    dispatches.push(Dispatch::of(Stage::RefineSelect));
                }
                Phase::Median => dispatches.push(Dispatch::of(Stage::Median)),
                Phase::Splat => dispatches.push(Dispatch::of(Stage::Splat)),
                Phase::Visibility => dispatches.push(Dispatch::of(Stage::Visibility)),
            }
            phase_ends.push(dispatches.len());
        }
        Self {
            shape,
            phases,
            dispatches,
            phase_ends,
        }
    }

    /// The schedule of a plan in one batch and one band (the phases are all the CPU engine
    /// reads; the WGSL engine makes its own from its shape of work on the adapter). With
    /// `subpixel_refine`, the refine phase follows finalize.
    pub fn of_plan(plan: &SweepPlan) -> Self {
        Self::new(ScheduleShape {
            batches: 1,
            box_passes: plan.box_passes(),
            cost_rows: plan.cost_rows(),
            sgm_paths: plan.sgm_paths(),
            bands: 1,
            refine_batches: u32::from(refines(plan)),
        })
    }

    /// The stages in order, one entry each.
    pub fn phases(&self) -> &[Phase] {
        &self.phases
    }

    /// The WGSL engine's dispatches in order.
    pub fn dispatches(&self) -> &[Dispatch] {
        &self.dispatches
    }

    /// Each phase with its dispatches, in order (the WGSL engine records one compute pass
    /// per phase).
    pub fn phase_dispatches(&self) -> impl Iterator<Item = (Phase, &[Dispatch])> {
        let starts = std::iter::once(0).chain(self.phase_ends.iter().copied());
        self.phases
            .iter()
            .zip(starts.zip(self.phase_ends.iter().copied()))
            .map(|(&phase, (start, end))| (phase, &self.dispatches[start..end]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(batches: u32, box_passes: bool, sgm_paths: u32, bands: u32) -> ScheduleShape {
        ScheduleShape {
            batches,
            box_passes,
            cost_rows: false,
            sgm_paths,
            bands,
            refine_batches: 0,
        }
    }

    #[test]
    fn winner_take_all_runs_no_sgm() {
        let s = Schedule::new(shape(2, true, 0, 1));
        assert!(!s.phases().contains(&Phase::Sgm));
        let stages: Vec<Stage> = s.dispatches().iter().map(|d| d.stage).collect();
        use Stage::*;
        assert_eq!(
            stages,
            [Cost, BoxH, Aggregate, Cost, BoxH, Aggregate, Finalize, Median, Splat, Visibility]
        );
    }

    /// With the cost and its row sums in one stage (`cost_rows.wgsl`) each batch runs it and
    /// aggregate: no cost pass, no row-sum pass.
    #[test]
    fn fused_cost_rows_replace_the_cost_and_row_sum_passes() {
        let s = Schedule::new(ScheduleShape {
            cost_rows: true,
            ..shape(2, true, 0, 1)
        });
        let stages: Vec<Stage> = s.dispatches().iter().map(|d| d.stage).collect();
        use Stage::*;
        assert_eq!(
            stages,
            [CostRows, Aggregate, CostRows, Aggregate, Finalize, Median, Splat, Visibility]
        );
    }

    /// The fine sweep follows finalize: its base surface, its batches (numbered after the
    /// sweep's, every band's aggregate), its result; the median reads what it wrote.
    #[test]
    fn the_fine_sweep_runs_between_finalize_and_the_median() {
        let s = Schedule::new(ScheduleShape {
            refine_batches: 2,
            ..shape(3, true, 0, 2)
        });
        let phases = s.phases();
        let at = |p: Phase| phases.iter().position(|&q| q == p).expect("phase");
        assert_eq!(at(Phase::Refine), at(Phase::Finalize) + 1);
        assert_eq!(at(Phase::Median), at(Phase::Refine) + 1);
        let (_, refine) = s
            .phase_dispatches()
            .find(|(p, _)| *p == Phase::Refine)
            .expect("refine");
        let stages: Vec<(Stage, u32, u32)> =
            refine.iter().map(|d| (d.stage, d.batch, d.band)).collect();
        use Stage::*;
        assert_eq!(
            stages,
            [
                (RefineBase, 0, 0),
                (Cost, 3, 0),
                (BoxH, 3, 0),
                (Aggregate, 3, 0),
                (Aggregate, 3, 1),
                (Cost, 4, 0),
                (BoxH, 4, 0),
                (Aggregate, 4, 0),
                (Aggregate, 4, 1),
                (RefineSelect, 0, 0),
            ]
        );
        assert!(!Schedule::new(shape(3, true, 0, 2))
            .phases()
            .contains(&Phase::Refine));
    }

    #[test]
    fn every_dispatch_belongs_to_its_phase() {
        let s = Schedule::new(ScheduleShape {
            refine_batches: 2,
            ..shape(3, true, 8, 2)
        });
        assert!(s.phases().contains(&Phase::Refine));
        let mut seen = 0;
        for (phase, dispatches) in s.phase_dispatches() {
            assert!(!dispatches.is_empty(), "{phase:?}");
            for d in dispatches {
                let expected = match d.stage {
                    Stage::Cost | Stage::CostRows | Stage::BoxH | Stage::Aggregate
                        if d.batch < s.shape.batches =>
                    {
                        Phase::Sweep
                    }
                    Stage::Cost | Stage::CostRows | Stage::BoxH | Stage::Aggregate => Phase::Refine,
                    Stage::RefineBase | Stage::RefineSelect => Phase::Refine,
                    Stage::Sgm => Phase::Sgm,
                    Stage::SgmSelect => Phase::SgmSelect,
                    Stage::Finalize => Phase::Finalize,
                    Stage::Median => Phase::Median,
                    Stage::Splat => Phase::Splat,
                    Stage::Visibility => Phase::Visibility,
                    Stage::Census
                    | Stage::Half
                    | Stage::Prefilter
                    | Stage::Unpack
                    | Stage::PlaneSpans
                    | Stage::PlaneRanges => {
                        unreachable!("not in a schedule: {d:?}")
                    }
                };
                assert_eq!(phase, expected, "{d:?}");
            }
            seen += dispatches.len();
        }
        assert_eq!(seen, s.dispatches().len());
        assert_eq!(s.phase_dispatches().count(), s.phases().len());
    }

    #[test]
    fn the_passes_together_walk_the_lines_of_their_directions() {
        // 8 paths over 40x30: 30 rows, 40 columns, 30 rows... each diagonal w + h - 1 lines.
        let each: Vec<u32> = SGM_DIRECTIONS
            .iter()
            .map(|&(dx, dy)| sgm_lines(dx, dy, 40, 30))
            .collect();
        assert_eq!(each, [30, 30, 40, 40, 69, 69, 69, 69]);
        assert_eq!(sgm_together_lines(1, 8, 40, 30), 30 + 40 + 40 + 4 * 69);
        assert_eq!(sgm_together_lines(1, 4, 40, 30), 30 + 40 + 40);
        assert_eq!(sgm_together_lines(1, 1, 40, 30), 0);
        assert_eq!(sgm_together_lines(0, 8, 40, 30), 2 * 30 + 2 * 40 + 4 * 69);
        assert_eq!(sgm_together_lines(0, 4, 40, 30), 2 * 30 + 2 * 40);
        assert_eq!((SGM_ALL_PASS, SGM_REST_PASS), (8, 9));
    }

    #[test]
    fn sgm_bands_run_down_then_up_and_the_first_direction_writes_first() {
        let s = Schedule::new(shape(1, false, 8, 3));
        let sgm: Vec<(u32, u32)> = s
            .dispatches()
            .iter()
            .filter(|d| d.stage == Stage::Sgm)
            .map(|d| (d.band, d.direction))
            .collect();
        assert_eq!(sgm.len(), 8 * 3);
        // Every band sees direction 0 (which writes the sums) before any other direction.
        for band in 0..3 {
            let first = sgm.iter().position(|&(b, _)| b == band);
            assert_eq!(first.map(|i| sgm[i].1), Some(0), "band {band}");
        }
        // Down-going directions visit bands 0, 1, 2; up-going ones 2, 1, 0.
        for r in 0..8u32 {
            let bands: Vec<u32> = sgm
                .iter()
                .filter(|&&(_, d)| d == r)
                .map(|&(b, _)| b)
                .collect();
            let expected = if SGM_DIRECTIONS[r as usize].1 >= 0 {
                vec![0, 1, 2]
            } else {
                vec![2, 1, 0]
            };
            assert_eq!(bands, expected, "direction {r}");
        }
        let aggregates = s
            .dispatches()
            .iter()
            .filter(|d| d.stage == Stage::Aggregate)
            .count();
        assert_eq!(aggregates, 3);
        assert_eq!(
            s.phases(),
            [
                Phase::Sweep,
                Phase::Sgm,
                Phase::SgmSelect,
                Phase::Finalize,
                Phase::Median,
                Phase::Splat,
                Phase::Visibility
            ]
        );
    }
}
