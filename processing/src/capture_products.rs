//! `stagehand process`: every capture of a run (each camera's frames of one step: a bracket
//! or a single exposure) decoded once and merged into HDR radiance through the cameras'
//! inverse responses (divided by the white balance of the lamp that lit it when a colour
//! calibration is given), then written as any of: the HDR image (`hdr`, OpenEXR), the image
//! rectified onto the reference plane (`rectified`, OpenEXR RGBA, A = 1 where the camera saw
//! the whole footprint), and the capture's cell of the BTF (`btf`, a Zarr v3 group
//! `btf.zarr` with `radiance [view, light, y, x, rgb]` and `seen [view, y, x]`).
//!
//! Every file is a product: written atomically and indexed with its inputs, calibrations and
//! parameters, so an interrupted `process` resumes, skipping what is current. Captures are
//! merged a few per core at a time and written in order, so memory stays bounded by the batch
//! whatever the run's size; nothing at full resolution is kept unless `hdr` is asked for.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::exr_hdr::encode_exr;
use stagehand_dataset::exr_planes::encode_exr_planes;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::btf_layout::BtfLayout;
use crate::calibrate_geometry::CameraGeometry;
use crate::colour_calibration::ColourSet;
use crate::error::ProcessingError;
use crate::hdr_frame::{MergeWeight, PixelState, RgbExposure, merge_rgb_frames};
use crate::rectify::{Image, Rectified, RectifyGrid, RectifyMap};
use crate::response_calibration::{CameraResponse, ResponseSet};
use crate::rig_frame::sample_to_camera;
use crate::run_frames::{
    BracketKey, axis_angle, bracket_keys, dataset_err, decode_frame_in, open_run,
};
use crate::zarr_array::{ZarrArray, ZarrType, group_metadata};

/// The calibrations an HDR merge is made with.
#[derive(Debug, Clone, Copy)]
pub struct HdrCalibrations<'a> {
    /// The response calibration and its id.
    pub response: (&'a ResponseSet, &'a str),
    /// The colour calibration and its id, if white balance is applied.
    pub colour: Option<(&'a ColourSet, &'a str)>,
    /// How exposures are weighted.
    pub weight: MergeWeight,
}

/// How captures are rectified onto the reference plane.
#[derive(Debug, Clone, Copy)]
pub struct Rectification<'a> {
    /// Every camera's geometry, by camera id, and the geometry calibration's id.
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The square of the reference plane and the output size.
    pub grid: RectifyGrid,
    /// The turntable's axis id (`None`: the sample never turns).
    pub turntable_axis: Option<&'a str>,
}

/// What `process` is asked to write.
#[derive(Debug, Clone, Copy, Default)]
pub struct Outputs<'a> {
    /// HDR images at the camera's resolution.
    pub hdr: bool,
    /// Rectified images.
    pub rectified: bool,
    /// The BTF, laid out.
    pub btf: Option<&'a BtfLayout>,
    /// Needed for `rectified` and `btf`.
    pub rectification: Option<Rectification<'a>>,
    /// Only these cameras' captures (`None`: every camera's).
    pub cameras: Option<&'a [String]>,
}

/// Products of one kind written and skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Counts {
    /// Written now.
    pub written: usize,
    /// Already current, skipped.
    pub skipped: usize,
}

/// What a `process` pass did.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ProductSummary {
    /// Captures in the run.
    pub captures: usize,
    /// Captures decoded and merged in this pass (the others were current in every output).
    pub merged: usize,
    /// HDR images.
    pub hdr: Counts,
    /// Rectified images.
    pub rectified: Counts,
    /// BTF files (metadata, radiance chunks, seen masks).
    pub btf: Counts,
    /// Merged samples saturated in every exposure (lower bounds).
    pub saturated_samples: u64,
    /// Merged samples black in every exposure (upper bounds).
    pub black_samples: u64,
}

/// The white balance scales of one capture: the colour calibration's S for the one lamp that
/// was on, `None` without a colour calibration or with other than one lamp on.
fn scales(
    key: &BracketKey,
    cal: &HdrCalibrations<'_>,
) -> Result<Option<[f64; 3]>, ProcessingError> {
    let Some((colour, id)) = cal.colour else {
        return Ok(None);
    };
    let [lamp] = key.meta.lamps_on.as_slice() else {
        return Ok(None);
    };
    let scale = colour
        .get(&key.camera)
        .and_then(|c| c.lamps.get(lamp))
        .map(|l| l.fit.scale)
        .ok_or_else(|| ProcessingError::CalibrationMismatch {
            id: id.to_string(),
            why: format!(
                "it has no white balance for camera `{}` under lamp `{lamp}` (step {}); calibrate the colour of this rig's cameras and lamps",
                key.camera, key.step
            ),
        })?;
    Ok(Some(scale))
}

