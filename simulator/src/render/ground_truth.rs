//! Ground truth beside the frames: for every pixel of a camera, what its centre ray hits
//! (distance, normal, material) and the noise-free radiance the sensor integrates.
//!
//! Geometry comes from one ray through each pixel centre (x + 0.5, y + 0.5), lens distortion
//! included, intersected with [`Scene::intersect`] exactly as the frame's rays are; radiance is
//! [`Renderer::radiance`], averaged over the pixel's sub-samples like the frame itself.
//! Background pixels (the ray leaves the turntable, or the reflectometer tube blocks it) carry
//! depth [`BACKGROUND_DEPTH`] = 0 and zero normal and material channels: every value is finite.

use glam::Vec3A;
use rayon::prelude::*;
use serde_json::{Value, json};
use stagehand_devices::ground_truth::{GroundTruthData, GroundTruthPlane};

use super::config::GroundTruthPlanes;
use super::geometry::{RigAngles, ToSample};
use super::material::{Material, Model};
use super::scene::{Hit, Scene, Shading};
use super::{RenderError, Renderer, lights};
use crate::world_snapshot::WorldSnapshot;

/// Depth of a background pixel (no surface along the pixel-centre ray). Real hits are > 0.
pub const BACKGROUND_DEPTH: f32 = 0.0;

/// Channel names of the depth plane (OpenEXR's conventional depth channel).
pub const DEPTH_CHANNELS: [&str; 1] = ["Z"];
/// Channel names of the normal plane: sample-frame x, y, z.
pub const NORMAL_CHANNELS: [&str; 3] = ["X", "Y", "Z"];
/// Channel names of the radiance plane.
pub const RADIANCE_CHANNELS: [&str; 3] = ["R", "G", "B"];
/// Channel names of the material plane, in sample order: diffuse albedo, specular albedo,
/// roughness (αx, αy), anisotropy tangent angle in radians, backlight transmittance,
/// subsurface medium (index + 1, 0 = opaque), reflectance model (index in [`Model`]'s
/// declaration order: 0 lambert, 1 ward, …; the notes name the ones present), mesostructure
/// entrance and exit factors.
pub const MATERIAL_CHANNELS: [&str; 14] = [
    "albedo.R",
    "albedo.G",
    "albedo.B",
    "ks",
    "alpha",
    "alpha_y",
    "tangent_rad",
    "transmittance.R",
    "transmittance.G",
    "transmittance.B",
    "medium",
    "model",
    "meso_in",
    "meso_out",
];

/// Per-pixel ground truth of one camera, row-major from the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruth {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Distance in mm from the camera centre along the unit pixel-centre ray to the first
    /// surface; [`BACKGROUND_DEPTH`] where nothing is hit.
    pub depth_mm: Vec<f32>,
    /// Unit shading normal (xyz) in the sample frame (z up, turning with the turntable);
    /// zero on background.
    pub normal: Vec<f32>,
    /// Noise-free linear RGB radiance in reference units (as [`Renderer::radiance`]).
    pub radiance: Vec<f32>,
    /// [`MATERIAL_CHANNELS`] per pixel; zero on background.
    pub material: Vec<f32>,
    /// What the planes mean (units, frame, sentinel, channels, models present).
    pub notes: Value,
}

impl GroundTruth {
    /// The planes as the device layer carries them (kinds `depth`, `normal`, `radiance`,
    /// `material`, in that order).
    pub fn into_data(self) -> GroundTruthData {
        self.into_data_of(&GroundTruthPlanes::All(true))
    }

    /// The planes of the kinds `wanted` asks for, in [`GroundTruth::into_data`]'s order.
    pub fn into_data_of(self, wanted: &GroundTruthPlanes) -> GroundTruthData {
        let plane = |kind: &str, channels: &[&str], samples: Vec<f32>| GroundTruthPlane {
            kind: kind.to_string(),
            channels: channels.iter().map(|c| c.to_string()).collect(),
            samples,
        };
        GroundTruthData {
            width: self.width,
            height: self.height,
            planes: [
                plane("depth", &DEPTH_CHANNELS, self.depth_mm),
                plane("normal", &NORMAL_CHANNELS, self.normal),
                plane("radiance", &RADIANCE_CHANNELS, self.radiance),
                plane("material", &MATERIAL_CHANNELS, self.material),
            ]
            .into_iter()
            .filter(|p| wanted.wants(&p.kind))
            .collect(),
            notes: self.notes,
        }
    }
}

