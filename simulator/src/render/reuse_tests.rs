//! What the renderer reuses between frames (each camera view's primary hits, the laser's
//! reach) changes no pixel: frames rendered with the kept tables are bit-identical to frames
//! rendered from scratch, across lamp sequences, laser sweeps, new views, a distorted lens,
//! the reflectometer's moving tube, HDR brackets and both quality presets.

use std::collections::BTreeMap;

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};

use super::*;
use crate::render::quality::Quality;
use crate::world_snapshot::LaserBeam;

fn rig(text: &str, fixture: &str, k1: f64) -> RigSpec {
    let mut rig = parse_rig(text, "test.toml").expect("built-in rig parses");
    for c in &mut rig.cameras {
        c.width = 48;
        c.height = 36;
        c.k1 = k1;
    }
    SimSpec::edit(&mut rig, |s| s.sample = fixture.into()).expect("sim");
    rig
}

fn world(fixture: &str, turntable_deg: f64) -> WorldSnapshot {
    WorldSnapshot {
        rig_time_s: 1.0,
        axes: BTreeMap::from([
            ("turntable".to_string(), turntable_deg),
            ("light_arc".to_string(), 60.0),
        ]),
        lamps: BTreeMap::new(),
        laser: None,
        cart_mm: 0.0,
        fixture: fixture.into(),
        fixture_pose: Default::default(),
    }
}

fn lamp(mut w: WorldSnapshot, id: &str) -> WorldSnapshot {
    w.lamps = BTreeMap::from([(id.to_string(), 1.0)]);
    w
}

fn laser(mut w: WorldSnapshot, tilt_deg: f64) -> WorldSnapshot {
    w.laser = Some(LaserBeam {
        colour_nm: 650,
        tilt_deg,
        mount_elevation_deg: 45.0,
    });
    w
}

/// Renders every world on every camera with a renderer that keeps primary hits and with one
/// that keeps none; the pixels and notes must match bit for bit, and the first must have used
/// its tables.
fn same_with_and_without_kept_hits(rig: &RigSpec, quality: Quality, worlds: &[WorldSnapshot]) {
    let mut kept = Renderer::with_knobs(rig, quality.knobs()).expect("renderer");
    // A repeated world would reuse the whole radiance; here the hits are under test.
    kept.radiance = kept_radiance::KeptRadiance::with_budget(0);
    let mut scratch = Renderer::with_knobs(rig, quality.knobs()).expect("renderer");
    scratch.primary_hits = primary_hits::PrimaryHits::with_budget(0);
    scratch.radiance = kept_radiance::KeptRadiance::with_budget(0);
    for (i, w) in worlds.iter().enumerate() {
        for cam in &rig.cameras {
            let a = kept
                .render(w, &cam.id, 0.02, 1.0, i as u64)
                .expect("render");
            let b = scratch
                .render(w, &cam.id, 0.02, 1.0, i as u64)
                .expect("render");
            assert!(a.pixels == b.pixels, "world {i}, {}: pixels differ", cam.id);
            assert_eq!(a.notes, b.notes, "world {i}, {}", cam.id);
        }
    }
    assert!(!kept.primary_hits.is_empty(), "the tables were used");
    assert!(scratch.primary_hits.is_empty());
}

#[test]
fn a_lamp_sequence_and_a_laser_sweep_at_one_view_are_bit_identical() {
    // `bumps` has relief, shadows, a specular lobe and (preview) the bounce pass.
    let rig = rig(BUILTIN_LIGHTSTAGE, "bumps", 0.0);
    let view = world("bumps", 30.0);
    let worlds = [
        lamp(view.clone(), "lamp1"),
        lamp(view.clone(), "lamp5"),
        laser(view.clone(), 2.0),
        laser(view.clone(), 1.0),
        laser(view.clone(), -3.0),
        view.clone(),
    ];
    for quality in [Quality::Preview, Quality::Standard] {
        same_with_and_without_kept_hits(&rig, quality, &worlds);
    }
}

/// The table a lamp frame records as it shades holds the hits and bounds a laser frame's
/// table, built before shading, holds for the same view, bit for bit, and the normals the
/// renderer computes.
#[test]
fn a_lamp_frames_recorded_table_is_the_one_a_build_makes() {
    let rig = rig(BUILTIN_LIGHTSTAGE, "bumps", 0.0);
    let view = world("bumps", 30.0);
    let recorder = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    let builder = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    for cam in &rig.cameras {
        recorder
            .render(&lamp(view.clone(), "lamp1"), &cam.id, 0.02, 1.0, 1)
            .expect("render");
        builder
            .render(&laser(view.clone(), 2.0), &cam.id, 0.02, 1.0, 1)
            .expect("render");
    }
    let recorded = recorder.primary_hits.held();
    let built = builder.primary_hits.held();
    assert_eq!(recorded.len(), rig.cameras.len(), "one table a camera");
    for ((key, a), (other, b)) in recorded.iter().zip(&built) {
        assert_eq!(key, other);
        assert!(a.same_hits(b), "{key}");
        assert!(a.normal(0, 0, 0).is_some() && b.normal(0, 0, 0).is_none());
    }
}

