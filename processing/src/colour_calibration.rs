//! `stagehand calibrate colour`: the joint camera+lamp channel scales (S_r, S_g, S_b) per
//! camera and lamp (seed 004 §3.1) from a run of `sequences/calibration_colorchecker.rhai`:
//! the colour checker flat and centred, one lamp at a time, an HDR bracket on every camera.
//!
//! Per camera and turntable angle: each lamp's bracket is merged through the camera's response
//! calibration (so S is in that calibration's units: dividing a merged frame by S gives
//! reflectance); the chart is located in the sum of those merged frames by projecting its
//! layout through the camera's geometry and refining the match ([`crate::chart_locate`]); each
//! patch is measured over the central part of its square with a robust mean, leaving out pixels
//! that were saturated or black in every exposure (a patch with more than 5 % of those is left
//! out whole); and per lamp the scales are fitted to the published reflectances
//! ([`white_balance`]), with the fit's relative residual as the quality figure. A lamp too dim
//! to measure is an error naming the camera and the lamp, never a NaN.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::calibrate_geometry::CameraGeometry;
use crate::chart_layout::{ChartLayout, PATCHES};
use crate::chart_locate::{ChartFit, LocateOptions, PlacedChart, locate_chart};
use crate::error::ProcessingError;
use crate::gray_image::GrayImage;
use crate::hdr_frame::{HdrFrame, PixelState};
use crate::response_calibration::{CameraResponse, ResponseSet};
use crate::rig_frame::sample_to_camera;
use crate::run_frames::{BracketKey, bracket_keys, merge_capture, open_run};
use crate::white_balance::{PatchMeasurement, WhiteBalance, patch_mean, white_balance};

/// Fewest pixels a patch's core must cover to be measured.
pub const MIN_PATCH_PIXELS: usize = 4;
/// Largest fraction of a patch's core pixels that may be bounds (saturated or black in every
/// exposure) in a channel; beyond it the patch is left out rather than biased.
pub const MAX_BOUND_FRACTION: f64 = 0.05;
/// Fewest patches a fit needs (as many as the neutral row has).
pub const MIN_PATCHES: usize = 6;
/// Fewest measured pixel values, as a fraction of a frame's, for a capture to help locate the
/// chart; below it the capture is left out of the search (and its lamp will fail its fit).
pub const MIN_LIT_FRACTION: f64 = 0.01;

/// Settings of the colour calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ColourOptions {
    /// The chart's physical layout.
    pub chart: ChartLayout,
    /// Id of the turntable axis in the frames' axis angles (`None`: the table stays at 0°).
    pub turntable_axis: Option<String>,
    /// Fraction of each patch's side measured, centred (the edges blur and misalign).
    pub core_fraction: f64,
    /// How far and how strictly the chart is searched for.
    pub locate: LocateOptions,
    /// The fixture name the colour checker's frames carry.
    pub fixture: String,
}

impl Default for ColourOptions {
    fn default() -> ColourOptions {
        ColourOptions {
            chart: ChartLayout::default(),
            turntable_axis: None,
            core_fraction: 0.5,
            locate: LocateOptions::default(),
            fixture: "colorchecker".into(),
        }
    }
}

/// Why a patch was left out of a fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Exclusion {
    /// Saturated in every exposure (a lower bound only).
    Saturated,
    /// Black in every exposure (an upper bound only).
    Black,
    /// Too few pixels in the image (a grazing view or the chart's edge out of frame).
    TooSmall,
}

/// A patch left out of a fit, and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExcludedPatch {
    /// Patch index, 0..24.
    pub patch: usize,
    /// The reason.
    pub reason: Exclusion,
}

/// One capture of the chart by one camera under one lamp, as measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampView {
    /// Plan step of the capture.
    pub step: usize,
    /// Turntable angle, degrees.
    pub turntable_deg: f64,
    /// The bracket's frames.
    pub frames: Vec<String>,
    /// The patches measured.
    pub patches: Vec<PatchMeasurement>,
    /// The patches left out.
    pub excluded: Vec<ExcludedPatch>,
}

