//! `stagehand process --products hdr`: every capture of a run (each camera's frames of one
//! step: a bracket or a single exposure) merged into HDR radiance through the cameras'
//! inverse responses, divided by the white balance of the lamp that lit it when a colour
//! calibration is given, and written as one OpenEXR product per (step, camera). Products
//! already made from the same frames, calibrations and settings are skipped, so an
//! interrupted run resumes where it stopped.

use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_hdr::encode_exr;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::colour_calibration::ColourSet;
use crate::error::ProcessingError;
use crate::hdr_frame::{MergeWeight, PixelState, RgbExposure, merge_rgb_frames};
use crate::response_calibration::{CameraResponse, ResponseSet};
use crate::run_frames::{BracketKey, bracket_keys, dataset_err, decode_frame_in, open_run};

/// The calibrations an HDR product is made with.
#[derive(Debug, Clone, Copy)]
pub struct HdrCalibrations<'a> {
    /// The response calibration and its id.
    pub response: (&'a ResponseSet, &'a str),
    /// The colour calibration and its id, if white balance is applied.
    pub colour: Option<(&'a ColourSet, &'a str)>,
    /// How exposures are weighted.
    pub weight: MergeWeight,
}

/// What a `process --products hdr` pass did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct HdrSummary {
    /// Products written now.
    pub written: usize,
    /// Products already current, skipped.
    pub skipped: usize,
    /// Merged samples saturated in every exposure (lower bounds).
    pub saturated_samples: u64,
    /// Merged samples black in every exposure (upper bounds).
    pub black_samples: u64,
}

/// The white balance scales of one capture: the colour calibration's S for the one lamp that
/// was on, `[1, 1, 1]` without a colour calibration or with other than one lamp on.
fn scales(
    key: &BracketKey,
    cal: &HdrCalibrations<'_>,
) -> Result<Option<[f64; 3]>, ProcessingError> {
    let Some((colour, id)) = cal.colour else {
        return Ok(None);
    };
    let [lamp] = key.meta.lamps_on.as_slice() else {
        return Ok(None);
    };
    let scale = colour
        .get(&key.camera)
        .and_then(|c| c.lamps.get(lamp))
        .map(|l| l.fit.scale)
        .ok_or_else(|| ProcessingError::CalibrationMismatch {
            id: id.to_string(),
            why: format!(
                "it has no white balance for camera `{}` under lamp `{lamp}` (step {}); calibrate the colour of this rig's cameras and lamps",
                key.camera, key.step
            ),
        })?;
    Ok(Some(scale))
}

/// Writes the HDR product of every capture of the run in `store`, calling `progress(done,
/// total)` after each. Refuses a calibration that does not cover a camera or lamp the run
/// uses, before writing anything.
pub fn hdr_products(
    store: &mut ProductStore,
    cal: HdrCalibrations<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<HdrSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let reader = open_run(&run_dir)?;
    let keys = bracket_keys(&reader, |_| true)?;
    let (responses, response_id) = cal.response;
    // Every camera and lamp checked before the first product.
    let mut plans = Vec::with_capacity(keys.len());
    for key in &keys {
        let response =
            responses
                .get(&key.camera)
                .ok_or_else(|| ProcessingError::CalibrationMismatch {
                    id: response_id.to_string(),
                    why: format!(
                        "it has no response for camera `{}`; it covers {}",
                        key.camera,
                        responses.keys().cloned().collect::<Vec<_>>().join(", ")
                    ),
                })?;
        plans.push((key, response, scales(key, &cal)?));
    }
    let mut calibrations = vec![response_id.to_string()];
    if let Some((_, id)) = cal.colour {
        calibrations.push(id.to_string());
    }
    let mut summary = HdrSummary::default();
    let total = plans.len();
    let mut done = 0;
    // Batches of a few captures per core: merged on every core, written in order, so memory
    // stays bounded whatever the run's size.
    let batch = 2 * rayon::current_num_threads().max(1);
    for chunk in plans.chunks(batch) {
        let mut todo = Vec::new();
        for (key, response, scale) in chunk {
            let new = NewProduct {
                kind: "hdr".into(),
                key: format!("hdr/s{:06}/{}", key.step, key.camera),
                file_name: format!("s{:06}_{}.exr", key.step, key.camera),
                inputs: key.frames.iter().map(|f| f.path.clone()).collect(),
                calibrations: calibrations.clone(),
                software: software.to_string(),
                parameters: serde_json::json!({
                    "weight": cal.weight,
                    "white_balance": scale,
                }),
            };
            if store.is_current(&new).map_err(dataset_err(&run_dir))? {
                summary.skipped += 1;
                done += 1;
                progress(done, total);
            } else {
                todo.push((*key, *response, *scale, new));
            }
        }
        let made: Vec<(NewProduct, Vec<u8>, u64, u64)> = todo
            .into_par_iter()
            .map(|(key, response, scale, new)| {
                let (bytes, saturated, black) = merge_one(
                    &run_dir,
                    key,
                    response,
                    scale,
                    &calibrations,
                    &new,
                    cal.weight,
                )?;
                Ok((new, bytes, saturated, black))
            })
            .collect::<Result<_, ProcessingError>>()?;
        for (new, bytes, saturated, black) in made {
            store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
            summary.written += 1;
            summary.saturated_samples += saturated;
            summary.black_samples += black;
            done += 1;
            progress(done, total);
        }
    }
    Ok(summary)
}

/// Merges one capture and encodes it: the OpenEXR bytes and the samples clipped and black in
/// every exposure.
fn merge_one(
    run_dir: &Path,
    key: &BracketKey,
    response: &CameraResponse,
    scale: Option<[f64; 3]>,
    calibrations: &[String],
    new: &NewProduct,
    weight: MergeWeight,
) -> Result<(Vec<u8>, u64, u64), ProcessingError> {
    let decoded = key
        .frames
        .iter()
        .map(|f| decode_frame_in(run_dir, f))
        .collect::<Result<Vec<_>, _>>()?;
    let bracket: Vec<RgbExposure<'_>> = decoded
        .iter()
        .zip(&key.frames)
        .map(|(d, f)| RgbExposure {
            exposure_s: f.meta.exposure_s,
            dn: &d.pixels,
        })
        .collect();
    let (w, h) = (key.meta.width as usize, key.meta.height as usize);
    let merged = merge_rgb_frames(
        &bracket,
        w,
        h,
        &response.channels,
        scale.unwrap_or([1.0; 3]),
        weight,
    )?;
    let count = |state: PixelState| merged.state.iter().filter(|s| **s == state).count() as u64;
    let (saturated, black) = (count(PixelState::AtLeast), count(PixelState::AtMost));
    let metadata = serde_json::json!({
        "camera": key.camera,
        "step": key.step,
        "lamps_on": key.meta.lamps_on,
        "axes_deg": key.meta.axes_deg,
        "exposures_s": key.frames.iter().map(|f| f.meta.exposure_s).collect::<Vec<_>>(),
        "units": if scale.is_some() { "reflectance of a white diffuser" } else { "the response calibration's relative radiance" },
        "saturated_samples": saturated,
        "black_samples": black,
        "calibrations": calibrations,
    });
    let bytes = encode_exr(
        &new.file_name,
        key.meta.width,
        key.meta.height,
        &merged.rgb,
        &metadata.to_string(),
    )
    .map_err(dataset_err(run_dir))?;
    Ok((bytes, saturated, black))
}