/// The exposures of an HDR bracket share one trace: every frame is bit-identical to one
/// traced on its own, and a world that differs in anything but the time is traced again.
#[test]
fn a_brackets_exposures_share_one_trace_and_stay_bit_identical() {
    let rig = rig(BUILTIN_LIGHTSTAGE, "bumps", 0.0);
    let kept = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    let mut scratch = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    scratch.radiance = kept_radiance::KeptRadiance::with_budget(0);
    let lit = lamp(world("bumps", 30.0), "lamp1");
    let cameras = rig.cameras.len() as u64;
    let mut first = Vec::new();
    for (i, exposure_s) in [0.005, 0.02, 0.08].into_iter().enumerate() {
        let at = WorldSnapshot {
            rig_time_s: 1.0 + 0.1 * i as f64,
            ..lit.clone()
        };
        for cam in &rig.cameras {
            let a = kept
                .render(&at, &cam.id, exposure_s, 1.0, 7)
                .expect("render");
            let b = scratch
                .render(&at, &cam.id, exposure_s, 1.0, 7)
                .expect("render");
            assert!(a.pixels == b.pixels, "exposure {exposure_s}, {}", cam.id);
            assert_eq!(a.notes, b.notes, "exposure {exposure_s}, {}", cam.id);
            if i == 0 {
                first.push(a.pixels);
            } else {
                assert!(first.iter().all(|p| *p != a.pixels), "the exposure shows");
            }
        }
    }
    assert_eq!(kept.radiance_reused(), 2 * cameras);
    assert_eq!(scratch.radiance_reused(), 0);
    // Another lamp, a lamp still warming up, another turntable angle, the laser, a dark
    // frame: each traced anew.
    let mut warming = lit.clone();
    warming.lamps.insert("lamp1".into(), 0.5);
    let others = [
        lamp(world("bumps", 30.0), "lamp2"),
        warming,
        lamp(world("bumps", 31.0), "lamp1"),
        laser(lit.clone(), 1.0),
    ];
    for (i, other) in others.iter().enumerate() {
        let a = kept.render(other, "cam1", 0.02, 1.0, 3).expect("render");
        let b = scratch.render(other, "cam1", 0.02, 1.0, 3).expect("render");
        assert!(a.pixels == b.pixels, "world {i}");
    }
    for _ in 0..2 {
        kept.render(&lit, "cam1", 0.0, 1.0, 3).expect("dark frame");
    }
    assert_eq!(kept.radiance_reused(), 2 * cameras, "nothing else reused");
}

#[test]
fn new_views_a_distorted_lens_and_a_placed_fixture_are_bit_identical() {
    let rig = rig(BUILTIN_LIGHTSTAGE, "cavity", -0.12);
    let mut placed = laser(world("cavity", 15.0), 0.5);
    placed.fixture_pose.tilt_deg = 10.0;
    placed.fixture_pose.x_mm = 3.0;
    let worlds = [
        laser(world("cavity", 0.0), 0.5),
        laser(world("cavity", 15.0), 0.5),
        placed,
        lamp(world("cavity", 15.0), "lamp3"),
    ];
    same_with_and_without_kept_hits(&rig, Quality::Preview, &worlds);
}

#[test]
fn the_reflectometer_tube_moving_over_the_sample_is_bit_identical() {
    // The tube's body blocks camera rays where it passes: its position is part of the view.
    let rig = rig(BUILTIN_REFLECTOMETER, "weave", 0.0);
    let worlds: Vec<WorldSnapshot> = [0.0, 120.0, 120.0, 200.0]
        .into_iter()
        .map(|cart_mm| WorldSnapshot {
            cart_mm,
            ..lamp(world("weave", 0.0), "tube")
        })
        .collect();
    same_with_and_without_kept_hits(&rig, Quality::Preview, &worlds);
}

/// A sweep frame at one view skips most of its pixels as black, and only black ones: its
/// noise-free radiance is bit-identical to a frame rendered from scratch.
#[test]
fn a_sweep_frame_skips_most_of_its_pixels_and_only_black_ones() {
    let mut rig = rig(BUILTIN_LIGHTSTAGE, "bumps", 0.0);
    for c in &mut rig.cameras {
        c.width = 160;
        c.height = 120;
    }
    let kept = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    let mut scratch = Renderer::with_knobs(&rig, Quality::Preview.knobs()).expect("renderer");
    scratch.primary_hits = primary_hits::PrimaryHits::with_budget(0);
    let view = world("bumps", 30.0);
    let spans = (rig.cameras.len() * 120 * 160usize.div_ceil(primary_hits::SPAN as usize)) as u64;
    for tilt in [4.0, 2.0, 0.0, -2.0, -4.0] {
        let before = kept.dark_spans_skipped();
        for cam in &rig.cameras {
            let w = laser(view.clone(), tilt);
            let a = kept.radiance(&w, &cam.id).expect("render");
            let b = scratch.radiance(&w, &cam.id).expect("render");
            assert!(a.rgb == b.rgb, "tilt {tilt}, {}: radiance differs", cam.id);
            assert!(
                a.rgb.iter().any(|&v| v > 0.0),
                "tilt {tilt}, {}: the line",
                cam.id
            );
        }
        let skipped = kept.dark_spans_skipped() - before;
        // A laser frame keeps its view's hits at first sight: every frame skips what the
        // sheet cannot reach.
        assert!(
            skipped * 2 > spans,
            "tilt {tilt}: {skipped} of {spans} runs skipped"
        );
    }
    assert_eq!(scratch.dark_spans_skipped(), 0);
}
