//! Twin of `shaders/sgm.wgsl` (semi-global matching over the u16 cost volume; its selection,
//! `shaders/sgm_select.wgsl`, is `sgm_select.rs`), in the classic two-pass layout: a forward
//! pass (rows top to bottom, pixels left to right) runs the directions whose predecessor it
//! has already visited ((1,0), (0,1), and with 8 paths (1,1),
//! (-1,1)), a backward pass the four opposite ones; each keeps only the previous row's path
//! costs, and the two passes run on two threads. The planes of a pixel are u16 lanes; the
//! integer arithmetic is the shader's, so the summed path costs are exactly equal.

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;
use crate::sweep::{CancelFlag, SweepError};

use super::common::vectorised_fn;
use super::select::{WtaChunk, WtaState};
use super::sgm_select::{select_chunk, uniqueness_chunk};
// The selection over the passes' sums, where the passes' other users find it.
pub use super::sgm_select::uniqueness_on_costs;
pub(super) use super::sgm_select::{uniqueness_of, winner, Uniqueness};

/// Planes per pixel in the CPU volume are rounded up to a multiple of this (vector lanes).
pub const LANES: usize = 16;
/// The cost of a padding lane: larger than any real path cost, so it never wins a minimum
/// (the shader skips planes >= planes instead).
pub const PAD: u16 = SGM_PATH_PAD as u16;

/// u16 lanes per pixel of the CPU cost volume.
pub fn stride(planes: usize) -> usize {
    planes.next_multiple_of(LANES)
}

/// Twin of `volume_level` (common.wgsl): a scored cost, raised by SGM_VOLUME_OFFSET (the
/// half-sequence's smooth minimum goes below zero), as u16 levels.
#[inline(always)]
pub fn volume_level(levels_per_unit: f32, score: f32) -> u16 {
    // Branch-free, so a row of scores vectorises (as a scalar loop it was 36 M of the
    // demo set's ~500 M sweep instructions). `raised` is never NaN (`max` drops it), so the rounded level is
    // at least 0.5 (or +inf) and clamping it to SGM_COST_MAX before the conversion to i32 gives
    // the shader's `min(u32(..), SGM_COST_MAX)` exactly.
    let raised = (score + SGM_VOLUME_OFFSET).max(0.0);
    let level = (raised * levels_per_unit + 0.5)
        .floor()
        .min(SGM_COST_MAX as f32);
    // The whole number 0..=SGM_COST_MAX as an integer without `as` (a saturating conversion
    // the compiler does one lane at a time): added to 2^23 it is the float's mantissa.
    let level = ((level + 8_388_608.0).to_bits() - 0x4b00_0000) as u16;
    if score >= 0.5 * BIG {
        SGM_COST_MAX as u16
    } else {
        level
    }
}

/// Twin of `colour_step`: the largest RGB channel difference of two packed colours.
#[inline(always)]
fn colour_step(a: u32, b: u32) -> u32 {
    let d = |shift: u32| ((a >> shift) & 0xff).abs_diff((b >> shift) & 0xff);
    d(0).max(d(8)).max(d(16))
}

