//! Twin of the selection step (`select_plane` in `shaders/common.wgsl`): streaming
//! winner-take-all with the winner's exact neighbours and rival, one slice per field so a plane
//! updates a run of pixels in vector lanes.

use super::common::fmin;
use crate::sweep::gpu_types::*;

/// Selection state of every pixel (the shader's `Wta`, field by field).
#[derive(Debug, Clone, PartialEq)]
pub struct WtaState {
    /// Best score (s0.x).
    pub best: Vec<f32>,
    /// Its plane, -1 = none yet (s0.y).
    pub best_plane: Vec<f32>,
    /// Score of plane best - 1 (s0.z), BIG when none.
    pub before: Vec<f32>,
    /// Score of plane best + 1 (s0.w), BIG when none.
    pub after: Vec<f32>,
    /// Best score away from best +- 1 (s1.x).
    pub rival: Vec<f32>,
    /// Minimum over planes 0..k-1 (s1.y).
    pub min_to_last: Vec<f32>,
    /// Minimum over planes 0..k-2 (s1.z).
    pub min_to_second_last: Vec<f32>,
    /// Score of plane k-1 (s1.w).
    pub last: Vec<f32>,
    /// Half-sequence selection at the best plane (s2.x).
    pub selection: Vec<f32>,
    /// With SGM: the confidence of the local winner, before SGM (s2.y; [`confidence`]).
    pub local_confidence: Vec<f32>,
}

/// How clearly a winner `best` beats the best `rival` away from its neighbouring planes:
/// `(rival - best) / (rival + 1)` in 0..1, 1 without a rival (`confidence` in finalize.wgsl).
#[inline(always)]
pub fn confidence(best: f32, rival: f32) -> f32 {
    if rival < 0.5 * BIG {
        ((rival - best) / (rival + 1.0)).clamp(0.0, 1.0)
    } else {
        1.0
    }
}

impl WtaState {
    pub fn new(pixels: usize) -> Self {
        let v = |x: f32| vec![x; pixels];
        Self {
            best: v(BIG),
            best_plane: v(-1.0),
            before: v(BIG),
            after: v(BIG),
            rival: v(BIG),
            min_to_last: v(BIG),
            min_to_second_last: v(BIG),
            last: v(BIG),
            selection: v(3.0),
            local_confidence: v(1.0),
        }
    }

    /// Back to the state before the first plane, for `pixels` pixels (buffers kept).
    pub fn reset(&mut self, pixels: usize) {
        let fill = |v: &mut Vec<f32>, x: f32| {
            v.clear();
            v.resize(pixels, x);
        };
        fill(&mut self.best, BIG);
        fill(&mut self.best_plane, -1.0);
        fill(&mut self.before, BIG);
        fill(&mut self.after, BIG);
        fill(&mut self.rival, BIG);
        fill(&mut self.min_to_last, BIG);
        fill(&mut self.min_to_second_last, BIG);
        fill(&mut self.last, BIG);
        fill(&mut self.selection, 3.0);
        fill(&mut self.local_confidence, 1.0);
    }

    /// [`Self::reset`] for a sweep with SGM: only the best score (BIG) and the local
    /// confidence (1) are written again, the other fields only sized. Such a sweep gives the
    /// plane and selection of every pixel whose best score falls below BIG ([`WtaChunk::update_best`],
    /// [`WtaChunk::settle_constant`]), SGM's selection writes its best, neighbours and rival
    /// for each of them, and neither SGM nor finalize reads any other field of a pixel whose
    /// best score stayed BIG, nor the streaming fields at all. Four fifths of the state's writes
    /// per set (a rectified pair's 18 MB).
    pub fn reset_for_sgm(&mut self, pixels: usize) {
        let fill = |v: &mut Vec<f32>, x: f32| {
            v.clear();
            v.resize(pixels, x);
        };
        fill(&mut self.best, BIG);
        fill(&mut self.local_confidence, 1.0);
        for (v, x) in [
            (&mut self.best_plane, -1.0),
            (&mut self.before, BIG),
            (&mut self.after, BIG),
            (&mut self.rival, BIG),
            (&mut self.min_to_last, BIG),
            (&mut self.min_to_second_last, BIG),
            (&mut self.last, BIG),
            (&mut self.selection, 3.0),
        ] {
            v.resize(pixels, x);
        }
    }

