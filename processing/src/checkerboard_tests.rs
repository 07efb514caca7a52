//! Tests of checkerboard detection on rendered boards with known corners.

use nalgebra::{Rotation3, Vector3};

use super::*;
use crate::camera_model::{CameraModel, Distortion, Intrinsics, Pose};

const SPEC: CheckerboardSpec = CheckerboardSpec {
    cols: 9,
    rows: 6,
    square_mm: 20.0,
};

fn camera(k1: f64) -> CameraModel {
    CameraModel {
        intrinsics: Intrinsics {
            fx: 900.0,
            fy: 900.0,
            cx: 320.0,
            cy: 240.0,
        },
        distortion: Distortion {
            k1,
            ..Distortion::default()
        },
    }
}

/// Renders the board (one square of white margin, grey background) seen through `cam` at
/// `pose`, 8×8 supersampled with jitter, with a little deterministic noise.
fn render(cam: &CameraModel, pose: &Pose, width: usize, height: usize) -> GrayImage {
    render_board(&SPEC, cam, pose, width, height)
}

/// [`render`] for any board.
fn render_board(
    spec: &CheckerboardSpec,
    cam: &CameraModel,
    pose: &Pose,
    width: usize,
    height: usize,
) -> GrayImage {
    let r = pose.rotation_matrix();
    let t = Vector3::from(pose.translation);
    let rt_t = r.transpose() * t;
    let s = spec.square_mm;
    let mut img = GrayImage::new(width, height);
    let mut state = 0x1234_5678_9abc_def1u64;
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0.0;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            // 8×8 jittered samples: a regular grid would bias axis-aligned edges.
            for sy in 0..8 {
                for sx in 0..8 {
                    let u = x as f64 + (sx as f64 + next()) / 8.0 - 0.5;
                    let v = y as f64 + (sy as f64 + next()) / 8.0 - 0.5;
                    let Some((nx, ny)) = cam.normalise(u, v) else {
                        continue;
                    };
                    let d = r.transpose() * Vector3::new(nx, ny, 1.0);
                    let lambda = rt_t.z / d.z;
                    let bx = lambda * d.x - rt_t.x;
                    let by = lambda * d.y - rt_t.y;
                    let (a, b) = ((bx / s).floor() as i64 + 1, (by / s).floor() as i64 + 1);
                    let inside =
                        (0..=spec.cols as i64).contains(&a) && (0..=spec.rows as i64).contains(&b);
                    let margin = (-1..=spec.cols as i64 + 1).contains(&a)
                        && (-1..=spec.rows as i64 + 1).contains(&b);
                    acc += if lambda <= 0.0 {
                        0.4
                    } else if inside {
                        if (a + b) % 2 == 0 { 0.08 } else { 0.85 }
                    } else if margin {
                        0.85
                    } else {
                        0.4
                    };
                }
            }
            let noise = (next() - 0.5) * 0.01;
            img.data[y * width + x] = (acc / 64.0 + noise) as f32;
        }
    }
    img
}

fn pose(tilt_x: f64, tilt_y: f64, spin: f64, centre: (f64, f64), distance: f64) -> Pose {
    let r =
        Rotation3::from_euler_angles(tilt_x.to_radians(), tilt_y.to_radians(), spin.to_radians());
    // Put the board's centre at `centre` (mm, camera x/y) and `distance`.
    let mid =
        Vector3::new(SPEC.cols as f64 - 1.0, SPEC.rows as f64 - 1.0, 0.0) * (SPEC.square_mm / 2.0);
    let t = Vector3::new(centre.0, centre.1, distance) - r * mid;
    Pose::from_parts(&r, t)
}

/// RMS and worst distance of detected corners from the true projections.
fn errors(found: &[(f64, f64)], cam: &CameraModel, pose: &Pose) -> (f64, f64) {
    let truth: Vec<(f64, f64)> = SPEC
        .board_points()
        .iter()
        .map(|&(x, y)| {
            let p = cam.project(pose, &Vector3::new(x, y, 0.0)).unwrap();
            (p.x, p.y)
        })
        .collect();
    assert_eq!(found.len(), truth.len());
    let d: Vec<f64> = found
        .iter()
        .zip(&truth)
        .map(|(a, b)| dist(*a, *b))
        .collect();
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    (rms, d.iter().copied().fold(0.0, f64::max))
}

