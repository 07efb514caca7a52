//! Ground truth beside frames (`sim.ground_truth = true`): depth, normal, radiance and
//! material OpenEXR files next to each camera's first exposure of a capture, indexed with
//! checksums, plus the manifest's `sim` block and the run's `scene.toml`; an aborted and
//! resumed run reproduces an uninterrupted one byte for byte, ground truth included.

use crate::common;

use std::sync::Arc;

use common::*;
use stagehand::executor::{AutoConfirm, Event, RunControl};
use stagehand::storage::RunStatus;
use stagehand::storage::exr_planes::decode_exr_planes;

const W: u32 = 32;
const H: u32 = 24;

fn quickstart() -> stagehand::session::Prepared {
    stagehand::session::prepare(
        script("quickstart.rhai"),
        &sets(&[("lamp_count", "1"), ("sweep_lines", "2")]),
        small_rig_with_ground_truth("lightstage", W, H),
    )
    .expect("sequence prepares")
}

#[test]
fn ground_truth_files_sit_beside_frames_and_are_indexed() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let out = run_prepared(
        quickstart(),
        tmp.path(),
        7,
        Arc::new(AutoConfirm),
        RunControl::new(),
    );
    out.result.as_ref().expect("run finishes");
    let conn = db(&out.dir);
    // Once per capture and camera: beside exposure 0, never beside later bracket exposures.
    let firsts = count(
        &conn,
        "SELECT count(*) FROM frames WHERE kind='raw' AND exposure_index=0",
    );
    let brackets = count(
        &conn,
        "SELECT count(*) FROM frames WHERE kind='raw' AND exposure_index>0",
    );
    assert!(
        firsts > 0 && brackets > 0,
        "{firsts} first exposures, {brackets} later"
    );
    assert_eq!(
        count(&conn, "SELECT count(*) FROM ground_truth"),
        4 * firsts
    );
    assert_eq!(
        count(
            &conn,
            "SELECT count(*) FROM ground_truth g JOIN frames f ON f.id = g.frame_id
             WHERE f.exposure_index = 0 AND f.camera = g.camera AND f.step = g.step"
        ),
        4 * firsts
    );
    // Every indexed file is on disk with the indexed checksum, and nothing else is.
    assert_eq!(checksums(&out.dir), {
        let mut disk: Vec<(String, String)> = disk_checksums(&out.dir)
            .into_iter()
            .map(|(name, sha)| (format!("frames/{name}"), sha))
            .collect();
        disk.sort();
        disk
    });
    // The effect plan of every frame is queryable from the index.
    assert_eq!(
        count(
            &conn,
            "SELECT count(*) FROM frames WHERE kind='raw'
             AND json_type(notes, '$.effects.shadows.on') IN ('true', 'false')"
        ),
        count(&conn, "SELECT count(*) FROM frames WHERE kind='raw'")
    );

    let mut stmt = conn
        .prepare(
            "SELECT g.kind, g.path, f.camera FROM ground_truth g JOIN frames f ON f.id = g.frame_id
             ORDER BY g.path",
        )
        .unwrap();
    let rows: Vec<(String, String, String)> = stmt
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
        .unwrap()
        .map(|r| r.unwrap())
        .collect();
    let (mut background, mut centre_hits) = (0usize, 0usize);
    for (kind, path, camera) in &rows {
        assert!(path.ends_with(&format!("_e0.{kind}.exr")), "{path}");
        let bytes = std::fs::read(out.dir.join(path)).unwrap();
        let planes = decode_exr_planes(path, &bytes).unwrap();
        assert_eq!((planes.width, planes.height), (W, H), "{path}");
        let meta: serde_json::Value =
            serde_json::from_str(planes.metadata.as_deref().unwrap()).unwrap();
        assert_eq!(meta["ground_truth"], kind.as_str());
        assert_eq!(meta["frame"]["camera"], camera.as_str());
        let n = (W * H) as usize;
        match kind.as_str() {
            "depth" => {
                let z = planes.channel("Z").unwrap();
                assert_eq!(z.len(), n);
                assert!(z.iter().all(|d| d.is_finite() && *d >= 0.0), "{path}");
                // The sample sits at the centre of every view.
                let centre = z[(H / 2 * W + W / 2) as usize];
                assert!(centre > 100.0, "{path}: centre depth {centre}");
                centre_hits += 1;
                background += z.iter().filter(|d| **d == 0.0).count();
            }
            "normal" => {
                let depth_path = path.replace(".normal.", ".depth.");
                let depth = decode_exr_planes(
                    &depth_path,
                    &std::fs::read(out.dir.join(&depth_path)).unwrap(),
                )
                .unwrap();
                let z = depth.channel("Z").unwrap();
                let (x, y, zz) = (
                    planes.channel("X").unwrap(),
                    planes.channel("Y").unwrap(),
                    planes.channel("Z").unwrap(),
                );
                for i in 0..n {
                    let len = (x[i] * x[i] + y[i] * y[i] + zz[i] * zz[i]).sqrt();
                    if z[i] > 0.0 {
                        assert!((len - 1.0).abs() < 1e-4, "{path} pixel {i}: |n| = {len}");
                    } else {
                        assert_eq!(len, 0.0, "{path} pixel {i}: background normal");
                    }
                }
            }
            "radiance" => {
                for c in ["R", "G", "B"] {
                    let v = planes.channel(c).unwrap();
                    assert!(v.iter().all(|v| v.is_finite() && *v >= 0.0), "{path}");
                }
            }
            "material" => {
                for c in ["albedo.R", "ks", "alpha", "alpha_y", "medium", "model"] {
                    assert_eq!(planes.channel(c).map(<[f32]>::len), Some(n), "{path} {c}");
                }
            }
            other => panic!("unexpected ground truth kind {other}"),
        }
    }
    assert!(centre_hits > 0);
    assert!(background > 0, "the low cameras see past the turntable");

    // The manifest records the renderer and the scene; the scene text is in the run.
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.dir.join("manifest.json")).unwrap()).unwrap();
    let sim = &manifest["sim"];
    assert_eq!(sim["quality"], "preview");
    assert_eq!(sim["sample"], "bumps");
    assert_eq!(sim["ground_truth"], true);
    assert!(sim["knobs"]["spp_side"].is_u64(), "{sim}");
    let scene = std::fs::read(out.dir.join("scene.toml")).unwrap();
    assert!(!scene.is_empty());
    use sha2::Digest;
    let sha: String = sha2::Sha256::digest(&scene)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(sim["scene_sha256"], sha.as_str());
}

