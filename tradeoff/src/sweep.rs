//! The sweep: a converged reference, then each knob varied alone from the standard preset,
//! plus the three presets; every setting timed (best of N) and compared to the reference.
//!
//! Timing: each repetition uses a fresh [`Renderer`] whose sample is built first by a dark
//! frame (untimed, reported as `build_s`), then the lit frame is timed. So a frame's time
//! includes what it computes for its lights (preview shadow maps) but not the per-fixture
//! sample build, which a capture pays once.

use std::time::Instant;

use serde_json::Value;

use super::metrics::{self, ErrorMetrics};
use super::pareto::{self, Cost, Target};
use super::{Setup, TradeoffError};
use stagehand_simulator::render::quality::{Knobs, Quality};
use stagehand_simulator::render::{RadianceImage, Renderer};

/// One knob setting to measure.
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    /// Short name, e.g. `spp_side=8` or `preset standard`.
    pub label: String,
    /// The knob varied (`preset` for the presets).
    pub knob: String,
    /// Its value as text.
    pub value: String,
    /// The full knob set rendered.
    pub knobs: Knobs,
}

/// A measured setting.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// What was rendered.
    pub setting: Setting,
    /// Best wall-clock time of one lit frame, seconds.
    pub time_s: f64,
    /// Every repetition's time, seconds.
    pub times_s: Vec<f64>,
    /// Best time of the untimed-in-`time_s` sample build (dark frame), seconds.
    pub build_s: f64,
    /// Error against the reference.
    pub error: ErrorMetrics,
    /// On the Pareto front of all points.
    pub pareto: bool,
    /// The image is bit-identical to the standard preset's (the knob changes nothing here).
    pub same_as_standard: bool,
}

impl Point {
    /// Time and error for the Pareto front.
    pub fn cost(&self) -> Cost {
        Cost {
            time_s: self.time_s,
            rmse: self.error.rmse,
            rel_rmse: self.error.rel_rmse,
        }
    }
}

/// What to sweep and how.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepConfig {
    /// Timed repetitions per setting (best is kept), ≥ 1.
    pub repeat: u32,
    /// Knobs of the converged reference.
    pub reference: Knobs,
    /// The settings to measure.
    pub settings: Vec<Setting>,
}

impl SweepConfig {
    /// The default sweep: [`reference_knobs`] and [`default_settings`], best of `repeat`.
    pub fn new(repeat: u32) -> SweepConfig {
        SweepConfig {
            repeat,
            reference: reference_knobs(),
            settings: default_settings(),
        }
    }
}

/// The converged reference: the reference preset with 256 samples per pixel, 1024 samples on
/// each halogen disk, finest relief, exact shadows and more bounce, tube and dipole samples.
pub fn reference_knobs() -> Knobs {
    let mut k = Quality::Reference.knobs();
    k.preset = "converged".into();
    k.spp_side = 16;
    k.halogen_samples = 1024;
    k.tube_samples = 1024;
    k.bounces = 3;
    k.bounce_rays = 256;
    k.bounce_tolerance = 0.0;
    k.relief_mm = 0.05;
    k.shadow_maps = false;
    k.dipole_samples = 128;
    k
}

