//! `stagehand process RUN`: products computed from a run's frames with stored calibrations,
//! written into the run (`products/`, indexed in its `products` table): HDR images, images
//! rectified onto the reference plane, and the BTF. An interrupted `process` resumes:
//! products already made the same way are skipped.

use std::collections::BTreeMap;
use std::path::PathBuf;

use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use stagehand_dataset::products::ProductStore;
use stagehand_devices::rig::{AxisRole, LampKind};
use stagehand_processing::btf_layout::{BtfAxes, LampPlacement, btf_layout};
use stagehand_processing::calibrate_geometry::CameraGeometry;
use stagehand_processing::calibration_store::{self, CalibrationKind};
use stagehand_processing::capture_products::{
    HdrCalibrations, Outputs, ProductSummary, Rectification, capture_products,
};
use stagehand_processing::colour_calibration::ColourSet;
use stagehand_processing::depth_products::{DepthMethod, DepthSetup, DepthSummary, depth_products};
use stagehand_processing::dipole_products::DipoleSummary;
use stagehand_processing::hdr_frame::MergeWeight;
use stagehand_processing::laser_plane_calibration::LaserPlanesResult;
use stagehand_processing::laser_planes::LaserPlanes;
use stagehand_processing::local_products::LocalSummary;
use stagehand_processing::mdf_merge::MergeOptions;
use stagehand_processing::mdf_products::{MdfSetup, MdfSummary, mdf_products};
use stagehand_processing::rectify::RectifyGrid;
use stagehand_processing::response_calibration::ResponseSet;
use stagehand_processing::run_frames::{bracket_keys, open_run};
use stagehand_processing::space_time::SpaceTimeOptions;
use stagehand_processing::surface_products::{SurfaceSummary, surface_products};

use stagehand_processing::reflectometer_calibration::SourceCalibration;
use stagehand_processing::reflectometer_products::{
    NOMINAL, ReflectometerSetup, ReflectometerSummary, reflectometer_products,
};
use stagehand_processing::ward_fit::WardFitOptions;

use super::calibrate::{processing_err, root_of, run_rig, store_err};
use super::calibrate_reflectometer::ReflectometerRig;
use super::process_dipole::{QuasiRun, dipole_fits, local_inputs, local_maps};
use crate::session::SessionError;

