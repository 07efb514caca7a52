//! The sweep's scene for Mitsuba 3: what `bench/peer/mitsuba_render.py` loads.
//!
//! Everything is in the renderer's sample frame (millimetres, turntable rotation applied to
//! the devices), so the numbers are the renderer's own:
//! - `sample.ply`: the relief grid as a triangle mesh (two triangles per cell, the renderer's
//!   per-vertex shading normals, uv over the square) plus the vertical walls where the relief
//!   meets the turntable above height 0; a flat sample is one quad;
//! - `albedo.pfm`: the Lambert albedo at every texel centre (linear float RGB, nearest
//!   filtering; texture row j is the texel row at y index j, v = (y + size/2) / size);
//! - `turntable.ply`: the turntable disk with the sample's square cut out (no coplanar faces);
//! - `scene.json`: camera (origin, target, up, horizontal fov, resolution; pixel centres at
//!   half-integers like the renderer's pinhole), lit lamps as sphere emitters of the halogen's
//!   radius with radiance = intensity / (π r²) × colour, or point emitters when the knobs
//!   use point lights, and the integrator depth.
//!
//! Radiometric scale: the renderer's irradiance from a lamp is I·cosθ/r² with I in reference
//! units × mm²; a sphere of radius ρ and radiance L has intensity π ρ² L in every direction,
//! so both renderers produce radiance in the same units. The Lambert term is exported, and a
//! GGX lobe shared by the whole sample (`ggx`: α, F0 and the dielectric's η), which the peer
//! script renders as our sum of Lambert and lobe (a `blendbsdf` of `diffuse` on
//! `albedo_doubled.pfm` and a GGX `roughconductor` of that η, each doubled) or, asked, as
//! Mitsuba's `roughplastic`; any other lobe (Ward, Blinn–Phong) is dropped and reported
//! (`lambert` false, `ggx` none).
//!
//! The line laser (with every lamp off) is exported as a `sheet` emitter: the sheet's apex,
//! central ray, normal, 1/e² half-width, peak irradiance at its reference distance, fan
//! half-angle and camera colour, with the distances and fan angle it must cover on the
//! turntable. The peer bakes it into Mitsuba's `projector` (a texture across and along the
//! fan, each texel set from the sheet's irradiance where its ray first lands). Under the laser
//! the albedo is exported as the reflectance at the laser's wavelength (the renderer's
//! `dot(albedo, reflect_weights)`) in every channel, the sheet carrying the camera colour.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use glam::Vec3A;
use serde::Serialize;
use serde_json::json;

use super::{Setup, TradeoffError};
use stagehand_simulator::render::RenderError;
use stagehand_simulator::render::config::SimSpec;
use stagehand_simulator::render::geometry::{RigAngles, ToSample};
use stagehand_simulator::render::laser::{FAN_HALF_ANGLE_DEG, LaserSheet};
use stagehand_simulator::render::lights::{self, Emitter, HALOGEN_RADIUS_MM, TURNTABLE_RADIUS_MM};
use stagehand_simulator::render::material::Model;
use stagehand_simulator::render::sample::Sample;

/// Albedo of the turntable around the sample (the renderer's dark grey).
pub const TURNTABLE_ALBEDO: f32 = 0.05;
/// Segments of the turntable's outer circle (a multiple of 8 puts vertices on the square's
/// corners).
const TURNTABLE_SEGMENTS: usize = 256;
/// Texel spacing used for samples without a relief grid, mm.
const FLAT_TEXEL_MM: f32 = 0.1;

/// A triangle mesh with per-vertex normals and uv.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Positions.
    pub positions: Vec<[f32; 3]>,
    /// Unit shading normals.
    pub normals: Vec<[f32; 3]>,
    /// Texture coordinates.
    pub uvs: Vec<[f32; 2]>,
    /// Triangles, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
}

