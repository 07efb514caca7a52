//! A snapshot of every device's state, read from the actors' published status (no device
//! round trip), for `GET /api/status`, `device` events and SSE resynchronisation; and the
//! task that publishes a `device` event whenever it changes.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use stagehand_devices::axis::AxisHandle;
use tokio::sync::watch;
use utoipa::ToSchema;

use super::state::AppState;
use crate::daemon::events::EventKind;
use crate::rig::Rig;

/// Shortest time between two `device` events (at most 10 per second).
pub const MIN_EVENT_INTERVAL: Duration = Duration::from_millis(100);
/// How often states without a change notification (switch banks, the cart) are compared.
const POLL_INTERVAL: Duration = Duration::from_millis(200);

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
    /// The interlock (door switch) is closed; the laser emits only while armed and closed.
    pub interlock_closed: bool,
    /// `closed`, `open`, or `not fitted` (a real rig without interlock wiring: reads closed).
    pub interlock: String,
    /// What switches the laser off if stagehand dies (`no watchdog: …` when nothing does).
    pub watchdog: String,
    /// Seconds after which a relay board's watchdog switches the laser off, if one does.
    pub watchdog_s: Option<f64>,
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

/// One axis's last published state.
pub fn axis_state(a: &AxisHandle) -> AxisState {
    let s = a.status();
    AxisState {
        id: a.id().to_string(),
        position_deg: s.position_deg,
        homed: s.homed,
        moving: s.moving,
        min_deg: a.spec().min_deg,
        max_deg: a.spec().max_deg,
    }
}

/// One lamp's last published state (`None` if the rig has no such lamp).
pub fn lamp_state(rig: &Rig, id: &str) -> Option<LampState> {
    let w = rig.lamps.get(id)?;
    let on = rig
        .banks
        .get(&w.bank)
        .and_then(|b| {
            b.states()
                .get(w.channel.saturating_sub(1) as usize)
                .copied()
        })
        .unwrap_or(false);
    Some(LampState {
        id: id.to_string(),
        on,
        bank: w.bank.clone(),
        channel: w.channel,
    })
}

/// The laser's last published state (`None` if the rig has no laser).
pub fn laser_state(rig: &Rig) -> Option<LaserState> {
    rig.laser.as_ref().map(|l| {
        let s = l.status();
        let interlock = match rig.interlock.source() {
            stagehand_devices::interlock::InterlockSource::NotFitted => "not fitted",
            _ if s.interlock_closed => "closed",
            _ => "open",
        };
        LaserState {
            id: l.id().to_string(),
            armed: s.armed,
            on: s.on,
            fitted_nm: s.fitted_nm,
            interlock_closed: s.interlock_closed,
            interlock: interlock.to_string(),
            watchdog: rig
                .spec
                .laser_watchdog()
                .map(|w| w.describe())
                .unwrap_or_default(),
            watchdog_s: match rig.spec.laser_watchdog() {
                Some(stagehand_devices::rig::LaserWatchdog::Relay { watchdog_s, .. }) => {
                    Some(watchdog_s)
                }
                _ => None,
            },
        }
    })
}

/// Reads the rig's devices' last published state.
pub fn snapshot(rig: &Rig) -> DevicesState {
    let axes = rig.axes.values().map(axis_state).collect();
    let lamps = rig
        .lamps
        .keys()
        .filter_map(|id| lamp_state(rig, id))
        .collect();
    let laser = laser_state(rig);
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

/// Publishes a `device` event with the [`DevicesState`] snapshot whenever it changes: woken by
/// the axes' and the laser's status channels, switch banks and the cart compared every
/// [`POLL_INTERVAL`]; at most one event per [`MIN_EVENT_INTERVAL`]. It only reads published
/// state, so it never waits on a device; it ends when the daemon is dropped.
pub fn spawn_device_watch(app: AppState) {
    let daemon = Arc::downgrade(&app.0);
    let mut axes: Vec<_> = app.rig.axes.values().map(AxisHandle::watch).collect();
    let mut laser: Vec<_> = app.rig.laser.iter().map(|l| l.watch()).collect();
    let mut last = serde_json::to_value(snapshot(&app.rig)).ok();
    drop(app);
    tokio::spawn(async move {
        let mut next_allowed = tokio::time::Instant::now();
        loop {
            let _ = tokio::time::timeout(POLL_INTERVAL, any_changed(&mut axes, &mut laser)).await;
            tokio::time::sleep_until(next_allowed).await;
            let Some(daemon) = daemon.upgrade() else {
                return;
            };
            // Mark everything seen: the snapshot below includes it.
            for a in &mut axes {
                a.borrow_and_update();
            }
            for l in &mut laser {
                l.borrow_and_update();
            }
            let snap = snapshot(&daemon.rig);
            let value = serde_json::to_value(&snap).ok();
            if value != last {
                daemon.hub.publish(EventKind::Device, &snap);
                last = value;
                next_allowed = tokio::time::Instant::now() + MIN_EVENT_INTERVAL;
            }
        }
    });
}

/// Resolves when any of the watched statuses changes; channels whose actor is gone are
/// dropped from the lists (their last state stays in the snapshot).
async fn any_changed<A, L>(axes: &mut Vec<watch::Receiver<A>>, laser: &mut Vec<watch::Receiver<L>>)
where
    A: Send + Sync,
    L: Send + Sync,
{
    axes.retain(|r| r.has_changed().is_ok());
    laser.retain(|r| r.has_changed().is_ok());
    let mut waits: Vec<Pin<Box<dyn Future<Output = ()> + Send + '_>>> = Vec::new();
    for r in axes.iter_mut() {
        waits.push(Box::pin(async move {
            if r.changed().await.is_err() {
                std::future::pending::<()>().await;
            }
        }));
    }
    for r in laser.iter_mut() {
        waits.push(Box::pin(async move {
            if r.changed().await.is_err() {
                std::future::pending::<()>().await;
            }
        }));
    }
    if waits.is_empty() {
        std::future::pending::<()>().await;
    }
    futures_util::future::select_all(waits).await;
}