/// The products `process` can make.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Product {
    /// HDR radiance per capture and camera (OpenEXR), through the response calibration and,
    /// when given, the colour calibration's white balance.
    Hdr,
    /// Each capture's HDR radiance rectified onto the reference plane (OpenEXR RGBA, A = 1
    /// where the camera saw the pixel), through the geometric calibration.
    Rectified,
    /// The BTF: one Zarr v3 group `products/btf/btf.zarr` with `radiance [view, light, y, x,
    /// rgb]` and `seen [view, y, x]`, views and lights in sample-frame angles.
    Btf,
    /// A depth image per laser sweep and camera (OpenEXR `D`: distance along the pixel's ray,
    /// mm, −1 unknown; `T`: peak time in frames), by space-time analysis against the laser
    /// sheets of a `laser-planes-…` calibration (else the rig file's), through the geometric
    /// calibration. Needs no response calibration.
    Depth,
    /// Each view's depth images (a camera at one turntable angle, one image per laser
    /// direction) merged over the directions (seed eqs 4.44–4.45, with outlying directions
    /// left out) into its MDF: OpenEXR `D`, `S` (2 measured, 1 inpainted, 0 none), `N`, `W`,
    /// and an 8-bit PNG as the seed stores it. Makes the depth images first.
    Mdf,
    /// The sample's surface from every view's MDF, on the rectified images' grid: a height
    /// map (`products/height/height.exr`), a normal map (`normal/normal.exr`) and a point
    /// cloud (`cloud/sample.ply`). Makes the depth images and MDFs first.
    Surface,
    /// A reflectometer run's isotropic Ward maps per camera (OpenEXR `rho_d.R/G/B`, `rho_s`,
    /// `alpha`, `rms`, `flags`, and a PNG preview of ρd), fitted to the tube sweep (combined
    /// with a sweep of the sample turned 90°, which flags anisotropy), through the response
    /// and `reflectometer-…` calibrations; the geometry calibration's cameras, else the rig
    /// file's.
    Ward,
    /// A reflectometer run's transparency map per camera from its backlight frame (OpenEXR
    /// `T.R/G/B`, `flags`, and a PNG preview), through the response and `reflectometer-…`
    /// calibrations.
    Transparency,
    /// A quasi-homogeneous run's dipole fit per laser colour (`products/dipole/<nm>nm.json`:
    /// α′, σ′t, R, the profile fitted and each camera's own fit), from the lines at normal
    /// incidence, the laser's power measured on the reference of `--reference-albedo`; through
    /// the response calibration and the geometry calibration's cameras, else the rig file's.
    Dipole,
    /// With the dipole fit, the mesostructure's exit function of each view (a camera at a
    /// turntable angle) from its sweep at normal incidence: `products/exit/<nm>nm_<cam>_<deg>deg.exr`
    /// (`exit`: the light each point sent over what the fitted homogeneous medium sends,
    /// `weight`: how well the lines lit it; 0 where they did not), in the camera's pixels.
    Exit,
    /// With the dipole fit, the mesostructure's entrance function per laser colour from step
    /// 1's oblique lines (`products/entrance/<nm>nm.json`: per direction of incidence, the
    /// light entering relative to normal incidence, per camera and averaged).
    Entrance,
    /// The local reflectance function of every halogen capture of step 3 (seed eq. 5.67):
    /// `products/local/<cam>_<table>deg_arc<arc>deg_<lamp>.exr` in the camera's pixels, the
    /// capture less the dipole's global term in reflectance-factor units (`local.R/G/B`,
    /// clamped at 0; `known.R/G/B`; `global.R/G/B`, the term subtracted). Makes the dipole
    /// fits, exit and entrance functions first; needs a colour calibration of the lamps.
    Local,
}

/// `--depth-method`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DepthMethodArg {
    /// Each pixel's peak time over the sweep (Curless–Levoy).
    SpaceTime,
    /// The line's peak across each column or row of every frame (Horus, FabScan).
    PerFrame,
}