/// One path step for one pixel over all its planes (`line_term` of sgm.wgsl):
/// `L = cost + min(prev, prev -+ 1 + P1, prev_min + P2) - prev_min`, or `L = cost` at the
/// start of a path (`START`); `L` goes into `out` (one PAD lane on each side, as `prev`) and is
/// written (`FIRST`) or added into `sum`. Returns the minimum of `L`. `N` lanes per pixel when
/// known at compile time ([`step_fixed`]), else 0 and as many as `cost` has.
#[inline(always)]
fn step<const N: usize, const START: bool, const FIRST: bool>(
    cost: &[u16],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    sum: &mut [u16],
) -> u16 {
    if N > 0 {
        return step_fixed::<N, START, FIRST>(cost, prev, prev_min, p1, p2, out, sum);
    }
    let n = cost.len();
    let (out, sum) = (&mut out[1..=n], &mut sum[..n]);
    let (minus, mid, plus) = (&prev[..n], &prev[1..=n], &prev[2..n + 2]);
    let jump = prev_min.saturating_add(p2);
    // Fixed chunks of LANES, so the compiler keeps each in one vector register (n is a
    // multiple of LANES).
    let mut lowest = [u16::MAX; LANES];
    for (((((cost, out), sum), minus), mid), plus) in cost
        .chunks_exact(LANES)
        .zip(out.chunks_exact_mut(LANES))
        .zip(sum.chunks_exact_mut(LANES))
        .zip(minus.chunks_exact(LANES))
        .zip(mid.chunks_exact(LANES))
        .zip(plus.chunks_exact(LANES))
    {
        for i in 0..LANES {
            let l = if START {
                cost[i]
            } else {
                let best = mid[i]
                    .min(minus[i].saturating_add(p1))
                    .min(plus[i].saturating_add(p1))
                    .min(jump);
                cost[i].saturating_add(best - prev_min)
            };
            out[i] = l;
            sum[i] = if FIRST { l } else { sum[i].wrapping_add(l) };
            lowest[i] = lowest[i].min(l);
        }
    }
    // A plain fold of the 16 lanes: the compiler reduces it with the horizontal minimum of
    // eight u16 (`phminposuw`), where the tree of halves written out compiled into shuffles.
    lowest.iter().fold(u16::MAX, |a, &b| a.min(b))
}

/// [`step`] for `N` lanes known at compile time (a multiple of LANES): `L` is made in a local
/// array from the loads alone, then stored, so the compiler keeps it in registers and needs no
/// run-time checks of `out` and `sum` against the loaded slices (with the lane count read at run
/// time the demo's path steps took ~1000 instructions per pixel and pass, their minimum going
/// through the stack).
#[inline(always)]
fn step_fixed<const N: usize, const START: bool, const FIRST: bool>(
    cost: &[u16],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    sum: &mut [u16],
) -> u16 {
    let (cost, prev, out, sum) = (&cost[..N], &prev[..N + 2], &mut out[1..=N], &mut sum[..N]);
    let jump = prev_min.saturating_add(p2);
    let mut l = [0u16; N];
    for i in 0..N {
        l[i] = if START {
            cost[i]
        } else {
            let best = prev[i + 1]
                .min(prev[i].saturating_add(p1))
                .min(prev[i + 2].saturating_add(p1))
                .min(jump);
            cost[i].saturating_add(best - prev_min)
        };
    }
    out.copy_from_slice(&l);
    for i in 0..N {
        sum[i] = if FIRST {
            l[i]
        } else {
            sum[i].wrapping_add(l[i])
        };
    }
    // The minimum a vector of LANES at a time (`lowest[i % LANES]` over all N lanes compiled
    // into one lane at a time above 32 lanes: the ring's 96 planes).
    let mut lowest = [u16::MAX; LANES];
    for chunk in l.chunks_exact(LANES) {
        for i in 0..LANES {
            lowest[i] = lowest[i].min(chunk[i]);
        }
    }
    // A plain fold of the 16 lanes: the compiler reduces it with the horizontal minimum of
    // eight u16 (`phminposuw`), where the tree of halves written out compiled into shuffles.
    lowest.iter().fold(u16::MAX, |a, &b| a.min(b))
}

/// `step` with its two switches as run-time values.
#[inline(always)]
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
pub(super) fn step_dyn<const N: usize>(
    start: bool,
    first: bool,
    cost: &[u16],
    prev: &[u16],
    prev_min: u16,
    p1: u16,
    p2: u16,
    out: &mut [u16],
    sum: &mut [u16],
) -> u16 {
    match (start, first) {
        (true, true) => step::<N, true, true>(cost, prev, prev_min, p1, p2, out, sum),
        (true, false) => step::<N, true, false>(cost, prev, prev_min, p1, p2, out, sum),
        (false, true) => step::<N, false, true>(cost, prev, prev_min, p1, p2, out, sum),
        (false, false) => step::<N, false, false>(cost, prev, prev_min, p1, p2, out, sum),
    }
}

