//! Calibrations as versioned artefacts: each is a directory `calibrations/<kind>-<hash>/`
//! holding one `calibration.json` with its inputs (runs and frames), parameters, results,
//! quality figures, the cameras and lamps it describes, and the software that made it. The id
//! is a hash of that content, so the same inputs and settings give the same id and a changed
//! calibration can never be mistaken for the old one. Directories are written whole (temp
//! directory, then rename) and never modified.

use std::fs;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use stagehand_dataset::atomic::{fsync_dir, write_atomic};
use stagehand_dataset::checksum::sha256_hex;
use thiserror::Error;

/// The kinds of calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CalibrationKind {
    /// Per-camera, per-channel inverse response curves.
    Response,
    /// Joint camera+lamp white-balance scales.
    Colour,
    /// Intrinsics, distortion and rig poses of the cameras.
    Geometry,
    /// Laser planes per laser position.
    LaserPlanes,
    /// The reflectometer's tube intensity and backlight panel radiance per camera, from a
    /// reference sample.
    Reflectometer,
}

impl CalibrationKind {
    /// The kind as spelled in ids and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            CalibrationKind::Response => "response",
            CalibrationKind::Colour => "colour",
            CalibrationKind::Geometry => "geometry",
            CalibrationKind::LaserPlanes => "laser-planes",
            CalibrationKind::Reflectometer => "reflectometer",
        }
    }
}

/// Frames of one run that a calibration used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationInput {
    /// The run's id (its directory name).
    pub run_id: String,
    /// Frame file names within the run.
    pub frames: Vec<String>,
}

/// The content of a calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// What it calibrates.
    pub kind: CalibrationKind,
    /// Camera ids it describes.
    pub cameras: Vec<String>,
    /// Lamp ids it describes (colour calibrations).
    pub lamps: Vec<String>,
    /// Where its data came from.
    pub inputs: Vec<CalibrationInput>,
    /// The settings of the computation.
    pub parameters: serde_json::Value,
    /// The result (kind-specific).
    pub result: serde_json::Value,
    /// Quality figures (RMS errors, residuals, standard deviations).
    pub quality: serde_json::Value,
    /// The stagehand version that computed it.
    pub software: String,
}

/// A stored calibration: its id and content.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredCalibration {
    /// `<kind>-<first 12 hex digits of the content's SHA-256>`.
    pub id: String,
    /// The calibration.
    #[serde(flatten)]
    pub calibration: Calibration,
}

/// Errors of the calibration store.
#[derive(Debug, Error)]
pub enum CalibrationStoreError {
    #[error("calibration store {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("calibration {id}: {message}")]
    Storage { id: String, message: String },
    #[error(
        "calibration {path} is not valid: {message}; it was edited or damaged — compute it again"
    )]
    Invalid { path: PathBuf, message: String },
    #[error("no calibration `{id}` in {root}; `stagehand calibrations list` shows the stored ones")]
    NotFound { id: String, root: PathBuf },
    #[error(
        "calibration {id} does not describe {what} `{missing}` (it covers {covered:?}); compute a calibration for this rig or name the right one"
    )]
    Mismatch {
        id: String,
        what: &'static str,
        missing: String,
        covered: Vec<String>,
    },
    #[error("calibration {id} is a {found} calibration, not a {wanted} one")]
    WrongKind {
        id: String,
        found: &'static str,
        wanted: &'static str,
    },
}

/// Name of the file inside a calibration directory.
pub const CALIBRATION_FILE: &str = "calibration.json";