    /// The pixels `range` of every field, to be updated by one worker.
    pub fn chunk_mut(&mut self, start: usize, end: usize) -> WtaChunk<'_> {
        WtaChunk {
            best: &mut self.best[start..end],
            best_plane: &mut self.best_plane[start..end],
            before: &mut self.before[start..end],
            after: &mut self.after[start..end],
            rival: &mut self.rival[start..end],
            min_to_last: &mut self.min_to_last[start..end],
            min_to_second_last: &mut self.min_to_second_last[start..end],
            last: &mut self.last[start..end],
            selection: &mut self.selection[start..end],
            local_confidence: &mut self.local_confidence[start..end],
        }
    }

    /// Splits the state into chunks of `size` pixels (the last may be shorter).
    pub fn chunks_mut(&mut self, size: usize) -> Vec<WtaChunk<'_>> {
        let n = self.best.len();
        let mut out = Vec::with_capacity(n.div_ceil(size.max(1)));
        let mut fields = self.chunk_mut(0, n);
        while !fields.best.is_empty() {
            let take = size.min(fields.best.len());
            let (head, tail) = fields.split_at(take);
            out.push(head);
            fields = tail;
        }
        out
    }
}

/// A run of pixels of [`WtaState`].
pub struct WtaChunk<'a> {
    pub best: &'a mut [f32],
    pub best_plane: &'a mut [f32],
    pub before: &'a mut [f32],
    pub after: &'a mut [f32],
    pub rival: &'a mut [f32],
    pub min_to_last: &'a mut [f32],
    pub min_to_second_last: &'a mut [f32],
    pub last: &'a mut [f32],
    pub selection: &'a mut [f32],
    pub local_confidence: &'a mut [f32],
}

impl<'a> WtaChunk<'a> {
    fn split_at(self, mid: usize) -> (WtaChunk<'a>, WtaChunk<'a>) {
        let (a0, b0) = self.best.split_at_mut(mid);
        let (a1, b1) = self.best_plane.split_at_mut(mid);
        let (a2, b2) = self.before.split_at_mut(mid);
        let (a3, b3) = self.after.split_at_mut(mid);
        let (a4, b4) = self.rival.split_at_mut(mid);
        let (a5, b5) = self.min_to_last.split_at_mut(mid);
        let (a6, b6) = self.min_to_second_last.split_at_mut(mid);
        let (a7, b7) = self.last.split_at_mut(mid);
        let (a8, b8) = self.selection.split_at_mut(mid);
        let (a9, b9) = self.local_confidence.split_at_mut(mid);
        (
            WtaChunk {
                best: a0,
                best_plane: a1,
                before: a2,
                after: a3,
                rival: a4,
                min_to_last: a5,
                min_to_second_last: a6,
                last: a7,
                selection: a8,
                local_confidence: a9,
            },
            WtaChunk {
                best: b0,
                best_plane: b1,
                before: b2,
                after: b3,
                rival: b4,
                min_to_last: b5,
                min_to_second_last: b6,
                last: b7,
                selection: b8,
                local_confidence: b9,
            },
        )
    }

    /// The pixels `start..end` of the chunk, reborrowed.
    pub fn sub(&mut self, start: usize, end: usize) -> WtaChunk<'_> {
        WtaChunk {
            best: &mut self.best[start..end],
            best_plane: &mut self.best_plane[start..end],
            before: &mut self.before[start..end],
            after: &mut self.after[start..end],
            rival: &mut self.rival[start..end],
            min_to_last: &mut self.min_to_last[start..end],
            min_to_second_last: &mut self.min_to_second_last[start..end],
            last: &mut self.last[start..end],
            selection: &mut self.selection[start..end],
            local_confidence: &mut self.local_confidence[start..end],
        }
    }

    /// `select_plane` for plane `k` on every pixel of the chunk: `cost[i]` and `sel[i]` are
    /// pixel i's aggregated score and selection code. Branch-free, so it vectorises.
    #[inline(always)]
    pub fn update(&mut self, k: f32, cost: &[f32], sel: &[f32]) {
        let n = self.best.len();
        update_fields(
            k,
            &cost[..n],
            &sel[..n],
            self.best,
            self.best_plane,
            self.before,
            self.after,
            self.rival,
            self.min_to_last,
            self.min_to_second_last,
            self.last,
            self.selection,
        );
    }
}

