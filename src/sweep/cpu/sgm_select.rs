//! Twin of `shaders/sgm_select.wgsl`: winner-take-all over SGM's summed path costs (the
//! forward and backward passes' sums of `sgm.rs`), and the winner's uniqueness on the matching
//! costs themselves.
// The `!(x < BIG)` test mirrors the shader and is NaN-safe on purpose.
#![expect(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
)]

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

use super::common::vectorised_fn;
use super::select::WtaChunk;

/// The winner over the summed path costs of one pixel.
pub(super) struct Winner {
    pub(super) best: usize,
    pub(super) best_sum: u16,
    pub(super) before: Option<u16>,
    pub(super) after: Option<u16>,
    pub(super) rival: Option<u16>,
}

/// Sums `forward + backward` into `sums` and finds the first minimum, its neighbours and the
/// smallest sum away from them (vector adds and minimum reductions, one scan for the index).
#[inline(always)]
pub(super) fn winner(forward: &[u16], backward: &[u16], sums: &mut [u16]) -> Winner {
    let planes = sums.len();
    for ((s, &f), &b) in sums
        .iter_mut()
        .zip(&forward[..planes])
        .zip(&backward[..planes])
    {
        *s = f.wrapping_add(b);
    }
    let lowest = |v: &[u16]| v.iter().copied().fold(u16::MAX, u16::min);
    let best_sum = lowest(sums);
    let best = sums.iter().position(|&v| v == best_sum).unwrap_or(0);
    let left = &sums[..best.saturating_sub(1)];
    let right = &sums[(best + 2).min(planes)..];
    let rival = (!left.is_empty() || !right.is_empty()).then(|| lowest(left).min(lowest(right)));
    Winner {
        best,
        best_sum,
        before: best.checked_sub(1).map(|d| sums[d]),
        after: sums.get(best + 1).copied(),
        rival,
    }
}

/// How the selection reads the uniqueness on the matching costs, where `uniqueness` or
/// `ambiguity` needs it.
pub(super) fn uniqueness_of(plan: &SweepPlan) -> Option<Uniqueness> {
    let p = &plan.params;
    (p.uniqueness > 0.0 || p.ambiguity > 0.0).then_some(Uniqueness {
        radius: p.uniqueness_radius.max(1) as usize,
        levels_per_unit: p.sgm_levels_per_unit,
    })
}

/// How [`uniqueness_on_costs`] reads a pixel's volume levels.
#[derive(Debug, Clone, Copy)]
pub(super) struct Uniqueness {
    /// Planes either side of the winner that are not its rivals.
    pub(super) radius: usize,
    /// Volume levels per score unit.
    pub(super) levels_per_unit: f32,
}

/// A volume level back to score units (twin of `level_score` in sgm_select.wgsl).
#[inline(always)]
pub(super) fn level_score(level: u16, levels_per_unit: f32) -> f32 {
    f32::from(level) / levels_per_unit - SGM_VOLUME_OFFSET
}

/// How clearly SGM's winner `best` is the best match on the matching costs themselves (the
/// pixel's volume `levels`): [`super::select::confidence`] of its cost against the lowest
/// cost more than `radius` planes away. A repeated pattern matches as well one period away
/// (SGM's paths make one of them win clearly); a blank surface matches about as well
/// anywhere. 1 when no plane lies that far.
#[inline(always)]
pub fn uniqueness_on_costs(
    levels: &[u16],
    best: usize,
    radius: usize,
    levels_per_unit: f32,
) -> f32 {
    // Planes 0..best - radius and best + radius + 1.. (two minimum reductions that vectorise).
    let lowest = |v: &[u16]| v.iter().copied().fold(u16::MAX, u16::min);
    let below = &levels[..best.saturating_sub(radius)];
    let above = levels.get(best + radius + 1..).unwrap_or(&[]);
    let rival = lowest(below).min(lowest(above));
    if rival == u16::MAX {
        return 1.0;
    }
    super::select::confidence(
        level_score(levels[best], levels_per_unit),
        level_score(rival, levels_per_unit),
    )
}

