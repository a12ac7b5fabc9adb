//! SGM's passes on many threads: the same path costs and sums as the two passes of
//! [`super::sgm::run_two_passes`] (each on one thread, whatever the machine has), laid out so
//! that every thread works.
//! A path direction that runs along the columns or diagonals needs only the previous row, so
//! each row's pixels are independent: the top-to-bottom directions (vertical and both
//! diagonals) and the bottom-to-top ones run side by side as before, each row split into
//! column chunks across the threads. The horizontal directions, which need the previous pixel
//! of their own row, run after them with the rows in parallel. The sums are wrapping `u16`
//! adds, so the order in which the directions add into them changes nothing: the forward and
//! backward sums together are bit for bit the two-pass layout's (`tests` below, and the
//! engine suites through [`applies`] forced on).
//!
//! Used where the machine has at least [`MIN_THREADS`] threads: a 16-core machine's SGM stage
//! took 1.4-1.7x the 2-core machine's with two passes on two threads (`bench --device cpu`:
//! ring 219 ms against 128 ms), the largest stage of a set there. On 2 threads the two passes
//! keep both threads busy already, and the wide layout reads the volume three times (the two
//! row walks and the horizontal pass) where they read it twice (not measured on 2 threads).
//! Not for a narrowed plan (coarse to fine), whose compact volume the two passes walk.

use std::sync::atomic::{AtomicU8, Ordering};

use rayon::prelude::*;

use crate::sweep::plan::SweepPlan;
use crate::sweep::{CancelFlag, SweepError};

use super::common::vectorised_fn;
use super::sgm::{edge_penalties_row, forward_and_backward, penalty_table, step_dyn, stride, PAD};

/// The fewest threads with which the wide layout is used.
pub const MIN_THREADS: usize = 4;

/// Forces the layout for tests and benches: 0 as the machine decides, 1 always wide, 2 never.
static FORCE: AtomicU8 = AtomicU8::new(0);

/// Forces ([`Some`]) or frees ([`None`]) the choice of layout (tests compare the two layouts'
/// sums on one machine).
pub fn force(wide: Option<bool>) {
    FORCE.store(
        match wide {
            None => 0,
            Some(true) => 1,
            Some(false) => 2,
        },
        Ordering::Relaxed,
    );
}

/// Whether `plan`'s SGM runs in the wide layout on this thread pool. Never for a narrowed
/// plan (coarse to fine): its volume holds each pixel's window of planes alone
/// (`sgm_windows::VolumeLayout`), which the two passes walk at a fraction of the full volume's cost.
pub fn applies(plan: &SweepPlan) -> bool {
    if plan.narrowed() {
        return false;
    }
    match FORCE.load(Ordering::Relaxed) {
        1 => true,
        2 => false,
        _ => plan.params.width > 0 && rayon::current_num_threads() >= MIN_THREADS,
    }
}

/// The wide layout of [`super::sgm::run_two_passes`]: the same `forward + backward` sums.
pub fn run(
    plan: &SweepPlan,
    colours: &[u32],
    volume: &[u16],
    forward: &mut Vec<u16>,
    backward: &mut Vec<u16>,
    cancel: &CancelFlag,
) -> Result<(), SweepError> {
    forward_and_backward(volume.len(), forward, backward, |walks_forward, sums| {
        rows_pass(plan, colours, volume, walks_forward, sums, cancel)
    });
    cancel.check()?;
    horizontal(plan, colours, volume, forward, cancel);
    cancel.check()
}

/// Columns per chunk of a row: one chunk per thread, at least 16 columns (on 16 cores four
/// chunks per thread, or at least 64 columns, measured the same or slower on the ring;
/// docs/notes/speed-history.md).
fn chunk_columns(width: usize) -> usize {
    width.div_ceil(rayon::current_num_threads()).max(16)
}

