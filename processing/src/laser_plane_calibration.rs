//! `stagehand calibrate laser-planes RUN`: each laser position's sheet measured on the
//! two-height planes fixture (seed 004 §2.2, L872). In every frame of the fixture with the
//! laser on, the line is found ([`crate::laser_line`]); each line point's ray, through the
//! geometric calibration, meets the raised plane (the fixture's half y > 0 of the sample
//! frame, `step_mm` up) or the low plane (y < 0, z = 0), which the ray's order of crossing
//! decides; points on the step's wall, near an edge or off the fixture are left out. The
//! points of every camera at one tilt, in the rig frame, fit one plane by total least squares
//! with outliers trimmed (points on two heights fix its angle, points on one only a line, which
//! is refused). Frames at several tilts of one position give the pencil the sweep turns in
//! ([`crate::laser_planes`]).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use stagehand_dataset::StoredFrame;

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::laser_line::{LineOptions, detect_line};
use crate::laser_planes::{
    CalibratedSheet, LaserPlanes, LaserPosition, PLANES_FIXTURE, angle_between, fit_plane,
    oriented_like,
};
use crate::laser_sheet::{LaserMount, laser_channel, nominal_emitter, nominal_sheet, scan_axis};
use crate::ray_plane::{Plane, pixel_ray};
use crate::rig_frame::sample_to_camera;
use crate::run_frames::{axis_angle, channel_image, decode_frame_in, raw_frames};

/// The two-height planes fixture: its low half (y < 0 of the sample frame) at z = 0 and its
/// raised half (y > 0) at `step_mm`, both `size_mm` across.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlanesFixture {
    /// Height of the raised plane, mm.
    pub step_mm: f64,
    /// Side of the fixture, mm.
    pub size_mm: f64,
    /// Points closer than this to the step or an outer edge are left out, mm.
    pub margin_mm: f64,
}

/// What the calibration needs besides the run.
#[derive(Debug, Clone, Copy)]
pub struct LaserPlanesSetup<'a> {
    /// Every camera's geometry, by id, and the geometry calibration's id.
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The fixture.
    pub fixture: PlanesFixture,
    /// The laser's distance from the rig origin (rig file), mm: the nominal sheet to compare.
    pub laser_distance_mm: f64,
    /// The turntable's axis id.
    pub turntable_axis: Option<&'a str>,
    /// The light arc's axis id.
    pub light_arc_axis: Option<&'a str>,
    /// Line detection settings.
    pub line: LineOptions,
}

/// The calibration's result and the frames it read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserPlanesResult {
    /// The calibrated positions.
    pub planes: LaserPlanes,
    /// Frame files used.
    pub frames: Vec<String>,
    /// Cameras whose frames were read.
    pub cameras: Vec<String>,
}

/// Fewest fitted points on each height for a sheet.
pub const MIN_POINTS_PER_HEIGHT: usize = 10;

/// A line point dimmer than this fraction of the frame's bright line (its 90th percentile)
/// is not the line.
pub const RELATIVE_FLOOR: f32 = 0.25;

/// A sheet whose points lie farther than this from it (RMS, mm) was fitted to more than the
/// line, and is refused.
pub const MAX_SHEET_RMS_MM: f64 = 0.25;

/// A line point found on the fixture, rig frame, and whether it lies on the raised plane.
type FixturePoint = (Vector3<f64>, bool);

/// One setting of the laser: colour, mount, arc and tilt in thousandths of a degree.
type SettingKey = (u32, i64, i64, i64);

fn milli(deg: f64) -> i64 {
    (deg * 1000.0).round() as i64
}

