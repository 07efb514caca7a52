//! The "as built" rig: the small deviations a real rig has from its drawing, drawn once per
//! rig from a seed so that calibration has something real to find. Each camera's focal length,
//! principal point, lens distortion and pose differ from nominal, each channel has its own
//! response curve, and each lamp its own intensity and colour. The draws are the simulator's
//! ground truth: the renderer uses them, `as_built.json` beside a run records them for
//! `stagehand evaluate`, and processing never reads them.
//!
//! Tolerances follow a machine-vision build like the seed's: focal length ±1 %, principal
//! point ±8 px, mild barrel distortion, cameras within ±3 mm and ±0.5° of their mounts,
//! lamps ±15 % in output and ±7 % per channel in colour.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use stagehand_devices::rig::{CameraSpec, RigSpec};

use crate::render::geometry::{CameraPose, ToSample};
use crate::render::rng::{hash3, mix64};
use crate::render::sensor::Response;

/// How strongly non-linear the drawn camera responses are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResponseStyle {
    #[default]
    /// Scientific cameras: y = x(1 − c + c·x) with c drawn per channel in [0, 0.08].
    Gentle,
    /// The seed's 8-bit consumer cameras: y = x^(1/γ) with γ drawn per channel in [2.0, 2.4].
    Strong,
}

/// The `[sim.as_built]` settings: draw deviations with `seed` in `response` style.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AsBuiltSpec {
    /// Seed of the draws (the same seed, the same rig).
    pub seed: u64,
    /// Response style of the cameras (`gentle` unless set).
    #[serde(default)]
    pub response: ResponseStyle,
}

/// One camera's deviations from its rig-file description.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraAsBuilt {
    /// Focal length relative to nominal.
    pub focal_scale: f64,
    /// Principal point offset added to the rig file's, pixels (x right, y down).
    pub principal_offset_px: [f64; 2],
    /// Brown–Conrady k1, k2, p1, p2, k3 replacing the rig file's (`None` keeps them).
    pub lens: Option<[f64; 5]>,
    /// Extra rotation of the camera about its right, up and forward axes, degrees.
    pub rotation_deg: [f64; 3],
    /// Offset of the camera's centre in the world frame, mm.
    pub position_mm: [f64; 3],
    /// Response per channel: gentle curvatures or gammas.
    pub response: [f32; 3],
    /// Whether `response` holds gammas (strong style) rather than curvatures.
    pub gamma: bool,
}

impl CameraAsBuilt {
    /// The nominal camera: no deviation and the default response.
    pub fn nominal() -> CameraAsBuilt {
        CameraAsBuilt {
            focal_scale: 1.0,
            principal_offset_px: [0.0; 2],
            lens: None,
            rotation_deg: [0.0; 3],
            position_mm: [0.0; 3],
            response: [crate::render::sensor::RESPONSE_CURVATURE as f32; 3],
            gamma: false,
        }
    }

    /// The sensor response.
    pub fn sensor_response(&self) -> Response {
        if self.gamma {
            Response::Gamma(self.response)
        } else {
            Response::Gentle(self.response)
        }
    }
}

impl CameraAsBuilt {
    /// `nominal` with this camera's focal length, principal point and lens.
    pub fn spec(&self, nominal: &CameraSpec) -> CameraSpec {
        let half_width = 0.5 * f64::from(nominal.width);
        let focal = half_width / (0.5 * nominal.fov_deg.to_radians()).tan() * self.focal_scale;
        let [k1, k2, p1, p2, k3] = self
            .lens
            .unwrap_or([nominal.k1, nominal.k2, nominal.p1, nominal.p2, nominal.k3]);
        CameraSpec {
            // Exactly the rig file's for a nominal camera, so its frames stay bit for bit.
            fov_deg: if self.focal_scale == 1.0 {
                nominal.fov_deg
            } else {
                2.0 * (half_width / focal).atan().to_degrees()
            },
            cx: nominal.cx + self.principal_offset_px[0],
            cy: nominal.cy + self.principal_offset_px[1],
            k1,
            k2,
            p1,
            p2,
            k3,
            ..nominal.clone()
        }
    }

