//! SGM under coarse to fine (twin of `sgm.wgsl` and `sgm_select.wgsl` for a narrowed plan):
//! each pixel's window of planes alone. A plane outside the pixel's tile range is absent: its
//! path cost is PAD, so no path passes through it, and the selection and the uniqueness skip it
//! (the shaders mark it SGM_OUTSIDE_LEVEL in the volume). The volume and the path sums hold only
//! each pixel's window, in groups of LANES lanes ([`VolumeLayout`]: a raw pair's full-resolution
//! volume is about a third of every plane's), and the passes walk a range tile at a time with
//! the window's group count known at compile time for the common counts.
#![expect(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
)]

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;
use crate::sweep::{CancelFlag, SweepError};

use super::common::vectorised_fn;
use super::select::{WtaChunk, WtaState};
use super::sgm::{
    edge_penalties_row, passes_selecting, penalty_table, stride, uniqueness_of,
    uniqueness_on_costs, winner, Uniqueness, LANES, PAD,
};

/// `sgm::run_two_passes` for a narrowed plan: the forward and backward passes on two threads,
/// each pixel's window alone (`volume`, `forward` and `backward` in the plan's
/// [`VolumeLayout`]); what [`run_and_select`] is tested against.
#[cfg(test)]
pub fn run_two_passes(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    cancel: &CancelFlag,
) -> Result<(), SweepError> {
    let layout = VolumeLayout::of(plan);
    super::sgm::forward_and_backward(volume.len(), forward, backward, |walks_forward, sums| {
        let mut write = |y: usize, row: &[u16]| {
            let at = layout.row_start(y);
            sums[at..at + row.len()].copy_from_slice(row);
        };
        pass_windowed(
            plan,
            &layout,
            reference_colours,
            volume,
            walks_forward,
            &mut write,
            cancel,
        );
    });
    cancel.check()
}

/// `sgm::run_and_select` for a narrowed plan: the two passes, each row's winners selected by
/// the pass that completes the row second (bit for bit the separate selection's, `select`,
/// kept for the tests).
pub fn run_and_select(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    state: &mut WtaState,
    cancel: &CancelFlag,
) -> Result<(), SweepError> {
    let layout = VolumeLayout::of(plan);
    let unit = plan.params.sgm_unit_per_level;
    let unique = uniqueness_of(plan);
    let select_row = |y: usize, lanes: [&[u16]; 3], st: &mut WtaChunk<'_>| {
        select_windows(&layout, y, unit, lanes, unique, st);
    };
    let walk = |walks_forward: bool, row_done: &mut dyn FnMut(usize, &[u16])| {
        pass_windowed(
            plan,
            &layout,
            reference_colours,
            volume,
            walks_forward,
            row_done,
            cancel,
        );
    };
    let (row_lanes, width) = (&layout.row_at, plan.params.width as usize);
    let sums = [forward, backward];
    passes_selecting(row_lanes, width, volume, sums, state, walk, select_row);
    cancel.check()
}

/// `sgm::select` for a narrowed plan: a row at a time, each pixel's window alone; what
/// [`run_and_select`] is tested against.
#[cfg(test)]
pub fn select(
    plan: &SweepPlan,
    volume: &[u16],
    forward: &[u16],
    backward: &[u16],
    state: &mut WtaState,
) {
    use rayon::prelude::*;
    let layout = VolumeLayout::of(plan);
    let unit = plan.params.sgm_unit_per_level;
    let unique = uniqueness_of(plan);
    let w = (plan.params.width as usize).max(1);
    state
        .chunks_mut(w)
        .into_par_iter()
        .enumerate()
        .for_each(|(y, mut st)| {
            let lanes = layout.row_start(y)..layout.row_start(y + 1);
            let row = [forward, backward, volume].map(|v| v.get(lanes.clone()).unwrap_or(&[]));
            select_windows(&layout, y, unit, row, unique, &mut st);
        });
}

/// The planes of a pixel that take part in SGM, `lo..=hi`: all of them, or under coarse to
/// fine its tile's range (`SweepPlan::plane_ranges`). A plane outside it is absent, as in the
/// shaders (whose volume marks it OUTSIDE_LEVEL): its path cost is PAD, so no path passes
/// through it, and the selection and the uniqueness skip it. The CPU walks only the groups of
/// LANES that hold the window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub lo: usize,
    pub hi: usize,
}

