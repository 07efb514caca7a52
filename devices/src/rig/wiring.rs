//! Checks of how a rig's devices are wired to drivers that hold for every backend: which
//! backends each kind of device accepts, baud rates, watchdog and pulse lengths. What one
//! backend needs (ports, channels, controller letters, shared controllers) is checked beside
//! its driver, in its folder's `wiring.rs`; this file calls each of them.

use super::span::{Problem, Seg, at, key};
use super::spec::{Backend, RigSpec};

/// Err unless `allowed` contains `b`, the backend of a device `what` at `path`.
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

/// Err if a serial baud rate is given and impossible.
fn baud_ok(path: Vec<Seg>, what: &str, baud: Option<u32>) -> Result<(), Problem> {
    match baud {
        Some(b) if !(300..=4_000_000).contains(&b) => Err((
            path,
            format!("{what}: baud must be between 300 and 4000000, got {b}"),
        )),
        _ => Ok(()),
    }
}

/// Backends, ports, controller letters and switch channels of every device: first what holds
/// for every backend, then each backend's own checks.
pub(super) fn check_wiring(spec: &RigSpec) -> Result<(), Problem> {
    check_kinds(spec)?;
    crate::grbl::wiring::check(spec)?;
    crate::relay_serial::wiring::check(spec)?;
    crate::hid_relay::wiring::check(spec)?;
    crate::switch_wired::wiring::check(spec)?;
    crate::ir_cart::wiring::check(spec)?;
    crate::cameras::wiring::check(spec)
}

/// The backends each kind of device accepts, and the settings every backend shares.
fn check_kinds(spec: &RigSpec) -> Result<(), Problem> {
    for (i, a) in spec.axes.iter().enumerate() {
        let what = format!("axis `{}`", a.id);
        backend_for(
            at("axis", i, "backend"),
            &what,
            a.backend,
            &[Backend::Sim, Backend::Grbl],
        )?;
        baud_ok(at("axis", i, "baud"), &what, a.baud)?;
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
        backend_for(
            at("camera", i, "backend"),
            &format!("camera `{}`", c.id),
            c.backend,
            &[
                Backend::Sim,
                Backend::V4l,
                Backend::Aravis,
                Backend::Gphoto2,
            ],
        )?;
    }
    if let Some(t) = &spec.trigger {
        let what = format!("trigger `{}`", t.id);
        backend_for(
            key("trigger", "backend"),
            &what,
            t.backend,
            &[Backend::Sim, Backend::Switch, Backend::Software],
        )?;
        if !(t.pulse_s.is_finite() && (1e-6..=1.0).contains(&t.pulse_s)) {
            return Err((
                key("trigger", "pulse_s"),
                format!(
                    "{what}: pulse_s must be between 1 µs and 1 s, got {}",
                    t.pulse_s
                ),
            ));
        }
    }
    if let Some(l) = &spec.laser {
        backend_for(
            key("laser", "backend"),
            &format!("laser `{}`", l.id),
            l.backend,
            &[Backend::Sim, Backend::Grbl, Backend::Switch],
        )?;
    }
    if let Some(c) = &spec.cart {
        let what = format!("cart `{}`", c.id);
        backend_for(
            key("cart", "backend"),
            &what,
            c.backend,
            &[Backend::Sim, Backend::IrBridge],
        )?;
        baud_ok(key("cart", "baud"), &what, c.baud)?;
    }
    Ok(())
}
