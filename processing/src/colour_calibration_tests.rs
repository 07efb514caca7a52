//! Tests of the colour calibration on charts rendered through a camera that is not where its
//! nominal geometry says: the chart must still be found, and the scales recovered.

use nalgebra::{Rotation3, Vector3};

use super::*;
use crate::camera_model::{Distortion, Pose};
use crate::chart_layout::{CARD_REFLECTANCE, Orientation};
use crate::nominal_geometry::{NominalCamera, nominal_geometry};
use crate::white_balance::checker_reflectance;

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

fn nominal(elevation_deg: f64) -> NominalCamera {
    NominalCamera {
        id: "cam".into(),
        width: 480,
        height: 360,
        azimuth_deg: 0.0,
        elevation_deg,
        distance_mm: 600.0,
        fov_deg: 11.0,
        principal_offset_px: [0.0, 0.0],
        distortion: Distortion::default(),
    }
}

/// The camera as built: turned by `turn_deg` about its own x, y, z axes, its principal point
/// off by (6, −5) px, its focal length 0.5 % long and a mild barrel distortion.
fn misplaced(elevation_deg: f64, turn_deg: [f64; 3]) -> CameraGeometry {
    let mut cam = nominal(elevation_deg);
    cam.principal_offset_px = [6.0, -5.0];
    cam.fov_deg = 2.0
        * ((11.0f64 / 2.0).to_radians().tan() / 1.005)
            .atan()
            .to_degrees();
    cam.distortion.k1 = -0.08;
    let mut g = nominal_geometry(&cam).unwrap();
    let [a, b, c] = turn_deg.map(f64::to_radians);
    let turn = Rotation3::from_euler_angles(a, b, c);
    let r = turn * g.rig_to_camera.rotation_matrix();
    g.rig_to_camera = Pose::from_parts(&r, turn * Vector3::from(g.rig_to_camera.translation));
    g
}

/// What a lamp does to the chart in the render: channel scales, noise σ, and the range the
/// merge could measure (below `floor` black, above `clip` saturated in every exposure).
#[derive(Clone, Copy)]
struct Light {
    scale: [f64; 3],
    sigma: f64,
    floor: f64,
    clip: f64,
}

const LIGHT: Light = Light {
    scale: [0.9, 0.62, 0.31],
    sigma: 0.002,
    floor: f64::NEG_INFINITY,
    clip: f64::INFINITY,
};

/// Renders the chart lying `orientation` at `turntable_deg` through `camera` (2×2 samples per
/// pixel; a grey turntable around the card).
fn render(
    camera: &CameraGeometry,
    turntable_deg: f64,
    orientation: Orientation,
    light: Light,
    seed: u64,
) -> HdrFrame {
    let layout = ChartLayout::default();
    let (w, h) = (480usize, 360usize);
    let pose = sample_to_camera(&camera.rig_to_camera, turntable_deg);
    let rt = pose.rotation_matrix().transpose();
    let centre = -(rt * Vector3::from(pose.translation));
    let mut noise = Noise(seed | 1);
    let mut rgb = vec![0.0f32; w * h * 3];
    let mut state = vec![PixelState::Measured; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let mut rho = [0.0; 3];
            for (sx, sy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let (xn, yn) = camera
                    .model
                    .normalise(x as f64 + sx, y as f64 + sy)
                    .unwrap();
                let d = rt * Vector3::new(xn, yn, 1.0);
                let p = centre + d * (-centre.z / d.z);
                let c = orientation.apply([p.x, p.y]);
                let r = if c[0].abs() > 40.0 || c[1].abs() > 40.0 {
                    [0.2; 3]
                } else {
                    match layout.patch_at(c[0], c[1]) {
                        Some(i) => checker_reflectance(i),
                        None => [CARD_REFLECTANCE; 3],
                    }
                };
                for k in 0..3 {
                    rho[k] += 0.25 * r[k];
                }
            }
            for (c, (scale, rho)) in light.scale.iter().zip(rho).enumerate() {
                let i = 3 * (y * w + x) + c;
                let v = scale * rho + light.sigma * noise.next();
                (rgb[i], state[i]) = if v >= light.clip {
                    (light.clip as f32, PixelState::AtLeast)
                } else if v <= light.floor {
                    (light.floor as f32, PixelState::AtMost)
                } else {
                    (v as f32, PixelState::Measured)
                };
            }
        }
    }
    HdrFrame {
        width: w,
        height: h,
        rgb,
        state,
    }
}

