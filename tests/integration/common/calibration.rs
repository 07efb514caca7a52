//! Helpers of the calibration tests: the built-in rig drawn as built, and the CLI.

use std::path::Path;
use std::process::{Command, Output};

use stagehand::rig::RigSource;

use super::small_rig;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

/// The built-in rig at 480×360 (the grazing cam1 sees the chart's patches a few pixels tall,
/// enough for the 5×5 sample windows) drawn as built with `response` style, at `bits` per
/// sample, with `edit` applied to the rig file's text.
pub fn as_built_rig_with(response: &str, bits: u8, edit: impl Fn(String) -> String) -> RigSource {
    let rig = small_rig("lightstage", 480, 360);
    let mut text = rig
        .text
        .replace("bit_depth = 12", &format!("bit_depth = {bits}"));
    text.push_str(&format!(
        "\n[sim.as_built]\nseed = 3\nresponse = \"{response}\"\n"
    ));
    RigSource::from_text(&edit(text), "test:lightstage+as_built").expect("rig parses")
}

/// [`as_built_rig_with`] unedited.
pub fn as_built_rig(response: &str, bits: u8) -> RigSource {
    as_built_rig_with(response, bits, |t| t)
}

/// Runs the stagehand CLI with `args`.
pub fn stagehand_output(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("stagehand runs")
}

/// Runs the stagehand CLI with `args`, expecting success and JSON on stdout.
pub fn stagehand(args: &[&str]) -> serde_json::Value {
    let out = stagehand_output(args);
    assert!(
        out.status.success(),
        "stagehand {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

/// Stores the simulator's exact cameras of simulated run `run_dir` as a geometry calibration
/// (`stagehand calibrate geometry --from-truth`); returns its id.
pub fn exact_geometry(run_dir: &Path) -> String {
    let stored = stagehand(&[
        "calibrate",
        "geometry",
        run_dir.to_str().expect("utf-8 path"),
        "--from-truth",
        "--json",
    ]);
    stored["id"].as_str().expect("an id").to_string()
}