/// The lane indices 0..N as u16 lanes, for masks made in the lanes' own width.
#[inline(always)]
fn lane_indices<const N: usize>() -> [u16; N] {
    std::array::from_fn(|d| d as u16)
}

/// [`uniqueness_on_costs`] of the first `planes` of `N` lanes known at compile time: the rival
/// as a minimum over every lane, those near the winner or past the planes masked, in vector
/// lanes (the two minima over slices whose ends move with the winner ran one lane at a time).
#[inline(always)]
fn uniqueness_fixed<const N: usize>(
    levels: &[u16],
    planes: usize,
    best: usize,
    unique: Uniqueness,
) -> f32 {
    let levels = &levels[..N];
    // `d + radius < best || (d > best + radius && d < planes)` in u16 lanes (with `usize` lane
    // indices the compiler compared 64-bit lanes, four vectors for each of the u16 ones).
    let (best16, planes16) = (best as u16, planes.min(N) as u16);
    let radius16 = u16::try_from(unique.radius).unwrap_or(u16::MAX);
    let mut rival = u16::MAX;
    for (&d, &level) in lane_indices::<N>().iter().zip(levels) {
        let away = (d.abs_diff(best16) > radius16) & (d < planes16);
        rival = rival.min(if away { level } else { u16::MAX });
    }
    if rival == u16::MAX {
        return 1.0;
    }
    super::select::confidence(
        level_score(levels[best], unique.levels_per_unit),
        level_score(rival, unique.levels_per_unit),
    )
}

vectorised_fn! {
/// The uniqueness on the matching costs of each valid pixel of a run, into `local_confidence`.
pub(super) fn uniqueness_chunk(planes: usize, n: usize, unique: Uniqueness, volume: &[u16], st: &mut WtaChunk<'_>) {
    // 32 lanes known at compile time (a pair's or the demo's planes), as `select_fixed`.
    if n == 32 && planes <= 32 {
        for i in 0..st.best.len() {
            if !(st.best[i] < 0.5 * BIG) || st.best_plane[i] < 0.0 {
                continue;
            }
            st.local_confidence[i] = uniqueness_fixed::<32>(
                &volume[i * 32..(i + 1) * 32],
                planes,
                st.best_plane[i] as usize,
                unique,
            );
        }
        return;
    }
    for i in 0..st.best.len() {
        if !(st.best[i] < 0.5 * BIG) || st.best_plane[i] < 0.0 {
            continue;
        }
        let levels = &volume[i * n..i * n + planes];
        st.local_confidence[i] = uniqueness_on_costs(
            levels,
            st.best_plane[i] as usize,
            unique.radius,
            unique.levels_per_unit,
        );
    }
}
}

vectorised_fn! {
/// [`select`] for one run of pixels.
pub(super) fn select_chunk(
    planes: usize,
    n: usize,
    unit: f32,
    forward: &[u16],
    backward: &[u16],
    st: &mut WtaChunk<'_>,
) {
    // Summed levels back to score units, less the offset every volume level carries.
    let score = |v: u16| f32::from(v) * unit - SGM_VOLUME_OFFSET;
    // 32 lanes known at compile time (the demo's planes); for more lanes the generic scan
    // below is faster (the (sum, plane) keys take twice the vectors; measured on a raw pair's
    // 96 lanes, docs/notes/speed-history.md).
    if n == 32 && planes <= 32 {
        select_fixed::<32>(planes, unit, forward, backward, st);
        return;
    }
    let mut sums = vec![0u16; planes];
    for i in 0..st.best.len() {
        if !(st.best[i] < 0.5 * BIG) || st.best_plane[i] < 0.0 {
            continue;
        }
        let (f, b) = (&forward[i * n..i * n + planes], &backward[i * n..i * n + planes]);
        let s = winner(f, b, &mut sums);
        st.best[i] = score(s.best_sum);
        st.best_plane[i] = s.best as f32;
        st.before[i] = s.before.map_or(BIG, score);
        st.after[i] = s.after.map_or(BIG, score);
        st.rival[i] = s.rival.map_or(BIG, score);
    }
}
}