/// Measures `frames` (lamp id, frame) with the nominal geometry of a camera at
/// `elevation_deg`.
fn measure(
    elevation_deg: f64,
    turntable_deg: f64,
    frames: &[(&str, HdrFrame)],
) -> Result<(ChartView, Vec<(String, LampView)>), ProcessingError> {
    let geometry = nominal_geometry(&nominal(elevation_deg)).unwrap();
    let names: Vec<String> = vec!["f.png".into()];
    let captures: Vec<LampCapture<'_>> = frames
        .iter()
        .enumerate()
        .map(|(step, (lamp, hdr))| LampCapture {
            lamp,
            step,
            frames: &names,
            hdr,
        })
        .collect();
    measure_view(
        &geometry,
        turntable_deg,
        &captures,
        &ColourOptions::default(),
    )
}

fn assert_scales(fit: &LampScale, truth: [f64; 3], tolerance: f64) {
    for (c, (got, want)) in fit.fit.scale.iter().zip(truth).enumerate() {
        let err = got / want - 1.0;
        assert!(
            err.abs() < tolerance,
            "channel {c}: {got} vs {want} ({err:+.4})"
        );
    }
}

#[test]
fn finds_the_chart_of_a_camera_off_its_mount_and_recovers_each_lamps_scales() {
    let camera = misplaced(35.0, [0.5, -0.4, 0.4]);
    let warm = LIGHT;
    let cool = Light {
        scale: [0.35, 0.5, 0.7],
        ..LIGHT
    };
    let frames = [
        ("lamp1", render(&camera, 0.0, Orientation::AsDrawn, warm, 1)),
        ("lamp2", render(&camera, 0.0, Orientation::AsDrawn, cool, 2)),
    ];
    let (view, lamps) = measure(35.0, 0.0, &frames).unwrap();
    let shift = view.fit.offset_px[0].hypot(view.fit.offset_px[1]);
    assert!(shift > 15.0, "the camera is ~0.6° off: {view:?}");
    assert!(view.fit.ncc > 0.95, "{view:?}");
    assert_eq!(view.fit.orientation, Orientation::AsDrawn);
    assert!(view.min_patch_pixels > 100, "{view:?}");
    for ((lamp, v), truth) in lamps.into_iter().zip([warm.scale, cool.scale]) {
        assert_eq!(v.patches.len(), 24, "{lamp}: {:?}", v.excluded);
        let fit = fit_lamp("cam", &lamp, vec![v]).unwrap();
        assert_scales(&fit, truth, 0.002);
        assert!(fit.fit.rel_residual.iter().all(|r| *r < 0.02), "{fit:?}");
    }
}

#[test]
fn a_grazing_view_with_patches_a_few_pixels_tall_is_measured() {
    // At 6° elevation a 10.5 mm patch is ~4.5 px tall; the camera is half a degree off.
    let camera = misplaced(6.0, [0.5, 0.3, -0.3]);
    let frames = [(
        "lamp1",
        render(&camera, 0.0, Orientation::AsDrawn, LIGHT, 3),
    )];
    let (view, lamps) = measure(6.0, 0.0, &frames).unwrap();
    assert!(view.min_patch_pixels >= MIN_PATCH_PIXELS, "{view:?}");
    let (lamp, v) = lamps.into_iter().next().unwrap();
    let fit = fit_lamp("cam", &lamp, vec![v]).unwrap();
    assert_scales(&fit, LIGHT.scale, 0.01);
}

#[test]
fn a_chart_turned_half_way_or_a_turned_table_is_still_read_patch_by_patch() {
    let camera = misplaced(45.0, [-0.3, 0.4, 0.2]);
    let frames = [(
        "lamp1",
        render(&camera, 0.0, Orientation::HalfTurn, LIGHT, 4),
    )];
    let (view, lamps) = measure(45.0, 0.0, &frames).unwrap();
    assert_eq!(view.fit.orientation, Orientation::HalfTurn);
    let fit = fit_lamp("cam", "lamp1", vec![lamps[0].1.clone()]).unwrap();
    assert_scales(&fit, LIGHT.scale, 0.002);
    // The table at 90°: the chart turns with it, and the geometry says so.
    let frames = [(
        "lamp1",
        render(&camera, 90.0, Orientation::AsDrawn, LIGHT, 5),
    )];
    let (view, lamps) = measure(45.0, 90.0, &frames).unwrap();
    assert_eq!(view.fit.orientation, Orientation::AsDrawn);
    let fit = fit_lamp("cam", "lamp1", vec![lamps[0].1.clone()]).unwrap();
    assert_scales(&fit, LIGHT.scale, 0.003);
}

