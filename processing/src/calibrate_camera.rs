//! Calibration of one camera from views of a planar target (Zhang 2000): homographies by
//! normalised DLT, the closed-form intrinsics and poses, then Levenberg–Marquardt over
//! intrinsics, Brown–Conrady distortion and every view's pose together, minimising the
//! reprojection error. The parameters' standard deviations come from the final Jacobian, and a
//! focal length the views leave undetermined (every view nearly fronto-parallel) is an error.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera_model::{CameraModel, Distortion, Intrinsics, Pose};
use crate::error::ProcessingError;
use crate::homography::fit_homography;
use crate::zhang::{intrinsics_from_homographies, pose_from_homography};

/// One view of the target: its points on the board plane (z = 0, millimetres) and where they
/// were found in the image (pixels), in the same order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoardView {
    /// Board coordinates, millimetres.
    pub board: Vec<(f64, f64)>,
    /// Image coordinates, pixels.
    pub image: Vec<(f64, f64)>,
}

/// Standard deviations of the fitted camera parameters (from the final Jacobian and the
/// residual variance).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IntrinsicsStd {
    /// σ of fx, pixels.
    pub fx: f64,
    /// σ of fy, pixels.
    pub fy: f64,
    /// σ of cx, pixels.
    pub cx: f64,
    /// σ of cy, pixels.
    pub cy: f64,
}

/// A calibrated camera with its board poses and quality figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraCalibration {
    /// Intrinsics and distortion.
    pub model: CameraModel,
    /// The board's pose in the camera for each view.
    pub poses: Vec<Pose>,
    /// Reprojection RMS over all points, pixels.
    pub rms_px: f64,
    /// Reprojection RMS of each view, pixels.
    pub view_rms_px: Vec<f64>,
    /// Standard deviations of the intrinsics.
    pub std: IntrinsicsStd,
    /// Levenberg–Marquardt function evaluations.
    pub evaluations: usize,
}

/// Largest relative standard deviation of the focal length accepted: beyond it the views
/// cannot tell focal length from distance.
pub const MAX_FOCAL_REL_STD: f64 = 0.01;

/// Parameters before the poses: fx, fy, cx, cy, k1, k2, p1, p2, k3.
const CAMERA_PARAMS: usize = 9;

/// Index of k3 among the parameters.
const K3: usize = 8;

/// Choices of the fit.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CalibrationOptions {
    /// Fit the r⁶ radial term k3 too. Off by default, as OpenCV users are advised for
    /// ordinary lenses: unless the board reaches the image corners, k3 trades off against k2
    /// and the principal point and makes them worse.
    pub fit_k3: bool,
}

/// Calibrates one camera from `views` of a planar target in a `width × height` image.
pub fn calibrate_camera(
    views: &[BoardView],
    width: u32,
    height: u32,
    options: CalibrationOptions,
) -> Result<CameraCalibration, ProcessingError> {
    let mut homographies = Vec::with_capacity(views.len());
    for view in views {
        homographies.push(fit_homography(&view.board, &view.image)?);
    }
    let k0 = intrinsics_from_homographies(&homographies, f64::from(width), f64::from(height))?;
    let mut poses = Vec::with_capacity(views.len());
    for h in &homographies {
        poses.push(
            pose_from_homography(&k0, h).ok_or_else(|| ProcessingError::IllPosed {
                what: "closed-form calibration",
                why: "a view's pose could not be recovered from its homography".into(),
            })?,
        );
    }
    let problem = Reprojection::new(views, &k0, &poses, options);
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    if !report.termination.was_successful() {
        return Err(ProcessingError::IllPosed {
            what: "calibration refinement",
            why: format!("Levenberg–Marquardt stopped: {:?}", report.termination),
        });
    }
    let (model, poses) = problem.unpack();
    let residuals = problem.residual_vector();
    let n_points: usize = views.iter().map(|v| v.board.len()).sum();
    let rms_px = (residuals.norm_squared() / n_points as f64).sqrt();
    let mut view_rms_px = Vec::with_capacity(views.len());
    let mut at = 0;
    for v in views {
        let r = residuals.rows(at, 2 * v.board.len());
        view_rms_px.push((r.norm_squared() / v.board.len() as f64).sqrt());
        at += 2 * v.board.len();
    }
    let std = intrinsics_std(&problem, &residuals)?;
    if !(std.fx / model.intrinsics.fx <= MAX_FOCAL_REL_STD
        && std.fy / model.intrinsics.fy <= MAX_FOCAL_REL_STD)
    {
        return Err(ProcessingError::IllPosed {
            what: "calibration",
            why: format!(
                "the views leave the focal length undetermined (σ {:.2} % of fx); the board is nearly fronto-parallel in every view: tilt it by 20° or more in some placements",
                100.0 * std.fx / model.intrinsics.fx
            ),
        });
    }
    Ok(CameraCalibration {
        model,
        poses,
        rms_px,
        view_rms_px,
        std,
        evaluations: report.number_of_evaluations,
    })
}

