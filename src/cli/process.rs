//! `stagehand process RUN`: products computed from a run's frames with stored calibrations,
//! written into the run (`products/`, indexed in its `products` table). An interrupted
//! `process` resumes: products already made the same way are skipped.

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use stagehand_dataset::products::ProductStore;
use stagehand_processing::calibration_store::{self, CalibrationKind};
use stagehand_processing::colour_calibration::ColourSet;
use stagehand_processing::hdr_frame::MergeWeight;
use stagehand_processing::hdr_products::{HdrCalibrations, hdr_products};
use stagehand_processing::response_calibration::ResponseSet;

use super::calibrate::{processing_err, root_of, store_err};
use crate::session::SessionError;

/// The products `process` can make.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Product {
    /// HDR radiance per capture and camera (OpenEXR), through the response calibration and,
    /// when given, the colour calibration's white balance.
    Hdr,
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
    /// from `calibrations/` beside the run. Default: those the run's rig file named
    /// (`[calibration]`, recorded in its manifest).
    #[arg(long = "calibration")]
    pub calibrations: Vec<String>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `stagehand process`.
pub fn process(args: ProcessArgs) -> Result<i32, SessionError> {
    let root = root_of(&args.run_dir);
    let ids = if args.calibrations.is_empty() {
        let manifest = stagehand_dataset::read_manifest(&args.run_dir)
            .map_err(|e| SessionError::Io(e.to_string()))?;
        manifest
            .calibrations
            .iter()
            .filter(|(kind, _)| matches!(kind.as_str(), "response" | "colour"))
            .map(|(_, id)| id.clone())
            .collect()
    } else {
        args.calibrations.clone()
    };
    let mut response: Option<(ResponseSet, String)> = None;
    let mut colour: Option<(ColourSet, String)> = None;
    for id in &ids {
        let stored = calibration_store::load(&root, id).map_err(store_err)?;
        let kind = stored.calibration.kind;
        let twice = |kind: &str| {
            SessionError::Io(format!(
                "--calibration {id}: a {kind} calibration is given twice; give one"
            ))
        };
        match kind {
            CalibrationKind::Response if response.is_some() => return Err(twice("response")),
            CalibrationKind::Response => {
                response = Some((stored.result(kind).map_err(store_err)?, stored.id.clone()));
            }
            CalibrationKind::Colour if colour.is_some() => return Err(twice("colour")),
            CalibrationKind::Colour => {
                colour = Some((stored.result(kind).map_err(store_err)?, stored.id.clone()));
            }
            other => {
                return Err(SessionError::Io(format!(
                    "--calibration {id}: the hdr product does not use a {} calibration; give a response and optionally a colour calibration",
                    other.as_str()
                )));
            }
        }
    }
    let (responses, response_id) = response.ok_or_else(|| {
        SessionError::Io(
            "process needs a response calibration: --calibration response-…, or name one in the rig file's [calibration] table before the capture (make one with `stagehand calibrate response`)".into(),
        )
    })?;
    let mut store =
        ProductStore::open(&args.run_dir).map_err(|e| SessionError::Io(e.to_string()))?;
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr_with_hz(5));
    let style = ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} hdr products  {eta}")
        .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style);
    let cal = HdrCalibrations {
        response: (&responses, &response_id),
        colour: colour.as_ref().map(|(set, id)| (set, id.as_str())),
        weight: MergeWeight::HatTimesExposure,
    };
    let software = format!("stagehand {}", env!("CARGO_PKG_VERSION"));
    let summary = hdr_products(&mut store, cal, &software, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .map_err(processing_err)?;
    bar.finish_and_clear();
    if args.json {
        super::print_json(&summary)?;
    } else {
        println!(
            "hdr: {} written, {} already current; {} samples saturated in every exposure, {} black in every exposure",
            summary.written, summary.skipped, summary.saturated_samples, summary.black_samples
        );
        println!(
            "products in {}",
            args.run_dir
                .join(stagehand_dataset::layout::PRODUCTS_DIR)
                .display()
        );
    }
    Ok(0)
}