/// Arguments of `stagehand process`.
#[derive(Args, Debug)]
pub struct ProcessArgs {
    /// The run to process.
    pub run_dir: PathBuf,
    /// Products to make, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "hdr")]
    pub products: Vec<Product>,
    /// A calibration to use, by id (repeatable): one `response-…`, optionally one `colour-…`,
    /// for `rectified`, `btf` and `depth` one `geometry-…`, and for `depth` optionally one
    /// `laser-planes-…`, from `calibrations/` beside the run.
    /// Default: those the run's rig file named (`[calibration]`, recorded in its manifest).
    #[arg(long = "calibration")]
    pub calibrations: Vec<String>,
    /// Pixels per side of rectified images and the BTF (the seed uses 128 or 256).
    #[arg(long, default_value_t = 256)]
    pub size_px: usize,
    /// Side of the square of the reference plane to rectify, mm. Default: the simulated
    /// sample's size; required for a real rig's runs.
    #[arg(long)]
    pub square_mm: Option<f64>,
    /// Centre of that square on the reference plane, mm (x,y in the sample frame).
    #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [0.0, 0.0])]
    pub centre_mm: Vec<f64>,
    /// How `depth` turns a sweep into depth: `space-time` (each pixel's peak time over the
    /// sweep) or `per-frame` (the naive baseline: the line's peak in each frame; products of
    /// kind `depth_per_frame`).
    #[arg(long, value_enum, default_value = "space-time")]
    pub depth_method: DepthMethodArg,
    /// Only these cameras' captures, comma-separated (e.g. those a geometric calibration
    /// covers). Default: every camera's.
    #[arg(long, value_delimiter = ',')]
    pub cameras: Vec<String>,
    /// `dipole`: the albedo of the reference the laser's power is measured on (one value, or
    /// R,G,B). Required for `dipole`.
    #[arg(long, value_delimiter = ',', num_args = 1..=3)]
    pub reference_albedo: Vec<f64>,
    /// `dipole`: the reference's fixture name in the frames.
    #[arg(long, default_value = "opal_reference")]
    pub reference_fixture: String,
    /// `dipole`: the sample's relative index of refraction η (the seed's 1.3 unless known).
    #[arg(long, default_value_t = 1.3)]
    pub eta: f64,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The calibrations `process` was given or found, decoded.
#[derive(Default)]
pub(super) struct Calibrations {
    pub(super) response: Option<(ResponseSet, String)>,
    pub(super) colour: Option<(ColourSet, String)>,
    /// The response calibration the colour calibration was made through.
    pub(super) colour_response: String,
    pub(super) geometry: Option<(BTreeMap<String, CameraGeometry>, String)>,
    pub(super) laser_planes: Option<(LaserPlanes, String)>,
    /// The sources per camera, the id, and the response calibration it was made through.
    pub(super) reflectometer: Option<(BTreeMap<String, SourceCalibration>, String, String)>,
}

/// Loads calibrations `ids`, at most one of each kind.
fn load_calibrations(root: &std::path::Path, ids: &[String]) -> Result<Calibrations, SessionError> {
    let mut found = Calibrations::default();
    for id in ids {
        let stored = calibration_store::load(root, id).map_err(store_err)?;
        let kind = stored.calibration.kind;
        let twice = || {
            SessionError::Io(format!(
                "--calibration {id}: a {} calibration is given twice; give one",
                kind.as_str()
            ))
        };
        match kind {
            CalibrationKind::Response if found.response.is_some() => return Err(twice()),
            CalibrationKind::Response => {
                found.response = Some((stored.result(kind).map_err(store_err)?, stored.id.clone()));
            }
            CalibrationKind::Colour if found.colour.is_some() => return Err(twice()),
            CalibrationKind::Colour => {
                found.colour = Some((stored.result(kind).map_err(store_err)?, stored.id.clone()));
                found.colour_response = stored.calibration.parameters["response"]
                    .as_str()
                    .unwrap_or_default()
                    .to_string();
            }
            CalibrationKind::Geometry if found.geometry.is_some() => return Err(twice()),
            CalibrationKind::Geometry => {
                let cameras = stored
                    .cameras()
                    .map_err(store_err)?
                    .into_iter()
                    .map(|g| (g.camera.clone(), g))
                    .collect();
                found.geometry = Some((cameras, stored.id.clone()));
            }
            CalibrationKind::LaserPlanes if found.laser_planes.is_some() => return Err(twice()),
            CalibrationKind::LaserPlanes => {
                let planes: LaserPlanesResult = stored.result(kind).map_err(store_err)?;
                found.laser_planes = Some((planes.planes, stored.id.clone()));
            }
            CalibrationKind::Reflectometer if found.reflectometer.is_some() => return Err(twice()),
            CalibrationKind::Reflectometer => {
                let through = stored.calibration.parameters["response"]
                    .as_str()
                    .unwrap_or_default()
                    .to_string();
                found.reflectometer = Some((
                    stored.result(kind).map_err(store_err)?,
                    stored.id.clone(),
                    through,
                ));
            }
        }
    }
    Ok(found)
}

/// Runs `stagehand process`.
pub fn process(args: ProcessArgs) -> Result<i32, SessionError> {
    let root = root_of(&args.run_dir);
    let (manifest, rig) = run_rig(&args.run_dir)?;
    let ids: Vec<String> = if args.calibrations.is_empty() {
        manifest
            .calibrations
            .iter()
            .filter(|(kind, _)| {
                matches!(
                    kind.as_str(),
                    "response" | "colour" | "geometry" | "laser-planes" | "reflectometer"
                )
            })
            .map(|(_, id)| id.clone())
            .collect()
    } else {
        args.calibrations.clone()
    };
    let found = load_calibrations(&root, &ids)?;
    let want = |p: Product| args.products.contains(&p);
    let merging = want(Product::Hdr) || want(Product::Rectified) || want(Product::Btf);
    if merging && found.response.is_none() {
        return Err(SessionError::Io(
            "process needs a response calibration for hdr, rectified and btf: --calibration response-…, or name one in the rig file's [calibration] table before the capture (make one with `stagehand calibrate response`)".into(),
        ));
    }
    let rectifying = want(Product::Rectified) || want(Product::Btf);
    let cameras = (!args.cameras.is_empty()).then_some(args.cameras.as_slice());
    if let Some(unknown) = args.cameras.iter().find(|c| rig.camera(c).is_none()) {
        return Err(SessionError::Io(format!(
            "--cameras: the run's rig has no camera `{unknown}`; it has {}",
            rig.cameras
                .iter()
                .map(|c| c.id.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let turntable = rig
        .axis_with_role(AxisRole::Turntable)
        .map(|a| a.id.clone());
    let surface = want(Product::Surface);
    let mdf = want(Product::Mdf) || surface;
    let grid = if rectifying || mdf {
        let size_mm = match (args.square_mm, manifest.sim.as_ref()) {
            (Some(mm), _) => mm,
            (None, Some(sim)) => sim.sample_size_mm,
            (None, None) => {
                return Err(SessionError::Io(
                    "rectified images, the BTF and the MDF need the sample's square of the reference plane: give --square-mm (the sample's side in mm)".into(),
                ));
            }
        };
        if !(size_mm.is_finite() && size_mm > 0.0 && (1..=4096).contains(&args.size_px)) {
            return Err(SessionError::Io(format!(
                "--square-mm {size_mm} --size-px {}: the square needs a positive side and 1 to 4096 pixels",
                args.size_px
            )));
        }
        Some(RectifyGrid {
            centre_mm: (args.centre_mm[0], args.centre_mm[1]),
            size_mm,
            pixels: args.size_px,
        })
    } else {
        None
    };
    let rectification = match (grid.filter(|_| rectifying), &found.geometry) {
        (Some(grid), Some((cameras, id))) => Some(Rectification {
            geometry: (cameras, id.as_str()),
            grid,
            turntable_axis: turntable.as_deref(),
        }),
        (Some(_), None) => {
            return Err(SessionError::Io(
                "rectified images and the BTF need a geometric calibration: --calibration geometry-…, or name one in the rig file's [calibration] table (make one with `stagehand calibrate geometry`)".into(),
            ));
        }
        (None, _) => None,
    };
    let layout = match (&found.geometry, want(Product::Btf)) {
        (Some((geometry, _)), true) => {
            let lamps: Vec<LampPlacement> = rig
                .lamps
                .iter()
                .filter(|l| l.kind == LampKind::Halogen)
                .map(|l| LampPlacement {
                    id: l.id.clone(),
                    elevation_deg: l.elevation_deg,
                    distance_mm: l.distance_mm,
                })
                .collect();
            let axes = BtfAxes {
                turntable: turntable.clone(),
                light_arc: rig.axis_with_role(AxisRole::LightArc).map(|a| a.id.clone()),
            };
            let reader = open_run(&args.run_dir).map_err(processing_err)?;
            let keys = bracket_keys(&reader, |m| cameras.is_none_or(|c| c.contains(&m.camera)))
                .map_err(processing_err)?;
            Some(
                btf_layout(&args.run_dir, &keys, geometry, &lamps, &axes)
                    .map_err(processing_err)?,
            )
        }
        _ => None,
    };
    let mut store =
        ProductStore::open(&args.run_dir).map_err(|e| SessionError::Io(e.to_string()))?;
    let software = format!("stagehand {}", env!("CARGO_PKG_VERSION"));
    let mut summary = ProductSummary::default();
    if let Some((responses, response_id)) = found.response.as_ref().filter(|_| merging) {
        let cal = HdrCalibrations {
            response: (responses, response_id),
            colour: found.colour.as_ref().map(|(set, id)| (set, id.as_str())),
            weight: MergeWeight::HatTimesExposure,
        };
        let outputs = Outputs {
            hdr: want(Product::Hdr),
            rectified: want(Product::Rectified),
            btf: layout.as_ref(),
            rectification,
            cameras,
        };
        summary = with_progress("captures", |progress| {
            capture_products(&mut store, cal, outputs, &software, progress)
        })
        .map_err(processing_err)?;
    }
    let depth = if want(Product::Depth) || mdf {
        let (geometry, geometry_id) = found.geometry.as_ref().ok_or_else(|| {
            SessionError::Io(
                "depth needs a geometric calibration: --calibration geometry-…, or name one in the rig file's [calibration] table (make one with `stagehand calibrate geometry`)".into(),
            )
        })?;
        let laser = rig.laser.as_ref().ok_or_else(|| {
            SessionError::Io(format!(
                "depth needs a laser, and the run's rig `{}` has none",
                rig.rig.name
            ))
        })?;
        let setup = DepthSetup {
            geometry: (geometry, geometry_id),
            laser_distance_mm: laser.distance_mm,
            turntable_axis: turntable.as_deref(),
            light_arc_axis: rig
                .axis_with_role(AxisRole::LightArc)
                .map(|a| a.id.as_str()),
            options: SpaceTimeOptions::default(),
            laser_planes: found
                .laser_planes
                .as_ref()
                .map(|(planes, id)| (planes, id.as_str())),
            cameras,
            method: match args.depth_method {
                DepthMethodArg::SpaceTime => DepthMethod::SpaceTime,
                DepthMethodArg::PerFrame => DepthMethod::PerFrame,
            },
        };
        let made = with_progress("sweeps", |progress| {
            depth_products(&mut store, setup, &software, progress)
        })
        .map_err(processing_err)?;
        Some(made)
    } else {
        None
    };
    let mdf = match (mdf, &found.geometry, grid) {
        (true, Some((geometry, geometry_id)), Some(square)) => {
            let setup = MdfSetup {
                geometry: (geometry, geometry_id),
                square,
                merge: MergeOptions::default(),
                cameras,
            };
            let made = with_progress("views", |progress| {
                mdf_products(&mut store, setup, &software, progress)
            })
            .map_err(processing_err)?;
            Some(made)
        }
        _ => None,
    };
    let surface = match (surface, &found.geometry, grid) {
        (true, Some((geometry, geometry_id)), Some(grid)) => {
            surface_products(&mut store, (geometry, geometry_id), grid, &software)
                .map_err(processing_err)?
        }
        _ => None,
    };
    let reflectometer = if want(Product::Ward) || want(Product::Transparency) {
        Some(reflectometer_maps(
            &args, &found, &rig, &root, &mut store, &software,
        )?)
    } else {
        None
    };
    let local = want(Product::Local);
    if local {
        local_inputs(&found)?;
    }
    let quasi = QuasiRun {
        args: &args,
        found: &found,
        rig: &rig,
        root: &root,
        turntable: turntable.as_deref(),
        software: &software,
    };
    let dipole = if want(Product::Dipole) || want(Product::Exit) || want(Product::Entrance) || local
    {
        Some(dipole_fits(&quasi, &mut store)?)
    } else {
        None
    };
    let local = if local {
        Some(local_maps(&quasi, &mut store)?)
    } else {
        None
    };
    let report = Report {
        summary,
        reflectometer,
        dipole,
        local,
        btf_layout: layout.as_ref().map(|l| BtfReport {
            views: l.views.len(),
            lights: l.lights.len(),
            cells: l.cells.len(),
            left_out: l.left_out.clone(),
        }),
        depth,
        mdf,
        surface,
    };
    if args.json {
        super::print_json(&report)?;
    } else {
        print_report(&report, &args);
    }
    Ok(0)
}

/// The Ward and transparency maps of a reflectometer run.
fn reflectometer_maps(
    args: &ProcessArgs,
    found: &Calibrations,
    rig: &stagehand_devices::rig::RigSpec,
    root: &std::path::Path,
    store: &mut ProductStore,
    software: &str,
) -> Result<ReflectometerSummary, SessionError> {
    let reflectometer = ReflectometerRig::of(rig)?;
    let (responses, response_id) = found.response.as_ref().ok_or_else(|| {
        SessionError::Io(
            "ward and transparency need a response calibration: --calibration response-… (the one the reflectometer calibration was made through)".into(),
        )
    })?;
    let (sources, sources_id, through) = found.reflectometer.as_ref().ok_or_else(|| {
        SessionError::Io(
            "ward and transparency need a reflectometer calibration: --calibration reflectometer-… (make one with `stagehand calibrate reflectometer` on a run over the reference sample)".into(),
        )
    })?;
    if through != response_id {
        return Err(SessionError::Io(format!(
            "--calibration {sources_id} was made through response calibration {through}, not {response_id}: the tube's intensity is in that calibration's units; process with --calibration {through}"
        )));
    }
    let (geometry, geometry_id) = cameras_geometry(args, found, rig, root)?;
    let setup = ReflectometerSetup {
        response: (responses, response_id),
        sources: (sources, sources_id),
        geometry: (&geometry, &geometry_id),
        lamps: reflectometer.lamps(),
        tube: reflectometer.tube_geometry,
        travel_mm: reflectometer.travel_mm,
        ward: args.products.contains(&Product::Ward),
        transparency: args.products.contains(&Product::Transparency),
        options: WardFitOptions::default(),
        cameras: (!args.cameras.is_empty()).then_some(args.cameras.as_slice()),
    };
    let made = with_progress("cameras", |progress| {
        reflectometer_products(store, setup, software, progress)
    })
    .map_err(processing_err)?;
    Ok(made)
}

/// The cameras' geometry and its id: the geometry calibration's, else the rig file's
/// ([`NOMINAL`]), for the cameras asked for.
pub(super) fn cameras_geometry(
    args: &ProcessArgs,
    found: &Calibrations,
    rig: &stagehand_devices::rig::RigSpec,
    root: &std::path::Path,
) -> Result<(BTreeMap<String, CameraGeometry>, String), SessionError> {
    if let Some((g, id)) = &found.geometry {
        return Ok((g.clone(), id.clone()));
    }
    let cameras: Vec<String> = match args.cameras.is_empty() {
        true => rig.cameras.iter().map(|c| c.id.clone()).collect(),
        false => args.cameras.clone(),
    };
    Ok((
        super::calibrate_colour::camera_geometry(rig, &cameras, None, root)?,
        NOMINAL.to_string(),
    ))
}

/// cleared when the work ends, however it ends.
pub(super) fn with_progress<T>(
    what: &str,
    work: impl FnOnce(&mut dyn FnMut(usize, usize)) -> T,
) -> T {
    let bar = progress_bar(what);
    let made = work(&mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    });
    bar.finish_and_clear();
    made
}

/// A progress bar on stderr counting `what`.
fn progress_bar(what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr_with_hz(5));
    let style = ProgressStyle::with_template(&format!(
        "{{bar:30.cyan/blue}} {{pos}}/{{len}} {what}  {{eta}}"
    ))
    .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    bar
}

/// The BTF's shape and what it left out.
#[derive(Debug, serde::Serialize)]
struct BtfReport {
    views: usize,
    lights: usize,
    cells: usize,
    left_out: Vec<(usize, String, String)>,
}

/// What `process --json` prints.
#[derive(Debug, serde::Serialize)]
struct Report {
    #[serde(flatten)]
    summary: ProductSummary,
    btf_layout: Option<BtfReport>,
    depth: Option<DepthSummary>,
    mdf: Option<MdfSummary>,
    surface: Option<SurfaceSummary>,
    reflectometer: Option<ReflectometerSummary>,
    dipole: Option<DipoleSummary>,
    local: Option<LocalSummary>,
}

fn print_report(report: &Report, args: &ProcessArgs) {
    let s = &report.summary;
    if s.captures > 0 {
        println!(
            "{} captures, {} merged; {} samples saturated in every exposure, {} black in every exposure",
            s.captures, s.merged, s.saturated_samples, s.black_samples
        );
    }
    for (name, c, asked) in [
        ("hdr", s.hdr, args.products.contains(&Product::Hdr)),
        (
            "rectified",
            s.rectified,
            args.products.contains(&Product::Rectified),
        ),
        ("btf files", s.btf, args.products.contains(&Product::Btf)),
    ] {
        if asked {
            println!(
                "{name}: {} written, {} already current",
                c.written, c.skipped
            );
        }
    }
    if let Some(b) = &report.btf_layout {
        println!(
            "btf: {} views × {} lights, {} cells filled",
            b.views, b.lights, b.cells
        );
        for (step, camera, why) in b.left_out.iter().take(5) {
            println!("  left out of the btf: step {step} camera {camera}: {why}");
        }
        if b.left_out.len() > 5 {
            println!("  … and {} more left out", b.left_out.len() - 5);
        }
    }
    if let Some(d) = &report.depth {
        println!(
            "depth: {} sweeps, {} written, {} already current; {:.1} % of the written pixels have a depth",
            d.sweeps,
            d.written,
            d.skipped,
            100.0 * d.known_fraction
        );
    }
    if let Some(m) = &report.mdf {
        print!(
            "mdf: {} views, {} written, {} already current",
            m.views, m.written, m.skipped
        );
        if m.written > 0 {
            print!(
                "; {:.2} % of the sample's pixels were holes (inpainted), {} conflicts, {} left unknown",
                100.0 * m.hole_fraction,
                m.conflicts,
                m.unfilled
            );
        }
        println!();
    }
    if let Some(s) = &report.surface {
        println!(
            "surface: {} points from {} views; {:.1} % of the grid's cells measured, the rest inpainted{}",
            s.points,
            s.views,
            100.0 * s.measured_fraction,
            if s.written { "" } else { " (already current)" }
        );
    }
    if let Some(r) = &report.reflectometer {
        println!(
            "ward: {} written, {} already current; transparency: {} written, {} already current",
            r.ward_written, r.ward_skipped, r.transparency_written, r.transparency_skipped
        );
        if r.ward_written > 0 {
            println!(
                "  of the pixels on the sample plane: {:.2} % refused or fitted poorly, {:.2} % anisotropic (isotropic Ward does not fit them)",
                100.0 * r.not_converged,
                100.0 * r.anisotropic
            );
        }
    }
    if let Some(d) = &report.dipole {
        println!(
            "dipole: {} colours written, {} already current; {} exit maps and {} entrance functions written",
            d.written, d.skipped, d.exit_written, d.entrance_written
        );
        for (nm, f, r) in &d.fits {
            let flags: Vec<String> = f.flags.iter().map(|f| format!("{f:?}")).collect();
            println!(
                "  {nm} nm: α′ {:.4}, σ′t {:.4} mm⁻¹, R {:.4}; relative RMS {:.3} over {} bins; re-rendered: {:.1} % RMS over {} pixels{}",
                f.alpha_p,
                f.sigma_t_p,
                f.reflectance,
                f.relative_rms,
                f.samples,
                100.0 * r.relative_rms,
                r.pixels,
                if flags.is_empty() {
                    String::new()
                } else {
                    format!("; flagged {}", flags.join(", "))
                }
            );
        }
    }
    if let Some(l) = &report.local {
        println!(
            "local: {} maps written, {} already current, {} captures left out",
            l.written,
            l.skipped,
            l.left_out.len()
        );
        for (name, c) in ["R", "G", "B"].iter().zip(&l.channels) {
            if c.known > 0 {
                println!(
                    "  {name}: {} pixels, {:.1} % clamped at 0; the dipole's global term is {:.1} % of the light",
                    c.known,
                    100.0 * c.clamped as f64 / c.known as f64,
                    100.0 * c.global / c.captured.max(f64::MIN_POSITIVE)
                );
            }
        }
        if l.extrapolated > 0 {
            println!(
                "  {} maps light the sample from outside step 1's mounts: the entrance function extrapolated",
                l.extrapolated
            );
        }
        for o in l.left_out.iter().take(3) {
            println!("  left out: {}: {}", o.frame, o.why);
        }
    }
    println!(
        "products in {}",
        args.run_dir
            .join(stagehand_dataset::layout::PRODUCTS_DIR)
            .display()
    );
}
