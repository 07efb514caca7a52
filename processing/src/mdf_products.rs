//! `stagehand process --products mdf`: each view's depth images (products of kind `depth`, one
//! per laser direction: a camera at one turntable angle) merged over the directions
//! ([`crate::mdf_merge`]) into the view's mesostructure distance function. Per view:
//! - `mdf/…exr`: OpenEXR `D` (distance along the pixel's ray, mm; −1 unknown), `S` (source: 2
//!   measured, 1 inpainted, 0 none: the occlusion mask), `N` (directions averaged) and `W`
//!   (their Σ τ, mm³);
//! - `mdf8/…png`: the MDF quantised to 8 bits as the seed stores it: 0 where unknown, else
//!   1 + round(254 (D − lo) / (hi − lo)) over the view's range [lo, hi] inside the sample,
//!   which the PNG's `stagehand` text chunk records.
//!
//! The sample region is where a pixel's ray meets the reference plane inside the sample's
//! square (the same square the rectified images use): holes are counted and inpainted there,
//! as heights above the reference plane.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::exr_planes::{decode_exr_planes, encode_exr_planes};
use stagehand_dataset::products::{NewProduct, ProductStore, StoredProduct};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::mdf_merge::{
    DepthLayer, MergeOptions, MergedDepth, drop_specks, drop_spikes, hole_fraction, inpaint,
    merge_layers, source,
};
use crate::ray_plane::{NO_DEPTH, pixel_ray};
use crate::rectify::RectifyGrid;
use crate::rig_frame::sample_to_camera;
use crate::run_frames::dataset_err;

/// What the merge is made with.
#[derive(Debug, Clone, Copy)]
pub struct MdfSetup<'a> {
    /// Every camera's geometry, by id, and the geometry calibration's id.
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The sample's square on the reference plane (its pixel count is not used).
    pub square: RectifyGrid,
    /// Merge settings.
    pub merge: MergeOptions,
    /// Only these cameras' views (`None`: every camera's).
    pub cameras: Option<&'a [String]>,
}

/// What an MDF pass did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MdfSummary {
    /// Views (camera × turntable angle) with depth images.
    pub views: usize,
    /// Views merged now.
    pub written: usize,
    /// Views already current.
    pub skipped: usize,
    /// Over the views merged now: the fraction of sample pixels no direction measured.
    pub hole_fraction: f64,
    /// Pixels where directions saw a depth but disagreed.
    pub conflicts: usize,
    /// Sample pixels left unknown after inpainting.
    pub unfilled: usize,
}

/// One view's depth images.
struct View<'a> {
    camera: String,
    turntable_deg: f64,
    depths: Vec<&'a StoredProduct>,
}

