//! The `World`: the simulated rig's state at every instant of the rig clock. Simulated devices
//! change it; simulated cameras render it at trigger time.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

use stagehand_devices::clock::RigClock;
use stagehand_devices::fixture_pose::FixturePose;
use stagehand_devices::motion::Trapezoid;
use stagehand_devices::rig::RigSpec;
use tokio::sync::broadcast;

use crate::render::Renderer;
use crate::render::config::SimSpec;
use crate::render_ahead::RenderAhead;
use crate::world_snapshot::{LaserBeam, WorldSnapshot};

/// One trigger pulse on the simulated trigger line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    pub trigger_id: u64,
    pub rig_time_s: f64,
    /// A pulse on a hardware line (an emulated board's GPIO): it carries no id of its own, so
    /// cameras tag its frame with the id the host announced (`CameraDriver::expect`), as
    /// hardware-triggered cameras do.
    pub hardware: bool,
}

/// Where an axis is: resting, or inside a planned move that started at `start_s`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AxisMotion {
    pub motor_deg: f64,
    /// Load-side offset from the motor caused by backlash after a negative move.
    pub backlash_offset_deg: f64,
    pub homed: bool,
    pub moving: Option<(Trapezoid, f64)>,
}

impl AxisMotion {
    pub(crate) fn motor_at(&self, t: f64) -> f64 {
        match self.moving {
            Some((traj, start)) => traj.position_at(t - start),
            None => self.motor_deg,
        }
    }
}

#[derive(Debug, Clone)]
struct Lamp {
    bank: String,
    channel: u32,
    warmup_s: f64,
    on_since: Option<f64>,
}

#[derive(Debug, Default)]
struct State {
    axes: BTreeMap<String, AxisMotion>,
    lamps: BTreeMap<String, Lamp>,
    laser_on: bool,
    laser_colour_nm: u32,
    laser_mount_deg: f64,
    cart_mm: f64,
    /// Direction (+1/-1) and start (time, position) of a cart run in progress.
    cart_run: Option<(f64, f64, f64)>,
    fixture: String,
    fixture_pose: FixturePose,
    exposing_until_s: f64,
    violations: Vec<String>,
    /// Frames each camera must still drop (fault injection, see [`World::stall_camera`]).
    stalled_frames: BTreeMap<String, u32>,
    /// Id of the last pulse sent, so an unannounced hardware pulse still gets a fresh id.
    last_pulse_id: u64,
}

/// The simulated rig shared by every simulated device.
pub struct World {
    rig: Arc<RigSpec>,
    clock: RigClock,
    seed: u64,
    state: Mutex<State>,
    pulses: broadcast::Sender<Pulse>,
    renderer: Renderer,
    /// The worker tracing the settled world ahead of its frames (real-time rigs only).
    ahead: OnceLock<RenderAhead>,
}

impl World {
    /// A powered-on rig: axes at 0° and not homed, everything off, the rig's sample on the stage.
    pub fn new(
        rig: Arc<RigSpec>,
        clock: RigClock,
        seed: u64,
    ) -> Result<Arc<World>, crate::render::RenderError> {
        let renderer = Renderer::new(&rig)?;
        let mut state = State {
            fixture: renderer.sim().sample.clone(),
            ..State::default()
        };
        for a in &rig.axes {
            state.axes.insert(
                a.id.clone(),
                AxisMotion {
                    motor_deg: 0.0,
                    backlash_offset_deg: 0.0,
                    homed: false,
                    moving: None,
                },
            );
        }
        for l in &rig.lamps {
            state.lamps.insert(
                l.id.clone(),
                Lamp {
                    bank: l.bank.clone(),
                    channel: l.channel,
                    warmup_s: l.warmup_s,
                    on_since: None,
                },
            );
        }
        if let Some(l) = &rig.laser {
            state.laser_colour_nm = l.fitted_nm;
            state.laser_mount_deg = l.mount_elevation_deg;
        }
        let (pulses, _) = broadcast::channel(64);
        Ok(Arc::new(World {
            rig,
            clock,
            seed,
            state: Mutex::new(state),
            pulses,
            renderer,
            ahead: OnceLock::new(),
        }))
    }

