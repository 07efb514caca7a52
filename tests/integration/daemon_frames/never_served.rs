//! What is never served: paths that traverse out of the data directory, index rows and
//! symlinks that point outside a run, and frame files that no longer match their checksum
//! (refused with a repair hint, and reported by verify).

use super::*;
use dataset::SECRET;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn path_traversal_never_serves_a_file() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.run_id;
        let (id, _) = first_of(d, "raw");
        for target in [
            "/api/runs/..%2F..%2Fetc/frames".to_string(),
            "/api/runs/..%2Fsecret.txt/frames/1".to_string(),
            format!("/api/runs/..%2Fruns%2F{run}/frames/{id}"),
            "/api/runs/%2Fetc%2Fpasswd/frames".to_string(),
            "/api/runs/..%5C..%5Csecret.txt/frames/1".to_string(),
            "/api/runs/a%00b/frames".to_string(),
            "/api/runs/..%2f..%2f..%2fetc%2fpasswd/frames/1/thumbnail".to_string(),
            format!("/api/runs/{run}%2F..%2F..%2Fsecret.txt/frames/{id}"),
            format!("/api/runs/{run}/frames/..%2F..%2Fsecret.txt"),
            format!("/api/runs/{run}/frames/{id}%2F..%2F..%2Fsecret.txt"),
            format!("/api/runs/{run}/frames/%2Fetc%2Fpasswd"),
            // Unencoded dot segments: no client normalises them on the way.
            format!("/api/runs/../runs/{run}/frames/{id}"),
            format!("/api/runs/{run}/frames/../../secret.txt"),
            format!("/api/runs/{run}/../../secret.txt"),
            "/api/runs/../../secret.txt".to_string(),
            "/api/runs/.%2E/frames".to_string(),
            "/api/cameras/..%2F..%2Fsecret.txt/latest".to_string(),
        ] {
            let (status, text) = api.raw_get(&target);
            assert!(
                status == 400 || status == 404,
                "{target}: status {status}\n{text}"
            );
            assert!(!text.contains(SECRET), "{target} served a secret");
            assert!(!text.contains("root:"), "{target} served /etc/passwd");
        }
        // A run directory that is a symlink is not a run.
        let (status, _) = api.raw_get("/api/runs/linked-run/frames");
        assert_eq!(status, 404);
        // Index rows and files pointing outside the run: 404, never the file.
        let evil = &d.evil_id;
        assert_eq!(
            api.get(&format!("/api/runs/{evil}/frames?limit=1")).status,
            200,
            "the tampered run still lists"
        );
        for (id, how) in &d.evil_frames {
            for suffix in ["", "?format=tiff", "/thumbnail"] {
                let a = api.get(&format!("/api/runs/{evil}/frames/{id}{suffix}"));
                assert_eq!(a.status, 404, "{how}{suffix}: {}", a.text());
                assert!(!a.text().contains(SECRET), "{how}{suffix} served a secret");
            }
        }
    })
    .await;
}

/// A frame file that no longer matches the SHA-256 its index row recorded (or is gone) is never
/// served: every format and the thumbnail answer 500 with a JSON error naming the file, the
/// frame and the step, and saying how to find and repair the damage.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn damaged_frame_files_are_refused_with_a_repair_hint() {
    let _turn = crate::grbl_peer::alongside();
    with_api(|d, api| {
        let run = &d.damaged_id;
        for (id, path, how) in &d.damaged_frames {
            let step: i64 = common::db(&d.run_dir)
                .query_row("SELECT step FROM frames WHERE id = ?1", [id], |r| r.get(0))
                .expect("step");
            for suffix in ["", "?format=tiff", "?format=exr", "/thumbnail"] {
                let a = api.get(&format!("/api/runs/{run}/frames/{id}{suffix}"));
                assert_eq!(a.status, 500, "{how}{suffix}: {}", a.text());
                assert!(
                    a.content_type.starts_with("application/json"),
                    "{how}{suffix}"
                );
                let error = a.json()["error"].as_str().unwrap_or("").to_string();
                let hint = a.json()["hint"].as_str().unwrap_or("").to_string();
                assert!(error.contains(path.as_str()), "{how}{suffix}: {error}");
                assert!(
                    error.contains(&format!("frame {id}")),
                    "{how}{suffix}: {error}"
                );
                assert!(
                    error.contains(&format!("step {step}")),
                    "{how}{suffix}: {error}"
                );
                assert!(hint.contains("stagehand verify"), "{how}{suffix}: {hint}");
                assert!(
                    hint.contains(&format!("--retake {step}")),
                    "{how}{suffix}: {hint}"
                );
            }
        }
        // The run's verify report names every damaged file and the steps to retake.
        let report = api.get(&format!("/api/runs/{run}/verify"));
        assert_eq!(report.status, 200, "{}", report.text());
        let report = report.json();
        assert_eq!(report["ok"], false, "{report}");
        let problems = report["problems"].as_array().cloned().unwrap_or_default();
        let mut steps = Vec::new();
        for (id, path, how) in &d.damaged_frames {
            let p = problems
                .iter()
                .find(|p| p["path"] == path.as_str())
                .unwrap_or_else(|| panic!("{how}: {path} not in {report}"));
            assert_eq!(p["frame_id"], *id, "{how}");
            steps.push(p["step"].as_u64().expect("step"));
        }
        steps.sort();
        steps.dedup();
        assert_eq!(report["retake_steps"], serde_json::json!(steps));
        let command = report["retake_command"].as_str().unwrap_or("");
        assert!(
            command.starts_with("stagehand resume --retake "),
            "{command}"
        );
        // The intact original verifies clean.
        let clean = api.get(&format!("/api/runs/{}/verify", d.run_id)).json();
        assert_eq!(clean["ok"], true, "{clean}");
        assert_eq!(clean["files_checked"], 80);
        assert_eq!(api.get("/api/runs/no-such-run/verify").status, 404);

        // An intact frame of the same run is still served.
        let intact: i64 = db(d)
            .query_row(
                "SELECT id FROM frames WHERE kind = 'raw' ORDER BY id LIMIT 1 OFFSET 1",
                [],
                |r| r.get(0),
            )
            .expect("a second raw frame");
        assert!(d.damaged_frames.iter().all(|(bad, _, _)| *bad != intact));
        let a = api.get(&format!("/api/runs/{run}/frames/{intact}?format=tiff"));
        assert_eq!(a.status, 200, "{}", a.text());
    })
    .await;
}