    /// The camera as built, with the turntable at `to_sample`.
    pub fn pose(&self, nominal: &CameraSpec, to_sample: ToSample) -> CameraPose {
        CameraPose::mounted(
            &self.spec(nominal),
            self.rotation_deg,
            self.position_mm,
            to_sample,
        )
    }
}

/// The laser unit's deviations on one mount: set on the light arc a little off the marked
/// elevation and the arc's azimuth, with the tilt axis's zero off, and rolled about its
/// untilted central ray (tilt axis and fan together). What a laser-plane calibration finds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LaserAsBuilt {
    /// Added to the mount's elevation, degrees.
    pub elevation_deg: f64,
    /// Added to the light arc's azimuth, degrees.
    pub azimuth_deg: f64,
    /// Added to the tilt axis's angle, degrees.
    pub tilt_zero_deg: f64,
    /// Roll of the unit about its central ray, degrees.
    pub roll_deg: f64,
}

impl LaserAsBuilt {
    /// The unit exactly where the script puts it.
    pub fn nominal() -> LaserAsBuilt {
        LaserAsBuilt {
            elevation_deg: 0.0,
            azimuth_deg: 0.0,
            tilt_zero_deg: 0.0,
            roll_deg: 0.0,
        }
    }
}

/// One lamp's deviations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LampAsBuilt {
    /// Output relative to nominal.
    pub intensity: f64,
    /// Colour relative to the nominal spectrum, per channel.
    pub rgb: [f64; 3],
}

/// Every camera's and lamp's deviations, by id.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AsBuilt {
    /// The settings they were drawn with (`None`: the nominal rig).
    pub spec: Option<AsBuiltSpec>,
    /// Cameras by id.
    pub cameras: BTreeMap<String, CameraAsBuilt>,
    /// Lamps by id.
    pub lamps: BTreeMap<String, LampAsBuilt>,
}

/// A uniform draw in [lo, hi] from `(seed, id, k)`.
fn draw(seed: u64, id: &str, k: u64, lo: f64, hi: f64) -> f64 {
    let id_hash = id
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| mix64(h ^ u64::from(b)));
    let u = (hash3(seed, id_hash, k, 0x0a5b_0117) >> 11) as f64 / (1u64 << 53) as f64;
    lo + (hi - lo) * u
}

impl AsBuilt {
    /// The nominal rig: every camera and lamp exactly as the rig file says.
    pub fn nominal(rig: &RigSpec) -> AsBuilt {
        AsBuilt {
            spec: None,
            cameras: rig
                .cameras
                .iter()
                .map(|c| (c.id.clone(), CameraAsBuilt::nominal()))
                .collect(),
            lamps: rig
                .lamps
                .iter()
                .map(|l| {
                    (
                        l.id.clone(),
                        LampAsBuilt {
                            intensity: 1.0,
                            rgb: [1.0; 3],
                        },
                    )
                })
                .collect(),
        }
    }

