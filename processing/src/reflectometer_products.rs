//! A reflectometer run's frames as the Ward fit and the transparency map need them, and the
//! products `stagehand process --products ward,transparency` writes from them:
//! - a sweep is one camera's frames lit by the tube alone within one script block, each turned
//!   into radiance through the response calibration (one exposure per stop) with its clipped
//!   pixels, at the tube's x (the cart position less half the travel);
//! - `ward`: per camera, an OpenEXR of ρd (RGB), ρs, α, the relative RMS residual and the flag
//!   mask ([`crate::ward_map`]), with a PNG preview of ρd; a second sweep with the sample
//!   turned (the frames' placement) is fitted too and combined per point of the sample, which
//!   flags anisotropic pixels;
//! - `transparency`: per camera, an OpenEXR of T (RGB) and its flags from the backlight frame
//!   (lit by the backlight alone), with a PNG preview.
//!
//! The tube's intensity and the panel's radiance come from a reflectometer calibration
//! ([`crate::reflectometer_calibration`]) made through the same response calibration.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::StoredFrame;
use stagehand_dataset::exr_planes::encode_exr_planes;
use stagehand_dataset::png16::encode_png16;
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::hdr_frame::{MergeWeight, PixelState, RgbExposure, merge_rgb_frames};
use crate::reflectometer_calibration::SourceCalibration;
use crate::response_calibration::{CameraResponse, ResponseSet};
use crate::run_frames::{dataset_err, decode_frame_in, raw_frames};
use crate::transparency::transparency;
use crate::ward_fit::{WardFitOptions, WardFlag};
use crate::ward_map::{REFUSED, SweepFrame, UNSEEN, WardMaps, combine_turned_maps, ward_maps};
use crate::ward_tube::Tube;

/// What [`ReflectometerSetup::geometry`] is called when it is the rig file's nominal geometry.
pub const NOMINAL: &str = "nominal";
/// Relative difference of α between the two turned scans above which a pixel is anisotropic.
pub const TURN_TOLERANCE: f64 = 0.25;

/// Which lamps are which, from the rig file.
#[derive(Debug, Clone, Copy)]
pub struct ReflectometerLamps<'a> {
    /// The tube lamps' ids.
    pub tube: &'a [String],
    /// The backlight lamps' ids.
    pub backlight: &'a [String],
}

/// One camera's frames of one tube sweep, by step.
#[derive(Debug, Clone)]
pub struct TubeSweep {
    /// Camera id.
    pub camera: String,
    /// The script block it ran in.
    pub block: String,
    /// The sample's turn about its normal (its placement), degrees.
    pub turn_deg: f64,
    /// Its frames.
    pub frames: Vec<StoredFrame>,
}

/// The run's tube sweeps (3 frames or more) and backlight frames, per camera.
#[derive(Debug, Clone, Default)]
pub struct ReflectometerFrames {
    /// Tube sweeps, by camera then block.
    pub sweeps: Vec<TubeSweep>,
    /// The last backlight frame of each camera.
    pub backlight: BTreeMap<String, StoredFrame>,
}

/// Sorts the run's raw frames into tube sweeps and backlight frames: a frame lit by tube
/// lamps and nothing else belongs to its block's sweep; one lit by the backlight alone is a
/// backlight frame.
pub fn reflectometer_frames(
    run_dir: &Path,
    lamps: ReflectometerLamps<'_>,
) -> Result<ReflectometerFrames, ProcessingError> {
    let mut groups: BTreeMap<(String, String), Vec<StoredFrame>> = BTreeMap::new();
    let mut backlight = BTreeMap::new();
    for f in raw_frames(run_dir)? {
        let on = &f.meta.lamps_on;
        if on.is_empty() || f.meta.laser_on {
            continue;
        }
        if on.iter().all(|l| lamps.tube.contains(l)) {
            groups
                .entry((f.meta.camera.clone(), f.meta.block.clone()))
                .or_default()
                .push(f);
        } else if on.iter().all(|l| lamps.backlight.contains(l)) {
            backlight.insert(f.meta.camera.clone(), f);
        }
    }
    let sweeps = groups
        .into_iter()
        .filter(|(_, frames)| frames.len() >= 3)
        .map(|((camera, block), mut frames)| {
            frames.sort_by_key(|f| (f.meta.step, f.meta.exposure_index));
            TubeSweep {
                camera,
                block,
                turn_deg: frames[0].meta.fixture_pose.turn_deg,
                frames,
            }
        })
        .collect();
    Ok(ReflectometerFrames { sweeps, backlight })
}