/// One capture's work: what it is made with and which of its products are due.
struct Job<'k> {
    key: &'k BracketKey,
    response: &'k CameraResponse,
    scale: Option<[f64; 3]>,
    /// The capture's geometry and turntable angle (with a rectification).
    placed: Option<(&'k CameraGeometry, f64)>,
    hdr: Option<NewProduct>,
    rectified: Option<NewProduct>,
    /// The BTF radiance chunk and, for the first capture of a view in this pass whose mask
    /// is not current, the view's seen mask.
    btf: Option<(NewProduct, Option<NewProduct>)>,
}

/// The BTF's three arrays.
struct BtfArrays {
    radiance: ZarrArray,
    seen: ZarrArray,
}

const BTF_DIR: &str = "btf.zarr";

fn btf_arrays(layout: &BtfLayout, n: usize) -> Result<BtfArrays, ProcessingError> {
    let (v, l, n) = (
        layout.views.len().max(1) as u64,
        layout.lights.len().max(1) as u64,
        n as u64,
    );
    Ok(BtfArrays {
        radiance: ZarrArray::new(
            &[v, l, n, n, 3],
            &[1, 1, n, n, 3],
            ZarrType::Float32,
            &["view", "light", "y", "x", "rgb"],
            json!({"units": "see the group's attributes"}),
        )?,
        seen: ZarrArray::new(
            &[v, n, n],
            &[1, n, n],
            ZarrType::Uint8,
            &["view", "y", "x"],
            json!({"meaning": "1 where the camera saw the whole footprint of the pixel"}),
        )?,
    })
}

