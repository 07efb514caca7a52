//! The connection to one GRBL 1.1 controller, shared by every axis (and the laser) that names
//! its port.
//!
//! The connection is a [`SerialLink`] behind an async mutex that is taken per exchange (one
//! line and its `ok`, one `?` and its report), never for a whole move, so a second axis can
//! queue its move while the first one moves, and a keepalive can poll while everyone waits.
//! Every line received is absorbed into the known state (replies matched to lines by the flow
//! counter, the last status, alarms, resets), whoever happens to read it.
//!
//! **Homing is exclusive.** Real GRBL answers nothing (not even `?`) during a homing cycle, so
//! a homing cycle holds the activity lock for writing: other requests wait for it, the
//! keepalive skips, and only one homing command is ever in flight. A stock build homes with
//! `$H` (every axis, in the firmware's cycles); a build with single-axis homing (`$I` option
//! `H`) homes one axis with `$HX`. Silence is bounded by a timeout derived from `$13x`,
//! `$24`, `$25` and `$27`.
//!
//! **Machine coordinates.** Moves are `G53 G0` to machine coordinates, so work offsets on the
//! board do not matter; `WPos` reports are turned into machine positions with the last `WCO`.
//! Rig degrees map onto machine coordinates through the rig file's `home_deg` and
//! `machine_sign` ([`MachineMap`]); settings that cannot work for the rig are refused at
//! connect ([`settings::problems`]).
//!
//! **No frame at an unverified position.** The controller's position is trusted only after the
//! axis was homed on the current connection. Connecting (the first use, and every reconnect
//! after a lost link, a timeout or garbage) soft-resets the controller and marks every axis not
//! homed, so a move fails with `NotHomed` until the axis is homed again; so do an `ALARM:N`, a
//! status in state `Alarm` and a reset we did not ask for. Our own stop (feed hold, then reset
//! in `Hold:0`) keeps the position, as GRBL does.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Weak};

use tokio::sync::{Mutex, MutexGuard, RwLock};
use tokio::time::Instant;

use super::codec::{Command, Realtime, State, Status, axis_index};
use super::conn::{Conn, ResetCause, SLICE_S};
use super::settings::BuildInfo;
use crate::clock::duration_s;
use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::motion::move_duration_s;
use crate::rig::AxisSpec;
use crate::serial_link::{SerialLink, TransportOpener};

/// How far a move's deadline is pushed out each time the controller is seen moving.
const MOVE_PROGRESS_S: f64 = 5.0;
/// Interval of status polls while a move or a feed hold runs (GRBL's documentation asks for
/// no more than 5–10 Hz); concurrent waits share a report this fresh.
const POLL_S: f64 = 0.1;

/// How many deceleration times a stop waits for a hold that is visibly slowing the axes before
/// it resets anyway.
const HOLD_GRACE: f64 = 4.0;
/// Polls in a row reporting Idle away from the target before a move is declared lost.
const IDLE_AWAY_POLLS: u32 = 10;
/// Keepalive period: notices a dead port while nobody talks.
const KEEPALIVE_S: f64 = 0.5;
/// Status reports to wait for one carrying `Ov:` (GRBL sends it at least every 20).
const OV_REPORTS: u32 = 25;

/// One GRBL controller on one port; see the module docs for the recovery rules.
pub struct GrblController {
    label: String,
    port: String,
    /// Ids of the configured axes and their letters (fixed at construction).
    axes: Vec<(char, String)>,
    conn: Mutex<Conn>,
    /// Read-held by every request, write-held by a homing cycle (see the module docs).
    activity: RwLock<()>,
    /// A homing line is in flight: a stop must reset instead of polling.
    homing_now: AtomicBool,
    /// A laser is switched by this controller's spindle output (checked against `$32`).
    has_laser: AtomicBool,
    keepalive_enabled: AtomicBool,
    keepalive_started: AtomicBool,
    me: Weak<GrblController>,
}

