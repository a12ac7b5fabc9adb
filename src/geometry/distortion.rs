//! Lens distortion models, with OpenCV's formulas, and their inverses.
//!
//! Both models map an undistorted normalised point `p = (x/z, y/z)` to a distorted one, as
//! `cv::projectPoints` (`plumb_bob`) and `cv::fisheye::projectPoints` (`equidistant`) do. Each is
//! a radial polynomial that is monotonic only up to a limit; past it the model *folds over*:
//! rays farther off axis land closer to the centre again. [`Distortion::undistort`] solves
//! the model on its monotonic branch only (safeguarded Newton with a bisection bracket, to the
//! last bits of an f64), so it converges wherever the model is defined, where OpenCV's
//! fixed-point iteration stops converging (fisheye beyond ~50 degrees, strong pincushion);
//! [`Distortion::max_undistorted_radius`] says where that branch ends, and
//! [`super::CameraModel::validate`] refuses a camera whose image reaches past a fold.

use glam::DVec2;
use serde::{Deserialize, Serialize};

/// Lens distortion, applied inside the projection (no rectification pass).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    #[default]
    None,
    /// Brown-Conrady as in OpenCV / ROS `plumb_bob`: D = [k1, k2, p1, p2, k3].
    PlumbBob {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    },
    /// Fisheye (Kannala-Brandt) as in OpenCV fisheye / ROS `equidistant`: D = [k1, k2, k3, k4].
    Equidistant { k1: f64, k2: f64, k3: f64, k4: f64 },
}

/// Iterations of the 1-D and 2-D solvers; each converges in a handful, the bound only stops a
/// pathological input.
const MAX_ITERATIONS: usize = 100;

/// How many models' branch ends [`Distortion::branch_end`] keeps per thread (a rig's cameras).
const BRANCH_END_CACHE: usize = 16;

/// A model (its kind and radial coefficients' bits) and its branch end.
type BranchEnd = ([u64; 5], f64);

