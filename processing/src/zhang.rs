//! Zhang's closed-form initial calibration: each board homography H gives two linear
//! constraints on the image of the absolute conic B = K⁻ᵀK⁻¹, a zero-skew row gives one more,
//! and K follows from B; each view's pose then follows from K⁻¹H. Pixel coordinates are first
//! scaled to about ±1 so the 6×6 system is well conditioned at any image size.

use nalgebra::{Matrix3, Matrix6, Rotation3, Vector3, Vector6};

use crate::camera_model::{Intrinsics, Pose};
use crate::error::ProcessingError;

/// The similarity taking pixels of a `width × height` image to about [−1, 1].
fn pixel_normaliser(width: f64, height: f64) -> Matrix3<f64> {
    let s = 2.0 / width.max(height);
    Matrix3::new(
        s,
        0.0,
        -s * width / 2.0,
        0.0,
        s,
        -s * height / 2.0,
        0.0,
        0.0,
        1.0,
    )
}

/// v_ij of Zhang's paper for columns i, j of `h`.
fn v(h: &Matrix3<f64>, i: usize, j: usize) -> Vector6<f64> {
    let (a, b) = (h.column(i), h.column(j));
    Vector6::new(
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[1] * b[1],
        a[2] * b[0] + a[0] * b[2],
        a[2] * b[1] + a[1] * b[2],
        a[2] * b[2],
    )
}

/// Intrinsics from the homographies of at least 2 views of a plane in different orientations
/// (3 or more for a well-conditioned answer) in a `width × height` image.
pub fn intrinsics_from_homographies(
    homographies: &[Matrix3<f64>],
    width: f64,
    height: f64,
) -> Result<Intrinsics, ProcessingError> {
    let ill = |why: &str| ProcessingError::IllPosed {
        what: "closed-form calibration",
        why: why.to_string(),
    };
    if homographies.len() < 2 {
        return Err(ill(
            "it needs the board in at least 2 orientations (3 or more recommended)",
        ));
    }
    let n = pixel_normaliser(width, height);
    let mut vtv = Matrix6::<f64>::zeros();
    for h in homographies {
        let mut hn = n * h;
        hn /= hn.norm();
        for row in [v(&hn, 0, 1), v(&hn, 0, 0) - v(&hn, 1, 1)] {
            vtv += row * row.transpose();
        }
    }
    // Zero skew: B12 = 0, weighted like one view's constraints.
    let skew = Vector6::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
    vtv += skew * skew.transpose() * (vtv.trace() / homographies.len() as f64);
    let eigen = vtv.symmetric_eigen();
    let mut order: Vec<usize> = (0..6).collect();
    order.sort_by(|&i, &j| eigen.eigenvalues[i].total_cmp(&eigen.eigenvalues[j]));
    let (e0, e1, e5) = (
        eigen.eigenvalues[order[0]],
        eigen.eigenvalues[order[1]],
        eigen.eigenvalues[order[5]],
    );
    let constrained = e1 >= 1e-10 * e5; // false for NaN too
    if !constrained || !e0.is_finite() {
        return Err(ill(
            "the board's orientations do not constrain the camera (all placements parallel, e.g. only turned in the board's own plane); tilt the board in at least 3 placements",
        ));
    }
    let mut b = eigen.eigenvectors.column(order[0]).into_owned();
    if b[0] < 0.0 {
        b = -b;
    }
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if !(den > 0.0 && b11 > 0.0) {
        return Err(ill(
            "the conic is not an ellipse (too few or too similar orientations)",
        ));
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let alpha2 = lambda / b11;
    let beta2 = lambda * b11 / den;
    if !(alpha2 > 0.0 && beta2 > 0.0) {
        return Err(ill(
            "the focal length comes out imaginary (too few or too similar orientations)",
        ));
    }
    let (alpha, beta) = (alpha2.sqrt(), beta2.sqrt());
    let gamma = -b12 * alpha2 * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha2 / lambda;
    // Back from normalised to pixel units: K = N⁻¹ K'.
    let kn = Matrix3::new(alpha, gamma, u0, 0.0, beta, v0, 0.0, 0.0, 1.0);
    let k = n
        .try_inverse()
        .map(|ni| ni * kn)
        .ok_or_else(|| ill("the image size is zero"))?;
    let intr = Intrinsics {
        fx: k[(0, 0)],
        fy: k[(1, 1)],
        cx: k[(0, 2)],
        cy: k[(1, 2)],
    };
    if [intr.fx, intr.fy, intr.cx, intr.cy]
        .iter()
        .all(|v| v.is_finite())
    {
        Ok(intr)
    } else {
        Err(ill("the solution is not finite"))
    }
}

/// The board's pose in the camera from its homography and the intrinsics, the rotation made
/// orthonormal (nearest rotation by SVD) and the board in front of the camera.
pub fn pose_from_homography(k: &Intrinsics, h: &Matrix3<f64>) -> Option<Pose> {
    let kinv = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0).try_inverse()?;
    let m = kinv * h;
    let (h1, h2, h3) = (m.column(0), m.column(1), m.column(2));
    let mut scale = 1.0 / h1.norm();
    if (h3 * scale).z < 0.0 {
        scale = -scale;
    }
    let r1 = h1 * scale;
    let r2 = h2 * scale;
    let r3 = r1.cross(&r2);
    let r = Matrix3::from_columns(&[r1.into_owned(), r2.into_owned(), r3]);
    let svd = r.svd(true, true);
    let mut nearest = svd.u? * svd.v_t?;
    if nearest.determinant() < 0.0 {
        nearest = -nearest;
    }
    let t: Vector3<f64> = (h3 * scale).into_owned();
    let rotation = Rotation3::from_matrix_unchecked(nearest);
    let pose = Pose::from_parts(&rotation, t);
    pose.rotation
        .iter()
        .chain(&pose.translation)
        .all(|v| v.is_finite())
        .then_some(pose)
}