#[test]
fn finds_a_tilted_board_in_order_to_sub_pixel_accuracy() {
    let cam = camera(0.0);
    let p = pose(20.0, -15.0, 10.0, (0.0, 0.0), 600.0);
    let found = detect_checkerboard(&render(&cam, &p, 640, 480), &SPEC).unwrap();
    let (rms, worst) = errors(&found, &cam, &p);
    assert!(rms < 0.06 && worst < 0.15, "rms {rms}, worst {worst}");
}

#[test]
fn a_board_turned_half_way_keeps_its_corner_order() {
    let cam = camera(0.0);
    for spin in [90.0, 180.0, 250.0] {
        let p = pose(-20.0, 10.0, spin, (0.0, 0.0), 600.0);
        let found = detect_checkerboard(&render(&cam, &p, 640, 480), &SPEC).unwrap();
        let (rms, worst) = errors(&found, &cam, &p);
        assert!(
            rms < 0.06 && worst < 0.15,
            "spin {spin}: rms {rms}, worst {worst}"
        );
    }
}

#[test]
fn corners_near_the_border_under_strong_distortion_are_found() {
    let cam = camera(-0.4);
    let p = pose(15.0, 25.0, -20.0, (62.0, 35.0), 520.0);
    let img = render(&cam, &p, 640, 480);
    let found = detect_checkerboard(&img, &SPEC).unwrap();
    let (rms, worst) = errors(&found, &cam, &p);
    assert!(rms < 0.06 && worst < 0.15, "rms {rms}, worst {worst}");
    let right = found.iter().map(|c| c.0).fold(0.0, f64::max);
    assert!(
        right > 580.0,
        "the board should reach the border, right-most corner at {right}"
    );
}

#[test]
fn no_board_or_a_partial_board_is_a_clear_error() {
    let cam = camera(0.0);
    let empty = GrayImage {
        width: 320,
        height: 240,
        data: vec![0.5; 320 * 240],
    };
    assert!(matches!(
        detect_checkerboard(&empty, &SPEC),
        Err(ProcessingError::IllPosed {
            what: "checkerboard detection",
            ..
        })
    ));
    // Half the board out of the frame.
    let p = pose(0.0, 0.0, 0.0, (140.0, 0.0), 600.0);
    let err = detect_checkerboard(&render(&cam, &p, 640, 480), &SPEC).unwrap_err();
    assert!(err.to_string().contains("in view"), "{err}");
}

#[test]
fn a_square_board_turned_a_quarter_is_found() {
    // 7×7 inner corners: the grid fits either way round, and a quarter turn is found only
    // the other way. Its half turn is ambiguous (7 + 7 is even), so the corners are compared
    // as a set.
    let spec = CheckerboardSpec {
        cols: 7,
        rows: 7,
        square_mm: 20.0,
    };
    let cam = camera(0.0);
    for spin in [0.0, 90.0, 270.0] {
        let r = Rotation3::from_euler_angles(
            15f64.to_radians(),
            -10f64.to_radians(),
            f64::to_radians(spin),
        );
        let mid = Vector3::new(60.0, 60.0, 0.0);
        let p = Pose::from_parts(&r, Vector3::new(0.0, 0.0, 600.0) - r * mid);
        let found = detect_checkerboard(&render_board(&spec, &cam, &p, 640, 480), &spec)
            .unwrap_or_else(|e| panic!("spin {spin}: {e}"));
        assert_eq!(found.len(), 49);
        for (x, y) in spec.board_points() {
            let q = cam.project(&p, &Vector3::new(x, y, 0.0)).unwrap();
            let nearest = found
                .iter()
                .map(|f| dist(*f, (q.x, q.y)))
                .fold(f64::INFINITY, f64::min);
            assert!(
                nearest < 0.2,
                "spin {spin}: corner ({x}, {y}) off by {nearest}"
            );
        }
    }
}

#[test]
fn a_lattice_grown_along_a_diagonal_is_made_rectangular_again() {
    // Cells of a 4 × 3 grid indexed (i + j, j): a parallelogram in index space.
    let sheared: Grid = (0..3)
        .flat_map(|j| (0..4).map(move |i| ((i + j, j), (j * 4 + i) as usize)))
        .collect();
    let fixed = rectangular(&sheared).expect("a shear makes it rectangular");
    for j in 0..3 {
        for i in 0..4 {
            assert_eq!(fixed[&(i, j)], (j * 4 + i) as usize);
        }
    }
    // A hole cannot be sheared away.
    let mut holed = fixed.clone();
    holed.remove(&(2, 1));
    holed.insert((9, 9), 99);
    assert!(rectangular(&holed).is_none());
}
