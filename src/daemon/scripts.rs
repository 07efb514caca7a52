//! The daemon's script library: built-in scripts (read-only, `*.rhai` in `--scripts`) and
//! scripts uploaded over the API (in `<data>/scripts/`), plus the dry run of a script on the
//! daemon's rig. Names are checked strictly so no name can reach outside those directories.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::error::ApiError;
use crate::dry_run::{render_report_with_renderer, renderer_line};
use crate::estimate::{Estimate, estimate};
use crate::plan::{Action, Plan};
use crate::rig::RigSource;
use crate::script::{ScriptError, ScriptSource, build_plan};
use crate::validate::{Severity, Violation, validate};

/// Largest script the API accepts (256 KiB; the longest built-in sequence is a few KiB).
pub const MAX_SCRIPT_BYTES: usize = 256 << 10;
/// Longest script or run name.
pub const MAX_NAME_LEN: usize = 64;
/// The extension every script file has.
const EXT: &str = ".rhai";

/// Checks a script name: 1–64 characters of `[A-Za-z0-9_.-]`, not starting with a dot and
/// without `..`, so a name is always one plain entry of its directory.
pub fn check_name(what: &str, name: &str) -> Result<(), ApiError> {
    check_plain(what, name, MAX_NAME_LEN)
}

/// Checks a run id like a script name, but up to
/// [`MAX_RUN_ID_LEN`](super::frame_index::MAX_RUN_ID_LEN) characters (run ids are
/// `<script>-<stamp>-<hash>`).
pub fn check_run_id(id: &str) -> Result<(), ApiError> {
    check_plain("run", id, super::frame_index::MAX_RUN_ID_LEN)
}

fn check_plain(what: &str, name: &str, max: usize) -> Result<(), ApiError> {
    let shown: String = name.chars().take(80).collect();
    let bad = |why: &str| {
        Err(ApiError::bad_request(format!("{what} name {shown:?}: {why}")).hint(format!(
            "{what} names are 1 to {max} characters of letters, digits, `_`, `-` and `.`, not starting with `.`"
        )))
    };
    if name.is_empty() {
        return bad("empty");
    }
    if name.len() > max {
        return bad("too long");
    }
    if name.starts_with('.') {
        return bad("starts with a dot");
    }
    if name.contains("..") {
        return bad("contains `..`");
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.')))
    {
        return bad(&format!("character {c:?} is not allowed"));
    }
    Ok(())
}

/// The library name of a script (`quickstart` for `quickstart` and `quickstart.rhai`),
/// after checking it.
pub fn script_stem(name: &str) -> Result<String, ApiError> {
    check_name("script", name)?;
    let stem = name.strip_suffix(EXT).unwrap_or(name);
    check_name("script", stem)?;
    Ok(stem.to_string())
}

/// Where a script comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ScriptOrigin {
    /// Shipped with the daemon (`--scripts`), read-only.
    Builtin,
    /// Uploaded with `PUT /api/scripts/{name}`.
    Uploaded,
}

/// One script of the library.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct ScriptEntry {
    /// Name without `.rhai` (both forms are accepted in URLs).
    pub name: String,
    pub source: ScriptOrigin,
    pub bytes: u64,
}

/// The two script directories.
#[derive(Debug, Clone)]
pub struct Library {
    pub builtin: Option<PathBuf>,
    pub uploads: PathBuf,
}

impl Library {
    /// The daemon's library.
    pub fn of(app: &super::state::Daemon) -> Library {
        Library {
            builtin: app.scripts_dir.clone(),
            uploads: app.uploads_dir(),
        }
    }

    fn builtin_path(&self, stem: &str) -> Option<PathBuf> {
        let path = self.builtin.as_ref()?.join(format!("{stem}{EXT}"));
        path.is_file().then_some(path)
    }

    fn upload_path(&self, stem: &str) -> PathBuf {
        self.uploads.join(format!("{stem}{EXT}"))
    }

    /// Every script, built-in first, each group sorted by name.
    pub fn list(&self) -> Result<Vec<ScriptEntry>, ApiError> {
        let mut out = Vec::new();
        if let Some(dir) = &self.builtin {
            out.extend(entries(dir, ScriptOrigin::Builtin)?);
        }
        out.extend(entries(&self.uploads, ScriptOrigin::Uploaded)?);
        Ok(out)
    }

