//! The effect plan: which effects this frame's scene calls for, each with the reason, so the
//! renderer spends time only where it changes the image and the notes say why.

use serde_json::{Value, json};
use stagehand_devices::rig::LampKind;

use super::bounce::{ReliefStats, bounces_needed};
use super::laser::LaserSheet;
use super::lights::{Emitter, Light};
use super::quality::Knobs;
use super::sample::Sample;
use super::subsurface;

/// One effect switched on or off, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// Whether the renderer computes the effect.
    pub on: bool,
    /// A short reason with the numbers behind it.
    pub why: String,
}

impl Decision {
    fn on(why: impl Into<String>) -> Decision {
        Decision {
            on: true,
            why: why.into(),
        }
    }
    fn off(why: impl Into<String>) -> Decision {
        Decision {
            on: false,
            why: why.into(),
        }
    }
    fn to_json(&self) -> Value {
        json!({ "on": self.on, "why": self.why })
    }
}

/// Every effect decision for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Hard shadows by marching the height field toward each light sample.
    pub shadows: Decision,
    /// The Ward specular lobe.
    pub specular: Decision,
    /// The laser sheet.
    pub laser: Decision,
    /// Halogen lamps as 10 mm disks rather than points.
    pub area_lights: Decision,
    /// The reflectometer tube integrated along its length.
    pub linear_light: Decision,
    /// Backlight seen through the sample.
    pub backlight: Decision,
    /// Diffuse light bounced between relief texels.
    pub interreflection: Decision,
    /// Bounces simulated when `interreflection` is on (0 when off).
    pub bounces: u32,
    /// The dipole diffusion term under the surface.
    pub subsurface: Decision,
}

impl Plan {
    /// The plan as the `effects` object of the frame notes.
    pub fn to_json(&self) -> Value {
        json!({
            "direct": "always",
            "shadows": self.shadows.to_json(),
            "specular": self.specular.to_json(),
            "laser": self.laser.to_json(),
            "area_lights": self.area_lights.to_json(),
            "linear_light": self.linear_light.to_json(),
            "backlight": self.backlight.to_json(),
            "interreflection": {
                "on": self.interreflection.on,
                "why": self.interreflection.why,
                "bounces": self.bounces,
            },
            "subsurface": self.subsurface.to_json(),
        })
    }
}

/// Decides the effects for `sample` under the lit `lights` and the laser; `relief` is the
/// sample's sky-view and albedo bound ([`super::bounce::relief_stats`], `None` when flat);
/// `probe` measures the first bounce under this frame's light (its argument: whether shadows
/// are on; see [`super::bounce::probe`]) and is called only when the relief's geometric bound
/// leaves interreflection in question.
pub fn plan(
    sample: &Sample,
    lights: &[Light],
    laser: Option<(&LaserSheet, f64, u32, f64)>,
    knobs: &Knobs,
    relief: Option<&ReliefStats>,
    probe: &dyn Fn(bool) -> Option<f32>,
) -> Plan {
    let lit = laser.is_some()
        || lights
            .iter()
            .any(|l| !matches!(l.emitter, Emitter::Backlight { .. }));
    let shadows = shadows(sample, lights, laser.map(|l| l.0));
    let probe = (laser.is_none()).then_some(|| probe(shadows.on));
    let (interreflection, bounces) = interreflection(sample, relief, lit, knobs, probe);
    Plan {
        interreflection,
        bounces,
        subsurface: subsurface(sample, lit, knobs),
        shadows,
        specular: specular(sample, lights, laser.is_some()),
        laser: match laser {
            Some((_, tilt, nm, mw)) => {
                Decision::on(format!("{nm} nm sheet, {mw} mW, tilt {tilt:.2}°"))
            }
            None => Decision::off("laser off"),
        },
        area_lights: area_lights(lights, knobs),
        linear_light: linear_light(lights, knobs),
        backlight: backlight(sample, lights),
    }
}

