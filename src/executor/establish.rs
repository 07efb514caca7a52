//! Bringing the rig into a known state: at the start of a run (home every axis) and on resume
//! (home, then move, switch and fit everything as the plan had it before the first pending step).

use std::collections::BTreeMap;

use stagehand_devices::{DeviceError, DeviceErrorKind};

use super::{Live, missing, try_all};
use crate::estimate::RigState;
use crate::rig::Rig;

/// Homes every axis, then re-creates `state` on the devices.
pub(super) async fn establish(
    rig: &Rig,
    live: &mut Live,
    state: &RigState,
) -> Result<(), DeviceError> {
    // Start from the safe state so nothing emits while axes home.
    rig.safe_state().await?;
    try_all(rig.axes.values().map(|a| a.home())).await?;
    let moves: Vec<_> = state
        .axes_deg
        .iter()
        .map(|(id, deg)| {
            rig.axes
                .get(id)
                .map(|h| (h, *deg))
                .ok_or_else(|| missing(id, "no such axis in this rig"))
        })
        .filter(|m| !matches!(m, Ok((h, deg)) if *deg == h.spec().home_deg))
        .collect::<Result<_, _>>()?;
    try_all(moves.iter().map(|(h, deg)| h.move_to(*deg))).await?;
    if let Some(w) = &rig.world {
        w.place_fixture(&state.fixture, state.fixture_pose);
    }
    if let Some(l) = &rig.laser {
        l.fitted(state.laser_fitted_nm, state.laser_mount_deg)
            .await?;
        if state.laser_armed {
            l.arm().await?;
        }
        if state.laser_on {
            l.on(state.laser_fitted_nm).await?;
        }
    }
    if let Some(c) = &rig.cart
        && state.cart_mm != 0.0
    {
        c.move_to(state.cart_mm).await?;
    }
    let lamps: BTreeMap<String, bool> =
        state.lamps_on.iter().map(|id| (id.clone(), true)).collect();
    live.state = state.clone();
    live.state.lamps_on.clear();
    switch_lamps(rig, live, &lamps).await
}

/// Takes the rig's state as it is for an in-place capture: every axis must be homed and still;
/// lamps (read back from their banks), laser, cart and fixture are recorded as found. Lamps
/// found on are treated as just switched on, so the capture waits their warm-up: their switch
/// time is not known.
pub(super) async fn adopt(rig: &Rig, live: &mut Live) -> Result<(), DeviceError> {
    let mut state = live.state.clone();
    for (id, axis) in &rig.axes {
        let s = axis.status();
        if !s.homed {
            return Err(DeviceError::new(id.clone(), DeviceErrorKind::NotHomed));
        }
        if s.moving {
            return Err(missing(
                id,
                "the axis is moving; wait for it to stop before capturing",
            ));
        }
        state.axes_deg.insert(id.clone(), s.position_deg);
    }
    state.lamps_on.clear();
    for (bank_id, bank) in &rig.banks {
        let states = bank.read().await?;
        for (id, wiring) in rig.lamps.iter().filter(|(_, w)| &w.bank == bank_id) {
            if states
                .get(wiring.channel.saturating_sub(1) as usize)
                .copied()
                .unwrap_or(false)
            {
                state.lamps_on.insert(id.clone());
            }
        }
    }
    if let Some(l) = &rig.laser {
        let s = l.status();
        state.laser_armed = s.armed;
        state.laser_on = s.on;
        state.laser_fitted_nm = s.fitted_nm;
        state.laser_mount_deg = s.mount_elevation_deg;
    }
    if let Some(c) = &rig.cart {
        state.cart_mm = c.position_mm();
    }
    if let Some(w) = &rig.world {
        (state.fixture, state.fixture_pose) = w.fixture();
    }
    let now = rig.clock.now_s();
    live.lamp_on_since = state.lamps_on.iter().map(|id| (id.clone(), now)).collect();
    live.state = state;
    Ok(())
}

/// Switches lamps by id (grouped per bank) and records switch-on times for the warm-up wait.
pub(super) async fn switch_lamps(
    rig: &Rig,
    live: &mut Live,
    states: &BTreeMap<String, bool>,
) -> Result<(), DeviceError> {
    let mut per_bank: BTreeMap<&str, Vec<(u32, bool)>> = BTreeMap::new();
    for (id, on) in states {
        let wiring = rig
            .lamps
            .get(id)
            .ok_or_else(|| missing(id, "no such lamp in this rig"))?;
        per_bank
            .entry(wiring.bank.as_str())
            .or_default()
            .push((wiring.channel, *on));
    }
    for (bank, changes) in per_bank {
        let handle = rig
            .banks
            .get(bank)
            .ok_or_else(|| missing(bank, "no such switch bank in this rig"))?;
        handle.set_many(&changes).await?;
    }
    let now = rig.clock.now_s();
    for (id, on) in states {
        if *on {
            if live.state.lamps_on.insert(id.clone()) {
                live.lamp_on_since.insert(id.clone(), now);
            }
        } else {
            live.state.lamps_on.remove(id);
            live.lamp_on_since.remove(id);
        }
    }
    Ok(())
}
