//! `stagehand process --products local`: the local reflectance function of every halogen
//! capture of a quasi-homogeneous run's step 3 ([`crate::dipole_local`]), from the products
//! the dipole pass made: each laser colour's fit (its channel's α′, so R), its entrance
//! function (f at the lamp's direction) and the exit map of the capture's view (f_v, the
//! same camera at the same turntable angle in step 2). The capture is merged through the
//! response calibration and divided by the colour calibration's S of its camera and lamp,
//! so values are reflectance factors (π·L/E).
//!
//! One OpenEXR per capture (`local/<cam>_<table>deg_arc<arc>deg_<lamp>.exr`, in the camera's
//! pixels): `local.R/G/B` (clamped at 0), `known.R/G/B` (1 where the exit function is known
//! and the capture measured; a channel without a laser colour is unknown everywhere),
//! `global.R/G/B` (the dipole's term subtracted: the fitted material re-rendered under the
//! lamp) and `captured.R/G/B` (the white-balanced capture), 0 where unknown. Captures are taken view by view, so only one view's exit maps are held.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::exr_planes::{decode_exr_planes, encode_exr_planes};
use stagehand_dataset::products::{NewProduct, ProductStore, StoredProduct};

use crate::calibrate_geometry::CameraGeometry;
use crate::colour_calibration::ColourSet;
use crate::dipole::{DipoleMedium, fresnel_transmittance, hemispherical_transmittance};
use crate::dipole_local::{
    EntranceAt, GlobalTerm, LOCAL_PLANES, LocalCounts, entrance_at, local_map,
};
use crate::dipole_products::{DipoleProduct, EntranceProduct, LeftOut};
use crate::dipole_profile::plane_pixels;
use crate::error::ProcessingError;
use crate::laser_sheet::laser_channel;
use crate::reflectometer_products::{NOMINAL, camera_response};
use crate::response_calibration::ResponseSet;
use crate::run_frames::{
    BracketKey, axis_angle, bracket_keys, dataset_err, merge_capture, open_run,
};

/// What the local products are made with.
#[derive(Debug, Clone, Copy)]
pub struct LocalSetup<'a> {
    /// The response calibration and its id (the dipole's).
    pub response: (&'a ResponseSet, &'a str),
    /// The colour calibration (S per camera and lamp) and its id.
    pub colour: (&'a ColourSet, &'a str),
    /// Each camera's geometry and where it comes from (the dipole's).
    pub geometry: (&'a BTreeMap<String, CameraGeometry>, &'a str),
    /// The turntable's axis id, if the rig has one.
    pub turntable_axis: Option<&'a str>,
    /// The light arc's axis id, if the rig has one.
    pub light_arc_axis: Option<&'a str>,
    /// Each halogen lamp's elevation on the light arc, degrees, by lamp id.
    pub lamps: &'a BTreeMap<String, f64>,
    /// Only these cameras (`None`: every camera).
    pub cameras: Option<&'a [String]>,
}

/// One channel of a local map: where its global term comes from and what the map holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocalChannel {
    /// The laser colour whose dipole serves the channel, nm.
    pub colour_nm: u32,
    /// f(ω_i) at the lamp.
    pub entrance: EntranceAt,
    /// The map's pixels.
    pub counts: LocalCounts,
}

/// What a local pass did.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LocalSummary {
    /// Maps written now.
    pub written: usize,
    /// Maps already current.
    pub skipped: usize,
    /// Per RGB channel, the written maps' pixels summed (zero for a channel no laser colour
    /// serves).
    pub channels: [LocalCounts; 3],
    /// Written maps whose lamp lies outside step 1's mounts (the entrance extrapolated).
    pub extrapolated: usize,
    /// Captures left out, and why.
    pub left_out: Vec<LeftOut>,
}

/// The dipole pass's products a local map is made from.
struct DipoleInputs {
    /// Per RGB channel: the fit, its laser colour, and its entrance function.
    channels: [Option<(DipoleProduct, EntranceProduct)>; 3],
    /// (colour, camera, turntable key) → exit map.
    exits: BTreeMap<(u32, String, i64), StoredProduct>,
    fixture: String,
}

/// A turntable angle as a map key (thousandths of a degree).
fn table_key(deg: f64) -> i64 {
    (deg * 1000.0).round() as i64
}

fn read_json<T: serde::de::DeserializeOwned>(
    run_dir: &Path,
    p: &StoredProduct,
) -> Result<T, ProcessingError> {
    let bad = |message: String| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message: format!(
            "product {}: {message}; remake it with `stagehand process`",
            p.path
        ),
    };
    let bytes = std::fs::read(run_dir.join(&p.path)).map_err(|e| bad(e.to_string()))?;
    serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))
}

