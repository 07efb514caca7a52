//! The rig-file wiring of devices on a switch bank (backend `switch`): the GPIO trigger needs
//! a relay-serial bank and a line; a laser powered through a relay (backend `switch`, or a GRBL
//! laser with `bank`) needs a bank and a free channel on it.

use crate::rig::span::{Problem, key};
use crate::rig::{Backend, RigSpec};

/// The trigger's GPIO line and the laser's power relay.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    if let Some(t) = spec
        .trigger
        .as_ref()
        .filter(|t| t.backend == Backend::Switch)
    {
        let what = format!("trigger `{}`", t.id);
        let bank = t.bank.as_deref().and_then(|b| spec.bank(b));
        match bank {
            Some(b) if b.backend == Backend::RelaySerial => {}
            _ => {
                return Err((
                    key("trigger", "backend"),
                    format!(
                        "{what}: backend `{}` needs `bank`, the id of a {} switch bank whose GPIO line fires the cameras",
                        Backend::Switch.as_str(),
                        Backend::RelaySerial.as_str()
                    ),
                ));
            }
        }
        if !matches!(t.line, Some(l) if l < 32) {
            return Err((
                key("trigger", "backend"),
                format!(
                    "{what}: backend `{}` needs `line`, the board's GPIO number (0–31)",
                    Backend::Switch.as_str()
                ),
            ));
        }
    }
    let Some(l) = &spec.laser else {
        return Ok(());
    };
    // A GRBL laser may also be powered through a relay (`bank`, `channel`): both must be
    // on to emit, and the relay board's watchdog switches it off if stagehand dies.
    if !(l.backend == Backend::Switch || (l.backend == Backend::Grbl && l.bank.is_some())) {
        return Ok(());
    }
    let what = format!("laser `{}`", l.id);
    let Some(bank) = l.bank.as_deref().and_then(|b| spec.bank(b)) else {
        return Err((
            key("laser", "backend"),
            format!("{what}: `bank` must name the switch bank whose relay powers the laser"),
        ));
    };
    let channel = l.channel.unwrap_or(0);
    if channel == 0 || channel > bank.channels {
        return Err((
            key("laser", "backend"),
            format!(
                "{what}: the laser's relay needs `channel` between 1 and {} (bank `{}`)",
                bank.channels, bank.id
            ),
        ));
    }
    if let Some(lamp) = spec
        .lamps
        .iter()
        .find(|x| x.bank == bank.id && x.channel == channel)
    {
        return Err((
            key("laser", "channel"),
            format!(
                "{what}: channel {channel} of bank `{}` already powers lamp `{}`",
                bank.id, lamp.id
            ),
        ));
    }
    Ok(())
}
