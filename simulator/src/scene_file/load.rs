//! Reading scene files: TOML syntax and schema errors, out-of-range values and unusable
//! referenced files (images, meshes) are all reported at file:line:col with a sentence saying
//! what to do, the way rig files are (the span helpers are shared with `stagehand_devices`).

use std::path::{Path, PathBuf};

use glam::Vec3A;
use stagehand_devices::rig::span::{Seg, line_col, locate};

use super::error::SceneError;
use super::image::{ImageMap, MapKind, read_png};
use super::mesh::parse_obj;
use super::resolved::{Meso, Param, Scene, SceneMaterial, SceneSource, Shape};
use super::spec::{MaterialSpec, MesoSpec, RenderSpec, SampleSpec, SceneSpec, SubsurfaceSpec};
use crate::render::RenderError;
use crate::render::material::{Medium, Model};
use crate::render::quality::Quality;

/// Largest sample edge a scene may set, in mm (the turntable is 400 mm across).
const MAX_SIZE_MM: f64 = 1000.0;

/// The offending value's path in the document and what to do about it.
type Problem = (Vec<Seg>, String);

/// Reads and checks the scene file at `path`; files it refers to are relative to its folder.
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|e| SceneError::Read {
        path: path.display().to_string(),
        reason: e.to_string(),
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut scene = parse_scene(&text, &path.display().to_string(), Some(dir))?;
    scene.source.path = Some(path.to_path_buf());
    Ok(scene)
}

/// Parses and checks scene TOML; `origin` names the file in errors and `dir` is the folder
/// relative paths start from (`None`: the working directory).
pub fn parse_scene(text: &str, origin: &str, dir: Option<&Path>) -> Result<Scene, SceneError> {
    let invalid = |offset: usize, message: String| {
        let (line, col) = line_col(text, offset);
        SceneError::Invalid {
            path: origin.to_string(),
            line,
            col,
            message,
        }
    };
    let spec: SceneSpec = toml::from_str(text).map_err(|e| {
        let offset = e.span().map(|s| s.start).unwrap_or(0);
        invalid(offset, e.message().trim().replace('\n', " "))
    })?;
    let resolve = |p: &str| match dir {
        Some(d) => d.join(p),
        None => PathBuf::from(p),
    };
    let checked = Checker { resolve: &resolve }
        .scene(&spec)
        .map_err(|(path, message)| invalid(locate(text, &path).unwrap_or(0), message))?;
    let (size_mm, shape, material, quality) = checked;
    Ok(Scene {
        source: SceneSource {
            name: spec.scene.name.clone(),
            path: None,
            text: text.to_string(),
        },
        description: spec.scene.description.clone(),
        size_mm,
        shape,
        material,
        quality,
        knobs: spec.render.and_then(|r| r.knobs),
    })
}

fn at(keys: &[&'static str]) -> Vec<Seg> {
    keys.iter().map(|k| Seg::Key(k)).collect()
}

fn indexed(keys: &[&'static str], index: usize) -> Vec<Seg> {
    let mut path = at(keys);
    path.push(Seg::Index(index));
    path
}

/// A number that must lie in a range: `lo_open`/`hi_open` exclude the bounds.
struct Range {
    lo: f64,
    lo_open: bool,
    hi: f64,
    hi_open: bool,
}

const FRACTION: Range = Range {
    lo: 0.0,
    lo_open: false,
    hi: 1.0,
    hi_open: false,
};
const ROUGHNESS: Range = Range {
    lo: 0.0,
    lo_open: true,
    hi: 1.0,
    hi_open: false,
};
const POSITIVE: Range = Range {
    lo: 0.0,
    lo_open: true,
    hi: f64::INFINITY,
    hi_open: true,
};
const NON_NEGATIVE: Range = Range {
    lo: 0.0,
    lo_open: false,
    hi: f64::INFINITY,
    hi_open: true,
};
const LENGTH_MM: Range = Range {
    lo: 0.0,
    lo_open: true,
    hi: MAX_SIZE_MM,
    hi_open: false,
};

impl Range {
    fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_open {
                v > self.lo
            } else {
                v >= self.lo
            })
            && (if self.hi_open {
                v < self.hi
            } else {
                v <= self.hi
            })
    }

    fn describe(&self) -> String {
        if self.hi.is_infinite() {
            return if self.lo_open {
                format!("a number > {}", self.lo)
            } else {
                format!("a number ≥ {}", self.lo)
            };
        }
        format!(
            "in {}{}, {}{}",
            if self.lo_open { '(' } else { '[' },
            self.lo,
            self.hi,
            if self.hi_open { ')' } else { ']' }
        )
    }
}

