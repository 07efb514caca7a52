//! `stagehand process --products dipole`: the dipole's α′ and σ′t per laser colour from a
//! quasi-homogeneous run (`sequences/quasi_homogeneous.rhai`, seed 004 Ch. 5):
//! - the laser's power per unit length φ, per camera, from the line on a reference of known
//!   albedo (Lambert: ∫L ds = ρ/π·φ across the line), with the line's own width;
//! - step 2's lines at normal incidence on the sample: each pixel near the sample's centre is
//!   placed on the sample plane by the camera's geometry, at its distance from the line (whose
//!   centre and direction are measured in the frame), and its radiance turned into the line
//!   profile's units, π·c(η)·L / (F_t(η, 1)·F_t(η, cosθo)·φ) (the simulator's exit lobe,
//!   `simulator/src/render/subsurface.rs`);
//! - the pixels of every camera and view pooled into bins across the line, the clipped core
//!   left out, and [`fit_dipole`] run on them (and on each camera alone, for a spread).
//!
//! The line's falloff is read by [`crate::dipole_profile`], the exit function made by
//! [`crate::dipole_exit`].
//!
//! The product is one JSON per colour (`dipole/<nm>nm.json`): the fit, the profile it was fitted
//! to, the reference's φ per camera and the frames left out with the reason.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::FrameMeta;
use stagehand_dataset::exr_planes::encode_exr_planes;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::calibrate_geometry::CameraGeometry;
use crate::dipole::{DipoleMedium, fresnel_transmittance, hemispherical_transmittance};
use crate::dipole_entrance::{Directions, EntranceDirection, line_amplitude};
use crate::dipole_exit::{ExitView, sees_steeply};
use crate::dipole_fit::{DipoleFit, blurred_profile};
use crate::dipole_profile::{
    Bins, LineFrame, LinePixel, PlanePixel, fit_bins, line_frame, plane_pixels, reference_line,
};
pub use crate::dipole_profile::{DipoleOptions, ProfileBin};
use crate::error::ProcessingError;
use crate::laser_sheet::laser_channel;
use crate::reflectometer_products::{NOMINAL, camera_response};
use crate::response_calibration::ResponseSet;
use crate::run_frames::{
    BracketKey, axis_angle, bracket_keys, dataset_err, merge_capture, open_run,
};

/// The reference sample that calibrates the laser's power: a fixture of known Lambert albedo.
#[derive(Debug, Clone, Copy)]
pub struct DipoleReference<'a> {
    /// Its fixture name in the frames (`opal_reference`).
    pub fixture: &'a str,
    /// Its albedo per RGB channel.
    pub albedo: [f64; 3],
}
/// What the dipole products are made with.
#[derive(Debug, Clone, Copy)]
pub struct DipoleSetup<'a> {
    /// The response calibration and its id.
    pub response: (&'a ResponseSet, &'a str),
    /// Each camera's geometry, and where it comes from (a calibration id, or [`NOMINAL`]).
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The turntable's axis id, if the rig has one.
    pub turntable_axis: Option<&'a str>,
    /// The light arc's axis id, if the rig has one (the oblique lines' azimuth).
    pub light_arc_axis: Option<&'a str>,
    /// The reference sample.
    pub reference: DipoleReference<'a>,
    /// How the profile is read.
    pub options: DipoleOptions,
    /// Only these cameras (`None`: every camera).
    pub cameras: Option<&'a [String]>,
    /// Also the exit function of each view ([`crate::dipole_exit`]).
    pub exit: bool,
    /// Also the entrance function from step 1's oblique lines ([`crate::dipole_entrance`]).
    pub entrance: bool,
}

/// The laser on the reference, as one camera saw it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReferenceLine {
    /// The laser's power per unit length, in the camera's radiance units × mm.
    pub phi: f64,
    /// The line's width across (standard deviation), mm.
    pub width_mm: f64,
}

/// A frame left out, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeftOut {
    /// The frame's path.
    pub frame: String,
    /// Why.
    pub why: String,
}

/// The fitted medium re-rendered at every pixel beside the line it was fitted to: each
/// pixel's radiance predicted from α′, σ′t, the laser's power and the Fresnel factors, against
/// the captured radiance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rerender {
    /// Pixels compared: outside the core, neither clipped nor black, within the window.
    pub pixels: usize,
    /// √(Σ(L − L̂)² / ΣL̂²) over them.
    pub relative_rms: f64,
    /// Median of |L − L̂| / L̂.
    pub median_relative: f64,
}