/// Reads the dipole pass's products from `store`.
fn dipole_inputs(store: &ProductStore) -> Result<DipoleInputs, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let run = run_dir.display().to_string();
    let products = store.products().map_err(dataset_err(&run_dir))?;
    let mut entrances: BTreeMap<u32, EntranceProduct> = BTreeMap::new();
    for p in products.iter().filter(|p| p.made.kind == "entrance") {
        let e: EntranceProduct = read_json(&run_dir, p)?;
        entrances.insert(e.colour_nm, e);
    }
    let mut channels: [Option<(DipoleProduct, EntranceProduct)>; 3] = Default::default();
    let mut fixture: Option<String> = None;
    for p in products.iter().filter(|p| p.made.kind == "dipole") {
        let d: DipoleProduct = read_json(&run_dir, p)?;
        let nm = d.colour_nm;
        let Some(entrance) = entrances.remove(&nm) else {
            return Err(ProcessingError::MissingInput {
                run,
                what: format!("entrance function of the {nm} nm laser"),
                hint: "process with --products local (it makes the entrance functions from step 1's lines first)",
            });
        };
        if let Some(f) = fixture.as_ref().filter(|f| **f != d.fixture) {
            return Err(ProcessingError::Dataset {
                run,
                message: format!(
                    "the dipole fits are of two samples, `{f}` and `{}`; a run holds one sample",
                    d.fixture
                ),
            });
        }
        fixture = Some(d.fixture.clone());
        let slot = &mut channels[laser_channel(nm)];
        if let Some((other, _)) = slot {
            return Err(ProcessingError::Dataset {
                run,
                message: format!(
                    "two laser colours, {} and {nm} nm, measured the same camera channel; the local reflectance function needs one per channel (process a run of one of them)",
                    other.colour_nm
                ),
            });
        }
        *slot = Some((d, entrance));
    }
    let Some(fixture) = fixture else {
        return Err(ProcessingError::MissingInput {
            run,
            what: "dipole fit".into(),
            hint: "process with --products local, which fits the dipole to step 2's lines first",
        });
    };
    let mut exits = BTreeMap::new();
    for p in products.into_iter().filter(|p| p.made.kind == "exit") {
        let q = &p.made.parameters;
        if let (Some(nm), Some(camera), Some(table)) = (
            q["colour_nm"].as_u64(),
            q["camera"].as_str(),
            q["turntable_deg"].as_f64(),
        ) {
            exits.insert((nm as u32, camera.to_string(), table_key(table)), p);
        }
    }
    Ok(DipoleInputs {
        channels,
        exits,
        fixture,
    })
}

/// One channel's exit map of a view, decoded: (exit, weight) planes.
type ExitPlanes = (Vec<f32>, Vec<f32>);

fn read_exit(
    run_dir: &Path,
    p: &StoredProduct,
    size: (usize, usize),
) -> Result<ExitPlanes, ProcessingError> {
    let bad = |message: String| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message: format!(
            "exit map {}: {message}; remake it with `stagehand process --products exit`",
            p.path
        ),
    };
    let bytes = std::fs::read(run_dir.join(&p.path)).map_err(|e| bad(e.to_string()))?;
    let planes = decode_exr_planes(&p.path, &bytes).map_err(|e| bad(e.to_string()))?;
    if (planes.width as usize, planes.height as usize) != size {
        return Err(bad(format!(
            "it is {}×{}, the capture {}×{}",
            planes.width, planes.height, size.0, size.1
        )));
    }
    match (planes.channel("exit"), planes.channel("weight")) {
        (Some(e), Some(w)) => Ok((e.to_vec(), w.to_vec())),
        _ => Err(bad("it lacks the exit or weight plane".into())),
    }
}