#[test]
fn saturated_and_black_patches_are_left_out_not_averaged_in() {
    let camera = misplaced(35.0, [0.2, 0.2, 0.0]);
    // White (0.9 × 0.87) clips; the black patch's blue (0.31 × 0.03) is below the floor.
    let light = Light {
        clip: 0.7,
        floor: 0.012,
        ..LIGHT
    };
    let frames = [(
        "lamp1",
        render(&camera, 0.0, Orientation::AsDrawn, light, 6),
    )];
    let (_, lamps) = measure(35.0, 0.0, &frames).unwrap();
    let v = &lamps[0].1;
    assert!(v.excluded.contains(&ExcludedPatch {
        patch: 18,
        reason: Exclusion::Saturated
    }));
    assert!(v.excluded.contains(&ExcludedPatch {
        patch: 23,
        reason: Exclusion::Black
    }));
    assert!(v.patches.iter().all(|p| p.patch != 18 && p.patch != 23));
    let fit = fit_lamp("cam", "lamp1", vec![v.clone()]).unwrap();
    assert_scales(&fit, light.scale, 0.005);
}

#[test]
fn a_lamp_too_dim_to_measure_is_an_error_naming_camera_and_lamp() {
    let camera = misplaced(35.0, [0.0; 3]);
    let bright = render(&camera, 0.0, Orientation::AsDrawn, LIGHT, 7);
    // Barely above the noise: patches measured, but the scale is lost in it.
    let faint = Light {
        scale: [2e-4, 1e-4, 5e-5],
        sigma: 0.01,
        floor: f64::NEG_INFINITY,
        ..LIGHT
    };
    // Below the merge's floor in every exposure: every patch is a bound.
    let dark = Light {
        sigma: 1e-5,
        floor: 0.001,
        ..faint
    };
    let frames = [
        ("lamp1", bright),
        (
            "lamp7",
            render(&camera, 0.0, Orientation::AsDrawn, faint, 8),
        ),
        ("lamp8", render(&camera, 0.0, Orientation::AsDrawn, dark, 9)),
    ];
    // The bright lamp locates the chart for all three.
    let (_, lamps) = measure(35.0, 0.0, &frames).unwrap();
    let mut lamps = lamps.into_iter();
    assert!(fit_lamp("cam3", "lamp1", vec![lamps.next().unwrap().1]).is_ok());
    for _ in 0..2 {
        let (lamp, v) = lamps.next().unwrap();
        let err = fit_lamp("cam3", &lamp, vec![v]).unwrap_err();
        assert!(
            matches!(&err, ProcessingError::CameraLamp { camera, lamp: l, .. } if camera == "cam3" && *l == lamp),
            "{err}"
        );
        let text = err.to_string();
        assert!(text.contains("cam3") && text.contains(&lamp), "{text}");
        assert!(text.contains("dim") && !text.contains("NaN"), "{text}");
    }
}

#[test]
fn a_camera_seeing_only_a_dark_lamp_says_so_rather_than_missing_the_chart() {
    let camera = misplaced(35.0, [0.0; 3]);
    let dark = Light {
        scale: [1e-5; 3],
        sigma: 1e-6,
        floor: 0.001,
        ..LIGHT
    };
    let frames = [(
        "lamp4",
        render(&camera, 0.0, Orientation::AsDrawn, dark, 10),
    )];
    let err = measure(35.0, 0.0, &frames).unwrap_err();
    assert!(
        matches!(&err, ProcessingError::CameraLamp { lamp, .. } if lamp == "lamp4"),
        "{err}"
    );
    assert!(err.to_string().contains("too dim"), "{err}");
}

#[test]
fn a_chart_out_of_view_is_an_error() {
    let blank = HdrFrame {
        width: 480,
        height: 360,
        rgb: vec![0.1; 480 * 360 * 3],
        state: vec![PixelState::Measured; 480 * 360 * 3],
    };
    let err = measure(35.0, 0.0, &[("lamp1", blank)]).unwrap_err();
    assert!(
        matches!(&err, ProcessingError::Camera { camera, .. } if camera == "cam"),
        "{err}"
    );
    assert!(err.to_string().contains("correlation"), "{err}");
}
