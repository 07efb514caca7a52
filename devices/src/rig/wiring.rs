//! Checks of how a rig's devices are wired to drivers: which backends each kind of device
//! accepts, the ports and channels a backend needs, and devices that share a controller.

use std::collections::BTreeMap;

use super::load::Seg;
use super::spec::{Backend, RigSpec};

type Problem = (Vec<Seg>, String);

fn at(table: &'static str, index: usize, key: &'static str) -> Vec<Seg> {
    vec![Seg::Key(table), Seg::Index(index), Seg::Key(key)]
}

fn backend_for(path: Vec<Seg>, what: &str, b: Backend, allowed: &[Backend]) -> Result<(), Problem> {
    if allowed.contains(&b) {
        return Ok(());
    }
    let list: Vec<&str> = allowed.iter().map(|&a| a.as_str()).collect();
    Err((
        path,
        format!(
            "{what}: backend `{}` cannot drive this kind of device; use one of {}",
            b.as_str(),
            list.join(", ")
        ),
    ))
}

fn needs_port(
    path: Vec<Seg>,
    what: &str,
    b: Backend,
    port: &Option<String>,
) -> Result<(), Problem> {
    match port {
        Some(p) if !p.trim().is_empty() => Ok(()),
        _ => Err((
            path,
            format!(
                "{what}: backend `{}` needs `port`, e.g. a /dev/serial/by-id/... path (list them with `stagehand devices`)",
                b.as_str()
            ),
        )),
    }
}

fn baud_ok(path: Vec<Seg>, what: &str, baud: Option<u32>) -> Result<(), Problem> {
    match baud {
        Some(b) if !(300..=4_000_000).contains(&b) => Err((
            path,
            format!("{what}: baud must be between 300 and 4000000, got {b}"),
        )),
        _ => Ok(()),
    }
}