/// σ of the intrinsics from (JᵀJ)⁻¹ scaled by the residual variance.
fn intrinsics_std(
    problem: &Reprojection<'_>,
    residuals: &DVector<f64>,
) -> Result<IntrinsicsStd, ProcessingError> {
    let j = problem.jacobian_matrix();
    let dof = (residuals.len() as f64 - j.ncols() as f64).max(1.0);
    // A perfect fit still has the corner detector's noise; keep σ² from reaching 0.
    let sigma2 = (residuals.norm_squared() / dof).max(1e-8);
    let mut jtj = j.transpose() * &j;
    if !problem.options.fit_k3 {
        // A fixed k3 has a zero column; pin it so the rest can be inverted.
        jtj[(K3, K3)] = 1.0;
    }
    let undetermined = || {
        ProcessingError::IllPosed {
        what: "calibration",
        why: "the views do not determine every camera parameter (the normal matrix is singular); add placements that tilt the board and fill the image corners".into(),
    }
    };
    let cov = jtj.cholesky().ok_or_else(undetermined)?.inverse();
    let sd = |i: usize| (cov[(i, i)] * sigma2).sqrt();
    let std = IntrinsicsStd {
        fx: sd(0),
        fy: sd(1),
        cx: sd(2),
        cy: sd(3),
    };
    if [std.fx, std.fy, std.cx, std.cy]
        .iter()
        .all(|v| v.is_finite())
    {
        Ok(std)
    } else {
        Err(undetermined())
    }
}

/// The reprojection least-squares problem over camera parameters and view poses.
struct Reprojection<'a> {
    views: &'a [BoardView],
    params: DVector<f64>,
    options: CalibrationOptions,
}

impl<'a> Reprojection<'a> {
    fn new(
        views: &'a [BoardView],
        k: &Intrinsics,
        poses: &[Pose],
        options: CalibrationOptions,
    ) -> Reprojection<'a> {
        let mut params = DVector::zeros(CAMERA_PARAMS + 6 * poses.len());
        params[0] = k.fx;
        params[1] = k.fy;
        params[2] = k.cx;
        params[3] = k.cy;
        for (i, p) in poses.iter().enumerate() {
            let at = CAMERA_PARAMS + 6 * i;
            for c in 0..3 {
                params[at + c] = p.rotation[c];
                params[at + 3 + c] = p.translation[c];
            }
        }
        Reprojection {
            views,
            params,
            options,
        }
    }

    fn model_of(p: &DVector<f64>) -> CameraModel {
        CameraModel {
            intrinsics: Intrinsics {
                fx: p[0],
                fy: p[1],
                cx: p[2],
                cy: p[3],
            },
            distortion: Distortion {
                k1: p[4],
                k2: p[5],
                p1: p[6],
                p2: p[7],
                k3: p[8],
            },
        }
    }

    fn pose_of(p: &DVector<f64>, view: usize) -> Pose {
        let at = CAMERA_PARAMS + 6 * view;
        Pose {
            rotation: [p[at], p[at + 1], p[at + 2]],
            translation: [p[at + 3], p[at + 4], p[at + 5]],
        }
    }

    fn unpack(&self) -> (CameraModel, Vec<Pose>) {
        (
            Self::model_of(&self.params),
            (0..self.views.len())
                .map(|v| Self::pose_of(&self.params, v))
                .collect(),
        )
    }

    /// Residuals of view `v` under parameters `p`, written into `out`.
    fn view_residuals(&self, p: &DVector<f64>, v: usize, out: &mut [f64]) {
        let model = Self::model_of(p);
        let pose = Self::pose_of(p, v);
        let view = &self.views[v];
        for (i, (b, m)) in view.board.iter().zip(&view.image).enumerate() {
            let (rx, ry) = match model.project(&pose, &Vector3::new(b.0, b.1, 0.0)) {
                Some(q) => (q.x - m.0, q.y - m.1),
                // Behind the camera: a large, smooth penalty keeps the step away.
                None => (1e6, 1e6),
            };
            out[2 * i] = rx;
            out[2 * i + 1] = ry;
        }
    }

    fn residual_vector(&self) -> DVector<f64> {
        let n: usize = self.views.iter().map(|v| 2 * v.board.len()).sum();
        let mut r = DVector::zeros(n);
        let mut at = 0;
        for v in 0..self.views.len() {
            let len = 2 * self.views[v].board.len();
            self.view_residuals(&self.params, v, &mut r.as_mut_slice()[at..at + len]);
            at += len;
        }
        r
    }

    /// The Jacobian by central differences, column by column; a pose parameter only touches
    /// its own view's rows.
    fn jacobian_matrix(&self) -> DMatrix<f64> {
        let n: usize = self.views.iter().map(|v| 2 * v.board.len()).sum();
        let mut j = DMatrix::zeros(n, self.params.len());
        let offsets: Vec<usize> = self
            .views
            .iter()
            .scan(0, |at, v| {
                let here = *at;
                *at += 2 * v.board.len();
                Some(here)
            })
            .collect();
        let mut plus = vec![0.0; n];
        let mut minus = vec![0.0; n];
        for c in 0..self.params.len() {
            if c == K3 && !self.options.fit_k3 {
                continue;
            }
            let h = 1e-6 * self.params[c].abs().max(1e-2);
            let mut p = self.params.clone();
            p[c] += h;
            let mut q = self.params.clone();
            q[c] -= h;
            let views: Vec<usize> = if c < CAMERA_PARAMS {
                (0..self.views.len()).collect()
            } else {
                vec![(c - CAMERA_PARAMS) / 6]
            };
            for v in views {
                let (at, len) = (offsets[v], 2 * self.views[v].board.len());
                self.view_residuals(&p, v, &mut plus[at..at + len]);
                self.view_residuals(&q, v, &mut minus[at..at + len]);
                for r in at..at + len {
                    j[(r, c)] = (plus[r] - minus[r]) / (2.0 * h);
                }
            }
        }
        j
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Reprojection<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.params.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.params.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let r = self.residual_vector();
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let j = self.jacobian_matrix();
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

#[cfg(test)]
#[path = "calibrate_camera_tests.rs"]
mod tests;
