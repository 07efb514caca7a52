//! Camera intrinsics with Brown–Conrady lens distortion: focal length and principal point in
//! pixels, radial (k1, k2, k3) and tangential (p1, p2) coefficients on normalised image
//! coordinates.
//!
//! Normalised coordinates are `x = (u − cx) / f`, `y = (v − cy) / f` for a pixel position
//! (u, v) measured from the top-left corner (v grows downward), so they are the ideal pinhole
//! image of a point at (x, y, 1) in the camera frame (x right, y down, z forward). The forward
//! model maps undistorted to distorted coordinates:
//!
//! ```text
//! r² = x² + y²,  R = 1 + k1 r² + k2 r⁴ + k3 r⁶
//! x_d = x R + 2 p1 x y + p2 (r² + 2 x²)
//! y_d = y R + p1 (r² + 2 y²) + 2 p2 x y
//! ```
//!
//! [`BrownConrady::undistort`] inverts it with damped Newton iterations. [`Intrinsics::check`]
//! accepts only lenses the inversion is unique for over the whole image: the radial map r·R(r²)
//! positive and strictly increasing out past the farthest image corner, and the full map
//! orientation-preserving (positive Jacobian) and round-tripping across the image.

use crate::rig::CameraSpec;

/// Most Newton iterations [`BrownConrady::undistort`] spends.
pub const MAX_ITERATIONS: u32 = 20;
/// Convergence tolerance of the inversion, in normalised units (≈ 1e-9 px for f ≈ 5000 px).
pub const TOLERANCE: f64 = 1.0e-12;
/// Largest round-trip error, in pixels, [`Intrinsics::check`] accepts anywhere in the image.
const ROUND_TRIP_TOLERANCE_PX: f64 = 1.0e-6;
/// Grid points per side over which [`Intrinsics::check`] tests the inversion.
const CHECK_GRID: u32 = 17;
/// Radial steps per normalised corner radius in the monotonicity march.
const RADIAL_STEPS: u32 = 4096;

/// Brown–Conrady distortion coefficients (all zero: an ideal pinhole).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BrownConrady {
    /// First radial coefficient (negative: barrel, positive: pincushion).
    pub k1: f64,
    /// Second radial coefficient.
    pub k2: f64,
    /// Third radial coefficient.
    pub k3: f64,
    /// First tangential (decentring) coefficient.
    pub p1: f64,
    /// Second tangential (decentring) coefficient.
    pub p2: f64,
}

impl BrownConrady {
    /// The coefficients of a rig camera.
    pub fn of(spec: &CameraSpec) -> BrownConrady {
        BrownConrady {
            k1: spec.k1,
            k2: spec.k2,
            k3: spec.k3,
            p1: spec.p1,
            p2: spec.p2,
        }
    }

    /// True when every coefficient is zero: the forward model is the identity.
    #[inline]
    pub fn is_identity(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.k3 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0
    }

    /// Radial factor R(r²) = 1 + k1 r² + k2 r⁴ + k3 r⁶.
    #[inline]
    pub fn radial(&self, r2: f64) -> f64 {
        1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
    }

    /// dR/d(r²).
    #[inline]
    fn radial_slope(&self, r2: f64) -> f64 {
        self.k1 + r2 * (2.0 * self.k2 + r2 * 3.0 * self.k3)
    }

    /// The forward model: distorted normalised coordinates of undistorted (x, y).
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian [[∂x_d/∂x, ∂x_d/∂y], [∂y_d/∂x, ∂y_d/∂y]] of [`BrownConrady::distort`].
    #[inline]
    pub fn jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        let slope = self.radial_slope(r2);
        let cross = 2.0 * x * y * slope + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        [
            [
                radial + 2.0 * x * x * slope + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
                cross,
            ],
            [
                cross,
                radial + 2.0 * y * y * slope + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
            ],
        ]
    }

    /// Undistorted normalised coordinates whose distortion is (xd, yd), and whether the
    /// inversion converged. Damped Newton: at most [`MAX_ITERATIONS`] steps, each halved
    /// until it reduces the residual, stopping once a step is below [`TOLERANCE`]. For a lens
    /// [`Intrinsics::check`] accepted it converges everywhere in the image.
    #[inline]
    pub fn undistort(&self, xd: f64, yd: f64) -> ((f64, f64), bool) {
        if self.is_identity() {
            return ((xd, yd), true);
        }
        let residual = |x: f64, y: f64| {
            let (dx, dy) = self.distort(x, y);
            (dx - xd, dy - yd)
        };
        // Start from the radial-only fixed-point guess.
        let r2 = xd * xd + yd * yd;
        let guess = self.radial(r2);
        let (mut x, mut y) = if guess > 0.1 {
            (xd / guess, yd / guess)
        } else {
            (xd, yd)
        };
        let (mut fx, mut fy) = residual(x, y);
        for _ in 0..MAX_ITERATIONS {
            let [[a, b], [c, d]] = self.jacobian(x, y);
            let det = a * d - b * c;
            if !(det.is_finite() && det.abs() > f64::MIN_POSITIVE) {
                break;
            }
            let sx = (d * fx - b * fy) / det;
            let sy = (a * fy - c * fx) / det;
            let norm2 = squared_norm(fx, fy);
            let mut scale = 1.0;
            let mut accepted = false;
            for _ in 0..8 {
                let (nx, ny) = (x - scale * sx, y - scale * sy);
                let (gx, gy) = residual(nx, ny);
                if squared_norm(gx, gy) <= norm2 || norm2 == 0.0 {
                    (x, y, fx, fy) = (nx, ny, gx, gy);
                    accepted = true;
                    break;
                }
                scale *= 0.5;
            }
            if !accepted {
                break;
            }
            if squared_norm(scale * sx, scale * sy) < TOLERANCE * TOLERANCE {
                return ((x, y), true);
            }
        }
        let converged = squared_norm(fx, fy) < (TOLERANCE * 16.0) * (TOLERANCE * 16.0);
        ((x, y), converged)
    }
}