    /// Reads a script by name: 404 if there is none.
    pub fn read(&self, name: &str) -> Result<(ScriptEntry, ScriptSource), ApiError> {
        let stem = script_stem(name)?;
        let (path, origin) = match self.builtin_path(&stem) {
            Some(p) => (p, ScriptOrigin::Builtin),
            None => (self.upload_path(&stem), ScriptOrigin::Uploaded),
        };
        let text = match std::fs::read(&path) {
            Ok(bytes) => String::from_utf8(bytes).map_err(|_| {
                ApiError::unprocessable(format!("script {stem}: the file is not UTF-8 text"))
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(ApiError::not_found(format!("no script named {stem:?}"))
                    .hint("`GET /api/scripts` lists the scripts; upload one with `PUT /api/scripts/{name}`"));
            }
            Err(e) => {
                return Err(ApiError::internal(format!(
                    "cannot read {}: {e}",
                    path.display()
                )));
            }
        };
        let entry = ScriptEntry {
            name: stem.clone(),
            source: origin,
            bytes: text.len() as u64,
        };
        Ok((
            entry,
            ScriptSource {
                name: format!("{stem}{EXT}"),
                text,
            },
        ))
    }

    /// Stores an uploaded script atomically (temp file, fsync, rename). Returns true when it
    /// replaced an earlier upload. Built-in names are refused (409).
    pub fn write(&self, name: &str, text: &str) -> Result<(ScriptSource, bool), ApiError> {
        let stem = script_stem(name)?;
        if self.builtin_path(&stem).is_some() {
            return Err(ApiError::conflict(format!(
                "{stem} is a built-in script and cannot be replaced"
            ))
            .hint("upload it under another name"));
        }
        if text.len() > MAX_SCRIPT_BYTES {
            return Err(too_large(text.len()));
        }
        let file = format!("{stem}{EXT}");
        let replaced = self.upload_path(&stem).is_file();
        crate::storage::atomic::write_atomic_durable(&self.uploads, &file, text.as_bytes())
            .map_err(|e| ApiError::internal(format!("cannot store the script: {e}")))?;
        Ok((
            ScriptSource {
                name: file,
                text: text.to_string(),
            },
            replaced,
        ))
    }
}

impl Library {
    /// Deletes an uploaded script: 404 if there is none, 409 for a built-in one.
    pub fn remove(&self, name: &str) -> Result<(), ApiError> {
        let stem = script_stem(name)?;
        if self.builtin_path(&stem).is_some() {
            return Err(ApiError::conflict(format!(
                "{stem} is a built-in script and cannot be deleted"
            ))
            .hint("only uploaded scripts can be deleted"));
        }
        match std::fs::remove_file(self.upload_path(&stem)) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(ApiError::not_found(
                format!("no uploaded script named {stem:?}"),
            )
            .hint("`GET /api/scripts` lists the scripts")),
            Err(e) => Err(ApiError::internal(format!("cannot delete {stem}: {e}"))),
        }
    }
}

/// 413 for a script over [`MAX_SCRIPT_BYTES`].
pub fn too_large(bytes: usize) -> ApiError {
    ApiError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!(
            "the script is {bytes} bytes; scripts may be at most {MAX_SCRIPT_BYTES} bytes (256 KiB)"
        ),
    )
    .hint("scripts describe loops, not data: generate the steps with loops and params")
}

fn entries(dir: &Path, origin: ScriptOrigin) -> Result<Vec<ScriptEntry>, ApiError> {
    let read = match std::fs::read_dir(dir) {
        Ok(r) => r,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => {
            return Err(ApiError::internal(format!(
                "cannot list {}: {e}",
                dir.display()
            )));
        }
    };
    let mut out: Vec<ScriptEntry> = read
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            let stem = name.strip_suffix(EXT)?;
            check_name("script", stem).ok()?;
            let meta = e.metadata().ok().filter(|m| m.is_file())?;
            Some(ScriptEntry {
                name: stem.to_string(),
                source: origin,
                bytes: meta.len(),
            })
        })
        .collect();
    out.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(out)
}