/// The directions along columns and diagonals of one walk (`forward`: top to bottom), their
/// path costs written into `sums` (the vertical) and added (the diagonals).
fn rows_pass(
    plan: &SweepPlan,
    colours: &[u32],
    volume: &[u16],
    forward: bool,
    sums: &mut [u16],
    cancel: &CancelFlag,
) {
    let p = &plan.params;
    let (w, h) = (p.width as usize, p.height as usize);
    let n = stride(p.planes as usize);
    let dirs = if p.sgm_paths == 8 { 3 } else { 1 };
    let (p1, p2, edge) = (p.sgm_p1, p.sgm_p2, p.sgm_edge);
    let penalties = penalty_table(p1, p2, edge);
    // Path costs of the previous and current row, [x][direction][PAD, lanes, PAD], and their
    // minima [x][direction].
    let mut prev = vec![PAD; w * dirs * (n + 2)];
    let mut cur = prev.clone();
    let mut prev_mins = vec![0u16; w * dirs];
    let mut cur_mins = prev_mins.clone();
    let mut pens: [Vec<u16>; 4] = std::array::from_fn(|_| vec![penalties[0]; w]);
    let chunk = chunk_columns(w);
    for walk_y in 0..h {
        if cancel.is_cancelled() {
            return;
        }
        let y = if forward { walk_y } else { h - 1 - walk_y };
        let prev_y = if forward { y.wrapping_sub(1) } else { y + 1 };
        if edge > 0 && w > 0 {
            let prev_y = (prev_y < h).then_some(prev_y);
            edge_penalties_row(&penalties, colours, w, y, prev_y, forward, &mut pens);
        }
        let row = Row {
            n,
            dirs,
            w,
            first: walk_y == 0,
            forward,
            p1: p1 as u16,
            costs: &volume[y * w * n..(y + 1) * w * n],
            prev: &prev,
            prev_mins: &prev_mins,
            pens: &pens,
        };
        sums[y * w * n..(y + 1) * w * n]
            .par_chunks_mut(chunk * n)
            .zip(cur.par_chunks_mut(chunk * dirs * (n + 2)))
            .zip(cur_mins.par_chunks_mut(chunk * dirs))
            .enumerate()
            .for_each(|(c, ((sums, cur), mins))| rows_chunk(&row, c * chunk, sums, cur, mins));
        std::mem::swap(&mut prev, &mut cur);
        std::mem::swap(&mut prev_mins, &mut cur_mins);
    }
}

/// What every chunk of one row of [`rows_pass`] reads.
struct Row<'a> {
    n: usize,
    dirs: usize,
    w: usize,
    /// The walk's first row: every path starts here.
    first: bool,
    forward: bool,
    p1: u16,
    /// The row's costs, `w x n`.
    costs: &'a [u16],
    prev: &'a [u16],
    prev_mins: &'a [u16],
    pens: &'a [Vec<u16>; 4],
}

vectorised_fn! { avx2:
/// The columns `x0..` of one row (as many as `mins` holds): each direction's path step from
/// the previous row (at x, behind and ahead), into `cur` and `mins`, written (the vertical)
/// or added (the diagonals) into `sums`.
fn rows_chunk(row: &Row<'_>, x0: usize, sums: &mut [u16], cur: &mut [u16], mins: &mut [u16]) {
    match row.n {
        16 => rows_chunk_lanes::<16>(row, x0, sums, cur, mins),
        32 => rows_chunk_lanes::<32>(row, x0, sums, cur, mins),
        48 => rows_chunk_lanes::<48>(row, x0, sums, cur, mins),
        64 => rows_chunk_lanes::<64>(row, x0, sums, cur, mins),
        96 => rows_chunk_lanes::<96>(row, x0, sums, cur, mins),
        128 => rows_chunk_lanes::<128>(row, x0, sums, cur, mins),
        _ => rows_chunk_lanes::<0>(row, x0, sums, cur, mins),
    }
}
}