impl Window {
    /// The groups of LANES lanes that hold the window.
    #[inline(always)]
    pub fn groups(self) -> std::ops::Range<usize> {
        self.lo / LANES..self.hi / LANES + 1
    }

    /// Lanes a pixel with this window holds in the volume ([`VolumeLayout`]).
    #[inline(always)]
    pub fn lanes(self) -> usize {
        self.groups().len() * LANES
    }
}

/// Where each pixel's lanes lie in the CPU's SGM volume and its path sums: the groups of LANES
/// lanes that hold its [`Window`] (from the first group's first lane), the pixels of a row's
/// range tile side by side, row after row. Without coarse to fine every pixel holds
/// `stride(planes)` lanes at `pixel * stride`. The sweep, the passes and the selection read
/// only these lanes, so a narrowed plan's volume is a fraction of the full one's and each pass
/// streams that fraction through memory (the full layout read each pixel's cache lines
/// whatever lanes the step used).
#[derive(Debug, Clone, Default)]
pub struct VolumeLayout {
    tiles: usize,
    /// Per (row, tile): the first lane of its first pixel, and its pixels' window.
    tile_at: Vec<(usize, Window)>,
    /// Per row its first lane, then the volume's length.
    pub(super) row_at: Vec<usize>,
}

impl VolumeLayout {
    pub fn of(plan: &SweepPlan) -> Self {
        let (w, h) = (plan.params.width as usize, plan.params.height as usize);
        let planes = plan.num_planes() as usize;
        let tile = crate::sweep::plan::RANGE_TILE as usize;
        let tiles = w.div_ceil(tile);
        let mut tile_at = Vec::with_capacity(tiles * h);
        let mut row_at = Vec::with_capacity(h + 1);
        let mut at = 0;
        for y in 0..h {
            row_at.push(at);
            let row = row_windows(plan, y);
            for t in 0..tiles {
                let window = window_at(row, t * tile, planes);
                tile_at.push((at, window));
                at += tile.min(w - t * tile) * window.lanes();
            }
        }
        row_at.push(at);
        Self {
            tiles,
            tile_at,
            row_at,
        }
    }

    /// Lanes of the whole volume.
    pub fn len(&self) -> usize {
        self.row_at.last().copied().unwrap_or(0)
    }

    /// Whether the volume has no lanes (an image without pixels).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The first lane of row `y` (of the row after the last: the length).
    #[inline(always)]
    pub fn row_start(&self, y: usize) -> usize {
        self.row_at.get(y).copied().unwrap_or_else(|| self.len())
    }

    /// Pixel `(x, y)`: its first lane and its window.
    #[inline(always)]
    pub fn pixel(&self, x: usize, y: usize) -> (usize, Window) {
        let tile = crate::sweep::plan::RANGE_TILE as usize;
        let t = x / tile;
        match self.tile_at.get(y * self.tiles + t) {
            Some(&(at, window)) => (at + (x - t * tile) * window.lanes(), window),
            None => (self.len(), Window { lo: 0, hi: 0 }),
        }
    }
}

/// The windows of row `y`'s pixels, one per range tile (`SweepPlan::plane_ranges`).
#[inline(always)]
pub(super) fn row_windows(plan: &SweepPlan, y: usize) -> &[[u32; 2]] {
    let tiles = crate::sweep::plan::range_tiles(plan.params.width) as usize;
    plan.plane_ranges
        .get(y * tiles..(y + 1) * tiles)
        .unwrap_or(&[])
}

/// The window of pixel `x` of a row whose tiles' ranges are `row` (every plane when the plan
/// has none for the row).
#[inline(always)]
pub(super) fn window_at(row: &[[u32; 2]], x: usize, planes: usize) -> Window {
    match row.get(x / crate::sweep::plan::RANGE_TILE as usize) {
        Some(&[lo, hi]) => Window {
            lo: lo as usize,
            hi: (hi as usize).min(planes.saturating_sub(1)),
        },
        None => Window {
            lo: 0,
            hi: planes.saturating_sub(1),
        },
    }
}