/// Calibrates every laser position of the run's planes-fixture frames.
pub fn calibrate_laser_planes(
    run_dir: &Path,
    setup: &LaserPlanesSetup<'_>,
) -> Result<LaserPlanesResult, ProcessingError> {
    let f = setup.fixture;
    if !(f.step_mm.is_finite() && f.step_mm > 0.0) {
        return Err(ProcessingError::BadParameter {
            name: "planes fixture step",
            value: f.step_mm,
            why: "the raised plane must stand a positive height (mm) above the low one",
        });
    }
    if !(f.size_mm.is_finite() && f.margin_mm >= 0.0 && f.size_mm > 4.0 * f.margin_mm) {
        return Err(ProcessingError::BadParameter {
            name: "planes fixture size",
            value: f.size_mm,
            why: "the fixture must be wider than four edge margins (mm)",
        });
    }
    let (cameras, geometry_id) = setup.geometry;
    let mut groups: BTreeMap<SettingKey, Vec<StoredFrame>> = BTreeMap::new();
    for frame in raw_frames(run_dir)? {
        let m = &frame.meta;
        if !(m.laser_on && m.fixture == PLANES_FIXTURE) {
            continue;
        }
        if !cameras.contains_key(&m.camera) {
            return Err(ProcessingError::CalibrationMismatch {
                id: geometry_id.to_string(),
                why: format!(
                    "it has no geometry for camera `{}` (frame {}); calibrate this rig's cameras with `stagehand calibrate geometry`",
                    m.camera, frame.path
                ),
            });
        }
        let missing = |what: &str| ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: format!("frame {} records no {what}", frame.path),
        };
        let mount = m
            .laser_mount_deg
            .ok_or_else(|| missing("laser mount elevation"))?;
        let tilt = m.laser_tilt_deg.ok_or_else(|| missing("laser tilt"))?;
        let arc = axis_angle(run_dir, m, &frame.path, setup.light_arc_axis)?;
        let key = (
            m.laser_colour_nm,
            milli(mount),
            milli(arc.rem_euclid(360.0)),
            milli(tilt),
        );
        groups.entry(key).or_default().push(frame);
    }
    if groups.is_empty() {
        return Err(ProcessingError::MissingInput {
            run: run_dir.display().to_string(),
            what: format!("frame of the `{PLANES_FIXTURE}` fixture with the laser on"),
            hint: "capture the two-height planes fixture under each laser position (sequences/mdf_laser.rhai does)",
        });
    }
    let all: Vec<&StoredFrame> = groups.values().flatten().collect();
    let points: Vec<Vec<FixturePoint>> = all
        .par_iter()
        .map(|frame| frame_points(run_dir, frame, cameras, setup))
        .collect::<Result<_, _>>()?;
    let mut by_frame: BTreeMap<&str, Vec<FixturePoint>> = BTreeMap::new();
    for (frame, p) in all.iter().zip(points) {
        by_frame.insert(frame.path.as_str(), p);
    }
    let mut positions: Vec<LaserPosition> = Vec::new();
    let mut failed: BTreeMap<(u32, i64, i64), Vec<(f64, ProcessingError)>> = BTreeMap::new();
    for ((colour, mount, arc, _), frames) in &groups {
        let first = &frames[0].meta;
        let tilt = first.laser_tilt_deg.unwrap_or(0.0);
        let mount_deg = first.laser_mount_deg.unwrap_or(0.0);
        let arc_deg = *arc as f64 / 1000.0;
        let laser = LaserMount {
            elevation_deg: mount_deg,
            distance_mm: setup.laser_distance_mm,
        };
        let nominal =
            nominal_sheet(&laser, arc_deg, tilt, 0.0).ok_or_else(|| ProcessingError::IllPosed {
                what: "nominal laser sheet",
                why: format!(
                    "the rig file's laser at {mount_deg}° elevation and {} mm makes no plane",
                    setup.laser_distance_mm
                ),
            })?;
        let here: Vec<FixturePoint> = frames
            .iter()
            .flat_map(|f| by_frame[f.path.as_str()].iter().copied())
            .collect();
        let name = format!(
            "laser {colour} nm at {mount_deg}° elevation, arc {arc_deg}°, tilt {tilt}° ({} frames from {})",
            frames.len(),
            frames[0].path
        );
        let mut cams: Vec<String> = frames.iter().map(|f| f.meta.camera.clone()).collect();
        cams.dedup();
        let sheet = match fit_sheet(&here, &nominal, &name) {
            Ok(sheet) => sheet,
            Err(e) => {
                failed
                    .entry((*colour, *mount, *arc))
                    .or_default()
                    .push((tilt, e));
                continue;
            }
        };
        let sheet = CalibratedSheet {
            tilt_deg: tilt,
            cameras: cams,
            ..sheet
        };
        let at = positions.iter().position(|p| {
            p.colour_nm == *colour && milli(p.mount_deg) == *mount && milli(p.light_arc_deg) == *arc
        });
        match at {
            Some(i) => positions[i].sheets.push(sheet),
            None => {
                let a = arc_deg.to_radians();
                positions.push(LaserPosition {
                    colour_nm: *colour,
                    mount_deg,
                    light_arc_deg: arc_deg,
                    nominal_angle_deg: angle_between(&sheet.plane, &nominal),
                    sheets: vec![sheet],
                    nominal_emitter_mm: nominal_emitter(&laser, arc_deg).into(),
                    nominal_fan: [-a.sin(), a.cos(), 0.0],
                    pencil_check: None,
                    skipped: Vec::new(),
                });
            }
        }
    }
    // A tilt whose line missed the fixture (a sweep wider than it) is left out when the
    // position has other tilts; a position with none is an error.
    for ((colour, mount, arc), errors) in failed {
        let found = positions.iter_mut().find(|p| {
            p.colour_nm == colour && milli(p.mount_deg) == mount && milli(p.light_arc_deg) == arc
        });
        match found {
            Some(p) => p.skipped.extend(
                errors
                    .into_iter()
                    .map(|(tilt, e)| format!("tilt {tilt}°: {e}")),
            ),
            None => {
                if let Some((_, e)) = errors.into_iter().next() {
                    return Err(e);
                }
            }
        }
    }
    for p in &mut positions {
        p.sheets.sort_by(|a, b| a.tilt_deg.total_cmp(&b.tilt_deg));
        if p.sheets.len() >= 3 {
            let mut worst = [0.0f64; 2];
            for middle in &p.sheets[1..p.sheets.len() - 1] {
                if let Some(predicted) = p.sheet(middle.tilt_deg) {
                    let predicted = oriented_like(predicted, &middle.plane);
                    worst[0] = worst[0].max(angle_between(&predicted, &middle.plane));
                    worst[1] = worst[1].max((predicted.d - middle.plane.d).abs());
                }
            }
            p.pencil_check = Some(worst);
        }
    }
    let mut frames: Vec<String> = all.iter().map(|f| f.path.clone()).collect();
    frames.sort();
    let mut used: Vec<String> = all.iter().map(|f| f.meta.camera.clone()).collect();
    used.sort();
    used.dedup();
    Ok(LaserPlanesResult {
        planes: LaserPlanes { positions },
        frames,
        cameras: used,
    })
}

