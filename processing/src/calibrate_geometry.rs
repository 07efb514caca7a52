//! Geometric calibration of the rig's cameras from one checkerboard run: every camera is
//! calibrated (Zhang + Levenberg–Marquardt) from all the placements it saw; the placements
//! with the board lying flat on the turntable at several table angles give that camera's
//! turntable axis, and the flat placement at table 0° gives the rig frame (seed 004 §3.2).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::calibrate_camera::{
    BoardView, CalibrationOptions, CameraCalibration, IntrinsicsStd, calibrate_camera,
};
use crate::camera_model::{CameraModel, Pose};
use crate::error::ProcessingError;
use crate::rig_frame::{TurntableAxis, rig_to_camera, turntable_axis};

/// How the board was placed for one capture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// The board lay flat on the turntable (only turned by the table).
    pub flat: bool,
    /// Turntable angle, degrees.
    pub table_deg: f64,
}

/// One camera's detected boards: (placement index, corners) pairs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraViews {
    /// Camera id.
    pub camera: String,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Views with the placement each came from.
    pub views: Vec<(usize, BoardView)>,
}

/// One camera's geometry in the rig frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraGeometry {
    /// Camera id.
    pub camera: String,
    /// Intrinsics and distortion.
    pub model: CameraModel,
    /// Rig → camera transform.
    pub rig_to_camera: Pose,
    /// The camera's centre in the rig frame, mm.
    pub centre_mm: [f64; 3],
    /// Reprojection RMS over all its views, pixels.
    pub rms_px: f64,
    /// Reprojection RMS per view, pixels, with the placement index.
    pub view_rms_px: Vec<(usize, f64)>,
    /// Standard deviations of the intrinsics.
    pub std: IntrinsicsStd,
    /// The turntable axis as this camera saw it.
    pub axis: TurntableAxis,
}

impl CameraGeometry {
    /// A camera whose geometry is known, not fitted (the rig file's nominal cameras, the
    /// simulator's truth): zero residuals and uncertainties, the turntable axis the rig
    /// frame's z axis through its origin.
    pub fn exact(camera: &str, model: CameraModel, rig_to_camera: Pose) -> CameraGeometry {
        let r = rig_to_camera.rotation_matrix();
        CameraGeometry {
            camera: camera.to_string(),
            model,
            rig_to_camera,
            centre_mm: rig_to_camera.centre().into(),
            rms_px: 0.0,
            view_rms_px: Vec::new(),
            std: IntrinsicsStd {
                fx: 0.0,
                fy: 0.0,
                cx: 0.0,
                cy: 0.0,
            },
            axis: TurntableAxis {
                point: rig_to_camera.translation,
                direction: (r * Vector3::z()).into(),
                radius_mm: 0.0,
                rms_mm: 0.0,
            },
        }
    }
}

/// What a geometric calibration found: the cameras it placed, and each camera it could not
/// calibrate or place, with why (processing then refuses that camera's frames).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeometrySolution {
    /// The calibrated cameras in the rig frame.
    pub cameras: Vec<CameraGeometry>,
    /// (camera, why) for every camera left out.
    pub failed: Vec<(String, String)>,
}

/// Calibrates every camera and places it in the rig frame. A camera that saw the board flat
/// at three or more table angles, the reference among them, finds the turntable axis and the
/// rig frame itself; any other (a grazing camera cannot see a flat board) is placed through a
/// placement it shares with a placed camera: rig → B = (board → B) ∘ (board → A)⁻¹ ∘ (rig → A),
/// over the shared placement with the smallest reprojection error in both. A camera whose
/// views leave it ill-posed is reported in `failed`, not guessed; no camera at all is an error.
pub fn calibrate_geometry(
    placements: &[Placement],
    cameras: &[CameraViews],
    options: CalibrationOptions,
) -> Result<GeometrySolution, ProcessingError> {
    let reference = placements
        .iter()
        .position(|p| p.flat && p.table_deg.rem_euclid(360.0).abs() < 1e-6)
        .ok_or_else(|| ProcessingError::IllPosed {
            what: "rig frame",
            why: "no placement has the board flat at turntable 0°; it defines the reference plane and the X axis".into(),
        })?;
    let mut failed = Vec::new();
    let mut usable = Vec::new();
    let mut solved = Vec::new();
    for cam in cameras {
        let views: Vec<BoardView> = cam.views.iter().map(|(_, v)| v.clone()).collect();
        match calibrate_camera(&views, cam.width, cam.height, options) {
            Ok(cal) => {
                usable.push(cam.clone());
                solved.push(cal);
            }
            Err(e) => failed.push((cam.camera.clone(), e.to_string())),
        }
    }
    let mut placed: Vec<Option<(Pose, TurntableAxis)>> = usable
        .iter()
        .zip(&solved)
        .map(|(cam, cal)| own_rig_frame(cam, cal, placements, reference))
        .collect();
    if placed.iter().all(Option::is_none) {
        let mut why =
            "no camera saw the board flat at 3 or more turntable angles including 0°".to_string();
        for (camera, e) in &failed {
            why += &format!("; `{camera}`: {e}");
        }
        return Err(ProcessingError::IllPosed {
            what: "rig frame",
            why,
        });
    }
    while let Some((b, frame)) = best_chain(&usable, &solved, &placed) {
        placed[b] = Some(frame);
    }
    let mut out = Vec::new();
    for ((cam, cal), frame) in usable.iter().zip(solved).zip(placed) {
        let Some((rig, axis)) = frame else {
            failed.push((
                cam.camera.clone(),
                "the camera shares no placement with a camera placed in the rig frame; add a placement both see".into(),
            ));
            continue;
        };
        out.push(CameraGeometry {
            camera: cam.camera.clone(),
            model: cal.model,
            rig_to_camera: rig,
            centre_mm: rig.centre().into(),
            rms_px: cal.rms_px,
            view_rms_px: cam
                .views
                .iter()
                .map(|(p, _)| *p)
                .zip(cal.view_rms_px)
                .collect(),
            std: cal.std,
            axis,
        });
    }
    Ok(GeometrySolution {
        cameras: out,
        failed,
    })
}