/// `sgm::step` over a pixel's [`Window`] alone, coarse to fine, with `G` groups of LANES lanes
/// known at compile time (0: the window's count): `cost` and `sum` are the pixel's lanes in the
/// [`VolumeLayout`] (its window's groups), `prev` and `out` slots of every lane with a PAD lane
/// on each side, as `sgm::step`'s. Lanes outside the window are PAD in `out` (and not summed: their
/// sums are never read); `old` holds the groups the slot's last pixel wrote, and those this
/// window does not cover are set to PAD, so every lane of `out` outside the window reads as PAD
/// to the next step.
#[inline(always)]
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn step_window<const G: usize, const START: bool, const FIRST: bool>(
    cost: &[u16],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    sum: &mut [u16],
    window: Window,
    old: &mut (usize, usize),
) -> u16 {
    let groups = window.groups();
    let first = groups.start;
    let count = if G > 0 { G } else { groups.len() };
    if *old != (groups.start, groups.end) {
        for g in old.0..old.1 {
            if !groups.contains(&g) {
                if let Some(lanes) = out.get_mut(1 + g * LANES..1 + (g + 1) * LANES) {
                    lanes.fill(PAD);
                }
            }
        }
        *old = (groups.start, groups.end);
    }
    let jump = prev_min.saturating_add(p2);
    let mut lowest = [u16::MAX; LANES];
    for j in 0..count {
        let base = (first + j) * LANES;
        let local = j * LANES;
        let (Some(cost), Some(prev), Some(out), Some(sum)) = (
            cost.get(local..local + LANES),
            prev.get(base..base + LANES + 2),
            out.get_mut(base + 1..base + 1 + LANES),
            sum.get_mut(local..local + LANES),
        ) else {
            break;
        };
        // The window's lanes of the group (u16 compares: as usize they took four vectors).
        let lo = window.lo.saturating_sub(base).min(LANES) as u16;
        let hi = window.hi.saturating_sub(base).min(LANES - 1) as u16;
        let mut l = [0u16; LANES];
        for i in 0..LANES {
            let value = if START {
                cost[i]
            } else {
                let best = prev[i + 1]
                    .min(prev[i].saturating_add(p1))
                    .min(prev[i + 2].saturating_add(p1))
                    .min(jump);
                cost[i].saturating_add(best - prev_min)
            };
            let lane = i as u16;
            l[i] = if lane >= lo && lane <= hi { value } else { PAD };
            lowest[i] = lowest[i].min(l[i]);
        }
        out.copy_from_slice(&l);
        for i in 0..LANES {
            sum[i] = if FIRST {
                l[i]
            } else {
                sum[i].wrapping_add(l[i])
            };
        }
    }
    let half: [u16; 8] = std::array::from_fn(|i| lowest[i].min(lowest[i + 8]));
    let quarter: [u16; 4] = std::array::from_fn(|i| half[i].min(half[i + 4]));
    quarter[0].min(quarter[2]).min(quarter[1].min(quarter[3]))
}

/// [`step_window`] with its two switches as run-time values.
#[inline(always)]
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn step_window_dyn<const G: usize>(
    start: bool,
    first: bool,
    cost: &[u16],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    sum: &mut [u16],
    window: Window,
    old: &mut (usize, usize),
) -> u16 {
    let (c, pr, m, w) = (cost, prev, prev_min, window);
    match (start, first) {
        (true, true) => step_window::<G, true, true>(c, pr, m, p1, p2, out, sum, w, old),
        (true, false) => step_window::<G, true, false>(c, pr, m, p1, p2, out, sum, w, old),
        (false, true) => step_window::<G, false, true>(c, pr, m, p1, p2, out, sum, w, old),
        (false, false) => step_window::<G, false, false>(c, pr, m, p1, p2, out, sum, w, old),
    }
}

/// What a windowed pass keeps from row to row (`pass_windowed`).
struct WindowedRows {
    /// Per row direction, the previous and current row's slots (every lane, a PAD lane on
    /// each side), their minima and the groups each slot's last pixel wrote.
    prev: Vec<Vec<u16>>,
    cur: Vec<Vec<u16>>,
    prev_mins: Vec<Vec<u16>>,
    cur_mins: Vec<Vec<u16>>,
    prev_groups: Vec<Vec<(usize, usize)>>,
    cur_groups: Vec<Vec<(usize, usize)>>,
    /// The horizontal direction's two slots and their groups.
    horizontal: [Vec<u16>; 2],
    horizontal_groups: [(usize, usize); 2],
}