/// Writes the local reflectance function of every step-3 capture of the run into `store`;
/// `progress(done, total)` after each view.
pub fn local_products(
    store: &mut ProductStore,
    setup: LocalSetup<'_>,
    software: &str,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<LocalSummary, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let inputs = dipole_inputs(store)?;
    let reader = open_run(&run_dir)?;
    let keep = |camera: &str| setup.cameras.is_none_or(|c| c.iter().any(|x| x == camera));
    let keys = bracket_keys(&reader, |m| {
        !m.laser_on && m.lamps_on.len() == 1 && m.fixture == inputs.fixture && keep(&m.camera)
    })?;
    if keys.is_empty() {
        return Err(ProcessingError::MissingInput {
            run: run_dir.display().to_string(),
            what: format!(
                "halogen capture of `{}` lit by one lamp at a time (step 3)",
                inputs.fixture
            ),
            hint: "record step 3 of sequences/quasi_homogeneous.rhai (--set step3=true)",
        });
    }
    let (colour, colour_id) = setup.colour;
    let (geometries, geometry_id) = setup.geometry;
    let calibrations: Vec<String> = [setup.response.1, colour_id, geometry_id]
        .into_iter()
        .filter(|id| *id != NOMINAL)
        .map(String::from)
        .collect();
    // Captures by view: one view's exit maps are read once for all its lamps.
    let mut views: BTreeMap<(String, i64), (f64, Vec<&BracketKey>)> = BTreeMap::new();
    for key in &keys {
        let table = axis_angle(
            &run_dir,
            &key.meta,
            &key.frames[0].path,
            setup.turntable_axis,
        )?;
        views
            .entry((key.camera.clone(), table_key(table)))
            .or_insert_with(|| (table, Vec::new()))
            .1
            .push(key);
    }
    let mut summary = LocalSummary::default();
    let total = views.len();
    for (done, ((camera, table_k), (table, captures))) in views.iter().enumerate() {
        progress(done, total);
        let exits: [Option<(&StoredProduct, &DipoleProduct, &EntranceProduct)>; 3] =
            std::array::from_fn(|c| {
                let (d, e) = inputs.channels[c].as_ref()?;
                let exit = inputs.exits.get(&(d.colour_nm, camera.clone(), *table_k))?;
                Some((exit, d, e))
            });
        if exits.iter().all(Option::is_none) {
            for key in captures {
                summary.left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: format!(
                        "step 2 made no exit map of camera {camera} at turntable {table}° (its lines must be seen from the same view)"
                    ),
                });
            }
            continue;
        }
        let geometry =
            geometries
                .get(camera)
                .ok_or_else(|| ProcessingError::CalibrationMismatch {
                    id: geometry_id.to_string(),
                    why: format!("it has no geometry for camera `{camera}`"),
                })?;
        let response = camera_response(setup.response, camera)?;
        // Read lazily: a view whose maps are all current needs neither.
        let mut planes: Option<([Option<ExitPlanes>; 3], Vec<f32>)> = None;
        for key in captures {
            let [lamp] = key.meta.lamps_on.as_slice() else {
                continue;
            };
            let Some(&elevation) = setup.lamps.get(lamp) else {
                summary.left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: format!("lamp `{lamp}` is not a halogen lamp on the light arc"),
                });
                continue;
            };
            let scale = colour
                .get(camera)
                .and_then(|c| c.lamps.get(lamp))
                .map(|l| l.fit.scale)
                .ok_or_else(|| ProcessingError::CalibrationMismatch {
                    id: colour_id.to_string(),
                    why: format!(
                        "it has no white balance for camera `{camera}` under lamp `{lamp}` (step {}); calibrate the colour of this rig's cameras and lamps (sequences/calibration_colorchecker.rhai)",
                        key.step
                    ),
                })?;
            let arc = axis_angle(
                &run_dir,
                &key.meta,
                &key.frames[0].path,
                setup.light_arc_axis,
            )?;
            let azimuth = arc - table;
            let mut channels: [Option<LocalChannel>; 3] = Default::default();
            let mut factors = [0.0; 3];
            let mut parameters = Vec::new();
            for (c, found) in exits.iter().enumerate() {
                let Some((exit, d, e)) = found else { continue };
                let entrance =
                    entrance_at(&e.directions, d.eta, elevation, azimuth).map_err(|why| {
                        ProcessingError::IllPosed {
                            what: "entrance function at a lamp",
                            why: format!("{} nm, lamp `{lamp}`: {why}", d.colour_nm),
                        }
                    })?;
                let medium = DipoleMedium {
                    alpha_p: d.fit.alpha_p,
                    sigma_t_p: d.fit.sigma_t_p,
                    eta: d.eta,
                };
                factors[c] = entrance.value * fresnel_transmittance(1.0, d.eta)
                    / hemispherical_transmittance(d.eta)
                    * medium.total_reflectance();
                parameters.push(json!({
                    "channel": c,
                    "colour_nm": d.colour_nm,
                    "alpha_p": d.fit.alpha_p,
                    "sigma_t_p": d.fit.sigma_t_p,
                    "eta": d.eta,
                    "entrance": entrance,
                    "exit": exit.sha256,
                }));
                channels[c] = Some(LocalChannel {
                    colour_nm: d.colour_nm,
                    entrance,
                    counts: LocalCounts::default(),
                });
            }
            let new = NewProduct {
                kind: "local".into(),
                key: format!("local/{camera}/{table:.3}/{arc:.3}/{lamp}"),
                file_name: format!("{camera}_{table:.0}deg_arc{arc:.0}deg_{lamp}.exr"),
                inputs: key.frames.iter().map(|f| f.path.clone()).collect(),
                calibrations: calibrations.clone(),
                software: software.to_string(),
                parameters: json!({
                    "camera": camera,
                    "turntable_deg": table,
                    "light_arc_deg": arc,
                    "lamp": lamp,
                    "lamp_elevation_deg": elevation,
                    "truth_frame": key.frames[0].path,
                    "white_balance": scale,
                    "geometry": geometry_id,
                    "channels": parameters,
                }),
            };
            if store.is_current(&new).map_err(dataset_err(&run_dir))? {
                summary.skipped += 1;
                continue;
            }
            let size = (key.meta.width as usize, key.meta.height as usize);
            if planes.as_ref().is_none_or(|p| p.1.len() != size.0 * size.1) {
                let mut maps: [Option<ExitPlanes>; 3] = Default::default();
                for (c, found) in exits.iter().enumerate() {
                    if let Some((exit, _, _)) = found {
                        maps[c] = Some(read_exit(&run_dir, exit, size)?);
                    }
                }
                let mut cos_out = vec![0.0f32; size.0 * size.1];
                for p in plane_pixels(geometry, *table, size, f64::INFINITY) {
                    cos_out[p.index] = p.cos_out as f32;
                }
                planes = Some((maps, cos_out));
            }
            let Some((maps, cos_out)) = planes.as_ref() else {
                continue;
            };
            let (mut hdr, _) =
                merge_capture(&reader, key, response).map_err(|e| ProcessingError::Dataset {
                    run: run_dir.display().to_string(),
                    message: format!("capture {} (camera {camera}): {e}", key.frames[0].path),
                })?;
            for px in hdr.rgb.chunks_exact_mut(3) {
                for (v, s) in px.iter_mut().zip(scale) {
                    *v = (f64::from(*v) / s) as f32;
                }
            }
            let terms: [Option<GlobalTerm<'_>>; 3] = std::array::from_fn(|c| {
                let (exit, weight) = maps[c].as_ref()?;
                let (_, d, _) = exits[c]?;
                Some(GlobalTerm {
                    exit,
                    weight,
                    factor: factors[c],
                    eta: d.eta,
                })
            });
            let (map, counts) = local_map(&hdr.rgb, &hdr.state, cos_out, &terms);
            if counts.iter().all(|c| c.known == 0) {
                summary.left_out.push(LeftOut {
                    frame: key.frames[0].path.clone(),
                    why: format!(
                        "none of its pixels has both a known exit function (step 2's lines lit too little of what camera {camera} sees) and a measured value"
                    ),
                });
                continue;
            }
            for (c, channel) in channels.iter_mut().enumerate() {
                if let Some(channel) = channel {
                    channel.counts = counts[c];
                    summary.channels[c] += counts[c];
                }
            }
            let extrapolated = channels.iter().flatten().any(|c| c.entrance.extrapolated);
            let metadata = json!({
                "camera": camera,
                "lamp": lamp,
                "units": "reflectance factor π·L/E (the capture over the colour calibration's S of its camera and lamp)",
                "channels": {
                    "local": "the capture less the dipole's global term, clamped at 0 (seed eq. 5.67)",
                    "known": "1 where the exit function is known and the capture measured, else 0",
                    "global": "the dipole's global term: the fitted material re-rendered under the lamp",
                    "captured": "the capture, white-balanced",
                },
                "per_channel": channels,
            })
            .to_string();
            let names: Vec<String> = LOCAL_PLANES.iter().map(|s| s.to_string()).collect();
            let exr = encode_exr_planes(
                &new.file_name,
                size.0 as u32,
                size.1 as u32,
                &names,
                &map,
                &metadata,
            )
            .map_err(dataset_err(&run_dir))?;
            store.write(new, &exr).map_err(dataset_err(&run_dir))?;
            summary.written += 1;
            summary.extrapolated += usize::from(extrapolated);
        }
    }
    progress(total, total);
    if summary.written + summary.skipped == 0 {
        return Err(ProcessingError::IllPosed {
            what: "local reflectance function",
            why: format!(
                "no halogen capture of `{}` has a view step 2 measured: {}",
                inputs.fixture,
                summary
                    .left_out
                    .iter()
                    .take(3)
                    .map(|l| format!("{}: {}", l.frame, l.why))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        });
    }
    Ok(summary)
}
