//! Per-pixel observation weights for [`super::integrate_weighted`]: how much each depth
//! pixel is trusted, from what a depth map carries (its confidence where the source has one,
//! its depth, its neighbours), so that the fused model leans on the better depths.
//!
//! - **Depth**: a depth triangulated over a baseline `B` has an error that grows with `z^2 / B`
//!   (a fixed disparity error), a variance with `z^4`; the weight falls as `(z0 / z)^p`.
//! - **Confidence**: the engine's confidence (0 .. 1, the margin of the best cost over the
//!   rest) raised to a power; below `min_confidence` a pixel adds nothing.
//! - **Baseline**: a view's depth over a baseline `B` has a variance about proportional to
//!   `1 / B^2`; the weight is `(B / B_max)^p`, `B_max` the largest of its set's references
//!   ([`rms_baseline_m`]).
//! - **Discontinuities**: a pixel whose depth differs from a 4-neighbour's by more than
//!   `edge_ratio` of its depth sits on an edge, where a matcher blends foreground and
//!   background (flying pixels): it adds nothing.

use rayon::prelude::*;

use crate::geometry::RigCamera;
use crate::image::ImageF32;

/// The root-mean-square distance from the reference camera's centre to the centres of the
/// other cameras swept with it (`swept`, indices into `cameras`): its baseline; 0 without
/// another camera.
pub fn rms_baseline_m(cameras: &[RigCamera], reference: usize, swept: &[usize]) -> f64 {
    let centre = |i: usize| cameras[i].cam_from_rig.inverse().translation;
    if reference >= cameras.len() {
        return 0.0;
    }
    let others: Vec<f64> = swept
        .iter()
        .filter(|&&i| i != reference && i < cameras.len())
        .map(|&i| centre(i).distance_squared(centre(reference)))
        .collect();
    if others.is_empty() {
        return 0.0;
    }
    (others.iter().sum::<f64>() / others.len() as f64).sqrt()
}

/// How [`observation_weights`] weighs a depth map's pixels.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Weighting {
    /// The exponent of the confidence (0: ignored).
    pub confidence_power: f32,
    /// Pixels whose confidence is below this add nothing (0: none refused).
    pub min_confidence: f32,
    /// The exponent `p` of `(z0 / z)^p` (0: ignored), `z0` = [`Weighting::REFERENCE_DEPTH_M`].
    pub depth_power: f32,
    /// A pixel whose depth differs from a 4-neighbour's by more than this share of its own
    /// depth adds nothing (`None`: no discontinuity test).
    pub edge_ratio: Option<f32>,
    /// The exponent of the view's baseline ratio (its root-mean-square baseline over the
    /// largest of its set's references; 0: ignored).
    pub baseline_power: f32,
}

impl Weighting {
    /// `z0` of the depth term: a pixel at 1 m weighs its other factors.
    pub const REFERENCE_DEPTH_M: f32 = 1.0;

    /// Every valid pixel 1 (as [`super::integrate()`]).
    pub const EQUAL: Self = Self {
        confidence_power: 0.0,
        min_confidence: 0.0,
        depth_power: 0.0,
        edge_ratio: None,
        baseline_power: 0.0,
    };

    /// What the node, `bag` and `fuse` weigh depth maps by (chosen on ICL-NUIM and the
    /// synthetic rig with `eval --fusion`, docs/fusion.md): the fourth power of the baseline
    /// ratio (steeper than the inverse variance's square: the references of a set share their
    /// images, so their errors are correlated and the widest baseline should decide), the
    /// square of the confidence (a soft threshold: where it is alone a doubtful depth still
    /// makes the surface), no depths at discontinuities of more than 5 % of the depth. Depth
    /// from other sources (`sweepdepth fuse`) has neither confidence nor baseline: only the
    /// discontinuity test (and the angle weight of every observation) applies.
    pub const DEPTH_MAPS: Self = Self {
        confidence_power: 2.0,
        min_confidence: 0.0,
        depth_power: 0.0,
        edge_ratio: Some(0.05),
        baseline_power: 4.0,
    };

    /// Whether every weight would be 1 (no image needed).
    pub fn is_equal(&self) -> bool {
        *self == Self::EQUAL
    }
}