/// One frame in radiance through `response` (one exposure), and its pixels clipped in any
/// channel.
pub fn frame_radiance(
    run_dir: &Path,
    frame: &StoredFrame,
    response: &CameraResponse,
) -> Result<(Vec<f32>, Vec<bool>), ProcessingError> {
    let png = decode_frame_in(run_dir, frame)?;
    let (w, h) = (png.width as usize, png.height as usize);
    let merged = merge_rgb_frames(
        &[RgbExposure {
            exposure_s: frame.meta.exposure_s,
            dn: &png.pixels,
        }],
        w,
        h,
        &response.channels,
        [1.0; 3],
        MergeWeight::Hat,
    )
    .map_err(|e| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message: format!("frame {}: {e}", frame.path),
    })?;
    let clipped = merged
        .state
        .chunks_exact(3)
        .map(|s| s.contains(&PixelState::AtLeast))
        .collect();
    Ok((merged.rgb, clipped))
}

/// One frame of a sweep in radiance.
#[derive(Debug, Clone)]
pub struct RadianceFrame {
    /// The tube's x, mm.
    pub tube_x_mm: f64,
    /// Radiance, RGB interleaved.
    pub rgb: Vec<f32>,
    /// Pixels clipped in any channel.
    pub clipped: Vec<bool>,
}

/// A sweep's frames in radiance at their tube positions.
pub fn sweep_radiance(
    run_dir: &Path,
    sweep: &TubeSweep,
    response: &CameraResponse,
    travel_mm: f64,
) -> Result<Vec<RadianceFrame>, ProcessingError> {
    sweep
        .frames
        .iter()
        .map(|f| {
            let cart = f.meta.cart_mm.filter(|c| c.is_finite()).ok_or_else(|| {
                ProcessingError::Dataset {
                    run: run_dir.display().to_string(),
                    message: format!(
                        "frame {} (step {}, camera {}) records no cart position; it was not taken on a reflectometer",
                        f.path, f.meta.step, f.meta.camera
                    ),
                }
            })?;
            let (rgb, clipped) = frame_radiance(run_dir, f, response)?;
            Ok(RadianceFrame {
                tube_x_mm: cart - 0.5 * travel_mm,
                rgb,
                clipped,
            })
        })
        .collect()
}

/// The sweep frames as [`SweepFrame`]s.
pub fn as_sweep_frames(s: &[RadianceFrame]) -> Vec<SweepFrame<'_>> {
    s.iter()
        .map(|f| SweepFrame {
            tube_x_mm: f.tube_x_mm,
            rgb: &f.rgb,
            clipped: Some(&f.clipped),
        })
        .collect()
}

/// The camera's response in `set`, or an error naming the calibration and the camera.
pub fn camera_response<'a>(
    (set, id): (&'a ResponseSet, &str),
    camera: &str,
) -> Result<&'a CameraResponse, ProcessingError> {
    set.get(camera)
        .ok_or_else(|| ProcessingError::CalibrationMismatch {
            id: id.to_string(),
            why: format!(
                "it has no response for camera `{camera}`; calibrate this camera's response (`stagehand calibrate response`)"
            ),
        })
}

/// What the reflectometer products are made with.
#[derive(Debug, Clone, Copy)]
pub struct ReflectometerSetup<'a> {
    /// The response calibration and its id.
    pub response: (&'a ResponseSet, &'a str),
    /// The sources' calibration per camera and its id.
    pub sources: (&'a BTreeMap<String, SourceCalibration>, &'a str),
    /// Each camera's geometry, and where it comes from (a calibration id, or [`NOMINAL`]).
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// Which lamps are the tube and the backlight.
    pub lamps: ReflectometerLamps<'a>,
    /// The tube: its height above the sample, length and glass radius (the rig file's), mm.
    pub tube: Tube,
    /// The cart's travel, mm.
    pub travel_mm: f64,
    /// Ward maps.
    pub ward: bool,
    /// Transparency maps.
    pub transparency: bool,
    /// The Ward fit's options.
    pub options: WardFitOptions,
    /// Only these cameras (`None`: every camera).
    pub cameras: Option<&'a [String]>,
}