/// Clears [`GrblController::homing_now`] however the homing future ends.
struct HomingFlag<'a>(&'a AtomicBool);

impl Drop for HomingFlag<'_> {
    fn drop(&mut self) {
        self.0.store(false, Ordering::SeqCst);
    }
}

impl GrblController {
    /// A controller on `port` at `baud` serving `axes` (the axes that name this port; their
    /// `controller_axis` letter and `steps_per_deg` are checked against `$100..$102` on
    /// connect). `device_label` names the controller in errors that concern no single axis.
    /// Nothing is opened until the first request.
    pub fn new(device_label: &str, port: &str, baud: u32, axes: Vec<AxisSpec>) -> Arc<Self> {
        Self::over(SerialLink::new(device_label, port, baud), axes)
    }

    /// Like [`GrblController::new`], over the streams `open` hands it (one per connect) instead
    /// of a serial port; `port` names them in errors. Lets a test run a fake controller on the
    /// other end of `tokio::io::duplex`, on tokio's paused clock.
    pub fn with_transport(
        device_label: &str,
        port: &str,
        open: TransportOpener,
        axes: Vec<AxisSpec>,
    ) -> Arc<Self> {
        Self::over(SerialLink::with_transport(device_label, port, open), axes)
    }

    fn over(link: SerialLink, axes: Vec<AxisSpec>) -> Arc<Self> {
        let device_label = link.device().to_string();
        let port = link.path().to_string();
        let axes: Vec<(char, AxisSpec)> = axes
            .into_iter()
            .filter_map(|a| Some((letter_of(&a)?, a)))
            .collect();
        Arc::new_cyclic(|me| GrblController {
            label: device_label,
            port,
            axes: axes.iter().map(|(l, a)| (*l, a.id.clone())).collect(),
            conn: Mutex::new(Conn::new(link, axes)),
            activity: RwLock::new(()),
            homing_now: AtomicBool::new(false),
            has_laser: AtomicBool::new(false),
            keepalive_enabled: AtomicBool::new(true),
            keepalive_started: AtomicBool::new(false),
            me: me.clone(),
        })
    }

    /// Name of the controller in errors.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Path of the serial port.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// Records that a laser is switched by the spindle output, so laser mode (`$32=1`, which
    /// keeps the output off while idle) is refused at connect.
    pub fn attach_laser(&self) {
        self.has_laser.store(true, Ordering::Relaxed);
    }

    /// Switches the idle keepalive (`?` every 0.5 s while nobody talks) on or off; it is on by
    /// default. Off only for tests that record the exact byte stream.
    pub fn set_keepalive(&self, on: bool) {
        self.keepalive_enabled.store(on, Ordering::Relaxed);
    }

    /// True if the axis with `letter` was homed on the current connection.
    pub async fn is_homed(&self, letter: char) -> bool {
        let c = self.conn.lock().await;
        axis_index(letter).is_some_and(|i| c.ready() && c.homed[i] && !c.in_alarm)
    }

    /// Connects (soft reset, banner, `$I`, `$$` and the rig checks) and returns the board's
    /// build info; a board whose settings cannot work for the rig is `Misconfigured`.
    pub async fn connect(&self) -> DeviceResult<BuildInfo> {
        let _busy = self.activity.read().await;
        let c = self.ready_conn().await?;
        Ok(c.build.clone())
    }

    /// The board's build info (`$I`) as read at the last connect.
    pub async fn build_info(&self) -> BuildInfo {
        self.conn.lock().await.build.clone()
    }

    /// True if `spec` is one of the axes this controller was built with, under its letter.
    pub(crate) fn serves(&self, spec: &AxisSpec, letter: char) -> bool {
        self.axes
            .iter()
            .any(|(l, id)| *l == letter && *id == spec.id)
    }