/// The per-pixel penalties of one path step: P2 lowered at colour edges (`sgm_edge`).
#[inline(always)]
fn penalty2(p1: u32, p2: u32, edge: u32, step: u32) -> u16 {
    if edge == 0 {
        return p2 as u16;
    }
    p1.max(p2 * edge / (edge + 16 * step)) as u16
}

/// P2 for every colour step (0..255): the shader's integer division, done once per pass.
pub(super) fn penalty_table(p1: u32, p2: u32, edge: u32) -> Vec<u16> {
    (0..256u32)
        .map(|step| penalty2(p1, p2, edge, step))
        .collect()
}

vectorised_fn! { avx2:
/// One pass over the image in walk order (`forward`: top to bottom, left to right; else the
/// reverse), summing the path costs of its directions a row at a time: each row's sums (the
/// row's pixels in x order, `stride` lanes each) go to `row_done(y, sums)` once complete. Stops
/// between rows once `cancel` is set (rows are then missing; the caller checks).
fn pass(plan: &SweepPlan, reference_colours: &[u32], volume: &[u16], forward: bool, row_done: &mut dyn FnMut(usize, &[u16]), cancel: &CancelFlag) {
    // The common lane counts known at compile time (the demo's 32 planes: 32; `step_fixed`).
    match stride(plan.params.planes as usize) {
        16 => pass_lanes::<16>(plan, reference_colours, volume, forward, row_done, cancel),
        32 => pass_lanes::<32>(plan, reference_colours, volume, forward, row_done, cancel),
        48 => pass_lanes::<48>(plan, reference_colours, volume, forward, row_done, cancel),
        64 => pass_lanes::<64>(plan, reference_colours, volume, forward, row_done, cancel),
        96 => pass_lanes::<96>(plan, reference_colours, volume, forward, row_done, cancel),
        128 => pass_lanes::<128>(plan, reference_colours, volume, forward, row_done, cancel),
        _ => pass_lanes::<0>(plan, reference_colours, volume, forward, row_done, cancel),
    }
}
}

/// [`pass`] with every row's sums written into `sums` (the volume's layout).
fn pass_into(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: bool,
    sums: &mut [u16],
    cancel: &CancelFlag,
) {
    let row = plan.params.width as usize * stride(plan.params.planes as usize);
    let mut write = |y: usize, row_sums: &[u16]| {
        sums[y * row..(y + 1) * row].copy_from_slice(row_sums);
    };
    pass(plan, reference_colours, volume, forward, &mut write, cancel);
}