/// What a reflectometer pass did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ReflectometerSummary {
    /// Ward maps written now (one per camera; a turned sweep is combined into it).
    pub ward_written: usize,
    /// Ward maps already current.
    pub ward_skipped: usize,
    /// Transparency maps written now.
    pub transparency_written: usize,
    /// Transparency maps already current.
    pub transparency_skipped: usize,
    /// Of the seen pixels of the Ward maps written, the fraction whose fit was refused or
    /// flagged poor (did not converge to the data).
    pub not_converged: f64,
    /// Of those pixels, the fraction flagged anisotropic.
    pub anisotropic: f64,
}

/// Tone-maps linear values (RGB interleaved) to a 16-bit sRGB-like preview (γ 1/2.2, 1 white).
fn preview(rgb: &[f32]) -> Vec<u16> {
    rgb.iter()
        .map(|v| (f64::from(v.clamp(0.0, 1.0)).powf(1.0 / 2.2) * 65535.0).round() as u16)
        .collect()
}

/// The products of one camera: (product, bytes) pairs.
type Made = Vec<(NewProduct, Vec<u8>)>;

/// Writes the Ward and transparency maps of every camera of the run into `store`;
/// `progress(done, total)` after each camera.
pub fn reflectometer_products(
    store: &mut ProductStore,
    setup: ReflectometerSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ReflectometerSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let found = reflectometer_frames(&run_dir, setup.lamps)?;
    let keep = |camera: &str| setup.cameras.is_none_or(|c| c.iter().any(|x| x == camera));
    let mut by_camera: BTreeMap<String, Vec<&TubeSweep>> = BTreeMap::new();
    for s in found.sweeps.iter().filter(|s| keep(&s.camera)) {
        by_camera.entry(s.camera.clone()).or_default().push(s);
    }
    if setup.ward && by_camera.is_empty() {
        return Err(ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: "the run has no tube sweep (3 frames or more lit by the tube alone in one block); record one with sequences/reflectometer.rhai".into(),
        });
    }
    if setup.transparency && !found.backlight.keys().any(|c| keep(c)) {
        return Err(ProcessingError::Dataset {
            run: run_dir.display().to_string(),
            message: "the run has no backlight frame (lit by the backlight alone); record one with sequences/reflectometer.rhai (backlight=true)".into(),
        });
    }
    let (sources, sources_id) = setup.sources;
    let (geometries, geometry_id) = setup.geometry;
    // Nominal geometry (the rig file's) is no calibration; the parameters name it.
    let calibrations: Vec<String> = [setup.response.1, sources_id, geometry_id]
        .into_iter()
        .filter(|id| *id != NOMINAL)
        .map(String::from)
        .collect();
    let source = |camera: &str| {
        sources
            .get(camera)
            .ok_or_else(|| ProcessingError::CalibrationMismatch {
                id: sources_id.to_string(),
                why: format!(
                    "it has no tube or panel for camera `{camera}`; calibrate this camera on the reference (`stagehand calibrate reflectometer`)"
                ),
            })
    };
    let tube = setup.tube;
    let mut summary = ReflectometerSummary::default();
    let cameras: Vec<String> = by_camera
        .keys()
        .chain(found.backlight.keys())
        .filter(|c| keep(c))
        .cloned()
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    let (mut seen, mut poor, mut aniso) = (0usize, 0usize, 0usize);
    for (done, camera) in cameras.iter().enumerate() {
        progress(done, cameras.len());
        let mut made: Made = Vec::new();
        if let Some(sweeps) = by_camera.get(camera).filter(|_| setup.ward) {
            let geometry =
                geometries
                    .get(camera)
                    .ok_or_else(|| ProcessingError::CalibrationMismatch {
                        id: geometry_id.to_string(),
                        why: format!("it has no geometry for camera `{camera}`"),
                    })?;
            let first = sweeps[0];
            let turned = sweeps
                .iter()
                .skip(1)
                .find(|s| (s.turn_deg - first.turn_deg).abs() > 1.0);
            let inputs: Vec<String> = sweeps
                .iter()
                .filter(|s| s.block == first.block || turned.is_some_and(|t| t.block == s.block))
                .flat_map(|s| s.frames.iter().map(|f| f.path.clone()))
                .collect();
            let blocks: Vec<&str> = std::iter::once(first.block.as_str())
                .chain(turned.map(|t| t.block.as_str()))
                .collect();
            let new = NewProduct {
                kind: "ward".into(),
                key: format!("ward/{camera}"),
                file_name: format!("{camera}.exr"),
                inputs,
                calibrations: calibrations.clone(),
                software: software.to_string(),
                parameters: json!({
                    "camera": camera,
                    "geometry": geometry_id,
                    "truth_frame": first.frames[0].path,
                    "blocks": blocks,
                    "turn_deg": turned.map(|t| t.turn_deg - first.turn_deg),
                    "tube": {"height_mm": tube.height_mm, "length_mm": tube.length_mm, "radius_mm": tube.radius_mm},
                    "travel_mm": setup.travel_mm,
                    "options": setup.options,
                    "turn_tolerance": TURN_TOLERANCE,
                }),
            };
            if store.is_current(&new).map_err(dataset_err(&run_dir))? {
                summary.ward_skipped += 1;
            } else {
                let response = camera_response(setup.response, camera)?;
                let tube_rgb = source(camera)?.tube_rgb;
                let fit = |sweep: &TubeSweep| -> Result<WardMaps, ProcessingError> {
                    let frames = sweep_radiance(&run_dir, sweep, response, setup.travel_mm)?;
                    let size = (
                        sweep.frames[0].meta.width as usize,
                        sweep.frames[0].meta.height as usize,
                    );
                    ward_maps(
                        &tube,
                        geometry,
                        size,
                        &as_sweep_frames(&frames),
                        tube_rgb,
                        &setup.options,
                    )
                    .map_err(|e| ProcessingError::Camera {
                        camera: camera.clone(),
                        source: Box::new(e),
                    })
                };
                let mut maps = fit(first)?;
                if let Some(t) = turned {
                    let other = fit(t)?;
                    maps = combine_turned_maps(
                        &maps,
                        &other,
                        geometry,
                        t.turn_deg - first.turn_deg,
                        TURN_TOLERANCE,
                    );
                }
                let n = maps.width * maps.height;
                let fitted = n - maps.count(UNSEEN);
                seen += fitted;
                poor += maps
                    .flags
                    .iter()
                    .filter(|f| **f & UNSEEN == 0 && **f & (REFUSED | WardFlag::PoorFit.bit()) != 0)
                    .count();
                aniso += maps.count(WardFlag::Anisotropic.bit());
                made.extend(ward_files(&run_dir, &new, &maps)?);
                summary.ward_written += 1;
            }
        }
        if let Some(frame) = found.backlight.get(camera).filter(|_| setup.transparency) {
            let new = NewProduct {
                kind: "transparency".into(),
                key: format!("transparency/{camera}"),
                file_name: format!("{camera}.exr"),
                inputs: vec![frame.path.clone()],
                calibrations: vec![setup.response.1.to_string(), sources_id.to_string()],
                software: software.to_string(),
                parameters: json!({"camera": camera, "truth_frame": frame.path}),
            };
            if store.is_current(&new).map_err(dataset_err(&run_dir))? {
                summary.transparency_skipped += 1;
            } else {
                let response = camera_response(setup.response, camera)?;
                let panel = source(camera)?.panel_rgb.ok_or_else(|| {
                    ProcessingError::CalibrationMismatch {
                        id: sources_id.to_string(),
                        why: format!(
                            "it has no backlight panel for camera `{camera}` (its reference run had no backlight frame)"
                        ),
                    }
                })?;
                let (rgb, clipped) = frame_radiance(&run_dir, frame, response)?;
                let map = transparency(&rgb, Some(&clipped), panel).map_err(|e| {
                    ProcessingError::Camera {
                        camera: camera.clone(),
                        source: Box::new(e),
                    }
                })?;
                let (w, h) = (frame.meta.width, frame.meta.height);
                let samples: Vec<f32> = map
                    .rgb
                    .chunks_exact(3)
                    .zip(&map.flags)
                    .flat_map(|(t, f)| [t[0], t[1], t[2], f32::from(*f)])
                    .collect();
                let metadata = json!({
                    "camera": camera,
                    "channels": {"T": "fraction of the backlight panel's radiance passing through", "flags": "1 clipped (T a lower bound), 2 above one (clamped)"},
                });
                let planes = Planes {
                    size: (w, h),
                    channels: &["T.R", "T.G", "T.B", "flags"],
                    samples: &samples,
                    preview_rgb: &map.rgb,
                };
                made.extend(map_files(&run_dir, &new, &planes, &metadata)?);
                summary.transparency_written += 1;
            }
        }
        for (new, bytes) in made {
            store.write(new, &bytes).map_err(dataset_err(&run_dir))?;
        }
    }
    progress(cameras.len(), cameras.len());
    if seen > 0 {
        summary.not_converged = poor as f64 / seen as f64;
        summary.anisotropic = aniso as f64 / seen as f64;
    }
    Ok(summary)
}

