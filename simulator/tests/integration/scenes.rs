//! Scene files end to end: every built-in scene builds, every kind of mistake is reported at
//! file:line:col, height images and meshes become the relief they describe, and a material
//! map shows up in a rendered frame.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};
use stagehand_simulator::render::config::{FIXTURES, SimSpec};
use stagehand_simulator::render::material::Model;
use stagehand_simulator::render::sample::{Kind, Sample};
use stagehand_simulator::render::{RenderError, Renderer};
use stagehand_simulator::scene_file::{BUILTIN_SCENES, load_scene_file};
use stagehand_simulator::world_snapshot::WorldSnapshot;
use tempfile::TempDir;

/// Writes `text` as `name` in `dir` and returns its path.
fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write test file");
    path
}

/// Writes a greyscale (1 channel) or RGB (3 channels) PNG of `bits` bits per sample.
fn write_png(path: &Path, width: u32, height: u32, channels: usize, bits: u8, values: &[u16]) {
    let file = std::fs::File::create(path).expect("create png");
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(if channels == 1 {
        png::ColorType::Grayscale
    } else {
        png::ColorType::Rgb
    });
    let data: Vec<u8> = if bits == 16 {
        encoder.set_depth(png::BitDepth::Sixteen);
        values.iter().flat_map(|v| v.to_be_bytes()).collect()
    } else {
        encoder.set_depth(png::BitDepth::Eight);
        values.iter().map(|&v| v as u8).collect()
    };
    let mut writer = encoder.write_header().expect("png header");
    writer.write_image_data(&data).expect("png data");
    writer.finish().expect("png finish");
}

#[test]
fn every_builtin_scene_builds_as_its_fixture() {
    let _turn = crate::grbl_peer::alongside();
    assert_eq!(BUILTIN_SCENES.len(), FIXTURES.len());
    for name in FIXTURES {
        let s = Sample::build(name, 80.0, 0.4).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(s.name, name);
        assert_eq!(s.source.name, name);
        assert!(s.source.path.is_none() && s.source.text.contains("[scene]"));
    }
    let marble = Sample::build("marble", 80.0, 0.4).expect("marble");
    assert_eq!(marble.media.len(), 1);
    let m = marble.material_at(0.0, 0.0);
    assert_eq!((m.model, m.medium), (Model::Ggx, 1));
    assert_eq!(
        m.albedo,
        glam::Vec3A::ZERO,
        "the dipole supplies the diffuse light"
    );
    let metal = Sample::build("brushed_metal", 80.0, 0.4).expect("metal");
    let m = metal.material_at(5.0, 5.0);
    assert_eq!(m.model, Model::WardAniso);
    assert!((m.tangent_rad - 30f32.to_radians()).abs() < 1e-6 && m.alpha_y > m.alpha);
    let blinn = Sample::build("glossy_blinn", 80.0, 0.4).expect("blinn");
    let m = blinn.material_at(0.0, 0.0);
    assert!(
        (m.alpha - (2.0f32 / 202.0).sqrt()).abs() < 1e-6,
        "{}",
        m.alpha
    );
    let felt = Sample::build("felt_quasi", 80.0, 0.4).expect("felt");
    let (lo, hi) = (0..160 * 160)
        .map(|k| {
            let (x, y) = (
                (k % 160) as f32 * 0.25 - 20.0,
                (k / 160) as f32 * 0.25 - 20.0,
            );
            felt.material_at(x, y).meso_in
        })
        .fold((1.0f32, 0.0f32), |(lo, hi), v| (lo.min(v), hi.max(v)));
    assert!(
        lo < 0.6 && hi > 0.9,
        "meso entrance varies with the weave: {lo}..{hi}"
    );
    let cavity = Sample::build("cavity", 80.0, 0.4).expect("cavity");
    assert_eq!(cavity.kind, Kind::Grooves);
    let g = cavity.grid.as_ref().expect("relief");
    assert!((g.zmax() - 8.0).abs() < 1e-3);
    assert!(
        cavity.height_at(-35.0, 0.0) < 0.4,
        "groove bottom within one 0.4 mm cell"
    );
}

