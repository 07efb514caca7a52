//! The scene a sweep renders: the built-in light stage with one camera at a reduced
//! resolution, a fixture on the turntable, and a fixed lighting state (lamps lit at full
//! output, light arc and turntable at set angles).

use std::collections::BTreeMap;

use stagehand_devices::rig::{AxisRole, BUILTIN_LIGHTSTAGE, LampKind, RigSpec, parse_rig};

use super::TradeoffError;
use stagehand_simulator::render::{RenderError, Renderer, quality::Quality};
use stagehand_simulator::world_snapshot::{LaserBeam, WorldSnapshot};

/// Largest camera edge accepted, in pixels.
pub const MAX_EDGE_PX: u32 = 4096;

/// What to render: scene, camera, resolution and lighting.
#[derive(Debug, Clone, PartialEq)]
pub struct SetupOptions {
    /// Fixture name the renderer accepts (`bumps`, `weave`, `steps`, `flat`, ...).
    pub scene: String,
    /// Camera id on the rig.
    pub camera: String,
    /// Camera width in pixels (the field of view is kept; height is set independently).
    pub width: u32,
    /// Camera height in pixels.
    pub height: u32,
    /// Lamps lit at full output.
    pub lamps: Vec<String>,
    /// Light-arc angle in degrees.
    pub light_arc_deg: f64,
    /// Turntable angle in degrees.
    pub turntable_deg: f64,
    /// The rig's line laser on in this colour (nm), untilted at its mount elevation; `None`
    /// for no laser.
    pub laser_nm: Option<u32>,
}

impl Default for SetupOptions {
    /// `bumps` seen by cam4 (35° elevation) at 256×192, lit by lamp2 (20°, long shadows) and
    /// lamp5 (50°) with the light arc at 60° (away from the mirror direction) and the
    /// turntable at 0°.
    fn default() -> SetupOptions {
        SetupOptions {
            scene: "bumps".into(),
            camera: "cam4".into(),
            width: 256,
            height: 192,
            lamps: vec!["lamp2".into(), "lamp5".into()],
            light_arc_deg: 60.0,
            turntable_deg: 0.0,
            laser_nm: None,
        }
    }
}

/// A rig with the camera resized and the world to render.
#[derive(Debug, Clone, PartialEq)]
pub struct Setup {
    /// The light stage, with `camera` at the requested resolution.
    pub rig: RigSpec,
    /// The camera that renders.
    pub camera: String,
    /// The lit world.
    pub world: WorldSnapshot,
    /// The same world with every lamp off (used to build the sample before timing).
    pub dark: WorldSnapshot,
    /// The options this was built from.
    pub options: SetupOptions,
}