/// The rig frame from the camera's own flat views, if it has enough of them.
fn own_rig_frame(
    cam: &CameraViews,
    cal: &CameraCalibration,
    placements: &[Placement],
    reference: usize,
) -> Option<(Pose, TurntableAxis)> {
    let flat: Vec<Pose> = cam
        .views
        .iter()
        .zip(&cal.poses)
        .filter(|((p, _), _)| placements.get(*p).is_some_and(|p| p.flat))
        .map(|(_, pose)| *pose)
        .collect();
    let reference_pose = cam
        .views
        .iter()
        .zip(&cal.poses)
        .find(|((p, _), _)| *p == reference)
        .map(|(_, pose)| *pose)?;
    let axis = turntable_axis(&flat).ok()?;
    let rig = rig_to_camera(&axis, &reference_pose).ok()?;
    Some((rig, axis))
}

/// The unplaced camera best placed through a placed one: (its index, rig → camera, axis).
fn best_chain(
    cameras: &[CameraViews],
    solved: &[CameraCalibration],
    placed: &[Option<(Pose, TurntableAxis)>],
) -> Option<(usize, (Pose, TurntableAxis))> {
    let mut best: Option<(f64, usize, Pose, TurntableAxis)> = None;
    for (b, cam_b) in cameras.iter().enumerate() {
        if placed[b].is_some() {
            continue;
        }
        for (a, cam_a) in cameras.iter().enumerate() {
            let Some((rig_a, axis_a)) = &placed[a] else {
                continue;
            };
            for (ib, (pb, _)) in cam_b.views.iter().enumerate() {
                let Some(ia) = cam_a.views.iter().position(|(pa, _)| pa == pb) else {
                    continue;
                };
                let cost = solved[a].view_rms_px[ia] + solved[b].view_rms_px[ib];
                if best.as_ref().is_some_and(|(c, ..)| *c <= cost) {
                    continue;
                }
                // camera A → camera B through the board of the shared placement.
                let a_to_b = solved[b].poses[ib].after(&solved[a].poses[ia].inverse());
                let rig_b = a_to_b.after(rig_a);
                let mut axis = TurntableAxis {
                    point: a_to_b.transform(&Vector3::from(axis_a.point)).into(),
                    direction: (a_to_b.rotation_matrix() * Vector3::from(axis_a.direction)).into(),
                    ..*axis_a
                };
                // Pointing towards the camera, as the camera's own fit would.
                if Vector3::from(axis.direction).dot(&Vector3::from(axis.point)) > 0.0 {
                    axis.direction = (-Vector3::from(axis.direction)).into();
                }
                best = Some((cost, b, rig_b, axis));
            }
        }
    }
    best.map(|(_, b, rig, axis)| (b, (rig, axis)))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Rotation3};

    use super::*;
    use crate::camera_model::{Distortion, Intrinsics};

    /// A camera `distance` mm from the rig origin at `elevation` and `azimuth` degrees,
    /// looking at the origin: its rig → camera pose.
    fn look_at(distance: f64, elevation: f64, azimuth: f64) -> Pose {
        let (e, a) = (elevation.to_radians(), azimuth.to_radians());
        let c = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin()) * distance;
        let z = -c.normalize();
        let x = z.cross(&Vector3::z()).normalize();
        let y = z.cross(&x);
        let r = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
            x.transpose(),
            y.transpose(),
            z.transpose(),
        ]));
        Pose::from_parts(&r, -(r * c))
    }

    fn compose(a: &Pose, b: &Pose) -> Pose {
        // a ∘ b: first b, then a.
        let r = a.rotation_matrix() * b.rotation_matrix();
        Pose::from_parts(
            &r,
            a.rotation_matrix() * Vector3::from(b.translation) + Vector3::from(a.translation),
        )
    }

    #[test]
    fn places_two_cameras_in_the_rig_frame() {
        let board: Vec<(f64, f64)> = (0..99)
            .map(|i| ((i % 11) as f64 * 15.0, (i / 11) as f64 * 15.0))
            .collect();
        let centre = Vector3::new(75.0, 60.0, 0.0);
        let mut placements = Vec::new();
        let mut board_to_rig = Vec::new();
        for k in 0..8 {
            let r = Rotation3::from_axis_angle(&Vector3::z_axis(), (45.0 * k as f64).to_radians());
            placements.push(Placement {
                flat: true,
                table_deg: 45.0 * k as f64,
            });
            board_to_rig.push(Pose::from_parts(&r, -(r * centre)));
        }
        for (tx, ty, spin) in [
            (30.0, 0.0, 10.0),
            (-30.0, 10.0, 80.0),
            (0.0, 35.0, 170.0),
            (10.0, -35.0, 260.0),
            (25.0, 25.0, 300.0),
        ] {
            let r = Rotation3::from_euler_angles(
                f64::to_radians(tx),
                f64::to_radians(ty),
                f64::to_radians(spin),
            );
            placements.push(Placement {
                flat: false,
                table_deg: 0.0,
            });
            board_to_rig.push(Pose::from_parts(
                &r,
                Vector3::new(0.0, 0.0, 40.0) - r * centre,
            ));
        }
        let model = CameraModel {
            intrinsics: Intrinsics {
                fx: 1400.0,
                fy: 1400.0,
                cx: 512.0,
                cy: 384.0,
            },
            distortion: Distortion {
                k1: -0.08,
                ..Distortion::default()
            },
        };
        let truth = [
            ("cam1", look_at(600.0, 30.0, 0.0)),
            ("cam2", look_at(620.0, 55.0, 20.0)),
        ];
        let cameras: Vec<CameraViews> = truth
            .iter()
            .map(|(id, rig)| CameraViews {
                camera: id.to_string(),
                width: 1024,
                height: 768,
                views: board_to_rig
                    .iter()
                    .enumerate()
                    .map(|(p, b2r)| {
                        let pose = compose(rig, b2r);
                        let image = board
                            .iter()
                            .map(|&(x, y)| {
                                let q = model.project(&pose, &Vector3::new(x, y, 0.0)).unwrap();
                                (q.x, q.y)
                            })
                            .collect();
                        (
                            p,
                            BoardView {
                                board: board.clone(),
                                image,
                            },
                        )
                    })
                    .collect(),
            })
            .collect();
        let out = calibrate_geometry(&placements, &cameras, CalibrationOptions::default())
            .unwrap()
            .cameras;
        for (g, (_, rig)) in out.iter().zip(&truth) {
            let err = (Vector3::from(g.centre_mm) - rig.centre()).norm();
            assert!(err < 0.01, "{}: centre off by {err} mm", g.camera);
            assert!(g.rms_px < 1e-3);
        }
        // A grazing camera that never saw the flat board is placed through cam1 and the
        // tilted placements both saw.
        let mut grazing = cameras[0].clone();
        grazing.camera = "cam0".into();
        let rig0 = look_at(640.0, 6.0, -10.0);
        grazing.views.retain(|(p, _)| !placements[*p].flat);
        for (p, view) in &mut grazing.views {
            let pose = compose(&rig0, &board_to_rig[*p]);
            for (pt, img) in view.board.iter().zip(&mut view.image) {
                let q = model
                    .project(&pose, &Vector3::new(pt.0, pt.1, 0.0))
                    .unwrap();
                *img = (q.x, q.y);
            }
        }
        let with_grazing = [cameras[0].clone(), grazing.clone()];
        let out = calibrate_geometry(&placements, &with_grazing, CalibrationOptions::default())
            .unwrap()
            .cameras;
        let err = (Vector3::from(out[1].centre_mm) - rig0.centre()).norm();
        assert!(err < 0.01, "chained camera off by {err} mm");
        // Alone it cannot be placed: the error names it.
        let e = calibrate_geometry(&placements, &[grazing], CalibrationOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("no camera saw the board flat"), "{e}");
        // Without the reference placement the rig frame is undefined.
        let no_ref: Vec<Placement> = placements
            .iter()
            .map(|p| Placement {
                table_deg: p.table_deg + 1.0,
                ..*p
            })
            .collect();
        assert!(calibrate_geometry(&no_ref, &cameras, CalibrationOptions::default()).is_err());
    }
}
