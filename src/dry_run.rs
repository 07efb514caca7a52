//! The human-readable dry-run report: what a plan will do and cost, and everything wrong with
//! it, before anything moves.

use std::cmp::Ordering;
use std::fmt::Write as _;

use stagehand_devices::rig::{Backend, RigSpec};
use stagehand_simulator::render::Renderer;

use crate::estimate::{DeviceKind, DeviceUsage, Estimate};
use crate::plan::Plan;
use crate::units::{hms, human_bytes};
use crate::validate::{Severity, Violation};

/// Human-readable dry-run report: steps, captures, frames (raw + HDR), bytes (human units),
/// estimated rig time (h:mm:ss), prompts, per-device usage table, then every violation as
/// "SCRIPT:LINE:COL: error|warning: message (step n)".
pub fn render_report(
    script_name: &str,
    plan: &Plan,
    estimate: &Estimate,
    violations: &[Violation],
) -> String {
    render_report_with_renderer(script_name, plan, estimate, violations, None)
}

/// [`render_report`] with a `renderer` line after the prompts (for simulated rigs: the
/// renderer's preset and resolved knobs, see [`renderer_line`]).
pub fn render_report_with_renderer(
    script_name: &str,
    plan: &Plan,
    estimate: &Estimate,
    violations: &[Violation],
    renderer: Option<&str>,
) -> String {
    let mut out = String::new();
    let hash = plan.hash();
    let _ = writeln!(
        out,
        "Dry run of {script_name} (plan {})",
        &hash[..hash.len().min(12)]
    );

    let total = plan.steps.len();
    let steps = if estimate.steps == total {
        total.to_string()
    } else {
        format!(
            "{} of {total} (from step {})",
            estimate.steps,
            total - estimate.steps
        )
    };
    let _ = writeln!(out, "  steps      {steps}");
    let _ = writeln!(out, "  captures   {}", estimate.captures);
    let _ = writeln!(
        out,
        "  frames     {} raw + {} HDR",
        estimate.raw_frames, estimate.hdr_frames
    );
    let _ = writeln!(
        out,
        "  data       {} (uncompressed upper bound: raw frames as 16-bit RGB, HDR frames as 32-bit float RGB)",
        human_bytes(estimate.bytes)
    );
    let operator = match estimate.prompts {
        0 => String::new(),
        1 => "; plus the operator's time at 1 prompt".to_string(),
        n => format!("; plus the operator's time at {n} prompts"),
    };
    let _ = writeln!(
        out,
        "  rig time   {} (estimated{operator})",
        hms(estimate.rig_time_s)
    );
    let _ = writeln!(out, "  prompts    {}", estimate.prompts);
    if let Some(line) = renderer {
        let _ = writeln!(out, "  renderer   {line}");
    }

    if !estimate.per_device.is_empty() {
        out.push('\n');
        out.push_str(&device_table(estimate));
    }

    out.push('\n');
    let errors = violations
        .iter()
        .filter(|v| v.severity == Severity::Error)
        .count();
    let warnings = violations.len() - errors;
    if violations.is_empty() {
        out.push_str("No problems found; the plan is ready to run.\n");
    } else {
        let _ = writeln!(
            out,
            "Problems: {}, {}",
            plural(errors, "error"),
            plural(warnings, "warning")
        );
        for v in violations {
            let severity = match v.severity {
                Severity::Error => "error",
                Severity::Warning => "warning",
            };
            let _ = writeln!(
                out,
                "{script_name}:{}:{}: {severity}: {} (step {})",
                v.at.line, v.at.col, v.message, v.step
            );
        }
        if errors > 0 {
            out.push_str("The plan cannot run until the errors are fixed.\n");
        } else {
            out.push_str("The plan can run; check the warnings first.\n");
        }
    }
    out
}

/// "1 error", "2 errors".
/// The renderer's preset, resolved knobs and sample in one line, for a rig whose cameras are
/// simulated (`None` otherwise). A renderer that cannot be set up says why instead.
pub fn renderer_line(rig: &RigSpec) -> Option<String> {
    if rig.cameras.is_empty() || rig.cameras.iter().any(|c| c.backend != Backend::Sim) {
        return None;
    }
    let line = Renderer::new(rig).and_then(|r| r.summary_line(&r.sim().sample));
    Some(line.unwrap_or_else(|e| format!("cannot be set up: {e}")))
}