/// Checks one number; the error names `name` and the range and adds `advice`.
fn number(path: Vec<Seg>, name: &str, v: f64, range: &Range, advice: &str) -> Result<f32, Problem> {
    if range.contains(v) {
        Ok(v as f32)
    } else {
        Err((
            path,
            format!("{name} must be {}, got {v}; {advice}", range.describe()),
        ))
    }
}

/// Checks an RGB triple component by component.
fn rgb(
    keys: &[&'static str],
    name: &str,
    v: [f64; 3],
    range: &Range,
    advice: &str,
) -> Result<Vec3A, Problem> {
    let mut out = [0.0f32; 3];
    for (k, (o, c)) in out.iter_mut().zip(v).enumerate() {
        *o = number(indexed(keys, k), &format!("{name}[{k}]"), c, range, advice)?;
    }
    Ok(Vec3A::from_array(out))
}

/// Rejects a key that does not belong with the rest of the table.
fn forbid(present: bool, keys: &[&'static str], message: String) -> Result<(), Problem> {
    if present {
        Err((at(keys), message))
    } else {
        Ok(())
    }
}

/// Semantic checks and resolution of one scene; `resolve` turns a path written in the file
/// into a path on disk.
struct Checker<'a> {
    resolve: &'a dyn Fn(&str) -> PathBuf,
}

type Checked = (Option<f32>, Shape, Option<SceneMaterial>, Option<Quality>);

impl Checker<'_> {
    fn scene(&self, spec: &SceneSpec) -> Result<Checked, Problem> {
        if spec.scene.name.trim().is_empty() {
            return Err((
                at(&["scene", "name"]),
                "scene name is empty; give the scene a short name".into(),
            ));
        }
        let size_mm = spec
            .sample
            .size_mm
            .map(|v| {
                number(
                    at(&["sample", "size_mm"]),
                    "size_mm",
                    v,
                    &LENGTH_MM,
                    "give the sample's edge length in millimetres (the turntable is 400 mm across)",
                )
            })
            .transpose()?;
        let shape = self.shape(&spec.sample)?;
        let material = spec
            .material
            .as_ref()
            .map(|m| self.material(m))
            .transpose()?;
        let quality = match &spec.render {
            Some(r) => render(r)?,
            None => None,
        };
        Ok((size_mm, shape, material, quality))
    }

    fn image(&self, keys: &[&'static str], path: &str, kind: MapKind) -> Result<ImageMap, Problem> {
        read_png(&(self.resolve)(path), kind).map_err(|e| (at(keys), e.to_string()))
    }

    fn shape(&self, s: &SampleSpec) -> Result<Shape, Problem> {
        const SHAPES: &str = "flat, bumps, steps, weave, checkerboard, colorchecker, planes, height_image, mesh, grooves or bowl";
        let params: [(&'static str, bool); 11] = [
            ("max_height_mm", s.max_height_mm.is_some()),
            ("seed", s.seed.is_some()),
            ("step_height_mm", s.step_height_mm.is_some()),
            ("square_mm", s.square_mm.is_some()),
            ("step_mm", s.step_mm.is_some()),
            ("path", s.path.is_some()),
            ("height_scale_mm", s.height_scale_mm.is_some()),
            ("scale", s.scale.is_some()),
            ("pitch_mm", s.pitch_mm.is_some()),
            ("depth_mm", s.depth_mm.is_some()),
            ("radius_mm", s.radius_mm.is_some()),
        ];
        let allowed: &[&str] = match s.shape.as_str() {
            "flat" | "weave" | "colorchecker" => &[],
            "bumps" => &["max_height_mm", "seed"],
            "steps" => &["step_height_mm"],
            "checkerboard" => &["square_mm"],
            "planes" => &["step_mm"],
            "height_image" => &["path", "height_scale_mm"],
            "mesh" => &["path", "scale"],
            "grooves" => &["pitch_mm", "depth_mm"],
            "bowl" => &["radius_mm", "depth_mm"],
            other => {
                return Err((
                    at(&["sample", "shape"]),
                    format!("shape `{other}` is unknown; use one of {SHAPES}"),
                ));
            }
        };
        for (name, present) in params {
            if present && !allowed.contains(&name) {
                let takes = if allowed.is_empty() {
                    "no parameters".to_string()
                } else {
                    allowed.join(", ")
                };
                return Err((
                    vec![Seg::Key("sample"), Seg::Key(name)],
                    format!(
                        "`{name}` does not apply to shape = \"{}\"; remove it (that shape takes {takes})",
                        s.shape
                    ),
                ));
            }
        }
        let length = |key: &'static str, v: Option<f64>, default: f64| {
            number(
                at(&["sample", key]),
                key,
                v.unwrap_or(default),
                &LENGTH_MM,
                "give a length in millimetres",
            )
        };
        let required = |key: &'static str, v: Option<f64>| {
            v.ok_or_else(|| {
                (
                    at(&["sample", "shape"]),
                    format!("shape = \"{}\" needs `{key}`; add it to [sample]", s.shape),
                )
            })
        };
        Ok(match s.shape.as_str() {
            "flat" => Shape::Flat,
            "weave" => Shape::Weave,
            "colorchecker" => Shape::ColorChecker,
            "bumps" => Shape::Bumps {
                max_height_mm: length("max_height_mm", s.max_height_mm, 3.0)?,
                seed: s
                    .seed
                    .map_or(crate::render::sample::BUMPS_SEED, |v| v as u64),
            },
            "steps" => Shape::Steps {
                step_height_mm: length("step_height_mm", s.step_height_mm, 1.5)?,
            },
            "checkerboard" => Shape::Checkerboard {
                square_mm: length("square_mm", s.square_mm, 10.0)?,
            },
            "planes" => Shape::Planes {
                step_mm: length("step_mm", s.step_mm, 20.0)?,
            },
            "height_image" => {
                let path = s.path.as_deref().ok_or_else(|| {
                    (
                        at(&["sample", "shape"]),
                        "shape = \"height_image\" needs `path` to a 16-bit greyscale PNG; add it to [sample]".to_string(),
                    )
                })?;
                let height_scale_mm = length(
                    "height_scale_mm",
                    Some(required("height_scale_mm", s.height_scale_mm)?),
                    0.0,
                )?;
                Shape::HeightImage {
                    image: self.image(&["sample", "path"], path, MapKind::Height)?,
                    height_scale_mm,
                }
            }
            "mesh" => {
                let path = s.path.as_deref().ok_or_else(|| {
                    (
                        at(&["sample", "shape"]),
                        "shape = \"mesh\" needs `path` to a Wavefront OBJ file; add it to [sample]"
                            .to_string(),
                    )
                })?;
                let scale = number(
                    at(&["sample", "scale"]),
                    "scale",
                    s.scale.unwrap_or(1.0),
                    &POSITIVE,
                    "give millimetres per OBJ unit (1 if the mesh is in mm)",
                )?;
                let file = (self.resolve)(path);
                let text = std::fs::read_to_string(&file).map_err(|e| {
                    (
                        at(&["sample", "path"]),
                        format!(
                            "cannot read `{}`: {e}; check the path (it is relative to the scene file)",
                            file.display()
                        ),
                    )
                })?;
                let mesh = parse_obj(&text).map_err(|e| {
                    (
                        at(&["sample", "path"]),
                        format!("{}:{}: {}", file.display(), e.line, e.message),
                    )
                })?;
                Shape::Mesh { mesh, scale }
            }
            "grooves" => Shape::Grooves {
                pitch_mm: length("pitch_mm", s.pitch_mm, 10.0)?,
                depth_mm: length("depth_mm", s.depth_mm, 8.0)?,
            },
            _ => {
                let radius_mm =
                    length("radius_mm", Some(required("radius_mm", s.radius_mm)?), 0.0)?;
                let depth_mm = length("depth_mm", Some(required("depth_mm", s.depth_mm)?), 0.0)?;
                if depth_mm > radius_mm {
                    return Err((
                        at(&["sample", "depth_mm"]),
                        format!(
                            "a bowl is a spherical cap: depth_mm ({depth_mm}) must not exceed radius_mm ({radius_mm}); make it shallower"
                        ),
                    ));
                }
                Shape::Bowl {
                    radius_mm,
                    depth_mm,
                }
            }
        })
    }

    fn material(&self, m: &MaterialSpec) -> Result<SceneMaterial, Problem> {
        let model = Model::parse(&m.model).ok_or_else(|| {
            (
                at(&["material", "model"]),
                format!(
                    "model `{}` is unknown; use lambert, ward, ward_aniso, blinn_phong or ggx",
                    m.model
                ),
            )
        })?;
        let name = model.name();
        let not_for = |key: &'static str, present: bool, why: &str| {
            forbid(
                present,
                &["material", key],
                format!("`{key}` does not apply to model = \"{name}\"; {why}"),
            )
        };
        let lobe =
            "remove it or choose a model with a specular lobe (ward, ward_aniso, blinn_phong, ggx)";
        if model == Model::Lambert {
            not_for("ks", m.ks.is_some(), lobe)?;
            not_for("ks_map", m.ks_map.is_some(), lobe)?;
            not_for("alpha", m.alpha.is_some(), lobe)?;
            not_for("alpha_map", m.alpha_map.is_some(), lobe)?;
        }
        if model != Model::WardAniso {
            let aniso = "remove it or use model = \"ward_aniso\"";
            not_for("alpha_y", m.alpha_y.is_some(), aniso)?;
            not_for("tangent_deg", m.tangent_deg.is_some(), aniso)?;
        }
        if model != Model::BlinnPhong {
            not_for(
                "exponent",
                m.exponent.is_some(),
                "remove it or use model = \"blinn_phong\" (other models take alpha)",
            )?;
        }
        let both = |a: &'static str, b: &'static str, present: bool| {
            forbid(
                present,
                &["material", b],
                format!("give either `{a}` or `{b}`, not both"),
            )
        };
        both(
            "albedo",
            "albedo_map",
            m.albedo.is_some() && m.albedo_map.is_some(),
        )?;
        both("ks", "ks_map", m.ks.is_some() && m.ks_map.is_some())?;
        both(
            "alpha",
            "alpha_map",
            m.alpha.is_some() && m.alpha_map.is_some(),
        )?;
        both(
            "alpha",
            "exponent",
            m.alpha.is_some() && m.exponent.is_some(),
        )?;
        both(
            "alpha_map",
            "exponent",
            m.alpha_map.is_some() && m.exponent.is_some(),
        )?;

        let medium = m.subsurface.as_ref().map(subsurface).transpose()?;
        let albedo_advice = "albedo is linear reflectance, a fraction of the incident light";
        let albedo = match (&m.albedo_map, m.albedo) {
            (Some(p), _) => {
                Param::Map(self.image(&["material", "albedo_map"], p, MapKind::Colour)?)
            }
            (None, Some(v)) => Param::Const(rgb(
                &["material", "albedo"],
                "albedo",
                v,
                &FRACTION,
                albedo_advice,
            )?),
            // Under a medium the dipole supplies the diffuse light.
            (None, None) if medium.is_some() => Param::Const(Vec3A::ZERO),
            (None, None) => Param::Const(Vec3A::splat(0.5)),
        };
        let ks = match (&m.ks_map, m.ks) {
            (Some(p), _) => Param::Map(self.image(&["material", "ks_map"], p, MapKind::Scalar)?),
            (None, v) => Param::Const(number(
                at(&["material", "ks"]),
                "ks",
                v.unwrap_or(if model == Model::Lambert { 0.0 } else { 0.04 }),
                &FRACTION,
                "ks is the specular albedo (F0 for ggx), a fraction",
            )?),
        };
        let alpha = match (&m.alpha_map, m.alpha, m.exponent) {
            (Some(p), _, _) => {
                Param::Map(self.image(&["material", "alpha_map"], p, MapKind::Scalar)?)
            }
            (None, _, Some(n)) => {
                let n = number(
                    at(&["material", "exponent"]),
                    "exponent",
                    n,
                    &POSITIVE,
                    "give the Blinn–Phong exponent n (larger is shinier)",
                )?;
                Param::Const((2.0 / (n + 2.0)).sqrt())
            }
            (None, v, None) => Param::Const(number(
                at(&["material", "alpha"]),
                "alpha",
                v.unwrap_or(0.2),
                &ROUGHNESS,
                "alpha is the lobe's roughness (0.05 shiny … 0.5 dull)",
            )?),
        };
        let alpha_y = m
            .alpha_y
            .map(|v| {
                number(
                    at(&["material", "alpha_y"]),
                    "alpha_y",
                    v,
                    &ROUGHNESS,
                    "alpha_y is the roughness across the tangent",
                )
            })
            .transpose()?;
        let tangent_deg = m.tangent_deg.unwrap_or(0.0);
        if !tangent_deg.is_finite() {
            return Err((
                at(&["material", "tangent_deg"]),
                format!("tangent_deg must be a finite angle in degrees, got {tangent_deg}"),
            ));
        }
        let transmittance = m
            .transmittance
            .map(|v| {
                rgb(
                    &["material", "transmittance"],
                    "transmittance",
                    v,
                    &FRACTION,
                    "transmittance is the fraction of the backlight passing through",
                )
            })
            .transpose()?
            .unwrap_or(Vec3A::ZERO);
        let meso = match &m.meso {
            None => None,
            Some(_) if medium.is_none() => {
                return Err((
                    at(&["material", "meso"]),
                    "[material.meso] modulates a subsurface medium; add [material.subsurface] or remove it".into(),
                ));
            }
            Some(meso) => Some(self.meso(meso)?),
        };
        Ok(SceneMaterial {
            model,
            albedo,
            ks,
            alpha,
            alpha_y,
            tangent_rad: (tangent_deg as f32).to_radians(),
            transmittance,
            medium,
            meso,
        })
    }

    fn meso(&self, m: &MesoSpec) -> Result<Meso, Problem> {
        let key = |k: &'static str| at(&["material", "meso", k]);
        let maps = m.entrance_map.is_some() || m.exit_map.is_some();
        let contrast = || {
            number(
                key("contrast"),
                "contrast",
                m.contrast.unwrap_or(0.5),
                &FRACTION,
                "contrast is how far the functions dip below 1",
            )
        };
        match (m.procedural.as_deref(), maps) {
            (Some(_), true) => Err((
                key("procedural"),
                "give either procedural or entrance_map/exit_map, not both".into(),
            )),
            (None, false) => Err((
                at(&["material", "meso"]),
                "[material.meso] needs entrance_map and/or exit_map, or procedural = \"relief\" or \"noise\"".into(),
            )),
            (None, true) => {
                forbid(m.contrast.is_some(), &["material", "meso", "contrast"], "contrast applies only to procedural meso; remove it".into())?;
                forbid(m.scale_mm.is_some(), &["material", "meso", "scale_mm"], "scale_mm applies only to procedural = \"noise\"; remove it".into())?;
                let load = |k: &'static str, p: &Option<String>| {
                    p.as_deref()
                        .map(|p| self.image(&["material", "meso", k], p, MapKind::Scalar))
                        .transpose()
                };
                Ok(Meso::Maps {
                    entrance: load("entrance_map", &m.entrance_map)?,
                    exit: load("exit_map", &m.exit_map)?,
                })
            }
            (Some("relief"), false) => {
                forbid(m.scale_mm.is_some(), &["material", "meso", "scale_mm"], "scale_mm applies only to procedural = \"noise\"; remove it".into())?;
                Ok(Meso::Relief {
                    contrast: contrast()?,
                })
            }
            (Some("noise"), false) => Ok(Meso::Noise {
                contrast: contrast()?,
                scale_mm: number(
                    key("scale_mm"),
                    "scale_mm",
                    m.scale_mm.unwrap_or(2.0),
                    &LENGTH_MM,
                    "give the noise's feature size in millimetres",
                )?,
            }),
            (Some(other), false) => Err((
                key("procedural"),
                format!("procedural meso `{other}` is unknown; use \"relief\" or \"noise\""),
            )),
        }
    }
}