/// Writes the products `outputs` asks for of every capture of the run in `store`, calling
/// `progress(done, total)` after each capture. Refuses a calibration that does not cover a
/// camera or lamp the run uses before writing anything.
pub fn capture_products(
    store: &mut ProductStore,
    cal: HdrCalibrations<'_>,
    outputs: Outputs<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ProductSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let reader = open_run(&run_dir)?;
    let keys = bracket_keys(&reader, |m| {
        outputs.cameras.is_none_or(|c| c.contains(&m.camera))
    })?;
    let (responses, response_id) = cal.response;
    let rectifying = outputs.rectified || outputs.btf.is_some();
    let rect = match (rectifying, outputs.rectification) {
        (false, _) => None,
        (true, Some(r)) => Some(r),
        (true, None) => {
            return Err(ProcessingError::MissingInput {
                run: run_dir.display().to_string(),
                what: "geometric calibration".into(),
                hint: "rectified images and the BTF need one: pass --calibration geometry-… or name one in the rig file's [calibration] table",
            });
        }
    };
    let mut calibrations = vec![response_id.to_string()];
    if let Some((_, id)) = cal.colour {
        calibrations.push(id.to_string());
    }
    let mut rect_calibrations = calibrations.clone();
    if let Some(r) = rect {
        rect_calibrations.push(r.geometry.1.to_string());
    }
    let mut summary = ProductSummary {
        captures: keys.len(),
        ..ProductSummary::default()
    };
    let count = |c: &mut Counts, current: bool| {
        if current {
            c.skipped += 1;
        } else {
            c.written += 1;
        }
    };
    // The BTF's metadata first: a reader sees the arrays' shapes before any chunk.
    let arrays = match (outputs.btf, rect) {
        (Some(layout), Some(r)) => {
            let arrays = btf_arrays(layout, r.grid.pixels)?;
            let attributes = json!({
                "views": layout.views,
                "lights": layout.lights,
                "cells": layout.cells,
                "grid": r.grid,
                "units": units(cal.colour.is_some()),
                "angles": "θ from the sample normal, φ from the sample's x axis, degrees, at the square's centre",
                "calibrations": rect_calibrations,
            });
            let files = [
                ("zarr.json".to_string(), group_metadata(attributes)),
                ("radiance/zarr.json".to_string(), arrays.radiance.metadata()),
                ("seen/zarr.json".to_string(), arrays.seen.metadata()),
            ];
            for (file, bytes) in files {
                let new = NewProduct {
                    kind: "btf".into(),
                    key: format!("btf/{file}"),
                    file_name: format!("{BTF_DIR}/{file}"),
                    inputs: Vec::new(),
                    calibrations: rect_calibrations.clone(),
                    software: software.to_string(),
                    parameters: json!({"sha256_of_content": stagehand_dataset::checksum::sha256_hex(&bytes)}),
                };
                let current = store.is_current(&new).map_err(dataset_err(&run_dir))?;
                if !current {
                    store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
                }
                count(&mut summary.btf, current);
            }
            Some(arrays)
        }
        _ => None,
    };
    // Every camera and lamp checked before the first product.
    let mut jobs = Vec::with_capacity(keys.len());
    let mut masks_due: BTreeSet<usize> = BTreeSet::new();
    for key in &keys {
        let response =
            responses
                .get(&key.camera)
                .ok_or_else(|| ProcessingError::CalibrationMismatch {
                    id: response_id.to_string(),
                    why: format!(
                        "it has no response for camera `{}`; it covers {}",
                        key.camera,
                        responses.keys().cloned().collect::<Vec<_>>().join(", ")
                    ),
                })?;
        let scale = scales(key, &cal)?;
        let merge_parameters = json!({"weight": cal.weight, "white_balance": scale});
        let product =
            |kind: &str, key_name: String, file_name: String, parameters, cals: &[String]| {
                NewProduct {
                    kind: kind.into(),
                    key: key_name,
                    file_name,
                    inputs: key.frames.iter().map(|f| f.path.clone()).collect(),
                    calibrations: cals.to_vec(),
                    software: software.to_string(),
                    parameters,
                }
            };
        let name = format!("s{:06}_{}", key.step, key.camera);
        let place = format!("s{:06}/{}", key.step, key.camera);
        let hdr = outputs.hdr.then(|| {
            product(
                "hdr",
                format!("hdr/{place}"),
                format!("{name}.exr"),
                merge_parameters.clone(),
                &calibrations,
            )
        });
        let mut placed = None;
        let mut rectified = None;
        let mut btf = None;
        if let Some(r) = rect {
            let geometry = r.geometry.0.get(&key.camera).ok_or_else(|| {
                ProcessingError::CalibrationMismatch {
                    id: r.geometry.1.to_string(),
                    why: format!(
                        "it has no geometry for camera `{}` (step {}); calibrate this rig's cameras with `stagehand calibrate geometry`, or process the others alone (`--cameras`)",
                        key.camera, key.step
                    ),
                }
            })?;
            let path = key.frames.first().map_or("?", |f| f.path.as_str());
            let table = axis_angle(&run_dir, &key.meta, path, r.turntable_axis)?;
            placed = Some((geometry, table));
            let parameters = json!({
                "weight": cal.weight,
                "white_balance": scale,
                "grid": r.grid,
                "turntable_deg": table,
            });
            rectified = outputs.rectified.then(|| {
                product(
                    "rectified",
                    format!("rectified/{place}"),
                    format!("{name}.exr"),
                    parameters.clone(),
                    &rect_calibrations,
                )
            });
            if let (Some(layout), Some(arrays)) = (outputs.btf, &arrays)
                && let Some(cell) = layout.cell_of(key.step, &key.camera)
            {
                let chunk =
                    arrays
                        .radiance
                        .chunk_key(&[cell.view as u64, cell.light as u64, 0, 0, 0])?;
                let radiance = product(
                    "btf",
                    format!("btf/radiance/v{:05}/l{:05}", cell.view, cell.light),
                    format!("{BTF_DIR}/radiance/{chunk}"),
                    parameters.clone(),
                    &rect_calibrations,
                );
                let mask_chunk = arrays.seen.chunk_key(&[cell.view as u64, 0, 0])?;
                let mask = product(
                    "btf",
                    format!("btf/seen/v{:05}", cell.view),
                    format!("{BTF_DIR}/seen/{mask_chunk}"),
                    json!({"grid": r.grid, "turntable_deg": table}),
                    &[r.geometry.1.to_string()],
                );
                // A view's mask depends on its geometry only: its first capture makes it.
                btf = Some((radiance, masks_due.insert(cell.view).then_some(mask)));
            }
        }
        jobs.push(Job {
            key,
            response,
            scale,
            placed,
            hdr,
            rectified,
            btf,
        });
    }
    let total = jobs.len();
    let mut done = 0;
    let mut maps = MapCache::default();
    let batch = 2 * rayon::current_num_threads().max(1);
    let mut jobs = jobs.into_iter().peekable();
    while jobs.peek().is_some() {
        let mut todo = Vec::new();
        for mut job in jobs.by_ref().take(batch) {
            let mut due = false;
            if let Some(p) = job.hdr.take() {
                let current = store.is_current(&p).map_err(dataset_err(&run_dir))?;
                count(&mut summary.hdr, current);
                due |= !current;
                job.hdr = (!current).then_some(p);
            }
            if let Some(p) = job.rectified.take() {
                let current = store.is_current(&p).map_err(dataset_err(&run_dir))?;
                count(&mut summary.rectified, current);
                due |= !current;
                job.rectified = (!current).then_some(p);
            }
            if let Some((p, mask)) = job.btf.take() {
                let current = store.is_current(&p).map_err(dataset_err(&run_dir))?;
                count(&mut summary.btf, current);
                due |= !current;
                let mask = match mask {
                    Some(m) => {
                        let current = store.is_current(&m).map_err(dataset_err(&run_dir))?;
                        count(&mut summary.btf, current);
                        (!current).then_some(m)
                    }
                    None => None,
                };
                due |= mask.is_some();
                job.btf = (!current || mask.is_some()).then_some((p, mask));
            }
            if due {
                todo.push(job);
            } else {
                done += 1;
                progress(done, total);
            }
        }
        summary.merged += todo.len();
        if let Some(r) = rect {
            maps.prepare(&todo, &r)?;
        }
        let made: Vec<Made> = todo
            .into_par_iter()
            .map(|job| {
                let map = maps.get(&job);
                make(
                    &run_dir,
                    &job,
                    &calibrations,
                    cal.weight,
                    map,
                    arrays.as_ref(),
                )
            })
            .collect::<Result<_, ProcessingError>>()?;
        for m in made {
            for (new, bytes) in m.files {
                store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
            }
            summary.saturated_samples += m.saturated;
            summary.black_samples += m.black;
            done += 1;
            progress(done, total);
        }
    }
    Ok(summary)
}

