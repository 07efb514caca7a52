//! `stagehand process --products depth`: every laser sweep of a run (the frames one camera took
//! with the laser on and the sample on the stage, within one block of the script: one laser
//! position) turned into a depth image by space-time analysis ([`crate::space_time`]) and
//! triangulation against the laser sheets ([`crate::laser_sheet`], [`crate::ray_plane`]),
//! through the geometric calibration. One OpenEXR product per sweep and camera: channel `D`,
//! the distance along the pixel's ray from the camera centre in mm (−1 where unknown), and
//! `T`, the peak time in frames (−1 where unknown). The sweep's frames stream through one at
//! a time; sweeps run on every core.
//!
//! The sheets are a laser-planes calibration's ([`crate::laser_planes`]) when one is given,
//! else the rig file's ([`crate::laser_sheet`]). This is the depth of one laser direction; the
//! merge over directions (seed eqs 4.44–4.45) is still to come.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::StoredFrame;
use stagehand_dataset::exr_planes::encode_exr_planes;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::gray_image::GrayImage;
use crate::laser_line::{LineOptions, ScanAxis, detect_line};
use crate::laser_planes::{LaserPlanes, PLANES_FIXTURE};
use crate::laser_sheet::{
    LaserMount, laser_channel, nominal_emitter, nominal_sheet, scan_axis, triangulation_volume,
};
use crate::ray_plane::{NO_DEPTH, depth_map, ray_distance};
use crate::rig_frame::sample_to_camera;
use crate::run_frames::{axis_angle, channel_image, dataset_err, decode_frame_in, raw_frames};
use crate::space_time::{DIM_WINDOW_PX, NO_TIME, SpaceTime, SpaceTimeOptions, drop_dim_peaks};

/// How a sweep becomes depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum DepthMethod {
    /// Each pixel's peak time over the sweep (Curless–Levoy): products of kind `depth`.
    SpaceTime,
    /// The naive baseline of Horus and FabScan: the line's peak across each column (or row)
    /// of every frame, triangulated against that frame's sheet: kind `depth_per_frame`.
    PerFrame,
}

impl DepthMethod {
    /// The product kind of depth images made this way.
    pub fn kind(self) -> &'static str {
        match self {
            DepthMethod::SpaceTime => "depth",
            DepthMethod::PerFrame => "depth_per_frame",
        }
    }
}

/// What depth is made with.
#[derive(Debug, Clone, Copy)]
pub struct DepthSetup<'a> {
    /// Every camera's geometry, by id, and the geometry calibration's id.
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The laser's distance from the rig origin (the rig file's), mm.
    pub laser_distance_mm: f64,
    /// The turntable's axis id.
    pub turntable_axis: Option<&'a str>,
    /// The light arc's axis id.
    pub light_arc_axis: Option<&'a str>,
    /// Space-time settings.
    pub options: SpaceTimeOptions,
    /// The calibrated laser sheets and their calibration's id (`None`: the rig file's).
    pub laser_planes: Option<(&'a LaserPlanes, &'a str)>,
    /// Only these cameras' sweeps (`None`: every camera's).
    pub cameras: Option<&'a [String]>,
    /// Space-time analysis, or the per-frame baseline.
    pub method: DepthMethod,
}

/// One camera's frames of one sweep, in capture order.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// Camera id.
    pub camera: String,
    /// The script block the sweep ran in.
    pub block: String,
    /// Its frames, by step.
    pub frames: Vec<StoredFrame>,
}

/// What a depth pass did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct DepthSummary {
    /// Sweeps (per camera) found.
    pub sweeps: usize,
    /// Depth images written now.
    pub written: usize,
    /// Depth images already current.
    pub skipped: usize,
    /// Of the pixels of the images written, the fraction with a depth.
    pub known_fraction: f64,
}

/// Every sweep of the run: raw frames with the laser on and not of the planes fixture,
/// grouped by block and camera; sweeps of fewer than 3 frames are left out.
pub fn sweeps(run_dir: &Path) -> Result<Vec<Sweep>, ProcessingError> {
    let mut groups: BTreeMap<(String, String), Vec<StoredFrame>> = BTreeMap::new();
    for f in raw_frames(run_dir)? {
        if f.meta.laser_on && f.meta.fixture != PLANES_FIXTURE {
            groups
                .entry((f.meta.block.clone(), f.meta.camera.clone()))
                .or_default()
                .push(f);
        }
    }
    Ok(groups
        .into_iter()
        .filter(|(_, frames)| frames.len() >= 3)
        .map(|((block, camera), mut frames)| {
            frames.sort_by_key(|f| (f.meta.step, f.meta.exposure_index));
            Sweep {
                camera,
                block,
                frames,
            }
        })
        .collect())
}