impl Mesh {
    fn vertex(&mut self, p: Vec3A, n: Vec3A, uv: [f32; 2]) -> u32 {
        self.positions.push(p.to_array());
        self.normals.push(n.to_array());
        self.uvs.push(uv);
        (self.positions.len() - 1) as u32
    }

    /// Binary little-endian PLY bytes (x y z nx ny nz u v; faces as uchar-counted int lists).
    pub fn to_ply(&self) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat binary_little_endian 1.0\ncomment stagehand tradeoff export, mm\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\nproperty float u\n\
             property float v\nelement face {}\nproperty list uchar int vertex_indices\n\
             end_header\n",
            self.positions.len(),
            self.faces.len()
        )
        .into_bytes();
        out.reserve(self.positions.len() * 32 + self.faces.len() * 13);
        for ((p, n), uv) in self.positions.iter().zip(&self.normals).zip(&self.uvs) {
            for v in p.iter().chain(n).chain(uv) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        for f in &self.faces {
            out.push(3);
            for i in f {
                out.extend_from_slice(&(*i as i32).to_le_bytes());
            }
        }
        out
    }
}

/// The sample's top surface and walls, and the albedo texture's size (texels per side).
pub fn sample_mesh(sample: &Sample) -> (Mesh, usize) {
    let size = sample.size_mm;
    let h = 0.5 * size;
    let uv = |x: f32, y: f32| [(x + h) / size, (y + h) / size];
    let mut mesh = Mesh::default();
    let Some(grid) = &sample.grid else {
        let corners = [(-h, -h), (h, -h), (h, h), (-h, h)];
        for (x, y) in corners {
            mesh.vertex(Vec3A::new(x, y, 0.0), Vec3A::Z, uv(x, y));
        }
        mesh.faces = vec![[0, 1, 2], [0, 2, 3]];
        let n = ((size / FLAT_TEXEL_MM).ceil() as usize).max(1);
        return (mesh, n);
    };
    let n = grid.cells();
    let w = n + 1;
    for j in 0..w {
        for i in 0..w {
            let (p, nrm) = grid.vertex(i, j);
            mesh.vertex(p, nrm, uv(p.x, p.y));
        }
    }
    for j in 0..n {
        for i in 0..n {
            let k = (j * w + i) as u32;
            let (k1, kw, kw1) = (k + 1, k + w as u32, k + w as u32 + 1);
            mesh.faces.push([k, k1, kw1]);
            mesh.faces.push([k, kw1, kw]);
        }
    }
    if grid.edge_max() > 0.0 {
        // Walk the border counter-clockwise seen from above; the outward normal is d × z.
        let border: Vec<(usize, usize)> = (0..n)
            .map(|i| (i, 0))
            .chain((0..n).map(|j| (n, j)))
            .chain((0..n).map(|i| (n - i, n)))
            .chain((0..n).map(|j| (0, n - j)))
            .collect();
        let half_texel = 0.5 / n as f32;
        let inset = |t: [f32; 2]| t.map(|c| c.clamp(half_texel, 1.0 - half_texel));
        for (s, &(i, j)) in border.iter().enumerate() {
            let (ni, nj) = border[(s + 1) % border.len()];
            let (a, _) = grid.vertex(i, j);
            let (b, _) = grid.vertex(ni, nj);
            if a.z <= 1.0e-6 && b.z <= 1.0e-6 {
                continue;
            }
            let d = (b - a).normalize_or(Vec3A::X);
            let out = d.cross(Vec3A::Z);
            let ground = |p: Vec3A| Vec3A::new(p.x, p.y, 0.0);
            let ba = mesh.vertex(ground(a), out, inset(uv(a.x, a.y)));
            let bb = mesh.vertex(ground(b), out, inset(uv(b.x, b.y)));
            let tb = mesh.vertex(b, out, inset(uv(b.x, b.y)));
            let ta = mesh.vertex(a, out, inset(uv(a.x, a.y)));
            mesh.faces.push([ba, bb, tb]);
            mesh.faces.push([ba, tb, ta]);
        }
    }
    (mesh, n)
}

