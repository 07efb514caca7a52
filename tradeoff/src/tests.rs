//! End to end: a tiny sweep on a 32×24 camera writes all four outputs.

use super::*;
use stagehand_simulator::render::quality::Quality;

/// A cheap sweep: coarse relief everywhere (so sample build and bounce set-up are small) and
/// a handful of settings.
fn tiny_config() -> SweepConfig {
    let coarse = |mut k: stagehand_simulator::render::quality::Knobs| {
        k.relief_mm = 1.0;
        k.bounce_rays = k.bounce_rays.min(8);
        k
    };
    let mut reference = coarse(sweep::reference_knobs());
    reference.spp_side = 8;
    reference.halogen_samples = 64;
    reference.bounces = 1;
    let settings = sweep::default_settings()
        .into_iter()
        .filter(|s| {
            s.knob == "preset"
                || matches!(
                    s.label.as_str(),
                    "spp_side=1" | "spp_side=4" | "halogen_samples=1" | "shadow_maps=true"
                )
        })
        .map(|mut s| {
            s.knobs = coarse(s.knobs);
            s
        })
        .collect();
    SweepConfig {
        repeat: 1,
        reference,
        settings,
    }
}

#[test]
fn tiny_sweep_writes_csv_markdown_and_plots() {
    let setup = Setup::new(SetupOptions {
        scene: "steps".into(),
        width: 32,
        height: 24,
        ..SetupOptions::default()
    })
    .expect("setup");
    let config = tiny_config();
    let mut lines = 0;
    let t = sweep::run(&setup, &config, &mut |_| lines += 1).expect("sweep");
    assert_eq!(t.points.len(), config.settings.len());
    assert!(lines > t.points.len());
    assert!(t.reference_mean > 0.0, "lit scene");
    assert!(t.points.iter().any(|p| p.pareto));
    for p in &t.points {
        assert!(p.time_s > 0.0 && p.error.rmse.is_finite(), "{p:?}");
    }
    // Fewer pixel samples cannot be closer to a 64-spp reference than 16 spp here.
    let err = |label: &str| {
        t.points
            .iter()
            .find(|p| p.setting.label == label)
            .map(|p| p.error.rmse)
            .expect(label)
    };
    assert!(err("spp_side=1") > err("spp_side=4"));
    let pick = t.pick(Target::Relative(10.0)).expect("loose target met");
    assert!(t.points.iter().all(|p| p.time_s >= pick.time_s));
    assert!(t.pick(Target::Rmse(1e-12)).is_err(), "unreachable");

    let dir = tempfile::tempdir().expect("tmp");
    let chosen = t.pick(Target::Relative(10.0));
    report::write(
        dir.path(),
        &t,
        Some((Target::Relative(10.0), &chosen)),
        None,
    )
    .expect("report");
    plot::write(dir.path(), &t, None).expect("plot");
    let csv = std::fs::read_to_string(dir.path().join("tradeoff.csv")).expect("csv");
    let mut rows = csv.lines();
    let header: Vec<&str> = rows.next().expect("header").split(',').collect();
    assert_eq!(header.join(","), report::CSV_HEADER);
    let rows: Vec<Vec<&str>> = rows.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), t.points.len());
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    for r in &rows {
        assert_eq!(r.len(), header.len(), "{r:?}");
        let time: f64 = r[col("time_s")].parse().expect("time");
        let rmse: f64 = r[col("rmse")].parse().expect("rmse");
        assert!(time > 0.0 && rmse >= 0.0);
        assert!(matches!(r[col("pareto")], "true" | "false"));
    }
    let md = std::fs::read_to_string(dir.path().join("tradeoff.md")).expect("md");
    assert!(md.contains("| ★ |") && md.contains("preset standard") && md.contains("Pick for"));
    for name in ["tradeoff.png", "tradeoff.svg"] {
        let len = std::fs::metadata(dir.path().join(name)).expect(name).len();
        assert!(len > 1000, "{name} is {len} bytes");
    }
    let png = std::fs::read(dir.path().join("tradeoff.png")).expect("png");
    assert!(png.starts_with(b"\x89PNG"));
    let svg = std::fs::read_to_string(dir.path().join("tradeoff.svg")).expect("svg");
    assert!(
        svg.contains("<svg") && svg.contains("preview"),
        "labels drawn"
    );
}

#[test]
fn tradeoff_rejects_bad_repeat_and_scene_overrides_nothing() {
    let setup = Setup::new(SetupOptions {
        width: 4,
        height: 3,
        ..SetupOptions::default()
    })
    .expect("setup");
    let mut config = tiny_config();
    config.repeat = 0;
    let e = sweep::run(&setup, &config, &mut |_| ()).expect_err("repeat 0");
    assert!(
        e.is_bad_input() && e.to_string().contains("--repeat"),
        "{e}"
    );
    let mut config = tiny_config();
    config.settings.truncate(1);
    config.settings[0].knobs = Quality::Preview.knobs();
    config.settings[0].knobs.spp_side = 0;
    let e = sweep::run(&setup, &config, &mut |_| ()).expect_err("bad knob");
    assert!(e.to_string().contains("spp_side"), "{e}");
}
