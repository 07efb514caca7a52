//! Tests of the whole run store: create, commit, crash, resume, formats and queries.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use super::*;
use crate::checksum::sha256_hex;
use crate::exr_hdr::decode_exr;
use crate::frame_meta::tests::sample_meta;
use crate::plan::{PlannedCapture, PlannedStep, RunPlan};
use crate::png16::decode_png16;
use crate::products::{NewProduct, ProductStore};
use serde::{Deserialize, Serialize};

type TestResult = std::result::Result<(), Box<dyn std::error::Error>>;

/// A plan as the engine's would serialise, reduced to what the dataset reads of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Plan {
    script: String,
    params: BTreeMap<String, serde_json::Value>,
    steps: Vec<Step>,
}

/// One step: its action kind, block, script line and (captures) what it records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Step {
    index: usize,
    block: String,
    line: u32,
    kind: String,
    cameras: Vec<String>,
    exposures_s: Vec<f64>,
    hdr: bool,
    /// Move targets (moves only), to give the plan a float to round-trip.
    targets: BTreeMap<String, f64>,
}

impl RunPlan for Plan {
    fn step_count(&self) -> usize {
        self.steps.len()
    }

    fn step(&self, index: usize) -> Option<PlannedStep<'_>> {
        let s = self.steps.get(index)?;
        Some(PlannedStep {
            kind: &s.kind,
            block: &s.block,
            line: s.line,
            col: 3,
            capture: (s.kind == "capture").then_some(PlannedCapture {
                cameras: &s.cameras,
                exposures: s.exposures_s.len(),
                hdr: s.hdr,
            }),
        })
    }
}

impl Plan {
    fn hash(&self) -> String {
        crate::plan_hash(self).unwrap_or_default()
    }
}

fn step(index: usize, kind: &str) -> Step {
    Step {
        index,
        block: "turntable".into(),
        line: index as u32 + 1,
        kind: kind.into(),
        cameras: Vec::new(),
        exposures_s: Vec::new(),
        hdr: false,
        targets: BTreeMap::new(),
    }
}

fn capture(index: usize, cameras: &[&str]) -> Step {
    Step {
        exposures_s: vec![0.01, 0.02],
        cameras: cameras.iter().map(|c| c.to_string()).collect(),
        hdr: true,
        ..step(index, "capture")
    }
}

fn plan() -> Plan {
    Plan {
        script: "sequences/olat scan.rhai".into(),
        params: BTreeMap::from([("steps".into(), serde_json::json!(3))]),
        steps: vec![
            step(0, "home"),
            capture(1, &["cam5", "cam6"]),
            capture(2, &["cam5"]),
            Step {
                targets: BTreeMap::from([("turntable".into(), 0.1 + 0.2)]),
                ..step(3, "move")
            },
        ],
    }
}

fn manifest() -> Manifest {
    Manifest {
        format_version: 0,
        run_id: String::new(),
        created_unix_s: 1_795_268_707.5,
        software_version: "0.1.0".into(),
        script_name: "sequences/olat scan.rhai".into(),
        script_text: "// scan\nhome([\"turntable\"]);\n".into(),
        plan_hash: String::new(),
        params: BTreeMap::from([("steps".into(), serde_json::json!(3))]),
        rig_name: "lab".into(),
        rig_toml: "name = \"lab\"\n".into(),
        seed: 42,
        simulated: true,
        sim: None,
        calibrations: BTreeMap::new(),
    }
}

fn raw_frame(step: usize, camera: &str, exposure_index: usize, lamps: &[&str]) -> FrameToWrite {
    let mut meta = sample_meta(step, camera, exposure_index);
    meta.lamps_on = lamps.iter().map(|l| l.to_string()).collect();
    let n = (meta.width * meta.height * 3) as usize;
    let seed = step * 1000 + exposure_index * 10 + camera.len();
    let pixels = (0..n)
        .map(|i| ((i * 977 + seed * 131) % 4096) as u16)
        .collect();
    FrameToWrite {
        meta,
        pixels: FramePixels::Raw(pixels),
        ground_truth: None,
    }
}

fn hdr_frame(step: usize, camera: &str) -> FrameToWrite {
    let mut meta = sample_meta(step, camera, 0);
    meta.kind = FrameKind::Hdr;
    meta.exposure_index = None;
    meta.exposures_s = vec![0.01, 0.02];
    meta.exposure_s = 0.02;
    meta.bit_depth = 32;
    meta.sample_shift = 0;
    meta.trigger_id = None;
    let n = (meta.width * meta.height * 3) as usize;
    let pixels = (0..n).map(|i| 1.0e5 * i as f32 + 0.125).collect();
    FrameToWrite {
        meta,
        pixels: FramePixels::Hdr(pixels),
        ground_truth: None,
    }
}

fn record(step: usize, end: f64) -> StepRecord {
    StepRecord {
        step,
        kind: "capture".into(),
        block: "turntable".into(),
        rig_time_start_s: end - 1.0,
        rig_time_end_s: end,
        wall_time_unix_s: 1_795_268_800.0 + end,
    }
}

/// Step 1: cam5 and cam6, two exposures each, lamps 1 and 3, plus cam5's HDR.
fn step1_frames() -> Vec<FrameToWrite> {
    let mut frames = Vec::new();
    for cam in ["cam5", "cam6"] {
        for e in 0..2 {
            frames.push(raw_frame(1, cam, e, &["lamp1", "lamp3"]));
        }
    }
    frames.push(hdr_frame(1, "cam5"));
    frames
}

fn frame_row_count(store: &RunStore) -> rusqlite::Result<i64> {
    store
        .index()
        .conn()
        .query_row("SELECT COUNT(*) FROM frames", [], |r| r.get(0))
}

fn files_in(dir: &Path) -> std::io::Result<Vec<String>> {
    let mut names: Vec<String> = fs::read_dir(dir)?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    Ok(names)
}

mod formats;
mod lifecycle;
mod products;
mod queries;