/// The turntable: an annulus from the sample's square out to the turntable radius at z = 0.
pub fn turntable_mesh(sample_size_mm: f32) -> Mesh {
    let h = 0.5 * sample_size_mm;
    let mut mesh = Mesh::default();
    for k in 0..TURNTABLE_SEGMENTS {
        let a = std::f32::consts::TAU * k as f32 / TURNTABLE_SEGMENTS as f32;
        let (s, c) = a.sin_cos();
        let square = h / c.abs().max(s.abs());
        mesh.vertex(
            Vec3A::new(c * square, s * square, 0.0),
            Vec3A::Z,
            [0.0, 0.0],
        );
        mesh.vertex(
            Vec3A::new(c * TURNTABLE_RADIUS_MM, s * TURNTABLE_RADIUS_MM, 0.0),
            Vec3A::Z,
            [0.0, 0.0],
        );
    }
    let m = TURNTABLE_SEGMENTS as u32;
    for k in 0..m {
        let (i0, o0) = (2 * k, 2 * k + 1);
        let (i1, o1) = (2 * ((k + 1) % m), 2 * ((k + 1) % m) + 1);
        mesh.faces.push([i0, o0, o1]);
        mesh.faces.push([i0, o1, i1]);
    }
    mesh
}

/// Albedo at texel centres of an n × n texture over the sample, rows by y, top row first.
pub fn albedo_texture(sample: &Sample, n: usize) -> Vec<f32> {
    let cell = sample.size_mm / n as f32;
    let origin = -0.5 * sample.size_mm;
    let mut rgb = Vec::with_capacity(n * n * 3);
    for j in 0..n {
        for i in 0..n {
            let x = origin + (i as f32 + 0.5) * cell;
            let y = origin + (j as f32 + 0.5) * cell;
            rgb.extend_from_slice(&sample.material_at(x, y).albedo.to_array());
        }
    }
    rgb
}

/// A sample whose every texel has the same GGX lobe: exported as Mitsuba's `roughplastic`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GgxLobe {
    /// GGX roughness α.
    pub alpha: f32,
    /// Normal-incidence reflectance F0.
    pub f0: f32,
    /// The dielectric's index of refraction with that F0 (air outside).
    pub eta: f32,
}

/// The GGX lobe shared by every texel centre of an `n` × `n` grid over the sample, or `None`
/// when some texel is not GGX or has another α or F0.
pub fn uniform_ggx(sample: &Sample, n: usize) -> Option<GgxLobe> {
    let cell = sample.size_mm / n as f32;
    let origin = -0.5 * sample.size_mm;
    let first = sample.material_at(origin + 0.5 * cell, origin + 0.5 * cell);
    if first.model != Model::Ggx || !(first.ks > 0.0 && first.ks < 1.0) {
        return None;
    }
    for j in 0..n {
        for i in 0..n {
            let m = sample.material_at(
                origin + (i as f32 + 0.5) * cell,
                origin + (j as f32 + 0.5) * cell,
            );
            if m.model != Model::Ggx || m.alpha != first.alpha || m.ks != first.ks {
                return None;
            }
        }
    }
    // F0 = ((η − 1)/(η + 1))², so η = (1 + √F0)/(1 − √F0).
    let r = first.ks.sqrt();
    Some(GgxLobe {
        alpha: first.alpha,
        f0: first.ks,
        eta: (1.0 + r) / (1.0 - r),
    })
}

/// What the export wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Export {
    /// `scene.json`, the file to hand to the Mitsuba script.
    pub scene_json: PathBuf,
    /// Vertices of the sample mesh.
    pub vertices: usize,
    /// Triangles of the sample mesh.
    pub faces: usize,
    /// Albedo texels per side.
    pub texels: usize,
    /// The sample is purely Lambertian (no specular lobe, no subsurface medium).
    pub lambert: bool,
    /// Largest Ward ρs on the sample.
    pub max_ks: f32,
    /// The sample's GGX lobe, exported as `roughplastic` (other lobes are dropped).
    pub ggx: Option<GgxLobe>,
}

