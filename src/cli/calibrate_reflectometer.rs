//! `stagehand calibrate reflectometer RUN --response ID --albedo A --transmittance T`: the
//! reflectometer's tube intensity and backlight panel radiance per camera, from a run of
//! `sequences/reflectometer.rhai` over a reference sample of known diffuse albedo and
//! transmittance (an opal diffuser; the simulator's `opal_reference`), in the units of the
//! named response calibration. `process --products ward,transparency` then gives albedos and
//! transmittances in absolute terms.

use std::collections::BTreeMap;
use std::path::PathBuf;

use clap::Args;
use stagehand_devices::rig::{LampKind, RigSpec};
use stagehand_processing::calibration_store::{
    self, Calibration, CalibrationInput, CalibrationKind, StoredCalibration,
};
use stagehand_processing::reflectometer_calibration::{
    ReferenceSample, SourceCalibration, calibrate_sources,
};
use stagehand_processing::reflectometer_products::{
    ReflectometerLamps, as_sweep_frames, camera_response, frame_radiance, reflectometer_frames,
    sweep_radiance,
};
use stagehand_processing::response_calibration::ResponseSet;
use stagehand_processing::ward_tube::Tube;

use super::calibrate::{processing_err, root_of, run_id, run_rig, store_err};
use super::calibrate_colour::camera_geometry;
use crate::session::SessionError;

/// Arguments of `stagehand calibrate reflectometer`.
#[derive(Args, Debug)]
pub struct ReflectometerArgs {
    /// The reflectometer run over the reference sample.
    pub run_dir: PathBuf,
    /// The response calibration its frames are read through (`stagehand calibrations list`);
    /// the sample runs must be processed through the same one.
    #[arg(long, value_name = "ID")]
    pub response: String,
    /// A geometry calibration of the camera; without it, the camera as the rig file
    /// describes it (nominal).
    #[arg(long, value_name = "ID")]
    pub geometry: Option<String>,
    /// The reference's diffuse albedo: one value, or R,G,B.
    #[arg(long, value_delimiter = ',', num_args = 1..=3, required = true)]
    pub albedo: Vec<f64>,
    /// The fraction of the backlight the reference passes: one value, or R,G,B.
    #[arg(long, value_delimiter = ',', num_args = 1..=3, required = true)]
    pub transmittance: Vec<f64>,
    /// Side of the reference's square on the sample plane, mm (default: the run's
    /// `[sim] sample_size_mm`; required for a real rig's runs).
    #[arg(long, value_name = "MM")]
    pub square_mm: Option<f64>,
    /// Print the stored calibration as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What a reflectometer rig file says about the tube, the backlight and the cart.
pub struct ReflectometerRig {
    /// The tube lamps' ids.
    pub tube: Vec<String>,
    /// The backlight lamps' ids.
    pub backlight: Vec<String>,
    /// The tube's height above the sample, length and glass radius, mm.
    pub tube_geometry: Tube,
    /// The cart's travel, mm.
    pub travel_mm: f64,
}

impl ReflectometerRig {
    /// Reads the rig, or says why it is no reflectometer.
    pub fn of(rig: &RigSpec) -> Result<ReflectometerRig, SessionError> {
        let ids = |kind: LampKind| -> Vec<String> {
            rig.lamps
                .iter()
                .filter(|l| l.kind == kind)
                .map(|l| l.id.clone())
                .collect()
        };
        let tube = rig.lamps.iter().find(|l| l.kind == LampKind::Tube);
        let (Some(tube), Some(cart)) = (tube, rig.cart.as_ref()) else {
            return Err(SessionError::Io(format!(
                "the run's rig `{}` is no reflectometer: it needs a tube lamp and a cart (devices/rigs/reflectometer.toml)",
                rig.rig.name
            )));
        };
        Ok(ReflectometerRig {
            tube: ids(LampKind::Tube),
            backlight: ids(LampKind::Backlight),
            tube_geometry: Tube {
                height_mm: tube.distance_mm,
                length_mm: tube.length_mm,
                radius_mm: tube.radius_mm,
            },
            travel_mm: cart.travel_mm,
        })
    }

    /// The lamps as processing names them.
    pub fn lamps(&self) -> ReflectometerLamps<'_> {
        ReflectometerLamps {
            tube: &self.tube,
            backlight: &self.backlight,
        }
    }
}

/// One value for every channel, or three.
fn rgb(name: &str, v: &[f64]) -> Result<[f64; 3], SessionError> {
    match v {
        [x] => Ok([*x; 3]),
        [r, g, b] => Ok([*r, *g, *b]),
        _ => Err(SessionError::Io(format!(
            "--{name}: give one value or three (R,G,B), got {}",
            v.len()
        ))),
    }
}