/// One colour's product.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DipoleProduct {
    /// The laser's wavelength, nm.
    pub colour_nm: u32,
    /// The RGB channel read.
    pub channel: usize,
    /// The sample's fixture.
    pub fixture: String,
    /// The reference's fixture and albedo in the channel read.
    pub reference: (String, f64),
    /// The reference line per camera.
    pub reference_lines: BTreeMap<String, ReferenceLine>,
    /// η assumed.
    pub eta: f64,
    /// The line width the model was blurred by (the median of the cameras'), mm.
    pub line_width_mm: f64,
    /// The core left out, mm.
    pub core_mm: f64,
    /// The pooled profile.
    pub profile: Vec<ProfileBin>,
    /// The fit of the pooled profile.
    pub fit: DipoleFit,
    /// Each camera's own fit, or why it has none.
    pub cameras: BTreeMap<String, Result<DipoleFit, String>>,
    /// The fit re-rendered against the captured pixels.
    pub rerender: Rerender,
    /// Sample frames used.
    pub frames_used: usize,
    /// Frames left out.
    pub left_out: Vec<LeftOut>,
}

/// One colour's entrance function (`entrance/<nm>nm.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EntranceProduct {
    /// The laser's wavelength, nm.
    pub colour_nm: u32,
    /// The sample's fixture.
    pub fixture: String,
    /// Every direction of incidence step 1 lit the sample from.
    pub directions: Vec<EntranceDirection>,
    /// Frames left out.
    pub left_out: Vec<LeftOut>,
}

/// What a dipole pass did.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DipoleSummary {
    /// Colours written now.
    pub written: usize,
    /// Colours already current.
    pub skipped: usize,
    /// Exit-function maps written now (one per camera and view).
    pub exit_written: usize,
    /// Entrance functions written now (one per colour).
    pub entrance_written: usize,
    /// The fits written and their re-render, by colour.
    pub fits: Vec<(u32, DipoleFit, Rerender)>,
}

/// Most pixels whose relative error is kept for the re-render's median (8 MB); beyond it an
/// evenly strided subset is kept (the sums for the RMS take every pixel).
const RERENDER_SAMPLES: usize = 1 << 21;

/// The fitted profile compared with every usable pixel's value outside the core, streamed:
/// exact sums for the RMS, and the relative errors of an evenly strided subset for the median.
struct RerenderSums {
    num: f64,
    den: f64,
    pixels: usize,
    stride: usize,
    rel: Vec<f32>,
}

impl RerenderSums {
    /// Sums for about `total` pixels.
    fn new(total: usize) -> RerenderSums {
        RerenderSums {
            num: 0.0,
            den: 0.0,
            pixels: 0,
            stride: total.div_ceil(RERENDER_SAMPLES).max(1),
            rel: Vec::new(),
        }
    }

    /// Adds a pixel's value `v` at distance `s` from the line against `medium`'s profile.
    fn add(&mut self, s: f64, v: f64, medium: &DipoleMedium, line_width_mm: f64, core_mm: f64) {
        if s.abs() <= core_mm || !v.is_finite() {
            return;
        }
        let model = blurred_profile(medium, s, line_width_mm);
        if model > 0.0 {
            self.num += (v - model).powi(2);
            self.den += model * model;
            if self.pixels.is_multiple_of(self.stride) {
                self.rel.push(((v - model) / model).abs() as f32);
            }
            self.pixels += 1;
        }
    }

    fn finish(mut self) -> Rerender {
        self.rel.sort_by(f32::total_cmp);
        Rerender {
            pixels: self.pixels,
            relative_rms: if self.den > 0.0 {
                (self.num / self.den).sqrt()
            } else {
                0.0
            },
            median_relative: self
                .rel
                .get(self.rel.len() / 2)
                .map_or(0.0, |&r| f64::from(r)),
        }
    }
}

/// A view's exit map as a product: its size, turntable angle and the frame whose truth it is
/// evaluated against.
struct ViewInfo {
    size: (usize, usize),
    table_deg: f64,
    truth_frame: String,
}

/// Each camera's plane pixels at its latest view: (turntable key, frame size, pixels).
type Planes = BTreeMap<String, (i64, (usize, usize), Vec<PlanePixel>)>;

/// A capture's view: its camera and turntable angle (in thousandths of a degree, a map key),
/// and the angle.
fn view_of(
    run_dir: &std::path::Path,
    key: &BracketKey,
    turntable_axis: Option<&str>,
) -> Result<((String, i64), f64), ProcessingError> {
    let table = axis_angle(run_dir, &key.meta, &key.frames[0].path, turntable_axis)?;
    Ok(((key.camera.clone(), (table * 1000.0).round() as i64), table))
}