/// One row of a windowed pass: its place and the penalties towards each predecessor.
struct WindowedRow<'a> {
    walk_y: usize,
    w: usize,
    forward: bool,
    p1: u16,
    pens: &'a [Vec<u16>; 4],
}

/// The pixels `xs` (walk order) of a row that share one range tile: its window of `G`
/// groups (0: any number) and its pixels' lanes from `at` in the layout, one after another.
/// `h_min`: the horizontal path's last minimum.
#[inline(always)]
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn tile_run<const G: usize>(
    row: &WindowedRow<'_>,
    rows: &mut WindowedRows,
    xs: std::ops::Range<usize>,
    window: Window,
    at: usize,
    volume: &[u16],
    sums: &mut [u16],
    h_min: &mut u16,
) {
    let (w, forward, p1) = (row.w, row.forward, row.p1);
    let [pen_h, pen_v, pen_b, pen_a] = row.pens;
    let lanes = window.lanes();
    let x0 = xs.start;
    let m = rows.horizontal[0].len();
    let row_dirs = rows.prev.len();
    let walk = |i: usize| if forward { x0 + i } else { xs.end - 1 - i };
    for i in 0..xs.len() {
        let x = walk(i);
        let from = at + (x - x0) * lanes;
        let (Some(cost), Some(sum)) = (
            volume.get(from..from + lanes),
            sums.get_mut(from..from + lanes),
        ) else {
            return;
        };
        let walk_x = if forward { x } else { w - 1 - x };
        // Horizontal: the previous pixel of this row; it writes the sums.
        let [a, b] = &mut rows.horizontal;
        let (h_prev, h_out) = if walk_x % 2 == 0 { (&*a, b) } else { (&*b, a) };
        let start = walk_x == 0;
        let pen = if start { 0 } else { pen_h[x] };
        let old = &mut rows.horizontal_groups[1 - walk_x % 2];
        *h_min = step_window_dyn::<G>(
            start, true, cost, h_prev, *h_min, p1, pen, h_out, sum, window, old,
        );
        // Vertical and diagonals: the previous row at x, behind and ahead.
        let behind = if forward { x.wrapping_sub(1) } else { x + 1 };
        let ahead = if forward { x + 1 } else { x.wrapping_sub(1) };
        for dir in 0..row_dirs {
            let px = match dir {
                0 => x,
                1 => behind,
                _ => ahead,
            };
            let start = row.walk_y == 0 || px >= w;
            let (prev, prev_min, pen) = if start {
                (&rows.prev[dir][..m], 0, 0)
            } else {
                (
                    &rows.prev[dir][px * m..(px + 1) * m],
                    rows.prev_mins[dir][px],
                    match dir {
                        0 => pen_v[x],
                        1 => pen_b[x],
                        _ => pen_a[x],
                    },
                )
            };
            let out = &mut rows.cur[dir][x * m..(x + 1) * m];
            let old = &mut rows.cur_groups[dir][x];
            rows.cur_mins[dir][x] = step_window_dyn::<G>(
                start, false, cost, prev, prev_min, p1, pen, out, sum, window, old,
            );
        }
    }
}

