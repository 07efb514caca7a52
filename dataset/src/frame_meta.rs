//! Per-frame metadata, the pixels that go with it, and the deterministic frame file name.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use stagehand_devices::fixture_pose::FixturePose;
use stagehand_devices::ground_truth::GroundTruthData;

use crate::layout::sanitize;

/// Whether a frame is one raw exposure or an HDR merge of a bracket.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum FrameKind {
    /// One exposure, 16-bit PNG.
    Raw,
    /// A merged bracket, OpenEXR.
    Hdr,
}

impl FrameKind {
    /// The text stored in SQLite and JSON (`raw` / `hdr`).
    pub fn as_str(self) -> &'static str {
        match self {
            FrameKind::Raw => "raw",
            FrameKind::Hdr => "hdr",
        }
    }

    /// Parses [`FrameKind::as_str`] output.
    pub fn parse(text: &str) -> Option<FrameKind> {
        match text {
            "raw" => Some(FrameKind::Raw),
            "hdr" => Some(FrameKind::Hdr),
            _ => None,
        }
    }
}

/// Every fact about one frame. One row per frame in the `frames` table; also embedded in the
/// image file (without the wall time, so identical captures give identical files).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "utoipa", derive(utoipa::ToSchema))]
pub struct FrameMeta {
    /// Plan step that captured the frame.
    pub step: usize,
    /// Enclosing block names joined with `/`.
    pub block: String,
    /// Free-form label of the capture.
    pub label: String,
    /// Camera id from the rig file.
    pub camera: String,
    /// Raw exposure or HDR merge.
    pub kind: FrameKind,
    /// Index into the capture's exposure list (raw frames; `None` for HDR).
    pub exposure_index: Option<usize>,
    /// Exposure time in seconds; for HDR the longest of the bracket.
    pub exposure_s: f64,
    /// Every exposure of the bracket in seconds (one entry for a raw frame).
    pub exposures_s: Vec<f64>,
    /// Analogue gain (linear).
    pub gain: f64,
    /// Trigger id the frame answers (raw frames).
    pub trigger_id: Option<u64>,
    /// Axis angles in degrees at capture time, by axis id.
    pub axes_deg: BTreeMap<String, f64>,
    /// Ids of the lamps that were on.
    pub lamps_on: Vec<String>,
    /// Laser armed.
    pub laser_armed: bool,
    /// Laser emitting.
    pub laser_on: bool,
    /// Fitted laser colour in nanometres.
    pub laser_colour_nm: u32,
    /// Laser tilt axis angle in degrees, if the rig has one.
    pub laser_tilt_deg: Option<f64>,
    /// Elevation on the light arc where the laser unit is mounted, in degrees.
    pub laser_mount_deg: Option<f64>,
    /// Fixture on the stage (sample, checkerboard, colorchecker, planes).
    pub fixture: String,
    /// How the operator was asked to place the fixture (index schema ≥ 4; flat and centred,
    /// and left out of the embedded JSON, unless a prompt said otherwise).
    #[serde(default, skip_serializing_if = "FixturePose::is_flat_centred")]
    #[cfg_attr(feature = "utoipa", schema(value_type = Object))]
    pub fixture_pose: FixturePose,
    /// Reflectometer cart position in millimetres, if known.
    pub cart_mm: Option<f64>,
    /// Rig time in seconds at which the exposure started.
    pub rig_time_s: f64,
    /// Wall-clock Unix time in seconds when the frame was captured (not embedded in the file).
    pub wall_time_unix_s: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Significant bits per sample of the sensor (raw) or 32 for f32 HDR.
    pub bit_depth: u8,
    /// Left shift of the samples in the raw PNG (`16 - bit_depth`: MSB-aligned, so viewers
    /// show the frame; the PNG's sBIT chunk says the same). 0 for HDR frames and for raw
    /// frames of datasets written before MSB alignment (index schema < 3). The storage writer
    /// sets it; readers get DN back from [`crate::png16::decode_png16`].
    #[serde(default)]
    pub sample_shift: u8,
    /// Samples at the sensor's maximum (raw) or saturated in every exposure (HDR).
    pub saturated_samples: u64,
    /// Backend-specific notes, stored verbatim.
    pub notes: serde_json::Value,
}

impl FrameMeta {
    /// The metadata JSON embedded in the image file: every field except `wall_time_unix_s` and `rig_time_s`,
    /// keys sorted, so an identical capture gives a byte-identical file.
    pub fn embedded_json(&self) -> Result<String, serde_json::Error> {
        let mut value = serde_json::to_value(self)?;
        if let serde_json::Value::Object(map) = &mut value {
            map.remove("wall_time_unix_s");
            // Rig time depends on how the run got there (a resumed run re-homes first), so
            // it lives in the index only; the file stays a pure function of the capture.
            map.remove("rig_time_s");
        }
        serde_json::to_string(&value)
    }
}

