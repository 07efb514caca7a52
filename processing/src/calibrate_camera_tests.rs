//! Tests of single-camera calibration on synthetic views with known truth.

use nalgebra::Rotation3;

use super::*;

/// A deterministic Gaussian source (xorshift, sum of 4 uniforms).
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        let mut s = 0.0;
        for _ in 0..4 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            s += (self.0 >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        }
        s * 3f64.sqrt()
    }
}

fn truth(k1: f64) -> CameraModel {
    CameraModel {
        intrinsics: Intrinsics {
            fx: 1500.0,
            fy: 1500.6,
            cx: 515.3,
            cy: 380.2,
        },
        distortion: Distortion {
            k1,
            k2: 0.08,
            p1: 0.0005,
            p2: -0.0003,
            k3: 0.0,
        },
    }
}

/// A 14×10-corner board with 18 mm squares, centred on its origin.
fn board() -> Vec<(f64, f64)> {
    (0..140)
        .map(|i| {
            (
                (i % 14) as f64 * 18.0 - 117.0,
                (i / 14) as f64 * 18.0 - 81.0,
            )
        })
        .collect()
}

/// A pose tilting the board by `tilt_x`, `tilt_y` degrees about its axes and `spin` about its
/// normal, `distance` mm in front of the camera, shifted by `(dx, dy)` mm.
fn pose(tilt_x: f64, tilt_y: f64, spin: f64, distance: f64, dx: f64, dy: f64) -> Pose {
    let r =
        Rotation3::from_euler_angles(tilt_x.to_radians(), tilt_y.to_radians(), spin.to_radians());
    Pose::from_parts(&r, Vector3::new(dx, dy, distance))
}

fn views(cam: &CameraModel, poses: &[Pose], noise_px: f64) -> Vec<BoardView> {
    let mut noise = Noise(0x9e37_79b9_7f4a_7c15);
    poses
        .iter()
        .map(|p| {
            let board = board();
            let image = board
                .iter()
                .map(|&(x, y)| {
                    let q = cam.project(p, &Vector3::new(x, y, 0.0)).unwrap();
                    (q.x + noise_px * noise.next(), q.y + noise_px * noise.next())
                })
                .collect();
            BoardView { board, image }
        })
        .collect()
}

/// Twelve placements tilted by up to 35° that together cover the image, as a calibration
/// sequence should place the board.
fn tilted_poses() -> Vec<Pose> {
    vec![
        pose(25.0, 0.0, 0.0, 480.0, 0.0, 0.0),
        pose(-25.0, 5.0, 10.0, 520.0, 60.0, -40.0),
        pose(0.0, 30.0, -15.0, 500.0, -60.0, 40.0),
        pose(5.0, -30.0, 5.0, 460.0, 60.0, 40.0),
        pose(20.0, 20.0, 30.0, 540.0, -60.0, -40.0),
        pose(-15.0, -20.0, -30.0, 450.0, 0.0, 45.0),
        pose(2.0, 1.0, 45.0, 500.0, 0.0, -45.0),
        pose(35.0, -10.0, 60.0, 500.0, 70.0, 0.0),
        pose(-35.0, 15.0, -60.0, 480.0, -70.0, 0.0),
        pose(10.0, 35.0, 90.0, 520.0, 30.0, 20.0),
        pose(-10.0, -35.0, -90.0, 470.0, -30.0, -20.0),
        pose(15.0, 15.0, 120.0, 500.0, 0.0, 0.0),
    ]
}