fn subsurface(s: &SubsurfaceSpec) -> Result<Medium, Problem> {
    let keys = |k: &'static str| ["material", "subsurface", k];
    let sigma_a = rgb(
        &keys("sigma_a"),
        "sigma_a",
        s.sigma_a,
        &NON_NEGATIVE,
        "sigma_a is the absorption coefficient in 1/mm",
    )?;
    let sigma_s_prime = rgb(
        &keys("sigma_s_prime"),
        "sigma_s_prime",
        s.sigma_s_prime,
        &POSITIVE,
        "sigma_s_prime is the reduced scattering coefficient in 1/mm (the dipole needs scattering)",
    )?;
    let eta = number(
        at(&keys("eta")),
        "eta",
        s.eta,
        &POSITIVE,
        "eta is the relative index of refraction (about 1.3–1.5 for most translucent materials)",
    )?;
    Ok(Medium {
        sigma_a,
        sigma_s_prime,
        eta,
    })
}

fn render(r: &RenderSpec) -> Result<Option<Quality>, Problem> {
    let quality = r
        .quality
        .as_deref()
        .map(|q| {
            Quality::parse(q).map_err(|_| {
                (
                    at(&["render", "quality"]),
                    format!("quality `{q}` is unknown; use preview, standard or reference"),
                )
            })
        })
        .transpose()?;
    if let Some(knobs) = &r.knobs {
        quality
            .unwrap_or(Quality::Preview)
            .knobs()
            .with(knobs)
            .map_err(|e| {
                let path = match &e {
                    RenderError::InvalidKnob { knob, .. } => at(&["render", "knobs", knob]),
                    _ => at(&["render", "knobs"]),
                };
                (path, e.to_string())
            })?;
    }
    Ok(quality)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> (usize, usize, String) {
        match parse_scene(text, "x.toml", None) {
            Err(SceneError::Invalid {
                line, col, message, ..
            }) => (line, col, message),
            other => panic!("expected an error, got {other:?}"),
        }
    }

    const HEAD: &str = "[scene]\nname = \"t\"\n[sample]\nshape = \"flat\"\n[material]\n";

    #[test]
    fn an_array_element_is_located_at_its_own_column() {
        let (l, c, m) = err(&format!(
            "{HEAD}model = \"ward\"\nalbedo = [0.5, 1.5, 0.2]\n"
        ));
        assert_eq!((l, c), (7, 16), "{m}");
    }

    #[test]
    fn conflicting_and_misplaced_keys_say_what_to_do() {
        let (l, _, m) = err(&format!(
            "{HEAD}model = \"blinn_phong\"\nalpha = 0.1\nexponent = 50.0\n"
        ));
        assert_eq!(l, 8);
        assert!(m.contains("either `alpha` or `exponent`"), "{m}");
        let (_, _, m) = err(&format!("{HEAD}model = \"ggx\"\ntangent_deg = 10.0\n"));
        assert!(m.contains("ward_aniso"), "{m}");
        let (l, _, m) = err(&format!(
            "{HEAD}model = \"ward\"\n[material.meso]\nprocedural = \"relief\"\n"
        ));
        assert_eq!(l, 7);
        assert!(m.contains("add [material.subsurface]"), "{m}");
        let (_, _, m) = err(
            "[scene]\nname = \"t\"\n[sample]\nshape = \"bowl\"\nradius_mm = 5.0\ndepth_mm = 6.0\n",
        );
        assert!(m.contains("must not exceed radius_mm"), "{m}");
        let (l, _, m) = err("[scene]\nname = \"t\"\n[sample]\nshape = \"height_image\"\n");
        assert_eq!(l, 4);
        assert!(m.contains("needs `path`"), "{m}");
    }

    #[test]
    fn defaults_follow_the_model_and_medium() {
        let scene = parse_scene(
            &format!(
                "{HEAD}model = \"ggx\"\n[material.subsurface]\nsigma_a = [0.1, 0.1, 0.1]\nsigma_s_prime = [1.0, 1.0, 1.0]\neta = 1.3\n"
            ),
            "x.toml",
            None,
        )
        .expect("valid");
        let m = scene.material.expect("material");
        assert!(matches!(m.albedo, Param::Const(a) if a == Vec3A::ZERO));
        assert!(matches!(m.ks, Param::Const(k) if k == 0.04));
        assert_eq!(m.medium.map(|m| m.eta), Some(1.3));
    }
}