vectorised_fn! { avx2:
/// `sgm::pass` under coarse to fine: each pixel's [`Window`] alone, its lanes in the
/// [`VolumeLayout`] of `volume` and `sums`; a range tile's pixels at a time, with its window's
/// group count known at compile time for the common counts (the per-pixel lookups and a
/// varying count cost more than the groups they skip). Each row's sums (its lanes in the
/// layout) go to `row_done(y, sums)` once complete.
fn pass_windowed(
    plan: &SweepPlan,
    layout: &VolumeLayout,
    reference_colours: &[u32],
    volume: &[u16],
    forward: bool,
    row_done: &mut dyn FnMut(usize, &[u16]),
    cancel: &CancelFlag,
) {
    let p = &plan.params;
    let (w, h) = (p.width as usize, p.height as usize);
    let n = stride(p.planes as usize);
    let (p1, p2, edge) = (p.sgm_p1, p.sgm_p2, p.sgm_edge);
    let row_dirs = if p.sgm_paths == 8 { 3 } else { 1 };
    let m = n + 2;
    let rows_of = |v| (0..row_dirs).map(|_| vec![v; w * m]).collect::<Vec<_>>();
    let groups_of = || vec![vec![(0, 0); w]; row_dirs];
    let mut rows = WindowedRows {
        prev: rows_of(PAD),
        cur: rows_of(PAD),
        prev_mins: vec![vec![0u16; w]; row_dirs],
        cur_mins: vec![vec![0u16; w]; row_dirs],
        prev_groups: groups_of(),
        cur_groups: groups_of(),
        horizontal: [vec![PAD; m], vec![PAD; m]],
        horizontal_groups: [(0, 0); 2],
    };
    let penalties = penalty_table(p1, p2, edge);
    let mut pens: [Vec<u16>; 4] = std::array::from_fn(|_| vec![penalties[0]; w]);
    let tile = crate::sweep::plan::RANGE_TILE as usize;
    let tiles = w.div_ceil(tile);
    let mut sums = Vec::new();
    for walk_y in 0..h {
        if cancel.is_cancelled() {
            return;
        }
        let y = if forward { walk_y } else { h - 1 - walk_y };
        // The row's sums, from its first lane in the layout.
        let row_start = layout.row_start(y);
        sums.resize(layout.row_start(y + 1) - row_start, 0);
        let prev_y = if forward { y.wrapping_sub(1) } else { y + 1 };
        if edge > 0 && w > 0 {
            let prev_y = (prev_y < h).then_some(prev_y);
            edge_penalties_row(
                &penalties,
                reference_colours,
                w,
                y,
                prev_y,
                forward,
                &mut pens,
            );
        }
        let row = WindowedRow {
            walk_y,
            w,
            forward,
            p1: p1 as u16,
            pens: &pens,
        };
        let mut h_min = 0u16;
        for walk_t in 0..tiles {
            let t = if forward { walk_t } else { tiles - 1 - walk_t };
            let xs = t * tile..((t + 1) * tile).min(w);
            let (at, window) = layout.pixel(xs.start, y);
            let run = (&row, &mut rows, xs, window, at - row_start, &volume[row_start..]);
            let sums = &mut sums[..];
            match window.groups().len() {
                1 => tile_run::<1>(run.0, run.1, run.2, run.3, run.4, run.5, sums, &mut h_min),
                2 => tile_run::<2>(run.0, run.1, run.2, run.3, run.4, run.5, sums, &mut h_min),
                3 => tile_run::<3>(run.0, run.1, run.2, run.3, run.4, run.5, sums, &mut h_min),
                _ => tile_run::<0>(run.0, run.1, run.2, run.3, run.4, run.5, sums, &mut h_min),
            }
        }
        row_done(y, &sums);
        std::mem::swap(&mut rows.prev, &mut rows.cur);
        std::mem::swap(&mut rows.prev_mins, &mut rows.cur_mins);
        std::mem::swap(&mut rows.prev_groups, &mut rows.cur_groups);
    }
}
}

