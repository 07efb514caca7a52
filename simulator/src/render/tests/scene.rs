//! What the cameras see of the rig: charts, the turntable, the reflectometer, errors, notes,
//! grazing angles and the lens tables.

use super::*;

#[test]
fn checkerboard_shows_dark_and_bright_squares() {
    let (r, _) = lightstage("checkerboard");
    let black = r.black_level_dn("cam6");
    let out = r
        .render(
            &world("checkerboard", &[("lamp4", 1.0)]),
            "cam6",
            0.02,
            1.0,
            1,
        )
        .expect("render");
    let mut dark = 0;
    let mut bright = 0;
    for y in 12..36 {
        for x in 16..48 {
            let g = out.pixels[((y * W + x) * 3 + 1) as usize] as f64 - black;
            if g < 100.0 {
                dark += 1;
            } else if g > 1000.0 {
                bright += 1;
            }
        }
    }
    assert!(dark > 100 && bright > 100, "dark {dark}, bright {bright}");
    assert_eq!(out.notes["effects"]["specular"]["on"], false);
}

#[test]
fn turntable_rotates_the_sample_not_the_camera() {
    let (r, _) = lightstage("colorchecker");
    let mut w = world("colorchecker", &[("lamp8", 1.0)]);
    let a = r.render(&w, "cam8", 0.02, 1.0, 1).expect("render");
    w.axes.insert("turntable".into(), 90.0);
    let b = r.render(&w, "cam8", 0.02, 1.0, 1).expect("render");
    assert_ne!(a.pixels, b.pixels);
    assert_eq!(b.notes["geometry"]["turntable_deg"], 90.0);
}

#[test]
fn reflectometer_tube_and_backlight() {
    let rig = small(BUILTIN_REFLECTOMETER, "weave");
    let r = Renderer::new(&rig).expect("renderer");
    let black = r.black_level_dn("cam1");
    let mut w = world("weave", &[("tube", 1.0)]);
    // Tube straight above the sample centre: x = cart − travel/2 = 0.
    w.cart_mm = 120.0;
    let lit = r.render(&w, "cam1", 0.02, 1.0, 1).expect("render");
    assert_eq!(
        lit.notes["effects"]["linear_light"]["on"], true,
        "{}",
        lit.notes["effects"]
    );
    assert!(mean_signal(&lit, black, 0, centre) > 200.0);
    let back = r
        .render(&world("weave", &[("backlight", 1.0)]), "cam1", 0.02, 1.0, 1)
        .expect("render");
    assert_eq!(back.notes["effects"]["backlight"]["on"], true);
    let signal = mean_signal(&back, black, 1, centre);
    assert!(signal > 10.0, "light comes through the gaps: {signal}");
    let opaque = r
        .render(
            &world("planes", &[("backlight", 1.0)]),
            "cam1",
            0.02,
            1.0,
            1,
        )
        .expect("render");
    assert_eq!(opaque.notes["effects"]["backlight"]["on"], false);
    assert!(mean_signal(&opaque, black, 1, centre).abs() < 2.0);
}

#[test]
fn errors_say_what_to_do() {
    let (r, _) = lightstage("flat");
    let e = r
        .render(&world("flat", &[]), "cam9", 0.01, 1.0, 0)
        .expect_err("no cam9");
    assert!(e.to_string().contains("cam1, cam2"), "{e}");
    let e = r
        .render(&world("teapot", &[]), "cam1", 0.01, 1.0, 0)
        .expect_err("no teapot");
    assert!(e.to_string().contains("place one of"), "{e}");
    let e = r
        .render(&world("flat", &[]), "cam1", f64::NAN, 1.0, 0)
        .expect_err("nan");
    assert!(matches!(e, RenderError::InvalidInput { .. }));
    let e = r
        .render(&world("flat", &[]), "cam1", 0.01, 0.0, 0)
        .expect_err("zero gain");
    assert!(e.to_string().contains("gain"), "{e}");
    let rf = Renderer::new(&small(BUILTIN_REFLECTOMETER, "flat")).expect("renderer");
    let w = WorldSnapshot {
        laser: Some(LaserBeam {
            colour_nm: 650,
            tilt_deg: 0.0,
            mount_elevation_deg: 45.0,
        }),
        ..world("flat", &[])
    };
    assert!(matches!(
        rf.render(&w, "cam1", 0.01, 1.0, 0),
        Err(RenderError::NoLaser(_))
    ));
    let mut bad = small(BUILTIN_LIGHTSTAGE, "flat");
    SimSpec::edit(&mut bad, |s| s.quality = "ultra".into()).expect("sim");
    assert!(matches!(
        Renderer::new(&bad),
        Err(RenderError::UnknownQuality(_))
    ));
    assert_eq!(r.black_level_dn("nope"), 0.0);
    assert_eq!(r.black_level_dn("cam1"), 82.0);
}

