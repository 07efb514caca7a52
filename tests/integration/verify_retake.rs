//! `stagehand verify` and `stagehand resume --retake`: a finished simulated run verifies
//! clean; damaged, missing and stray files make verify fail naming each of them and print the
//! retake command; the retake captures exactly those steps again, after which the run
//! verifies clean and every frame is byte-identical to the original (the simulated rig is
//! deterministic and trigger ids depend only on step and exposure).

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::*;
use stagehand::storage::RunStatus;
use stagehand::storage::verify::{ProblemKind, verify_run};

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

fn stagehand(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("stagehand runs")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// (step, path) of the first frame row matching `condition`.
fn frame_where(dir: &Path, condition: &str) -> (usize, String) {
    db(dir)
        .query_row(
            &format!("SELECT step, path FROM frames WHERE {condition} ORDER BY id LIMIT 1"),
            [],
            |r| Ok((r.get::<_, i64>(0)? as usize, r.get(1)?)),
        )
        .expect("a frame row")
}

#[test]
fn damaged_steps_are_found_by_verify_and_repaired_by_a_retake() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().expect("temp dir");
    let out = run_sequence(
        "quickstart.rhai",
        small_rig("lightstage", 32, 24),
        &[],
        tmp.path(),
        7,
    );
    assert_eq!(out.result.expect("quickstart runs").status, RunStatus::Done);
    let dir = out.dir;
    let d = dir.to_str().expect("utf-8 path");

    let clean = stagehand(&["verify", d]);
    assert_eq!(clean.status.code(), Some(0), "{}", text(&clean));
    assert!(text(&clean).contains("ok:"), "{}", text(&clean));
    let original_pixels = raw_pixels(&dir);
    let original_files = disk_checksums(&dir);

    // Damage three capture steps: a lamp capture, the HDR bracket and a laser line.
    let (lamp_step, garbage) = frame_where(&dir, "kind = 'raw' AND laser_on = 0");
    let (hdr_step, flipped) = frame_where(&dir, "kind = 'hdr'");
    let (laser_step, deleted) = frame_where(&dir, "kind = 'raw' AND laser_on = 1");
    assert!(lamp_step < hdr_step && hdr_step < laser_step);
    std::fs::write(dir.join(&garbage), b"garbage").expect("garbage");
    let mut bytes = std::fs::read(dir.join(&flipped)).expect("hdr");
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    std::fs::write(dir.join(&flipped), bytes).expect("flip");
    std::fs::remove_file(dir.join(&deleted)).expect("delete");
    // A leftover temp file and a stray file.
    let temp = "frames/.s000001_cam1_e0.png.99.0.stagehand-tmp";
    std::fs::write(dir.join(temp), b"half a frame").expect("temp");
    std::fs::write(dir.join("frames/notes.txt"), b"mine").expect("stray");

    let report = verify_run(&dir).expect("verify");
    assert!(!report.ok);
    let kind_of = |path: &str| {
        report
            .problems
            .iter()
            .find(|p| p.path.as_deref() == Some(path))
            .map(|p| p.kind)
    };
    assert_eq!(kind_of(&garbage), Some(ProblemKind::SizeMismatch));
    assert_eq!(kind_of(&flipped), Some(ProblemKind::ChecksumMismatch));
    assert_eq!(kind_of(&deleted), Some(ProblemKind::MissingFile));
    assert_eq!(kind_of(temp), Some(ProblemKind::TempFile));
    assert_eq!(kind_of("frames/notes.txt"), Some(ProblemKind::StrayFile));
    assert_eq!(report.problems.len(), 5, "{:#?}", report.problems);
    assert_eq!(report.retake_steps, vec![lamp_step, hdr_step, laser_step]);
    let command = format!("stagehand resume --retake {lamp_step},{hdr_step},{laser_step} {d}");
    assert_eq!(report.retake_command.as_deref(), Some(command.as_str()));

    // The CLI: exit 1, every damaged file and the repair command in the report; --json too.
    let failed = stagehand(&["verify", d]);
    assert_eq!(failed.status.code(), Some(1), "{}", text(&failed));
    for path in [&garbage, &flipped, &deleted] {
        assert!(text(&failed).contains(path.as_str()), "{}", text(&failed));
    }
    assert!(
        text(&failed).contains(&format!("repair: {command}")),
        "{}",
        text(&failed)
    );
    let json = stagehand(&["verify", "--json", d]);
    assert_eq!(json.status.code(), Some(1));
    let parsed: serde_json::Value = serde_json::from_slice(&json.stdout).expect("JSON report");
    assert_eq!(
        parsed["retake_steps"],
        serde_json::json!([lamp_step, hdr_step, laser_step])
    );

    // A step that records no frames cannot be retaken: bad input, nothing changes.
    let refused = stagehand(&["resume", "--retake", "0", d, "--yes"]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(text(&refused).contains("step 0"), "{}", text(&refused));

    std::fs::remove_file(dir.join("frames/notes.txt")).expect("remove stray");
    let retake = format!("{lamp_step},{hdr_step},{laser_step}");
    let repaired = stagehand(&["resume", "--retake", &retake, d, "--yes"]);
    assert_eq!(repaired.status.code(), Some(0), "{}", text(&repaired));

    let after = verify_run(&dir).expect("verify");
    assert!(after.ok, "{}", after.render());
    let pixels = raw_pixels(&dir);
    assert_eq!(pixels.len(), original_pixels.len());
    let differing: Vec<&String> = pixels
        .iter()
        .zip(&original_pixels)
        .filter(|(a, b)| a != b)
        .map(|(a, _)| &a.0)
        .collect();
    assert!(differing.is_empty(), "retaken pixels differ: {differing:?}");
    assert_eq!(disk_checksums(&dir), original_files, "retaken files differ");
    let conn = db(&dir);
    assert_eq!(
        count(&conn, "SELECT count(*) FROM runs WHERE status = 'done'"),
        1
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM steps WHERE status != 'done'"),
        0
    );
}
