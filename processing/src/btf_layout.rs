//! Where each capture of a run goes in the BTF `[view, light, y, x, rgb]`: a view is a camera
//! at a turntable angle, a light is a lamp at an azimuth relative to the sample (light-arc
//! angle minus turntable angle), so captures that light the sample from the same direction
//! share a light index whatever the table's angle. Each view and light carries its direction
//! at the sample's centre in sample-frame angles (θ from the sample normal, φ from the
//! sample's x axis, degrees): views from the calibrated camera centres, lights from the lamps'
//! places on the light arc as the rig file gives them (the geometric calibration does not
//! measure lamps).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::run_frames::{BracketKey, axis_angle};

/// A lamp on the light arc, as the rig file places it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampPlacement {
    /// Lamp id.
    pub id: String,
    /// Elevation above the sample plane, degrees.
    pub elevation_deg: f64,
    /// Distance from the sample centre, mm.
    pub distance_mm: f64,
}

/// The axes whose angles place views and lights (ids as the frames record them).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BtfAxes {
    /// The turntable (`None`: the sample never turns).
    pub turntable: Option<String>,
    /// The light arc (`None`: the lamps never move).
    pub light_arc: Option<String>,
}

/// One view: a camera at a turntable angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BtfView {
    /// Camera id.
    pub camera: String,
    /// Turntable angle, degrees.
    pub turntable_deg: f64,
    /// Polar angle of the direction to the camera, degrees from the sample normal.
    pub theta_deg: f64,
    /// Azimuth of the direction to the camera, degrees from the sample's x axis.
    pub phi_deg: f64,
}

/// One light: a lamp at an azimuth relative to the sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BtfLight {
    /// Lamp id.
    pub lamp: String,
    /// Light-arc angle minus turntable angle, in [0, 360) degrees.
    pub relative_arc_deg: f64,
    /// Polar angle of the direction to the lamp, degrees from the sample normal.
    pub theta_deg: f64,
    /// Azimuth of the direction to the lamp, degrees from the sample's x axis.
    pub phi_deg: f64,
}

/// One filled cell of the BTF: which capture it holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BtfCell {
    /// View index.
    pub view: usize,
    /// Light index.
    pub light: usize,
    /// Plan step of the capture.
    pub step: usize,
    /// Camera id.
    pub camera: String,
}

/// The BTF's axes and which capture fills each cell.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BtfLayout {
    /// Views, by turntable angle then camera id.
    pub views: Vec<BtfView>,
    /// Lights, by relative azimuth then lamp id.
    pub lights: Vec<BtfLight>,
    /// Filled cells, by view then light; the others read as 0.
    pub cells: Vec<BtfCell>,
    /// (step, camera, why) of the captures left out.
    pub left_out: Vec<(usize, String, String)>,
}

impl BtfLayout {
    /// The cell of capture (`step`, `camera`), if it has one.
    pub fn cell_of(&self, step: usize, camera: &str) -> Option<&BtfCell> {
        self.cells
            .iter()
            .find(|c| c.step == step && c.camera == camera)
    }
}

/// A view (table angle, camera) or light (relative azimuth, lamp) as a sortable key.
type AxisKey = (i64, String);

/// An angle in thousandths of a degree in [0, 360°): the key that makes equal angles equal.
fn angle_key(deg: f64) -> i64 {
    (deg.rem_euclid(360.0) * 1000.0).round() as i64 % 360_000
}

/// θ and φ (degrees) of direction `d` in the sample frame.
fn angles_of(d: Vector3<f64>) -> (f64, f64) {
    let n = d.norm();
    let theta = (d.z / n).clamp(-1.0, 1.0).acos().to_degrees();
    let phi = d.y.atan2(d.x).to_degrees().rem_euclid(360.0);
    (theta, phi)
}

/// A rig-frame point seen in the sample frame when the table is at `turntable_deg`.
fn in_sample_frame(p: Vector3<f64>, turntable_deg: f64) -> Vector3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), -turntable_deg.to_radians()) * p
}

