//! The sensor at its limits and invalid inputs: saturation, dark frames, non-finite values,
//! every fixture rendering finite radiance.

use super::*;

/// A huge exposure (the camera maximum of 4 s at gain 16, then f64::MAX seconds, then gain
/// 1e300) saturates every lit pixel at exactly 2^bits − 1 for 8, 12 and 16 bits, and nothing
/// wraps around: no pixel anywhere exceeds the maximum, and lit pixels never read low.
#[test]
fn huge_exposure_saturates_at_the_bit_depth_maximum() {
    let _turn = crate::grbl_peer::alongside();
    for bits in [8u8, 12, 16] {
        let mut rig = rig("bumps", "preview");
        for c in &mut rig.cameras {
            c.bit_depth = bits;
        }
        let r = Renderer::new(&rig).expect("renderer");
        let max = sensor::max_dn(bits) as u16;
        let w = world("bumps", &[("lamp4", 1.0)], 0.0);
        let radiance = checked(&r, &w, "cam5");
        for (exposure, gain) in [
            (4.0, 16.0),
            (f64::MAX, 1.0),
            (1.0, 1e300),
            (f64::MAX, f64::MAX),
        ] {
            let out = r.render(&w, "cam5", exposure, gain, 3).expect("render");
            let mut lit = 0;
            for (k, (&dn, &rad)) in out.pixels.iter().zip(&radiance.rgb).enumerate() {
                assert!(dn <= max, "{bits} bits: pixel {k} = {dn} > {max}");
                // Radiance ≥ 1e-3 collects ≥ 1e-3 × 1.9e6 × 4 s electrons: far past full well.
                if rad >= 1e-3 {
                    lit += 1;
                    assert_eq!(
                        dn, max,
                        "{bits} bits, exposure {exposure:e} s, gain {gain:e}: lit pixel {k} (radiance {rad}) = {dn}"
                    );
                }
            }
            assert!(lit > 1000, "{bits} bits: {lit} lit values");
        }
    }
    // The sensor alone, at non-finite and extreme radiance.
    for bits in [8u8, 12, 16] {
        let max = sensor::max_dn(bits) as u16;
        for (exposure, gain) in [(4.0, 16.0), (f64::MAX, 1.0), (1.0, 1e300), (1e40, 1e40)] {
            let s = Sensor::new(bits, exposure, gain, 5);
            for p in 0..2000u64 {
                let dn = s.digitise_rgb([1.0, 1e30, f32::MAX], p);
                assert_eq!(
                    dn, [max; 3],
                    "{bits} bits exposure {exposure:e} gain {gain:e} pixel {p}"
                );
                let dn = s.digitise_rgb([f32::INFINITY, f32::NAN, 0.0], p);
                assert!(dn.iter().all(|&v| v <= max), "{dn:?}");
                assert_eq!(dn[0], max, "infinite radiance saturates");
            }
        }
    }
}