/// Writes the depth image of every sweep of the run in `store`; `progress(done, total)`
/// after each.
pub fn depth_products(
    store: &mut ProductStore,
    setup: DepthSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<DepthSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let sweeps: Vec<Sweep> = sweeps(&run_dir)?
        .into_iter()
        .filter(|s| setup.cameras.is_none_or(|c| c.contains(&s.camera)))
        .collect();
    let (cameras, geometry_id) = setup.geometry;
    let mut summary = DepthSummary {
        sweeps: sweeps.len(),
        ..DepthSummary::default()
    };
    let mut todo = Vec::new();
    for sweep in &sweeps {
        let geometry =
            cameras
                .get(&sweep.camera)
                .ok_or_else(|| ProcessingError::CalibrationMismatch {
                    id: geometry_id.to_string(),
                    why: format!(
                        "it has no geometry for camera `{}` (sweep in block `{}`); calibrate this rig's cameras with `stagehand calibrate geometry`, or process the others alone (`--cameras`)",
                        sweep.camera, sweep.block
                    ),
                })?;
        let first = sweep.frames[0].meta.step;
        let table = axis_angle(
            &run_dir,
            &sweep.frames[0].meta,
            &sweep.frames[0].path,
            setup.turntable_axis,
        )?;
        let kind = setup.method.kind();
        let new = NewProduct {
            kind: kind.into(),
            key: format!("{kind}/s{first:06}/{}", sweep.camera),
            file_name: format!("s{first:06}_{}.exr", sweep.camera),
            inputs: sweep.frames.iter().map(|f| f.path.clone()).collect(),
            calibrations: std::iter::once(geometry_id.to_string())
                .chain(setup.laser_planes.map(|(_, id)| id.to_string()))
                .collect(),
            software: software.to_string(),
            parameters: json!({
                "threshold_sigmas": setup.options.threshold_sigmas,
                "relative_floor": setup.options.relative_floor,
                "laser_distance_mm": setup.laser_distance_mm,
                "sheets": setup.laser_planes.map_or("nominal (rig file)", |(_, id)| id),
                "distance": "along the unit pixel ray from the camera centre, mm; -1 unknown",
                "camera": sweep.camera,
                "turntable_deg": table,
            }),
        };
        if store.is_current(&new).map_err(dataset_err(&run_dir))? {
            summary.skipped += 1;
        } else {
            todo.push((sweep, geometry, new));
        }
    }
    let total = sweeps.len();
    let mut done = summary.skipped;
    progress(done, total);
    let (mut known, mut pixels) = (0usize, 0usize);
    // A few sweeps per core at a time: each holds two frames and its per-pixel state.
    let batch = 2 * rayon::current_num_threads().max(1);
    for chunk in todo.chunks(batch) {
        let made: Vec<(NewProduct, Vec<u8>, usize, usize)> = chunk
            .par_iter()
            .map(|(sweep, geometry, new)| {
                let (bytes, k, n) = one_sweep(&run_dir, sweep, geometry, &setup, new)?;
                Ok((new.clone(), bytes, k, n))
            })
            .collect::<Result<_, ProcessingError>>()?;
        for (new, bytes, k, n) in made {
            store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
            summary.written += 1;
            known += k;
            pixels += n;
            done += 1;
            progress(done, total);
        }
    }
    summary.known_fraction = if pixels > 0 {
        known as f64 / pixels as f64
    } else {
        0.0
    };
    Ok(summary)
}