fn plural(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

/// "1 move", "3 moves".
fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// The per-device usage table; a cell that does not apply to the kind of device is "-".
fn device_table(estimate: &Estimate) -> String {
    let mut rows: Vec<(&String, &DeviceUsage)> = estimate.per_device.iter().collect();
    rows.sort_by(|a, b| a.1.kind.cmp(&b.1.kind).then_with(|| natural_cmp(a.0, b.0)));
    let header = [
        "device",
        "kind",
        "busy",
        "operations",
        "travel",
        "on",
        "frames",
    ];
    let mut table: Vec<[String; 7]> = vec![header.map(str::to_string)];
    for (id, u) in rows {
        let dash = || "-".to_string();
        let (kind, busy, ops, travel, on, frames) = match u.kind {
            DeviceKind::Axis => (
                "axis",
                hms(u.busy_s),
                count(u.operations, "move", "moves"),
                format!("{:.1}°", u.travel),
                dash(),
                dash(),
            ),
            DeviceKind::Lamp => (
                "lamp",
                dash(),
                count(u.operations, "switch", "switches"),
                dash(),
                hms(u.on_s),
                dash(),
            ),
            DeviceKind::Laser => (
                "laser",
                dash(),
                count(u.operations, "switch", "switches"),
                dash(),
                hms(u.on_s),
                dash(),
            ),
            DeviceKind::Camera => (
                "camera",
                hms(u.busy_s),
                dash(),
                dash(),
                dash(),
                u.frames.to_string(),
            ),
            DeviceKind::Cart => (
                "cart",
                hms(u.busy_s),
                count(u.operations, "move", "moves"),
                format!("{:.1} mm", u.travel),
                dash(),
                dash(),
            ),
            DeviceKind::Trigger => (
                "trigger",
                dash(),
                count(u.operations, "fire", "fires"),
                dash(),
                dash(),
                dash(),
            ),
        };
        table.push([id.clone(), kind.to_string(), busy, ops, travel, on, frames]);
    }
    let mut widths = [0usize; 7];
    for row in &table {
        for (w, cell) in widths.iter_mut().zip(row) {
            *w = (*w).max(cell.chars().count());
        }
    }
    let mut out = String::from("Devices\n");
    for row in &table {
        let mut line = String::from(" ");
        for (i, (cell, w)) in row.iter().zip(widths).enumerate() {
            let pad = w - cell.chars().count();
            line.push(' ');
            // Text columns align left, numbers right.
            if i < 2 {
                line.push_str(cell);
                line.push_str(&" ".repeat(pad));
            } else {
                line.push_str(&" ".repeat(pad));
                line.push_str(cell);
            }
            line.push(' ');
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

/// Compares ids so that "cam2" sorts before "cam10".
fn natural_cmp(a: &str, b: &str) -> Ordering {
    fn chunks(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let bytes = s.as_bytes();
        for i in 1..=bytes.len() {
            if i == bytes.len() || bytes[i].is_ascii_digit() != bytes[start].is_ascii_digit() {
                out.push((bytes[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        out
    }
    let (ca, cb) = (chunks(a), chunks(b));
    for ((da, xa), (db, xb)) in ca.iter().zip(&cb) {
        let ord = if *da && *db {
            let (ta, tb) = (xa.trim_start_matches('0'), xb.trim_start_matches('0'));
            ta.len().cmp(&tb.len()).then_with(|| ta.cmp(tb))
        } else {
            xa.cmp(xb)
        };
        if ord != Ordering::Equal {
            return ord;
        }
    }
    ca.len().cmp(&cb.len()).then_with(|| a.cmp(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::{estimate, estimate_from, state_before};
    use crate::plan::{Action, SourcePos};
    use crate::test_support::plan_at;
    use crate::validate::validate;
    use std::collections::BTreeMap;

    fn plan(actions: Vec<Action>) -> Plan {
        plan_at("scan.rhai", actions, |i| SourcePos {
            line: i as u32 + 10,
            col: 3,
        })
    }

    #[test]
    fn simulated_rigs_report_the_renderer_in_one_line() {
        let rig = stagehand_devices::rig::parse_rig(
            stagehand_devices::rig::BUILTIN_LIGHTSTAGE,
            "lightstage.toml",
        )
        .expect("built-in rig parses");
        let line = renderer_line(&rig).expect("a simulated rig");
        assert!(
            line.starts_with("preview (spp 1×1") && line.ends_with("on bumps"),
            "{line}"
        );
        assert!(!line.contains('\n'));
        let p = plan(vec![]);
        let report =
            render_report_with_renderer("x.rhai", &p, &estimate(&p, &rig), &[], Some(&line));
        assert!(
            report.contains(&format!("  renderer   {line}\n")),
            "{report}"
        );
    }

    #[test]
    fn sorts_ids_naturally() {
        let mut ids = vec!["cam10", "cam2", "cam1", "lamp", "cam02"];
        ids.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(ids, vec!["cam1", "cam02", "cam2", "cam10", "lamp"]);
    }

    #[test]
    fn report_has_totals_devices_and_violations() {
        let rig = crate::estimate::test_rigs::lightstage();
        let p = plan(vec![
            Action::Move {
                targets: BTreeMap::from([("turntable".to_string(), 400.0)]),
            },
            Action::Capture {
                exposures_s: vec![0.01, 0.1],
                cameras: vec!["cam1".into(), "cam2".into()],
                gain: 1.0,
                hdr: true,
                label: String::new(),
                min_interval_s: 0.0,
            },
            Action::Prompt {
                message: "swap".into(),
                fixture: None,
                placement: None,
                laser_mount_deg: None,
                laser_fit_nm: None,
            },
        ]);
        let e = estimate(&p, &rig);
        let v = validate(&p, &rig);
        let report = render_report("scan.rhai", &p, &e, &v);
        assert!(
            report.starts_with("Dry run of scan.rhai (plan "),
            "{report}"
        );
        assert!(report.contains("  steps      3\n"), "{report}");
        assert!(report.contains("  captures   1\n"), "{report}");
        assert!(report.contains("  frames     4 raw + 2 HDR\n"), "{report}");
        assert!(report.contains("uncompressed upper bound"), "{report}");
        assert!(report.contains("operator's time at 1 prompt"), "{report}");
        assert!(report.contains("  prompts    1\n"), "{report}");
        assert!(report.contains("Devices\n"), "{report}");
        let cam_row = report
            .lines()
            .find(|l| l.trim_start().starts_with("cam1 "))
            .unwrap_or_default();
        assert!(
            cam_row.contains("camera") && cam_row.trim_end().ends_with('2'),
            "{cam_row}"
        );
        assert!(
            report.contains("Problems: 1 error, 1 warning\n"),
            "{report}"
        );
        assert!(
            report.contains("scan.rhai:10:3: error: move_to: turntable target 400°"),
            "{report}"
        );
        assert!(report.contains("(step 0)\n"), "{report}");
        assert!(
            report.contains("scan.rhai:11:3: warning: capture: no lamp is on"),
            "{report}"
        );
        assert!(report.contains("cannot run"), "{report}");
        // Axis rows come before lamp rows; cameras in natural order.
        let at = |s: &str| report.find(s).unwrap_or(usize::MAX);
        assert!(at("turntable") < at("lamp1") && at("lamp1") < at("cam1 "));

        let clean = render_report("x.rhai", &plan(vec![]), &estimate(&plan(vec![]), &rig), &[]);
        assert!(clean.contains("No problems found"), "{clean}");
        assert!(clean.contains("rig time   0:00:00 (estimated)"), "{clean}");

        let rest = estimate_from(&p, &rig, 1, &state_before(&p, &rig, 1));
        let report = render_report("scan.rhai", &p, &rest, &[]);
        assert!(
            report.contains("steps      2 of 3 (from step 1)"),
            "{report}"
        );
    }
}