    /// Reads the status report (`?`), connecting first if needed. Positions are machine
    /// coordinates.
    pub async fn status(&self, device: &str) -> DeviceResult<Status> {
        let r = async {
            let _busy = self.activity.read().await;
            let mut c = self.ready_conn().await?;
            c.query_status().await
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// The rig angle of axis `letter`, read from a fresh status report.
    pub async fn position_deg(&self, device: &str, letter: char) -> DeviceResult<f64> {
        let r = async {
            let idx = index(letter, &self.label)?;
            let _busy = self.activity.read().await;
            let mut c = self.ready_conn().await?;
            let s = c.query_status().await?;
            Ok(c.to_deg(idx, s.pos[idx]))
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// Sends one command line and waits for its `ok` (an `error:N` is `Rejected`).
    pub async fn command(&self, device: &str, cmd: Command, timeout_s: f64) -> DeviceResult<()> {
        let r = async {
            let _busy = self.activity.read().await;
            self.command_inner(&cmd, timeout_s).await
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    async fn command_inner(&self, cmd: &Command, timeout_s: f64) -> DeviceResult<()> {
        let deadline = Instant::now() + duration_s(timeout_s);
        let (seq, epoch, alarms) = {
            let mut c = self.ready_conn().await?;
            let seq = c.send_line(cmd, deadline, timeout_s).await?;
            (seq, c.resets, c.alarm_events)
        };
        self.wait_reply(seq, epoch, alarms, cmd, deadline, timeout_s)
            .await
    }

    /// Switches the spindle output (the laser) with `M3 S<power>` or `M5`, then confirms the
    /// output state from the status reports (`A:S` with `Ov:`, and the `FS:` spindle speed):
    /// a laser that does not follow is [`DeviceErrorKind::LaserNotSwitched`].
    pub async fn switch_spindle(
        &self,
        device: &str,
        on: bool,
        power: u32,
        timeout_s: f64,
    ) -> DeviceResult<()> {
        let r = async {
            let _busy = self.activity.read().await;
            let cmd = if on {
                Command::LaserOn { power }
            } else {
                Command::LaserOff
            };
            self.command_inner(&cmd, timeout_s).await?;
            let mut c = self.ready_conn().await?;
            let seen = c.ov_reports;
            for _ in 0..OV_REPORTS {
                let s = c.query_status().await?;
                if c.ov_reports == seen {
                    continue;
                }
                let output = c.spindle_on.unwrap_or(false);
                let speed = s.spindle_speed.unwrap_or(if output { 1.0 } else { 0.0 });
                if output == on && (speed > 0.0) == on {
                    return Ok(());
                }
                let wanted = if on { "on" } else { "off" };
                return Err(DeviceError::new(device.to_string(), DeviceErrorKind::LaserNotSwitched { wanted, reason: format!(
                        "after `{}` the controller on {} reports the spindle output {} at speed {speed}",
                        cmd.line(),
                        self.port,
                        if output { "on (A:S)" } else { "off" },
                    ) }));
            }
            Err(c.link.protocol(format!(
                "no status report with `Ov:` in {OV_REPORTS} reports after `{}`, so the laser output cannot be verified",
                cmd.line()
            )))
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// Homes the axis `letter` and returns its rig angle afterwards (`home_deg`). A build with
    /// single-axis homing homes only this axis (`$HX`); a stock build homes every axis (`$H`).
    /// An axis homed on this connection and not moved since is already home: nothing is sent.
    pub async fn home(&self, device: &str, letter: char) -> DeviceResult<f64> {
        let r = async {
            let idx = index(letter, &self.label)?;
            let _exclusive = self.activity.write().await;
            let mut c = self.ready_conn().await?;
            if c.homed[idx] && !c.in_alarm && !c.moved_since_home[idx] {
                let s = c.query_status().await?;
                return Ok(c.to_deg(idx, s.pos[idx]));
            }
            let single = c.build.single_axis_homing();
            let mask = if single {
                let mut m = [false; 3];
                m[idx] = true;
                m
            } else {
                [true; 3]
            };
            let cmd = Command::Home(single.then_some(letter));
            let timeout_s = c.settings.homing_bound_s(mask);
            let deadline = Instant::now() + duration_s(timeout_s);
            self.homing_now.store(true, Ordering::SeqCst);
            let _flag = HomingFlag(&self.homing_now);
            let seq = c.send_line(&cmd, deadline, timeout_s).await?;
            let (epoch, alarms) = (c.resets, c.alarm_events);
            drop(c);
            let r = self
                .wait_reply(seq, epoch, alarms, &cmd, deadline, timeout_s)
                .await;
            drop(_flag);
            let mut c = self.conn.lock().await;
            let r = r.and_then(|()| c.check_continuity(epoch, alarms, &cmd));
            if let Err(e) = r {
                return Err(homing_error(e, &cmd, mask, &self.port));
            }
            for (i, on) in mask.iter().enumerate() {
                if *on {
                    c.homed[i] = true;
                    c.moved_since_home[i] = false;
                }
            }
            c.in_alarm = false;
            c.motion_end = None;
            let s = c.query_status().await?;
            if s.state == State::Alarm {
                return Err(c.other(format!(
                    "still in Alarm after `{}`; check the homing switch of axis {letter} and `$22=1`",
                    cmd.line()
                )));
            }
            Ok(c.to_deg(idx, s.pos[idx]))
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// Moves axis `letter` of `spec` to `target_deg` (`G53 G0` to its machine coordinate),
    /// waits until the controller reports Idle at the target, and returns the angle reached.
    /// Fails with `NotHomed` unless the axis was homed on this connection.
    pub async fn move_axis(
        &self,
        device: &str,
        spec: &AxisSpec,
        letter: char,
        target_deg: f64,
    ) -> DeviceResult<f64> {
        let r = async {
            let _busy = self.activity.read().await;
            self.move_inner(device, spec, letter, target_deg).await
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// The error for an alarm raised while a move of axis `idx` was under way: `HardLimit`
    /// with the position for ALARM:1, `Alarm` otherwise.
    async fn alarm_during_move(&self, idx: usize, e: DeviceError) -> DeviceError {
        if !matches!(
            e,
            DeviceError {
                kind: DeviceErrorKind::Alarm { code: 1, .. },
                ..
            }
        ) {
            return e;
        }
        let mut c = self.conn.lock().await;
        // A hard limit is critical: GRBL answers no `?` until a reset, so the last report tells.
        let fresh = if c.critical {
            None
        } else {
            c.query_status().await.ok()
        };
        let pos = fresh.or(c.last_status).map(|s| c.to_deg(idx, s.pos[idx]));
        c.alarm_error(pos)
    }

    async fn move_inner(
        &self,
        device: &str,
        spec: &AxisSpec,
        letter: char,
        target_deg: f64,
    ) -> DeviceResult<f64> {
        let idx = index(letter, &self.label)?;
        if !target_deg.is_finite() {
            return Err(DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Other {
                    message: format!("target {target_deg} is not a number"),
                },
            ));
        }
        // One and a half microsteps, plus the rounding of the 3-decimal report.
        let tolerance = 1.5 / spec.steps_per_deg.max(1e-9) + 0.0005;
        let (cmd, sent, seq, epoch, alarms, deadline, timeout_s) = {
            let mut c = self.ready_conn().await?;
            if !c.homed[idx] || c.in_alarm {
                return Err(DeviceError::new(
                    device.to_string(),
                    DeviceErrorKind::NotHomed,
                ));
            }
            let machine = c.to_machine(idx, target_deg);
            let cmd = Command::Move {
                axis: letter,
                machine,
            };
            let sent = (machine * 1000.0).round() / 1000.0;
            let now = Instant::now();
            let from = c
                .last_status
                .map_or(target_deg, |s| c.to_deg(idx, s.pos[idx]));
            let physics = move_duration_s(from, target_deg, spec.kinematics(), 0.0) * 1.5 + 2.0;
            // Moves of one controller run one after another: ours starts when the queue ends.
            let start = c.motion_end.filter(|t| *t > now).unwrap_or(now);
            let deadline = start + duration_s(physics);
            c.motion_end = Some(deadline);
            let timeout_s = (deadline - now).as_secs_f64();
            c.moved_since_home[idx] = true;
            let seq = c.send_line(&cmd, deadline, timeout_s).await?;
            (
                cmd,
                sent,
                seq,
                c.resets,
                c.alarm_events,
                deadline,
                timeout_s,
            )
        };
        if let Err(e) = self
            .wait_reply(seq, epoch, alarms, &cmd, deadline, timeout_s)
            .await
        {
            return Err(self.alarm_during_move(idx, e).await);
        }
        let mut idle_away = 0;
        // While the controller is visibly moving (an earlier queued move, ours), the wait is
        // extended: the deadline guards against a stalled controller, not a busy one. The
        // axis handle's own timeout (which allows for the other axes) still bounds it.
        let mut deadline = deadline;
        let mut last_pos: Option<[f64; 3]> = None;
        loop {
            let (s, deg) = {
                let mut c = self.conn.lock().await;
                c.check_continuity(epoch, alarms, &cmd)?;
                let s = c.fresh_status(POLL_S).await?;
                let deg = c.to_deg(idx, s.pos[idx]);
                if c.alarm_events != alarms || s.state == State::Alarm {
                    return Err(c.alarm_error(Some(deg)));
                }
                c.check_continuity(epoch, alarms, &cmd)?;
                (s, deg)
            };
            let pos = s.pos[idx];
            if s.state == State::Run && last_pos.is_some_and(|p| p != s.pos) {
                deadline =
                    deadline.max(Instant::now() + duration_s(timeout_s.min(MOVE_PROGRESS_S)));
            }
            last_pos = Some(s.pos);
            if s.state == State::Idle {
                if (pos - sent).abs() <= tolerance {
                    return Ok(deg);
                }
                idle_away += 1;
                if idle_away >= IDLE_AWAY_POLLS {
                    let c = self.conn.lock().await;
                    return Err(c.link.protocol(format!(
                        "controller is Idle at machine {letter}{pos:.3} after `{}`; the move was lost",
                        cmd.line()
                    )));
                }
            } else {
                idle_away = 0;
            }
            if Instant::now() >= deadline {
                return Err(DeviceError::new(
                    device.to_string(),
                    DeviceErrorKind::Timeout {
                        request: cmd.line(),
                        timeout_s,
                    },
                ));
            }
            tokio::time::sleep(duration_s(POLL_S)).await;
        }
    }

    /// Stops all motion of the controller and returns the rig angle of `letter`. Nothing
    /// moving: nothing is sent but `?`. Moving: feed hold, wait until the hold is complete (at
    /// most `decel_timeout_s`), then soft reset (which empties the planner; the position is
    /// kept because the reset comes in `Hold:0`). Homing: soft reset at once (GRBL answers
    /// nothing while it homes; the axes must be homed again).
    pub async fn stop(
        &self,
        device: &str,
        letter: char,
        decel_timeout_s: f64,
    ) -> DeviceResult<f64> {
        let r = async {
            let idx = index(letter, &self.label)?;
            let mut c = self.conn.lock().await;
            if !c.ready() {
                // Connecting soft-resets the controller, which stops it as well.
                drop(c);
                let mut c = self.ready_conn().await?;
                let s = c.query_status().await?;
                return Ok(c.to_deg(idx, s.pos[idx]));
            }
            if self.homing_now.load(Ordering::SeqCst) {
                c.expect_reset = Some(ResetCause::Reconnect);
                c.send_realtime(Realtime::SoftReset).await?;
                c.homed = [false; 3];
                c.await_banner(false).await?;
                let s = c.query_status().await?;
                return Ok(c.to_deg(idx, s.pos[idx]));
            }
            let now = Instant::now();
            let queued = c.motion_end.is_some_and(|t| t > now) || c.flow.lines_in_flight() > 0;
            let s = c.query_status().await?;
            if s.state == State::Idle && !queued {
                return Ok(c.to_deg(idx, s.pos[idx]));
            }
            c.send_realtime(Realtime::FeedHold).await?;
            let start = Instant::now();
            let deadline = start + duration_s(decel_timeout_s);
            // A controller that acknowledged the hold (`Hold:1`) and is still slowing down gets
            // longer: a reset while it decelerates would lose the position. A slow board (or a
            // loaded host running a simulated one) decelerates in more wall time.
            let last_chance = start + duration_s(HOLD_GRACE * decel_timeout_s);
            let mut last: Option<[f64; 3]> = None;
            let mut still = 0;
            loop {
                let s = c.query_status().await?;
                // A hold with nothing moving may stay `Hold:1`: standing still for three polls
                // in a row counts as held (a reset while decelerating would lose the position).
                still = if matches!(s.state, State::Hold(_)) && last == Some(s.pos) {
                    still + 1
                } else {
                    0
                };
                let standing = still >= 3;
                let held = standing
                    || matches!(
                        s.state,
                        State::Hold(0)
                            | State::Idle
                            | State::Alarm
                            | State::Door(_)
                            | State::Sleep
                            | State::Check
                    );
                let now = Instant::now();
                let slowing = matches!(s.state, State::Hold(_)) && last.is_some_and(|p| p != s.pos);
                if held || now >= last_chance || (now >= deadline && !slowing) {
                    break;
                }
                last = Some(s.pos);
                tokio::time::sleep(duration_s(POLL_S)).await;
            }
            c.soft_reset().await?;
            let s = c.query_status().await?;
            Ok(c.to_deg(idx, s.pos[idx]))
        }
        .await;
        r.map_err(|e| named(e, device))
    }

    /// The connection, connected and handshaken (reconnecting if the link was lost).
    async fn ready_conn(&self) -> DeviceResult<MutexGuard<'_, Conn>> {
        let mut c = self.conn.lock().await;
        if !c.ready() {
            c.handshake(self.has_laser.load(Ordering::Relaxed)).await?;
            self.start_keepalive();
        } else if c.critical {
            c.reset_after_critical_alarm().await?;
        }
        Ok(c)
    }

    /// Waits for the reply to line `seq`, releasing the lock between reads.
    async fn wait_reply(
        &self,
        seq: u64,
        epoch: u64,
        alarms: u64,
        cmd: &Command,
        deadline: Instant,
        timeout_s: f64,
    ) -> DeviceResult<()> {
        loop {
            let mut c = self.conn.lock().await;
            if let Some(r) = c.done.remove(&seq) {
                return r.map_err(|code| c.rejected(cmd, code));
            }
            c.check_continuity(epoch, alarms, cmd)?;
            let now = Instant::now();
            if now >= deadline {
                c.absorb_arrived(&cmd.line()).await?;
                if let Some(r) = c.done.remove(&seq) {
                    return r.map_err(|code| c.rejected(cmd, code));
                }
                return Err(c.deaf(&cmd.line(), timeout_s));
            }
            let slice = (deadline - now).as_secs_f64().min(SLICE_S);
            c.pump(slice, &cmd.line()).await?;
        }
    }

    fn start_keepalive(&self) {
        if self.keepalive_started.swap(true, Ordering::Relaxed) {
            return;
        }
        tokio::spawn(keepalive(self.me.clone()));
    }
}

/// Polls `?` every 0.5 s while nobody else talks, so a dead port is noticed (and reconnected on
/// the next request). GRBL has no watchdog: this keeps no laser lease. Ends when the
/// controller is dropped.
async fn keepalive(me: Weak<GrblController>) {
    loop {
        tokio::time::sleep(duration_s(KEEPALIVE_S)).await;
        let Some(ctl) = me.upgrade() else { break };
        if !ctl.keepalive_enabled.load(Ordering::Relaxed) {
            continue;
        }
        // Never during homing: GRBL answers nothing then, and a `?` would look like a dead port.
        let Ok(_busy) = ctl.activity.try_read() else {
            continue;
        };
        if ctl.homing_now.load(Ordering::SeqCst) {
            continue;
        }
        let Ok(mut c) = ctl.conn.try_lock() else {
            continue;
        };
        if c.ready()
            && !c.critical
            && c.last_io.elapsed().as_secs_f64() >= KEEPALIVE_S * 0.9
            && let Err(e) = c.query_status().await
        {
            tracing::warn!("{}: keepalive failed: {e}", ctl.label);
        }
    }
}

/// The controller letter of a GRBL axis (`controller_axis`: one of X, Y, Z).
pub(crate) fn letter_of(spec: &AxisSpec) -> Option<char> {
    let text = spec.controller_axis.as_deref()?.trim();
    let mut chars = text.chars();
    let letter = chars.next()?.to_ascii_uppercase();
    (chars.next().is_none() && axis_index(letter).is_some()).then_some(letter)
}

fn index(letter: char, label: &str) -> DeviceResult<usize> {
    axis_index(letter).ok_or_else(|| {
        DeviceError::new(
            label.to_string(),
            DeviceErrorKind::Other {
                message: format!("`{letter}` is not a GRBL axis letter (X, Y or Z)"),
            },
        )
    })
}

/// A failed homing cycle as [`DeviceErrorKind::HomingFailed`] (for an alarm) saying what to check.
fn homing_error(e: DeviceError, cmd: &Command, mask: [bool; 3], port: &str) -> DeviceError {
    let DeviceError {
        device,
        kind: DeviceErrorKind::Alarm { code, meaning },
    } = e
    else {
        return e;
    };
    let letters: String = super::codec::AXIS_LETTERS
        .iter()
        .zip(mask)
        .filter(|(_, on)| *on)
        .map(|(l, _)| *l)
        .collect();
    let check = match code {
        9 => format!(
            "`{}` on {port} found no switch of axis {letters} within 1.5 × `$13x`: check the switch wiring, `$5` (switch polarity), `$23` (homing direction), `$25` (seek rate) and `$13x` (travel)",
            cmd.line()
        ),
        8 => format!(
            "`{}` on {port}: the switch of axis {letters} stayed pressed after the pull-off: check `$27` (pull-off), `$5` (switch polarity) and the switch wiring",
            cmd.line()
        ),
        6 => format!(
            "`{}` on {port} was interrupted by a reset; home again",
            cmd.line()
        ),
        _ => format!(
            "`{}` on {port}: check the homing switches of axis {letters}, `$5`, `$23` and `$25`",
            cmd.line()
        ),
    };
    DeviceError::new(
        device,
        DeviceErrorKind::HomingFailed {
            code,
            meaning,
            check,
        },
    )
}

/// The same error naming `name` as its device (an axis id instead of the controller).
pub(crate) fn named(e: DeviceError, name: &str) -> DeviceError {
    e.with_device(name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grbl::conn::tests::spec;

    #[test]
    fn axis_letters_are_x_y_or_z() {
        assert_eq!(letter_of(&spec(Some("x"))), Some('X'));
        assert_eq!(letter_of(&spec(Some(" Z "))), Some('Z'));
        assert_eq!(letter_of(&spec(Some("A"))), None);
        assert_eq!(letter_of(&spec(Some("XY"))), None);
        assert_eq!(letter_of(&spec(None)), None);
    }

    #[test]
    fn errors_are_renamed_to_the_axis() {
        let e = named(
            DeviceError::new(
                "grbl",
                DeviceErrorKind::Timeout {
                    request: "?".into(),
                    timeout_s: 1.0,
                },
            ),
            "turntable",
        );
        assert_eq!(e.device(), "turntable");
    }
}