/// One sweep's depth image: its OpenEXR bytes, and the pixels known and in all.
fn one_sweep(
    run_dir: &Path,
    sweep: &Sweep,
    geometry: &CameraGeometry,
    setup: &DepthSetup<'_>,
    new: &NewProduct,
) -> Result<(Vec<u8>, usize, usize), ProcessingError> {
    let first = &sweep.frames[0];
    let (w, h) = (first.meta.width as usize, first.meta.height as usize);
    let channel = laser_channel(first.meta.laser_colour_nm);
    let saturation = ((1u32 << first.meta.bit_depth.min(16)) - 1) as f32;
    let mut st = match setup.method {
        DepthMethod::SpaceTime => Some(SpaceTime::new(
            w,
            h,
            SpaceTimeOptions {
                saturation: Some(saturation),
                ..setup.options
            },
        )?),
        DepthMethod::PerFrame => None,
    };
    let table = axis_angle(run_dir, &first.meta, &first.path, setup.turntable_axis)?;
    let arc = axis_angle(run_dir, &first.meta, &first.path, setup.light_arc_axis)?;
    let mount = LaserMount {
        elevation_deg: first
            .meta
            .laser_mount_deg
            .ok_or_else(|| ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!("frame {} records no laser mount elevation", first.path),
            })?,
        distance_mm: setup.laser_distance_mm,
    };
    let colour = first.meta.laser_colour_nm;
    if let Some((planes, id)) = setup.laser_planes
        && planes.position(colour, mount.elevation_deg, arc).is_none()
    {
        {
            return Err(ProcessingError::CalibrationMismatch {
                id: id.to_string(),
                why: format!(
                    "it has no laser position {colour} nm at {}° elevation and light arc {arc}° for the sweep of camera `{}` in block `{}`; calibrate this run's laser positions with `stagehand calibrate laser-planes`, or leave the calibration out to use the rig file's sheets",
                    mount.elevation_deg, sweep.camera, sweep.block
                ),
            });
        }
    }
    let sheet_at = |tilt: f64| match setup.laser_planes {
        Some((planes, _)) => planes.sheet(colour, mount.elevation_deg, arc, tilt, table),
        None => nominal_sheet(&mount, arc, tilt, table),
    };
    let pose = sample_to_camera(&geometry.rig_to_camera, table);
    let mut per_frame = PerFrame::new(w, h, scan_axis(&geometry.model, &pose, arc, table));
    let mut tilts = Vec::with_capacity(sweep.frames.len());
    for (k, f) in sweep.frames.iter().enumerate() {
        let png = decode_frame_in(run_dir, f)?;
        if (png.width as usize, png.height as usize) != (w, h) {
            return Err(ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!(
                    "frame {} is {}×{} but its sweep's are {w}×{h}",
                    f.path, png.width, png.height
                ),
            });
        }
        let image = channel_image(&png, channel);
        let tilt = f
            .meta
            .laser_tilt_deg
            .ok_or_else(|| ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!(
                    "frame {} records no laser tilt; a sweep needs the tilt of every line",
                    f.path
                ),
            })?;
        tilts.push(tilt);
        match st.as_mut() {
            Some(st) => st.push(&image.data)?,
            None => {
                let options = LineOptions {
                    saturation: Some(saturation),
                    ..LineOptions::default()
                };
                let sheet = sheet_at(tilt);
                per_frame.add(&image, &options, k, |u, v| {
                    sheet.and_then(|s| ray_distance(&geometry.model, &pose, (u, v), &s))
                })?;
            }
        }
    }
    let (depth, time) = match st {
        Some(st) => {
            let mut times = st.finish()?;
            drop_dim_peaks(&mut times, DIM_WINDOW_PX, setup.options.relative_floor);
            let last = (tilts.len() - 1) as f64;
            let depth = depth_map(&times, &geometry.model, &pose, |t| {
                if !(0.0..=last).contains(&t) {
                    return None;
                }
                let k = (t.floor() as usize).min(tilts.len() - 2);
                let frac = t - k as f64;
                sheet_at(tilts[k] + (tilts[k + 1] - tilts[k]) * frac)
            });
            (depth, times.time)
        }
        None => (per_frame.depth, per_frame.time),
    };
    let known = depth.iter().filter(|d| **d != NO_DEPTH).count();
    let mut samples = Vec::with_capacity(2 * w * h);
    for (d, t) in depth.iter().zip(&time) {
        samples.push(*d);
        samples.push(*t);
    }
    let middle = tilts[tilts.len() / 2];
    let nu = sheet_at(middle).map_or(0.0, |sheet| {
        let to_sample =
            nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), -table.to_radians());
        let emitter = to_sample * nominal_emitter(&mount, arc);
        triangulation_volume(&emitter, &pose.centre(), &sheet)
    });
    let metadata = json!({
        "camera": sweep.camera,
        "first_frame": first.path,
        "nu_mm3": nu,
        "block": sweep.block,
        "steps": [first.meta.step, sweep.frames[sweep.frames.len() - 1].meta.step],
        "turntable_deg": table,
        "light_arc_deg": arc,
        "laser_mount_deg": mount.elevation_deg,
        "laser_colour_nm": first.meta.laser_colour_nm,
        "method": setup.method,
        "channels": {"D": "distance along the pixel ray, mm; -1 unknown", "T": "peak time, frames; -1 unknown"},
    });
    let bytes = encode_exr_planes(
        &new.file_name,
        w as u32,
        h as u32,
        &["D".to_string(), "T".to_string()],
        &samples,
        &metadata.to_string(),
    )
    .map_err(dataset_err(run_dir))?;
    Ok((bytes, known, w * h))
}

/// The per-frame baseline's image: at each pixel the depth of the brightest line point that
/// fell in it, over the sweep's frames.
struct PerFrame {
    width: usize,
    axis: ScanAxis,
    depth: Vec<f32>,
    time: Vec<f32>,
    height: Vec<f32>,
}

impl PerFrame {
    fn new(width: usize, height: usize, axis: ScanAxis) -> PerFrame {
        PerFrame {
            width,
            axis,
            depth: vec![NO_DEPTH; width * height],
            time: vec![NO_TIME; width * height],
            height: vec![0.0; width * height],
        }
    }

    /// Adds frame `k`'s line: each point triangulated by `distance(u, v)`.
    fn add(
        &mut self,
        image: &GrayImage,
        options: &LineOptions,
        k: usize,
        distance: impl Fn(f64, f64) -> Option<f64>,
    ) -> Result<(), ProcessingError> {
        let found = detect_line(image, self.axis, options)?;
        let rows = self.depth.len() / self.width.max(1);
        for p in found.points {
            let (u, v) = match self.axis {
                ScanAxis::Columns => (p.along as f64, p.across),
                ScanAxis::Rows => (p.across, p.along as f64),
            };
            let (x, y) = (u.round() as usize, v.round() as usize);
            if x >= self.width || y >= rows {
                continue;
            }
            let i = y * self.width + x;
            if p.height <= self.height[i] {
                continue;
            }
            if let Some(d) = distance(u, v) {
                self.depth[i] = d as f32;
                self.time[i] = k as f32;
                self.height[i] = p.height;
            }
        }
        Ok(())
    }
}