/// A view: a camera at a turntable angle (thousandths of a degree).
type ViewKey = (String, i64);

/// Most rectification maps kept at once: a turntable angle's views of an 8-camera rig twice.
const MAP_CACHE: usize = 16;

/// The rectification maps of the views being processed. The captures of a run come view by
/// view (every light at one table angle), so a handful of maps serves them all; the cache is
/// emptied when it would grow past [`MAP_CACHE`], which bounds its memory whatever the run.
#[derive(Default)]
struct MapCache {
    maps: HashMap<ViewKey, (RectifyMap, RectifyGrid, f64)>,
}

impl MapCache {
    fn key(job: &Job<'_>) -> Option<ViewKey> {
        let (_, table) = job.placed?;
        let due = job.rectified.is_some() || job.btf.is_some();
        due.then(|| {
            (
                job.key.camera.clone(),
                (table.rem_euclid(360.0) * 1000.0).round() as i64,
            )
        })
    }

    /// Makes (on every core) the maps `jobs` need that the cache lacks.
    fn prepare(&mut self, jobs: &[Job<'_>], r: &Rectification<'_>) -> Result<(), ProcessingError> {
        let mut missing: BTreeMap<ViewKey, &Job<'_>> = BTreeMap::new();
        for job in jobs {
            if let Some(key) = Self::key(job).filter(|k| !self.maps.contains_key(k)) {
                missing.entry(key).or_insert(job);
            }
        }
        if self.maps.len() + missing.len() > MAP_CACHE {
            self.maps.clear();
        }
        let made: Vec<(ViewKey, (RectifyMap, RectifyGrid, f64))> = missing
            .into_par_iter()
            .filter_map(|(key, job)| job.placed.map(|placed| (key, job, placed)))
            .map(|(key, job, (geometry, table))| {
                let pose = sample_to_camera(&geometry.rig_to_camera, table);
                let (w, h) = (job.key.meta.width as usize, job.key.meta.height as usize);
                let map = RectifyMap::new(&geometry.model, &pose, &r.grid, w, h)?;
                Ok((key, (map, r.grid, table)))
            })
            .collect::<Result<_, ProcessingError>>()?;
        self.maps.extend(made);
        Ok(())
    }

    /// The map of `job`'s view, its grid and table angle, if it rectifies.
    fn get(&self, job: &Job<'_>) -> Option<(&RectifyMap, RectifyGrid, f64)> {
        let (map, grid, table) = self.maps.get(&Self::key(job)?)?;
        Some((map, *grid, *table))
    }
}

/// The units a product's values are in.
fn units(white_balanced: bool) -> &'static str {
    if white_balanced {
        "reflectance of a white diffuser"
    } else {
        "the response calibration's relative radiance"
    }
}

