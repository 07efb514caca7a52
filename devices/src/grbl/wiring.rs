//! The rig-file wiring of GRBL devices: every GRBL axis and the GRBL laser name a port, and
//! each axis has its own controller letter on its port.

use std::collections::BTreeMap;

use crate::rig::span::{Problem, at, key, needs_port};
use crate::rig::{Backend, RigSpec};

/// Ports and controller letters of the rig's GRBL axes and laser.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    // One controller per port, each letter once.
    let mut letters: BTreeMap<(&str, &str), &str> = BTreeMap::new();
    for (i, a) in spec.axes.iter().enumerate() {
        if a.backend != Backend::Grbl {
            continue;
        }
        let what = format!("axis `{}`", a.id);
        needs_port(at("axis", i, "backend"), &what, a.backend, &a.port)?;
        let letter = a.controller_axis.as_deref().unwrap_or("");
        if !["X", "Y", "Z"].contains(&letter) {
            return Err((
                at("axis", i, "backend"),
                format!(
                    "{what}: a GRBL axis needs controller_axis = \"X\", \"Y\" or \"Z\" (the letter it has on the controller)"
                ),
            ));
        }
        let port = a.port.as_deref().unwrap_or("");
        if let Some(other) = letters.insert((port, letter), &a.id) {
            return Err((
                at("axis", i, "controller_axis"),
                format!(
                    "{what}: controller axis {letter} on {port} is already axis `{other}`; give each axis its own letter"
                ),
            ));
        }
    }
    if let Some(l) = spec.laser.as_ref().filter(|l| l.backend == Backend::Grbl) {
        needs_port(
            key("laser", "backend"),
            &format!("laser `{}`", l.id),
            l.backend,
            &l.port,
        )?;
    }
    Ok(())
}
