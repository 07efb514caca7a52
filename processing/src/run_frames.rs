//! Raw frames of a run as processing needs them: the (step, camera) pairs that hold a bracket,
//! listed from the index without pixels, and one bracket at a time decoded from its PNGs, so
//! memory stays bounded by one bracket however large the run.

use std::collections::BTreeMap;
use std::path::Path;

use stagehand_dataset::png16::{DecodedPng, decode_png16};
use stagehand_dataset::{FrameKind, FrameMeta, FrameQuery, RunReader, StoredFrame};

use crate::error::ProcessingError;
use crate::hdr_frame::{HdrFrame, MergeWeight, RgbExposure, merge_rgb_frames};
use crate::response_calibration::CameraResponse;

/// One capture of one camera: the facts shared by its exposures.
#[derive(Debug, Clone, PartialEq)]
pub struct BracketKey {
    /// Plan step.
    pub step: usize,
    /// Camera id.
    pub camera: String,
    /// The first frame's metadata (fixture, lamps, axes, size, bit depth, notes).
    pub meta: FrameMeta,
    /// The bracket's frames, shortest exposure first.
    pub frames: Vec<StoredFrame>,
}

/// One decoded exposure.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedExposure {
    /// Exposure time, seconds.
    pub exposure_s: f64,
    /// Interleaved RGB sensor DNs.
    pub dn: Vec<u16>,
    /// The frame's path in the run.
    pub path: String,
}

pub(crate) fn dataset_err(
    run: &Path,
) -> impl Fn(stagehand_dataset::StorageError) -> ProcessingError + '_ {
    move |e| ProcessingError::Dataset {
        run: run.display().to_string(),
        message: e.to_string(),
    }
}

/// Opens the run at `run_dir`.
pub fn open_run(run_dir: &Path) -> Result<RunReader, ProcessingError> {
    RunReader::open(run_dir).map_err(dataset_err(run_dir))
}

/// Every (step, camera) capture of raw frames in the run whose first frame passes `keep`.
pub fn bracket_keys(
    reader: &RunReader,
    keep: impl Fn(&FrameMeta) -> bool,
) -> Result<Vec<BracketKey>, ProcessingError> {
    let page = reader
        .frames(&FrameQuery {
            kind: Some(FrameKind::Raw),
            ..FrameQuery::default()
        })
        .map_err(dataset_err(reader.dir()))?;
    let mut groups: BTreeMap<(usize, String), Vec<StoredFrame>> = BTreeMap::new();
    for f in page.frames {
        groups
            .entry((f.meta.step, f.meta.camera.clone()))
            .or_default()
            .push(f);
    }
    Ok(groups
        .into_iter()
        .filter_map(|((step, camera), mut frames)| {
            frames.sort_by(|a, b| a.meta.exposure_s.total_cmp(&b.meta.exposure_s));
            let meta = frames.first()?.meta.clone();
            keep(&meta).then_some(BracketKey {
                step,
                camera,
                meta,
                frames,
            })
        })
        .collect())
}

/// Every raw frame of the run at `run_dir`, in index order.
pub fn raw_frames(run_dir: &Path) -> Result<Vec<StoredFrame>, ProcessingError> {
    let page = open_run(run_dir)?
        .frames(&FrameQuery {
            kind: Some(FrameKind::Raw),
            ..FrameQuery::default()
        })
        .map_err(dataset_err(run_dir))?;
    Ok(page.frames)
}

/// One colour channel (0 red, 1 green, 2 blue) of a decoded RGB frame, in DN.
pub fn channel_image(png: &DecodedPng, channel: usize) -> crate::gray_image::GrayImage {
    crate::gray_image::GrayImage {
        width: png.width as usize,
        height: png.height as usize,
        data: png
            .pixels
            .chunks_exact(3)
            .map(|px| f32::from(px[channel]))
            .collect(),
    }
}

/// Decodes one raw frame, naming it (and what to do) when it cannot be read.
pub fn decode_frame(reader: &RunReader, f: &StoredFrame) -> Result<DecodedPng, ProcessingError> {
    decode_frame_in(reader.dir(), f)
}