    /// Deviations for every camera and lamp of `rig`, drawn with `spec`.
    pub fn draw(rig: &RigSpec, spec: AsBuiltSpec) -> AsBuilt {
        let s = spec.seed;
        let cameras = rig
            .cameras
            .iter()
            .map(|c| {
                let id = c.id.as_str();
                let d = |k, lo, hi| draw(s, id, k, lo, hi);
                let (response, gamma) = match spec.response {
                    ResponseStyle::Gentle => (
                        [
                            d(20, 0.0, 0.08) as f32,
                            d(21, 0.0, 0.08) as f32,
                            d(22, 0.0, 0.08) as f32,
                        ],
                        false,
                    ),
                    ResponseStyle::Strong => (
                        [
                            d(20, 2.0, 2.4) as f32,
                            d(21, 2.0, 2.4) as f32,
                            d(22, 2.0, 2.4) as f32,
                        ],
                        true,
                    ),
                };
                let camera = CameraAsBuilt {
                    focal_scale: d(1, 0.99, 1.01),
                    principal_offset_px: [d(2, -8.0, 8.0), d(3, -8.0, 8.0)],
                    lens: Some([
                        d(4, -0.12, -0.02),
                        d(5, -0.02, 0.05),
                        d(6, -5e-4, 5e-4),
                        d(7, -5e-4, 5e-4),
                        0.0,
                    ]),
                    rotation_deg: [d(8, -0.5, 0.5), d(9, -0.5, 0.5), d(10, -0.5, 0.5)],
                    position_mm: [d(11, -3.0, 3.0), d(12, -3.0, 3.0), d(13, -3.0, 3.0)],
                    response,
                    gamma,
                };
                (c.id.clone(), camera)
            })
            .collect();
        let lamps = rig
            .lamps
            .iter()
            .map(|l| {
                let id = l.id.as_str();
                let d = |k, lo, hi| draw(s, id, k, lo, hi);
                (
                    l.id.clone(),
                    LampAsBuilt {
                        intensity: d(30, 0.85, 1.15),
                        rgb: [d(31, 0.93, 1.07), d(32, 0.93, 1.07), d(33, 0.93, 1.07)],
                    },
                )
            })
            .collect();
        AsBuilt {
            spec: Some(spec),
            cameras,
            lamps,
        }
    }

    /// The deviations of camera `id` (nominal for an unknown id).
    pub fn camera(&self, id: &str) -> CameraAsBuilt {
        self.cameras
            .get(id)
            .copied()
            .unwrap_or_else(CameraAsBuilt::nominal)
    }

    /// The laser unit's deviations when mounted at `elevation_deg` on the arc: drawn per
    /// mount (each remount sits differently; the same mount, the same draw), nominal for the
    /// nominal rig. Elevation ±0.5°, azimuth ±0.5°, tilt zero ±0.3°, roll ±1°.
    pub fn laser(&self, elevation_deg: f64) -> LaserAsBuilt {
        let Some(spec) = self.spec else {
            return LaserAsBuilt::nominal();
        };
        let id = format!("laser@{:.2}", elevation_deg);
        let d = |k, lo, hi| draw(spec.seed, &id, k, lo, hi);
        LaserAsBuilt {
            elevation_deg: d(40, -0.5, 0.5),
            azimuth_deg: d(41, -0.5, 0.5),
            tilt_zero_deg: d(42, -0.3, 0.3),
            roll_deg: d(43, -1.0, 1.0),
        }
    }

    /// The deviations of lamp `id` (nominal for an unknown id).
    pub fn lamp(&self, id: &str) -> LampAsBuilt {
        self.lamps.get(id).copied().unwrap_or(LampAsBuilt {
            intensity: 1.0,
            rgb: [1.0; 3],
        })
    }
}