/// The body of [`pass`] for `N` lanes per pixel (0: any number).
#[inline(always)]
fn pass_lanes<const N: usize>(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: bool,
    row_done: &mut dyn FnMut(usize, &[u16]),
    cancel: &CancelFlag,
) {
    {
        let p = &plan.params;
        let (w, h) = (p.width as usize, p.height as usize);
        let n = if N == 0 { stride(p.planes as usize) } else { N };
        let (p1, p2, edge) = (p.sgm_p1, p.sgm_p2, p.sgm_edge);
        // Path costs with a PAD lane on each side: the previous and current row of the vertical
        // and (8 paths) the two diagonal directions, and the last two pixels of the horizontal one.
        let row_dirs = if p.sgm_paths == 8 { 3 } else { 1 };
        let row_buffer = || vec![PAD; w * (n + 2)];
        let mut prev_rows: Vec<Vec<u16>> = (0..row_dirs).map(|_| row_buffer()).collect();
        let mut cur_rows: Vec<Vec<u16>> = (0..row_dirs).map(|_| row_buffer()).collect();
        let mut prev_mins = vec![vec![0u16; w]; row_dirs];
        let mut cur_mins = vec![vec![0u16; w]; row_dirs];
        let mut horizontal = [vec![PAD; n + 2], vec![PAD; n + 2]];
        let mut sums = vec![0u16; w * n];
        let penalties = penalty_table(p1, p2, edge);
        let p1 = p1 as u16;
        // Each pixel's P2 towards its predecessor in every direction, a row at a time (x order):
        // horizontal, vertical, diagonal behind, diagonal ahead. Without `sgm_edge` all are P2.
        let mut pens: [Vec<u16>; 4] = std::array::from_fn(|_| vec![penalties[0]; w]);
        for walk_y in 0..h {
            if cancel.is_cancelled() {
                return;
            }
            let y = if forward { walk_y } else { h - 1 - walk_y };
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
            let [pen_h, pen_v, pen_b, pen_a] = &pens;
            let mut h_min = 0u16;
            for walk_x in 0..w {
                let x = if forward { walk_x } else { w - 1 - walk_x };
                let pix = y * w + x;
                let cost = &volume[pix * n..(pix + 1) * n];
                let sum = &mut sums[x * n..(x + 1) * n];
                // Predecessor columns in walk order: behind (x - s) and ahead (x + s).
                let behind = if forward { x.wrapping_sub(1) } else { x + 1 };
                let ahead = if forward { x + 1 } else { x.wrapping_sub(1) };

                // Horizontal: the previous pixel of this row; it writes the sums.
                let [a, b] = &mut horizontal;
                let (h_prev, h_out) = if walk_x % 2 == 0 { (&*a, b) } else { (&*b, a) };
                let start = walk_x == 0;
                let pen = if start { 0 } else { pen_h[x] };
                h_min = step_dyn::<N>(start, true, cost, h_prev, h_min, p1, pen, h_out, sum);

                // Vertical and diagonals: the previous row at x, behind and ahead.
                for dir in 0..row_dirs {
                    let px = match dir {
                        0 => x,
                        1 => behind,
                        _ => ahead,
                    };
                    let start = walk_y == 0 || px >= w;
                    let (prev, prev_min, pen) = if start {
                        (&prev_rows[dir][..n + 2], 0, 0)
                    } else {
                        (
                            &prev_rows[dir][px * (n + 2)..(px + 1) * (n + 2)],
                            prev_mins[dir][px],
                            match dir {
                                0 => pen_v[x],
                                1 => pen_b[x],
                                _ => pen_a[x],
                            },
                        )
                    };
                    let out = &mut cur_rows[dir][x * (n + 2)..(x + 1) * (n + 2)];
                    cur_mins[dir][x] =
                        step_dyn::<N>(start, false, cost, prev, prev_min, p1, pen, out, sum);
                }
            }
            row_done(y, &sums);
            std::mem::swap(&mut prev_rows, &mut cur_rows);
            std::mem::swap(&mut prev_mins, &mut cur_mins);
        }
    }
}

/// P2 of every pixel of row `y` towards its predecessor in each direction (`penalty2` of the
/// colour step, looked up in `penalties`), in x order, for a pass walking `forward` or back:
/// `pens` = [horizontal (x -+ 1), vertical (x on `prev_y`), diagonal behind (x -+ 1 on
/// `prev_y`), diagonal ahead (x +- 1 on `prev_y`)]; `prev_y` None on the first row. Entries
/// whose predecessor is outside the image keep their last value (never read: a path starts
/// there). The colour steps of a row vectorise; the per-pixel lookups were a third of a pass.
#[inline(always)]
pub(super) fn edge_penalties_row(
    penalties: &[u16],
    colours: &[u32],
    w: usize,
    y: usize,
    prev_y: Option<usize>,
    forward: bool,
    pens: &mut [Vec<u16>; 4],
) {
    let lookup = |here: &[u32], there: &[u32], out: &mut [u16]| {
        let mut steps = [0u32; 64];
        for ((here, there), out) in here
            .chunks(64)
            .zip(there.chunks(64))
            .zip(out.chunks_mut(64))
        {
            let n = out.len();
            for ((s, &a), &b) in steps[..n].iter_mut().zip(here).zip(there) {
                *s = colour_step(a, b);
            }
            for (o, &s) in out.iter_mut().zip(&steps[..n]) {
                *o = penalties[s as usize];
            }
        }
    };
    let cur = &colours[y * w..(y + 1) * w];
    let [pen_h, pen_v, pen_b, pen_a] = pens;
    // Behind = x - 1 walking forward, x + 1 back; ahead the other way.
    let (lo, hi) = (1..w, 0..w - 1);
    let (behind_x, behind_from) = if forward {
        (lo.clone(), hi.clone())
    } else {
        (hi.clone(), lo.clone())
    };
    lookup(
        &cur[behind_x.clone()],
        &cur[behind_from.clone()],
        &mut pen_h[behind_x.clone()],
    );
    if let Some(prev_y) = prev_y {
        let prev = &colours[prev_y * w..(prev_y + 1) * w];
        lookup(cur, prev, pen_v);
        lookup(
            &cur[behind_x.clone()],
            &prev[behind_from.clone()],
            &mut pen_b[behind_x.clone()],
        );
        lookup(
            &cur[behind_from.clone()],
            &prev[behind_x.clone()],
            &mut pen_a[behind_from],
        );
    }
}