/// Writes the MDF of every view of the run's depth images in `store`.
pub fn mdf_products(
    store: &mut ProductStore,
    setup: MdfSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MdfSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let products = store.products().map_err(dataset_err(&run_dir))?;
    let mut views: BTreeMap<(String, i64), View<'_>> = BTreeMap::new();
    for p in products.iter().filter(|p| p.made.kind == "depth") {
        let params = &p.made.parameters;
        let (Some(camera), Some(table)) =
            (params["camera"].as_str(), params["turntable_deg"].as_f64())
        else {
            return Err(ProcessingError::Dataset {
                run: run_dir.display().to_string(),
                message: format!(
                    "depth product {} records no camera or turntable angle; make the depth images again with this stagehand (`process --products depth`)",
                    p.made.key
                ),
            });
        };
        if setup
            .cameras
            .is_some_and(|c| !c.iter().any(|id| id == camera))
        {
            continue;
        }
        let key = (
            camera.to_string(),
            (table.rem_euclid(360.0) * 1000.0).round() as i64,
        );
        views
            .entry(key)
            .or_insert_with(|| View {
                camera: camera.to_string(),
                turntable_deg: table,
                depths: Vec::new(),
            })
            .depths
            .push(p);
    }
    let (cameras, geometry_id) = setup.geometry;
    let mut summary = MdfSummary {
        views: views.len(),
        ..MdfSummary::default()
    };
    let mut todo = Vec::new();
    for view in views.values() {
        let geometry = cameras.get(&view.camera).ok_or_else(|| {
            ProcessingError::CalibrationMismatch {
                id: geometry_id.to_string(),
                why: format!(
                    "it has no geometry for camera `{}`; process the others alone (`--cameras`)",
                    view.camera
                ),
            }
        })?;
        let mut inputs: Vec<String> = view.depths.iter().map(|p| p.path.clone()).collect();
        inputs.sort();
        let calibrations = view.depths[0].made.calibrations.clone();
        if calibrations.first().map(String::as_str) != Some(geometry_id) {
            return Err(ProcessingError::CalibrationMismatch {
                id: geometry_id.to_string(),
                why: format!(
                    "the depth images of camera `{}` were made with {:?}; make them again with this geometry (`--products depth,mdf`)",
                    view.camera, calibrations
                ),
            });
        }
        let milli = (view.turntable_deg.rem_euclid(360.0) * 1000.0).round() as i64;
        let name = format!("t{milli:06}_{}", view.camera);
        let parameters = json!({
            "merge": setup.merge,
            "square": setup.square,
            "camera": view.camera,
            "turntable_deg": view.turntable_deg,
            "directions": view.depths.len(),
            // A frame of the view, where a simulated run's ground truth sits.
            "truth_frame": view.depths[0].made.inputs.first(),
        });
        let mdf = NewProduct {
            kind: "mdf".into(),
            key: format!("mdf/{name}"),
            file_name: format!("{name}.exr"),
            inputs: inputs.clone(),
            calibrations: calibrations.clone(),
            software: software.to_string(),
            parameters: parameters.clone(),
        };
        let mdf8 = NewProduct {
            kind: "mdf8".into(),
            key: format!("mdf8/{name}"),
            file_name: format!("{name}.png"),
            ..mdf.clone()
        };
        let current = store.is_current(&mdf).map_err(dataset_err(&run_dir))?
            && store.is_current(&mdf8).map_err(dataset_err(&run_dir))?;
        if current {
            summary.skipped += 1;
        } else {
            todo.push((view, geometry, mdf, mdf8));
        }
    }
    let total = summary.views;
    let mut done = summary.skipped;
    progress(done, total);
    let (mut holes, mut inside) = (0.0, 0usize);
    let batch = 2 * rayon::current_num_threads().max(1);
    for chunk in todo.chunks(batch) {
        let made: Vec<_> = chunk
            .par_iter()
            .map(|(view, geometry, mdf, mdf8)| {
                one_view(&run_dir, view, geometry, &setup, mdf, mdf8)
            })
            .collect::<Result<_, ProcessingError>>()?;
        for ((_, _, mdf, mdf8), made) in chunk.iter().zip(made) {
            store
                .write(mdf.clone(), &made.exr)
                .map_err(dataset_err(&run_dir))?;
            store
                .write(mdf8.clone(), &made.png)
                .map_err(dataset_err(&run_dir))?;
            summary.written += 1;
            summary.conflicts += made.conflicts;
            summary.unfilled += made.unfilled;
            holes += made.hole_fraction * made.region as f64;
            inside += made.region;
            done += 1;
            progress(done, total);
        }
    }
    summary.hole_fraction = if inside > 0 {
        holes / inside as f64
    } else {
        0.0
    };
    Ok(summary)
}

/// One view's files and figures.
struct MadeView {
    exr: Vec<u8>,
    png: Vec<u8>,
    conflicts: usize,
    unfilled: usize,
    hole_fraction: f64,
    region: usize,
}