/// Backends, ports, controller letters and switch channels of every device.
pub(super) fn check_wiring(spec: &RigSpec) -> Result<(), Problem> {
    // GRBL: one controller per port, each letter once.
    let mut letters: BTreeMap<(&str, &str), &str> = BTreeMap::new();
    for (i, a) in spec.axes.iter().enumerate() {
        let what = format!("axis `{}`", a.id);
        backend_for(
            at("axis", i, "backend"),
            &what,
            a.backend,
            &[Backend::Sim, Backend::Grbl],
        )?;
        baud_ok(at("axis", i, "baud"), &what, a.baud)?;
        if a.backend != Backend::Grbl {
            continue;
        }
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
    for (i, b) in spec.switch_banks.iter().enumerate() {
        let what = format!("switch bank `{}`", b.id);
        backend_for(
            at("switch_bank", i, "backend"),
            &what,
            b.backend,
            &[Backend::Sim, Backend::RelaySerial, Backend::HidRelay],
        )?;
        baud_ok(at("switch_bank", i, "baud"), &what, b.baud)?;
        if b.backend == Backend::RelaySerial {
            needs_port(at("switch_bank", i, "backend"), &what, b.backend, &b.port)?;
            if b.channels > 32 {
                return Err((
                    at("switch_bank", i, "channels"),
                    format!(
                        "{what}: a serial relay board has at most 32 relays, got {}",
                        b.channels
                    ),
                ));
            }
        }
        if b.backend == Backend::HidRelay && b.channels > 8 {
            return Err((
                at("switch_bank", i, "channels"),
                format!(
                    "{what}: a USB HID relay board has at most 8 relays, got {}",
                    b.channels
                ),
            ));
        }
        if !(b.watchdog_s.is_finite() && (0.5..=600.0).contains(&b.watchdog_s)) {
            return Err((
                at("switch_bank", i, "watchdog_s"),
                format!(
                    "{what}: watchdog_s must be between 0.5 and 600 s, got {}",
                    b.watchdog_s
                ),
            ));
        }
    }
    for (i, c) in spec.cameras.iter().enumerate() {
        let what = format!("camera `{}`", c.id);
        backend_for(
            at("camera", i, "backend"),
            &what,
            c.backend,
            &[
                Backend::Sim,
                Backend::V4l,
                Backend::Aravis,
                Backend::Gphoto2,
            ],
        )?;
        if c.backend == Backend::V4l {
            needs_port(at("camera", i, "backend"), &what, c.backend, &c.port)?;
        }
    }
    if let Some(t) = &spec.trigger {
        let key = |k| vec![Seg::Key("trigger"), Seg::Key(k)];
        let what = format!("trigger `{}`", t.id);
        backend_for(
            key("backend"),
            &what,
            t.backend,
            &[Backend::Sim, Backend::Switch, Backend::Software],
        )?;
        if !(t.pulse_s.is_finite() && (1e-6..=1.0).contains(&t.pulse_s)) {
            return Err((
                key("pulse_s"),
                format!(
                    "{what}: pulse_s must be between 1 µs and 1 s, got {}",
                    t.pulse_s
                ),
            ));
        }
        if t.backend == Backend::Switch {
            let bank = t.bank.as_deref().and_then(|b| spec.bank(b));
            match bank {
                Some(b) if b.backend == Backend::RelaySerial => {}
                _ => {
                    return Err((
                        key("backend"),
                        format!(
                            "{what}: backend `switch` needs `bank`, the id of a relay-serial switch bank whose GPIO line fires the cameras"
                        ),
                    ));
                }
            }
            if !matches!(t.line, Some(l) if l < 32) {
                return Err((
                    key("backend"),
                    format!(
                        "{what}: backend `switch` needs `line`, the board's GPIO number (0–31)"
                    ),
                ));
            }
        }
    }
    if let Some(l) = &spec.laser {
        let key = |k| vec![Seg::Key("laser"), Seg::Key(k)];
        let what = format!("laser `{}`", l.id);
        backend_for(
            key("backend"),
            &what,
            l.backend,
            &[Backend::Sim, Backend::Grbl, Backend::Switch],
        )?;
        if l.backend == Backend::Grbl {
            needs_port(key("backend"), &what, l.backend, &l.port)?;
        }
        // A GRBL laser may also be powered through a relay (`bank`, `channel`): both must be
        // on to emit, and the relay board's watchdog switches it off if stagehand dies.
        if l.backend == Backend::Switch || (l.backend == Backend::Grbl && l.bank.is_some()) {
            let Some(bank) = l.bank.as_deref().and_then(|b| spec.bank(b)) else {
                return Err((
                    key("backend"),
                    format!(
                        "{what}: `bank` must name the switch bank whose relay powers the laser"
                    ),
                ));
            };
            let channel = l.channel.unwrap_or(0);
            if channel == 0 || channel > bank.channels {
                return Err((
                    key("backend"),
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
                    key("channel"),
                    format!(
                        "{what}: channel {channel} of bank `{}` already powers lamp `{}`",
                        bank.id, lamp.id
                    ),
                ));
            }
        }
    }
    if let Some(c) = &spec.cart {
        let key = |k| vec![Seg::Key("cart"), Seg::Key(k)];
        let what = format!("cart `{}`", c.id);
        backend_for(
            key("backend"),
            &what,
            c.backend,
            &[Backend::Sim, Backend::IrBridge],
        )?;
        baud_ok(key("baud"), &what, c.baud)?;
        if c.backend == Backend::IrBridge {
            needs_port(key("backend"), &what, c.backend, &c.port)?;
        }
        if !(1..=4).contains(&c.ir_channel) {
            return Err((
                key("ir_channel"),
                format!(
                    "{what}: ir_channel must be 1–4 (the receiver's channel switch), got {}",
                    c.ir_channel
                ),
            ));
        }
        if c.ir_output != "A" && c.ir_output != "B" {
            return Err((
                key("ir_output"),
                format!(
                    "{what}: ir_output must be \"A\" or \"B\", got `{}`",
                    c.ir_output
                ),
            ));
        }
        if !(1..=7).contains(&c.ir_speed_step) {
            return Err((
                key("ir_speed_step"),
                format!("{what}: ir_speed_step must be 1–7, got {}", c.ir_speed_step),
            ));
        }
    }
    Ok(())
}