/// Each pixel's observation weight under `weighting` (the depth's size): NaN where the depth
/// is invalid (not finite or not positive) or the pixel is refused. Without `confidence` (or
/// one of another size) the confidence terms are left out, without `baseline_ratio` the
/// baseline term.
pub fn observation_weights(
    depth: &ImageF32,
    confidence: Option<&ImageF32>,
    baseline_ratio: Option<f32>,
    weighting: &Weighting,
) -> ImageF32 {
    let scale = match baseline_ratio {
        Some(r) if weighting.baseline_power != 0.0 && r.is_finite() && r > 0.0 => {
            r.powf(weighting.baseline_power)
        }
        _ => 1.0,
    };
    let width = depth.width as usize;
    let height = depth.height as usize;
    let d = &depth.data;
    let confidence = confidence.filter(|c| c.data.len() == d.len());
    let z0 = Weighting::REFERENCE_DEPTH_M;
    let mut data = vec![f32::NAN; d.len()];
    if width == 0 {
        return ImageF32 {
            width: depth.width,
            height: depth.height,
            data,
        };
    }
    data.par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, out)| {
            for (col, w) in out.iter_mut().enumerate() {
                let i = row * width + col;
                let z = d[i];
                if !(z.is_finite() && z > 0.0) {
                    continue;
                }
                if let Some(ratio) = weighting.edge_ratio {
                    let limit = ratio * z;
                    // An invalid neighbour (the image's border, a hole) is no edge.
                    let jump = |j: usize| {
                        let n = d[j];
                        n.is_finite() && n > 0.0 && (n - z).abs() > limit
                    };
                    let edge = (col > 0 && jump(i - 1))
                        || (col + 1 < width && jump(i + 1))
                        || (row > 0 && jump(i - width))
                        || (row + 1 < height && jump(i + width));
                    if edge {
                        continue;
                    }
                }
                let mut weight = scale;
                if let Some(c) = confidence {
                    let c = c.data[i];
                    if !(c.is_finite() && c >= weighting.min_confidence) {
                        continue;
                    }
                    if weighting.confidence_power != 0.0 {
                        weight *= power(c.max(0.0), weighting.confidence_power);
                    }
                }
                if weighting.depth_power != 0.0 {
                    weight *= power(z0 / z, weighting.depth_power);
                }
                if weight.is_finite() && weight > 0.0 {
                    *w = weight;
                }
            }
        });
    ImageF32 {
        width: depth.width,
        height: depth.height,
        data,
    }
}

/// `x^p`, by multiplications for small whole exponents (a `powf` per pixel of a 640x480 map
/// costs milliseconds).
#[inline(always)]
fn power(x: f32, p: f32) -> f32 {
    if p.fract() == 0.0 && p.abs() <= 8.0 {
        x.powi(p as i32)
    } else {
        x.powf(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(width: u32, data: Vec<f32>) -> ImageF32 {
        ImageF32 {
            width,
            height: data.len() as u32 / width,
            data,
        }
    }

    #[test]
    fn weights_fall_with_depth_and_confidence_and_edges_are_refused() {
        let depth = image(4, vec![1.0, 1.0, 2.0, 2.0, 1.0, 1.0, 2.0, f32::NAN]);
        let equal = observation_weights(&depth, None, None, &Weighting::EQUAL);
        assert_eq!(&equal.data[..7], &[1.0; 7]);
        assert!(equal.data[7].is_nan());
        let by_depth = Weighting {
            depth_power: 2.0,
            baseline_power: 1.0,
            ..Weighting::EQUAL
        };
        let w = observation_weights(&depth, None, Some(2.0), &by_depth);
        assert_eq!(&w.data[..3], &[2.0, 2.0, 0.5]);
        let confidence = image(4, vec![1.0, 0.5, 0.1, 1.0, 1.0, 1.0, 1.0, 1.0]);
        let by_confidence = Weighting {
            confidence_power: 2.0,
            min_confidence: 0.2,
            ..Weighting::EQUAL
        };
        let w = observation_weights(&depth, Some(&confidence), None, &by_confidence);
        assert_eq!(&w.data[..2], &[1.0, 0.25]);
        assert!(w.data[2].is_nan(), "below min_confidence");
        // Without a confidence image the confidence terms are left out.
        let w = observation_weights(&depth, None, None, &by_confidence);
        assert_eq!(w.data[2], 1.0);
        // Columns 1 and 2 meet at a jump of 1 m: an edge for a ratio of 0.2, not for 2.
        let edges = Weighting {
            edge_ratio: Some(0.2),
            ..Weighting::EQUAL
        };
        let w = observation_weights(&depth, None, None, &edges);
        let kept: Vec<bool> = w.data.iter().map(|v| !v.is_nan()).collect();
        assert_eq!(kept, [true, false, false, true, true, false, false, false]);
        let loose = Weighting {
            edge_ratio: Some(2.0),
            ..Weighting::EQUAL
        };
        let w = observation_weights(&depth, None, None, &loose);
        assert_eq!(w.data.iter().filter(|v| !v.is_nan()).count(), 7);
    }
}