/// A height field can shadow a point only where the terrain rises faster than the ray toward
/// the light: if its steepest slope is below the lowest light elevation, no ray is blocked.
fn shadows(sample: &Sample, lights: &[Light], laser: Option<&LaserSheet>) -> Decision {
    let zmax = sample.grid.as_ref().map_or(0.0, |g| g.zmax());
    let mut elevation = lights
        .iter()
        .filter_map(|l| l.min_elevation_rad(zmax))
        .fold(f32::INFINITY, f32::min);
    if let Some(sheet) = laser {
        let q = sheet.origin;
        let e = (q.z - zmax).atan2(q.truncate().length() + super::lights::TURNTABLE_RADIUS_MM);
        elevation = elevation.min(e);
    }
    if !elevation.is_finite() {
        return Decision::off("no lit source casts shadows");
    }
    let elev_deg = elevation.to_degrees();
    let Some(grid) = &sample.grid else {
        return Decision::off(format!(
            "flat height field: max slope 0° below light elevation {elev_deg:.1}°"
        ));
    };
    if grid.edge_max() > 1.0e-4 {
        return Decision::on(format!(
            "sample edge is a {:.2} mm cliff (slope 90°) above light elevation {elev_deg:.1}°",
            grid.edge_max()
        ));
    }
    let slope_deg = grid.max_slope().atan().to_degrees();
    if slope_deg < elev_deg {
        Decision::off(format!(
            "max slope {slope_deg:.1}° below light elevation {elev_deg:.1}°"
        ))
    } else {
        Decision::on(format!(
            "max slope {slope_deg:.1}° ≥ light elevation {elev_deg:.1}°"
        ))
    }
}

fn specular(sample: &Sample, lights: &[Light], laser: bool) -> Decision {
    let reflected = laser
        || lights
            .iter()
            .any(|l| !matches!(l.emitter, Emitter::Backlight { .. }));
    if !reflected {
        return Decision::off("no lit source reflects off the sample");
    }
    if sample.max_ks > 0.0 {
        Decision::on(format!("ks={:.2}>0", sample.max_ks))
    } else {
        Decision::off(format!("ks=0 everywhere on `{}`", sample.name))
    }
}

fn area_lights(lights: &[Light], knobs: &Knobs) -> Decision {
    if !lights.iter().any(|l| l.kind == LampKind::Halogen) {
        return Decision::off("no halogen lamp lit");
    }
    match knobs.halogen_samples {
        1 => Decision::off("halogen_samples=1: halogen lamps as point lights"),
        n => Decision::on(format!(
            "halogen lamps as 10 mm disks, {n} samples per pixel"
        )),
    }
}

fn linear_light(lights: &[Light], knobs: &Knobs) -> Decision {
    match lights.iter().find_map(|l| match l.emitter {
        Emitter::Tube {
            start,
            axis,
            length,
            ..
        } => Some(start + axis * (0.5 * length)),
        _ => None,
    }) {
        Some(c) => Decision::on(format!(
            "tube at x={:.1} mm, z={:.1} mm: {} samples per pixel along its length",
            c.x, c.z, knobs.tube_samples
        )),
        None => Decision::off("tube off"),
    }
}

fn backlight(sample: &Sample, lights: &[Light]) -> Decision {
    match lights
        .iter()
        .find(|l| matches!(l.emitter, Emitter::Backlight { .. }))
    {
        None => Decision::off("backlight off"),
        Some(_) if sample.max_transmittance <= 0.0 => {
            Decision::off(format!("`{}` is opaque", sample.name))
        }
        Some(l) => Decision::on(format!(
            "backlight at {:.0}% through transmittance up to {:.2}",
            100.0 * l.output,
            sample.max_transmittance
        )),
    }
}