/// Both passes, on two threads: the forward directions' path costs summed into `forward`, the
/// backward ones' into `backward` (resized to the volume; [`select`] adds the two). Not for a
/// narrowed plan, whose volume holds each pixel's window alone (`sgm_windows`).
/// `Err(Cancelled)` when `cancel` stopped it between rows. The engine runs [`run_and_select`]
/// (these passes selecting as they go), or the wide layout where it
/// [`super::sgm_wide::applies`] (4 threads or more); the whole sums here are what both are
/// tested against.
pub fn run_two_passes(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    cancel: &CancelFlag,
) -> Result<(), SweepError> {
    forward_and_backward(volume.len(), forward, backward, |walks_forward, sums| {
        pass_into(plan, reference_colours, volume, walks_forward, sums, cancel)
    });
    cancel.check()
}

/// [`run_two_passes`] and [`select`] in one: the two passes on two threads, each row's winner
/// selected by the pass that completes the row second, from its own sums (still in cache) and
/// those the other pass stored; the first stores its row into `forward` or `backward` (about
/// half the rows each). The selection is [`select`]'s bit for bit, and neither the second
/// reading of both sums nor half their stores is made (a rectified pair's selection was
/// bound by those reads). On one thread the forward pass stores every row and the backward
/// pass selects them all.
pub fn run_and_select(
    plan: &SweepPlan,
    reference_colours: &[u32],
    volume: &[u16],
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    state: &mut WtaState,
    cancel: &CancelFlag,
) -> Result<(), SweepError> {
    let p = &plan.params;
    let planes = plan.num_planes() as usize;
    let n = stride(planes);
    let w = p.width as usize;
    if w == 0 || planes == 0 {
        return cancel.check();
    }
    let (unit, unique) = (p.sgm_unit_per_level, uniqueness_of(plan));
    let row_lanes: Vec<usize> = (0..=p.height as usize).map(|y| y * w * n).collect();
    let select_row = |_y: usize, [f, b, levels]: [&[u16]; 3], st: &mut WtaChunk<'_>| {
        select_chunk(planes, n, unit, f, b, st);
        if let Some(unique) = unique {
            uniqueness_chunk(planes, n, unique, levels, st);
        }
    };
    let walk = |walks_forward: bool, row_done: &mut dyn FnMut(usize, &[u16])| {
        pass(
            plan,
            reference_colours,
            volume,
            walks_forward,
            row_done,
            cancel,
        );
    };
    let sums = [forward, backward];
    passes_selecting(&row_lanes, w, volume, sums, state, walk, select_row);
    cancel.check()
}

