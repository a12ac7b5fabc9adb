//! Lens distortion models, as OpenCV and ROS name them.

use glam::DVec2;
use serde::{Deserialize, Serialize};

use super::GeometryError;

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

impl Distortion {
    /// Maps an undistorted normalised image point (x/z, y/z) to the distorted one.
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
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                let r = p.length();
                if r < 1e-12 {
                    return p;
                }
                let theta = r.atan();
                let t2 = theta * theta;
                let theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
                p * (theta_d / r)
            }
        }
    }

    /// Inverse of [`Distortion::distort`] by fixed-point iteration (used to unproject pixels of
    /// a distorted reference camera).
    pub fn undistort(&self, distorted: DVec2) -> DVec2 {
        if matches!(self, Distortion::None) {
            return distorted;
        }
        let mut p = distorted;
        for _ in 0..50 {
            let error = self.distort(p) - distorted;
            p -= error;
            if error.length_squared() < 1e-24 {
                break;
            }
        }
        p
    }

    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// Parses a ROS `distortion_model` + `D`.
    pub fn from_ros(camera: &str, model: &str, d: &[f64]) -> Result<Self, GeometryError> {
        let all_zero = d.iter().all(|&v| v == 0.0);
        let need = |expected: usize| {
            if d.len() < expected {
                Err(GeometryError::DistortionCoefficients {
                    camera: camera.to_string(),
                    model: model.to_string(),
                    expected,
                    got: d.len(),
                })
            } else {
                Ok(())
            }
        };
        match model {
            "" | "none" if all_zero => Ok(Distortion::None),
            "plumb_bob" | "rational_polynomial" => {
                if all_zero {
                    return Ok(Distortion::None);
                }
                need(5)?;
                if d.iter().skip(5).any(|&v| v != 0.0) {
                    let model = if model == "rational_polynomial" {
                        "rational_polynomial with non-zero k4..k6".to_string()
                    } else {
                        format!("plumb_bob with {} coefficients (it has 5)", d.len())
                    };
                    return Err(GeometryError::UnsupportedDistortion {
                        camera: camera.to_string(),
                        model,
                    });
                }
                Ok(Distortion::PlumbBob {
                    k1: d[0],
                    k2: d[1],
                    p1: d[2],
                    p2: d[3],
                    k3: d[4],
                })
            }
            "equidistant" | "fisheye" => {
                if all_zero {
                    return Ok(Distortion::None);
                }
                need(4)?;
                if d.iter().skip(4).any(|&v| v != 0.0) {
                    return Err(GeometryError::UnsupportedDistortion {
                        camera: camera.to_string(),
                        model: format!("{model} with {} coefficients (it has 4)", d.len()),
                    });
                }
                Ok(Distortion::Equidistant {
                    k1: d[0],
                    k2: d[1],
                    k3: d[2],
                    k4: d[3],
                })
            }
            other => Err(GeometryError::UnsupportedDistortion {
                camera: camera.to_string(),
                model: other.to_string(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distortion_round_trips() {
        for d in [
            Distortion::PlumbBob {
                k1: -0.28,
                k2: 0.07,
                p1: 0.001,
                p2: -0.0005,
                k3: 0.0,
            },
            Distortion::Equidistant {
                k1: 0.01,
                k2: -0.005,
                k3: 0.001,
                k4: 0.0,
            },
        ] {
            let p = DVec2::new(0.3, -0.2);
            let back = d.undistort(d.distort(p));
            assert!((back - p).length() < 1e-9, "{d:?}: {back:?}");
        }
    }
}