/// `set` of a request as `--set` pairs: strings as they are, numbers and booleans as JSON,
/// lists comma-separated.
pub fn overrides(
    set: Option<&BTreeMap<String, serde_json::Value>>,
) -> Result<Vec<(String, String)>, ApiError> {
    let scalar = |name: &str, v: &serde_json::Value| -> Result<String, ApiError> {
        match v {
            serde_json::Value::String(s) => Ok(s.clone()),
            serde_json::Value::Number(n) => Ok(n.to_string()),
            serde_json::Value::Bool(b) => Ok(b.to_string()),
            _ => {
                let message =
                    format!("set.{name}: values are strings, numbers, booleans or lists of those");
                Err(ApiError::unprocessable(message.clone())
                    .hint(r#"e.g. "set": {"lamp_count": 1, "bracket": [0.01, 0.04]}"#)
                    .violations(vec![super::error::ViolationItem {
                        line: None,
                        col: None,
                        message,
                    }]))
            }
        }
    };
    let mut out = Vec::new();
    for (name, value) in set.into_iter().flatten() {
        let text = match value {
            serde_json::Value::Array(items) => items
                .iter()
                .map(|v| scalar(name, v))
                .collect::<Result<Vec<_>, _>>()?
                .join(","),
            v => scalar(name, v)?,
        };
        out.push((name.clone(), text));
    }
    Ok(out)
}

/// One problem of a plan, at its script position.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ViolationInfo {
    /// `error` (the plan cannot run) or `warning`.
    pub severity: String,
    pub line: u32,
    pub col: u32,
    pub step: usize,
    pub message: String,
}

impl ViolationInfo {
    pub fn of(v: &Violation) -> Self {
        Self {
            severity: match v.severity {
                Severity::Error => "error",
                Severity::Warning => "warning",
            }
            .into(),
            line: v.at.line,
            col: v.at.col,
            step: v.step,
            message: v.message.clone(),
        }
    }
}

/// Cost of one top-level block of a plan.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct BlockEstimate {
    /// Top-level block name (`""` for steps outside any block).
    pub block: String,
    pub steps: usize,
    pub frames: usize,
    pub rig_time_s: f64,
}

/// What a plan will cost.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct EstimateInfo {
    pub rig_time_s: f64,
    /// Raw plus HDR frames.
    pub frames: usize,
    pub raw_frames: usize,
    pub hdr_frames: usize,
    /// Uncompressed upper bound of the frame data.
    pub bytes: u64,
    pub steps: usize,
    pub captures: usize,
    pub prompts: usize,
    /// Per top-level block, in plan order.
    pub blocks: Vec<BlockEstimate>,
}

impl EstimateInfo {
    /// Summarises an estimate of `plan`.
    pub fn of(plan: &Plan, e: &Estimate) -> Self {
        let mut blocks: Vec<BlockEstimate> = Vec::new();
        let mut prev_end = 0.0;
        for (i, step) in plan.steps.iter().enumerate() {
            let top = step.block.split('/').next().unwrap_or("").to_string();
            let end = e.step_end_s.get(i).copied().unwrap_or(prev_end);
            let frames = match &step.action {
                Action::Capture {
                    exposures_s,
                    cameras,
                    hdr,
                    ..
                } => {
                    exposures_s.len() * cameras.len()
                        + if *hdr && exposures_s.len() > 1 {
                            cameras.len()
                        } else {
                            0
                        }
                }
                _ => 0,
            };
            match blocks.last_mut() {
                Some(b) if b.block == top => {
                    b.steps += 1;
                    b.frames += frames;
                    b.rig_time_s += end - prev_end;
                }
                _ => blocks.push(BlockEstimate {
                    block: top,
                    steps: 1,
                    frames,
                    rig_time_s: end - prev_end,
                }),
            }
            prev_end = end;
        }
        Self {
            rig_time_s: e.rig_time_s,
            frames: e.raw_frames + e.hdr_frames,
            raw_frames: e.raw_frames,
            hdr_frames: e.hdr_frames,
            bytes: e.bytes,
            steps: e.steps,
            captures: e.captures,
            prompts: e.prompts,
            blocks,
        }
    }
}