impl Setup {
    /// Builds the setup on the built-in light stage, checking the camera, size, lamps and that
    /// the renderer knows the scene.
    pub fn new(options: SetupOptions) -> Result<Setup, TradeoffError> {
        let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").map_err(|e| {
            TradeoffError::InvalidInput {
                what: "built-in light stage".into(),
                expected: "a valid rig".into(),
                got: e.to_string(),
            }
        })?;
        Setup::on_rig(rig, options)
    }

    /// As [`Setup::new`] on any rig.
    pub fn on_rig(mut rig: RigSpec, options: SetupOptions) -> Result<Setup, TradeoffError> {
        for (what, v) in [("--width", options.width), ("--height", options.height)] {
            if !(1..=MAX_EDGE_PX).contains(&v) {
                return Err(TradeoffError::InvalidInput {
                    what: what.into(),
                    expected: format!("a number of pixels from 1 to {MAX_EDGE_PX}"),
                    got: v.to_string(),
                });
            }
        }
        for (what, v) in [
            ("light arc angle", options.light_arc_deg),
            ("turntable angle", options.turntable_deg),
        ] {
            if !v.is_finite() {
                return Err(TradeoffError::InvalidInput {
                    what: what.into(),
                    expected: "finite degrees".into(),
                    got: v.to_string(),
                });
            }
        }
        let known = rig.cameras.iter().map(|c| c.id.clone()).collect::<Vec<_>>();
        let Some(cam) = rig.cameras.iter_mut().find(|c| c.id == options.camera) else {
            return Err(TradeoffError::InvalidInput {
                what: "--camera".into(),
                expected: format!("one of {}", known.join(", ")),
                got: format!("`{}`", options.camera),
            });
        };
        cam.width = options.width;
        cam.height = options.height;
        let mut lamps = BTreeMap::new();
        for id in &options.lamps {
            match rig.lamp(id) {
                Some(l) if l.kind == LampKind::Halogen => {
                    lamps.insert(id.clone(), 1.0);
                }
                _ => {
                    return Err(TradeoffError::InvalidInput {
                        what: "lamp".into(),
                        expected: "a halogen lamp of the rig".into(),
                        got: format!("`{id}`"),
                    });
                }
            }
        }
        let mut axes = BTreeMap::new();
        for (role, deg) in [
            (AxisRole::Turntable, options.turntable_deg),
            (AxisRole::LightArc, options.light_arc_deg),
        ] {
            if let Some(a) = rig.axis_with_role(role) {
                axes.insert(a.id.clone(), deg);
            }
        }
        let laser = match (options.laser_nm, &rig.laser) {
            (None, _) => None,
            (Some(nm), Some(spec)) if spec.colours_nm.contains(&nm) => Some(LaserBeam {
                colour_nm: nm,
                tilt_deg: 0.0,
                mount_elevation_deg: spec.mount_elevation_deg,
            }),
            (Some(nm), spec) => {
                return Err(TradeoffError::InvalidInput {
                    what: "--laser".into(),
                    expected: match spec {
                        Some(s) => format!("one of the laser's colours {:?} nm", s.colours_nm),
                        None => "a rig with a line laser".into(),
                    },
                    got: format!("{nm} nm"),
                });
            }
        };
        let world = WorldSnapshot {
            rig_time_s: 0.0,
            axes,
            lamps,
            laser,
            cart_mm: 0.0,
            fixture: options.scene.clone(),
            fixture_pose: Default::default(),
        };
        let dark = WorldSnapshot {
            lamps: BTreeMap::new(),
            laser: None,
            ..world.clone()
        };
        let setup = Setup {
            rig,
            camera: options.camera.clone(),
            world,
            dark,
            options,
        };
        // A dark frame at the coarsest relief builds the sample: an unknown scene fails here.
        let mut coarse = Quality::Preview.knobs();
        coarse.relief_mm = 5.0;
        let probe = Renderer::with_knobs(&setup.rig, coarse)?;
        match probe.radiance(&setup.dark, &setup.camera) {
            Ok(_) => Ok(setup),
            Err(RenderError::UnknownFixture(name)) => Err(TradeoffError::UnknownScene {
                scene: name,
                detail: RenderError::UnknownFixture(setup.options.scene.clone()).to_string(),
            }),
            Err(e) => Err(e.into()),
        }
    }

    /// Pixels × channels of one image.
    pub fn values(&self) -> usize {
        self.options.width as usize * self.options.height as usize * 3
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_are_named() {
        let bad = |o: SetupOptions, needle: &str| {
            let e = Setup::new(o).expect_err(needle);
            assert!(e.is_bad_input(), "{e}");
            assert!(e.to_string().contains(needle), "{e}");
        };
        bad(
            SetupOptions {
                scene: "teapot".into(),
                ..SetupOptions::default()
            },
            "teapot",
        );
        bad(
            SetupOptions {
                camera: "cam9".into(),
                ..SetupOptions::default()
            },
            "cam9",
        );
        bad(
            SetupOptions {
                width: 0,
                ..SetupOptions::default()
            },
            "--width",
        );
        bad(
            SetupOptions {
                lamps: vec!["lamp42".into()],
                ..SetupOptions::default()
            },
            "lamp42",
        );
    }

    #[test]
    fn world_has_the_lamps_and_angles() {
        let s = Setup::new(SetupOptions {
            width: 8,
            height: 6,
            ..SetupOptions::default()
        })
        .expect("valid");
        assert_eq!(s.world.lamps.len(), 2);
        assert_eq!(s.world.axes.get("light_arc"), Some(&60.0));
        assert!(s.dark.lamps.is_empty());
        assert_eq!(s.values(), 8 * 6 * 3);
        assert_eq!(s.rig.camera("cam4").map(|c| c.width), Some(8));
    }
}