impl WtaChunk<'_> {
    /// [`Self::update`] for SGM plans: only the fields that SGM's selection and finalize read
    /// from the local winner-take-all (the best score, for validity, its plane and its
    /// half-sequence selection); `sgm::select` writes the best, its neighbours and the rival
    /// of every valid pixel anew, and finalize reads no other field of an invalid one. A third
    /// of the state's memory traffic per plane.
    #[inline(always)]
    pub fn update_best(&mut self, k: f32, cost: &[f32], sel: &[f32]) {
        let n = self.best.len();
        let (cost, sel) = (&cost[..n], &sel[..n]);
        let (best, best_plane, selection) = (
            &mut self.best[..n],
            &mut self.best_plane[..n],
            &mut self.selection[..n],
        );
        for i in 0..n {
            let (c, s) = (cost[i], sel[i]);
            let (b, plane, se) = (best[i], best_plane[i], selection[i]);
            let new_best = c < b;
            best_plane[i] = if new_best { k } else { plane };
            selection[i] = if new_best { s } else { se };
            best[i] = fmin(b, c);
        }
    }
}

impl WtaChunk<'_> {
    /// [`Self::update_best`] for SGM plans whose every score below BIG carries one selection
    /// code (`aggregate::RowScorer::constant_selection`: a stereo pair's): only the best
    /// score, a third of its memory traffic per plane. [`Self::settle_constant`] then gives the
    /// pixels that saw a plane that code and a plane of their own.
    #[inline(always)]
    pub fn update_lowest(&mut self, cost: &[f32]) {
        let n = self.best.len();
        for (b, &c) in self.best.iter_mut().zip(&cost[..n]) {
            *b = fmin(*b, c);
        }
    }

    /// After [`Self::update_lowest`] over every plane: every pixel whose best score is below
    /// BIG (the pixels `update_best` would have given a winner) takes the selection code `sel`
    /// (what its winner carried) and plane 0 in place of its winner's, which SGM's selection
    /// writes for every such pixel before anything reads it.
    pub fn settle_constant(&mut self, sel: f32) {
        for ((&b, plane), selection) in self
            .best
            .iter()
            .zip(self.best_plane.iter_mut())
            .zip(self.selection.iter_mut())
        {
            if b < BIG {
                *plane = 0.0;
                *selection = sel;
            }
        }
    }
}

/// The body of [`WtaChunk::update`]. The fields come in as separate `&mut` arguments: the
/// compiler then knows they do not overlap and vectorises the loop without run-time checks.
#[inline(always)]
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn update_fields(
    k: f32,
    cost: &[f32],
    sel: &[f32],
    best: &mut [f32],
    best_plane: &mut [f32],
    before: &mut [f32],
    after: &mut [f32],
    rival: &mut [f32],
    min_to_last: &mut [f32],
    min_to_second_last: &mut [f32],
    last: &mut [f32],
    selection: &mut [f32],
) {
    let n = cost.len();
    let (sel, best, best_plane, before, after) = (
        &sel[..n],
        &mut best[..n],
        &mut best_plane[..n],
        &mut before[..n],
        &mut after[..n],
    );
    let (rival, min_to_last, min_to_second_last, last, selection) = (
        &mut rival[..n],
        &mut min_to_last[..n],
        &mut min_to_second_last[..n],
        &mut last[..n],
        &mut selection[..n],
    );
    for i in 0..n {
        // Every field loaded first, each store a plain two-way choice between loaded values
        // (a choice that may keep the stored value in place becomes a masked store, and the
        // loop then stays scalar).
        let (c, s) = (cost[i], sel[i]);
        let (b, plane, r, a, bf) = (best[i], best_plane[i], rival[i], after[i], before[i]);
        let (m1, m2, l, se) = (min_to_last[i], min_to_second_last[i], last[i], selection[i]);
        let new_best = c < b;
        let next_to_best = k == plane + 1.0;
        let rival_kept = if next_to_best { r } else { fmin(r, c) };
        let after_kept = if next_to_best { c } else { a };
        rival[i] = if new_best { m2 } else { rival_kept };
        after[i] = if new_best { BIG } else { after_kept };
        before[i] = if new_best { l } else { bf };
        best_plane[i] = if new_best { k } else { plane };
        selection[i] = if new_best { s } else { se };
        // `if new_best { c } else { b }` for non-NaN scores.
        best[i] = fmin(b, c);
        min_to_second_last[i] = m1;
        min_to_last[i] = fmin(m1, c);
        last[i] = c;
    }
}