/// The core of [`run_and_select`] for any layout of the volume (row `y`'s lanes in the volume
/// and its sums are `row_lanes[y]..row_lanes[y + 1]`, its pixels `width` of `state`):
/// `walk(forward, row_done)` runs one pass, handing each row's sums to `row_done(y, sums)`; both run on two
/// threads. The pass that completes a row first stores it into its sums (`sums[0]` forward,
/// `sums[1]` backward, resized to the volume); the second selects it, `select_row(y, [forward,
/// backward, volume], state)` on the row's lanes and its pixels' state.
pub(super) fn passes_selecting(
    row_lanes: &[usize],
    width: usize,
    volume: &[u16],
    sums: [&mut Vec<u16>; 2],
    state: &mut WtaState,
    walk: impl Fn(bool, &mut dyn FnMut(usize, &[u16])) + Sync,
    select_row: impl Fn(usize, [&[u16]; 3], &mut WtaChunk<'_>) + Sync,
) {
    /// A row of the image: the sums each pass may store, its pixels' selection state and
    /// costs, and whether one pass has stored its sums.
    struct Row<'a> {
        forward: &'a mut [u16],
        backward: &'a mut [u16],
        state: WtaChunk<'a>,
        volume: &'a [u16],
        stored: bool,
    }
    let [forward, backward] = sums;
    forward.resize(volume.len(), 0);
    backward.resize(volume.len(), 0);
    let (mut f, mut b, mut v) = (&mut forward[..], &mut backward[..], volume);
    let rows: Vec<std::sync::Mutex<Row<'_>>> = state
        .chunks_mut(width.max(1))
        .into_iter()
        .zip(row_lanes.windows(2))
        .map(|(state, lanes)| {
            let len = (lanes[1] - lanes[0]).min(v.len());
            let (forward, rest) = std::mem::take(&mut f).split_at_mut(len);
            f = rest;
            let (backward, rest) = std::mem::take(&mut b).split_at_mut(len);
            b = rest;
            let (volume, rest) = v.split_at(len);
            v = rest;
            std::sync::Mutex::new(Row {
                forward,
                backward,
                state,
                volume,
                stored: false,
            })
        })
        .collect();
    let walk = |walks_forward: bool| {
        let mut row_done = |y: usize, sums: &[u16]| {
            let Some(row) = rows.get(y) else {
                return;
            };
            // A pass that panicked leaves no half-written row behind a lock: its rows are
            // written whole before `stored` is set.
            let mut guard = row
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let row = &mut *guard;
            if !row.stored {
                let own = if walks_forward {
                    &mut *row.forward
                } else {
                    &mut *row.backward
                };
                own.copy_from_slice(sums);
                row.stored = true;
                return;
            }
            let (f, b) = if walks_forward {
                (sums, &*row.backward)
            } else {
                (&*row.forward, sums)
            };
            select_row(y, [f, b, row.volume], &mut row.state);
        };
        walk(walks_forward, &mut row_done);
    };
    rayon::join(|| walk(true), || walk(false));
}

/// `pass` walking forward into `forward` and backward into `backward` on two threads, the sums
/// resized to the volume's `lanes` first (every layout of the passes runs its two so).
pub(super) fn forward_and_backward(
    lanes: usize,
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    pass: impl Fn(bool, &mut [u16]) + Sync,
) {
    forward.resize(lanes, 0);
    backward.resize(lanes, 0);
    rayon::join(|| pass(true, forward), || pass(false, backward));
}