/// One camera's channel scales under one lamp.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampScale {
    /// S_r, S_g, S_b with their relative standard errors and fit residuals.
    #[serde(flatten)]
    pub fit: WhiteBalance,
    /// The captures the fit pooled.
    pub views: Vec<LampView>,
}

/// Where the chart was found in one camera's view at one turntable angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChartView {
    /// Turntable angle, degrees.
    pub turntable_deg: f64,
    /// The capture steps that share this view.
    pub steps: Vec<usize>,
    /// The correction from the geometry's projection to the image.
    pub fit: ChartFit,
    /// Fewest core pixels of any patch.
    pub min_patch_pixels: usize,
}

/// One camera's colour calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraColour {
    /// Scales by lamp id.
    pub lamps: BTreeMap<String, LampScale>,
    /// The chart as located in each view.
    pub chart: Vec<ChartView>,
}

/// Every camera's colour calibration, by camera id.
pub type ColourSet = BTreeMap<String, CameraColour>;

/// One lamp's merged capture of the chart.
#[derive(Debug, Clone, Copy)]
pub struct LampCapture<'a> {
    /// Lamp id.
    pub lamp: &'a str,
    /// Plan step.
    pub step: usize,
    /// The bracket's frames.
    pub frames: &'a [String],
    /// The merged frame.
    pub hdr: &'a HdrFrame,
}

fn in_camera(camera: &str) -> impl Fn(ProcessingError) -> ProcessingError + '_ {
    move |e| ProcessingError::Camera {
        camera: camera.to_string(),
        source: Box::new(e),
    }
}

/// Measures the chart's patches in one camera's captures at one turntable angle, one capture
/// per lamp (all the same size): locates the chart in their summed luminance, then measures
/// every patch under each lamp.
pub fn measure_view(
    geometry: &CameraGeometry,
    turntable_deg: f64,
    captures: &[LampCapture<'_>],
    options: &ColourOptions,
) -> Result<(ChartView, Vec<(String, LampView)>), ProcessingError> {
    let named = in_camera(&geometry.camera);
    let first = captures.first().ok_or_else(|| {
        named(ProcessingError::IllPosed {
            what: "colour calibration",
            why: "no capture of the chart".into(),
        })
    })?;
    let (w, h) = (first.hdr.width, first.hdr.height);
    let mut luminance = GrayImage::new(w, h);
    let mut lit = 0;
    for c in captures {
        if (c.hdr.width, c.hdr.height) != (w, h) {
            return Err(named(ProcessingError::SizeMismatch {
                index: c.step,
                expected: w * h * 3,
                got: c.hdr.rgb.len(),
            }));
        }
        // A capture with next to nothing measured would only add noise to the search.
        let measured = c.hdr.state.iter().filter(|s| **s == PixelState::Measured);
        if (measured.count() as f64) < MIN_LIT_FRACTION * c.hdr.state.len() as f64 {
            continue;
        }
        lit += 1;
        for (l, px) in luminance.data.iter_mut().zip(c.hdr.rgb.chunks_exact(3)) {
            *l += (px[0] + px[1] + px[2]) / 3.0;
        }
    }
    if lit == 0 {
        return Err(ProcessingError::CameraLamp {
            camera: geometry.camera.clone(),
            lamp: first.lamp.to_string(),
            source: Box::new(ProcessingError::IllPosed {
                what: "white balance",
                why: format!(
                    "less than {:.0} % of the frame is measured (the rest black or saturated in every exposure): the lamp is too dim or off, or the exposures far too short",
                    100.0 * MIN_LIT_FRACTION
                ),
            }),
        });
    }
    let pose = sample_to_camera(&geometry.rig_to_camera, turntable_deg);
    let fit = locate_chart(
        &luminance,
        &geometry.model,
        &pose,
        &options.chart,
        &options.locate,
    )
    .map_err(&named)?;
    let placed = PlacedChart {
        model: &geometry.model,
        pose,
        layout: options.chart,
        fit,
    };
    let pixels: Vec<Vec<usize>> = (0..PATCHES)
        .map(|i| placed.patch_pixels(i, options.core_fraction, w, h))
        .collect();
    let view = ChartView {
        turntable_deg,
        steps: captures.iter().map(|c| c.step).collect(),
        fit,
        min_patch_pixels: pixels.iter().map(Vec::len).min().unwrap_or(0),
    };
    let lamps = captures
        .iter()
        .map(|c| {
            let (patches, excluded) = measure_patches(c.hdr, &pixels);
            (
                c.lamp.to_string(),
                LampView {
                    step: c.step,
                    turntable_deg,
                    frames: c.frames.to_vec(),
                    patches,
                    excluded,
                },
            )
        })
        .collect();
    Ok((view, lamps))
}

/// Each patch's robust mean per channel over `pixels[patch]` of `hdr`, or why it was left out.
pub fn measure_patches(
    hdr: &HdrFrame,
    pixels: &[Vec<usize>],
) -> (Vec<PatchMeasurement>, Vec<ExcludedPatch>) {
    let mut measured = Vec::new();
    let mut excluded = Vec::new();
    'patch: for (patch, px) in pixels.iter().enumerate() {
        let out = |reason| ExcludedPatch { patch, reason };
        if px.len() < MIN_PATCH_PIXELS {
            excluded.push(out(Exclusion::TooSmall));
            continue;
        }
        let mut mean = [0.0; 3];
        let mut std_err = [0.0; 3];
        for c in 0..3 {
            let (mut values, mut high, mut low) = (Vec::with_capacity(px.len()), 0, 0);
            for &i in px {
                match hdr.state.get(3 * i + c) {
                    Some(PixelState::Measured) => values.push(f64::from(hdr.rgb[3 * i + c])),
                    Some(PixelState::AtLeast) => high += 1,
                    Some(PixelState::AtMost) | None => low += 1,
                }
            }
            if (high + low) as f64 > MAX_BOUND_FRACTION * px.len() as f64 {
                excluded.push(out(if high >= low {
                    Exclusion::Saturated
                } else {
                    Exclusion::Black
                }));
                continue 'patch;
            }
            match patch_mean(&values) {
                Some((m, e)) => (mean[c], std_err[c]) = (m, e),
                None => {
                    excluded.push(out(Exclusion::TooSmall));
                    continue 'patch;
                }
            }
        }
        measured.push(PatchMeasurement {
            patch,
            mean,
            std_err,
        });
    }
    (measured, excluded)
}