/// [`decode_frame`] from the run directory `run` (no reader: callable from worker threads).
pub fn decode_frame_in(run: &Path, f: &StoredFrame) -> Result<DecodedPng, ProcessingError> {
    let path = run.join(&f.path);
    let bytes = std::fs::read(&path).map_err(|e| ProcessingError::Dataset {
        run: run.display().to_string(),
        message: format!(
            "frame {} (step {}, camera {}) cannot be read: {e}; run `stagehand verify` on the run",
            f.path, f.meta.step, f.meta.camera
        ),
    })?;
    let png = decode_png16(&f.path, &bytes).map_err(dataset_err(run))?;
    if (png.width, png.height) != (f.meta.width, f.meta.height) {
        return Err(ProcessingError::Dataset {
            run: run.display().to_string(),
            message: format!(
                "frame {} is {}×{} but the index says {}×{}",
                f.path, png.width, png.height, f.meta.width, f.meta.height
            ),
        });
    }
    Ok(png)
}

/// Decodes the frames of `key`, checking each file's size against the capture's.
pub fn decode_bracket(
    reader: &RunReader,
    key: &BracketKey,
) -> Result<Vec<DecodedExposure>, ProcessingError> {
    key.frames
        .iter()
        .map(|f| {
            let png = decode_frame(reader, f)?;
            if (png.width, png.height) != (key.meta.width, key.meta.height) {
                return Err(ProcessingError::Dataset {
                    run: reader.dir().display().to_string(),
                    message: format!(
                        "frame {} is {}×{} but its capture is {}×{}",
                        f.path, png.width, png.height, key.meta.width, key.meta.height
                    ),
                });
            }
            Ok(DecodedExposure {
                exposure_s: f.meta.exposure_s,
                dn: png.pixels,
                path: f.path.clone(),
            })
        })
        .collect()
}

/// Merges one capture's bracket through `response` (weights favouring the longer exposures);
/// returns the merge and the frames' paths.
pub fn merge_capture(
    reader: &RunReader,
    key: &BracketKey,
    response: &CameraResponse,
) -> Result<(HdrFrame, Vec<String>), ProcessingError> {
    let exposures = decode_bracket(reader, key)?;
    let bracket: Vec<RgbExposure<'_>> = exposures
        .iter()
        .map(|e| RgbExposure {
            exposure_s: e.exposure_s,
            dn: &e.dn,
        })
        .collect();
    let hdr = merge_rgb_frames(
        &bracket,
        key.meta.width as usize,
        key.meta.height as usize,
        &response.channels,
        [1.0; 3],
        MergeWeight::HatTimesExposure,
    )?;
    Ok((hdr, exposures.into_iter().map(|e| e.path).collect()))
}

/// An axis angle a frame records, degrees: 0 when the rig has no such axis (`None`); an error
/// naming the frame when the rig has it but the frame does not record it.
pub fn axis_angle(
    run: &Path,
    meta: &FrameMeta,
    path: &str,
    axis: Option<&str>,
) -> Result<f64, ProcessingError> {
    let Some(axis) = axis else { return Ok(0.0) };
    meta.axes_deg
        .get(axis)
        .copied()
        .filter(|a| a.is_finite())
        .ok_or_else(|| ProcessingError::Dataset {
            run: run.display().to_string(),
            message: format!(
                "frame {path} (step {}, camera {}) records no angle of axis `{axis}`",
                meta.step, meta.camera
            ),
        })
}

/// The black level of a capture in DN: from the frame notes of a simulated camera
/// (`black_level_dn`), else 0 (a real camera's offset is then absorbed by the response).
pub fn black_level_dn(meta: &FrameMeta) -> f64 {
    meta.notes
        .get("black_level_dn")
        .and_then(serde_json::Value::as_f64)
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(0.0)
}

/// The read noise of a capture in DN: from the frame notes (`sensor.read_noise_dn`), else
/// 0.1 % of full scale.
pub fn read_noise_dn(meta: &FrameMeta) -> f64 {
    meta.notes
        .get("sensor")
        .and_then(|s| s.get("read_noise_dn"))
        .and_then(serde_json::Value::as_f64)
        .filter(|v| v.is_finite() && *v >= 0.0)
        .unwrap_or(0.001 * ((1u64 << meta.bit_depth.min(16)) - 1) as f64)
}