fn one_view(
    run_dir: &Path,
    view: &View<'_>,
    geometry: &CameraGeometry,
    setup: &MdfSetup<'_>,
    mdf: &NewProduct,
    mdf8: &NewProduct,
) -> Result<MadeView, ProcessingError> {
    let bad = |message: String| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message,
    };
    let mut images = Vec::with_capacity(view.depths.len());
    let mut size = None;
    for p in &view.depths {
        let bytes = std::fs::read(run_dir.join(&p.path)).map_err(|e| {
            bad(format!(
                "{}: {e}; make it again with `process --products depth`",
                p.path
            ))
        })?;
        let planes = decode_exr_planes(&p.path, &bytes).map_err(dataset_err(run_dir))?;
        let nu = planes
            .metadata
            .as_deref()
            .and_then(|m| serde_json::from_str::<serde_json::Value>(m).ok())
            .and_then(|m| m["nu_mm3"].as_f64())
            .ok_or_else(|| {
                bad(format!(
                    "{} records no ν (nu_mm3); make the depth images again with this stagehand",
                    p.path
                ))
            })?;
        let wh = (planes.width as usize, planes.height as usize);
        if *size.get_or_insert(wh) != wh {
            return Err(bad(format!(
                "{} is {}×{}, unlike the view's other depth images",
                p.path, wh.0, wh.1
            )));
        }
        let d = planes
            .channel("D")
            .ok_or_else(|| bad(format!("{} has no D channel", p.path)))?
            .to_vec();
        images.push((d, nu));
    }
    let (w, h) = size.unwrap_or((0, 0));
    let layers: Vec<DepthLayer<'_>> = images
        .iter()
        .map(|(d, nu)| DepthLayer { depth: d, nu: *nu })
        .collect();
    let mut merged = merge_layers(w, h, &layers, geometry.model.intrinsics.fx, &setup.merge)?;
    let fx = geometry.model.intrinsics.fx;
    let spikes = drop_spikes(&mut merged, fx, setup.merge.agree_footprints);
    let specks = drop_specks(&mut merged, min_island(w * h));
    let rays = pixel_rays(geometry, view.turntable_deg, w, h);
    let region = sample_region(&rays, &setup.square);
    let holes = hole_fraction(&merged, &region);
    inpaint_heights(&mut merged, &region, &rays);
    let inside = region.iter().filter(|r| **r).count();
    let unfilled = region
        .iter()
        .zip(&merged.source)
        .filter(|(r, s)| **r && **s == source::NONE)
        .count();
    let metadata = json!({
        "camera": view.camera,
        "turntable_deg": view.turntable_deg,
        "directions": view.depths.len(),
        "hole_fraction": holes,
        "conflicts": merged.conflicts,
        "specks_dropped": specks,
        "spikes_dropped": spikes,
        "channels": {"D": "distance along the pixel ray, mm; -1 unknown", "S": "2 measured, 1 inpainted, 0 none", "N": "directions averaged", "W": "their weight Σ τ, mm³"},
    });
    let mut samples = Vec::with_capacity(4 * w * h);
    for i in 0..w * h {
        samples.extend([
            merged.depth[i],
            f32::from(merged.source[i]),
            f32::from(merged.agreeing[i]),
            merged.weight[i],
        ]);
    }
    let channels = ["D", "S", "N", "W"].map(String::from);
    let exr = encode_exr_planes(
        &mdf.file_name,
        w as u32,
        h as u32,
        &channels,
        &samples,
        &metadata.to_string(),
    )
    .map_err(dataset_err(run_dir))?;
    let png = quantised_png(&merged, &region, w, h, &metadata)
        .map_err(|e| bad(format!("{}: {e}", mdf8.file_name)))?;
    Ok(MadeView {
        exr,
        png,
        conflicts: merged.conflicts,
        unfilled,
        hole_fraction: holes,
        region: inside,
    })
}

/// The smallest island of measured pixels kept: 1/2000 of the image, at least 16 pixels
/// (86 at 480×360, 393 at 1024×768).
pub fn min_island(pixels: usize) -> usize {
    (pixels / 2000).max(16)
}