/// The laser sheet for the peer: its geometry and radiometry as the renderer uses them, and
/// what it must cover (the turntable, within [`TURNTABLE_RADIUS_MM`] of the rig's centre).
fn sheet_emitter(sheet: &LaserSheet) -> serde_json::Value {
    let apex = sheet.origin.length();
    let reach = TURNTABLE_RADIUS_MM * 1.1;
    let near = (apex - reach).max(1.0);
    json!({
        "type": "sheet",
        "origin": sheet.origin.to_array(),
        "centre": sheet.centre.to_array(),
        "normal": sheet.normal.to_array(),
        "fan_axis": sheet.fan_axis.to_array(),
        "half_width_mm": sheet.half_width_mm,
        "peak": sheet.peak,
        "ref_distance_mm": sheet.ref_distance_mm,
        "rgb": sheet.camera_rgb.to_array(),
        "fan_half_angle_deg": FAN_HALF_ANGLE_DEG,
        "cover_half_angle_deg": (reach / near).atan().to_degrees().min(FAN_HALF_ANGLE_DEG),
        "range_mm": [near, apex + reach],
    })
}

fn put(path: &Path, bytes: &[u8]) -> Result<(), TradeoffError> {
    let mut f = std::fs::File::create(path).map_err(|e| TradeoffError::io(path, e))?;
    f.write_all(bytes).map_err(|e| TradeoffError::io(path, e))
}