/// Interreflection is worth simulating only on concave relief whose first bounce's bound
/// (ρmax·(1 − Vmin)) exceeds the tolerance, and then only if the light probe (when given: not
/// under the laser, whose sheet is thinner than the probe's texels) finds the first bounce
/// under this frame's light above it too; then as many bounces as have estimates above it
/// (bounce k: probe·(ρmax(1 − Vmin))^(k−1)), capped at the knob.
fn interreflection(
    sample: &Sample,
    relief: Option<&ReliefStats>,
    lit: bool,
    knobs: &Knobs,
    probe: Option<impl FnOnce() -> Option<f32>>,
) -> (Decision, u32) {
    let off = |why: String| (Decision::off(why), 0);
    let Some(r) = relief.filter(|_| sample.grid.is_some()) else {
        return off(format!(
            "flat sample `{}`: nothing to bounce between",
            sample.name
        ));
    };
    if !lit {
        return off("no lit source reflects off the sample".into());
    }
    if !r.concave() {
        return off(format!(
            "convex relief: every texel sees at least 99% of the sky (Vmin = {:.3})",
            r.v_min
        ));
    }
    let (per, needed, simulated) = bounces_needed(r, knobs.bounce_tolerance, knobs.bounces);
    let numbers = format!(
        "Vmin = {:.3}, ρmax = {:.2}: bound per bounce ρmax(1 − Vmin) = {per:.4}",
        r.v_min, r.rho_max
    );
    if needed == 0 {
        return off(format!(
            "concave relief but {numbers} ≤ tolerance {}",
            knobs.bounce_tolerance
        ));
    }
    if simulated == 0 {
        return off(format!(
            "{numbers} needs {needed} bounce(s) but bounces = 0"
        ));
    }
    if let Some(first) = probe.and_then(|p| p()).filter(|f| f.is_finite()) {
        let tol = knobs.bounce_tolerance;
        let probed = format!(
            "concave relief ({numbers}), but under this light the first bounce adds at most \
             {first:.4} of the mean direct irradiance (light probe: at most {} texels per side, {} rays)",
            super::bounce::PROBE_TEXELS,
            super::bounce::PROBE_RAYS
        );
        if first <= tol {
            return off(format!("{probed} ≤ tolerance {tol}"));
        }
        let mut lit_needed = 0u32;
        let mut estimate = first;
        while lit_needed < needed && estimate > tol {
            lit_needed += 1;
            estimate *= per;
        }
        let simulated = lit_needed.min(knobs.bounces);
        return (
            Decision::on(format!(
                "concave relief, {numbers}; under this light the first bounce adds up to \
                 {first:.4} of the mean direct irradiance > tolerance {tol}: {lit_needed} \
                 bounce(s) above it, {simulated} simulated (bounces = {}), {} rays per texel",
                knobs.bounces, knobs.bounce_rays
            )),
            simulated,
        );
    }
    (
        Decision::on(format!(
            "concave relief, {numbers} > tolerance {}: {needed} bounce(s) above it, {simulated} \
             simulated (bounces = {}), {} rays per texel",
            knobs.bounce_tolerance, knobs.bounces, knobs.bounce_rays
        )),
        simulated,
    )
}

/// Subsurface scattering only under a scattering medium, and only when light enters it.
fn subsurface(sample: &Sample, lit: bool, knobs: &Knobs) -> Decision {
    let media: Vec<_> = sample
        .media
        .iter()
        .filter(|m| subsurface::scatters(m))
        .collect();
    if media.is_empty() {
        return Decision::off(format!("no scattering material on `{}`", sample.name));
    }
    if !lit {
        return Decision::off("no lit source enters the sample");
    }
    let fmt3 = |v: [f64; 3], p: usize| format!("({:.p$}, {:.p$}, {:.p$})", v[0], v[1], v[2], p = p);
    let (n, h) = subsurface::resolution(&sample.media, sample.size_mm, knobs.dipole_samples);
    let parts: Vec<String> = media
        .iter()
        .map(|m| {
            let d = subsurface::dipoles(m);
            let radius = subsurface::medium_radius(m, knobs.dipole_samples, sample.size_mm as f64);
            format!(
                "σ′t = {}/mm, α′ = {}, η = {:.2}, kernel radius {radius:.1} mm",
                fmt3(d.map(|d| d.sigma_t_prime()), 2),
                fmt3(d.map(|d| d.reduced_albedo()), 4),
                m.eta
            )
        })
        .collect();
    Decision::on(format!(
        "dipole diffusion under `{}`: {}; R_d tail < {} of its energy beyond the radius; \
         {n}² texels of {h:.3} mm, {} radial samples per mean free path; single scattering \
         omitted",
        sample.name,
        parts.join("; "),
        subsurface::TAIL,
        knobs.dipole_samples
    ))
}