#[inline(always)]
fn rows_chunk_lanes<const N: usize>(
    row: &Row<'_>,
    x0: usize,
    sums: &mut [u16],
    cur: &mut [u16],
    mins: &mut [u16],
) {
    let (n, dirs, w, m) = (row.n, row.dirs, row.w, row.n + 2);
    let [_, pen_v, pen_b, pen_a] = row.pens;
    for i in 0..mins.len() / dirs {
        let x = x0 + i;
        let cost = &row.costs[x * n..(x + 1) * n];
        let sum = &mut sums[i * n..(i + 1) * n];
        let behind = if row.forward {
            x.wrapping_sub(1)
        } else {
            x + 1
        };
        let ahead = if row.forward {
            x + 1
        } else {
            x.wrapping_sub(1)
        };
        for dir in 0..dirs {
            let (px, pen) = match dir {
                0 => (x, pen_v[x]),
                1 => (behind, pen_b[x]),
                _ => (ahead, pen_a[x]),
            };
            let start = row.first || px >= w;
            let (prev, prev_min, pen) = if start {
                (&row.prev[..m], 0, 0)
            } else {
                let at = px * dirs + dir;
                (&row.prev[at * m..(at + 1) * m], row.prev_mins[at], pen)
            };
            let at = i * dirs + dir;
            let out = &mut cur[at * m..(at + 1) * m];
            mins[at] = step_dyn::<N>(start, dir == 0, cost, prev, prev_min, row.p1, pen, out, sum);
        }
    }
}

/// The horizontal directions (left to right, then right to left), the rows in parallel, added
/// into `sums`.
fn horizontal(
    plan: &SweepPlan,
    colours: &[u32],
    volume: &[u16],
    sums: &mut [u16],
    cancel: &CancelFlag,
) {
    let p = &plan.params;
    let (w, h) = (p.width as usize, p.height as usize);
    let n = stride(p.planes as usize);
    let (p1, p2, edge) = (p.sgm_p1, p.sgm_p2, p.sgm_edge);
    if w == 0 || h == 0 {
        return;
    }
    let penalties = penalty_table(p1, p2, edge);
    sums.par_chunks_mut(w * n).enumerate().for_each_init(
        || {
            let pens: [Vec<u16>; 4] = std::array::from_fn(|_| vec![penalties[0]; w]);
            (pens, [vec![PAD; n + 2], vec![PAD; n + 2]])
        },
        |(pens, line), (y, sums)| {
            if cancel.is_cancelled() {
                return;
            }
            let costs = &volume[y * w * n..(y + 1) * w * n];
            for forward in [true, false] {
                if edge > 0 {
                    edge_penalties_row(&penalties, colours, w, y, None, forward, pens);
                }
                horizontal_row(n, p1 as u16, forward, costs, &pens[0], line, sums);
            }
        },
    );
}

vectorised_fn! { avx2:
/// One row's horizontal path walking `forward` (left to right) or back, added into `sums`.
fn horizontal_row(n: usize, p1: u16, forward: bool, costs: &[u16], pen_h: &[u16], line: &mut [Vec<u16>; 2], sums: &mut [u16]) {
    match n {
        16 => horizontal_lanes::<16>(n, p1, forward, costs, pen_h, line, sums),
        32 => horizontal_lanes::<32>(n, p1, forward, costs, pen_h, line, sums),
        48 => horizontal_lanes::<48>(n, p1, forward, costs, pen_h, line, sums),
        64 => horizontal_lanes::<64>(n, p1, forward, costs, pen_h, line, sums),
        96 => horizontal_lanes::<96>(n, p1, forward, costs, pen_h, line, sums),
        128 => horizontal_lanes::<128>(n, p1, forward, costs, pen_h, line, sums),
        _ => horizontal_lanes::<0>(n, p1, forward, costs, pen_h, line, sums),
    }
}
}