/// The PNG preview's product beside `new`'s OpenEXR.
fn preview_product(new: &NewProduct) -> NewProduct {
    NewProduct {
        key: format!("{}/preview", new.key),
        file_name: new.file_name.replace(".exr", ".png"),
        ..new.clone()
    }
}

/// A map's planes: its size, channel names, interleaved samples, and the RGB its preview shows.
struct Planes<'a> {
    size: (u32, u32),
    channels: &'a [&'a str],
    samples: &'a [f32],
    preview_rgb: &'a [f32],
}

/// A map's OpenEXR (`new`) and its PNG preview, with `metadata` in both.
fn map_files(
    run_dir: &Path,
    new: &NewProduct,
    planes: &Planes<'_>,
    metadata: &serde_json::Value,
) -> Result<Made, ProcessingError> {
    let (w, h) = planes.size;
    let metadata = metadata.to_string();
    let channels: Vec<String> = planes.channels.iter().map(|c| c.to_string()).collect();
    let exr = encode_exr_planes(&new.file_name, w, h, &channels, planes.samples, &metadata)
        .map_err(dataset_err(run_dir))?;
    let png = encode_png16(
        &new.file_name,
        w,
        h,
        &preview(planes.preview_rgb),
        16,
        &metadata,
    )
    .map_err(dataset_err(run_dir))?;
    Ok(vec![(preview_product(new), png), (new.clone(), exr)])
}