/// x² + y²: the inversion compares residual lengths by their squares, which orders them as
/// `hypot` does at a fraction of its cost (it runs three times a rendered pixel). A square that
/// overflows is infinite and never counts as a reduction below a finite one.
#[inline]
fn squared_norm(x: f64, y: f64) -> f64 {
    x * x + y * y
}

/// Pixel geometry of a camera: focal length, principal point and lens.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length in pixels, from the horizontal field of view.
    pub focal_px: f64,
    /// Principal point, pixels from the left edge (image centre plus `cx`).
    pub principal_x: f64,
    /// Principal point, pixels from the top edge (image centre plus `cy`).
    pub principal_y: f64,
    /// Lens distortion.
    pub lens: BrownConrady,
}

/// Why a lens cannot be inverted uniquely over the image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LensError {
    /// The field of view gives no finite positive focal length.
    #[error("the field of view gives no usable focal length")]
    NoFocalLength,
    /// The radial map stops increasing inside the image.
    #[error(
        "the radial distortion folds back at {at_px:.0} px from the principal point, inside the image (corner at {corner_px:.0} px): 1 + k1 r² + k2 r⁴ + k3 r⁶ must stay positive and r·(1 + k1 r² + …) increasing out to the image corner"
    )]
    FoldsBack {
        /// Image radius where it folds, in pixels.
        at_px: f64,
        /// Radius of the farthest image corner, in pixels.
        corner_px: f64,
    },
    /// The corner is pulled in beyond 8× its pinhole radius.
    #[error(
        "the radial distortion compresses the image corner ({0:.0} px from the principal point) beyond 8× its pinhole radius; use smaller radial coefficients"
    )]
    CornerCompressed(f64),
    /// A pixel where undistortion fails or the map folds.
    #[error(
        "the distortion cannot be inverted at pixel ({u:.0}, {v:.0}): the tangential (p1, p2) or radial terms fold the image there; use smaller coefficients"
    )]
    NotInvertible {
        /// Column.
        u: f64,
        /// Row.
        v: f64,
    },
}

impl Intrinsics {
    /// The intrinsics of a rig camera.
    pub fn of(spec: &CameraSpec) -> Intrinsics {
        Intrinsics {
            width: spec.width,
            height: spec.height,
            focal_px: 0.5 * spec.width as f64 / (0.5 * spec.fov_deg.to_radians()).tan(),
            principal_x: 0.5 * spec.width as f64 + spec.cx,
            principal_y: 0.5 * spec.height as f64 + spec.cy,
            lens: BrownConrady::of(spec),
        }
    }

    /// Normalised distance from the principal point to the farthest image corner.
    pub fn corner_radius(&self) -> f64 {
        let dx = self
            .principal_x
            .abs()
            .max((self.width as f64 - self.principal_x).abs());
        let dy = self
            .principal_y
            .abs()
            .max((self.height as f64 - self.principal_y).abs());
        dx.hypot(dy) / self.focal_px
    }

