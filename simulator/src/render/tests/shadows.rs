//! Shadows: when the plan marches them, what they darken, and preview maps against exact rays.

use super::*;

#[test]
fn flat_sample_plans_no_shadows_and_never_marches() {
    for fixture in ["flat", "checkerboard", "colorchecker"] {
        let (r, _) = lightstage(fixture);
        for lamp in ["lamp1", "lamp8"] {
            let out = r
                .render(&world(fixture, &[(lamp, 1.0)]), "cam1", 0.02, 1.0, 1)
                .expect("render");
            let shadows = &out.notes["effects"]["shadows"];
            assert_eq!(shadows["on"], false, "{fixture} {lamp}: {shadows}");
            let why = shadows["why"].as_str().unwrap_or("");
            assert!(why.starts_with("flat height field: max slope 0°"), "{why}");
            assert_eq!(out.notes["stats"]["shadow_rays"], 0);
        }
    }
}

#[test]
fn bumps_at_low_light_elevation_cast_shadows_and_high_light_may_not() {
    let (r, _) = lightstage("bumps");
    let low = r
        .render(&world("bumps", &[("lamp1", 1.0)]), "cam4", 0.02, 1.0, 1)
        .expect("render");
    assert_eq!(
        low.notes["effects"]["shadows"]["on"], true,
        "{}",
        low.notes["effects"]["shadows"]
    );
    // Preview: the relief is shadowed through one cached visibility map per lamp; points
    // on the turntable still march.
    assert_eq!(low.notes["stats"]["visibility_maps"], 1);
    assert!(low.notes["stats"]["shadow_rays"].as_u64().unwrap_or(0) > 0);
    let high = r
        .render(&world("bumps", &[("lamp8", 1.0)]), "cam4", 0.02, 1.0, 1)
        .expect("render");
    let why = high.notes["effects"]["shadows"]["why"]
        .as_str()
        .unwrap_or("")
        .to_string();
    if high.notes["effects"]["shadows"]["on"] == false {
        assert!(why.contains("below light elevation"), "{why}");
        assert_eq!(high.notes["stats"]["shadow_rays"], 0);
        assert_eq!(high.notes["stats"]["visibility_maps"], 0);
    }
}

#[test]
fn shadows_darken_the_far_side_of_bumps() {
    let preview = quality::Quality::Preview.knobs();
    // Same geometry with and without shadow rays: shadows only ever remove light.
    let (r, _) = lightstage("bumps");
    let w = world("bumps", &[("lamp1", 1.0)]);
    let with = r.render(&w, "cam8", 0.02, 1.0, 5).expect("render");
    let sample = r.sample("bumps").expect("sample");
    let rig = small(BUILTIN_LIGHTSTAGE, "bumps");
    let cam = rig.camera("cam8").expect("cam8");
    let angles = RigAngles::from_world(&rig, &w.axes);
    let ts = ToSample::new(0.0);
    let pose = CameraPose::new(cam, ts);
    let (lights, _) = lights::lit_lamps(
        &rig,
        &crate::as_built::AsBuilt::nominal(&rig),
        &w,
        angles,
        ts,
    );
    let shading = |shadows| Shading {
        shadows,
        specular: true,
        knobs: &preview,
    };
    let scene = Scene::new(
        &sample,
        lights.clone(),
        None,
        vec![],
        shading(false),
        &|_| None,
    );
    let mut rays = 0;
    let unshadowed: f32 = (0..H)
        .flat_map(|y| (0..W).map(move |x| (x, y)))
        .map(|(x, y)| scene.pixel(&pose, x, y, &mut rays).x)
        .sum();
    assert_eq!(rays, 0);
    let scene = Scene::new(&sample, lights, None, vec![], shading(true), &|_| None);
    let shadowed: f32 = (0..H)
        .flat_map(|y| (0..W).map(move |x| (x, y)))
        .map(|(x, y)| scene.pixel(&pose, x, y, &mut rays).x)
        .sum();
    assert!(rays > 0);
    assert!(
        shadowed < 0.97 * unshadowed,
        "shadowed {shadowed} vs {unshadowed}"
    );
    assert_eq!(with.notes["effects"]["shadows"]["on"], true);
}

#[test]
fn preview_visibility_maps_agree_with_exact_shadow_rays() {
    let preview = quality::Quality::Preview.knobs();
    // The same frame shadowed through per-vertex maps and by marching every pixel: the maps
    // only blur shadow edges over one relief cell.
    for (fixture, lamp, cam) in [("bumps", "lamp1", "cam6"), ("steps", "lamp2", "cam5")] {
        let (r, rig) = lightstage(fixture);
        let sample = r.sample(fixture).expect("sample");
        let w = world(fixture, &[(lamp, 1.0)]);
        let ts = ToSample::new(0.0);
        let pose = CameraPose::new(rig.camera(cam).expect("camera"), ts);
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
            knobs: &preview,
        };
        let grid = sample.grid.as_ref().expect("relief");
        let map = |light| {
            Some(std::sync::Arc::new(shadow::VertexVisibility::compute(
                grid, light,
            )))
        };
        let exact = Scene::new(&sample, lights.clone(), None, vec![], shading, &|_| None);
        let mapped = Scene::new(&sample, lights, None, vec![], shading, &map);
        assert_eq!(mapped.visibility_maps(), 1);
        let (mut rays_exact, mut rays_mapped) = (0, 0);
        let (mut sum_exact, mut sum_mapped, mut differ) = (0.0f32, 0.0f32, 0);
        for y in 0..H {
            for x in 0..W {
                let a = exact.pixel(&pose, x, y, &mut rays_exact).y;
                let b = mapped.pixel(&pose, x, y, &mut rays_mapped).y;
                sum_exact += a;
                sum_mapped += b;
                if (a - b).abs() > 0.05 * a.max(b).max(1e-3) {
                    differ += 1;
                }
            }
        }
        assert!(
            rays_mapped < rays_exact,
            "{fixture}: maps replace rays on the relief"
        );
        let rel = (sum_mapped - sum_exact).abs() / sum_exact;
        assert!(rel < 0.03, "{fixture}: mean radiance differs by {rel}");
        assert!(
            differ < (W * H / 10) as usize,
            "{fixture}: {differ} pixels differ"
        );
    }
}