impl AsBuilt {
    /// The ground truth of the rig as built, for `as_built.json`: each camera in OpenCV's
    /// convention (world frame at turntable 0°) with its response, and each lamp.
    pub fn truth(&self, rig: &RigSpec) -> Value {
        let cameras: serde_json::Map<String, Value> = rig
            .cameras
            .iter()
            .map(|c| {
                let built = self.camera(&c.id);
                let geometry = built.pose(c, ToSample::new(0.0)).opencv();
                let response = if built.gamma {
                    json!({"kind": "gamma", "gamma": built.response, "formula": "y = x^(1/gamma)"})
                } else {
                    json!({"kind": "gentle", "curvature": built.response, "formula": "y = x(1 - c + c x)"})
                };
                (
                    c.id.clone(),
                    json!({"geometry": geometry, "response": response, "bit_depth": c.bit_depth}),
                )
            })
            .collect();
        json!({
            "spec": self.spec,
            "cameras": cameras,
            "lamps": self.lamps,
            "laser": "drawn per mount elevation from spec.seed: AsBuilt::laser",
        })
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3A;

    use super::*;

    #[test]
    fn the_truth_projects_points_where_the_renderer_does() {
        let rig = stagehand_devices::rig::parse_rig(
            stagehand_devices::rig::BUILTIN_LIGHTSTAGE,
            "lightstage.toml",
        )
        .unwrap();
        let a = AsBuilt::draw(
            &rig,
            AsBuiltSpec {
                seed: 11,
                response: ResponseStyle::Gentle,
            },
        );
        for cam in &rig.cameras {
            let pose = a.camera(&cam.id).pose(cam, ToSample::new(0.0));
            let cv = pose.opencv();
            for p in [[0.0, 0.0, 0.0], [20.0, -15.0, 3.0], [-25.0, 25.0, 0.0]] {
                let Some((x, y)) = pose.project(Vec3A::new(p[0] as f32, p[1] as f32, p[2] as f32))
                else {
                    continue;
                };
                let pc: Vec<f64> = (0..3)
                    .map(|r| {
                        (0..3).map(|c| cv.rotation[r][c] * p[c]).sum::<f64>() + cv.translation[r]
                    })
                    .collect();
                let (u, v) = (pc[0] / pc[2], pc[1] / pc[2]);
                let [k1, k2, p1, p2, k3] = cv.distortion;
                let r2 = u * u + v * v;
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let ud = u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u);
                let vd = v * radial + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v;
                let (px, py) = (cv.fx * ud + cv.cx, cv.fy * vd + cv.cy);
                // The renderer's pixel (x, y) is sampled at (x + 0.5, y + 0.5).
                assert!(
                    (px - (f64::from(x) - 0.5)).abs() < 0.01
                        && (py - (f64::from(y) - 0.5)).abs() < 0.01,
                    "{}: ({px}, {py}) vs ({x}, {y})",
                    cam.id
                );
            }
        }
    }

    #[test]
    fn draws_are_deterministic_within_tolerance_and_differ_per_device() {
        let rig = stagehand_devices::rig::parse_rig(
            stagehand_devices::rig::BUILTIN_LIGHTSTAGE,
            "lightstage.toml",
        )
        .unwrap();
        let spec = AsBuiltSpec {
            seed: 7,
            response: ResponseStyle::Strong,
        };
        let a = AsBuilt::draw(&rig, spec);
        assert_eq!(a, AsBuilt::draw(&rig, spec));
        assert_ne!(a, AsBuilt::draw(&rig, AsBuiltSpec { seed: 8, ..spec }));
        let cams: Vec<&CameraAsBuilt> = a.cameras.values().collect();
        assert_eq!(cams.len(), rig.cameras.len());
        assert_ne!(cams[0], cams[1]);
        for c in cams {
            assert!((0.99..=1.01).contains(&c.focal_scale));
            assert!(c.lens.is_some_and(|l| l[0] < 0.0) && c.gamma);
            assert!(c.response.iter().all(|g| (2.0..=2.4).contains(g)));
        }
        for l in a.lamps.values() {
            assert!((0.85..=1.15).contains(&l.intensity));
        }
        let n = AsBuilt::nominal(&rig);
        let first = &rig.cameras[0];
        assert_eq!(n.camera(&first.id), CameraAsBuilt::nominal());
        assert_eq!(&n.camera(&first.id).spec(first), first);
        // The truth record matches the rendering pose: the nominal camera's centre lies at its
        // rig-file distance, the drawn one within a few mm of it.
        let truth = a.truth(&rig);
        let centre = &truth["cameras"][&first.id]["geometry"]["centre_mm"];
        let r: f64 = (0..3)
            .map(|i| centre[i].as_f64().unwrap().powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((r - first.distance_mm).abs() < 6.0, "{r}");
    }
}