/// [`select_chunk`] for `N` lanes per pixel known at compile time: the sums, their minimum and
/// the rival in vector lanes, the first minimum's plane as the minimum of (sum, plane) keys
/// (the scalar scans of `winner` were ~320 instructions per pixel of the demo).
#[inline(always)]
fn select_fixed<const N: usize>(
    planes: usize,
    unit: f32,
    forward: &[u16],
    backward: &[u16],
    st: &mut WtaChunk<'_>,
) {
    let score = |v: u16| f32::from(v) * unit - SGM_VOLUME_OFFSET;
    let (lanes, planes16) = (lane_indices::<N>(), planes.min(N) as u16);
    for i in 0..st.best.len() {
        if !(st.best[i] < 0.5 * BIG) || st.best_plane[i] < 0.0 {
            continue;
        }
        let (f, b) = (&forward[i * N..(i + 1) * N], &backward[i * N..(i + 1) * N]);
        let mut sums = [0u16; N];
        for d in 0..N {
            sums[d] = f[d].wrapping_add(b[d]);
        }
        // (sum, plane) keys: the smallest is the first plane of the smallest sum; lanes past
        // the planes never win.
        let mut lowest = u32::MAX;
        for (d, &s) in sums.iter().enumerate() {
            let key = if d < planes {
                (u32::from(s) << 8) | d as u32
            } else {
                u32::MAX
            };
            lowest = lowest.min(key);
        }
        let (best, best_sum) = ((lowest & 0xff) as usize, (lowest >> 8) as u16);
        // The smallest sum away from the winner and its neighbours (planes 0..best - 1 and
        // best + 2..planes), if there are such planes; the mask in u16 lanes (see
        // `uniqueness_fixed`).
        let mut rival = u16::MAX;
        let best16 = best as u16;
        for (&d, &s) in lanes.iter().zip(&sums) {
            let away = (d.abs_diff(best16) > 1) & (d < planes16);
            rival = rival.min(if away { s } else { u16::MAX });
        }
        let has_rival = best >= 2 || best + 2 < planes;
        st.best[i] = score(best_sum);
        st.best_plane[i] = best as f32;
        st.before[i] = if best > 0 { score(sums[best - 1]) } else { BIG };
        st.after[i] = if best + 1 < planes {
            score(sums[best + 1])
        } else {
            BIG
        };
        st.rival[i] = if has_rival { score(rival) } else { BIG };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rival on the matching costs lies more than `radius` planes from SGM's winner: a
    /// repeated pattern's second minimum is one, the winner's own slope is not.
    #[test]
    fn uniqueness_over_fixed_lanes_is_the_general_one() {
        // Every winner and radius over 32 lanes of which the first `planes` are planes (the
        // rest PAD, never a rival), with a second minimum placed at every distance.
        let per_unit = 16.0;
        for planes in [3usize, 17, 31, 32] {
            for best in 0..planes {
                for second in 0..planes {
                    let mut lanes = [SGM_PATH_PAD as u16; 32];
                    for (d, level) in lanes.iter_mut().enumerate().take(planes) {
                        *level = 400 + (d as u16 * 37) % 101;
                    }
                    lanes[best] = 10;
                    lanes[second] = lanes[second].min(12);
                    for radius in [1usize, 2, 5, 40] {
                        let unique = Uniqueness {
                            radius,
                            levels_per_unit: per_unit,
                        };
                        let general = uniqueness_on_costs(&lanes[..planes], best, radius, per_unit);
                        let fixed = uniqueness_fixed::<32>(&lanes, planes, best, unique);
                        assert_eq!(
                            general.to_bits(),
                            fixed.to_bits(),
                            "planes {planes}, best {best}, second {second}, radius {radius}"
                        );
                    }
                }
            }
        }
    }

    /// The selection over 32 lanes known at compile time (`select_fixed`) is the general one
    /// (the same chunk laid out in 48 lanes), bit for bit: every plane count up to 32, every
    /// winner, a second sum near it or tied with it (the first plane wins), low sums in the
    /// lanes past the planes, and pixels the local winner-take-all left invalid untouched.
    #[test]
    fn selection_over_fixed_lanes_is_the_general_one() {
        use crate::sweep::cpu::select::WtaState;
        let pad = SGM_PATH_PAD as u16;
        for planes in [1usize, 2, 3, 4, 17, 31, 32] {
            for best in 0..planes {
                for second in 0..planes {
                    for tie in [false, true] {
                        // Lanes past the planes hold sums lower than any plane's, which
                        // must not count.
                        let mut forward = [1; 32];
                        let mut backward = [1; 32];
                        for d in 0..planes {
                            forward[d] = 400 + (d as u16 * 37) % 101;
                            backward[d] = 300 + (d as u16 * 53) % 89;
                        }
                        forward[best] = 10;
                        backward[best] = 5;
                        if second != best {
                            forward[second] = if tie { 10 } else { 12 };
                            backward[second] = 5;
                        }
                        // Pixel 0 valid, pixel 1 left invalid by the local winner-take-all.
                        let wide = |lanes: &[u16; 32]| {
                            let mut out = [pad; 96];
                            out[..32].copy_from_slice(lanes);
                            out[48..80].copy_from_slice(lanes);
                            out
                        };
                        let narrow = |lanes: &[u16; 32]| [*lanes, *lanes].concat();
                        let start = || {
                            let mut state = WtaState::new(2);
                            state.best[0] = 1.0;
                            state.best_plane[0] = 0.0;
                            state
                        };
                        let (mut fixed, mut general) = (start(), start());
                        let unit = 0.25;
                        let (f, b) = (narrow(&forward), narrow(&backward));
                        select_chunk(planes, 32, unit, &f, &b, &mut fixed.chunks_mut(2)[0]);
                        let (f, b) = (wide(&forward), wide(&backward));
                        select_chunk(planes, 48, unit, &f, &b, &mut general.chunks_mut(2)[0]);
                        assert!(
                            fixed == general,
                            "planes {planes}, best {best}, second {second}, tie {tie}"
                        );
                        let expected = if tie { best.min(second) } else { best };
                        assert_eq!(fixed.best_plane[0], expected as f32);
                        assert_eq!(fixed.best_plane[1], -1.0);
                    }
                }
            }
        }
    }

    #[test]
    fn uniqueness_on_costs_looks_past_the_radius() {
        let per_unit = 1.0;
        let score = |level: u16| f32::from(level) - SGM_VOLUME_OFFSET;
        // Two minima 4 planes apart (a period), the winner's neighbours close to it.
        let levels = [300, 200, 112, 114, 300, 300, 113, 300];
        // Radius 1: the period's other minimum (plane 6) rivals plane 2.
        let rival_close = uniqueness_on_costs(&levels, 2, 1, per_unit);
        let expected = ((score(113) - score(112)) / (score(113) + 1.0)).clamp(0.0, 1.0);
        assert_eq!(rival_close, expected);
        assert!(rival_close < 0.01, "{rival_close}");
        // Radius 4: nothing below, plane 7 (300) above: the winner is unique.
        let alone = uniqueness_on_costs(&levels, 2, 4, per_unit);
        assert_eq!(alone, (score(300) - score(112)) / (score(300) + 1.0));
        assert!(alone > 0.5, "{alone}");
        // Nothing beyond the radius either side: 1.
        assert_eq!(uniqueness_on_costs(&levels, 2, 8, per_unit), 1.0);
        // A winner worse than its rival (SGM overruled the matching costs): 0.
        assert_eq!(uniqueness_on_costs(&levels, 6, 2, per_unit), 0.0);
    }
}
