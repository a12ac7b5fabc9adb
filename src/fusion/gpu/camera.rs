//! The integration shader's camera (`shaders/camera.wgsl`'s `Camera`) from the projector of
//! a depth map's view.

use bytemuck::{Pod, Zeroable};

use crate::fusion::integrate::Projector;
use crate::geometry::{CameraModel, Distortion};

/// `camera.wgsl`'s distortion models.
const DIST_NONE: u32 = 0;
const DIST_PLUMB_BOB: u32 = 1;
const DIST_EQUIDISTANT: u32 = 2;

/// WGSL `Camera` (`shaders/camera.wgsl`); only the intrinsics, distortion and size are read.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuCamera {
    rows: [[f32; 4]; 3],
    intrinsics: [f32; 4],
    dist_a: [f32; 4],
    dist_b: [f32; 4],
    size: [u32; 4],
    info: [u32; 4],
}

/// The shader's camera: the projector's intrinsics (f32, as the CPU's pinhole path uses
/// them), the distortion's coefficients and the square of its largest undistorted radius.
pub(super) fn gpu_camera(projector: &Projector, model: &CameraModel) -> GpuCamera {
    let k = &model.intrinsics;
    let intrinsics = match *projector {
        Projector::Pinhole { fx, fy, cx, cy } => [fx, fy, cx, cy],
        Projector::Distorted(..) => [k.fx_px, k.fy_px, k.cx_px, k.cy_px].map(|v| v as f32),
    };
    let max_radius = match projector {
        Projector::Pinhole { .. } => f64::INFINITY,
        Projector::Distorted(_, radius) => *radius,
    };
    let max_r2 = (max_radius * max_radius).min(f64::from(f32::MAX)) as f32;
    let (kind, dist_a, dist_b) = match model.distortion {
        Distortion::None => (DIST_NONE, [0.0; 4], [0.0, f32::MAX, 0.0, 0.0]),
        Distortion::PlumbBob { k1, k2, p1, p2, k3 } => (
            DIST_PLUMB_BOB,
            [k1, k2, p1, p2].map(|v| v as f32),
            [k3 as f32, max_r2, 0.0, 0.0],
        ),
        Distortion::Equidistant { k1, k2, k3, k4 } => (
            DIST_EQUIDISTANT,
            [k1, k2, k3, k4].map(|v| v as f32),
            [0.0, max_r2, 0.0, 0.0],
        ),
    };
    GpuCamera {
        rows: [[0.0; 4]; 3],
        intrinsics,
        dist_a,
        dist_b,
        size: [k.width_px, k.height_px, 0, kind],
        info: [0; 4],
    }
}