/// The three presets, then each knob alone from the standard preset (values equal to the
/// standard's are left out: the standard preset is that point). The tube is not lit on the
/// light stage, so `tube_samples` is not swept by default.
pub fn default_settings() -> Vec<Setting> {
    let standard = Quality::Standard.knobs();
    let mut out: Vec<Setting> = [Quality::Preview, Quality::Standard, Quality::Reference]
        .into_iter()
        .map(|q| Setting {
            label: format!("preset {}", q.name()),
            knob: "preset".into(),
            value: q.name().into(),
            knobs: q.knobs(),
        })
        .collect();
    let mut vary = |knob: &str, values: &[&str], set: &dyn Fn(&mut Knobs, &str)| {
        for v in values {
            let mut k = standard.clone();
            set(&mut k, v);
            if k == standard {
                continue;
            }
            k.preset = "standard+custom".into();
            out.push(Setting {
                label: format!("{knob}={v}"),
                knob: knob.into(),
                value: (*v).into(),
                knobs: k,
            });
        }
    };
    let num = |v: &str| v.parse::<u32>().unwrap_or(1);
    vary("spp_side", &["1", "2", "3", "4", "6", "8"], &|k, v| {
        k.spp_side = num(v)
    });
    vary(
        "halogen_samples",
        &["1", "2", "4", "8", "16", "32", "64"],
        &|k, v| k.halogen_samples = num(v),
    );
    vary("relief_mm", &["0.4", "0.2", "0.1", "0.05"], &|k, v| {
        k.relief_mm = v.parse().unwrap_or(0.1)
    });
    vary("shadow_maps", &["true", "false"], &|k, v| {
        k.shadow_maps = v == "true"
    });
    vary("bounces", &["0", "1", "2", "3"], &|k, v| k.bounces = num(v));
    vary("bounce_rays", &["4", "16", "64"], &|k, v| {
        k.bounce_rays = num(v)
    });
    vary("dipole_samples", &["4", "16", "64"], &|k, v| {
        k.dipole_samples = num(v)
    });
    // Adaptive sampling changes two knobs together: a contrast threshold and the sample count
    // of the pixels it refines.
    for (threshold, side) in ADAPTIVE {
        let mut k = standard.clone();
        k.preset = "standard+custom".into();
        k.adaptive_threshold = threshold;
        k.spp_side = side;
        out.push(Setting {
            label: format!("adaptive={threshold} spp_side={side}"),
            knob: "adaptive_threshold".into(),
            value: format!("{threshold}@{side}"),
            knobs: k,
        });
    }
    out
}

/// The adaptive settings swept: (contrast threshold, `spp_side` of refined pixels).
const ADAPTIVE: [(f32, u32); 7] = [
    (0.05, 2),
    (0.05, 3),
    (0.05, 4),
    (0.02, 4),
    (0.02, 8),
    (0.01, 8),
    (0.01, 16),
];

/// A finished sweep.
#[derive(Debug, Clone)]
pub struct Tradeoff {
    /// The setup rendered.
    pub setup: Setup,
    /// The reference's knobs.
    pub reference_knobs: Knobs,
    /// The converged reference image.
    pub reference: RadianceImage,
    /// Time of the reference frame (one run), seconds.
    pub reference_time_s: f64,
    /// Mean of the reference's channel values (what relative RMSE divides by).
    pub reference_mean: f64,
    /// Every measured setting, in sweep order.
    pub points: Vec<Point>,
    /// Timed repetitions per setting.
    pub repeat: u32,
    /// Worker threads of the rayon pool the frames ran on.
    pub threads: usize,
}

impl Tradeoff {
    /// Time and error of every point.
    pub fn costs(&self) -> Vec<Cost> {
        self.points.iter().map(Point::cost).collect()
    }

    /// The cheapest point meeting `target`.
    pub fn pick(&self, target: Target) -> Result<&Point, TradeoffError> {
        let labels: Vec<String> = self
            .points
            .iter()
            .map(|p| p.setting.label.clone())
            .collect();
        let i = pareto::pick(&self.costs(), &labels, target)?;
        self.points
            .get(i)
            .ok_or_else(|| TradeoffError::InvalidInput {
                what: "pick".into(),
                expected: "an index into the points".into(),
                got: i.to_string(),
            })
    }

    /// The Pareto points sorted by time.
    pub fn front(&self) -> Vec<&Point> {
        let mut f: Vec<&Point> = self.points.iter().filter(|p| p.pareto).collect();
        f.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
        f
    }

    /// The reference frame's notes (effect plan), e.g. whether interreflection is modelled.
    pub fn reference_notes(&self) -> &Value {
        &self.reference.notes
    }
}

/// Fails if the frame was rendered with other knobs than asked (a scene file's `[render]`
/// table overrides the renderer's knobs, which would make the sweep meaningless).
fn check_knobs_used(
    setup: &Setup,
    asked: &Knobs,
    img: &RadianceImage,
) -> Result<(), TradeoffError> {
    let Some(used) = img.notes.get("knobs") else {
        return Ok(());
    };
    let Ok(mut used) = serde_json::from_value::<Knobs>(used.clone()) else {
        return Ok(());
    };
    used.preset.clone_from(&asked.preset);
    if &used == asked {
        return Ok(());
    }
    Err(TradeoffError::InvalidInput {
        what: format!("scene `{}`", setup.options.scene),
        expected: "a scene without its own [render] knobs (they override the sweep's)".into(),
        got: format!("frames rendered with {used:?}"),
    })
}