/// The dry run of a script: what it will do and cost on the daemon's rig, and what is wrong
/// with it. Nothing moves.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DryRun {
    /// True when the plan can run (no errors; warnings are fine).
    pub ok: bool,
    /// Script file name as errors name it (e.g. `quickstart.rhai`).
    pub script: String,
    /// Steps of the plan (0 when the script failed).
    pub steps: usize,
    /// `null` when the script failed before making a plan.
    pub estimate: Option<EstimateInfo>,
    pub violations: Vec<ViolationInfo>,
    /// The script's own error (`file:line:col: message`), when it failed to make a plan.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Line and column of `error`, when known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_line: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_col: Option<u32>,
    /// The human-readable report (as `stagehand plan` prints it).
    pub report: String,
}

impl DryRun {
    fn failed(script: &ScriptSource, e: &ScriptError) -> Self {
        let (line, col) = e.position().unzip();
        Self {
            ok: false,
            script: script.name.clone(),
            steps: 0,
            estimate: None,
            violations: Vec::new(),
            error: Some(e.to_string()),
            error_line: line,
            error_col: col,
            report: format!("{e}\n"),
        }
    }

    /// Every error as `file:line:col: error: message` lines (for a 422).
    pub fn errors_text(&self) -> String {
        if let Some(e) = &self.error {
            return e.clone();
        }
        self.violations
            .iter()
            .filter(|v| v.severity == "error")
            .map(|v| {
                format!(
                    "{}:{}:{}: error: {} (step {})",
                    self.script, v.line, v.col, v.message, v.step
                )
            })
            .collect::<Vec<_>>()
            .join("\n")
    }
}

/// Builds, validates and estimates `script` on `rig` (blocking: scripts may run for seconds;
/// call it on a blocking thread).
pub fn dry_run(script: &ScriptSource, set: &[(String, String)], rig: &RigSource) -> DryRun {
    let plan = match build_plan(script, set, &rig.spec) {
        Ok(p) => p,
        Err(e) => return DryRun::failed(script, &e),
    };
    let violations = validate(&plan, &rig.spec);
    let e = estimate(&plan, &rig.spec);
    let renderer = renderer_line(&rig.spec);
    let report =
        render_report_with_renderer(&script.name, &plan, &e, &violations, renderer.as_deref());
    DryRun {
        ok: !violations.iter().any(|v| v.severity == Severity::Error),
        script: script.name.clone(),
        steps: plan.steps.len(),
        estimate: Some(EstimateInfo::of(&plan, &e)),
        violations: violations.iter().map(ViolationInfo::of).collect(),
        error: None,
        error_line: None,
        error_col: None,
        report,
    }
}

/// [`dry_run`] on a blocking thread.
pub async fn dry_run_async(
    script: ScriptSource,
    set: Vec<(String, String)>,
    rig: RigSource,
) -> Result<DryRun, ApiError> {
    stagehand_devices::realtime::spawn_blocking(move || dry_run(&script, &set, &rig))
        .await
        .map_err(|e| ApiError::internal(format!("the dry run stopped: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_plain_entries() {
        for good in ["quickstart", "quickstart.rhai", "a-b_c.1", "X"] {
            assert!(check_name("script", good).is_ok(), "{good}");
        }
        let long = "a".repeat(65);
        for bad in [
            "",
            ".hidden",
            "..",
            "a..b",
            "a/b",
            "a\\b",
            "../etc",
            "a\0b",
            "a b",
            "é",
            long.as_str(),
        ] {
            let e = check_name("script", bad).expect_err(bad);
            assert_eq!(e.status, StatusCode::BAD_REQUEST, "{bad}");
        }
        assert_eq!(script_stem("q.rhai").ok().as_deref(), Some("q"));
        assert!(script_stem(".rhai").is_err());
    }

    #[test]
    fn set_values_become_set_pairs() {
        let set: BTreeMap<String, serde_json::Value> = serde_json::from_str(
            r#"{"n": 2, "x": 0.5, "b": true, "s": "cam1", "l": [0.01, 0.04]}"#,
        )
        .expect("json");
        let pairs = overrides(Some(&set)).expect("valid");
        let get = |k: &str| pairs.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
        assert_eq!(get("n"), Some("2"));
        assert_eq!(get("x"), Some("0.5"));
        assert_eq!(get("b"), Some("true"));
        assert_eq!(get("s"), Some("cam1"));
        assert_eq!(get("l"), Some("0.01,0.04"));
        let bad: BTreeMap<String, serde_json::Value> =
            serde_json::from_str(r#"{"o": {"a": 1}}"#).expect("json");
        assert!(overrides(Some(&bad)).is_err());
    }
}