    /// Renders ahead (`on`) or stops: while the rig settles, a worker thread traces what every
    /// camera will see once it has (`crate::render_ahead`). For a rig on the real-time clock
    /// (the daemon, while a run drives it), whose frames would otherwise render after their
    /// exposure.
    pub fn set_render_ahead(self: &Arc<World>, on: bool) -> std::io::Result<()> {
        if on && self.ahead.get().is_none() {
            let worker = RenderAhead::start(Arc::downgrade(self))?;
            // A second caller racing this one keeps the first worker; this one stops.
            let _ = self.ahead.set(worker);
        }
        if let Some(ahead) = self.ahead.get() {
            ahead.set_on(on);
        }
        Ok(())
    }

    /// Something changed that the cameras will see once the rig settles.
    pub(crate) fn settling(&self) {
        if let Some(ahead) = self.ahead.get() {
            ahead.changed();
        }
    }

    /// Blocks until the render-ahead worker has traced every change so far (for tests;
    /// returns at once without one).
    pub fn wait_render_ahead(&self) {
        if let Some(ahead) = self.ahead.get() {
            ahead.wait_idle();
        }
    }

    pub fn rig(&self) -> &RigSpec {
        &self.rig
    }

    /// The rig's `[sim]` settings (sample, quality, ground truth).
    pub fn sim(&self) -> &SimSpec {
        self.renderer.sim()
    }

    pub fn clock(&self) -> RigClock {
        self.clock
    }

    /// Seed of the sensor noise; frames are a pure function of (seed, trigger id, state).
    pub fn seed(&self) -> u64 {
        self.seed
    }

    pub fn renderer(&self) -> &Renderer {
        &self.renderer
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock cannot leave the state half-written in a way that
        // matters more than stopping; recover the guard rather than propagate the poison.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub(crate) fn with_axis<R>(&self, id: &str, f: impl FnOnce(&mut AxisMotion) -> R) -> Option<R> {
        self.lock().axes.get_mut(id).map(f)
    }

    /// True while any camera is exposing at rig time `t`.
    pub fn exposing_at(&self, t: f64) -> bool {
        t < self.lock().exposing_until_s
    }

    /// Records that a camera exposes until `until_s`; a move starting before then is a violation.
    pub(crate) fn begin_exposure(&self, start_s: f64, until_s: f64) {
        let mut s = self.lock();
        if let Some((id, _)) = s
            .axes
            .iter()
            .find(|(_, a)| matches!(a.moving, Some((traj, t0)) if t0 + traj.duration_s() > start_s))
        {
            let msg = format!(
                "axis `{id}` was moving when an exposure started at rig time {start_s:.3} s"
            );
            s.violations.push(msg);
        }
        s.exposing_until_s = s.exposing_until_s.max(until_s);
    }

    /// Starts an exposure window as a camera would (for tests of the motion interlock).
    pub fn begin_exposure_for_test(&self, start_s: f64, until_s: f64) {
        self.begin_exposure(start_s, until_s);
    }

    /// Records a safety violation observed by a simulated device.
    pub(crate) fn violation(&self, message: String) {
        self.lock().violations.push(message);
    }

    /// Every safety violation the simulated devices observed (motion during exposure, ...).
    pub fn violations(&self) -> Vec<String> {
        self.lock().violations.clone()
    }

    pub(crate) fn set_channel(&self, bank: &str, channel: u32, on: bool, t: f64) {
        let mut s = self.lock();
        for lamp in s
            .lamps
            .values_mut()
            .filter(|l| l.bank == bank && l.channel == channel)
        {
            lamp.on_since = match (on, lamp.on_since) {
                (true, Some(since)) => Some(since),
                (true, None) => Some(t),
                (false, _) => None,
            };
        }
        drop(s);
        self.settling();
    }