#[inline(always)]
fn horizontal_lanes<const N: usize>(
    n: usize,
    p1: u16,
    forward: bool,
    costs: &[u16],
    pen_h: &[u16],
    line: &mut [Vec<u16>; 2],
    sums: &mut [u16],
) {
    let w = pen_h.len();
    let mut h_min = 0u16;
    for walk_x in 0..w {
        let x = if forward { walk_x } else { w - 1 - walk_x };
        let cost = &costs[x * n..(x + 1) * n];
        let sum = &mut sums[x * n..(x + 1) * n];
        let [a, b] = line;
        let (prev, out) = if walk_x % 2 == 0 { (&*a, b) } else { (&*b, a) };
        let start = walk_x == 0;
        let pen = if start { 0 } else { pen_h[x] };
        h_min = step_dyn::<N>(start, false, cost, prev, h_min, p1, pen, out, sum);
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::cpu::sgm;
    use crate::sweep::{Optimizer, SweepParams};
    use crate::synthetic;

    /// A plan of `w x h` pixels and `planes` planes with `paths` paths and, when `edge`, P2
    /// lowered at colour edges.
    pub(in crate::sweep::cpu) fn plan(
        w: u32,
        h: u32,
        planes: u32,
        paths: u32,
        edge: bool,
    ) -> SweepPlan {
        let model = CameraModel::pinhole(synthetic::intrinsics(w, h));
        let rig = synthetic::row_rig(2, 0.1, model, 0).expect("rig");
        let params = SweepParams {
            num_planes: planes,
            optimizer: Optimizer::Sgm,
            ..SweepParams::default()
        };
        let mut plan = SweepPlan::new(&rig, &params).expect("plan");
        plan.params.sgm_paths = paths;
        plan.params.sgm_p1 = 10;
        plan.params.sgm_p2 = 60;
        plan.params.sgm_edge = if edge { 8 * 16 } else { 0 };
        plan
    }

    /// Pseudo-random costs and colours (a fixed LCG), some at the top level.
    pub(in crate::sweep::cpu) fn noise(len: usize, seed: u32, modulo: u32) -> Vec<u32> {
        let mut s = seed;
        (0..len)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 8) % modulo
            })
            .collect()
    }

    #[test]
    fn the_wide_layout_sums_what_the_two_passes_sum() {
        // Lane counts with and without a compile-time path (32, 40 -> 48, 72 -> 80: none),
        // 4 and 8 paths, with and without edge penalties, widths not a multiple of a chunk.
        for (w, h, planes, paths, edge) in [
            (37, 9, 32, 8, true),
            (53, 7, 40, 8, false),
            (29, 11, 72, 8, true),
            (41, 6, 32, 4, true),
        ] {
            let plan = plan(w, h, planes, paths, edge);
            let n = stride(plan.params.planes as usize);
            let pixels = (w * h) as usize;
            let mut volume: Vec<u16> = noise(pixels * n, planes, 200)
                .into_iter()
                .map(|v| v as u16)
                .collect();
            for (i, v) in volume.iter_mut().enumerate() {
                if i % n >= plan.params.planes as usize {
                    *v = PAD;
                }
            }
            let colours = noise(pixels, w, 1 << 24);
            let cancel = CancelFlag::new();
            let (mut f2, mut b2, mut fw, mut bw) = (vec![], vec![], vec![], vec![]);
            sgm::run_two_passes(&plan, &colours, &volume, &mut f2, &mut b2, &cancel)
                .expect("two passes");
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(4)
                .build()
                .expect("pool");
            pool.install(|| run(&plan, &colours, &volume, &mut fw, &mut bw, &cancel))
                .expect("wide");
            let total = |f: &[u16], b: &[u16]| -> Vec<u16> {
                f.iter().zip(b).map(|(a, b)| a.wrapping_add(*b)).collect()
            };
            assert!(
                total(&f2, &b2) == total(&fw, &bw),
                "{w}x{h}, {planes} planes, {paths} paths, edge {edge}: sums differ"
            );
            // Not all alike: the paths did add something.
            assert!(total(&fw, &bw).iter().any(|&v| v != total(&fw, &bw)[0]));
        }
    }
}