/// Loads `text` as a scene file and returns its error message, checking it starts with
/// `path:LINE:COL:` where LINE is the line containing `marker`.
fn error_at(text: &str, marker: &str) -> String {
    let dir = TempDir::new().expect("tempdir");
    let path = write(dir.path(), "x.toml", text);
    let e = load_scene_file(&path).expect_err("scene must be rejected");
    let msg = e.to_string();
    let line = text
        .lines()
        .position(|l| l.contains(marker))
        .unwrap_or_else(|| panic!("marker {marker} not in text"))
        + 1;
    let prefix = format!("{}:{line}:", path.display());
    assert!(msg.starts_with(&prefix), "expected {prefix}…, got {msg}");
    let col: String = msg[prefix.len()..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    assert!(col.parse::<usize>().is_ok_and(|c| c >= 1), "{msg}");
    msg
}

const HEAD: &str = "[scene]\nname = \"t\"\n\n[sample]\nshape = \"bumps\"\n";

#[test]
fn schema_errors_name_file_line_and_column() {
    let _turn = crate::grbl_peer::alongside();
    let m = error_at(&format!("{HEAD}colour = 3\n"), "colour");
    assert!(m.contains("unknown field `colour`"), "{m}");
    let m = error_at(
        &format!("{HEAD}\n[material]\nmodel = \"ward\"\nks = \"shiny\"\n"),
        "shiny",
    );
    assert!(m.contains("invalid type"), "{m}");
    let m = error_at(
        "[scene]\nname = \"t\"\n[sample]\nshape = \"teapot\"\n",
        "teapot",
    );
    assert!(m.contains("shape `teapot` is unknown; use one of"), "{m}");
    let m = error_at(&format!("{HEAD}[material]\nmodel = \"phong\"\n"), "phong");
    assert!(m.contains("model `phong` is unknown"), "{m}");
    let m = error_at(&format!("{HEAD}square_mm = 5.0\n"), "square_mm");
    assert!(m.contains("does not apply to shape"), "{m}");
    let m = error_at(
        &format!("{HEAD}[material]\nmodel = \"lambert\"\nks = 0.2\n"),
        "ks =",
    );
    assert!(m.contains("does not apply to model"), "{m}");
}

#[test]
fn out_of_range_values_name_file_line_and_column() {
    let _turn = crate::grbl_peer::alongside();
    let mat = |body: &str| format!("{HEAD}[material]\nmodel = \"ggx\"\n{body}\n");
    let m = error_at(&mat("albedo = [0.5, 1.5, 0.2]"), "albedo");
    assert!(m.contains("albedo[1] must be in [0, 1], got 1.5"), "{m}");
    let m = error_at(&mat("alpha = 0.0"), "alpha");
    assert!(m.contains("alpha must be in (0, 1]"), "{m}");
    let sub = |a: &str, s: &str, eta: &str| {
        mat(&format!(
            "[material.subsurface]\nsigma_a = {a}\nsigma_s_prime = {s}\neta = {eta}"
        ))
    };
    let m = error_at(
        &sub("[0.1, -0.2, 0.1]", "[1.0, 1.0, 1.0]", "1.3"),
        "sigma_a",
    );
    assert!(
        m.contains("sigma_a[1] must be a number ≥ 0, got -0.2"),
        "{m}"
    );
    let m = error_at(
        &sub("[0.1, 0.1, 0.1]", "[1.0, 0.0, 1.0]", "1.3"),
        "sigma_s_prime",
    );
    assert!(m.contains("sigma_s_prime[1] must be a number > 0"), "{m}");
    let m = error_at(&sub("[0.1, 0.1, 0.1]", "[1.0, 1.0, 1.0]", "0.0"), "eta");
    assert!(m.contains("eta must be a number > 0, got 0"), "{m}");
    let m = error_at(&format!("{HEAD}[render]\nquality = \"ultra\"\n"), "ultra");
    assert!(m.contains("use preview, standard or reference"), "{m}");
    let m = error_at(
        &format!("{HEAD}[render.knobs]\nspp_side = 100\n"),
        "spp_side",
    );
    assert!(m.contains("spp_side"), "{m}");
    let m = error_at(&format!("{HEAD}[render.knobs]\nspp = 4\n"), "spp");
    assert!(m.contains("unknown field `spp`"), "{m}");
}

#[test]
fn bad_referenced_files_name_the_scene_key() {
    let _turn = crate::grbl_peer::alongside();
    let dir = TempDir::new().expect("tempdir");
    let m = error_at(
        &format!("{HEAD}[material]\nmodel = \"ward\"\nalbedo_map = \"missing.png\"\n"),
        "missing.png",
    );
    assert!(
        m.contains("missing.png") && m.contains("check the path"),
        "{m}"
    );
    // Wrong bit depth: an 8-bit height image.
    let png8 = dir.path().join("h8.png");
    write_png(&png8, 4, 4, 1, 8, &[128; 16]);
    let text = format!(
        "[scene]\nname = \"t\"\n[sample]\nshape = \"height_image\"\npath = \"{}\"\nheight_scale_mm = 2.0\n",
        png8.display()
    );
    let m = error_at(&text, "path =");
    assert!(
        m.contains("8-bit greyscale") && m.contains("16-bit greyscale"),
        "{m}"
    );
    // Not a PNG at all.
    let junk = write(dir.path(), "junk.png", "not an image");
    let text = format!(
        "{HEAD}[material]\nmodel = \"ward\"\nks_map = \"{}\"\n",
        junk.display()
    );
    let m = error_at(&text, "ks_map");
    assert!(m.contains("not a readable PNG"), "{m}");
    // An OBJ syntax error names the OBJ's own line too.
    let obj = write(
        dir.path(),
        "bad.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    );
    let text = format!(
        "[scene]\nname = \"t\"\n[sample]\nshape = \"mesh\"\npath = \"{}\"\n",
        obj.display()
    );
    let m = error_at(&text, "path =");
    assert!(m.contains("bad.obj:4:") && m.contains("vertex 9"), "{m}");
    let text = "[scene]\nname = \"t\"\n[sample]\nshape = \"mesh\"\npath = \"nowhere.obj\"\n";
    let m = error_at(text, "path =");
    assert!(
        m.contains("nowhere.obj") && m.contains("cannot read"),
        "{m}"
    );
}

#[test]
fn missing_scene_file_is_a_clear_render_error() {
    let _turn = crate::grbl_peer::alongside();
    let e = Sample::build("/nonexistent/scene.toml", 80.0, 0.4).expect_err("missing");
    assert!(matches!(e, RenderError::Scene(_)), "{e:?}");
    assert!(e.to_string().contains("/nonexistent/scene.toml"), "{e}");
    let e = Sample::build("teapot", 80.0, 0.4).expect_err("unknown");
    assert!(
        e.to_string().contains("marble") && e.to_string().contains(".toml"),
        "{e}"
    );
}

#[test]
fn sixteen_bit_height_image_round_trips_into_the_relief() {
    let _turn = crate::grbl_peer::alongside();
    let dir = TempDir::new().expect("tempdir");
    // A ramp along the columns (+y): 0 at the left, full white at the right.
    let (w, h) = (65u32, 9u32);
    let values: Vec<u16> = (0..h)
        .flat_map(|_| (0..w).map(|c| (c * 65535 / (w - 1)) as u16))
        .collect();
    write_png(&dir.path().join("ramp.png"), w, h, 1, 16, &values);
    let scene = write(
        dir.path(),
        "ramp.toml",
        "[scene]\nname = \"ramp\"\n[sample]\nsize_mm = 65.0\nshape = \"height_image\"\npath = \"ramp.png\"\nheight_scale_mm = 4.0\n",
    );
    let s = Sample::build(scene.to_str().expect("utf-8 path"), 80.0, 0.5).expect("builds");
    assert_eq!(s.size_mm, 65.0, "the scene's size wins over the rig's");
    assert_eq!(s.kind, Kind::HeightImage);
    assert_eq!(s.source.path.as_deref(), Some(scene.as_path()));
    // Pixel centres map to heights c/(w-1)·4 mm.
    for c in [0u32, 16, 32, 48, 64] {
        let y = -32.5 + (c as f32 + 0.5);
        let expected = c as f32 / (w - 1) as f32 * 4.0;
        let got = s.height_at(0.0, y);
        assert!(
            (got - expected).abs() < 0.02,
            "column {c}: {got} vs {expected}"
        );
    }
}

#[test]
fn obj_pyramid_rasterises_to_its_heights() {
    let _turn = crate::grbl_peer::alongside();
    let dir = TempDir::new().expect("tempdir");
    write(
        dir.path(),
        "pyramid.obj",
        "# square pyramid, base 40 mm, apex 10 mm\nv -20 -20 0\nv 20 -20 0\nv 20 20 0\nv -20 20 0\nv 0 0 10\n\
         f 1 2 5\nf 2 3 5\nf 3 4 5\nf 4 1 5\nf 4 3 2 1\n",
    );
    let scene = write(
        dir.path(),
        "pyramid.toml",
        "[scene]\nname = \"pyramid\"\n[sample]\nshape = \"mesh\"\npath = \"pyramid.obj\"\n",
    );
    let s = Sample::build(scene.to_str().expect("utf-8 path"), 80.0, 0.5).expect("builds");
    let g = s.grid.as_ref().expect("relief");
    assert!((g.zmax() - 10.0).abs() < 1e-4, "apex {}", g.zmax());
    for (x, y, z) in [
        (0.0, 0.0, 10.0),
        (10.0, 0.0, 5.0),
        (0.0, -10.0, 5.0),
        (-15.0, 5.0, 2.5),
        (30.0, 0.0, 0.0),
    ] {
        let got = s.height_at(x, y);
        assert!((got - z).abs() < 1e-3, "({x}, {y}): {got} vs {z}");
    }
}

#[test]
fn an_albedo_map_shows_up_in_the_rendered_frame() {
    let _turn = crate::grbl_peer::alongside();
    let dir = TempDir::new().expect("tempdir");
    // 8-bit sRGB map: left half (−y) red, right half (+y) blue.
    let (w, h) = (8u32, 8u32);
    let values: Vec<u16> = (0..h)
        .flat_map(|_| {
            (0..w).flat_map(|c| {
                if c < w / 2 {
                    [230, 20, 20]
                } else {
                    [20, 20, 230]
                }
            })
        })
        .collect();
    write_png(&dir.path().join("albedo.png"), w, h, 3, 8, &values);
    let scene = write(
        dir.path(),
        "painted.toml",
        "[scene]\nname = \"painted\"\n[sample]\nshape = \"flat\"\n[material]\nmodel = \"lambert\"\nalbedo_map = \"albedo.png\"\n",
    );
    let fixture = scene.to_str().expect("utf-8 path").to_string();
    let mut text = BUILTIN_LIGHTSTAGE.to_string();
    text = text
        .replace("width = 1024", "width = 64")
        .replace("height = 768", "height = 48");
    let mut rig = parse_rig(&text, "lightstage.toml").expect("rig");
    SimSpec::edit(&mut rig, |s| s.sample = fixture.clone()).expect("sim");
    let renderer = Renderer::new(&rig).expect("renderer");
    let lamps: BTreeMap<String, f64> = rig.lamps.iter().map(|l| (l.id.clone(), 1.0)).collect();
    let world = WorldSnapshot {
        rig_time_s: 1.0,
        axes: BTreeMap::new(),
        lamps,
        laser: None,
        cart_mm: 0.0,
        fixture: fixture.clone(),
        fixture_pose: Default::default(),
    };
    let camera = rig.cameras[0].id.clone();
    let image = renderer.radiance(&world, &camera).expect("renders");
    assert_eq!(image.notes["fixture"], fixture.as_str());
    let (mut red, mut blue) = (0, 0);
    for px in image.rgb.chunks_exact(3) {
        if px[0] > 3.0 * px[2] && px[0] > 1e-3 {
            red += 1;
        }
        if px[2] > 3.0 * px[0] && px[2] > 1e-3 {
            blue += 1;
        }
    }
    // The sample fills a few hundred of the small camera's pixels; each half shows its colour.
    let n = image.rgb.len() / 3;
    assert!(red > 40 && blue > 40, "red {red}, blue {blue} of {n}");
}

#[test]
fn scene_render_settings_apply_on_top_of_the_rigs() {
    let _turn = crate::grbl_peer::alongside();
    let dir = TempDir::new().expect("tempdir");
    let scene = write(
        dir.path(),
        "fine.toml",
        "[scene]\nname = \"fine\"\n[sample]\nshape = \"flat\"\n[render]\nquality = \"standard\"\n[render.knobs]\nbounces = 3\n",
    );
    let fixture = scene.to_str().expect("utf-8 path").to_string();
    let text = BUILTIN_LIGHTSTAGE
        .replace("width = 1024", "width = 16")
        .replace("height = 768", "height = 12");
    let mut rig = parse_rig(&text, "lightstage.toml").expect("rig");
    SimSpec::edit(&mut rig, |s| s.sample = fixture.clone()).expect("sim");
    let renderer = Renderer::new(&rig).expect("renderer");
    let world = WorldSnapshot {
        rig_time_s: 1.0,
        axes: BTreeMap::new(),
        lamps: BTreeMap::new(),
        laser: None,
        cart_mm: 0.0,
        fixture,
        fixture_pose: Default::default(),
    };
    let image = renderer
        .radiance(&world, &rig.cameras[0].id)
        .expect("renders");
    assert_eq!(image.notes["quality"], "standard+custom");
    assert_eq!(image.notes["knobs"]["bounces"], 3);
    assert_eq!(image.notes["knobs"]["spp_side"], 2);
}