/// The line points of one fixture frame on the fixture's two planes, rig frame.
fn frame_points(
    run_dir: &Path,
    frame: &StoredFrame,
    cameras: &BTreeMap<String, CameraGeometry>,
    setup: &LaserPlanesSetup<'_>,
) -> Result<Vec<FixturePoint>, ProcessingError> {
    let m = &frame.meta;
    let Some(geometry) = cameras.get(&m.camera) else {
        return Ok(Vec::new());
    };
    let table = axis_angle(run_dir, m, &frame.path, setup.turntable_axis)?;
    let arc = axis_angle(run_dir, m, &frame.path, setup.light_arc_axis)?;
    let pose = sample_to_camera(&geometry.rig_to_camera, table);
    let png = decode_frame_in(run_dir, frame)?;
    let image = channel_image(&png, laser_channel(m.laser_colour_nm));
    let options = LineOptions {
        saturation: Some(((1u32 << m.bit_depth.min(16)) - 1) as f32),
        ..setup.line
    };
    let axis = scan_axis(&geometry.model, &pose, arc, table);
    let found = detect_line(&image, axis, &options).map_err(|e| ProcessingError::Camera {
        camera: m.camera.clone(),
        source: Box::new(e),
    })?;
    // The fixture is uniformly white: where the line lies on it, it is about equally bright
    // everywhere. Peaks far dimmer are light from elsewhere (the line reflected off the step,
    // stray light in a column the line does not cross), found above the noise all the same.
    let mut heights: Vec<f32> = found.points.iter().map(|p| p.height).collect();
    heights.sort_by(f32::total_cmp);
    let bright = heights.get(heights.len() * 9 / 10).copied().unwrap_or(0.0);
    let floor = RELATIVE_FLOOR * bright;
    let f = setup.fixture;
    let half = 0.5 * f.size_mm - f.margin_mm;
    let to_rig = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), table.to_radians());
    let mut out = Vec::with_capacity(found.points.len());
    for p in found.points.into_iter().filter(|p| p.height >= floor) {
        let (u, v) = match axis {
            crate::laser_line::ScanAxis::Columns => (p.along as f64, p.across),
            crate::laser_line::ScanAxis::Rows => (p.across, p.along as f64),
        };
        let Some((centre, dir)) = pixel_ray(&geometry.model, &pose, (u, v)) else {
            continue;
        };
        let at = |z: f64| {
            let t = (z - centre.z) / dir.z;
            (t.is_finite() && t > 0.0).then(|| centre + dir * t)
        };
        // A ray coming down crosses the raised plane first: on it if it lands on the raised
        // half, else it goes on to the low plane (or hits the wall between them).
        let on = match (at(f.step_mm), at(0.0)) {
            (Some(q), _) if q.y > f.margin_mm && q.y < half && q.x.abs() < half => Some((q, true)),
            (_, Some(q)) if q.y < -f.margin_mm && q.y > -half && q.x.abs() < half => {
                Some((q, false))
            }
            _ => None,
        };
        if let Some((q, high)) = on {
            out.push((to_rig * q, high));
        }
    }
    Ok(out)
}