/// The Ward maps' OpenEXR and ρd preview.
fn ward_files(run_dir: &Path, new: &NewProduct, maps: &WardMaps) -> Result<Made, ProcessingError> {
    let n = maps.width * maps.height;
    let samples: Vec<f32> = (0..n)
        .flat_map(|i| {
            [
                maps.rho_d[i * 3],
                maps.rho_d[i * 3 + 1],
                maps.rho_d[i * 3 + 2],
                maps.rho_s[i],
                maps.alpha[i],
                maps.relative_rms[i],
                f32::from(maps.flags[i]),
            ]
        })
        .collect();
    let metadata = json!({
        "camera": new.parameters["camera"],
        "channels": {
            "rho_d": "diffuse albedo", "rho_s": "specular albedo", "alpha": "Ward roughness",
            "rms": "relative RMS residual of the fit",
            "flags": "bits: 0 black, 1 no specular, 2 specular peak outside the sweep, 3 alpha below the stop spacing, 4 alpha at the search's end, 5 saturated samples, 6 poor fit, 7 anisotropic, 13 not in the turned scan, 14 unseen, 15 refused",
        },
    });
    let planes = Planes {
        size: (maps.width as u32, maps.height as u32),
        channels: &[
            "rho_d.R", "rho_d.G", "rho_d.B", "rho_s", "alpha", "rms", "flags",
        ],
        samples: &samples,
        preview_rgb: &maps.rho_d,
    };
    map_files(run_dir, new, &planes, &metadata)
}