thread_local! {
    static BRANCH_ENDS: std::cell::RefCell<Vec<BranchEnd>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

impl Distortion {
    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// The coefficients, for messages and finiteness checks.
    pub fn coefficients(&self) -> Vec<f64> {
        match *self {
            Distortion::None => Vec::new(),
            Distortion::PlumbBob { k1, k2, p1, p2, k3 } => vec![k1, k2, p1, p2, k3],
            Distortion::Equidistant { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        }
    }

    /// The model's ROS / OpenCV name.
    pub fn name(&self) -> &'static str {
        match self {
            Distortion::None => "none",
            Distortion::PlumbBob { .. } => "plumb_bob",
            Distortion::Equidistant { .. } => "equidistant",
        }
    }

    /// Maps an undistorted normalised image point (x/z, y/z) to the distorted one (OpenCV's
    /// formulas; defined everywhere, folded branch included).
    pub fn distort(&self, p: DVec2) -> DVec2 {
        match *self {
            Distortion::None => p,
            Distortion::PlumbBob { k1, k2, p1, p2, k3 } => {
                let r2 = p.length_squared();
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let xy = p.x * p.y;
                DVec2::new(
                    p.x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * p.x * p.x),
                    p.y * radial + p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * p2 * xy,
                )
            }
            Distortion::Equidistant { .. } => {
                let r = p.length();
                if r < 1e-12 {
                    return p;
                }
                p * (self.radial(r.atan()) / r)
            }
        }
    }

    /// The radial function: the distorted radius of an undistorted radius `r` (plumb_bob,
    /// without the tangential terms), or theta_d of the angle `theta` off axis (equidistant).
    fn radial(&self, v: f64) -> f64 {
        let s = v * v;
        match *self {
            Distortion::None => v,
            Distortion::PlumbBob { k1, k2, k3, .. } => v * (1.0 + s * (k1 + s * (k2 + s * k3))),
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                v * (1.0 + s * (k1 + s * (k2 + s * (k3 + s * k4))))
            }
        }
    }

    /// The derivative of [`Self::radial`], as a polynomial in `s = v²`: its coefficients.
    fn radial_derivative_coefficients(&self) -> Vec<f64> {
        match *self {
            Distortion::None => vec![1.0],
            Distortion::PlumbBob { k1, k2, k3, .. } => vec![1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3],
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                vec![1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3, 9.0 * k4]
            }
        }
    }

    fn radial_derivative(&self, v: f64) -> f64 {
        polynomial(&self.radial_derivative_coefficients(), v * v)
    }

    /// Where the monotonic branch of [`Self::radial`] ends, in the model's own variable
    /// (undistorted radius for plumb_bob, angle off axis for equidistant, at most pi/2 there):
    /// the first zero of its derivative, or infinity (plumb_bob) / pi/2 (equidistant).
    ///
    /// The root search takes up to 20 000 polynomial evaluations (all of them when the model
    /// never folds), and [`super::CameraModel::project`] and [`Self::undistort`] need the end
    /// for every point: the ends of the last [`BRANCH_END_CACHE`] models are kept per thread
    /// (the same value, looked up by the coefficients' bits).
    fn branch_end(&self) -> f64 {
        let key = match *self {
            Distortion::None => return f64::INFINITY,
            Distortion::PlumbBob { k1, k2, k3, .. } => {
                [1, k1.to_bits(), k2.to_bits(), k3.to_bits(), 0]
            }
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                [2, k1.to_bits(), k2.to_bits(), k3.to_bits(), k4.to_bits()]
            }
        };
        BRANCH_ENDS.with(|ends| {
            let mut ends = ends.borrow_mut();
            if let Some(&(_, end)) = ends.iter().find(|(k, _)| *k == key) {
                return end;
            }
            let end = self.branch_end_uncached();
            if ends.len() == BRANCH_END_CACHE {
                ends.pop();
            }
            ends.insert(0, (key, end));
            end
        })
    }

    fn branch_end_uncached(&self) -> f64 {
        let first_zero = first_positive_root(&self.radial_derivative_coefficients());
        match self {
            Distortion::Equidistant { .. } => {
                let horizon = std::f64::consts::FRAC_PI_2;
                first_zero.map_or(horizon, |s| s.sqrt().min(horizon))
            }
            _ => first_zero.map_or(f64::INFINITY, f64::sqrt),
        }
    }

    /// Whether the model folds over at `branch_end` (its derivative turns negative
    /// there), rather than merely reaching the horizon.
    pub fn fold(&self) -> Option<Fold> {
        let end = self.branch_end();
        let folds = match self {
            Distortion::None => false,
            Distortion::PlumbBob { .. } => end.is_finite(),
            Distortion::Equidistant { .. } => end < std::f64::consts::FRAC_PI_2,
        };
        folds.then(|| {
            let (undistorted_radius, angle_rad) = match self {
                Distortion::Equidistant { .. } => (end.tan(), end),
                _ => (end, end.atan()),
            };
            Fold {
                undistorted_radius,
                distorted_radius: self.radial(end),
                angle_rad,
            }
        })
    }

    /// The largest undistorted normalised radius `|(x/z, y/z)|` on the monotonic branch:
    /// points farther off axis are on the folded branch and have no true image (infinite when
    /// the model never folds in front of the camera).
    pub fn max_undistorted_radius(&self) -> f64 {
        self.fold().map_or(f64::INFINITY, |f| f.undistorted_radius)
    }

    /// The largest distorted normalised radius that has a ray in front of the camera: the
    /// fold's, or for equidistant without a fold the horizon's (theta_d at 90 degrees);
    /// infinite for plumb_bob without a fold.
    pub fn max_distorted_radius(&self) -> f64 {
        match (self, self.fold()) {
            (_, Some(fold)) => fold.distorted_radius,
            (Distortion::Equidistant { .. }, None) => self.radial(std::f64::consts::FRAC_PI_2),
            _ => f64::INFINITY,
        }
    }

    /// Inverse of [`Distortion::distort`] on the monotonic branch: the undistorted normalised
    /// point, or `None` when `distorted` has no ray in front of the camera on that branch
    /// (beyond the fold, or beyond 90 degrees for a fisheye).
    ///
    /// Equidistant: theta from theta_d by safeguarded Newton on the bracket [0, branch end].
    /// Plumb_bob: the radial part the same way, then 2-D Newton with the full Jacobian
    /// (tangential terms), step halving, and the solution kept on the branch; `None` if it
    /// does not converge to 1e-12 (relative).
    pub fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        if !distorted.is_finite() {
            return None;
        }
        match *self {
            Distortion::None => Some(distorted),
            Distortion::Equidistant { .. } => {
                let theta_d = distorted.length();
                if theta_d == 0.0 {
                    return Some(distorted);
                }
                let end = self.branch_end();
                if theta_d > self.radial(end) {
                    return None;
                }
                let theta = self.solve_radial(theta_d, end);
                if theta >= std::f64::consts::FRAC_PI_2 {
                    return None;
                }
                Some(distorted * (theta.tan() / theta_d))
            }
            Distortion::PlumbBob { .. } => self.undistort_plumb_bob(distorted),
        }
    }

    /// Solves `radial(v) = target` for v in [0, hi] (radial increasing there).
    fn solve_radial(&self, target: f64, hi: f64) -> f64 {
        let (mut lo, mut hi) = (0.0f64, hi);
        if !hi.is_finite() {
            // plumb_bob without a fold: radial grows without bound; find a bracket.
            hi = target.max(1.0);
            while self.radial(hi) < target && hi < 1e150 {
                hi *= 2.0;
            }
        }
        let mut v = target.clamp(lo, hi);
        for _ in 0..MAX_ITERATIONS {
            let f = self.radial(v) - target;
            if f == 0.0 {
                return v;
            }
            if f < 0.0 {
                lo = v;
            } else {
                hi = v;
            }
            let slope = self.radial_derivative(v);
            let mut next = v - f / slope;
            if !(slope > 0.0 && next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
            if (next - v).abs() <= 1e-16 * v.abs().max(1e-300) || hi - lo <= 1e-16 * hi {
                return next;
            }
            v = next;
        }
        v
    }

    fn undistort_plumb_bob(&self, target: DVec2) -> Option<DVec2> {
        let Distortion::PlumbBob { k1, k2, p1, p2, k3 } = *self else {
            return None;
        };
        let r_max = self.max_undistorted_radius();
        let rd = target.length();
        if rd == 0.0 {
            return Some(target);
        }
        // The radial-only solution is the start (exact without tangential terms).
        let r0 = if r_max.is_finite() && rd >= self.radial(r_max) {
            r_max
        } else {
            self.solve_radial(rd, r_max)
        };
        let mut p = target * (r0 / rd);
        let residual = |p: DVec2| self.distort(p) - target;
        let mut f = residual(p);
        let tolerance = 1e-12 * rd.max(1.0);
        for _ in 0..MAX_ITERATIONS {
            if f.length() <= 1e-15 * rd.max(1.0) {
                break;
            }
            // The Jacobian of distort at p.
            let r2 = p.length_squared();
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let q = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
            let (x, y) = (p.x, p.y);
            let j00 = radial + 2.0 * x * x * q + 2.0 * p1 * y + 6.0 * p2 * x;
            let j01 = 2.0 * x * y * q + 2.0 * p1 * x + 2.0 * p2 * y;
            let j11 = radial + 2.0 * y * y * q + 6.0 * p1 * y + 2.0 * p2 * x;
            let det = j00 * j11 - j01 * j01;
            if !(det.is_finite() && det != 0.0) {
                break;
            }
            let step = DVec2::new(j11 * f.x - j01 * f.y, j00 * f.y - j01 * f.x) / det;
            let mut scale = 1.0;
            let mut accepted = false;
            for _ in 0..60 {
                let next = p - step * scale;
                let f_next = residual(next);
                if next.length() <= r_max && f_next.length() < f.length() {
                    p = next;
                    f = f_next;
                    accepted = true;
                    break;
                }
                scale *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        (f.length() <= tolerance && p.length() <= r_max).then_some(p)
    }
}

/// Where a distortion model folds over (its radial function stops increasing).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fold {
    /// Undistorted normalised radius `|(x/z, y/z)|` of the fold.
    pub undistorted_radius: f64,
    /// Distorted normalised radius there: no ray of the branch lands farther out.
    pub distorted_radius: f64,
    /// The angle off the optical axis of the fold, radians.
    pub angle_rad: f64,
}

/// `sum c[i] s^i`.
fn polynomial(coefficients: &[f64], s: f64) -> f64 {
    coefficients.iter().rev().fold(0.0, |acc, &c| acc * s + c)
}

/// The smallest `s > 0` where the polynomial (with `c[0] = 1 > 0`) reaches 0, or `None`.
///
/// Every real root lies within Cauchy's bound `1 + max |c[i] / c[n]|`; the interval up to it
/// is scanned on a geometric grid of 20000 points for the first sign change, then bisected to
/// the last bit. (A dip below zero narrower than one grid step, 0.14 % of s, is not seen:
/// such a fold spans less than a hundredth of a degree.)
fn first_positive_root(c: &[f64]) -> Option<f64> {
    let n = c.iter().rposition(|&v| v != 0.0)?;
    if n == 0 {
        return None;
    }
    let bound = 1.0 + c[..n].iter().map(|v| (v / c[n]).abs()).fold(0.0, f64::max);
    const STEPS: usize = 20_000;
    let start = bound * 1e-12;
    let ratio = (bound / start).powf(1.0 / STEPS as f64);
    let mut lo = 0.0;
    let mut s = start;
    for _ in 0..=STEPS {
        if polynomial(c, s) <= 0.0 {
            let mut hi = s;
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if polynomial(c, mid) <= 0.0 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            return Some(hi);
        }
        lo = s;
        s *= ratio;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fisheye(k1: f64, k2: f64, k3: f64, k4: f64) -> Distortion {
        Distortion::Equidistant { k1, k2, k3, k4 }
    }

    fn plumb_bob(k1: f64, k2: f64, p1: f64, p2: f64, k3: f64) -> Distortion {
        Distortion::PlumbBob { k1, k2, p1, p2, k3 }
    }

    #[test]
    fn distortion_round_trips() {
        for d in [
            plumb_bob(-0.28, 0.07, 0.001, -0.0005, 0.0),
            fisheye(0.01, -0.005, 0.001, 0.0),
        ] {
            let p = DVec2::new(0.3, -0.2);
            let back = d.undistort(d.distort(p)).unwrap();
            assert!((back - p).length() < 1e-14, "{d:?}: {back:?}");
        }
    }

    /// A direction `deg` degrees off axis, as a normalised point.
    fn off_axis(deg: f64, azimuth_deg: f64) -> DVec2 {
        let r = deg.to_radians().tan();
        let (s, c) = azimuth_deg.to_radians().sin_cos();
        DVec2::new(r * c, r * s)
    }

    #[test]
    fn wide_fisheye_unprojects_to_the_horizon() {
        // A real-world 190-degree-class calibration (monotonic up to 90 degrees): OpenCV's
        // fixed-point undistortion used to stop converging past ~50 degrees.
        let d = fisheye(-0.013, 0.021, -0.014, 0.0026);
        assert_eq!(d.fold(), None);
        for deg in [
            0.5, 10.0, 45.0, 55.0, 60.0, 70.0, 75.0, 80.0, 85.0, 89.0, 89.9,
        ] {
            for azimuth in [0.0, 37.0, 90.0, 200.0] {
                let p = off_axis(deg, azimuth);
                let back = d.undistort(d.distort(p)).unwrap();
                let error = (back - p).length() / p.length();
                assert!(error < 1e-12, "{deg} deg: relative error {error:e}");
            }
        }
        // Beyond the horizon (theta_d past 90 degrees) there is no ray in front.
        let horizon = d.max_distorted_radius();
        assert!(d.undistort(DVec2::new(horizon * 1.001, 0.0)).is_none());
        assert!(d.undistort(DVec2::new(horizon * 0.999, 0.0)).is_some());
    }

    #[test]
    fn fisheye_that_folds_is_inverted_up_to_the_fold_only() {
        // k1 = -0.3 alone: theta_d = theta (1 - 0.3 theta²) peaks at theta = 1/sqrt(0.9).
        let d = fisheye(-0.3, 0.0, 0.0, 0.0);
        let fold = d.fold().unwrap();
        let theta_c = (1.0f64 / 0.9).sqrt();
        assert!((fold.angle_rad - theta_c).abs() < 1e-12, "{fold:?}");
        assert!((fold.distorted_radius - theta_c * (1.0 - 0.3 / 0.9)).abs() < 1e-12);
        // Just inside the fold: still exact.
        let p = off_axis(theta_c.to_degrees() - 0.5, 20.0);
        let back = d.undistort(d.distort(p)).unwrap();
        assert!((back - p).length() < 1e-9 * p.length(), "{back} vs {p}");
        // A point past the fold lands inside (the fold), but unprojects to the branch's ray.
        let beyond = off_axis(theta_c.to_degrees() + 3.0, 0.0);
        let back = d.undistort(d.distort(beyond)).unwrap();
        assert!(back.length() < fold.undistorted_radius);
        assert!(d
            .undistort(DVec2::new(fold.distorted_radius * 1.0001, 0.0))
            .is_none());
    }

    #[test]
    fn strong_pincushion_and_barrel_plumb_bob_converge() {
        for d in [
            plumb_bob(0.9, 0.6, 0.002, -0.003, 0.4), // strong pincushion, never folds
            plumb_bob(-0.42, 0.21, 0.001, 0.0015, -0.05), // strong barrel
            plumb_bob(-0.28, 0.07, 0.0, 0.0, 0.0),
        ] {
            let r_max = d.max_undistorted_radius();
            for deg in [1.0, 20.0, 35.0, 45.0, 55.0, 60.0, 65.0] {
                let p = off_axis(deg, 33.0);
                if p.length() >= 0.98 * r_max {
                    continue;
                }
                let back = d.undistort(d.distort(p)).unwrap();
                let error = (back - p).length() / p.length();
                assert!(
                    error < 1e-12,
                    "{d:?} at {deg} deg: relative error {error:e}"
                );
            }
        }
        // The pincushion one never folds; the barrel one folds (k3 < 0).
        assert_eq!(plumb_bob(0.9, 0.6, 0.002, -0.003, 0.4).fold(), None);
        assert!(plumb_bob(-0.42, 0.21, 0.001, 0.0015, -0.05)
            .fold()
            .is_some());
        // The classic barrel (k1 < 0 alone) folds at r = 1/sqrt(3 |k1|).
        let fold = plumb_bob(-0.3, 0.0, 0.0, 0.0, 0.0).fold().unwrap();
        assert!((fold.undistorted_radius - (1.0f64 / 0.9).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn fixed_point_iteration_fails_where_this_solver_does_not() {
        // The fixed-point iteration p <- p - (distort(p) - target) (what this module used to
        // do) diverges for strong pincushion: make sure the case is a real test of the solver.
        let d = plumb_bob(0.9, 0.6, 0.0, 0.0, 0.4);
        let p = off_axis(40.0, 10.0);
        let target = d.distort(p);
        let mut fixed = target;
        for _ in 0..50 {
            fixed -= d.distort(fixed) - target;
        }
        assert!(
            (fixed - p).length().is_nan() || (fixed - p).length() >= 1e-3,
            "fixed point converged: {fixed}"
        );
        let back = d.undistort(target).unwrap();
        assert!((back - p).length() < 1e-12);
    }

    #[test]
    fn branch_ends_kept_per_thread_are_those_of_the_model() {
        // More models than the cache holds, pairs differing in one radial coefficient only,
        // looked up twice in turn: every lookup gives the model's own end.
        let mut models = Vec::new();
        for i in 0..12 {
            let a = -0.05 * i as f64;
            models.push(plumb_bob(a, 0.0, 0.001, 0.0, 0.0));
            models.push(plumb_bob(a, 0.0, 0.001, 0.0, 0.01));
            models.push(plumb_bob(a, 0.02, 0.001, 0.0, 0.0));
            models.push(fisheye(a, 0.0, 0.0, 0.0));
            models.push(fisheye(a, 0.0, 0.0, -0.01));
        }
        assert!(models.len() > BRANCH_END_CACHE);
        for _ in 0..2 {
            for d in &models {
                let (cached, fresh) = (d.branch_end(), d.branch_end_uncached());
                assert!(
                    cached == fresh || (cached.is_nan() && fresh.is_nan()),
                    "{d:?}: {cached} kept, {fresh} computed"
                );
            }
        }
        // The pairs do differ (else the test could not tell a key that leaves a coefficient out).
        assert_ne!(models[5].branch_end(), models[6].branch_end());
        assert_ne!(models[8].branch_end(), models[9].branch_end());
    }

    #[test]
    fn first_positive_root_finds_the_first_sign_change() {
        // 1 - s: root 1.
        assert!((first_positive_root(&[1.0, -1.0]).unwrap() - 1.0).abs() < 1e-15);
        // (1 - s)(1 - s/4) = 1 - 1.25 s + 0.25 s²: first root 1.
        let r = first_positive_root(&[1.0, -1.25, 0.25]).unwrap();
        assert!((r - 1.0).abs() < 1e-14, "{r}");
        // 1 + s²: none.
        assert_eq!(first_positive_root(&[1.0, 0.0, 1.0]), None);
        assert_eq!(first_positive_root(&[1.0]), None);
        assert_eq!(first_positive_root(&[1.0, 0.0, 0.0]), None);
    }

    #[test]
    fn non_finite_input_has_no_ray() {
        let d = fisheye(0.01, 0.0, 0.0, 0.0);
        assert!(d.undistort(DVec2::new(f64::NAN, 0.0)).is_none());
        assert!(plumb_bob(0.1, 0.0, 0.0, 0.0, 0.0)
            .undistort(DVec2::new(f64::INFINITY, 0.0))
            .is_none());
    }
}