/// Candidate planes [`consensus`] tries.
const CONSENSUS_TRIES: usize = 400;

/// A point within this distance of a candidate plane supports it, mm.
const CONSENSUS_TOLERANCE_MM: f64 = 0.2;

/// The points that support the plane through three of them (one on each height at least)
/// that most points support (RANSAC with a fixed sequence of draws, so a calibration is
/// reproducible): a least-squares start from all points is pulled off by a fifth of stray
/// points, and trimming from there keeps them. All the points when no three make a plane.
fn consensus(points: &[FixturePoint]) -> Vec<FixturePoint> {
    let n = points.len();
    if n < 3 {
        return points.to_vec();
    }
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut draw = || {
        // SplitMix64.
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) % n as u64) as usize
    };
    let mut best: Option<(usize, Vector3<f64>, f64)> = None;
    for _ in 0..CONSENSUS_TRIES {
        let (a, b, c) = (points[draw()], points[draw()], points[draw()]);
        if a.1 == b.1 && b.1 == c.1 {
            continue;
        }
        let Some(normal) = (b.0 - a.0).cross(&(c.0 - a.0)).try_normalize(1e-9) else {
            continue;
        };
        let d = normal.dot(&a.0);
        let support = points
            .iter()
            .filter(|p| (normal.dot(&p.0) - d).abs() <= CONSENSUS_TOLERANCE_MM)
            .count();
        if best.is_none_or(|(s, _, _)| support > s) {
            best = Some((support, normal, d));
        }
    }
    match best {
        Some((support, normal, d)) if support >= 3 => points
            .iter()
            .filter(|p| (normal.dot(&p.0) - d).abs() <= CONSENSUS_TOLERANCE_MM)
            .copied()
            .collect(),
        _ => points.to_vec(),
    }
}

/// The least share of a tilt's points the consensus plane must hold: with less, two sheets
/// (or the line and as much stray light) compete and neither is taken.
const MIN_CONSENSUS: f64 = 0.6;