/// Pixels of a frame to write.
#[derive(Debug, Clone, PartialEq)]
pub enum FramePixels {
    /// Interleaved RGB digital numbers, `width * height * 3` samples.
    Raw(Vec<u16>),
    /// Interleaved RGB linear radiance, `width * height * 3` samples.
    Hdr(Vec<f32>),
}

impl FramePixels {
    /// The kind of frame these pixels make.
    pub fn kind(&self) -> FrameKind {
        match self {
            FramePixels::Raw(_) => FrameKind::Raw,
            FramePixels::Hdr(_) => FrameKind::Hdr,
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            FramePixels::Raw(p) => p.len(),
            FramePixels::Hdr(p) => p.len(),
        }
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A frame handed to [`crate::RunStore::commit_step`].
#[derive(Debug, Clone, PartialEq)]
pub struct FrameToWrite {
    /// Its metadata.
    pub meta: FrameMeta,
    /// Its pixels; the variant must match `meta.kind`.
    pub pixels: FramePixels,
    /// Ground truth to write beside it ([`ground_truth_file_name`]), if any.
    pub ground_truth: Option<Arc<GroundTruthData>>,
}

/// Deterministic file name of a frame: `s{step:06}_{camera}_e{idx}.png` for raw frames and
/// `s{step:06}_{camera}_hdr.exr` for HDR frames. The camera id is sanitised to
/// `[A-Za-z0-9_-]`; a raw frame without an exposure index is named `e0`.
pub fn frame_file_name(meta: &FrameMeta) -> String {
    match meta.kind {
        FrameKind::Raw => raw_file_name(meta.step, &meta.camera, meta.exposure_index.unwrap_or(0)),
        FrameKind::Hdr => hdr_file_name(meta.step, &meta.camera),
    }
}

/// [`frame_file_name`] of raw exposure `exposure_index` of `camera` in step `step`.
pub fn raw_file_name(step: usize, camera: &str, exposure_index: usize) -> String {
    format!(
        "s{step:06}_{}_e{exposure_index}.png",
        sanitize(camera, "camera")
    )
}

/// [`frame_file_name`] of the HDR merge of `camera`'s bracket in step `step`.
pub fn hdr_file_name(step: usize, camera: &str) -> String {
    format!("s{step:06}_{}_hdr.exr", sanitize(camera, "camera"))
}

/// File name of a ground-truth image of a frame: the frame's file stem, then the plane kind
/// (sanitised): `s000007_cam5_e0.depth.exr`.
pub fn ground_truth_file_name(meta: &FrameMeta, kind: &str) -> String {
    let frame = frame_file_name(meta);
    let stem = frame
        .rsplit_once('.')
        .map_or(frame.as_str(), |(stem, _)| stem);
    format!("{stem}.{}.exr", sanitize(kind, "plane"))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A plausible raw frame's metadata for tests.
    pub(crate) fn sample_meta(step: usize, camera: &str, exposure_index: usize) -> FrameMeta {
        FrameMeta {
            step,
            block: "turntable/lamp sweep".into(),
            label: format!("step {step}"),
            camera: camera.into(),
            kind: FrameKind::Raw,
            exposure_index: Some(exposure_index),
            exposure_s: 0.01 * (exposure_index + 1) as f64,
            exposures_s: vec![0.01 * (exposure_index + 1) as f64],
            gain: 1.0,
            trigger_id: Some(1000 + step as u64),
            axes_deg: BTreeMap::from([("turntable".into(), 15.0), ("light_arc".into(), -30.5)]),
            lamps_on: vec!["lamp1".into(), "lamp3".into()],
            laser_armed: false,
            laser_on: false,
            laser_colour_nm: 650,
            laser_tilt_deg: None,
            laser_mount_deg: Some(45.0),
            fixture: "sample".into(),
            fixture_pose: FixturePose::default(),
            cart_mm: None,
            rig_time_s: 12.5 + step as f64,
            wall_time_unix_s: 1_795_268_707.25,
            width: 4,
            height: 3,
            bit_depth: 12,
            sample_shift: 4,
            saturated_samples: 0,
            notes: serde_json::json!({"renderer": {"spp": 4, "effects": ["diffuse", "specular"]}}),
        }
    }

    #[test]
    fn names_are_deterministic() {
        let mut meta = sample_meta(7, "cam/5", 2);
        assert_eq!(frame_file_name(&meta), "s000007_cam_5_e2.png");
        assert_eq!(
            ground_truth_file_name(&meta, "depth"),
            "s000007_cam_5_e2.depth.exr"
        );
        meta.kind = FrameKind::Hdr;
        meta.exposure_index = None;
        assert_eq!(frame_file_name(&meta), "s000007_cam_5_hdr.exr");
    }

    #[test]
    fn embedded_json_has_no_wall_time() -> Result<(), serde_json::Error> {
        let a = sample_meta(1, "cam1", 0);
        let mut b = a.clone();
        b.wall_time_unix_s += 100.0;
        assert_eq!(a.embedded_json()?, b.embedded_json()?);
        assert!(!a.embedded_json()?.contains("wall_time"));
        Ok(())
    }
}
