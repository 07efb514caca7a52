//! `stagehand process --products hdr`: every capture of a run (each camera's frames of one
//! step: a bracket or a single exposure) merged into HDR radiance through the cameras'
//! inverse responses, divided by the white balance of the lamp that lit it when a colour
//! calibration is given, and written as one OpenEXR product per (step, camera). Products
//! already made from the same frames, calibrations and settings are skipped, so an
//! interrupted run resumes where it stopped.

use serde::{Deserialize, Serialize};
use stagehand_dataset::exr_hdr::encode_exr;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::colour_calibration::ColourSet;
use crate::error::ProcessingError;
use crate::hdr_frame::{MergeWeight, PixelState, RgbExposure, merge_rgb_frames};
use crate::response_calibration::ResponseSet;
use crate::run_frames::{BracketKey, bracket_keys, decode_bracket, open_run};

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
    for (done, (key, response, scale)) in plans.into_iter().enumerate() {
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
        let current = store
            .is_current(&new)
            .map_err(|e| ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: e.to_string(),
            })?;
        if current {
            summary.skipped += 1;
            progress(done + 1, total);
            continue;
        }
        let decoded = decode_bracket(&reader, key)?;
        let bracket: Vec<RgbExposure<'_>> = decoded
            .iter()
            .map(|d| RgbExposure {
                exposure_s: d.exposure_s,
                dn: &d.dn,
            })
            .collect();
        let (w, h) = (key.meta.width as usize, key.meta.height as usize);
        let merged = merge_rgb_frames(
            &bracket,
            w,
            h,
            &response.channels,
            scale.unwrap_or([1.0; 3]),
            cal.weight,
        )?;
        let saturated = merged
            .state
            .iter()
            .filter(|s| **s == PixelState::AtLeast)
            .count() as u64;
        let black = merged
            .state
            .iter()
            .filter(|s| **s == PixelState::AtMost)
            .count() as u64;
        summary.saturated_samples += saturated;
        summary.black_samples += black;
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
        .map_err(|e| ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: e.to_string(),
        })?;
        store
            .write(new, &bytes)
            .map_err(|e| ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: e.to_string(),
            })?;
        summary.written += 1;
        progress(done + 1, total);
    }
    Ok(summary)
}