/// Runs quickstart, aborting when the `abort_at`-th capture step starts (if any).
fn run_aborting(out: &std::path::Path, abort_at: Option<usize>) -> std::path::PathBuf {
    let prepared = quickstart();
    let control = RunControl::new();
    let runtime = stagehand::session::runtime_for(&prepared.rig).unwrap();
    let store = stagehand::session::create_run(&prepared, out, 11).unwrap();
    let dir = store.dir().to_path_buf();
    let result = runtime.block_on(async {
        let (tx, mut rx) = tokio::sync::broadcast::channel(10_000);
        let ctl = control.clone();
        tokio::spawn(async move {
            let mut captures = 0;
            while let Ok(e) = rx.recv().await {
                if let Event::StepStarted {
                    kind: "capture", ..
                } = e
                {
                    captures += 1;
                    if Some(captures) == abort_at {
                        ctl.abort();
                    }
                }
            }
        });
        let wiring = stagehand::session::Wiring {
            events: tx,
            control: control.clone(),
            operator: Arc::new(AutoConfirm),
            reserve_bytes: 0,
        };
        let rig = stagehand::session::open_rig(&prepared.rig, 11, None).unwrap();
        stagehand::session::run(prepared, store, rig, wiring).await
    });
    assert_eq!(result.is_err(), abort_at.is_some(), "{:?}", result.err());
    dir
}

#[test]
fn an_aborted_and_resumed_run_reproduces_frames_and_ground_truth() {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir().unwrap();
    let reference = run_aborting(&tmp.path().join("reference"), None);
    let interrupted = run_aborting(&tmp.path().join("interrupted"), Some(3));
    let partial = count(&db(&interrupted), "SELECT count(*) FROM ground_truth");
    let full = count(&db(&reference), "SELECT count(*) FROM ground_truth");
    assert!(
        partial < full,
        "the abort left work to do: {partial} of {full}"
    );
    let summary = resume(&interrupted, Arc::new(AutoConfirm)).expect("resume");
    assert_eq!(summary.status, RunStatus::Done);
    assert_eq!(disk_checksums(&interrupted), disk_checksums(&reference));
    assert_eq!(checksums(&interrupted), checksums(&reference));
    assert_eq!(
        checksums(&interrupted).len(),
        disk_checksums(&interrupted).len()
    );
}