/// One timed frame: (lit image, best lit time, all lit times, best build time).
fn measure(
    setup: &Setup,
    knobs: &Knobs,
    repeat: u32,
) -> Result<(RadianceImage, f64, Vec<f64>, f64), TradeoffError> {
    let mut image = None;
    let mut times = Vec::new();
    let mut build = f64::INFINITY;
    for _ in 0..repeat.max(1) {
        let renderer = Renderer::with_knobs(&setup.rig, knobs.clone())?;
        let t = Instant::now();
        renderer.radiance(&setup.dark, &setup.camera)?;
        build = build.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let img = renderer.radiance(&setup.world, &setup.camera)?;
        times.push(t.elapsed().as_secs_f64());
        check_knobs_used(setup, knobs, &img)?;
        image.get_or_insert(img);
    }
    let best = times.iter().copied().fold(f64::INFINITY, f64::min);
    let image = image.ok_or_else(|| TradeoffError::InvalidInput {
        what: "--repeat".into(),
        expected: "at least 1".into(),
        got: repeat.to_string(),
    })?;
    Ok((image, best, times, build))
}

/// Runs the sweep; `progress` receives one line per finished setting.
pub fn run(
    setup: &Setup,
    config: &SweepConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Tradeoff, TradeoffError> {
    if !(1..=1000).contains(&config.repeat) {
        return Err(TradeoffError::InvalidInput {
            what: "--repeat".into(),
            expected: "a count from 1 to 1000".into(),
            got: config.repeat.to_string(),
        });
    }
    for s in &config.settings {
        s.knobs.validate()?;
    }
    // Start the thread pool before anything is timed.
    rayon::broadcast(|_| ());
    progress("rendering the converged reference…");
    let (reference, reference_time_s, _, _) = measure(setup, &config.reference, 1)?;
    let reference_mean = metrics::mean(&reference.rgb);
    progress(&format!(
        "reference: {:.2} s, mean radiance {:.4e}",
        reference_time_s, reference_mean
    ));
    let standard = Quality::Standard.knobs();
    let standard_image = measure(setup, &standard, 1)?.0;
    let mut points = Vec::with_capacity(config.settings.len());
    for setting in &config.settings {
        let (image, time_s, times_s, build_s) = measure(setup, &setting.knobs, config.repeat)?;
        let error = metrics::compare(&reference.rgb, &image.rgb)?;
        progress(&format!(
            "{:<22} {:>9.2} ms  RMSE {:.3e}  ({:.2}%)",
            setting.label,
            time_s * 1e3,
            error.rmse,
            error.rel_rmse * 100.0
        ));
        points.push(Point {
            setting: setting.clone(),
            time_s,
            times_s,
            build_s,
            error,
            pareto: false,
            same_as_standard: image.rgb == standard_image.rgb,
        });
    }
    let costs: Vec<Cost> = points.iter().map(Point::cost).collect();
    for (p, on) in points.iter_mut().zip(pareto::front(&costs)) {
        p.pareto = on;
    }
    Ok(Tradeoff {
        setup: setup.clone(),
        reference_knobs: config.reference.clone(),
        reference,
        reference_time_s,
        reference_mean,
        points,
        repeat: config.repeat,
        threads: rayon::current_num_threads(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_settings_are_valid_and_distinct() {
        let s = default_settings();
        assert!(s.len() > 20);
        for x in &s {
            x.knobs.validate().expect(&x.label);
        }
        let mut labels: Vec<&str> = s.iter().map(|x| x.label.as_str()).collect();
        labels.sort_unstable();
        labels.dedup();
        assert_eq!(labels.len(), s.len(), "labels unique");
        assert!(
            !s.iter().any(|x| x.label == "spp_side=2"),
            "standard value skipped"
        );
        reference_knobs().validate().expect("reference valid");
    }
}