/// The sheet through `points`: the consensus of [`consensus`], then outliers trimmed
/// (residuals beyond 4 robust σ, at least 0.02 mm, in three rounds), oriented like `nominal`;
/// refused when the points kept lie farther than [`MAX_SHEET_RMS_MM`] from it.
fn fit_sheet(
    points: &[FixturePoint],
    nominal: &Plane,
    name: &str,
) -> Result<CalibratedSheet, ProcessingError> {
    let ill = |why: String| ProcessingError::IllPosed {
        what: "laser-plane calibration",
        why: format!("{name}: {why}"),
    };
    let mut kept: Vec<FixturePoint> = consensus(points);
    if points.len() >= 2 * MIN_POINTS_PER_HEIGHT
        && (kept.len() as f64) < MIN_CONSENSUS * points.len() as f64
    {
        return Err(ill(format!(
            "no plane holds most of its points (at best {} of {}, within {CONSENSUS_TOLERANCE_MM} mm): light other than the line was taken for it — check for reflections and stray light on the fixture",
            kept.len(),
            points.len()
        )));
    }
    let count = |kept: &[FixturePoint]| {
        let high = kept.iter().filter(|p| p.1).count();
        (kept.len() - high, high)
    };
    let mut plane = None;
    for round in 0..4 {
        let (low, high) = count(&kept);
        if low < MIN_POINTS_PER_HEIGHT || high < MIN_POINTS_PER_HEIGHT {
            return Err(ill(format!(
                "the line was found at {low} points on the low plane and {high} on the raised one (after {round} rounds of trimming); at least {MIN_POINTS_PER_HEIGHT} on each are needed to fix the sheet's angle — check that the fixture is in place, the laser on and the exposure shows the line"
            )));
        }
        let xyz: Vec<Vector3<f64>> = kept.iter().map(|p| p.0).collect();
        let (fit, spread) = fit_plane(&xyz).ok_or_else(|| ill("too few points".into()))?;
        if spread[1] < 1.0 {
            return Err(ill(format!(
                "the points lie along one line (spread {:.3} mm across it); the line must cross both heights",
                spread[1]
            )));
        }
        let fit = oriented_like(fit, nominal);
        plane = Some(fit);
        if round == 3 {
            break;
        }
        let n = Vector3::from(fit.normal);
        let mut residuals: Vec<f64> = xyz.iter().map(|p| (n.dot(p) - fit.d).abs()).collect();
        residuals.sort_by(f64::total_cmp);
        let mad = residuals[residuals.len() / 2];
        let limit = (4.0 * 1.4826 * mad).max(0.02);
        kept.retain(|p| (n.dot(&p.0) - fit.d).abs() <= limit);
    }
    let plane = plane.ok_or_else(|| ill("no fit".into()))?;
    let n = Vector3::from(plane.normal);
    let rms = (kept
        .iter()
        .map(|p| (n.dot(&p.0) - plane.d).powi(2))
        .sum::<f64>()
        / kept.len() as f64)
        .sqrt();
    let (low, high) = count(&kept);
    if rms.is_nan() || rms > MAX_SHEET_RMS_MM {
        return Err(ill(format!(
            "its {} points lie {rms:.2} mm from the best plane (RMS; at most {MAX_SHEET_RMS_MM} mm): light other than the line was taken for it — check for reflections and stray light on the fixture",
            kept.len()
        )));
    }
    Ok(CalibratedSheet {
        tilt_deg: 0.0,
        plane,
        points_low: low,
        points_high: high,
        rms_mm: rms,
        cameras: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of the sheet x + 0.3 z = 0 on the fixture: the low plane (z = 0, y < 0) and the
    /// raised one (z = 20, y > 0), 0.01 mm of noise.
    fn sheet_points(plane: impl Fn(f64, f64) -> f64) -> Vec<FixturePoint> {
        let mut out = Vec::new();
        for i in 0..40 {
            let y = 2.0 + 0.8 * f64::from(i);
            let noise = 0.01 * ((f64::from(i) * 1.7).sin());
            out.push((Vector3::new(plane(-y, 0.0) + noise, -y, 0.0), false));
            out.push((Vector3::new(plane(y, 20.0) - noise, y, 20.0), true));
        }
        out
    }

    fn nominal() -> Plane {
        Plane::through([0.0, 0.0, 0.0], [1.0, 0.0, 0.3]).unwrap()
    }

    #[test]
    fn stray_points_off_the_line_are_trimmed() {
        let mut points = sheet_points(|_, z| -0.3 * z);
        // A fifth as many again of stray light on the low plane, far from the line.
        for i in 0..16 {
            let x = -30.0 + 4.0 * f64::from(i);
            points.push((Vector3::new(x, -10.0 - f64::from(i), 0.0), false));
        }
        let sheet = fit_sheet(&points, &nominal(), "test").expect("a sheet");
        assert!(angle_between(&sheet.plane, &nominal()) < 0.01, "{sheet:?}");
        assert!(sheet.rms_mm < 0.02, "{sheet:?}");
        assert_eq!((sheet.points_low, sheet.points_high), (40, 40));
    }

    #[test]
    fn points_of_two_sheets_are_refused_not_averaged() {
        // Half the points from a sheet turned 10° away: no plane fits both.
        let mut points = sheet_points(|_, z| -0.3 * z);
        let turned = (10f64).to_radians().tan();
        points.extend(sheet_points(|y, z| -0.3 * z + turned * y));
        let e = fit_sheet(&points, &nominal(), "test").expect_err("two sheets");
        assert!(
            e.to_string().contains("no plane holds most of its points"),
            "{e}"
        );
    }
}