/// Fits one camera's scales under one lamp from every view of it.
pub fn fit_lamp(
    camera: &str,
    lamp: &str,
    views: Vec<LampView>,
) -> Result<LampScale, ProcessingError> {
    let named = |e| ProcessingError::CameraLamp {
        camera: camera.to_string(),
        lamp: lamp.to_string(),
        source: Box::new(e),
    };
    let patches: Vec<PatchMeasurement> = views
        .iter()
        .flat_map(|v| v.patches.iter().copied())
        .collect();
    if patches.len() < MIN_PATCHES {
        let count = |r| {
            views
                .iter()
                .flat_map(|v| &v.excluded)
                .filter(|e| e.reason == r)
                .count()
        };
        let (black, saturated, small) = (
            count(Exclusion::Black),
            count(Exclusion::Saturated),
            count(Exclusion::TooSmall),
        );
        let advice = if black >= saturated.max(small) {
            "the lamp is too dim or off, or the exposures too short"
        } else if saturated >= small {
            "the exposures are too long for this lamp"
        } else {
            "the chart is too small in this view"
        };
        return Err(named(ProcessingError::IllPosed {
            what: "white balance",
            why: format!(
                "only {} chart patches were measured ({black} black and {saturated} saturated in every exposure, {small} too small in the image; at least {MIN_PATCHES} are needed): {advice}",
                patches.len()
            ),
        }));
    }
    let fit = white_balance(&patches).map_err(named)?;
    Ok(LampScale { fit, views })
}