#[test]
fn notes_record_quality_and_samples() {
    let mut rig = small(BUILTIN_LIGHTSTAGE, "bumps");
    SimSpec::edit(&mut rig, |s| s.quality = "standard".into()).expect("sim");
    let r = Renderer::new(&rig).expect("renderer");
    let out = r
        .render(&world("bumps", &[("lamp6", 1.0)]), "cam2", 0.02, 1.0, 1)
        .expect("render");
    assert_eq!(out.notes["quality"], "standard");
    assert_eq!(out.notes["knobs"]["spp_side"], 2);
    assert_eq!(out.notes["effects"]["area_lights"]["on"], true);
    assert_eq!(out.notes["fixture"], "bumps");
    assert_eq!(out.notes["black_level_dn"], 82.0);
    assert!(
        out.notes["effects"]["specular"]["why"]
            .as_str()
            .unwrap_or("")
            .starts_with("ks=")
    );
}

#[test]
fn nothing_radiates_nan_or_negative_at_grazing_light_and_view() {
    let preview = quality::Quality::Preview.knobs();
    // cam1 at 5°, lamp1 at 10°: the most grazing pair on the rig, on every height field.
    for fixture in ["bumps", "steps", "weave", "planes", "flat"] {
        let (r, rig) = lightstage(fixture);
        let sample = r.sample(fixture).expect("sample");
        let w = world(fixture, &[("lamp1", 1.0)]);
        let ts = ToSample::new(0.0);
        let pose = CameraPose::new(rig.camera("cam1").expect("cam1"), ts);
        let (lights, _) = lights::lit_lamps(
            &rig,
            &crate::as_built::AsBuilt::nominal(&rig),
            &w,
            RigAngles::from_world(&rig, &w.axes),
            ts,
        );
        let scene = Scene::new(
            &sample,
            lights,
            None,
            vec![],
            Shading {
                shadows: true,
                specular: true,
                knobs: &preview,
            },
            &|_| None,
        );
        let mut rays = 0;
        for y in 0..H {
            for x in 0..W {
                let l = scene.pixel(&pose, x, y, &mut rays);
                assert!(
                    l.is_finite() && l.min_element() >= 0.0,
                    "{fixture} ({x},{y}): {l}"
                );
                assert!(l.max_element() < 100.0, "{fixture} ({x},{y}): {l}");
            }
        }
        let _ = Vec3A::ZERO;
    }
}

/// A distorted camera's pixels through its lens table are the pixels computed without it,
/// bit for bit, at 2×2 samples a pixel.
#[test]
fn lens_table_pixels_are_the_computed_pixels() {
    let standard = quality::Quality::Standard.knobs();
    let rig = small(BUILTIN_LIGHTSTAGE, "bumps");
    let (r, _) = lightstage("bumps");
    let sample = r.sample("bumps").expect("sample");
    let w = world("bumps", &[("lamp1", 1.0)]);
    let spec = CameraSpec {
        k1: -0.2,
        p2: 5e-4,
        ..rig.camera("cam3").expect("cam3").clone()
    };
    let ts = ToSample::new(30.0);
    let pose = CameraPose::new(&spec, ts);
    let (lights, _) = lights::lit_lamps(
        &rig,
        &crate::as_built::AsBuilt::nominal(&rig),
        &w,
        RigAngles::from_world(&rig, &w.axes),
        ts,
    );
    let shading = Shading {
        shadows: true,
        specular: true,
        knobs: &standard,
    };
    let scene = Scene::new(&sample, lights, None, vec![], shading, &|_| None);
    let tables = pixel_samples::LensTables::default();
    let table = tables.get(&pose, standard.spp_side, false).expect("table");
    let (mut a, mut b) = (0, 0);
    for y in 0..H {
        for x in 0..W {
            let computed = scene
                .pixel(&pose, x, y, &mut a)
                .to_array()
                .map(f32::to_bits);
            let tabled = scene
                .pixel_with(&pose, Some(&table), None, None, x, y, &mut b)
                .to_array()
                .map(f32::to_bits);
            assert_eq!(tabled, computed, "({x}, {y})");
        }
    }
    assert_eq!(a, b, "the same shadow rays");
}