/// True for a frame of step 2: the laser on, mounted for normal incidence.
fn overhead(meta: &FrameMeta, options: &DipoleOptions) -> bool {
    meta.laser_on
        && meta
            .laser_mount_deg
            .is_some_and(|m| (m - options.mount_deg).abs() <= 0.5)
}

/// Writes the dipole product of every laser colour of the run into `store`;
/// `progress(done, total)` after each colour.
pub fn dipole_products(
    store: &mut ProductStore,
    setup: DipoleSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<DipoleSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let options = setup.options;
    if !(1.0..=3.0).contains(&options.eta) {
        return Err(ProcessingError::BadParameter {
            name: "eta",
            value: options.eta,
            why: "the dipole's diffuse Fresnel fit holds for η in 1–3",
        });
    }
    let reader = open_run(&run_dir)?;
    let keep = |camera: &str| setup.cameras.is_none_or(|c| c.iter().any(|x| x == camera));
    let keys = bracket_keys(&reader, |m| overhead(m, &options) && keep(&m.camera))?;
    // Step 1's lines: the laser on, mounted anywhere but overhead.
    let oblique_keys = if setup.entrance {
        bracket_keys(&reader, |m| {
            m.laser_on && m.laser_mount_deg.is_some() && !overhead(m, &options) && keep(&m.camera)
        })?
    } else {
        Vec::new()
    };
    let mut by_colour: BTreeMap<u32, (Vec<&BracketKey>, Vec<&BracketKey>)> = BTreeMap::new();
    for k in &keys {
        let e = by_colour.entry(k.meta.laser_colour_nm).or_default();
        if k.meta.fixture == setup.reference.fixture {
            e.0.push(k);
        } else {
            e.1.push(k);
        }
    }
    by_colour.retain(|_, (_, sample)| !sample.is_empty());
    if by_colour.is_empty() {
        return Err(ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!(
                "the run has no laser line at normal incidence (laser mounted at {}°) on a sample; record one with sequences/quasi_homogeneous.rhai (step 2)",
                options.mount_deg
            ),
        });
    }
    let (geometries, geometry_id) = setup.geometry;
    let calibrations: Vec<String> = [setup.response.1, geometry_id]
        .into_iter()
        .filter(|id| *id != NOMINAL)
        .map(String::from)
        .collect();
    let mut planes = Planes::new();
    let radius = options
        .strip_mm
        .hypot(options.window_mm.max(options.reference_mm + 2.0))
        + 2.0;
    let mut summary = DipoleSummary::default();
    let total = by_colour.len();
    for (done, (nm, (references, samples))) in by_colour.iter().enumerate() {
        progress(done, total);
        let nm = *nm;
        let channel = laser_channel(nm);
        let mut fixtures: Vec<&str> = samples.iter().map(|k| k.meta.fixture.as_str()).collect();
        fixtures.sort_unstable();
        fixtures.dedup();
        if fixtures.len() > 1 {
            return Err(ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!(
                    "the {nm} nm lines at normal incidence fall on {} fixtures ({}), and none is the reference `{}`; a run holds one sample beside its reference: name the reference with --reference-fixture",
                    fixtures.len(),
                    fixtures.join(", "),
                    setup.reference.fixture
                ),
            });
        }
        let fixture = fixtures[0].to_string();
        if references.is_empty() {
            return Err(ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: format!(
                    "capture of the {nm} nm laser on the reference `{}`",
                    setup.reference.fixture
                ),
                hint: "record step 2 with its reference (sequences/quasi_homogeneous.rhai, reference=opal_reference), or name the reference's fixture (--reference-fixture)",
            });
        }
        let albedo = setup.reference.albedo[channel];
        let new = NewProduct {
            kind: "dipole".into(),
            key: format!("dipole/{nm}"),
            file_name: format!("{nm}nm.json"),
            inputs: references
                .iter()
                .chain(samples.iter())
                .flat_map(|k| k.frames.iter().map(|f| f.path.clone()))
                .collect(),
            calibrations: calibrations.clone(),
            software: software.to_string(),
            parameters: json!({
                "colour_nm": nm,
                "channel": channel,
                "geometry": geometry_id,
                "reference": {"fixture": setup.reference.fixture, "albedo": albedo},
                "options": options,
            }),
        };
        // One exit map per camera and turntable angle (a view: its pixels stay on the same
        // points of the sample through the sweep).
        let mut views: BTreeMap<(String, i64), ViewInfo> = BTreeMap::new();
        if setup.exit {
            for key in samples
                .iter()
                .filter(|k| sees_steeply(geometries.get(&k.camera), options.min_cos_out))
            {
                let (view, table) = view_of(&run_dir, key, setup.turntable_axis)?;
                views.entry(view).or_insert_with(|| ViewInfo {
                    size: (key.meta.width as usize, key.meta.height as usize),
                    table_deg: table,
                    truth_frame: key.frames[0].path.clone(),
                });
            }
        }
        let exit_new = |(camera, _): &(String, i64), view: &ViewInfo| NewProduct {
            kind: "exit".into(),
            key: format!("exit/{nm}/{camera}/{:.3}", view.table_deg),
            file_name: format!("{nm}nm_{camera}_{:.0}deg.exr", view.table_deg),
            inputs: new.inputs.clone(),
            calibrations: new.calibrations.clone(),
            software: software.to_string(),
            parameters: json!({
                "colour_nm": nm,
                "camera": camera,
                "turntable_deg": view.table_deg,
                "truth_frame": view.truth_frame,
                "dipole": new.parameters,
            }),
        };
        let oblique: Vec<&BracketKey> = oblique_keys
            .iter()
            .filter(|k| k.meta.laser_colour_nm == nm && k.meta.fixture == fixture)
            .collect();
        let entrance_new = NewProduct {
            kind: "entrance".into(),
            key: format!("entrance/{nm}"),
            file_name: format!("{nm}nm.json"),
            inputs: new
                .inputs
                .iter()
                .cloned()
                .chain(
                    oblique
                        .iter()
                        .flat_map(|k| k.frames.iter().map(|f| f.path.clone())),
                )
                .collect(),
            calibrations: new.calibrations.clone(),
            software: software.to_string(),
            parameters: json!({"colour_nm": nm, "dipole": new.parameters}),
        };
        if setup.entrance && oblique.is_empty() {
            return Err(ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: format!("oblique {nm} nm laser lines on `{fixture}` (step 1)"),
                hint: "record step 1 of sequences/quasi_homogeneous.rhai (--set step1=true), or leave `entrance` out of --products",
            });
        }
        let mut all_current = store.is_current(&new).map_err(dataset_err(&run_dir))?;
        if setup.entrance {
            all_current &= store
                .is_current(&entrance_new)
                .map_err(dataset_err(&run_dir))?;
        }
        for (k, v) in &views {
            all_current &= store
                .is_current(&exit_new(k, v))
                .map_err(dataset_err(&run_dir))?;
        }
        if all_current {
            summary.skipped += 1;
            continue;
        }
        let mut left_out = Vec::new();
        let line_of = |key: &BracketKey,
                       planes: &mut Planes|
         -> Result<Result<LineFrame, String>, ProcessingError> {
            let geometry = geometries.get(&key.camera).ok_or_else(|| {
                ProcessingError::CalibrationMismatch {
                    id: geometry_id.to_string(),
                    why: format!("it has no geometry for camera `{}`", key.camera),
                }
            })?;
            let ((camera, table_key), table) = view_of(&run_dir, key, setup.turntable_axis)?;
            let size = (key.meta.width as usize, key.meta.height as usize);
            // One view per camera is kept: a view's frames come one after another.
            let cached = planes
                .entry(camera)
                .or_insert_with(|| (i64::MIN, (0, 0), Vec::new()));
            if (cached.0, cached.1) != (table_key, size) {
                *cached = (table_key, size, plane_pixels(geometry, table, size, radius));
            }
            let plane = &cached.2;
            let response = camera_response(setup.response, &key.camera)?;
            let (hdr, _) =
                merge_capture(&reader, key, response).map_err(|e| ProcessingError::Dataset {
                    run: run_dir.display().to_string(),
                    message: format!(
                        "capture {} (camera {}): {e}",
                        key.frames[0].path, key.camera
                    ),
                })?;
            Ok(line_frame(&hdr.rgb, &hdr.state, plane, channel, &options))
        };
        // The reference: φ and the line's width per camera.
        let mut reference_lines = BTreeMap::new();
        for key in references {
            let found = line_of(key, &mut planes)?.and_then(|l| reference_line(&l, &options));
            match found {
                Ok((integral, width)) => {
                    reference_lines.insert(
                        key.camera.clone(),
                        ReferenceLine {
                            phi: std::f64::consts::PI / albedo * integral,
                            width_mm: width,
                        },
                    );
                }
                Err(why) => left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: format!("reference: {why}"),
                }),
            }
        }
        let mut widths: Vec<f64> = reference_lines.values().map(|r| r.width_mm).collect();
        widths.sort_by(f64::total_cmp);
        let Some(&line_width_mm) = widths.get(widths.len() / 2) else {
            return Err(ProcessingError::IllPosed {
                what: "laser power calibration",
                why: format!(
                    "no camera saw the {nm} nm line on the reference `{}`: {}",
                    setup.reference.fixture,
                    left_out
                        .iter()
                        .map(|l| format!("{}: {}", l.frame, l.why))
                        .collect::<Vec<_>>()
                        .join("; ")
                ),
            });
        };
        // The sample's lines, pooled and per camera.
        let c_eta = hemispherical_transmittance(options.eta);
        let t_in = fresnel_transmittance(1.0, options.eta);
        // A pixel's radiance in the profile's units, π·c(η)·L / (F_t(η, 1)·F_t(η, cosθo)·φ);
        // `None` beyond the window or for a pixel too wide across the line.
        let profile_value = |p: &LinePixel, phi: f64| {
            (p.s.abs() <= options.window_mm && p.across_mm <= options.max_footprint_mm).then(|| {
                let t_out = fresnel_transmittance(p.cos_out, options.eta);
                std::f64::consts::PI * c_eta * p.radiance / (t_in * t_out * phi)
            })
        };
        let mut pooled = Bins::default();
        let mut per_camera: BTreeMap<String, Bins> = BTreeMap::new();
        let mut frames_used = 0;
        // Pixels neither clipped nor black: the re-render's, counted for its subset's stride.
        let mut usable = 0;
        // Pass 1: the profile. The re-render and the exit maps need the fit, so they come in a
        // second pass over the frames (keeping every pixel for them held gigabytes at full
        // size).
        for key in samples {
            let Some(reference) = reference_lines.get(&key.camera) else {
                left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: "its camera has no reference line".into(),
                });
                continue;
            };
            let line = match line_of(key, &mut planes)? {
                Ok(l) => l,
                Err(why) => {
                    left_out.push(LeftOut {
                        frame: key.frames[0].path.clone(),
                        why,
                    });
                    continue;
                }
            };
            frames_used += 1;
            let bins = per_camera.entry(key.camera.clone()).or_default();
            for p in &line.pixels {
                let Some(v) = profile_value(p, reference.phi) else {
                    continue;
                };
                pooled.add(options.bin_mm, p.s, v, p);
                bins.add(options.bin_mm, p.s, v, p);
                usable += usize::from(!(p.clipped || p.black));
            }
        }
        let profile = pooled.profile(options.bin_mm);
        let (fit, core_mm) =
            fit_bins(&profile, &options, line_width_mm).map_err(|e| ProcessingError::IllPosed {
                what: "dipole fit",
                why: format!("{nm} nm on `{fixture}`: {e}"),
            })?;
        let cameras = per_camera
            .iter()
            .map(|(camera, bins)| {
                let fit = fit_bins(&bins.profile(options.bin_mm), &options, line_width_mm)
                    .map(|(f, _)| f)
                    .map_err(|e| e.to_string());
                (camera.clone(), fit)
            })
            .collect();
        let medium = DipoleMedium {
            alpha_p: fit.alpha_p,
            sigma_t_p: fit.sigma_t_p,
            eta: options.eta,
        };
        // Pass 2, view by view: the fitted medium re-rendered at every usable pixel, and each
        // view's exit map, written when its frames are summed (one view's sums held at a time).
        let mut sums = RerenderSums::new(usable);
        let mut by_view: BTreeMap<(String, i64), Vec<&BracketKey>> = BTreeMap::new();
        for key in samples
            .iter()
            .filter(|k| reference_lines.contains_key(&k.camera))
        {
            let view = view_of(&run_dir, key, setup.turntable_axis)?.0;
            by_view.entry(view).or_default().push(key);
        }
        for (k, keys) in &by_view {
            let info = views.get(k);
            let mut exit = info.map(|v| ExitView::new(v.size.0 * v.size.1));
            for key in keys {
                let reference = reference_lines[&key.camera];
                // A frame pass 1 left out (with its reason) is left out again.
                let Ok(line) = line_of(key, &mut planes)? else {
                    continue;
                };
                for p in line.pixels.iter().filter(|p| !(p.clipped || p.black)) {
                    let Some(v) = profile_value(p, reference.phi) else {
                        continue;
                    };
                    sums.add(p.s, v, &medium, line_width_mm, core_mm);
                    if let Some(exit) = exit.as_mut() {
                        exit.add(p.index, p.s, v, &medium, line_width_mm, core_mm);
                    }
                }
            }
            if let (Some(exit), Some(info)) = (exit, info) {
                let maps = exit.maps();
                let made = exit_new(k, info);
                let metadata = json!({
                    "camera": k.0,
                    "colour_nm": nm,
                    "channels": {
                        "exit": "light leaving each point over what the fitted homogeneous medium sends (the mesostructure's exit function); 0 where no line lit it",
                        "weight": "the fitted medium's light summed over the lines, over its largest in the map: how well the point was lit",
                    },
                })
                .to_string();
                let (w, h) = info.size;
                let exr = encode_exr_planes(
                    &made.file_name,
                    w as u32,
                    h as u32,
                    &["exit".to_string(), "weight".to_string()],
                    &maps,
                    &metadata,
                )
                .map_err(dataset_err(&run_dir))?;
                store.write(made, &exr).map_err(dataset_err(&run_dir))?;
                summary.exit_written += 1;
            }
        }
        let rerender = sums.finish();
        let product = DipoleProduct {
            colour_nm: nm,
            channel,
            fixture: fixture.clone(),
            reference: (setup.reference.fixture.to_string(), albedo),
            reference_lines: reference_lines.clone(),
            eta: options.eta,
            line_width_mm,
            core_mm,
            profile,
            fit: fit.clone(),
            cameras,
            rerender,
            frames_used,
            left_out,
        };
        if setup.entrance {
            let mut directions = Directions::default();
            let mut left_out = Vec::new();
            for key in &oblique {
                let mount = key.meta.laser_mount_deg.unwrap_or(options.mount_deg);
                let cos_in = (90.0 - mount).to_radians().cos();
                let amplitude = match reference_lines.get(&key.camera) {
                    _ if cos_in <= 0.05 => Err(format!("the laser at {mount}° grazes the sample")),
                    None => Err("its camera has no reference line".to_string()),
                    // In step 2's units (normal incidence's Fresnel factor in), the amplitude
                    // is f(ω_i) itself. The sheet's width on the sample grows as 1/cos θi.
                    Some(reference) => line_of(key, &mut planes)?.and_then(|line| {
                        let values: Vec<(f64, f64)> = line
                            .pixels
                            .iter()
                            .filter(|p| !(p.clipped || p.black))
                            .filter_map(|p| Some((p.s, profile_value(p, reference.phi)?)))
                            .collect();
                        line_amplitude(&values, &medium, line_width_mm / cos_in, core_mm)
                    }),
                };
                match amplitude {
                    Ok(a) => {
                        let angle = |axis: &str| key.meta.axes_deg.get(axis).copied();
                        let azimuth = setup.light_arc_axis.and_then(angle).unwrap_or(0.0)
                            - setup.turntable_axis.and_then(angle).unwrap_or(0.0);
                        directions.add(mount, azimuth, &key.camera, a);
                    }
                    Err(why) => left_out.push(LeftOut {
                        frame: key.frames[0].path.clone(),
                        why,
                    }),
                }
            }
            let directions = directions.finish();
            if directions.is_empty() {
                return Err(ProcessingError::IllPosed {
                    what: "entrance function",
                    why: format!(
                        "no oblique {nm} nm line on `{fixture}` could be read: {}",
                        left_out
                            .iter()
                            .take(3)
                            .map(|l| format!("{}: {}", l.frame, l.why))
                            .collect::<Vec<_>>()
                            .join("; ")
                    ),
                });
            }
            let entrance = EntranceProduct {
                colour_nm: nm,
                fixture: fixture.clone(),
                directions,
                left_out,
            };
            let bytes =
                serde_json::to_vec_pretty(&entrance).map_err(|e| ProcessingError::Dataset {
                    run: run_dir.display().to_string(),
                    message: format!("entrance product of {nm} nm: {e}"),
                })?;
            store
                .write(entrance_new, &bytes)
                .map_err(dataset_err(&run_dir))?;
            summary.entrance_written += 1;
        }
        let bytes = serde_json::to_vec_pretty(&product).map_err(|e| ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!("dipole product of {nm} nm: {e}"),
        })?;
        store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
        summary.written += 1;
        summary.fits.push((nm, fit, rerender));
    }
    progress(total, total);
    Ok(summary)
}
