//! `stagehand process` end to end: a response sweep on the simulated as-built rig (8-bit
//! cameras with the seed's strongly non-linear response, ground truth on), `calibrate
//! response`, then `process --products hdr` on the sweep: one OpenEXR product per camera,
//! indexed with its inputs, calibration and checksum, within 1 % (median) of the noise-free
//! radiance where the linear merge of the capture is several times worse; a rerun skips every
//! product, a deleted product is made again and only it; and a run whose camera the
//! calibration does not cover is refused before anything is written, naming the camera.

use std::sync::Arc;

use stagehand::executor::{AutoConfirm, RunControl};
use stagehand::rig::RigSource;
use stagehand::script::ScriptSource;
use stagehand::session;
use stagehand_dataset::products::ProductStore;

use super::common::calibration::{as_built_rig_with, stagehand, stagehand_output};
use super::common::{run_prepared, run_sequence, small_rig};

#[test]
fn hdr_products_are_indexed_resumed_and_refused_for_cameras_not_calibrated() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().unwrap();
    let sweep = run_sequence(
        "calibration_response.rhai",
        as_built_rig_with("strong", 8, |text| {
            text.replacen("[sim]\n", "[sim]\nground_truth = true\n", 1)
        }),
        &[],
        out.path(),
        1,
    );
    sweep.result.as_ref().expect("the sweep runs");
    let dir = sweep.dir.to_str().expect("utf-8 path");
    let response = stagehand(&["calibrate", "response", dir, "--json"]);
    let id = response["id"].as_str().expect("an id").to_string();

    let first = stagehand(&["process", dir, "--calibration", &id, "--json"]);
    assert_eq!(first["hdr"]["written"], 8, "{first}");
    assert_eq!(first["hdr"]["skipped"], 0);
    let products = ProductStore::open(&sweep.dir).unwrap().products().unwrap();
    assert_eq!(products.len(), 8);
    for p in &products {
        assert_eq!(p.made.kind, "hdr");
        assert_eq!(p.made.calibrations, vec![id.clone()]);
        assert_eq!(p.made.inputs.len(), 12, "the 12-exposure bracket");
        let bytes = std::fs::read(sweep.dir.join(&p.path)).expect("the product file");
        let exr = stagehand_dataset::exr_hdr::decode_exr(&p.path, &bytes).expect("OpenEXR");
        assert_eq!((exr.width, exr.height), (480, 360));
        assert!(exr.pixels.iter().all(|v| v.is_finite() && *v >= 0.0));
        assert!(exr.pixels.iter().any(|v| *v > 0.0));
    }

    // Against the noise-free radiance (measured: 0.47 % median, 1.2 % at p90; the linear merge
    // 4.3 % and 22 %).
    let report = stagehand(&["evaluate", dir]);
    let hdr = &report["hdr"];
    assert_eq!(hdr["products"], 8, "{report:#}");
    let ours = hdr["calibrated"]["median"].as_f64().expect("figures");
    let linear = hdr["linear_merge"]["median"].as_f64().expect("figures");
    assert!(ours < 0.01, "{hdr:#}");
    assert!(linear > 3.0 * ours, "{hdr:#}");

    // Rerun: nothing to do. A product lost: made again, alone.
    let again = stagehand(&["process", dir, "--calibration", &id, "--json"]);
    assert_eq!(
        (
            again["hdr"]["written"].as_u64(),
            again["hdr"]["skipped"].as_u64()
        ),
        (Some(0), Some(8))
    );
    std::fs::remove_file(sweep.dir.join(&products[3].path)).unwrap();
    let repaired = stagehand(&["process", dir, "--calibration", &id, "--json"]);
    assert_eq!(
        (
            repaired["hdr"]["written"].as_u64(),
            repaired["hdr"]["skipped"].as_u64()
        ),
        (Some(1), Some(7))
    );

    // A rig whose cam8 is called cam9, naming the response calibration in its file: the run
    // records it, `process` uses it by default, and it does not cover cam9.
    let rig = small_rig("lightstage", 48, 36);
    let renamed = format!(
        "{}\n[calibration]\nresponse = \"{id}\"\n",
        rig.text.replace("id = \"cam8\"", "id = \"cam9\"")
    );
    assert_ne!(renamed, rig.text);
    let rig = RigSource::from_text(&renamed, "test:lightstage+cam9").expect("rig parses");
    let script = ScriptSource {
        name: "one.rhai".into(),
        text: "home();\nlamps_on(lamps());\ncapture(0.01);\nlamps_off();\n".into(),
    };
    let prepared = session::prepare(script, &[], rig).expect("prepares");
    let other_out = out.path().join("other");
    let other = run_prepared(
        prepared,
        &other_out,
        1,
        Arc::new(AutoConfirm),
        RunControl::new(),
    );
    other.result.as_ref().expect("the capture runs");
    // The calibration lives beside the sweep: copy it beside this run.
    let from = out.path().join("calibrations").join(&id);
    let to = other_out.join("calibrations").join(&id);
    std::fs::create_dir_all(&to).unwrap();
    for f in std::fs::read_dir(&from).unwrap() {
        let f = f.unwrap();
        std::fs::copy(f.path(), to.join(f.file_name())).unwrap();
    }
    let manifest = stagehand_dataset::read_manifest(&other.dir).unwrap();
    assert_eq!(manifest.calibrations.get("response"), Some(&id));
    let refused = stagehand_output(&["process", other.dir.to_str().unwrap()]);
    assert!(!refused.status.success());
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(
        text.contains(&id) && text.contains("camera `cam9`"),
        "{text}"
    );
    assert!(
        ProductStore::open(&other.dir)
            .unwrap()
            .products()
            .unwrap()
            .is_empty(),
        "nothing written"
    );
}