/// Zero (and negative) exposure gives the black level plus read noise: mean within
/// `DARK_MEAN_SIGMAS` standard errors of the black level, spread within `READ_NOISE_REL_TOL` of
/// the nominal read noise, no pixel more than `DARK_MAX_SIGMAS` σ from black, and at 8 bits and
/// gain 16 (σ = 3 DN around a black level of 5 DN) values clip at 0 rather than wrapping.
#[test]
fn zero_exposure_gives_black_level_plus_read_noise() {
    let _turn = crate::grbl_peer::alongside();
    for (bits, gain) in [(12u8, 1.0), (16, 4.0), (8, 16.0)] {
        let mut rig = rig("bumps", "preview");
        for c in &mut rig.cameras {
            c.bit_depth = bits;
        }
        let r = Renderer::new(&rig).expect("renderer");
        let black = r.black_level_dn("cam3");
        let sigma = sensor::READ_NOISE_DN_12BIT * gain * sensor::max_dn(bits) / 4095.0;
        for exposure in [0.0, -1.0] {
            let out = r
                .render(
                    &world("bumps", &[("lamp3", 1.0)], 0.0),
                    "cam3",
                    exposure,
                    gain,
                    11,
                )
                .expect("render");
            let v: Vec<f64> = out.pixels.iter().map(|&p| p as f64).collect();
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let std = (v.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
            let max = v.iter().copied().fold(0.0, f64::max);
            if bits == 8 && gain == 16.0 {
                // Clipped at 0 from below: the mean rises above black, nothing wraps.
                assert!(v.contains(&0.0), "8-bit dark frame never clips at 0");
                assert!(
                    max <= black + DARK_MAX_SIGMAS * sigma + 0.5,
                    "wrapped: max {max}"
                );
                assert!(mean >= black - 0.5, "mean {mean}");
                continue;
            }
            assert!(
                (mean - black).abs() <= DARK_MEAN_SIGMAS * sigma / n.sqrt() + 0.5 / n.sqrt(),
                "{bits} bits exposure {exposure}: mean {mean} vs black {black}"
            );
            assert!(
                (std - sigma).abs() <= READ_NOISE_REL_TOL * sigma,
                "{bits} bits: read noise {std} vs {sigma}"
            );
            for &d in &v {
                assert!(
                    (d - black).abs() <= DARK_MAX_SIGMAS * sigma + 0.5,
                    "{bits} bits: dark pixel {d} (black {black}, σ {sigma})"
                );
            }
            assert_eq!(out.notes["sensor"]["light_integrated"], false);
        }
    }
}

/// NaN and infinite inputs to `render` and `radiance` — exposure, gain, axis angles, lamp
/// output, cart position, laser angles — are `InvalidInput` errors naming the value, never a
/// panic and never a frame.
#[test]
fn non_finite_inputs_are_errors_not_panics() {
    let _turn = crate::grbl_peer::alongside();
    let rig = rig("bumps", "preview");
    let r = Renderer::new(&rig).expect("renderer");
    let base = world("bumps", &[("lamp2", 1.0)], 0.0);
    let bad_numbers = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
    let mut cases: Vec<(String, WorldSnapshot, f64, f64)> = Vec::new();
    for x in bad_numbers {
        cases.push((format!("exposure {x}"), base.clone(), x, 1.0));
        cases.push((format!("gain {x}"), base.clone(), 0.02, x));
        for axis in ["turntable", "light_arc", "laser_tilt"] {
            let mut w = base.clone();
            w.axes.insert(axis.into(), x);
            cases.push((format!("axis {axis} {x}"), w, 0.02, 1.0));
        }
        let mut w = base.clone();
        w.lamps.insert("lamp2".into(), x);
        cases.push((format!("lamp output {x}"), w, 0.02, 1.0));
        let mut w = base.clone();
        w.cart_mm = x;
        cases.push((format!("cart {x}"), w, 0.02, 1.0));
        for field in 0..2 {
            let mut beam = LaserBeam {
                colour_nm: 650,
                tilt_deg: 0.0,
                mount_elevation_deg: 45.0,
            };
            if field == 0 {
                beam.tilt_deg = x;
            } else {
                beam.mount_elevation_deg = x;
            }
            let w = WorldSnapshot {
                laser: Some(beam),
                ..base.clone()
            };
            cases.push((format!("laser field {field} {x}"), w, 0.02, 1.0));
        }
    }
    cases.push(("gain 0".into(), base.clone(), 0.02, 0.0));
    cases.push(("gain -1".into(), base.clone(), 0.02, -1.0));
    let mut w = base.clone();
    w.lamps.insert("lamp2".into(), -0.5);
    cases.push(("lamp output -0.5".into(), w, 0.02, 1.0));
    for (what, w, exposure, gain) in cases {
        let result = std::panic::catch_unwind(|| r.render(&w, "cam2", exposure, gain, 1));
        match result {
            Ok(Err(RenderError::InvalidInput { .. })) => {}
            Ok(other) => panic!(
                "{what}: expected InvalidInput, got {:?}",
                other.map(|o| o.notes)
            ),
            Err(_) => panic!("{what}: render panicked"),
        }
        // `radiance` checks the world the same way (exposure and gain are not its inputs).
        if !what.starts_with("exposure") && !what.starts_with("gain") {
            let result = std::panic::catch_unwind(|| r.radiance(&w, "cam2"));
            assert!(
                matches!(result, Ok(Err(RenderError::InvalidInput { .. }))),
                "{what}: radiance did not reject it"
            );
        }
    }
}

/// Every fixture under the most grazing lamp (10°, then moved to 1°), every camera, with the
/// laser on, at preview and standard: no NaN, infinity or negative radiance anywhere.
#[test]
fn every_fixture_renders_finite_non_negative_radiance() {
    let _turn = crate::grbl_peer::alongside();
    for quality in ["preview", "standard"] {
        for elevation in [10.0, 1.0] {
            for fixture in stagehand_simulator::render::sample::FIXTURES {
                let mut rig = rig(fixture, quality);
                rig.lamps[0].elevation_deg = elevation;
                let r = Renderer::new(&rig).expect("renderer");
                let mut w = world(fixture, &[("lamp1", 1.0), ("lamp8", 0.5)], 30.0);
                w.axes.insert("turntable".into(), 17.0);
                w.laser = Some(LaserBeam {
                    colour_nm: 532,
                    tilt_deg: 3.0,
                    mount_elevation_deg: 45.0,
                });
                let cams: &[&str] = if quality == "preview" {
                    &[
                        "cam1", "cam2", "cam3", "cam4", "cam5", "cam6", "cam7", "cam8",
                    ]
                } else {
                    // Standard costs ~15× preview per pixel: its most grazing camera only.
                    &["cam1"]
                };
                for cam in cams {
                    checked(&r, &w, cam);
                }
            }
        }
    }
}