/// The material channels of a hit, in [`MATERIAL_CHANNELS`] order.
fn material_channels(m: &Material) -> [f32; 14] {
    [
        m.albedo.x,
        m.albedo.y,
        m.albedo.z,
        m.ks,
        m.alpha,
        m.alpha_y,
        m.tangent_rad,
        m.transmittance.x,
        m.transmittance.y,
        m.transmittance.z,
        f32::from(m.medium),
        f32::from(m.model as u8),
        m.meso_in,
        m.meso_out,
    ]
}

/// Zeroes anything non-finite, so every ground-truth value is a finite number.
fn finite(v: f32) -> f32 {
    if v.is_finite() { v } else { 0.0 }
}

impl Renderer {
    /// Ground truth of what camera `camera_id` sees of `world`: depth, normals and material
    /// along each pixel-centre ray, and the noise-free radiance. Deterministic.
    pub fn ground_truth(
        &self,
        world: &WorldSnapshot,
        camera_id: &str,
    ) -> Result<GroundTruth, RenderError> {
        self.ground_truth_of(world, camera_id, &GroundTruthPlanes::All(true))
    }

    /// [`Renderer::ground_truth`] for the planes `wanted` asks for: without radiance, no
    /// second render (the radiance plane is then empty).
    pub fn ground_truth_of(
        &self,
        world: &WorldSnapshot,
        camera_id: &str,
        wanted: &GroundTruthPlanes,
    ) -> Result<GroundTruth, RenderError> {
        let (radiance, render_notes) = if wanted.wants("radiance") {
            let r = self.radiance(world, camera_id)?;
            (r.rgb.into_iter().map(finite).collect(), r.notes)
        } else {
            (Vec::new(), Value::Null)
        };
        let cam = self.camera(camera_id)?;
        let sample = self.sample(&world.fixture)?;
        let knobs = self.knobs_for(&sample);
        let angles = RigAngles::from_world(&self.rig, &world.axes);
        let to_sample = ToSample::placed(angles.turntable_deg, &world.fixture_pose);
        let pose = self.as_built().camera(&cam.id).pose(cam, to_sample);
        let tubes = lights::tube_bodies(&self.rig, world, to_sample);
        // Geometry only: no lights, no shading, no shadow maps.
        let shading = Shading {
            shadows: false,
            specular: false,
            knobs,
        };
        let scene = Scene::new(&sample, Vec::new(), None, tubes, shading, &|_| None);
        let width = cam.width as usize;
        let hits: Vec<Option<Hit>> = (0..width * cam.height as usize)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % width) as f32 + 0.5, (i / width) as f32 + 0.5);
                scene.intersect(pose.origin, pose.ray(x, y))
            })
            .collect();
        let mut depth_mm = Vec::with_capacity(hits.len());
        let mut normal = Vec::with_capacity(hits.len() * 3);
        let mut material = Vec::with_capacity(hits.len() * MATERIAL_CHANNELS.len());
        let mut models = std::collections::BTreeMap::new();
        for hit in &hits {
            match hit {
                Some(h) => {
                    let n = h.n.normalize_or(Vec3A::Z);
                    depth_mm.push(finite((h.p - pose.origin).length()));
                    normal.extend(n.to_array().map(finite));
                    material.extend(material_channels(&h.material).map(finite));
                    models.insert(h.material.model as u8, h.material.model.name());
                }
                None => {
                    depth_mm.push(BACKGROUND_DEPTH);
                    normal.extend([0.0; 3]);
                    material.extend([0.0; MATERIAL_CHANNELS.len()]);
                }
            }
        }
        let models: serde_json::Map<String, Value> = models
            .into_iter()
            .map(|(index, name)| (index.to_string(), json!(name)))
            .collect();
        let notes = json!({
            "camera": cam.id,
            "fixture": sample.name,
            "rays": "one per pixel centre (x + 0.5, y + 0.5), lens distortion applied",
            "depth": {
                "channels": DEPTH_CHANNELS,
                "unit": "mm along the unit pixel-centre ray from the camera centre",
                "background": BACKGROUND_DEPTH,
                "background_means": "nothing hit: beyond the turntable, or the reflectometer tube in the way",
            },
            "normal": {
                "channels": NORMAL_CHANNELS,
                "frame": "sample frame: z up, x/y turn with the turntable",
                "background": [0.0, 0.0, 0.0],
            },
            "radiance": {
                "channels": RADIANCE_CHANNELS,
                "unit": "linear RGB in reference units (white Lambert under the reference lamp = 1/π), noise-free, averaged over the pixel's sub-samples",
            },
            "material": {
                "channels": MATERIAL_CHANNELS,
                "models": models,
                "default_model": Model::default().name(),
                "background": "all channels 0",
            },
            "render": render_notes,
        });
        Ok(GroundTruth {
            width: cam.width,
            height: cam.height,
            depth_mm,
            normal,
            radiance,
            material,
            notes,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use crate::render::config::SimSpec;
    use stagehand_devices::lens::Intrinsics;
    use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, RigSpec, parse_rig};

    use super::*;
    use crate::render::geometry::CameraPose;

    fn rig(fixture: &str, w: u32, h: u32) -> RigSpec {
        let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "test.toml").expect("built-in rig parses");
        for c in &mut rig.cameras {
            c.width = w;
            c.height = h;
        }
        SimSpec::edit(&mut rig, |s| s.sample = fixture.into()).expect("sim");
        rig
    }

    fn world(fixture: &str, lamps: &[&str]) -> WorldSnapshot {
        WorldSnapshot {
            rig_time_s: 1.0,
            axes: BTreeMap::new(),
            lamps: lamps.iter().map(|id| (id.to_string(), 1.0)).collect(),
            laser: None,
            cart_mm: 0.0,
            fixture: fixture.into(),
            fixture_pose: Default::default(),
        }
    }

    #[test]
    fn depth_normals_and_radiance_describe_the_flat_sample() {
        let rig = rig("flat", 48, 36);
        let renderer = Renderer::new(&rig).expect("renderer");
        let w = world("flat", &["lamp4"]);
        // cam1 sits 5° above the stage: its top rows look past the turntable.
        let gt = renderer.ground_truth(&w, "cam1").expect("ground truth");
        let n = 48 * 36;
        assert_eq!(gt.depth_mm.len(), n);
        assert_eq!(gt.normal.len(), n * 3);
        assert_eq!(gt.radiance.len(), n * 3);
        assert_eq!(gt.material.len(), n * MATERIAL_CHANNELS.len());
        let pose = CameraPose::new(rig.camera("cam1").expect("cam1"), ToSample::new(0.0));
        let (mut hits, mut background) = (0, 0);
        for i in 0..n {
            let d = gt.depth_mm[i];
            assert!(d.is_finite() && d >= 0.0);
            let normal = Vec3A::from_slice(&gt.normal[i * 3..i * 3 + 3]);
            if d == BACKGROUND_DEPTH {
                background += 1;
                assert_eq!(normal, Vec3A::ZERO);
                continue;
            }
            hits += 1;
            // The flat sample and the turntable are the plane z = 0, facing up.
            let (x, y) = ((i % 48) as f32 + 0.5, (i / 48) as f32 + 0.5);
            let p = pose.origin + pose.ray(x, y) * d;
            assert!(p.z.abs() < 1.0e-2, "pixel {i}: {p}");
            assert!((normal - Vec3A::Z).length() < 1.0e-5, "{normal}");
        }
        assert!(
            hits > n / 4 && background > 0,
            "{hits} hits, {background} background"
        );
        assert!(gt.radiance.iter().all(|v| v.is_finite() && *v >= 0.0));
        assert!(gt.radiance.iter().any(|v| *v > 0.0));
        // Radiance is exactly what `radiance()` reports.
        let radiance = renderer.radiance(&w, "cam1").expect("radiance");
        assert_eq!(gt.radiance, radiance.rgb);
        // Deterministic, and the planes go into the device type in a fixed order.
        let again = renderer.ground_truth(&w, "cam1").expect("ground truth");
        assert_eq!(again, gt);
        let data = gt.into_data();
        let kinds: Vec<&str> = data.planes.iter().map(|p| p.kind.as_str()).collect();
        assert_eq!(kinds, ["depth", "normal", "radiance", "material"]);
        assert_eq!(data.check(), Ok(()));
        assert_eq!(data.notes["depth"]["background"], 0.0);
    }

    #[test]
    fn a_tilted_shifted_fixture_lies_in_its_placed_plane_in_the_world() {
        use stagehand_devices::fixture_pose::FixturePose;
        let rig = rig("checkerboard", 48, 36);
        let renderer = Renderer::new(&rig).expect("renderer");
        let pose = FixturePose {
            tilt_deg: 30.0,
            tilt_toward_deg: 120.0,
            turn_deg: 20.0,
            x_mm: 8.0,
            y_mm: -5.0,
            lift_mm: 12.0,
        };
        let mut w = world("checkerboard", &["lamp4"]);
        w.fixture_pose = pose;
        w.axes.insert("turntable".into(), 0.0);
        let gt = renderer.ground_truth(&w, "cam4").expect("ground truth");
        // cam4 in the world frame (turntable at 0°: the world and turntable frames agree).
        let cam = CameraPose::new(rig.camera("cam4").expect("cam4"), ToSample::new(0.0));
        let r = pose.rotation();
        let normal = Vec3A::new(r[0][2] as f32, r[1][2] as f32, r[2][2] as f32);
        let centre = Vec3A::new(8.0, -5.0, 12.0);
        let mut hits = 0;
        for i in 0..48 * 36 {
            let d = gt.depth_mm[i];
            if d == BACKGROUND_DEPTH {
                continue;
            }
            hits += 1;
            let (x, y) = ((i % 48) as f32 + 0.5, (i / 48) as f32 + 0.5);
            let p = cam.origin + cam.ray(x, y) * d;
            let off_plane = normal.dot(p - centre);
            assert!(
                off_plane.abs() < 0.05,
                "pixel {i}: {off_plane} mm off the plane"
            );
        }
        assert!(hits > 48 * 36 / 4, "{hits} hits");
        // Flat and centred renders differently: the placement reaches the renderer.
        let flat = renderer
            .ground_truth(&world("checkerboard", &["lamp4"]), "cam4")
            .expect("flat");
        assert_ne!(flat.depth_mm, gt.depth_mm);
    }

    #[test]
    fn material_channels_follow_the_checkerboard() {
        let renderer = Renderer::new(&rig("checkerboard", 32, 24)).expect("renderer");
        let gt = renderer
            .ground_truth(&world("checkerboard", &[]), "cam4")
            .expect("ground truth");
        let stride = MATERIAL_CHANNELS.len();
        let albedo: Vec<f32> = gt.material.chunks(stride).map(|m| m[0]).collect();
        assert!(albedo.iter().any(|a| *a > 0.5) && albedo.iter().any(|a| *a < 0.1));
        // Unlit: no radiance, but the geometry is there.
        assert!(gt.radiance.iter().all(|v| *v == 0.0));
        assert!(gt.depth_mm.iter().all(|d| *d > 0.0));
        assert_eq!(gt.notes["material"]["models"]["0"], "lambert");
    }

    /// Column of the black/white edge nearest `near` in row `y` of a per-pixel value.
    fn edge_near(values: &[f32], width: usize, y: usize, near: usize) -> Option<usize> {
        let row = &values[y * width..(y + 1) * width];
        (1..width)
            .filter(|&x| (row[x] > 0.3) != (row[x - 1] > 0.3))
            .min_by_key(|&x| x.abs_diff(near))
    }

    #[test]
    fn a_straight_checkerboard_edge_renders_curved_through_a_barrel_lens() {
        let (w, h) = (384u32, 288u32);
        let edges = |k1: f64| {
            let mut rig = rig("checkerboard", w, h);
            let cam = &mut rig.cameras[0];
            (
                cam.elevation_deg,
                cam.azimuth_deg,
                cam.distance_mm,
                cam.fov_deg,
            ) = (90.0, 0.0, 130.0, 30.0);
            cam.k1 = k1;
            Intrinsics::of(cam).check().expect("a valid lens");
            let id = cam.id.clone();
            let renderer = Renderer::new(&rig).expect("renderer");
            let gt = renderer
                .ground_truth(&world("checkerboard", &["lamp8"]), &id)
                .expect("ground truth");
            let albedo: Vec<f32> = gt
                .material
                .chunks(MATERIAL_CHANNELS.len())
                .map(|m| m[0])
                .collect();
            let mid = edge_near(&albedo, w as usize, h as usize / 2, 300).expect("an edge");
            let top = edge_near(&albedo, w as usize, 4, mid).expect("an edge");
            let bottom = edge_near(&albedo, w as usize, h as usize - 5, mid).expect("an edge");
            // The rendered light shows the same edge.
            let green: Vec<f32> = gt.radiance.chunks(3).map(|c| c[1]).collect();
            let bright = green.iter().copied().fold(0.0f32, f32::max);
            let lit: Vec<f32> = green.iter().map(|g| g / bright).collect();
            let lit_mid = edge_near(&lit, w as usize, h as usize / 2, mid).expect("lit edge");
            assert!(
                lit_mid.abs_diff(mid) <= 1,
                "radiance edge {lit_mid}, albedo {mid}"
            );
            (top, mid, bottom)
        };
        let (top, mid, bottom) = edges(0.0);
        assert!(
            top.abs_diff(mid) <= 1 && bottom.abs_diff(mid) <= 1,
            "pinhole: a straight edge stays straight: {top} {mid} {bottom}"
        );
        let (top, mid, bottom) = edges(-1.0);
        assert!(
            mid >= top + 3 && mid >= bottom + 3,
            "barrel: the edge bows outward in the middle row: {top} {mid} {bottom}"
        );
    }
}