/// The calibrations directory under a data root.
pub fn calibrations_dir(data_root: &Path) -> PathBuf {
    data_root.join("calibrations")
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CalibrationStoreError + '_ {
    move |source| CalibrationStoreError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The content id of `calibration`.
pub fn calibration_id(calibration: &Calibration) -> String {
    // serde_json maps are sorted, so the bytes (and the id) do not depend on field order.
    let bytes = serde_json::to_vec(calibration).unwrap_or_default();
    format!(
        "{}-{}",
        calibration.kind.as_str(),
        &sha256_hex(&bytes)[..12]
    )
}

/// Stores `calibration` under `root` (the calibrations directory) and returns it with its id.
/// Storing the same content again is a no-op that returns the same id.
pub fn save(
    root: &Path,
    calibration: Calibration,
) -> Result<StoredCalibration, CalibrationStoreError> {
    fs::create_dir_all(root).map_err(io(root))?;
    let id = calibration_id(&calibration);
    let stored = StoredCalibration { id, calibration };
    let dir = root.join(&stored.id);
    if dir.join(CALIBRATION_FILE).is_file() {
        return Ok(stored);
    }
    let tmp = root.join(format!(".{}.{}.tmp", stored.id, std::process::id()));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).map_err(io(&tmp))?;
    }
    fs::create_dir(&tmp).map_err(io(&tmp))?;
    let json = serde_json::to_vec_pretty(&stored).map_err(|e| CalibrationStoreError::Storage {
        id: stored.id.clone(),
        message: e.to_string(),
    })?;
    write_atomic(&tmp, CALIBRATION_FILE, &json).map_err(|e| CalibrationStoreError::Storage {
        id: stored.id.clone(),
        message: e.to_string(),
    })?;
    let storage = |e: stagehand_dataset::StorageError| CalibrationStoreError::Storage {
        id: stored.id.clone(),
        message: e.to_string(),
    };
    fsync_dir(&tmp).map_err(storage)?;
    fs::rename(&tmp, &dir).map_err(io(&dir))?;
    fsync_dir(root).map_err(|e| CalibrationStoreError::Storage {
        id: stored.id.clone(),
        message: e.to_string(),
    })?;
    Ok(stored)
}

/// Loads calibration `id` from `root`, checking that its content still has that id.
pub fn load(root: &Path, id: &str) -> Result<StoredCalibration, CalibrationStoreError> {
    let path = root.join(id).join(CALIBRATION_FILE);
    if !path.is_file() {
        return Err(CalibrationStoreError::NotFound {
            id: id.to_string(),
            root: root.to_path_buf(),
        });
    }
    let bytes = fs::read(&path).map_err(io(&path))?;
    let stored: StoredCalibration =
        serde_json::from_slice(&bytes).map_err(|e| CalibrationStoreError::Invalid {
            path: path.clone(),
            message: e.to_string(),
        })?;
    let expected = calibration_id(&stored.calibration);
    if stored.id != id || expected != id {
        return Err(CalibrationStoreError::Invalid {
            path,
            message: format!("its content hashes to {expected}, not {id}"),
        });
    }
    Ok(stored)
}

/// Every stored calibration under `root`, by id; unreadable ones are returned as errors in
/// place so a listing shows them.
pub fn list(
    root: &Path,
) -> Result<Vec<Result<StoredCalibration, CalibrationStoreError>>, CalibrationStoreError> {
    if !root.exists() {
        return Ok(Vec::new());
    }
    let mut ids: Vec<String> = fs::read_dir(root)
        .map_err(io(root))?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| !n.starts_with('.'))
        .collect();
    ids.sort();
    Ok(ids.iter().map(|id| load(root, id)).collect())
}

impl StoredCalibration {
    /// The result decoded as `T`, after checking the kind.
    pub fn result<T: DeserializeOwned>(
        &self,
        kind: CalibrationKind,
    ) -> Result<T, CalibrationStoreError> {
        if self.calibration.kind != kind {
            return Err(CalibrationStoreError::WrongKind {
                id: self.id.clone(),
                found: self.calibration.kind.as_str(),
                wanted: kind.as_str(),
            });
        }
        serde_json::from_value(self.calibration.result.clone()).map_err(|e| {
            CalibrationStoreError::Storage {
                id: self.id.clone(),
                message: format!("its result does not decode: {e}"),
            }
        })
    }