    pub(crate) fn channel_on(&self, bank: &str, channel: u32) -> Option<bool> {
        let s = self.lock();
        s.lamps
            .values()
            .find(|l| l.bank == bank && l.channel == channel)
            .map(|l| l.on_since.is_some())
    }

    pub(crate) fn set_laser(&self, on: bool, colour_nm: u32) {
        let mut s = self.lock();
        s.laser_on = on;
        s.laser_colour_nm = colour_nm;
        drop(s);
        self.settling();
    }

    pub(crate) fn fit_laser(&self, colour_nm: u32, mount_deg: f64) {
        let mut s = self.lock();
        s.laser_colour_nm = colour_nm;
        s.laser_mount_deg = mount_deg;
        drop(s);
        self.settling();
    }

    /// The operator placed `fixture` on the stage, as `pose` says.
    pub fn place_fixture(&self, fixture: &str, pose: FixturePose) {
        let mut s = self.lock();
        s.fixture = fixture.to_string();
        s.fixture_pose = pose;
        drop(s);
        self.settling();
    }

    /// What lies on the stage now, and how it was placed.
    pub fn fixture(&self) -> (String, FixturePose) {
        let s = self.lock();
        (s.fixture.clone(), s.fixture_pose)
    }

    pub(crate) fn cart_drive(&self, direction: f64, t: f64) {
        let mut s = self.lock();
        let speed = self.rig.cart.as_ref().map(|c| c.speed_mm_s).unwrap_or(0.0);
        let travel = self.rig.cart.as_ref().map(|c| c.travel_mm).unwrap_or(0.0);
        if let Some((dir, t0, p0)) = s.cart_run.take() {
            s.cart_mm = (p0 + dir * speed * (t - t0)).clamp(0.0, travel);
        }
        if direction != 0.0 {
            let p = s.cart_mm;
            s.cart_run = Some((direction, t, p));
        }
    }

    fn cart_at(s: &State, rig: &RigSpec, t: f64) -> f64 {
        let (speed, travel) = rig
            .cart
            .as_ref()
            .map(|c| (c.speed_mm_s, c.travel_mm))
            .unwrap_or((0.0, 0.0));
        match s.cart_run {
            Some((dir, t0, p0)) => (p0 + dir * speed * (t - t0)).clamp(0.0, travel),
            None => s.cart_mm,
        }
    }

    pub(crate) fn pulse(&self, trigger_id: u64, t: f64) {
        self.send_pulse(trigger_id, t, false);
    }

    fn send_pulse(&self, trigger_id: u64, t: f64, hardware: bool) {
        self.lock().last_pulse_id = trigger_id;
        // No camera armed is not an error for the line itself; the executor accounts frames.
        let _ = self.pulses.send(Pulse {
            trigger_id,
            rig_time_s: t,
            hardware,
        });
    }

    /// A pulse on the hardware trigger line at rig time `t` (a rising edge seen by an emulated
    /// board). The line carries no id: the pulse gets the id after the last one, and cameras
    /// tag its frame with the id the host announced to them.
    pub fn pulse_hardware(&self, t: f64) {
        let id = self.lock().last_pulse_id.wrapping_add(1);
        self.send_pulse(id, t, true);
    }

    /// Fault injection: camera `camera` sees its next `frames` trigger pulses but delivers no
    /// frame for them (a stalled camera), so the host's frame accounting must notice.
    pub fn stall_camera(&self, camera: &str, frames: u32) {
        *self
            .lock()
            .stalled_frames
            .entry(camera.to_string())
            .or_insert(0) += frames;
    }

    /// True (and one fewer frame left to drop) if `camera` must drop its current frame.
    pub(crate) fn take_stalled_frame(&self, camera: &str) -> bool {
        let mut s = self.lock();
        match s.stalled_frames.get_mut(camera) {
            Some(n) if *n > 0 => {
                *n -= 1;
                true
            }
            _ => false,
        }
    }