/// Lays out the BTF of `keys`: every capture with exactly one lamp of `lamps` on, by a camera
/// `geometry` covers. The others are listed as left out with the reason.
pub fn btf_layout(
    run: &Path,
    keys: &[BracketKey],
    geometry: &BTreeMap<String, CameraGeometry>,
    lamps: &[LampPlacement],
    axes: &BtfAxes,
) -> Result<BtfLayout, ProcessingError> {
    let mut views: BTreeMap<AxisKey, BtfView> = BTreeMap::new();
    let mut lights: BTreeMap<AxisKey, BtfLight> = BTreeMap::new();
    let mut cells: BTreeMap<(AxisKey, AxisKey), (usize, String)> = BTreeMap::new();
    let mut left_out = Vec::new();
    for key in keys {
        let [lamp_id] = key.meta.lamps_on.as_slice() else {
            left_out.push((
                key.step,
                key.camera.clone(),
                format!(
                    "{} lamps on; a BTF capture has exactly one",
                    key.meta.lamps_on.len()
                ),
            ));
            continue;
        };
        let Some(lamp) = lamps.iter().find(|l| &l.id == lamp_id) else {
            left_out.push((
                key.step,
                key.camera.clone(),
                format!("lamp `{lamp_id}` is not a halogen lamp on the light arc"),
            ));
            continue;
        };
        let Some(camera) = geometry.get(&key.camera) else {
            left_out.push((
                key.step,
                key.camera.clone(),
                "the geometric calibration does not cover this camera".into(),
            ));
            continue;
        };
        let path = key.frames.first().map_or("?", |f| f.path.as_str());
        let table = axis_angle(run, &key.meta, path, axes.turntable.as_deref())?;
        let arc = axis_angle(run, &key.meta, path, axes.light_arc.as_deref())?;
        let view_key = (angle_key(table), key.camera.clone());
        let relative = (arc - table).rem_euclid(360.0);
        let light_key = (angle_key(relative), lamp.id.clone());
        views.entry(view_key.clone()).or_insert_with(|| {
            let (theta_deg, phi_deg) =
                angles_of(in_sample_frame(Vector3::from(camera.centre_mm), table));
            BtfView {
                camera: key.camera.clone(),
                turntable_deg: table.rem_euclid(360.0),
                theta_deg,
                phi_deg,
            }
        });
        lights.entry(light_key.clone()).or_insert_with(|| {
            let (a, e) = (relative.to_radians(), lamp.elevation_deg.to_radians());
            let p = Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin()) * lamp.distance_mm;
            let (theta_deg, phi_deg) = angles_of(p);
            BtfLight {
                lamp: lamp.id.clone(),
                relative_arc_deg: relative,
                theta_deg,
                phi_deg,
            }
        });
        if let Some((earlier, _)) =
            cells.insert((view_key, light_key), (key.step, key.camera.clone()))
        {
            left_out.push((
                earlier,
                key.camera.clone(),
                format!(
                    "step {} captured the same view and light again; the later capture is used",
                    key.step
                ),
            ));
        }
    }
    let view_index: BTreeMap<_, usize> = views.keys().cloned().zip(0..).collect();
    let light_index: BTreeMap<_, usize> = lights.keys().cloned().zip(0..).collect();
    let mut cells: Vec<BtfCell> = cells
        .into_iter()
        .map(|((v, l), (step, camera))| BtfCell {
            view: view_index[&v],
            light: light_index[&l],
            step,
            camera,
        })
        .collect();
    cells.sort_by_key(|c| (c.view, c.light));
    Ok(BtfLayout {
        views: views.into_values().collect(),
        lights: lights.into_values().collect(),
        cells,
        left_out,
    })
}

#[cfg(test)]
mod tests {
    use stagehand_dataset::FrameMeta;

    use super::*;
    use crate::nominal_geometry::{NominalCamera, nominal_geometry};

    fn key(step: usize, camera: &str, table: f64, arc: f64, lamps: &[&str]) -> BracketKey {
        let meta: FrameMeta = serde_json::from_value(serde_json::json!({
            "step": step, "block": "", "label": "", "camera": camera, "kind": "raw",
            "exposure_index": 0, "exposure_s": 0.01, "exposures_s": [0.01], "gain": 1.0,
            "trigger_id": null, "lamps_on": lamps,
            "axes_deg": {"turntable": table, "light_arc": arc},
            "laser_armed": false, "laser_on": false, "laser_colour_nm": 0,
            "laser_tilt_deg": null, "laser_mount_deg": null, "fixture": "sample",
            "cart_mm": null, "rig_time_s": 0.0, "wall_time_unix_s": 0.0, "width": 64,
            "height": 48, "bit_depth": 12, "saturated_samples": 0, "notes": {}
        }))
        .unwrap();
        BracketKey {
            step,
            camera: camera.into(),
            meta,
            frames: Vec::new(),
        }
    }

