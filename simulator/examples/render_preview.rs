//! Renders a few views of the built-in rigs and writes 8-bit PNG previews (black level
//! removed, sRGB-encoded) to the directory given as the first argument:
//!
//! ```text
//! cargo run --release -p stagehand-simulator --example render_preview -- /tmp/previews [quality]
//! ```
//!
//! The optional second argument overrides the rigs' `sim.quality` (preview, standard,
//! reference); a third keeps only the views whose name contains it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};
use stagehand_simulator::render::config::SimSpec;
use stagehand_simulator::render::{Rendered, Renderer};
use stagehand_simulator::world_snapshot::{LaserBeam, WorldSnapshot};

struct View {
    name: &'static str,
    fixture: &'static str,
    camera: &'static str,
    lamps: &'static [(&'static str, f64)],
    laser: Option<(u32, f64)>,
    turntable_deg: f64,
    light_arc_deg: f64,
    cart_mm: f64,
    exposure_s: f64,
}

const fn view(
    name: &'static str,
    fixture: &'static str,
    camera: &'static str,
    lamps: &'static [(&'static str, f64)],
    exposure_s: f64,
) -> View {
    View {
        name,
        fixture,
        camera,
        lamps,
        laser: None,
        turntable_deg: 0.0,
        light_arc_deg: 0.0,
        cart_mm: 0.0,
        exposure_s,
    }
}

const LIGHTSTAGE_VIEWS: &[View] = &[
    View {
        light_arc_deg: 150.0,
        ..view("bumps_lamp3_cam5", "bumps", "cam5", &[("lamp3", 1.0)], 0.03)
    },
    View {
        light_arc_deg: 150.0,
        ..view(
            "bumps_lamp1_cam5_shadows",
            "bumps",
            "cam5",
            &[("lamp1", 1.0)],
            0.04,
        )
    },
    View {
        light_arc_deg: 90.0,
        ..view(
            "bumps_lamp2_cam1_grazing",
            "bumps",
            "cam1",
            &[("lamp2", 1.0)],
            0.04,
        )
    },
    View {
        light_arc_deg: 180.0,
        ..view(
            "bumps_lamp5_cam8_specular",
            "bumps",
            "cam8",
            &[("lamp5", 1.0)],
            0.03,
        )
    },
    View {
        laser: Some((650, 0.0)),
        ..view("bumps_laser650_cam4", "bumps", "cam4", &[], 0.004)
    },
    View {
        laser: Some((532, 2.0)),
        ..view("planes_laser532_tilt2_cam6", "planes", "cam6", &[], 0.004)
    },
    View {
        laser: Some((473, -1.0)),
        ..view(
            "bumps_laser473_lamp4_cam6",
            "bumps",
            "cam6",
            &[("lamp4", 0.3)],
            0.004,
        )
    },
    View {
        light_arc_deg: 30.0,
        ..view(
            "checkerboard_lamp5_cam5",
            "checkerboard",
            "cam5",
            &[("lamp5", 1.0)],
            0.02,
        )
    },
    View {
        turntable_deg: 20.0,
        ..view(
            "checkerboard_turntable20_cam3",
            "checkerboard",
            "cam3",
            &[("lamp6", 1.0)],
            0.02,
        )
    },
    View {
        light_arc_deg: 20.0,
        ..view(
            "colorchecker_lamp7_cam8",
            "colorchecker",
            "cam8",
            &[("lamp7", 1.0)],
            0.02,
        )
    },
    View {
        light_arc_deg: 120.0,
        ..view("steps_lamp2_cam6", "steps", "cam6", &[("lamp2", 1.0)], 0.03)
    },
    View {
        light_arc_deg: 60.0,
        ..view("weave_lamp3_cam7", "weave", "cam7", &[("lamp3", 1.0)], 0.03)
    },
    View {
        light_arc_deg: 45.0,
        ..view("flat_lamp6_cam7", "flat", "cam7", &[("lamp6", 1.0)], 0.02)
    },
];