/// Each pixel's ray in the sample frame at `turntable_deg`: camera centre and unit direction.
type Ray = Option<(Vector3<f64>, Vector3<f64>)>;

fn pixel_rays(
    geometry: &CameraGeometry,
    turntable_deg: f64,
    width: usize,
    height: usize,
) -> Vec<Ray> {
    let pose = sample_to_camera(&geometry.rig_to_camera, turntable_deg);
    (0..width * height)
        .map(|i| {
            pixel_ray(
                &geometry.model,
                &pose,
                ((i % width) as f64, (i / width) as f64),
            )
        })
        .collect()
}

/// The pixels whose ray meets the reference plane (z = 0 of the sample frame) inside
/// `square`.
fn sample_region(rays: &[Ray], square: &RectifyGrid) -> Vec<bool> {
    let half = 0.5 * square.size_mm;
    rays.iter()
        .map(|ray| {
            ray.is_some_and(|(c, d)| {
                let t = -c.z / d.z;
                if !(t.is_finite() && t > 0.0) {
                    return false;
                }
                let p = c + d * t;
                (p.x - square.centre_mm.0).abs() <= half && (p.y - square.centre_mm.1).abs() <= half
            })
        })
        .collect()
}

/// Inpaints the holes of the region as heights above the reference plane, which vary little
/// over a sample, rather than as distances along the rays, which vary with the view's
/// perspective: each known depth becomes its point's height, the heights are inpainted, and
/// each filled height goes back to a distance along its pixel's ray.
fn inpaint_heights(merged: &mut MergedDepth, region: &[bool], rays: &[Ray]) {
    let mut heights = merged.clone();
    for (i, ray) in rays.iter().enumerate() {
        if heights.source[i] == source::NONE {
            continue;
        }
        match ray {
            Some((c, d)) => heights.depth[i] = (c.z + d.z * f64::from(merged.depth[i])) as f32,
            None => heights.source[i] = source::NONE,
        }
    }
    inpaint(&mut heights, region);
    for (i, ray) in rays.iter().enumerate() {
        if heights.source[i] != source::INPAINTED {
            continue;
        }
        let Some((c, d)) = ray else { continue };
        let t = (f64::from(heights.depth[i]) - c.z) / d.z;
        if t.is_finite() && t > 0.0 {
            merged.depth[i] = t as f32;
            merged.source[i] = source::INPAINTED;
        }
    }
}

/// The MDF quantised to 8 bits over its range inside the region, with the range in the PNG's
/// `stagehand` text chunk.
fn quantised_png(
    merged: &MergedDepth,
    region: &[bool],
    w: usize,
    h: usize,
    metadata: &serde_json::Value,
) -> Result<Vec<u8>, String> {
    let known = |i: usize| merged.source[i] != source::NONE && merged.depth[i] != NO_DEPTH;
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for i in (0..w * h).filter(|&i| region[i] && known(i)) {
        lo = lo.min(merged.depth[i]);
        hi = hi.max(merged.depth[i]);
    }
    let span = if lo.is_finite() && hi > lo {
        hi - lo
    } else {
        1.0
    };
    let lo = if lo.is_finite() { lo } else { 0.0 };
    let pixels: Vec<u8> = (0..w * h)
        .map(|i| {
            if !known(i) {
                return 0;
            }
            let q = 1.0 + (254.0 * (merged.depth[i] - lo) / span).round();
            q.clamp(1.0, 255.0) as u8
        })
        .collect();
    let text = json!({
        "mdf": metadata,
        "quantisation": {"lo_mm": lo, "hi_mm": lo + span, "formula": "0 unknown; else D = lo + (v - 1) (hi - lo) / 254"},
    });
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, w as u32, h as u32);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    encoder
        .add_itxt_chunk("stagehand".to_string(), text.to_string())
        .map_err(|e| e.to_string())?;
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer
        .write_image_data(&pixels)
        .map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    Ok(out)
}