/// Writes the scene of `setup` into `dir`: relief at `relief_mm`, lamps as spheres when
/// `area_lights` (else points), integrator `max_depth` (2 = direct light only).
pub fn export(
    setup: &Setup,
    relief_mm: f32,
    area_lights: bool,
    max_depth: u32,
    dir: &Path,
) -> Result<Export, TradeoffError> {
    std::fs::create_dir_all(dir).map_err(|e| TradeoffError::io(dir, e))?;
    let rig = &setup.rig;
    let world = &setup.world;
    let sim = SimSpec::of(rig).map_err(RenderError::from)?;
    let size_mm = sim.sample_size_mm;
    // The same rig the renderer draws: as built when `[sim.as_built]` asks for it.
    let as_built = sim.as_built.map_or_else(
        || stagehand_simulator::as_built::AsBuilt::nominal(rig),
        |spec| stagehand_simulator::as_built::AsBuilt::draw(rig, spec),
    );
    let sample = Sample::build(&world.fixture, size_mm as f32, relief_mm).map_err(|e| match e {
        RenderError::UnknownFixture(_) => TradeoffError::UnknownScene {
            scene: world.fixture.clone(),
            detail: e.to_string(),
        },
        other => other.into(),
    })?;
    let lambert = sample.max_ks <= 0.0 && sample.media.is_empty();
    let angles = RigAngles::from_world(rig, &world.axes);
    let to_sample = ToSample::new(angles.turntable_deg);
    let (lit, _) = lights::lit_lamps(rig, &as_built, world, angles, to_sample);
    let mut emitters = Vec::new();
    let sheet = match (&world.laser, &rig.laser) {
        (None, _) => None,
        (Some(_), _) if !lit.is_empty() => {
            return Err(TradeoffError::Export(
                "the laser is exported only with every lamp off".into(),
            ));
        }
        (Some(_), None) => {
            return Err(TradeoffError::Export("the rig has no line laser".into()));
        }
        (Some(beam), Some(spec)) => Some(LaserSheet::built(
            spec,
            beam,
            angles.light_arc_deg,
            to_sample,
            &as_built.laser(beam.mount_elevation_deg),
        )),
    };
    if let Some(sheet) = &sheet {
        emitters.push(sheet_emitter(sheet));
    }
    for light in &lit {
        match light.emitter {
            Emitter::Halogen {
                centre, intensity, ..
            } => {
                let rgb = light.rgb * intensity;
                emitters.push(if area_lights {
                    let area = std::f32::consts::PI * HALOGEN_RADIUS_MM * HALOGEN_RADIUS_MM;
                    json!({ "type": "sphere", "id": light.id, "centre": centre.to_array(),
                            "radius_mm": HALOGEN_RADIUS_MM, "radiance_rgb": (rgb / area).to_array() })
                } else {
                    json!({ "type": "point", "id": light.id, "position": centre.to_array(),
                            "intensity_rgb": rgb.to_array() })
                });
            }
            _ => {
                return Err(TradeoffError::Export(format!(
                    "lamp `{}` is not a halogen lamp (only halogen lamps are exported)",
                    light.id
                )));
            }
        }
    }
    let cam = rig
        .camera(&setup.camera)
        .ok_or_else(|| TradeoffError::InvalidInput {
            what: "--camera".into(),
            expected: "a camera of the rig".into(),
            got: setup.camera.clone(),
        })?;
    let pose = as_built.camera(&cam.id).pose(cam, to_sample);
    let (mesh, texels) = sample_mesh(&sample);
    put(&dir.join("sample.ply"), &mesh.to_ply())?;
    put(
        &dir.join("turntable.ply"),
        &turntable_mesh(sample.size_mm).to_ply(),
    )?;
    let mut albedo = albedo_texture(&sample, texels);
    if let Some(sheet) = &sheet {
        for rgb in albedo.chunks_exact_mut(3) {
            let mono = Vec3A::from_slice(rgb).dot(sheet.reflect_weights);
            rgb.fill(mono);
        }
    }
    let ggx = uniform_ggx(&sample, texels);
    if ggx.is_some() {
        // The peer blends half of each BSDF: the diffuse part doubled keeps the sum.
        let doubled: Vec<f32> = albedo.iter().map(|a| 2.0 * a).collect();
        super::pfm::write(
            &dir.join("albedo_doubled.pfm"),
            texels as u32,
            texels as u32,
            &doubled,
        )?;
    }
    super::pfm::write(
        &dir.join("albedo.pfm"),
        texels as u32,
        texels as u32,
        &albedo,
    )?;
    let scene = json!({
        "units": "mm",
        "scene": world.fixture,
        "camera": {
            "id": cam.id,
            "origin": pose.origin.to_array(),
            "target": (pose.origin + pose.forward).to_array(),
            "up": pose.up.to_array(),
            "fov_deg": cam.fov_deg,
            "fov_axis": "x",
            "width": cam.width,
            "height": cam.height,
        },
        "sample": { "mesh": "sample.ply", "albedo": "albedo.pfm", "texels": texels,
                    "ggx": ggx, "albedo_doubled": ggx.map(|_| "albedo_doubled.pfm") },
        "turntable": { "mesh": "turntable.ply", "albedo": TURNTABLE_ALBEDO },
        "emitters": emitters,
        "max_depth": max_depth,
        "lambert": lambert,
        "max_ks": sample.max_ks,
    });
    let scene_json = dir.join("scene.json");
    let text =
        serde_json::to_string_pretty(&scene).map_err(|e| TradeoffError::io(&scene_json, e))?;
    put(&scene_json, text.as_bytes())?;
    Ok(Export {
        scene_json,
        vertices: mesh.positions.len(),
        faces: mesh.faces.len(),
        texels,
        lambert,
        max_ks: sample.max_ks,
        ggx,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SetupOptions;

    /// Header counts and body size of a binary PLY.
    fn ply_counts(bytes: &[u8]) -> (usize, usize, usize) {
        let end = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .expect("header")
            + 11;
        let header = String::from_utf8_lossy(&bytes[..end]);
        let count = |what: &str| {
            header
                .lines()
                .find_map(|l| l.strip_prefix(what))
                .and_then(|n| n.trim().parse::<usize>().ok())
                .expect(what)
        };
        (
            count("element vertex "),
            count("element face "),
            bytes.len() - end,
        )
    }

    #[test]
    fn relief_mesh_has_grid_and_wall_counts() {
        // 80 mm at 5 mm: 16 cells per side.
        let steps = Sample::build("steps", 80.0, 5.0).expect("steps");
        let (mesh, texels) = sample_mesh(&steps);
        assert_eq!(texels, 16);
        // 17² grid vertices + 4 per wall quad; 2·16² top faces + 2 per wall quad; every
        // border segment of `steps` is 1.5 mm high.
        assert_eq!(mesh.positions.len(), 17 * 17 + 4 * 64);
        assert_eq!(mesh.faces.len(), 2 * 256 + 2 * 64);
        let bytes = mesh.to_ply();
        let (v, f, body) = ply_counts(&bytes);
        assert_eq!((v, f), (mesh.positions.len(), mesh.faces.len()));
        assert_eq!(body, v * 32 + f * 13);
        assert!(mesh.faces.iter().flatten().all(|&i| (i as usize) < v));
        // Top faces wind counter-clockwise seen from above (normal +z).
        let [a, b, c] = mesh.faces[0].map(|i| Vec3A::from(mesh.positions[i as usize]));
        assert!((b - a).cross(c - a).z > 0.0);
        // Bumps meet the turntable at height 0: no walls.
        let bumps = Sample::build("bumps", 80.0, 5.0).expect("bumps");
        assert_eq!(sample_mesh(&bumps).0.faces.len(), 2 * 256);
        let flat = Sample::build("checkerboard", 80.0, 5.0).expect("flat");
        let (quad, n) = sample_mesh(&flat);
        assert_eq!((quad.positions.len(), quad.faces.len(), n), (4, 2, 800));
    }

    #[test]
    fn turntable_has_a_square_hole() {
        let t = turntable_mesh(80.0);
        assert_eq!(t.positions.len(), 2 * TURNTABLE_SEGMENTS);
        assert_eq!(t.faces.len(), 2 * TURNTABLE_SEGMENTS);
        // Inner ring on the square (a corner at 45°), outer on the circle.
        let corner = Vec3A::from(t.positions[2 * TURNTABLE_SEGMENTS / 8]);
        assert!(
            (corner - Vec3A::new(40.0, 40.0, 0.0)).length() < 1e-3,
            "{corner}"
        );
        let outer = Vec3A::from(t.positions[1]);
        assert!((outer.length() - TURNTABLE_RADIUS_MM).abs() < 1e-3);
        let [a, b, c] = t.faces[0].map(|i| Vec3A::from(t.positions[i as usize]));
        assert!((b - a).cross(c - a).z > 0.0, "faces up");
    }

    #[test]
    fn export_writes_the_scene() {
        let setup = Setup::new(SetupOptions {
            scene: "planes".into(),
            width: 32,
            height: 24,
            ..SetupOptions::default()
        })
        .expect("setup");
        let dir = tempfile::tempdir().expect("tmp");
        let e = export(&setup, 5.0, true, 2, dir.path()).expect("export");
        assert!(e.lambert, "planes are matte");
        let bytes = std::fs::read(dir.path().join("sample.ply")).expect("ply");
        let (v, f, _) = ply_counts(&bytes);
        assert_eq!((v, f), (e.vertices, e.faces));
        let scene: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&e.scene_json).expect("json"))
                .expect("valid json");
        assert_eq!(scene["emitters"].as_array().map(Vec::len), Some(2));
        assert_eq!(scene["camera"]["width"], 32);
        let (w, h, rgb) = crate::pfm::read(&dir.path().join("albedo.pfm")).expect("albedo");
        assert_eq!((w as usize, h as usize), (e.texels, e.texels));
        assert!(
            rgb.iter().all(|&a| (a - 0.8).abs() < 1e-6),
            "planes are grey 0.8"
        );
    }

    /// A uniform GGX sample exports its lobe (for `roughplastic`); a Ward one does not.
    #[test]
    fn a_glossy_ggx_sample_exports_its_lobe_and_a_ward_one_does_not() {
        let export_of = |scene: &str| {
            let setup = Setup::new(SetupOptions {
                scene: scene.into(),
                width: 16,
                height: 12,
                ..SetupOptions::default()
            })
            .expect("setup");
            let dir = tempfile::tempdir().expect("tmp");
            let e = export(&setup, 5.0, true, 2, dir.path()).expect("export");
            let json: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&e.scene_json).expect("json"))
                    .expect("valid json");
            (e, json)
        };
        let (e, json) = export_of("plastic_ggx");
        let g = e.ggx.expect("plastic_ggx is uniform GGX");
        assert!(!e.lambert);
        assert_eq!((g.alpha, g.f0), (0.15, 0.04));
        assert!(
            (g.eta - 1.5).abs() < 1e-5,
            "F0 0.04 is a dielectric of η 1.5: {}",
            g.eta
        );
        assert_eq!(json["sample"]["ggx"]["alpha"], 0.15f32 as f64);
        let (e, json) = export_of("bumps");
        assert!(e.ggx.is_none() && !e.lambert, "bumps has a Ward lobe");
        assert!(json["sample"]["ggx"].is_null());
    }

    /// The laser scene exports one sheet emitter with the renderer's sheet (its apex on the
    /// light arc, unit vectors, the peak and half-width the rig gives, the camera colour) and
    /// the albedo at the laser's wavelength; lamps with it, a colour the laser lacks, or no
    /// laser are refused with the reason.
    #[test]
    fn the_laser_line_exports_as_a_sheet() {
        let laser = |nm: u32, lamps: Vec<String>| {
            Setup::new(SetupOptions {
                scene: "planes".into(),
                width: 16,
                height: 12,
                lamps,
                laser_nm: Some(nm),
                ..SetupOptions::default()
            })
        };
        let setup = laser(650, Vec::new()).expect("setup");
        let dir = tempfile::tempdir().expect("tmp");
        let e = export(&setup, 5.0, true, 2, dir.path()).expect("export");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&e.scene_json).expect("json"))
                .expect("valid json");
        let emitters = json["emitters"].as_array().expect("emitters");
        assert_eq!(emitters.len(), 1);
        let sheet = &emitters[0];
        assert_eq!(sheet["type"], "sheet");
        let v = |k: &str| {
            let a: Vec<f32> = serde_json::from_value(sheet[k].clone()).expect(k);
            Vec3A::from_slice(&a)
        };
        assert!(
            (v("origin").length() - 700.0).abs() < 1.0,
            "{}",
            v("origin")
        );
        for k in ["centre", "normal", "fan_axis"] {
            assert!((v(k).length() - 1.0).abs() < 1e-4, "{k}");
        }
        assert!(v("centre").dot(v("normal")).abs() < 1e-4);
        assert!(v("rgb").x > 0.9 && v("rgb").y < 0.2, "650 nm is red");
        let range: Vec<f32> = serde_json::from_value(sheet["range_mm"].clone()).expect("range");
        assert!(range[0] < 700.0 && range[1] > 700.0, "{range:?}");
        let (_, _, rgb) = crate::pfm::read(&dir.path().join("albedo.pfm")).expect("albedo");
        assert!(rgb.chunks_exact(3).all(|c| c[0] == c[1] && c[1] == c[2]));
        // Refusals, each with its reason.
        let lit = laser(650, vec!["lamp2".into()]).expect("setup");
        let err = export(&lit, 5.0, true, 2, dir.path()).expect_err("lamps too");
        assert!(err.to_string().contains("every lamp off"), "{err}");
        let err = laser(999, Vec::new()).expect_err("no such colour");
        assert!(
            err.is_bad_input() && err.to_string().contains("999 nm"),
            "{err}"
        );
    }
}
