//! `stagehand process` for a quasi-homogeneous run: the dipole pass (fits, exit and entrance
//! functions) and the local reflectance function after it.

use std::collections::BTreeMap;

use stagehand_dataset::products::ProductStore;
use stagehand_devices::rig::{AxisRole, LampKind};
use stagehand_processing::colour_calibration::ColourSet;
use stagehand_processing::dipole_products::{
    DipoleOptions, DipoleReference, DipoleSetup, DipoleSummary, dipole_products,
};
use stagehand_processing::local_products::{LocalSetup, LocalSummary, local_products};

use super::calibrate::processing_err;
use super::process::{Calibrations, ProcessArgs, Product, cameras_geometry, with_progress};
use crate::session::SessionError;

/// What both passes over a quasi-homogeneous run read: the command's arguments, the
/// calibrations found, the run's rig and directory, its turntable axis and the software name
/// the products record.
pub(super) struct QuasiRun<'a> {
    pub args: &'a ProcessArgs,
    pub found: &'a Calibrations,
    pub rig: &'a stagehand_devices::rig::RigSpec,
    pub root: &'a std::path::Path,
    pub turntable: Option<&'a str>,
    pub software: &'a str,
}

/// The dipole fits of a quasi-homogeneous run.
pub(super) fn dipole_fits(
    run: &QuasiRun<'_>,
    store: &mut ProductStore,
) -> Result<DipoleSummary, SessionError> {
    let QuasiRun {
        args,
        found,
        rig,
        root,
        turntable,
        software,
    } = *run;
    let (responses, response_id) = found.response.as_ref().ok_or_else(|| {
        SessionError::Io(
            "dipole needs a response calibration: --calibration response-… (make one with `stagehand calibrate response`)".into(),
        )
    })?;
    let albedo = match args.reference_albedo.as_slice() {
        [a] => [*a; 3],
        [r, g, b] => [*r, *g, *b],
        [] => {
            return Err(SessionError::Io(format!(
                "dipole needs the albedo of the reference `{}` the laser's power is measured on: --reference-albedo A (or R,G,B)",
                args.reference_fixture
            )));
        }
        other => {
            return Err(SessionError::Io(format!(
                "--reference-albedo takes 1 or 3 values, got {}",
                other.len()
            )));
        }
    };
    if let Some(bad) = albedo.iter().find(|a| !(**a > 0.0 && **a <= 1.0)) {
        return Err(SessionError::Io(format!(
            "--reference-albedo {bad}: an albedo is above 0 and at most 1"
        )));
    }
    let (geometry, geometry_id) = cameras_geometry(args, found, rig, root)?;
    let light_arc = rig.axis_with_role(AxisRole::LightArc).map(|a| a.id.clone());
    let setup = DipoleSetup {
        response: (responses, response_id),
        geometry: (&geometry, &geometry_id),
        turntable_axis: turntable,
        light_arc_axis: light_arc.as_deref(),
        reference: DipoleReference {
            fixture: &args.reference_fixture,
            albedo,
        },
        options: DipoleOptions {
            eta: args.eta,
            ..DipoleOptions::default()
        },
        cameras: (!args.cameras.is_empty()).then_some(args.cameras.as_slice()),
        exit: args.products.contains(&Product::Exit) || args.products.contains(&Product::Local),
        entrance: args.products.contains(&Product::Entrance)
            || args.products.contains(&Product::Local),
    };
    let made = with_progress("colours", |progress| {
        dipole_products(store, setup, software, progress)
    })
    .map_err(processing_err)?;
    Ok(made)
}

/// The colour calibration `local` needs, checked before the dipole pass runs: it must exist
/// and be made through the response calibration the captures are merged with.
pub(super) fn local_inputs(found: &Calibrations) -> Result<(&ColourSet, &str), SessionError> {
    let (colour, colour_id) = found.colour.as_ref().ok_or_else(|| {
        SessionError::Io(
            "local needs a colour calibration of the lamps (S per camera and lamp, which turns a halogen capture into reflectance): --calibration colour-… (make one with `stagehand calibrate colour` on a run of sequences/calibration_colorchecker.rhai)".into(),
        )
    })?;
    if let Some((_, response_id)) = &found.response
        && found.colour_response != *response_id
    {
        return Err(SessionError::Io(format!(
            "--calibration {colour_id} was made through response calibration {}, not {response_id}: its scales are in that calibration's units; process with --calibration {}",
            found.colour_response, found.colour_response
        )));
    }
    Ok((colour, colour_id))
}

/// The local reflectance function of a quasi-homogeneous run's step 3, after its dipole pass.
pub(super) fn local_maps(
    run: &QuasiRun<'_>,
    store: &mut ProductStore,
) -> Result<LocalSummary, SessionError> {
    let QuasiRun {
        args,
        found,
        rig,
        root,
        turntable,
        software,
    } = *run;
    let (colour, colour_id) = local_inputs(found)?;
    let (responses, response_id) = found.response.as_ref().ok_or_else(|| {
        SessionError::Io(
            "local needs a response calibration: --calibration response-… (make one with `stagehand calibrate response`)".into(),
        )
    })?;
    let (geometry, geometry_id) = cameras_geometry(args, found, rig, root)?;
    let light_arc = rig.axis_with_role(AxisRole::LightArc).map(|a| a.id.clone());
    let lamps: BTreeMap<String, f64> = rig
        .lamps
        .iter()
        .filter(|l| l.kind == LampKind::Halogen)
        .map(|l| (l.id.clone(), l.elevation_deg))
        .collect();
    let setup = LocalSetup {
        response: (responses, response_id),
        colour: (colour, colour_id),
        geometry: (&geometry, &geometry_id),
        turntable_axis: turntable,
        light_arc_axis: light_arc.as_deref(),
        lamps: &lamps,
        cameras: (!args.cameras.is_empty()).then_some(args.cameras.as_slice()),
    };
    let made = with_progress("views", |progress| {
        local_products(store, setup, software, progress)
    })
    .map_err(processing_err)?;
    Ok(made)
}