/// One capture's files, ready to write, and its merge's counts.
struct Made {
    files: Vec<(NewProduct, Vec<u8>)>,
    saturated: u64,
    black: u64,
}

/// Decodes and merges one capture and encodes every product `job` has due.
fn make(
    run_dir: &Path,
    job: &Job<'_>,
    calibrations: &[String],
    weight: MergeWeight,
    map: Option<(&RectifyMap, RectifyGrid, f64)>,
    arrays: Option<&BtfArrays>,
) -> Result<Made, ProcessingError> {
    let key = job.key;
    let decoded = key
        .frames
        .iter()
        .map(|f| decode_frame_in(run_dir, f))
        .collect::<Result<Vec<_>, _>>()?;
    let bracket: Vec<RgbExposure<'_>> = decoded
        .iter()
        .zip(&key.frames)
        .map(|(d, f)| RgbExposure {
            exposure_s: f.meta.exposure_s,
            dn: &d.pixels,
        })
        .collect();
    let (w, h) = (key.meta.width as usize, key.meta.height as usize);
    let merged = merge_rgb_frames(
        &bracket,
        w,
        h,
        &job.response.channels,
        job.scale.unwrap_or([1.0; 3]),
        weight,
    )?;
    drop(decoded);
    let count = |state: PixelState| merged.state.iter().filter(|s| **s == state).count() as u64;
    let (saturated, black) = (count(PixelState::AtLeast), count(PixelState::AtMost));
    let metadata = json!({
        "camera": key.camera,
        "step": key.step,
        "lamps_on": key.meta.lamps_on,
        "axes_deg": key.meta.axes_deg,
        "exposures_s": key.frames.iter().map(|f| f.meta.exposure_s).collect::<Vec<_>>(),
        "units": units(job.scale.is_some()),
        "saturated_samples": saturated,
        "black_samples": black,
        "calibrations": calibrations,
    });
    let mut files = Vec::new();
    if let Some(new) = &job.hdr {
        let bytes = encode_exr(
            &new.file_name,
            key.meta.width,
            key.meta.height,
            &merged.rgb,
            &metadata.to_string(),
        )
        .map_err(dataset_err(run_dir))?;
        files.push((new.clone(), bytes));
    }
    if let Some((map, grid, table)) = map
        && (job.rectified.is_some() || job.btf.is_some())
    {
        let image = Image {
            width: w,
            height: h,
            channels: 3,
            data: &merged.rgb,
        };
        let out: Rectified = map.apply(&image)?;
        let n = grid.pixels;
        if let Some(new) = &job.rectified {
            let mut rgba = Vec::with_capacity(n * n * 4);
            for (px, seen) in out.data.chunks_exact(3).zip(&out.seen) {
                rgba.extend_from_slice(px);
                rgba.push(if *seen { 1.0 } else { 0.0 });
            }
            let mut meta = metadata.clone();
            meta["grid"] = json!(grid);
            meta["turntable_deg"] = json!(table);
            meta["calibrations"] = json!(new.calibrations);
            let channels = ["R", "G", "B", "A"].map(String::from);
            let bytes = encode_exr_planes(
                &new.file_name,
                n as u32,
                n as u32,
                &channels,
                &rgba,
                &meta.to_string(),
            )
            .map_err(dataset_err(run_dir))?;
            files.push((new.clone(), bytes));
        }
        if let (Some((radiance, mask)), Some(arrays)) = (&job.btf, arrays) {
            files.push((radiance.clone(), arrays.radiance.encode_f32(&out.data)?));
            if let Some(mask) = mask {
                let seen: Vec<u8> = out.seen.iter().map(|&s| u8::from(s)).collect();
                files.push((mask.clone(), arrays.seen.encode_u8(&seen)?));
            }
        }
    }
    Ok(Made {
        files,
        saturated,
        black,
    })
}