#[test]
fn recovers_a_camera_within_the_issue_targets() {
    let cam = truth(-0.12);
    let truth_poses = tilted_poses();
    let cal = calibrate_camera(
        &views(&cam, &truth_poses, 0.05),
        1024,
        768,
        CalibrationOptions::default(),
    )
    .unwrap();
    let (k, t) = (cal.model.intrinsics, cam.intrinsics);
    assert!(cal.rms_px < 0.1, "rms {}", cal.rms_px);
    assert!((k.fx / t.fx - 1.0).abs() < 1e-3, "fx {} vs {}", k.fx, t.fx);
    assert!((k.fy / t.fy - 1.0).abs() < 1e-3, "fy {} vs {}", k.fy, t.fy);
    assert!(
        (k.cx - t.cx).abs() < 0.5 && (k.cy - t.cy).abs() < 0.5,
        "{k:?}"
    );
    for (fit, truth) in cal.poses.iter().zip(&truth_poses) {
        let (a, b) = (fit.centre(), truth.centre());
        assert!(
            (a - b).norm() < 0.5,
            "camera centre off by {} mm",
            (a - b).norm()
        );
    }
    // Distortion residual over the image: the correction each model applies to a pixel
    // (undistorted minus distorted position) agrees within 0.1 px.
    let correction = |m: &CameraModel, u: f64, v: f64| {
        let (x, y) = m.normalise(u, v).unwrap();
        let k = m.intrinsics;
        (k.fx * x + k.cx - u, k.fy * y + k.cy - v)
    };
    let mut worst = 0.0f64;
    for i in 0..=16 {
        for j in 0..=12 {
            let (u, v) = (1023.0 * i as f64 / 16.0, 767.0 * j as f64 / 12.0);
            let (a, b) = (correction(&cal.model, u, v), correction(&cam, u, v));
            worst = worst.max(((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt());
        }
    }
    assert!(worst < 0.1, "distortion residual {worst} px");
    assert!(cal.std.fx < 1.5 && cal.std.fx > 0.0);
}

#[test]
fn corners_at_the_border_under_strong_distortion_converge() {
    let cam = truth(-0.35);
    let poses: Vec<Pose> = tilted_poses()
        .into_iter()
        .zip([
            (-90.0, -70.0),
            (90.0, 70.0),
            (-90.0, 70.0),
            (90.0, -70.0),
            (0.0, 0.0),
            (60.0, 0.0),
            (-60.0, 0.0),
        ])
        .map(|(p, (dx, dy))| Pose {
            translation: [dx, dy, p.translation[2]],
            ..p
        })
        .collect();
    let vs = views(&cam, &poses, 0.05);
    let (mut umin, mut umax) = (f64::MAX, f64::MIN);
    for v in &vs {
        for p in &v.image {
            umin = umin.min(p.0);
            umax = umax.max(p.0);
        }
    }
    assert!(umin < 60.0 && umax > 960.0, "board reaches {umin}–{umax}");
    let cal = calibrate_camera(&vs, 1024, 768, CalibrationOptions::default()).unwrap();
    assert!(cal.rms_px < 0.1, "rms {}", cal.rms_px);
    assert!(
        (cal.model.distortion.k1 + 0.35).abs() < 0.01,
        "{:?}",
        cal.model.distortion
    );
    assert!((cal.model.intrinsics.fx / 1500.0 - 1.0).abs() < 1e-3);
}

#[test]
fn a_near_fronto_parallel_view_among_tilted_ones_is_fine() {
    let cam = truth(-0.12);
    let mut poses = tilted_poses();
    poses.push(pose(0.2, -0.1, 0.0, 600.0, 0.0, 0.0));
    let cal = calibrate_camera(
        &views(&cam, &poses, 0.05),
        1024,
        768,
        CalibrationOptions::default(),
    )
    .unwrap();
    assert!((cal.model.intrinsics.fx / 1500.0 - 1.0).abs() < 1e-3);
}

#[test]
fn only_fronto_parallel_views_are_reported_not_solved() {
    let cam = truth(-0.12);
    let poses = vec![
        pose(0.3, 0.0, 0.0, 600.0, 0.0, 0.0),
        pose(0.0, 0.4, 20.0, 620.0, 30.0, 0.0),
        pose(-0.3, 0.2, 40.0, 640.0, 0.0, 30.0),
        pose(0.1, -0.3, 60.0, 610.0, -30.0, -20.0),
    ];
    let err = calibrate_camera(
        &views(&cam, &poses, 0.05),
        1024,
        768,
        CalibrationOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(err, ProcessingError::IllPosed { .. }), "{err}");
}

#[test]
fn a_board_only_turned_in_its_own_plane_is_reported() {
    // The seed's trap: a flat board on the turntable only spins about its own normal.
    let cam = truth(0.0);
    let poses: Vec<Pose> = (0..6)
        .map(|i| pose(0.0, 0.0, 60.0 * i as f64, 600.0, 0.0, 0.0))
        .collect();
    let err = calibrate_camera(
        &views(&cam, &poses, 0.0),
        1024,
        768,
        CalibrationOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(err, ProcessingError::IllPosed { .. }), "{err}");
}
