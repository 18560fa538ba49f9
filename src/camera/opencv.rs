//! OpenCV calibrations: `cv2.Rodrigues` rotation vectors and `cv2.projectPoints` distortion
//! vectors of 4, 5, 8 or 12 coefficients, and their conversion to COLMAP models.
//!
//! Pixel conventions differ by half a pixel: OpenCV puts the centre of the first pixel at
//! (0, 0), COLMAP at (0.5, 0.5). [`OpencvCamera::to_colmap`] adds 0.5 to the principal point
//! so that the same physical ray lands on the same pixel.

use super::CameraModel;
use nalgebra::{Rotation3, Vector3};

/// OpenCV's rotation vector (axis times angle in radians) as a rotation matrix.
pub fn rodrigues(rvec: [f64; 3]) -> Rotation3<f64> {
    Rotation3::from_scaled_axis(Vector3::from(rvec))
}

/// Intrinsics and distortion as OpenCV stores them.
#[derive(Debug, Clone, PartialEq)]
pub struct OpencvCamera {
    /// Focal lengths and principal point, OpenCV convention (first pixel centre at 0, 0).
    pub fx: f64,
    /// See `fx`.
    pub fy: f64,
    /// See `fx`.
    pub cx: f64,
    /// See `fx`.
    pub cy: f64,
    /// `k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4]]]`: 4, 5, 8 or 12 coefficients.
    pub dist: Vec<f64>,
}

impl OpencvCamera {
    fn coeff(&self, i: usize) -> f64 {
        self.dist.get(i).copied().unwrap_or(0.0)
    }

    /// Distorts normalised coordinates exactly as `cv2.projectPoints` does.
    pub fn distort(&self, x: f64, y: f64) -> [f64; 2] {
        let c = |i| self.coeff(i);
        let (k1, k2, p1, p2, k3, k4, k5, k6) = (c(0), c(1), c(2), c(3), c(4), c(5), c(6), c(7));
        let (s1, s2, s3, s4) = (c(8), c(9), c(10), c(11));
        let r2 = x * x + y * y;
        let (r4, r6) = (r2 * r2, r2 * r2 * r2);
        let radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
        [
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4,
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4,
        ]
    }

    /// Pixel (OpenCV convention) of camera-frame point `p`, or `None` behind the camera.
    pub fn project(&self, p: &Vector3<f64>) -> Option<[f64; 2]> {
        if p.z <= 0.0 {
            return None;
        }
        let [x, y] = self.distort(p.x / p.z, p.y / p.z);
        Some([self.fx * x + self.cx, self.fy * y + self.cy])
    }

    /// The equivalent COLMAP model and parameters (principal point shifted by +0.5), or `None`
    /// when thin-prism terms are non-zero: no COLMAP model has OpenCV's rational thin prism.
    pub fn to_colmap(&self) -> Option<(CameraModel, Vec<f64>)> {
        let c = |i| self.coeff(i);
        let base = [self.fx, self.fy, self.cx + 0.5, self.cy + 0.5];
        if (8..12).any(|i| c(i) != 0.0) || !matches!(self.dist.len(), 4 | 5 | 8 | 12) {
            return None;
        }
        if (4..8).all(|i| c(i) == 0.0) {
            let mut p = base.to_vec();
            p.extend((0..4).map(c));
            return Some((CameraModel::Opencv, p));
        }
        let mut p = base.to_vec();
        p.extend((0..8).map(c));
        Some((CameraModel::FullOpencv, p))
    }
}