    fn geometry(azimuths: &[(&str, f64)]) -> BTreeMap<String, CameraGeometry> {
        azimuths
            .iter()
            .map(|&(id, az)| {
                let nominal = NominalCamera {
                    id: id.into(),
                    width: 64,
                    height: 48,
                    azimuth_deg: az,
                    elevation_deg: 30.0,
                    distance_mm: 1000.0,
                    fov_deg: 10.0,
                    principal_offset_px: [0.0; 2],
                    distortion: Default::default(),
                };
                (id.to_string(), nominal_geometry(&nominal).unwrap())
            })
            .collect()
    }

    fn axes() -> BtfAxes {
        BtfAxes {
            turntable: Some("turntable".into()),
            light_arc: Some("light_arc".into()),
        }
    }

    #[test]
    fn lights_from_the_same_direction_share_an_index_whatever_the_table_angle() {
        let lamps = [LampPlacement {
            id: "lamp1".into(),
            elevation_deg: 60.0,
            distance_mm: 800.0,
        }];
        let geo = geometry(&[("cam1", 0.0)]);
        // Two table angles × two arc angles, 90° apart: relative azimuths 0, 90 and 270.
        let keys = [
            key(1, "cam1", 0.0, 0.0, &["lamp1"]),
            key(2, "cam1", 0.0, 90.0, &["lamp1"]),
            key(3, "cam1", 90.0, 90.0, &["lamp1"]),
            key(4, "cam1", 90.0, 0.0, &["lamp1"]),
            key(5, "cam1", 90.0, 0.0, &[]),
        ];
        let layout = btf_layout(Path::new("run"), &keys, &geo, &lamps, &axes()).unwrap();
        assert_eq!(layout.views.len(), 2);
        assert_eq!(layout.lights.len(), 3);
        assert_eq!(layout.cells.len(), 4);
        assert_eq!(layout.left_out.len(), 1, "the dark capture");
        // Steps 1 and 3 light the sample from its own 0°: one light.
        assert_eq!(
            layout.cell_of(1, "cam1").unwrap().light,
            layout.cell_of(3, "cam1").unwrap().light
        );
        let light = &layout.lights[layout.cell_of(4, "cam1").unwrap().light];
        assert!((light.relative_arc_deg - 270.0).abs() < 1e-9);
        assert!((light.theta_deg - 30.0).abs() < 1e-9, "{light:?}");
        assert!((light.phi_deg - 270.0).abs() < 1e-9, "{light:?}");
        // The camera at azimuth 0, 30° up; at table 90° the sample sees it at φ = 270°.
        let view = &layout.views[layout.cell_of(3, "cam1").unwrap().view];
        assert!((view.theta_deg - 60.0).abs() < 1e-6, "{view:?}");
        assert!((view.phi_deg - 270.0).abs() < 1e-6, "{view:?}");
    }

    #[test]
    fn captures_it_cannot_place_are_left_out_with_the_reason() {
        let lamps = [LampPlacement {
            id: "lamp1".into(),
            elevation_deg: 60.0,
            distance_mm: 800.0,
        }];
        let geo = geometry(&[("cam1", 0.0)]);
        let keys = [
            key(1, "cam2", 0.0, 0.0, &["lamp1"]),
            key(2, "cam1", 0.0, 0.0, &["tube"]),
            key(3, "cam1", 0.0, 0.0, &["lamp1", "lamp2"]),
        ];
        let layout = btf_layout(Path::new("run"), &keys, &geo, &lamps, &axes()).unwrap();
        assert!(layout.cells.is_empty());
        let why: Vec<&str> = layout.left_out.iter().map(|l| l.2.as_str()).collect();
        assert!(why[0].contains("does not cover"), "{why:?}");
        assert!(why[1].contains("not a halogen lamp"), "{why:?}");
        assert!(why[2].contains("2 lamps on"), "{why:?}");
        // A frame that does not record the turntable is an error naming it.
        let mut no_axis = key(4, "cam1", 0.0, 0.0, &["lamp1"]);
        no_axis.meta.axes_deg.clear();
        let err = btf_layout(Path::new("run"), &[no_axis], &geo, &lamps, &axes()).unwrap_err();
        assert!(err.to_string().contains("turntable"), "{err}");
    }
}
