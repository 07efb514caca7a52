//! A snapshot of every device's state, read from the actors' published status (no device
//! round trip), for `GET /api/status`, `device` events and SSE resynchronisation.

use serde::Serialize;
use utoipa::ToSchema;

use crate::rig::Rig;

/// One axis.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct AxisState {
    pub id: String,
    pub position_deg: f64,
    pub homed: bool,
    pub moving: bool,
    pub min_deg: f64,
    pub max_deg: f64,
}

/// One lamp and the switch channel that powers it.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct LampState {
    pub id: String,
    pub on: bool,
    pub bank: String,
    pub channel: u32,
}

/// The laser's safety state.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct LaserState {
    pub id: String,
    pub armed: bool,
    pub on: bool,
    pub fitted_nm: u32,
}

/// One camera.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct CameraState {
    pub id: String,
    pub width: u32,
    pub height: u32,
}

/// The reflectometer cart.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct CartState {
    pub id: String,
    pub position_mm: f64,
}

/// Every device of the rig.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct DevicesState {
    pub axes: Vec<AxisState>,
    pub lamps: Vec<LampState>,
    pub laser: Option<LaserState>,
    pub cameras: Vec<CameraState>,
    pub cart: Option<CartState>,
}

/// Reads the rig's devices' last published state.
pub fn snapshot(rig: &Rig) -> DevicesState {
    let axes = rig
        .axes
        .values()
        .map(|a| {
            let s = a.status();
            AxisState {
                id: a.id().to_string(),
                position_deg: s.position_deg,
                homed: s.homed,
                moving: s.moving,
                min_deg: a.spec().min_deg,
                max_deg: a.spec().max_deg,
            }
        })
        .collect();
    let lamps = rig
        .lamps
        .iter()
        .map(|(id, w)| {
            let on = rig
                .banks
                .get(&w.bank)
                .and_then(|b| {
                    b.states()
                        .get(w.channel.saturating_sub(1) as usize)
                        .copied()
                })
                .unwrap_or(false);
            LampState {
                id: id.clone(),
                on,
                bank: w.bank.clone(),
                channel: w.channel,
            }
        })
        .collect();
    let laser = rig.laser.as_ref().map(|l| {
        let s = l.status();
        LaserState {
            id: l.id().to_string(),
            armed: s.armed,
            on: s.on,
            fitted_nm: s.fitted_nm,
        }
    });
    let cameras = rig
        .cameras
        .values()
        .map(|c| CameraState {
            id: c.id().to_string(),
            width: c.spec().width,
            height: c.spec().height,
        })
        .collect();
    let cart = rig.cart.as_ref().map(|c| CartState {
        id: c.id().to_string(),
        position_mm: c.position_mm(),
    });
    DevicesState {
        axes,
        lamps,
        laser,
        cameras,
        cart,
    }
}
