//! The linear-light reflectometer end to end on the simulated rig (ground truth on, as-built
//! cameras): a response sweep and `calibrate response`; the opal reference scanned and
//! `calibrate reflectometer`; then a glossy, a matte and an anisotropic sample scanned,
//! `process --products ward,transparency`, and `evaluate` against the material plane. The
//! cameras' exact geometry (`calibrate geometry --from-truth`) is used so that the figures
//! measure the reflectometry, not a geometric calibration.

use std::path::{Path, PathBuf};

use stagehand::rig::RigSource;
use stagehand_dataset::products::ProductStore;

use super::common::calibration::{exact_geometry, stagehand, stagehand_output};
use super::common::{run_sequence, small_rig};

/// The reflectometer rig at 128×96, with as-built deviations and the material plane of ground
/// truth (what the maps are evaluated against; the radiance plane would render every frame
/// twice).
fn rig() -> RigSource {
    let text = small_rig("reflectometer", 128, 96).text.replacen(
        "[sim]\n",
        "[sim]\nground_truth = [\"material\"]\n",
        1,
    ) + "\n[sim.as_built]\nseed = 5\n";
    RigSource::from_text(&text, "test:reflectometer+as_built").expect("rig parses")
}

/// Runs reflectometer.rhai over `sample` with `sets`; returns the run directory.
fn scan(out: &Path, sample: &str, sets: &[(&str, &str)]) -> PathBuf {
    let mut all = vec![("sample", sample), ("positions", "61")];
    all.extend_from_slice(sets);
    let run = run_sequence("reflectometer.rhai", rig(), &all, out, 1);
    run.result.as_ref().expect("the scan runs");
    run.dir.clone()
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A scene file of a flat sample with `material` (TOML lines).
fn scene(dir: &Path, name: &str, material: &str) -> String {
    let file = dir.join(format!("{name}.toml"));
    let text = format!(
        "[scene]\nname = \"{name}\"\n\n[sample]\nshape = \"flat\"\n\n[material]\n{material}\n"
    );
    std::fs::write(&file, text).expect("write scene");
    path(&file).to_string()
}

fn figure(report: &serde_json::Value, section: &str, what: &str) -> f64 {
    report[section][what]["median"]
        .as_f64()
        .unwrap_or_else(|| panic!("{section}.{what} in {report:#}"))
}

#[test]
fn ward_and_transparency_maps_come_back_from_simulated_scans() {
    let _turn = crate::grbl_peer::alongside();
    let out = tempfile::tempdir().unwrap();
    let sweep = run_sequence("calibration_response.rhai", rig(), &[], out.path(), 1);
    sweep.result.as_ref().expect("the response sweep runs");
    let response = stagehand(&["calibrate", "response", path(&sweep.dir), "--json"]);
    let response = response["id"].as_str().expect("an id").to_string();

    let reference = scan(out.path(), "opal_reference", &[]);
    let geometry = exact_geometry(&reference);
    let sources = stagehand(&[
        "calibrate",
        "reflectometer",
        path(&reference),
        "--response",
        &response,
        "--geometry",
        &geometry,
        "--albedo",
        "0.8",
        "--transmittance",
        "0.5",
        "--json",
    ]);
    let sources = sources["id"].as_str().expect("an id").to_string();
    let process = |run: &Path| {
        stagehand(&[
            "process",
            path(run),
            "--products",
            "ward,transparency",
            "--calibration",
            &response,
            "--calibration",
            &sources,
            "--calibration",
            &geometry,
            "--json",
        ])
    };

    // Glossy, and a little transparent.
    let glossy = scan(
        out.path(),
        &scene(
            out.path(),
            "glossy",
            "model = \"ward\"\nalbedo = [0.3, 0.2, 0.1]\nks = 0.2\nalpha = 0.15\ntransmittance = [0.2, 0.3, 0.4]",
        ),
        &[],
    );
    let made = process(&glossy);
    assert_eq!(made["reflectometer"]["ward_written"], 1, "{made:#}");
    assert_eq!(made["reflectometer"]["transparency_written"], 1, "{made:#}");
    let products = ProductStore::open(&glossy).unwrap().products().unwrap();
    let files: Vec<&str> = products.iter().map(|p| p.path.as_str()).collect();
    assert_eq!(
        files,
        [
            "products/transparency/cam1.exr",
            "products/transparency/cam1.png",
            "products/ward/cam1.exr",
            "products/ward/cam1.png",
        ],
        "{files:?}"
    );
    let report = stagehand(&["evaluate", path(&glossy)]);
    eprintln!("glossy: {:#}", report["ward"]);
    eprintln!("glossy transparency: {:#}", report["transparency"]);
    assert!(figure(&report, "ward", "rho_d") < 0.02, "{report:#}");
    assert!(figure(&report, "ward", "rho_s") < 0.05, "{report:#}");
    assert!(figure(&report, "ward", "alpha") < 0.05, "{report:#}");
    assert!(report["ward"]["not_converged"].as_f64().unwrap() < 0.05);
    // The fitted model re-rendered under every stop: within the sensor's noise.
    assert!(figure(&report, "ward", "rerender") < 0.03, "{report:#}");
    assert_eq!(report["ward"]["flagged_anisotropic"], 0.0, "{report:#}");
    assert!(report["transparency"]["error"]["median"].as_f64().unwrap() < 0.01);
    // A rerun makes nothing again.
    let again = process(&glossy);
    assert_eq!(again["reflectometer"]["ward_skipped"], 1, "{again:#}");
    assert_eq!(again["reflectometer"]["transparency_skipped"], 1);

    // Matte: the diffuse albedo, and no specular lobe to report.
    let matte = scan(
        out.path(),
        &scene(
            out.path(),
            "matte",
            "model = \"lambert\"\nalbedo = [0.6, 0.5, 0.4]",
        ),
        &[("backlight", "false")],
    );
    process_ward_only(&matte, &response, &sources, &geometry);
    let report = stagehand(&["evaluate", path(&matte)]);
    eprintln!("matte: {:#}", report["ward"]);
    assert!(figure(&report, "ward", "rho_d") < 0.02, "{report:#}");
    assert!(
        report["ward"]["no_specular"].as_f64().unwrap() > 0.9,
        "{report:#}"
    );

    // Brushed metal, scanned twice with a quarter turn: isotropic Ward does not fit it, and
    // the maps say so.
    let brushed = scan(
        out.path(),
        "brushed_metal",
        &[("turned", "true"), ("backlight", "false")],
    );
    process_ward_only(&brushed, &response, &sources, &geometry);
    let report = stagehand(&["evaluate", path(&brushed)]);
    eprintln!("brushed: {:#}", report["ward"]);
    let found = report["ward"]["anisotropy_found"].as_f64().unwrap();
    assert!(found > 0.9, "{report:#}");

    // Through another response calibration than the reference's: refused, naming the right one.
    let other = stagehand(&[
        "calibrate",
        "response",
        path(&sweep.dir),
        "--smoothness",
        "50",
        "--json",
    ]);
    let other = other["id"].as_str().unwrap();
    let refused = stagehand_output(&[
        "process",
        path(&matte),
        "--products",
        "ward",
        "--calibration",
        other,
        "--calibration",
        &sources,
    ]);
    assert!(!refused.status.success());
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(
        text.contains(&response) && text.contains("made through"),
        "{text}"
    );
}

fn process_ward_only(run: &Path, response: &str, sources: &str, geometry: &str) {
    let made = stagehand(&[
        "process",
        path(run),
        "--products",
        "ward",
        "--calibration",
        response,
        "--calibration",
        sources,
        "--calibration",
        geometry,
        "--json",
    ]);
    assert_eq!(made["reflectometer"]["ward_written"], 1, "{made:#}");
}