/// Twin of `sgm_select.wgsl`: winner-take-all over the summed path costs (score units) into
/// the selection state, for every pixel the local winner-take-all found valid. The streaming
/// selection's result written directly: the first minimum, its two neighbours, and the
/// smallest sum away from them (`u16` sums map to scores strictly monotonically). Where
/// `uniqueness` or `ambiguity` reads it, the winner's uniqueness on the matching costs of
/// `volume` too ([`uniqueness_on_costs`]).
pub fn select(
    plan: &SweepPlan,
    volume: &[u16],
    forward: &[u16],
    backward: &[u16],
    state: &mut WtaState,
) {
    use rayon::prelude::*;
    let planes = plan.num_planes() as usize;
    let n = stride(planes);
    let p = &plan.params;
    let unit = p.sgm_unit_per_level;
    let chunk = 1024;
    let unique = uniqueness_of(plan);
    state
        .chunks_mut(chunk)
        .into_par_iter()
        .zip(
            forward
                .par_chunks(chunk * n)
                .zip(backward.par_chunks(chunk * n))
                .zip(volume.par_chunks(chunk * n)),
        )
        .for_each(|(mut st, ((forward, backward), volume))| {
            select_chunk(planes, n, unit, forward, backward, &mut st);
            if let Some(unique) = unique {
                uniqueness_chunk(planes, n, unique, volume, &mut st);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::{Optimizer, SweepParams};
    use crate::synthetic;

    /// A 2x1 image with 3 planes, P1 = 10, P2 = 30 levels, 4 paths (the vertical ones are
    /// one pixel long, so they add each pixel's own cost).
    fn plan() -> SweepPlan {
        let model = CameraModel::pinhole(synthetic::intrinsics(2, 1));
        let rig = synthetic::row_rig(2, 0.1, model, 0).expect("rig");
        let params = SweepParams {
            num_planes: 3,
            optimizer: Optimizer::Sgm,
            ..SweepParams::default()
        };
        let mut plan = SweepPlan::new(&rig, &params).expect("plan");
        plan.params.sgm_paths = 4;
        plan.params.sgm_p1 = 10;
        plan.params.sgm_p2 = 30;
        plan.params.sgm_edge = 0;
        plan.params.sgm_unit_per_level = 1.0;
        plan
    }

    fn volume(pixels: &[[u16; 3]]) -> Vec<u16> {
        let n = stride(3);
        let mut v = vec![PAD; pixels.len() * n];
        for (i, c) in pixels.iter().enumerate() {
            v[i * n..i * n + 3].copy_from_slice(c);
        }
        v
    }

    fn real(sums: &[u16]) -> Vec<[u16; 3]> {
        sums.chunks(stride(3)).map(|c| [c[0], c[1], c[2]]).collect()
    }

    #[test]
    fn path_costs_by_hand() {
        let plan = plan();
        // Pixel 0 is sure of plane 0; pixel 1 slightly prefers plane 2 locally.
        let costs = volume(&[[0, 50, 50], [5, 40, 0]]);
        let mut sums = vec![0u16; costs.len()];
        pass_into(&plan, &[0, 0], &costs, true, &mut sums, &CancelFlag::new());
        // Left to right, pixel 1: d0 = 5 + min(0, 50 + 10, 0 + 30) - 0 = 5; d1 = 40 + min(50,
        // 0 + 10, 50 + 10, 30) = 50; d2 = 0 + min(50, 50 + 10, 30) = 30. The vertical path
        // adds the pixel's own cost.
        assert_eq!(real(&sums), [[0, 100, 100], [10, 90, 30]]);
        // Right to left, pixel 0: d0 = 0 + min(5, 40 + 10, 0 + 30) - 0 = 5; d1 = 50 + min(40,
        // 5 + 10, 0 + 10, 30) - 0 = 60; d2 = 50 + min(0, 40 + 10, 30) = 50.
        pass_into(&plan, &[0, 0], &costs, false, &mut sums, &CancelFlag::new());
        assert_eq!(real(&sums), [[5, 110, 100], [10, 80, 0]]);
        let (mut forward, mut backward) = (Vec::new(), Vec::new());
        run_two_passes(
            &plan,
            &[0, 0],
            &costs,
            &mut forward,
            &mut backward,
            &CancelFlag::new(),
        )
        .expect("not cancelled");
        let total: Vec<u16> = forward
            .iter()
            .zip(&backward)
            .map(|(a, b)| a.wrapping_add(*b))
            .collect();
        assert_eq!(real(&total), [[5, 210, 200], [20, 170, 30]]);
        let mut state = WtaState::new(2);
        state.best.fill(0.0);
        state.best_plane.fill(2.0);
        select(&plan, &costs, &forward, &backward, &mut state);
        // Pixel 1 moves to plane 0; its neighbour is plane 1, and plane 2 is the rival (in
        // score units, less the volume's offset).
        assert_eq!(state.best_plane, [0.0, 0.0]);
        let o = SGM_VOLUME_OFFSET;
        assert_eq!(
            (state.best[1], state.after[1], state.rival[1]),
            (20.0 - o, 170.0 - o, 30.0 - o)
        );
        assert_eq!(state.before[1], BIG);
    }

    /// The passes that select ([`run_and_select`]) leave the selection state [`select`] leaves
    /// after [`run_two_passes`], bit for bit, on two threads (rows stored by either pass,
    /// the meeting row contended) and on one (the forward pass stores every row), with the
    /// uniqueness on the costs read and pixels the local winner-take-all left invalid.
    #[test]
    fn the_passes_select_what_select_selects() {
        use crate::sweep::cpu::sgm_wide::tests::{noise, plan};
        for (w, h, planes, paths, edge) in [
            (37, 19, 32, 8, true),
            (53, 7, 40, 8, false),
            (29, 11, 72, 4, true),
            (8, 1, 16, 8, false),
        ] {
            let mut plan = plan(w, h, planes, paths, edge);
            plan.params.uniqueness = 0.2;
            plan.params.uniqueness_radius = 2;
            let n = stride(plan.params.planes as usize);
            let pixels = (w * h) as usize;
            let volume: Vec<u16> = noise(pixels * n, planes, 300)
                .into_iter()
                .enumerate()
                .map(|(i, v)| {
                    if i % n >= planes as usize {
                        PAD
                    } else {
                        v as u16
                    }
                })
                .collect();
            let colours = noise(pixels, w, 1 << 24);
            // The local winner-take-all's state: every 7th pixel invalid.
            let mut before = WtaState::new(pixels);
            for i in 0..pixels {
                if i % 7 != 3 {
                    before.best[i] = 1.0;
                    before.best_plane[i] = (i % planes as usize) as f32;
                    before.local_confidence[i] = 0.5;
                }
            }
            let cancel = CancelFlag::new();
            let (mut f, mut b) = (vec![], vec![]);
            run_two_passes(&plan, &colours, &volume, &mut f, &mut b, &cancel).expect("passes");
            let mut expected = before.clone();
            select(&plan, &volume, &f, &b, &mut expected);
            assert_ne!(expected, before, "{w}x{h}: the selection changed nothing");
            for threads in [2, 1] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                let mut state = before.clone();
                let (mut f, mut b) = (vec![], vec![]);
                pool.install(|| {
                    run_and_select(
                        &plan, &colours, &volume, &mut f, &mut b, &mut state, &cancel,
                    )
                })
                .expect("passes");
                assert!(
                    state == expected,
                    "{w}x{h}, {planes} planes, {paths} paths, {threads} threads: the selections differ"
                );
            }
        }
    }

    /// The half-sequence's smooth minimum scores the best matches below zero (down to
    /// -HALF_NOISE_FLOOR / 4): they keep distinct levels, and tau still fits.
    #[test]
    fn negative_scores_keep_their_levels() {
        let plan = plan();
        let per_unit = plan.params.sgm_levels_per_unit;
        let level = |score: f32| volume_level(per_unit, score);
        let floor = -HALF_NOISE_FLOOR / 4.0;
        assert_eq!(level(floor), 0);
        assert!(level(floor) < level(-4.0));
        assert!(level(-4.0) < level(-1.0));
        assert!(level(-1.0) < level(0.0));
        assert_eq!(
            level(100.0),
            SGM_COST_MAX as u16,
            "tau (100) is the top level"
        );
        assert!(level(99.0) < SGM_COST_MAX as u16);
        assert_eq!(level(BIG), SGM_COST_MAX as u16);
    }

    #[test]
    fn edge_step_lowers_p2() {
        let mut plan = plan();
        // Edge = 8 grey levels (x 16): a step of 8 halves P2 (30 -> 15).
        plan.params.sgm_edge = 8 * 16;
        let costs = volume(&[[0, 50, 50], [50, 50, 0]]);
        let mut sums = vec![0u16; costs.len()];
        pass_into(&plan, &[0, 8], &costs, true, &mut sums, &CancelFlag::new());
        // Pixel 1, plane 2: 0 + min(50, 50 + 10, 0 + 15) = 15, plus its own vertical 0.
        assert_eq!(real(&sums)[1], [100, 110, 15]);
    }
}