vectorised_fn! {
/// [`super::sgm::select`] for row `y` under coarse to fine (`lanes`: the row's lanes of the
/// forward and backward sums and of the volume in `layout`, from the row's first): each pixel's [`Window`] alone (the planes outside it are absent: never
/// the winner, its neighbour or a rival, as the shader's BIG for a plane marked OUTSIDE_LEVEL).
fn select_windows(
    layout: &VolumeLayout,
    y: usize,
    unit: f32,
    lanes: [&[u16]; 3],
    unique: Option<Uniqueness>,
    st: &mut WtaChunk<'_>,
) {
    let score = |v: u16| f32::from(v) * unit - SGM_VOLUME_OFFSET;
    let [forward, backward, volume] = lanes;
    let mut sums = vec![0u16; 0];
    for x in 0..st.best.len() {
        if !(st.best[x] < 0.5 * BIG) || st.best_plane[x] < 0.0 {
            continue;
        }
        let (at, window) = layout.pixel(x, y);
        let at = at - layout.row_start(y);
        // The window's planes from its first (`lo`), at their place in its groups.
        let planes = at + window.lo - window.groups().start * LANES..;
        let planes = planes.start..planes.start + window.hi + 1 - window.lo;
        sums.resize(planes.len(), 0);
        let (Some(f), Some(b), Some(levels)) = (
            forward.get(planes.clone()),
            backward.get(planes.clone()),
            volume.get(planes),
        ) else {
            continue;
        };
        // The winner among them, its neighbours inside the window, the rival away from them
        // inside it.
        let s = winner(f, b, &mut sums);
        st.best[x] = score(s.best_sum);
        st.best_plane[x] = (window.lo + s.best) as f32;
        st.before[x] = s.before.map_or(BIG, score);
        st.after[x] = s.after.map_or(BIG, score);
        st.rival[x] = s.rival.map_or(BIG, score);
        if let Some(unique) = unique {
            st.local_confidence[x] =
                uniqueness_on_costs(levels, s.best, unique.radius, unique.levels_per_unit);
        }
    }
}
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::cpu::select::WtaState;
    use crate::sweep::cpu::sgm_select::level_score;
    use crate::sweep::{Optimizer, SweepParams};
    use crate::synthetic;

    /// Coarse to fine: a pixel's planes outside its tile's range are absent (PAD path costs,
    /// skipped by the selection and the uniqueness). The windowed passes over the compact
    /// layout against a scalar walk of every path over every plane with that rule, on a
    /// 40x6 image of three range tiles with 40 planes (three groups of lanes, the last partial),
    /// ranges that differ from row to row and tile to tile, and levels of their own in the
    /// lanes of a window's groups outside its range (which must not count); then the passes
    /// that select as they go (`run_and_select`) against it.
    #[test]
    fn windowed_passes_match_a_scalar_walk_of_the_absent_planes_rule() {
        let (w, h, planes) = (40usize, 6usize, 40usize);
        let model = CameraModel::pinhole(synthetic::intrinsics(w as u32, h as u32));
        let rig = synthetic::row_rig(2, 0.1, model, 0).expect("rig");
        let params = SweepParams {
            num_planes: planes as u32,
            optimizer: Optimizer::Sgm,
            ..SweepParams::default()
        };
        let mut base = SweepPlan::new(&rig, &params).expect("plan");
        base.params.sgm_paths = 8;
        base.params.sgm_p1 = 10;
        base.params.sgm_p2 = 60;
        base.params.sgm_edge = 0;
        base.params.sgm_unit_per_level = 1.0;
        base.params.uniqueness = 0.1;
        base.params.uniqueness_radius = 2;
        let tiles = w.div_ceil(16);
        let ranges: Vec<[u32; 2]> = (0..h * tiles)
            .map(|i| {
                let (y, t) = (i / tiles, i % tiles);
                let lo = ((y * 7 + t * 13) % 30) as u32;
                [
                    lo,
                    (lo + 3 + ((y + 2 * t) % 14) as u32).min(planes as u32 - 1),
                ]
            })
            .collect();
        let plan = base.narrow_planes(ranges.clone()).expect("narrowed");
        let window = |x: usize, y: usize| ranges[y * tiles + x / 16];
        // Levels of every pixel and plane (a fixed LCG), laid out as the sweep writes them.
        let mut seed = 12_345u32;
        let mut level = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            ((seed >> 8) % 300) as u16
        };
        let costs: Vec<Vec<u16>> = (0..w * h)
            .map(|_| (0..planes).map(|_| level()).collect())
            .collect();
        let layout = VolumeLayout::of(&plan);
        let mut volume = vec![PAD; layout.len()];
        for y in 0..h {
            for x in 0..w {
                let (at, win) = layout.pixel(x, y);
                assert_eq!([win.lo as u32, win.hi as u32], window(x, y));
                let first = win.groups().start * LANES;
                for (d, &c) in costs[y * w + x].iter().enumerate() {
                    if win.groups().contains(&(d / LANES)) {
                        volume[at + d - first] = c;
                    }
                }
            }
        }
        // The scalar walk: every direction, every plane, absent planes PAD.
        let inside = |x: usize, y: usize, d: usize| {
            let [lo, hi] = window(x, y);
            d >= lo as usize && d <= hi as usize
        };
        let (p1, p2) = (10u32, 60u32);
        let mut totals = vec![vec![0u32; planes]; w * h];
        for (dx, dy) in crate::sweep::schedule::SGM_DIRECTIONS {
            let mut l = vec![vec![0u32; planes]; w * h];
            let ys: Vec<usize> = if dy >= 0 {
                (0..h).collect()
            } else {
                (0..h).rev().collect()
            };
            let xs: Vec<usize> = if dx >= 0 {
                (0..w).collect()
            } else {
                (0..w).rev().collect()
            };
            for &y in &ys {
                for &x in &xs {
                    let (px, py) = (x as i64 - i64::from(dx), y as i64 - i64::from(dy));
                    let prev = (px >= 0 && py >= 0 && px < w as i64 && py < h as i64)
                        .then(|| l[py as usize * w + px as usize].clone());
                    for d in 0..planes {
                        l[y * w + x][d] = if !inside(x, y, d) {
                            u32::from(PAD)
                        } else if let Some(prev) = &prev {
                            let m = *prev.iter().min().expect("planes");
                            let mut best = prev[d].min(m + p2);
                            if d > 0 {
                                best = best.min(prev[d - 1] + p1);
                            }
                            if d + 1 < planes {
                                best = best.min(prev[d + 1] + p1);
                            }
                            u32::from(costs[y * w + x][d]) + best - m
                        } else {
                            u32::from(costs[y * w + x][d])
                        };
                    }
                }
            }
            for (t, l) in totals.iter_mut().zip(&l) {
                for (t, l) in t.iter_mut().zip(l) {
                    *t += l;
                }
            }
        }
        let (mut forward, mut backward) = (Vec::new(), Vec::new());
        let cancel = CancelFlag::new();
        run_two_passes(
            &plan,
            &vec![0; w * h],
            &volume,
            &mut forward,
            &mut backward,
            &cancel,
        )
        .expect("not cancelled");
        let mut state = WtaState::new(w * h);
        state.best.fill(0.0);
        state.best_plane.fill(0.0);
        select(&plan, &volume, &forward, &backward, &mut state);
        let o = SGM_VOLUME_OFFSET;
        let score = |v: u32| v as f32 - o;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let [lo, hi] = window(x, y).map(|v| v as usize);
                let sums = &totals[i];
                let best = (lo..=hi).min_by_key(|&d| (sums[d], d)).expect("a plane");
                let at = |d: usize| (lo..=hi).contains(&d).then(|| score(sums[d]));
                let rival = (lo..=hi)
                    .filter(|&d| d + 1 < best || d > best + 1)
                    .map(|d| sums[d])
                    .min();
                let want = (
                    best as f32,
                    score(sums[best]),
                    best.checked_sub(1).and_then(at).unwrap_or(BIG),
                    at(best + 1).unwrap_or(BIG),
                    rival.map_or(BIG, score),
                );
                let got = (
                    state.best_plane[i],
                    state.best[i],
                    state.before[i],
                    state.after[i],
                    state.rival[i],
                );
                assert_eq!(got, want, "pixel ({x}, {y}), window {lo}..={hi}");
                // The uniqueness on the matching costs: the rival beyond the radius, inside.
                let level_rival = (lo..=hi)
                    .filter(|&d| d + 2 < best || d > best + 2)
                    .map(|d| costs[i][d])
                    .min();
                let per_unit = plan.params.sgm_levels_per_unit;
                let want = level_rival.map_or(1.0, |r| {
                    super::super::select::confidence(
                        level_score(costs[i][best], per_unit),
                        level_score(r, per_unit),
                    )
                });
                assert_eq!(state.local_confidence[i], want, "pixel ({x}, {y})");
            }
        }
        // The passes that select as they go (`run_and_select`), on two threads (each row
        // selected by whichever pass completes it second) and on one: the same state.
        for threads in [2, 1] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let mut selected = WtaState::new(w * h);
            selected.best.fill(0.0);
            selected.best_plane.fill(0.0);
            let (mut f, mut b) = (Vec::new(), Vec::new());
            let colours = vec![0; w * h];
            pool.install(|| {
                run_and_select(
                    &plan,
                    &colours,
                    &volume,
                    &mut f,
                    &mut b,
                    &mut selected,
                    &cancel,
                )
            })
            .expect("not cancelled");
            assert!(
                selected == state,
                "{threads} threads: the selections differ"
            );
        }
    }
}