    /// The cameras of a geometry calibration: its result is a list of [`CameraGeometry`], a
    /// map by camera id, or either under a `cameras` key (a [`GeometryCalibration`]).
    ///
    /// [`CameraGeometry`]: crate::calibrate_geometry::CameraGeometry
    /// [`GeometryCalibration`]: crate::geometry_calibration::GeometryCalibration
    pub fn cameras(
        &self,
    ) -> Result<Vec<crate::calibrate_geometry::CameraGeometry>, CalibrationStoreError> {
        use crate::calibrate_geometry::CameraGeometry;
        let value: serde_json::Value = self.result(CalibrationKind::Geometry)?;
        let cameras = value.get("cameras").unwrap_or(&value);
        if let Ok(list) = serde_json::from_value::<Vec<CameraGeometry>>(cameras.clone()) {
            return Ok(list);
        }
        serde_json::from_value::<std::collections::BTreeMap<String, CameraGeometry>>(
            cameras.clone(),
        )
        .map(|m| m.into_values().collect())
        .map_err(|e| CalibrationStoreError::Storage {
            id: self.id.clone(),
            message: format!("its result holds no camera geometries ({e})"),
        })
    }

    /// Checks that the calibration covers every camera in `cameras` and lamp in `lamps`.
    pub fn check_covers(
        &self,
        cameras: &[String],
        lamps: &[String],
    ) -> Result<(), CalibrationStoreError> {
        for (what, wanted, covered) in [
            ("camera", cameras, &self.calibration.cameras),
            ("lamp", lamps, &self.calibration.lamps),
        ] {
            if let Some(missing) = wanted.iter().find(|w| !covered.contains(w)) {
                return Err(CalibrationStoreError::Mismatch {
                    id: self.id.clone(),
                    what,
                    missing: missing.clone(),
                    covered: covered.clone(),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Calibration {
        Calibration {
            kind: CalibrationKind::Colour,
            cameras: vec!["cam1".into(), "cam2".into()],
            lamps: vec!["lamp1".into()],
            inputs: vec![CalibrationInput {
                run_id: "run-1".into(),
                frames: vec!["a.png".into()],
            }],
            parameters: serde_json::json!({"patches": "all"}),
            result: serde_json::json!({"scale": [1.0, 0.5, 0.25]}),
            quality: serde_json::json!({"rel_std": 0.001}),
            software: "stagehand 0.1.0".into(),
        }
    }

    #[test]
    fn saves_loads_and_lists_by_content_id() {
        let dir = tempfile::tempdir().unwrap();
        let root = calibrations_dir(dir.path());
        let a = save(&root, sample()).unwrap();
        assert!(a.id.starts_with("colour-") && a.id.len() == "colour-".len() + 12);
        assert_eq!(
            save(&root, sample()).unwrap().id,
            a.id,
            "same content, same id"
        );
        let mut other = sample();
        other.parameters = serde_json::json!({"patches": "neutral"});
        let b = save(&root, other).unwrap();
        assert_ne!(a.id, b.id);
        assert_eq!(load(&root, &a.id).unwrap(), a);
        assert_eq!(list(&root).unwrap().len(), 2);
        #[derive(Deserialize)]
        struct Scale {
            scale: [f64; 3],
        }
        let s: Scale = a.result(CalibrationKind::Colour).unwrap();
        assert_eq!(s.scale, [1.0, 0.5, 0.25]);
        assert!(matches!(
            a.result::<Scale>(CalibrationKind::Geometry),
            Err(CalibrationStoreError::WrongKind { .. })
        ));
    }

    #[test]
    fn a_tampered_or_mismatched_calibration_is_refused_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let root = calibrations_dir(dir.path());
        let a = save(&root, sample()).unwrap();
        let err = a.check_covers(&["cam3".into()], &[]).unwrap_err();
        assert!(err.to_string().contains("camera `cam3`"), "{err}");
        assert!(a.check_covers(&["cam1".into()], &["lamp1".into()]).is_ok());
        let path = root.join(&a.id).join(CALIBRATION_FILE);
        let text = fs::read_to_string(&path).unwrap().replace("0.25", "0.26");
        fs::write(&path, text).unwrap();
        let err = load(&root, &a.id).unwrap_err();
        assert!(
            matches!(err, CalibrationStoreError::Invalid { .. }),
            "{err}"
        );
        assert!(matches!(
            load(&root, "colour-000000000000"),
            Err(CalibrationStoreError::NotFound { .. })
        ));
    }
}