/// Runs `stagehand calibrate reflectometer`.
pub fn run(args: ReflectometerArgs) -> Result<i32, SessionError> {
    let run_dir = &args.run_dir;
    let (manifest, rig) = run_rig(run_dir)?;
    let reflectometer = ReflectometerRig::of(&rig)?;
    let root = root_of(run_dir);
    let response = calibration_store::load(&root, &args.response).map_err(store_err)?;
    let responses: ResponseSet = response
        .result(CalibrationKind::Response)
        .map_err(store_err)?;
    let square_mm = match (args.square_mm, manifest.sim.as_ref()) {
        (Some(mm), _) => mm,
        (None, Some(sim)) => sim.sample_size_mm,
        (None, None) => {
            return Err(SessionError::Io(
                "give --square-mm: the side of the reference on the sample plane, mm".into(),
            ));
        }
    };
    let reference = ReferenceSample {
        albedo: rgb("albedo", &args.albedo)?,
        transmittance: rgb("transmittance", &args.transmittance)?,
        square_mm,
    };
    let found = reflectometer_frames(run_dir, reflectometer.lamps()).map_err(processing_err)?;
    let mut first_sweep = BTreeMap::new();
    for s in &found.sweeps {
        first_sweep.entry(s.camera.clone()).or_insert(s);
    }
    if first_sweep.is_empty() {
        return Err(SessionError::Io(format!(
            "{}: no tube sweep (3 frames or more lit by the tube alone in one block); record the reference with sequences/reflectometer.rhai",
            run_dir.display()
        )));
    }
    let cameras: Vec<String> = first_sweep.keys().cloned().collect();
    response.check_covers(&cameras, &[]).map_err(store_err)?;
    let geometry = camera_geometry(&rig, &cameras, args.geometry.as_deref(), &root)?;
    let tube = reflectometer.tube_geometry;
    let mut set: BTreeMap<String, SourceCalibration> = BTreeMap::new();
    let mut frames = Vec::new();
    for (camera, sweep) in &first_sweep {
        let response =
            camera_response((&responses, &args.response), camera).map_err(processing_err)?;
        let radiance = sweep_radiance(run_dir, sweep, response, reflectometer.travel_mm)
            .map_err(processing_err)?;
        let backlight = found
            .backlight
            .get(camera)
            .map(|f| frame_radiance(run_dir, f, response))
            .transpose()
            .map_err(processing_err)?;
        let size = (
            sweep.frames[0].meta.width as usize,
            sweep.frames[0].meta.height as usize,
        );
        let cal = calibrate_sources(
            camera,
            &tube,
            &geometry[camera],
            size,
            &as_sweep_frames(&radiance),
            backlight
                .as_ref()
                .map(|(rgb, clipped)| (rgb.as_slice(), Some(clipped.as_slice()))),
            &reference,
        )
        .map_err(processing_err)?;
        frames.extend(sweep.frames.iter().map(|f| f.path.clone()));
        frames.extend(found.backlight.get(camera).map(|f| f.path.clone()));
        set.insert(camera.clone(), cal);
    }
    let stored = store(&args, &reference, &tube, &set, frames)?;
    if args.json {
        super::print_json(&stored)?;
    } else {
        println!(
            "calibration {} ({} cameras; reference albedo {:?}, transmittance {:?}, {square_mm} mm square; geometry {})",
            stored.id,
            set.len(),
            reference.albedo,
            reference.transmittance,
            args.geometry.as_deref().unwrap_or("nominal")
        );
        for (camera, c) in &set {
            let [r, g, b] = c.tube_rgb;
            let spread = c.tube_spread.map(|s| 100.0 * s);
            println!(
                "  {camera}: tube ({r:.4e}, {g:.4e}, {b:.4e}) per mm over {} pixels, spread {:.2} / {:.2} / {:.2} %",
                c.tube_pixels, spread[0], spread[1], spread[2]
            );
            match c.panel_rgb {
                Some([r, g, b]) => println!(
                    "    backlight panel ({r:.4e}, {g:.4e}, {b:.4e}) over {} pixels",
                    c.panel_pixels
                ),
                None => println!(
                    "    no backlight frame: transparency maps cannot use this calibration"
                ),
            }
        }
        println!("stored in {}", root.join(&stored.id).display());
    }
    Ok(0)
}

/// Stores the calibration beside the run.
fn store(
    args: &ReflectometerArgs,
    reference: &ReferenceSample,
    tube: &Tube,
    set: &BTreeMap<String, SourceCalibration>,
    frames: Vec<String>,
) -> Result<StoredCalibration, SessionError> {
    let quality: serde_json::Map<String, serde_json::Value> = set
        .iter()
        .map(|(camera, c)| {
            (
                camera.clone(),
                serde_json::json!({
                    "tube_spread": c.tube_spread,
                    "tube_pixels": c.tube_pixels,
                    "panel_pixels": c.panel_pixels,
                }),
            )
        })
        .collect();
    let calibration = Calibration {
        kind: CalibrationKind::Reflectometer,
        cameras: set.keys().cloned().collect(),
        lamps: Vec::new(),
        inputs: vec![CalibrationInput {
            run_id: run_id(&args.run_dir),
            frames,
        }],
        parameters: serde_json::json!({
            "response": args.response,
            "geometry": args.geometry.as_deref().unwrap_or("nominal"),
            "reference": reference,
            "tube": {"height_mm": tube.height_mm, "length_mm": tube.length_mm, "radius_mm": tube.radius_mm},
        }),
        result: serde_json::to_value(set).map_err(|e| SessionError::Io(e.to_string()))?,
        quality: serde_json::Value::Object(quality),
        software: format!("stagehand {}", env!("CARGO_PKG_VERSION")),
    };
    calibration_store::save(&root_of(&args.run_dir), calibration).map_err(store_err)
}
