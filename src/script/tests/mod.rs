//! Tests of the script builder and of every sequence in `sequences/`. This file holds the
//! helpers (the built-in rigs, running a script); each topic is a submodule.

mod capture_api;
mod errors;
mod limits;
mod params;
mod sequences;

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER, RigSpec, parse_rig};

use super::*;
use crate::plan::Plan;

fn lightstage() -> RigSpec {
    parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("built-in rig parses")
}

fn reflectometer() -> RigSpec {
    parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").expect("built-in rig parses")
}

fn src(text: &str) -> ScriptSource {
    ScriptSource {
        name: "test.rhai".into(),
        text: text.into(),
    }
}

fn sets(pairs: &[&str]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|p| parse_set(p).expect("valid --set"))
        .collect()
}

fn run(text: &str) -> Result<Plan, ScriptError> {
    build_plan(&src(text), &[], &lightstage())
}

fn run_ok(text: &str) -> Plan {
    match run(text) {
        Ok(p) => p,
        Err(e) => panic!("script failed: {e}"),
    }
}

fn run_err(text: &str) -> ScriptError {
    match run(text) {
        Ok(p) => panic!("script should fail but made {} steps", p.steps.len()),
        Err(e) => e,
    }
}

fn count(plan: &Plan, kind: &str) -> usize {
    plan.steps
        .iter()
        .filter(|s| s.action.kind() == kind)
        .count()
}