    /// Wavelength of the laser module currently fitted (emulated boards switch it on and off).
    pub(crate) fn laser_colour_nm(&self) -> u32 {
        self.lock().laser_colour_nm
    }

    /// Trigger pulses for a simulated camera: it listens while armed.
    pub(crate) fn subscribe(&self) -> broadcast::Receiver<Pulse> {
        self.pulses.subscribe()
    }

    /// How many simulated cameras are armed (listening for trigger pulses): a run that ends,
    /// however it ends, leaves none.
    pub fn armed_cameras(&self) -> usize {
        self.pulses.receiver_count()
    }

    /// The rig's state at rig time `t` (for rendering and for tests).
    pub fn snapshot_at(&self, t: f64) -> WorldSnapshot {
        let s = self.lock();
        let axes = s
            .axes
            .iter()
            .map(|(id, a)| (id.clone(), a.motor_at(t) + a.backlash_offset_deg))
            .collect();
        let lamps = s
            .lamps
            .iter()
            .map(|(id, l)| {
                let since = l.on_since.map(|since| t - since);
                (
                    id.clone(),
                    since.map_or(0.0, |t| warmup_fraction(t, l.warmup_s)),
                )
            })
            .collect();
        self.snapshot_of(&s, t, axes, lamps)
    }

    /// The rig's state once it has settled, if nothing else changes: every axis at its move's
    /// target (with the backlash the move leaves) and every lamp that is on warmed up. `None`
    /// while the cart runs (its frames see it moving).
    pub fn settled_snapshot(&self) -> Option<WorldSnapshot> {
        let t = self.clock.now_s();
        let s = self.lock();
        if s.cart_run.is_some() {
            return None;
        }
        let axes = s
            .axes
            .iter()
            .map(|(id, a)| {
                let at = match a.moving {
                    None => a.motor_deg + a.backlash_offset_deg,
                    Some((traj, _)) => {
                        let backlash = self.rig.axis(id).map_or(0.0, |spec| spec.backlash_deg);
                        let offset = if traj.to_deg < traj.from_deg {
                            backlash
                        } else if traj.to_deg > traj.from_deg {
                            0.0
                        } else {
                            a.backlash_offset_deg
                        };
                        traj.to_deg + offset
                    }
                };
                (id.clone(), at)
            })
            .collect();
        let lamps = s
            .lamps
            .iter()
            .map(|(id, l)| (id.clone(), if l.on_since.is_some() { 1.0 } else { 0.0 }))
            .collect();
        Some(self.snapshot_of(&s, t, axes, lamps))
    }

    /// The snapshot of state `s` at `t` with these axis angles and lamp outputs.
    fn snapshot_of(
        &self,
        s: &State,
        t: f64,
        axes: BTreeMap<String, f64>,
        lamps: BTreeMap<String, f64>,
    ) -> WorldSnapshot {
        let laser = match (&self.rig.laser, s.laser_on) {
            (Some(spec), true) => Some(LaserBeam {
                colour_nm: s.laser_colour_nm,
                tilt_deg: axes.get(&spec.tilt_axis).copied().unwrap_or(0.0),
                mount_elevation_deg: s.laser_mount_deg,
            }),
            _ => None,
        };
        WorldSnapshot {
            rig_time_s: t,
            axes,
            lamps,
            laser,
            cart_mm: Self::cart_at(s, &self.rig, t),
            fixture: s.fixture.clone(),
            fixture_pose: s.fixture_pose,
        }
    }
}

/// Output of a lamp `t` seconds after switch-on as a fraction of steady state: a cubic ramp
/// that reaches exactly 1 at `warmup_s`, so a capture that waits out the warm-up sees the same
/// light whenever the lamp was switched on.
pub fn warmup_fraction(t: f64, warmup_s: f64) -> f64 {
    if warmup_s <= 0.0 || t >= warmup_s {
        return 1.0;
    }
    if t <= 0.0 {
        return 0.0;
    }
    let r = 1.0 - t / warmup_s;
    1.0 - r * r * r
}
