//! `eval`'s scores: error rates against disparity ground truth (Middlebury: bad > 0.5 / 1 / 2 px,
//! RMS, mean signed error, invalid share, how well the confidence ranks the errors) and
//! against depth ground truth (ICL-NUIM: relative errors), and which apply to a dataset.

use super::EvalError;
use crate::datasets::{Dataset, GroundTruth};
use crate::image::ImageF32;
use crate::sweep::DepthMaps;

/// Error rates against disparity ground truth. Rates are percentages of the evaluated pixels
/// (known ground truth, outside the border) unless said otherwise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisparityMetrics {
    /// Pixels with known ground truth outside the border.
    pub evaluated_px: usize,
    /// |d − gt| > 1, invalid estimates counted as bad.
    pub bad1: f64,
    /// |d − gt| > 2, invalid estimates counted as bad.
    pub bad2: f64,
    /// |d − gt| > 0.5, invalid estimates counted as bad (precision, issue 29).
    pub bad05: f64,
    /// Root mean square of d − gt over the valid estimates, in evaluation pixels (NaN when none
    /// is valid); gross errors included.
    pub rms: f64,
    /// Root mean square of d − gt over the valid estimates within 2 px of the ground truth:
    /// the sub-pixel precision of the estimates that are right (NaN when there is none).
    pub rms_inliers: f64,
    /// Mean of d − gt over the valid estimates (positive: too near), NaN when none is valid.
    pub mean_signed: f64,
    /// |d − gt| > 1 among the valid estimates only (NaN when none is valid).
    pub bad1_valid: f64,
    /// Pixels with no estimate.
    pub invalid: f64,
    /// Whether confidence ranks errors; `None` with fewer than 2 valid estimates.
    pub confidence_ranking: Option<ConfidenceRanking>,
}

/// The evaluated pixels with a valid estimate, sorted by confidence and split in two halves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConfidenceRanking {
    /// bad>1 rate (%) of the more confident half.
    pub bad1_confident_half: f64,
    /// bad>1 rate (%) of the less confident half.
    pub bad1_rest: f64,
}

/// Errors against depth ground truth, over pixels with known ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMetrics {
    pub evaluated_px: usize,
    /// Mean |z − gt| / gt over the valid estimates (NaN when none is valid).
    pub mean_abs_rel: f64,
    /// % of ground-truth pixels within 1 % of the ground truth (invalid = not within).
    pub within_1pct: f64,
    /// % within 5 %.
    pub within_5pct: f64,
    /// % with no estimate.
    pub invalid: f64,
    /// Whether confidence ranks depth errors; `None` without a confidence map or with fewer
    /// than 2 valid estimates.
    pub confidence_ranking: Option<DepthConfidenceRanking>,
}

/// The ground-truth pixels with a valid estimate, sorted by confidence: error rates (% off by
/// more than 1 % / 5 % of the ground truth) of the more confident half and of all of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthConfidenceRanking {
    pub off1_confident_half: f64,
    pub off1_all_valid: f64,
    pub off5_confident_half: f64,
    pub off5_all_valid: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Metrics {
    Disparity(DisparityMetrics),
    Depth(DepthMetrics),
}

fn percent(count: usize, total: usize) -> f64 {
    if total == 0 {
        f64::NAN
    } else {
        100.0 * count as f64 / total as f64
    }
}