const REFLECTOMETER_VIEWS: &[View] = &[
    View {
        cart_mm: 60.0,
        ..view(
            "reflectometer_weave_tube_cart60",
            "weave",
            "cam1",
            &[("tube", 1.0)],
            0.02,
        )
    },
    View {
        cart_mm: 120.0,
        ..view(
            "reflectometer_weave_tube_cart120",
            "weave",
            "cam1",
            &[("tube", 1.0)],
            0.02,
        )
    },
    View {
        cart_mm: 200.0,
        ..view(
            "reflectometer_weave_tube_cart200",
            "weave",
            "cam1",
            &[("tube", 1.0)],
            0.02,
        )
    },
    View {
        cart_mm: 150.0,
        ..view(
            "reflectometer_bumps_tube_cart150",
            "bumps",
            "cam1",
            &[("tube", 1.0)],
            0.02,
        )
    },
    View {
        cart_mm: 0.0,
        ..view(
            "reflectometer_weave_backlight",
            "weave",
            "cam1",
            &[("backlight", 1.0)],
            0.05,
        )
    },
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = std::env::args().nth(1).map(PathBuf::from) else {
        eprintln!("usage: render_preview <output directory>");
        std::process::exit(2);
    };
    std::fs::create_dir_all(&dir)?;
    let quality = std::env::args().nth(2);
    let filter = std::env::args().nth(3).unwrap_or_default();
    for (text, views) in [
        (BUILTIN_LIGHTSTAGE, LIGHTSTAGE_VIEWS),
        (BUILTIN_REFLECTOMETER, REFLECTOMETER_VIEWS),
    ] {
        let mut rig = parse_rig(text, "built-in")?;
        if let Some(q) = &quality {
            SimSpec::edit(&mut rig, |s| s.quality = q.clone())?;
        }
        let renderer = Renderer::new(&rig)?;
        for v in views.iter().filter(|v| v.name.contains(&filter)) {
            let world = WorldSnapshot {
                rig_time_s: 0.0,
                axes: BTreeMap::from([
                    ("turntable".to_string(), v.turntable_deg),
                    ("light_arc".to_string(), v.light_arc_deg),
                ]),
                lamps: v
                    .lamps
                    .iter()
                    .map(|(id, out)| (id.to_string(), *out))
                    .collect(),
                laser: v.laser.map(|(nm, tilt)| LaserBeam {
                    colour_nm: nm,
                    tilt_deg: tilt,
                    mount_elevation_deg: 45.0,
                }),
                cart_mm: v.cart_mm,
                fixture: v.fixture.to_string(),
                fixture_pose: Default::default(),
            };
            let frame = renderer.render(&world, v.camera, v.exposure_s, 1.0, 1)?;
            let path = dir.join(format!("{}.png", v.name));
            write_png(
                &path,
                &rig,
                v.camera,
                renderer.black_level_dn(v.camera),
                &frame,
            )?;
            println!("{} — {}", path.display(), frame.notes["effects"]);
        }
    }
    Ok(())
}

fn write_png(
    path: &Path,
    rig: &RigSpec,
    camera: &str,
    black: f64,
    frame: &Rendered,
) -> Result<(), Box<dyn std::error::Error>> {
    let cam = rig.camera(camera).ok_or("camera vanished")?;
    let max = ((1u32 << cam.bit_depth) - 1) as f64;
    let bytes: Vec<u8> = frame
        .pixels
        .iter()
        .map(|&dn| {
            let x = ((dn as f64 - black) / (max - black)).clamp(0.0, 1.0);
            let s = if x <= 0.003_130_8 {
                12.92 * x
            } else {
                1.055 * x.powf(1.0 / 2.4) - 0.055
            };
            (s * 255.0).round() as u8
        })
        .collect();
    let mut encoder = png::Encoder::new(BufWriter::new(File::create(path)?), cam.width, cam.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(&bytes)?;
    Ok(())
}