/// The response must have been fitted on frames of the same bit depth: its usable range ends
/// 2 % below full scale.
fn check_depth(
    camera: &str,
    key: &BracketKey,
    response: &CameraResponse,
) -> Result<(), ProcessingError> {
    let max = ((1u64 << key.meta.bit_depth.min(16)) - 1) as f64;
    let hi = response.channels[1].range.hi;
    if (hi / max - 0.98).abs() > 0.01 {
        return Err(ProcessingError::IllPosed {
            what: "colour calibration",
            why: format!(
                "camera `{camera}`: its response calibration's range ends at DN {hi:.0}, but these frames have {} bits (full scale {max:.0}); calibrate the response at the same bit depth",
                key.meta.bit_depth
            ),
        });
    }
    Ok(())
}

/// Calibrates every camera's scales under every lamp from the colour-checker run at
/// `run_dir`, with `responses` for the merge and `geometry` to find the chart (one entry per
/// camera of the run: calibrated, or [`crate::nominal_geometry::nominal_geometry`]).
pub fn calibrate_colour(
    run_dir: &Path,
    responses: &ResponseSet,
    geometry: &BTreeMap<String, CameraGeometry>,
    options: &ColourOptions,
) -> Result<ColourSet, ProcessingError> {
    options.chart.check()?;
    if !(options.core_fraction > 0.0 && options.core_fraction <= 1.0) {
        return Err(ProcessingError::BadParameter {
            name: "core_fraction",
            value: options.core_fraction,
            why: "the measured part of a patch is a fraction of its side in (0, 1]",
        });
    }
    let reader = open_run(run_dir)?;
    let keys = bracket_keys(&reader, |m| {
        m.fixture == options.fixture && m.lamps_on.len() == 1
    })?;
    if keys.is_empty() {
        return Err(ProcessingError::MissingInput {
            run: run_dir.display().to_string(),
            what: format!("capture of the `{}` under a single lamp", options.fixture),
            hint: "capture them with sequences/calibration_colorchecker.rhai",
        });
    }
    let table = |key: &BracketKey| {
        options
            .turntable_axis
            .as_ref()
            .and_then(|a| key.meta.axes_deg.get(a))
            .copied()
            .unwrap_or(0.0)
    };
    // Camera → turntable angle (millidegrees) → captures.
    let mut views: BTreeMap<&str, BTreeMap<i64, Vec<&BracketKey>>> = BTreeMap::new();
    for key in &keys {
        views
            .entry(key.camera.as_str())
            .or_default()
            .entry((table(key) * 1000.0).round() as i64)
            .or_default()
            .push(key);
    }
    let mut out = ColourSet::new();
    for (camera, by_angle) in views {
        let response = responses
            .get(camera)
            .ok_or_else(|| ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: format!("response calibration for camera `{camera}`"),
                hint: "name a response calibration of this rig's cameras",
            })?;
        let geo = geometry
            .get(camera)
            .ok_or_else(|| ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: format!("geometry for camera `{camera}`"),
                hint: "name a geometry calibration of this rig's cameras, or use the nominal one",
            })?;
        let mut chart = Vec::new();
        let mut per_lamp: BTreeMap<String, Vec<LampView>> = BTreeMap::new();
        for group in by_angle.values() {
            let mut merged = Vec::with_capacity(group.len());
            for key in group {
                check_depth(camera, key, response)?;
                merged.push(merge_capture(&reader, key, response).map_err(in_camera(camera))?);
            }
            let captures: Vec<LampCapture<'_>> = group
                .iter()
                .zip(&merged)
                .map(|(key, (hdr, frames))| LampCapture {
                    lamp: key.meta.lamps_on[0].as_str(),
                    step: key.step,
                    frames,
                    hdr,
                })
                .collect();
            let (view, lamps) = measure_view(geo, table(group[0]), &captures, options)?;
            chart.push(view);
            for (lamp, v) in lamps {
                per_lamp.entry(lamp).or_default().push(v);
            }
        }
        let lamps = per_lamp
            .into_iter()
            .map(|(lamp, v)| Ok((lamp.clone(), fit_lamp(camera, &lamp, v)?)))
            .collect::<Result<_, ProcessingError>>()?;
        out.insert(camera.to_string(), CameraColour { lamps, chart });
    }
    Ok(out)
}

#[cfg(test)]
#[path = "colour_calibration_tests.rs"]
mod tests;