fn mean_or_nan(sum: f64, count: usize) -> f64 {
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

fn check_size(what: &'static str, image: &ImageF32, gt: &ImageF32) -> Result<(), EvalError> {
    let n = gt.width as usize * gt.height as usize;
    if image.width != gt.width
        || image.height != gt.height
        || image.data.len() != n
        || gt.data.len() != n
    {
        return Err(EvalError::Size {
            what,
            got_w: image.width,
            got_h: image.height,
            got_len: image.data.len(),
            want_w: gt.width,
            want_h: gt.height,
        });
    }
    Ok(())
}

fn valid_depth(z: f32) -> bool {
    z.is_finite() && z > 0.0
}

/// Disparity in evaluation units from depth: `focal_baseline_eval / z`, NaN where invalid.
pub fn depth_to_disparity(depth_m: &ImageF32, focal_baseline_eval: f64) -> ImageF32 {
    ImageF32 {
        width: depth_m.width,
        height: depth_m.height,
        data: depth_m
            .data
            .iter()
            .map(|&z| {
                if valid_depth(z) {
                    (focal_baseline_eval / f64::from(z)) as f32
                } else {
                    f32::NAN
                }
            })
            .collect(),
    }
}

/// Bad-pixel rates of an estimated depth map against disparity ground truth (NaN = unknown),
/// over pixels at least `border_px` from every image edge. An estimate is valid when its depth
/// is finite and positive.
pub fn disparity_metrics(
    depth_m: &ImageF32,
    confidence: &ImageF32,
    gt_disparity_eval_px: &ImageF32,
    focal_baseline_eval: f64,
    border_px: u32,
) -> Result<DisparityMetrics, EvalError> {
    let gt = gt_disparity_eval_px;
    check_size("the depth map", depth_m, gt)?;
    check_size("the confidence map", confidence, gt)?;
    let (w, h) = (gt.width, gt.height);
    let mut evaluated = 0usize;
    let mut bad1 = 0usize;
    let mut bad2 = 0usize;
    let mut bad05 = 0usize;
    let mut valid = 0usize;
    let mut bad1_among_valid = 0usize;
    let (mut sum_sq, mut sum_signed) = (0.0f64, 0.0f64);
    let (mut inliers, mut sum_sq_inliers) = (0usize, 0.0f64);
    // (confidence, bad1) of the evaluated pixels with a valid estimate.
    let mut ranked: Vec<(f32, bool)> = Vec::new();
    for y in border_px..h.saturating_sub(border_px) {
        for x in border_px..w.saturating_sub(border_px) {
            let i = y as usize * w as usize + x as usize;
            let g = gt.data[i];
            if !g.is_finite() {
                continue;
            }
            evaluated += 1;
            let z = depth_m.data[i];
            if !valid_depth(z) {
                bad1 += 1;
                bad2 += 1;
                bad05 += 1;
                continue;
            }
            let d = focal_baseline_eval / f64::from(z);
            let signed = d - f64::from(g);
            let err = signed.abs();
            valid += 1;
            sum_sq += signed * signed;
            sum_signed += signed;
            if err <= 2.0 {
                inliers += 1;
                sum_sq_inliers += signed * signed;
            }
            if err > 0.5 {
                bad05 += 1;
            }
            let is_bad1 = err > 1.0;
            if is_bad1 {
                bad1 += 1;
                bad1_among_valid += 1;
            }
            if err > 2.0 {
                bad2 += 1;
            }
            let c = confidence.data[i];
            ranked.push((if c.is_finite() { c } else { 0.0 }, is_bad1));
        }
    }
    if evaluated == 0 {
        return Err(EvalError::NoGroundTruthPixels(format!(
            " outside the {border_px}-pixel border of the {w}x{h} image"
        )));
    }
    let confidence_ranking = (ranked.len() >= 2).then(|| {
        // Most confident first; ties keep pixel order (stable sort).
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        let half = ranked.len() / 2;
        let (top, rest) = ranked.split_at(half);
        let rate = |s: &[(f32, bool)]| percent(s.iter().filter(|p| p.1).count(), s.len());
        ConfidenceRanking {
            bad1_confident_half: rate(top),
            bad1_rest: rate(rest),
        }
    });
    Ok(DisparityMetrics {
        evaluated_px: evaluated,
        bad1: percent(bad1, evaluated),
        bad2: percent(bad2, evaluated),
        bad05: percent(bad05, evaluated),
        rms: mean_or_nan(sum_sq, valid).sqrt(),
        rms_inliers: mean_or_nan(sum_sq_inliers, inliers).sqrt(),
        mean_signed: mean_or_nan(sum_signed, valid),
        bad1_valid: percent(bad1_among_valid, valid),
        invalid: percent(evaluated - valid, evaluated),
        confidence_ranking,
    })
}

/// Relative errors of an estimated depth map against depth ground truth (NaN or <= 0 =
/// unknown).
pub fn depth_metrics(depth_m: &ImageF32, gt_depth_m: &ImageF32) -> Result<DepthMetrics, EvalError> {
    depth_metrics_ranked(depth_m, None, gt_depth_m)
}

/// [`depth_metrics`], with the confidence ranking when `confidence` is given.
pub fn depth_metrics_ranked(
    depth_m: &ImageF32,
    confidence: Option<&ImageF32>,
    gt_depth_m: &ImageF32,
) -> Result<DepthMetrics, EvalError> {
    check_size("the depth map", depth_m, gt_depth_m)?;
    if let Some(c) = confidence {
        check_size("the confidence map", c, gt_depth_m)?;
    }
    // (confidence, relative error) of the ground-truth pixels with a valid estimate.
    let mut ranked: Vec<(f32, f64)> = Vec::new();
    let mut evaluated = 0usize;
    let mut valid = 0usize;
    let mut sum_rel = 0.0f64;
    let mut within1 = 0usize;
    let mut within5 = 0usize;
    for (i, (&z, &g)) in depth_m.data.iter().zip(&gt_depth_m.data).enumerate() {
        if !valid_depth(g) {
            continue;
        }
        evaluated += 1;
        if !valid_depth(z) {
            continue;
        }
        valid += 1;
        let rel = (f64::from(z) - f64::from(g)).abs() / f64::from(g);
        if let Some(c) = confidence {
            let c = c.data[i];
            ranked.push((if c.is_finite() { c } else { 0.0 }, rel));
        }
        sum_rel += rel;
        if rel <= 0.01 {
            within1 += 1;
        }
        if rel <= 0.05 {
            within5 += 1;
        }
    }
    if evaluated == 0 {
        return Err(EvalError::NoGroundTruthPixels(String::new()));
    }
    let confidence_ranking = (ranked.len() >= 2).then(|| {
        // Most confident first; ties keep pixel order (stable sort).
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        let (top, _) = ranked.split_at(ranked.len() / 2);
        let off = |s: &[(f32, f64)], limit: f64| {
            percent(s.iter().filter(|p| p.1 > limit).count(), s.len())
        };
        DepthConfidenceRanking {
            off1_confident_half: off(top, 0.01),
            off1_all_valid: off(&ranked, 0.01),
            off5_confident_half: off(top, 0.05),
            off5_all_valid: off(&ranked, 0.05),
        }
    });
    Ok(DepthMetrics {
        evaluated_px: evaluated,
        mean_abs_rel: if valid == 0 {
            f64::NAN
        } else {
            sum_rel / valid as f64
        },
        within_1pct: percent(within1, evaluated),
        within_5pct: percent(within5, evaluated),
        invalid: percent(evaluated - valid, evaluated),
        confidence_ranking,
    })
}

/// Metrics of `maps` against the dataset's ground truth, `None` when it has none.
pub fn metrics_for(dataset: &Dataset, maps: &DepthMaps) -> Result<Option<Metrics>, EvalError> {
    match &dataset.ground_truth {
        GroundTruth::Disparity {
            disparity_eval_px,
            focal_baseline_eval,
            border_px,
            ..
        } => Ok(Some(Metrics::Disparity(disparity_metrics(
            &maps.depth_m,
            &maps.confidence,
            disparity_eval_px,
            *focal_baseline_eval,
            *border_px,
        )?))),
        GroundTruth::Depth { depth_m } => Ok(Some(Metrics::Depth(depth_metrics_ranked(
            &maps.depth_m,
            Some(&maps.confidence),
            depth_m,
        )?))),
        GroundTruth::None => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, data: Vec<f32>) -> ImageF32 {
        ImageF32 {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn nonocc_mask_by_hand() {
        // Left row: d = 1, 1, 3, NaN, 2. Right row (x_r = x - d): pixel 0 -> -1 (outside),
        // 1 -> 0 (right 1.0: ok), 2 -> -1 (outside), 3 unknown, 4 -> 2 (right 4.0: occluded).
        let left = img(5, 1, vec![1.0, 1.0, 3.0, f32::NAN, 2.0]);
        let right = img(5, 1, vec![1.0, 1.5, 4.0, 2.0, 2.0]);
        assert_eq!(
            crate::datasets::nonocc_mask(&left, &right),
            vec![false, true, false, false, false]
        );
        // The tolerance is 1 px: right 2.9 at x_r = 2 passes for d = 2 at x = 4.
        let right = img(5, 1, vec![1.0, 1.5, 2.9, 2.0, 2.0]);
        assert_eq!(
            crate::datasets::nonocc_mask(&left, &right),
            vec![false, true, false, false, true]
        );
    }

    #[test]
    fn depth_confidence_ranking_by_hand() {
        // GT 1 m everywhere; relative errors 0, 0.02, 0.10, 0.005, invalid, and confidences
        // 0.9, 0.1, 0.2, 0.8, 1.0: the confident half (0.9, 0.8) is off by 0 and 0.005.
        let gt = img(5, 1, vec![1.0; 5]);
        let depth = img(5, 1, vec![1.0, 1.02, 1.10, 0.995, f32::NAN]);
        let conf = img(5, 1, vec![0.9, 0.1, 0.2, 0.8, 1.0]);
        let m = depth_metrics_ranked(&depth, Some(&conf), &gt).unwrap();
        let r = m.confidence_ranking.unwrap();
        assert_eq!((r.off1_confident_half, r.off5_confident_half), (0.0, 0.0));
        assert_eq!((r.off1_all_valid, r.off5_all_valid), (50.0, 25.0));
        assert!(depth_metrics(&depth, &gt)
            .unwrap()
            .confidence_ranking
            .is_none());
    }

    #[test]
    fn disparity_metrics_by_hand() {
        // f B = 10: z = 10 / d. GT row: 2, 2, NaN, 4, 5, 8.
        let gt = img(6, 1, vec![2.0, 2.0, f32::NAN, 4.0, 5.0, 8.0]);
        // Estimates: d = 2 (ok), 4.5 (bad1+bad2), any (no GT), invalid, 6.5 (bad1 only), 8.
        let depth = img(
            6,
            1,
            vec![5.0, 10.0 / 4.5, 1.0, f32::NAN, 10.0 / 6.5, 10.0 / 8.0],
        );
        let conf = img(6, 1, vec![0.9, 0.1, 0.5, 0.0, 0.2, 0.8]);
        let m = disparity_metrics(&depth, &conf, &gt, 10.0, 0).unwrap();
        assert_eq!(m.evaluated_px, 5);
        assert!((m.bad1 - 60.0).abs() < 1e-9, "{m:?}");
        assert!((m.bad2 - 40.0).abs() < 1e-9);
        assert!((m.bad1_valid - 50.0).abs() < 1e-9);
        assert!((m.invalid - 20.0).abs() < 1e-9);
        // Precision: signed errors 0, +2.5, +1.5, 0 over the valid four; bad>0.5 counts the
        // invalid one too; the inliers (within 2 px) are 0, 1.5, 0.
        assert!((m.bad05 - 60.0).abs() < 1e-9);
        assert!((m.rms - 2.125f64.sqrt()).abs() < 1e-6, "{m:?}");
        assert!((m.rms_inliers - 0.75f64.sqrt()).abs() < 1e-6);
        assert!((m.mean_signed - 1.0).abs() < 1e-6);
        let r = m.confidence_ranking.unwrap();
        // Valid: conf .9 ok, .1 bad, .2 bad, .8 ok -> top half (.9, .8) 0 %, rest 100 %.
        assert_eq!((r.bad1_confident_half, r.bad1_rest), (0.0, 100.0));
    }
}