    /// Pixel position of undistorted normalised coordinates.
    pub fn to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        let (xd, yd) = self.lens.distort(x, y);
        (
            self.principal_x + self.focal_px * xd,
            self.principal_y + self.focal_px * yd,
        )
    }

    /// Undistorted normalised coordinates of a pixel position, and whether the inversion
    /// converged.
    pub fn from_pixel(&self, u: f64, v: f64) -> ((f64, f64), bool) {
        self.lens.undistort(
            (u - self.principal_x) / self.focal_px,
            (v - self.principal_y) / self.focal_px,
        )
    }

    /// Checks that the lens can be inverted uniquely over the whole image: the radial map
    /// r·R(r²) stays positive and strictly increasing until it passes the farthest corner, and
    /// every point of a grid over the image undistorts (converging), has a positive Jacobian
    /// and projects back within 1e-6 px.
    pub fn check(&self) -> Result<(), LensError> {
        let lens = &self.lens;
        if lens.is_identity() {
            return Ok(());
        }
        let corner = self.corner_radius();
        if !(corner.is_finite() && corner > 0.0) {
            return Err(LensError::NoFocalLength);
        }
        // March the undistorted radius outward until its image passes the corner.
        let step = corner / RADIAL_STEPS as f64;
        let mut r = 0.0f64;
        let mut previous = 0.0f64;
        let limit = 8 * RADIAL_STEPS;
        for _ in 0..limit {
            r += step;
            let r2 = r * r;
            let radial = lens.radial(r2);
            let slope = radial + 2.0 * r2 * lens.radial_slope(r2);
            let image = r * radial;
            if !(radial > 0.0 && slope > 0.0 && image > previous) {
                return Err(LensError::FoldsBack {
                    at_px: image.max(previous) * self.focal_px,
                    corner_px: corner * self.focal_px,
                });
            }
            previous = image;
            if image > corner * 1.01 {
                break;
            }
        }
        if previous <= corner {
            return Err(LensError::CornerCompressed(corner * self.focal_px));
        }
        for j in 0..CHECK_GRID {
            for i in 0..CHECK_GRID {
                let u = self.width as f64 * i as f64 / (CHECK_GRID - 1) as f64;
                let v = self.height as f64 * j as f64 / (CHECK_GRID - 1) as f64;
                let ((x, y), converged) = self.from_pixel(u, v);
                let [[a, b], [c, d]] = lens.jacobian(x, y);
                let (bu, bv) = self.to_pixel(x, y);
                let error = (bu - u).hypot(bv - v);
                let folded = a * d - b * c <= 0.0;
                if !converged || folded || error.is_nan() || error >= ROUND_TRIP_TOLERANCE_PX {
                    return Err(LensError::NotInvertible { u, v });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strong() -> BrownConrady {
        BrownConrady {
            k1: -0.25,
            k2: 0.08,
            k3: -0.01,
            p1: 0.004,
            p2: -0.003,
        }
    }

    #[test]
    fn undistort_inverts_distort() {
        let lens = strong();
        for i in -10..=10 {
            for j in -10..=10 {
                let (x, y) = (i as f64 * 0.06, j as f64 * 0.045);
                let (xd, yd) = lens.distort(x, y);
                let ((bx, by), ok) = lens.undistort(xd, yd);
                assert!(ok, "({x}, {y}) did not converge");
                assert!((bx - x).hypot(by - y) < 1e-10, "({x}, {y}) → ({bx}, {by})");
            }
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let lens = strong();
        let (x, y, h) = (0.31, -0.22, 1e-6);
        let j = lens.jacobian(x, y);
        let (px, py) = lens.distort(x + h, y);
        let (mx, my) = lens.distort(x - h, y);
        let (qx, qy) = lens.distort(x, y + h);
        let (nx, ny) = lens.distort(x, y - h);
        let fd = [
            [(px - mx) / (2.0 * h), (qx - nx) / (2.0 * h)],
            [(py - my) / (2.0 * h), (qy - ny) / (2.0 * h)],
        ];
        for r in 0..2 {
            for c in 0..2 {
                assert!((j[r][c] - fd[r][c]).abs() < 1e-6, "{j:?} vs {fd:?}");
            }
        }
    }

    #[test]
    fn zero_coefficients_are_the_identity() {
        let lens = BrownConrady::default();
        assert!(lens.is_identity());
        assert_eq!(lens.distort(0.3, -0.2), (0.3, -0.2));
        assert_eq!(lens.undistort(0.3, -0.2), ((0.3, -0.2), true));
    }

    fn intrinsics(lens: BrownConrady) -> Intrinsics {
        Intrinsics {
            width: 640,
            height: 480,
            focal_px: 400.0,
            principal_x: 325.0,
            principal_y: 236.0,
            lens,
        }
    }

    #[test]
    fn check_accepts_realistic_and_rejects_folding_lenses() {
        assert!(intrinsics(strong()).check().is_ok());
        let barrel = BrownConrady {
            k1: -0.08,
            ..BrownConrady::default()
        };
        assert!(intrinsics(barrel).check().is_ok());
        // r·(1 − 0.6 r²) peaks at r ≈ 0.75, before the corner at ≈ 1.0.
        let folding = BrownConrady {
            k1: -0.6,
            ..BrownConrady::default()
        };
        let e = intrinsics(folding).check().unwrap_err().to_string();
        assert!(e.contains("folds back"), "{e}");
        let tangential = BrownConrady {
            p1: 0.6,
            ..BrownConrady::default()
        };
        assert!(intrinsics(tangential).check().is_err());
    }
}
