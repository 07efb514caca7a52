//! Renderer-level tests on small cameras, by topic; the helpers they share.

use std::collections::BTreeMap;

use crate::render::config::SimSpec;
use glam::Vec3A;
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};

use super::*;
use crate::render::geometry::CameraPose;
use crate::world_snapshot::LaserBeam;

const W: u32 = 64;
const H: u32 = 48;

mod adaptive;
mod laser;
mod scene;
mod sensor;
mod shadows;
mod transport;

pub(super) fn small(text: &str, fixture: &str) -> RigSpec {
    let mut rig = parse_rig(text, "test.toml").expect("built-in rig parses");
    for c in &mut rig.cameras {
        c.width = W;
        c.height = H;
    }
    SimSpec::edit(&mut rig, |s| s.sample = fixture.into()).expect("sim");
    rig
}

pub(super) fn lightstage(fixture: &str) -> (Renderer, RigSpec) {
    let rig = small(BUILTIN_LIGHTSTAGE, fixture);
    (Renderer::new(&rig).expect("renderer"), rig)
}

pub(super) fn world(fixture: &str, lamps: &[(&str, f64)]) -> WorldSnapshot {
    WorldSnapshot {
        rig_time_s: 1.0,
        axes: BTreeMap::new(),
        lamps: lamps.iter().map(|(id, v)| (id.to_string(), *v)).collect(),
        laser: None,
        cart_mm: 0.0,
        fixture: fixture.into(),
        fixture_pose: Default::default(),
    }
}

/// Mean of (DN − black) over channel `c` of the pixels where `keep(x, y)`.
pub(super) fn mean_signal(
    r: &Rendered,
    black: f64,
    c: usize,
    keep: impl Fn(u32, u32) -> bool,
) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for y in 0..H {
        for x in 0..W {
            if keep(x, y) {
                sum += r.pixels[((y * W + x) * 3) as usize + c] as f64 - black;
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

pub(super) fn centre(x: u32, y: u32) -> bool {
    (16..48).contains(&x) && (12..36).contains(&y)
}

/// Row of the brightest red pixel in column `x`.
pub(super) fn brightest_row(r: &Rendered, x: u32) -> u32 {
    (0..H)
        .max_by_key(|&y| r.pixels[((y * W + x) * 3) as usize])
        .unwrap_or(0)
}
