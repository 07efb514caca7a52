#![cfg(feature = "cam-aravis")]
//! GigE Vision end to end through a real GVCP/GVSP stack: eight `arv-fake-gv-camera-0.8`
//! processes (Debian's aravis-tools) on 127.0.0.2–9 serve the `aravis` backend over loopback,
//! with the cameras of `rigs/lightstage-gige.toml`.
//!
//! Each test starts its own cameras (the tests take turns) and stops them when it ends. Without
//! the tool, without root to add the loopback addresses, or outside a network namespace with
//! only loopback (aravis's discovery broadcasts on every interface that is up), a test prints
//! why and passes, unless `STAGEHAND_REQUIRE_PEERS=1`, which makes it fail with the reason.
//! `.ci/gige.sh` runs them in such a namespace (`unshare --net`).
//! No test asserts a duration: waits are bounded by generous deadlines, and the figures of the
//! ignored `measure_eight_cameras` are printed, not checked:
//!
//! ```sh
//! .ci/gige.sh --ignored --nocapture measure_eight_cameras
//! ```
//!
//! `arv-fake-gv-camera-0.8 --gvsp-lost-ratio` counts lost packets per thousand, so 1 % is 10.
//! The fake camera ignores GVCP packet-resend requests, so every frame that lost a packet is lost.

use std::collections::BTreeMap;
use std::net::Ipv4Addr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use stagehand_devices::camera::CameraHandle;
use stagehand_devices::cameras::aravis::{AravisCamera, StreamCounters, StreamStats, gvcp_probe};
use stagehand_devices::cameras::config::TriggerMode;
use stagehand_devices::discover::discover;
use stagehand_devices::rig::{Backend, CameraSpec, load_rig_file};
use stagehand_devices::{DeviceError, DeviceErrorKind, DeviceResult, Frame};

const TOOL: &str = "arv-fake-gv-camera-0.8";
const CAMERAS: usize = 8;
/// 1 % packet loss in the fake camera's unit (packets per thousand).
const ONE_PERCENT: f64 = 10.0;
/// Exposure of every test trigger: the fake camera's ramp is unscaled at 10 ms and GainRaw 0.
const EXPOSURE_S: f64 = 0.01;
/// How long a restarted camera may take to answer (generous: a loaded 2-core machine).
const READY_DEADLINE: Duration = Duration::from_secs(30);

fn address(i: usize) -> Ipv4Addr {
    Ipv4Addr::new(127, 0, 0, 2 + i as u8)
}

fn serial(i: usize) -> String {
    format!("GV{:02}", i + 2)
}

fn device_id(i: usize) -> String {
    format!("Aravis-Fake-{}", serial(i))
}

/// The tests share the addresses, so they take turns.
static TURN: Mutex<()> = Mutex::new(());

/// The environment cannot run the fake cameras: a failure under `STAGEHAND_REQUIRE_PEERS=1`,
/// otherwise a note and a skip.
fn unavailable<T>(why: &str) -> Option<T> {
    if std::env::var("STAGEHAND_REQUIRE_PEERS").is_ok_and(|v| v == "1") {
        panic!("STAGEHAND_REQUIRE_PEERS=1, but the fake GigE cameras cannot run: {why}");
    }
    eprintln!("skipping: {why} (STAGEHAND_REQUIRE_PEERS=1 makes this a failure)");
    None
}

/// Up interfaces other than loopback, with their IPv4 addresses: aravis's discovery (listing,
/// and opening by id or serial) broadcasts on every one of them.
fn other_networks() -> Vec<String> {
    let Ok(out) = Command::new("ip")
        .args(["-4", "-o", "addr", "show", "up"])
        .output()
    else {
        return Vec::new();
    };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (f.len() > 3 && f[1] != "lo").then(|| format!("{} {}", f[1], f[3]))
        })
        .collect()
}

/// Brings `lo` up and adds 127.0.0.2–9 to it where missing (needs root).
fn ensure_addresses() -> Result<(), String> {
    let up = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .output()
        .map_err(|e| format!("cannot run `ip` (iproute2): {e}"))?;
    if !up.status.success() {
        return Err(format!(
            "cannot bring lo up (run as root): {}",
            String::from_utf8_lossy(&up.stderr).trim()
        ));
    }
    let shown = Command::new("ip")
        .args(["-4", "-o", "addr", "show", "dev", "lo"])
        .output()
        .map_err(|e| format!("cannot run `ip` (iproute2): {e}"))?;
    let shown = String::from_utf8_lossy(&shown.stdout).into_owned();
    for i in 0..CAMERAS {
        let a = address(i);
        if shown.contains(&format!("inet {a}/")) {
            continue;
        }
        let out = Command::new("ip")
            .args(["addr", "add", &format!("{a}/8"), "dev", "lo"])
            .output()
            .map_err(|e| format!("cannot run `ip`: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "cannot add {a} to lo (run as root, or add 127.0.0.2-9 first): {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
    }
    Ok(())
}

/// Eight fake GigE cameras, GV02…GV09 on 127.0.0.2–9, stopped on drop.
struct FakeCameras {
    children: Vec<Option<Child>>,
    loss_per_thousand: f64,
    _turn: MutexGuard<'static, ()>,
}

impl FakeCameras {
    /// Starts the cameras with `loss_per_thousand` GVSP packets dropped, once each answers
    /// GVCP; `None` when the environment cannot (see [`unavailable`]).
    fn start(loss_per_thousand: f64) -> Option<Self> {
        let turn = TURN.lock().unwrap_or_else(PoisonError::into_inner);
        let present = Command::new(TOOL)
            .arg("--help")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if !present {
            return unavailable(&format!(
                "`{TOOL}` is not installed (apt-get install aravis-tools)"
            ));
        }
        let others = other_networks();
        if !others.is_empty() && std::env::var("STAGEHAND_GIGE_ANY_NETWORK").is_err() {
            return unavailable(&format!(
                "aravis's discovery would broadcast on {} too; run in a network namespace with \
                 only loopback, as .ci/gige.sh does (unshare --net), or set \
                 STAGEHAND_GIGE_ANY_NETWORK=1 where that traffic is welcome",
                others.join(", ")
            ));
        }
        if let Err(why) = ensure_addresses() {
            return unavailable(&why);
        }
        for i in 0..CAMERAS {
            assert!(
                !gvcp_probe(address(i), Duration::from_millis(200)),
                "something already answers GVCP at {} (a leftover {TOOL}?); stop it first",
                address(i)
            );
        }
        let mut cams = Self {
            children: (0..CAMERAS).map(|_| None).collect(),
            loss_per_thousand,
            _turn: turn,
        };
        for i in 0..CAMERAS {
            cams.launch(i);
        }
        for i in 0..CAMERAS {
            cams.wait_ready(i);
        }
        Some(cams)
    }

    fn launch(&mut self, i: usize) {
        let mut cmd = Command::new(TOOL);
        cmd.args(["-i", &address(i).to_string(), "-s", &serial(i)]);
        if self.loss_per_thousand > 0.0 {
            cmd.args(["-r", &self.loss_per_thousand.to_string()]);
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {TOOL} for {}: {e}", address(i)));
        self.children[i] = Some(child);
    }

    /// Waits until camera `i` answers a GVCP discovery.
    fn wait_ready(&mut self, i: usize) {
        let deadline = Instant::now() + READY_DEADLINE;
        while !gvcp_probe(address(i), Duration::from_millis(200)) {
            if let Some(child) = self.children[i].as_mut()
                && let Ok(Some(status)) = child.try_wait()
            {
                panic!("{TOOL} on {} exited: {status}", address(i));
            }
            assert!(
                Instant::now() < deadline,
                "{TOOL} on {} did not answer within {READY_DEADLINE:?}",
                address(i)
            );
        }
    }

    /// Kills camera `i`'s process (SIGKILL), as a power cut or a crash would.
    fn kill(&mut self, i: usize) {
        if let Some(mut child) = self.children[i].take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Starts camera `i` again (same address and serial) and waits until it answers.
    fn restart(&mut self, i: usize) {
        self.kill(i);
        self.launch(i);
        self.wait_ready(i);
    }
}

impl Drop for FakeCameras {
    fn drop(&mut self) {
        for i in 0..CAMERAS {
            self.kill(i);
        }
    }
}

/// The eight cameras of the GigE rig file, in order (cam1 is GV02 …).
fn rig_cameras() -> Vec<CameraSpec> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("rigs/lightstage-gige.toml");
    let rig = load_rig_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(rig.cameras.len(), CAMERAS);
    for (i, c) in rig.cameras.iter().enumerate() {
        assert_eq!(c.port.as_deref(), Some(device_id(i).as_str()), "{}", c.id);
    }
    rig.cameras
}

/// Open cameras with their transport counters.
struct Cameras {
    handles: Vec<CameraHandle>,
    stats: Vec<StreamStats>,
}

impl Cameras {
    fn open(specs: &[CameraSpec]) -> Self {
        let mut handles = Vec::new();
        let mut stats = Vec::new();
        for s in specs {
            let (link, st) = AravisCamera::open_with_stats(s, TriggerMode::Software)
                .unwrap_or_else(|e| panic!("open {}: {e}", s.id));
            handles.push(CameraHandle::spawn(s.clone(), link));
            stats.push(st);
        }
        Self { handles, stats }
    }

    /// Arms every camera, retrying while a camera is still coming back (as the executor's
    /// recovery does), within a generous deadline.
    async fn arm(&self) {
        for h in &self.handles {
            let deadline = Instant::now() + READY_DEADLINE;
            loop {
                match h.set_armed(true).await {
                    Ok(()) => break,
                    Err(e) if e.is_recoverable() && Instant::now() < deadline => {
                        eprintln!("arm {}: {e}; retrying", h.id());
                        tokio::time::sleep(Duration::from_millis(500)).await;
                    }
                    Err(e) => panic!("arm {}: {e}", h.id()),
                }
            }
        }
    }

    /// Disarms every camera. A camera whose link just failed may still be busy with the
    /// library's retries (seconds), so a timeout is retried within a generous deadline.
    async fn disarm(&self) {
        for h in &self.handles {
            let deadline = Instant::now() + READY_DEADLINE;
            loop {
                match h.set_armed(false).await {
                    Ok(()) => break,
                    Err(
                        e @ DeviceError {
                            kind: DeviceErrorKind::Timeout { .. },
                            ..
                        },
                    ) if Instant::now() < deadline => {
                        eprintln!("disarm {}: {e}; retrying", h.id());
                    }
                    Err(e) => panic!("disarm {}: {e}", h.id()),
                }
            }
        }
    }

    async fn configure(&self, exposure_s: f64, gain: f64) {
        for h in &self.handles {
            h.configure(exposure_s, gain)
                .await
                .unwrap_or_else(|e| panic!("configure {}: {e}", h.id()));
        }
    }

    /// Fires trigger `id` the way the executor does (announce it on every camera, then collect
    /// every camera's frame) and returns each camera's outcome.
    async fn shoot(&self, id: u64) -> Vec<DeviceResult<Frame>> {
        let mut out: Vec<Option<DeviceResult<Frame>>> =
            (0..self.handles.len()).map(|_| None).collect();
        for (i, h) in self.handles.iter().enumerate() {
            if let Err(e) = h.expect(id, EXPOSURE_S).await {
                out[i] = Some(Err(e));
            }
        }
        let mut tasks = Vec::new();
        for (i, h) in self.handles.iter().enumerate() {
            if out[i].is_none() {
                let h = h.clone();
                tasks.push((
                    i,
                    tokio::spawn(async move { h.frame_for(id, EXPOSURE_S).await }),
                ));
            }
        }
        for (i, t) in tasks {
            out[i] = Some(t.await.expect("frame task"));
        }
        out.into_iter()
            .map(|o| o.expect("every camera answered"))
            .collect()
    }

    fn counters(&self) -> Vec<StreamCounters> {
        self.stats.iter().map(StreamStats::snapshot).collect()
    }
}

/// Paces triggers at the rig's rate: at most one per `period`.
struct Pace {
    period: Duration,
    next: Instant,
}

impl Pace {
    fn new(fps: f64) -> Self {
        Self {
            period: Duration::from_secs_f64(1.0 / fps),
            next: Instant::now(),
        }
    }

    async fn wait(&mut self) {
        tokio::time::sleep_until(self.next.into()).await;
        self.next = (self.next + self.period).max(Instant::now());
    }
}

/// Checks every pixel of a delivered frame against the fake camera's diagonal ramp for the
/// frame's own id, scaled by the gain and exposure the camera reported: a corrupt, partial or
/// misattributed frame fails here.
fn check_pixels(f: &Frame) {
    let sequence = f.notes["sequence"].as_u64().expect("sequence in notes");
    // GigE block ids 1..=65535 are counted from 0 by the driver.
    let frame_id = sequence + 1;
    let cam = &f.notes["camera"];
    let exposure_us = cam["exposure_us"].as_f64().expect("exposure read back");
    let gain_raw = cam["gain"].as_f64().expect("gain read back");
    let scale = 1.0 + gain_raw + (exposure_us / 10_000.0).log10();
    let (w, h) = (f.width as u64, f.height as u64);
    assert_eq!(f.pixels.len() as u64, w * h * 3, "{}: frame size", f.camera);
    assert_eq!(f.bit_depth, 8);
    for (i, px) in f.pixels.chunks_exact(3).enumerate() {
        let (x, y) = (i as u64 % w, i as u64 / w);
        let want = (((x + y + frame_id) % 255) as f64 * scale).clamp(0.0, 255.0) as u16;
        if px != [want; 3] {
            panic!(
                "{} trigger {}: pixel ({x},{y}) is {px:?}, the ramp of frame id {frame_id} has {want}",
                f.camera, f.trigger_id
            );
        }
    }
}

/// Frames per camera per trigger id, and the errors.
struct Tally {
    frames: Vec<BTreeMap<u64, u32>>,
    missing: Vec<Vec<u64>>,
    /// Check every pixel (off while measuring rates: the check costs more than a frame).
    pixels: bool,
}

impl Tally {
    fn new() -> Self {
        Self {
            frames: vec![BTreeMap::new(); CAMERAS],
            missing: vec![Vec::new(); CAMERAS],
            pixels: true,
        }
    }

    /// Records one trigger's outcomes: frames must answer `id` with intact pixels; the only
    /// error allowed is a missing frame naming that camera and trigger.
    fn record(&mut self, ids: &[String], id: u64, outcomes: Vec<DeviceResult<Frame>>) {
        for (i, r) in outcomes.into_iter().enumerate() {
            match r {
                Ok(f) => {
                    assert_eq!(f.trigger_id, id, "{}", ids[i]);
                    assert_eq!(f.camera, ids[i]);
                    if self.pixels {
                        check_pixels(&f);
                    }
                    *self.frames[i].entry(id).or_default() += 1;
                }
                Err(DeviceError {
                    device,
                    kind: DeviceErrorKind::MissingFrame { trigger_id, .. },
                }) => {
                    assert_eq!((device.as_str(), trigger_id), (ids[i].as_str(), id));
                    self.missing[i].push(id);
                }
                Err(e) => panic!("{} trigger {id}: unexpected error {e}", ids[i]),
            }
        }
    }

    fn lost(&self) -> usize {
        self.missing.iter().map(Vec::len).sum()
    }

    fn delivered(&self) -> u32 {
        self.frames.iter().flat_map(|m| m.values()).sum()
    }
}

fn ids(specs: &[CameraSpec]) -> Vec<String> {
    specs.iter().map(|s| s.id.clone()).collect()
}

#[test]
fn discovery_lists_every_fake_camera_with_a_rig_snippet() {
    let Some(_cams) = FakeCameras::start(0.0) else {
        return;
    };
    let found = discover().cameras;
    for i in 0..CAMERAS {
        let (id, addr, sn) = (device_id(i), address(i).to_string(), serial(i));
        let entry = found
            .iter()
            .find(|c| c.backend == Backend::Aravis && c.path == id)
            .unwrap_or_else(|| panic!("{id} not discovered; found {found:#?}"));
        assert!(
            entry.name.contains(&addr) && entry.name.contains(&sn),
            "{entry:?}"
        );
        for part in [
            "[[camera]]",
            "backend = \"aravis\"",
            &format!("port = \"{id}\""),
            &addr,
            &sn,
        ] {
            assert!(entry.rig_snippet.contains(part), "{part}: {entry:?}");
        }
    }
}

/// A camera opens by address, by serial and by id; trigger, exposure and gain are read back
/// and take effect (the fake camera scales its ramp by them); an unknown port is a typed error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn opens_by_address_serial_and_id_and_reads_settings_back() {
    let Some(_cams) = FakeCameras::start(0.0) else {
        return;
    };
    let mut specs: Vec<CameraSpec> = rig_cameras().into_iter().take(3).collect();
    specs[0].port = Some(address(0).to_string());
    specs[1].port = Some(serial(1));
    specs[2].port = Some(device_id(2));
    let cams = Cameras::open(&specs);
    // 20 ms and gain 3: ExposureTimeAbs 20000 µs, GainRaw 2 (max_gain 11 over GainRaw 0..10).
    cams.configure(0.02, 3.0).await;
    cams.arm().await;
    let outcomes = cams.shoot(7).await;
    for (i, r) in outcomes.into_iter().enumerate() {
        let f = r.unwrap_or_else(|e| panic!("{}: {e}", specs[i].id));
        let cam = &f.notes["camera"];
        assert_eq!(cam["exposure_feature"], "ExposureTimeAbs");
        assert_eq!(cam["exposure_us"], 20_000.0);
        assert_eq!(cam["gain_feature"], "GainRaw");
        assert_eq!(cam["gain"], 2.0);
        assert_eq!(cam["trigger_selector"], "FrameStart");
        assert_eq!(cam["trigger_mode"], "On");
        assert_eq!(cam["trigger_source"], "Software");
        assert_eq!((f.width, f.height, f.trigger_id), (512, 512, 7));
        check_pixels(&f);
    }
    cams.disarm().await;

    let mut nowhere = specs[0].clone();
    nowhere.id = "cam9".into();
    nowhere.port = Some("GV99".into());
    match AravisCamera::open(&nowhere, TriggerMode::Software) {
        Err(DeviceError {
            device,
            kind: DeviceErrorKind::PortUnavailable { port, .. },
        }) => {
            assert_eq!((device.as_str(), port.as_str()), ("cam9", "GV99"));
        }
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("GV99 does not exist"),
    }
}

/// Eight cameras at the rig's rate: N triggers give exactly N frames per camera, each id once,
/// each frame intact; nothing lost at 0 % packet loss.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_cameras_give_one_frame_per_trigger_at_the_rig_rate() {
    let Some(_fakes) = FakeCameras::start(0.0) else {
        return;
    };
    let specs = rig_cameras();
    let names = ids(&specs);
    let cams = Cameras::open(&specs);
    cams.configure(EXPOSURE_S, 1.0).await;
    cams.arm().await;
    let n = 45u64;
    let mut pace = Pace::new(specs[0].fps);
    let mut tally = Tally::new();
    for id in 1..=n {
        pace.wait().await;
        let outcomes = cams.shoot(id).await;
        tally.record(&names, id, outcomes);
    }
    cams.disarm().await;
    assert_eq!(tally.lost(), 0, "frames lost at 0 %: {:?}", tally.missing);
    for (i, frames) in tally.frames.iter().enumerate() {
        let want: BTreeMap<u64, u32> = (1..=n).map(|id| (id, 1)).collect();
        assert_eq!(frames, &want, "{}", names[i]);
    }
    for (i, c) in cams.counters().iter().enumerate() {
        assert_eq!(c.completed_frames, n, "{}: {c:?}", names[i]);
        assert_eq!(c.reopens, 0, "{}: {c:?}", names[i]);
    }
}

/// A camera process killed mid-run: its frame is a missing-frame error naming it; once the
/// process is back the driver reopens the camera and the retaken trigger and every later one
/// have exactly one frame on every camera.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_camera_is_a_missing_frame_then_recovers() {
    let Some(mut fakes) = FakeCameras::start(0.0) else {
        return;
    };
    let specs = rig_cameras();
    let names = ids(&specs);
    let cams = Cameras::open(&specs);
    cams.configure(EXPOSURE_S, 1.0).await;
    cams.arm().await;
    let victim = 3;
    let (before, after) = (10u64, 20u64);
    let mut pace = Pace::new(specs[0].fps);
    let mut tally = Tally::new();
    for id in 1..=before {
        pace.wait().await;
        tally.record(&names, id, cams.shoot(id).await);
    }
    fakes.kill(victim);
    // The step's trigger: the killed camera's frame is missing; the others are unaffected.
    let failed_id = before + 1;
    let outcomes = cams.shoot(failed_id).await;
    for (i, r) in outcomes.iter().enumerate() {
        match (i == victim, r) {
            (
                true,
                Err(DeviceError {
                    device,
                    kind: DeviceErrorKind::MissingFrame { trigger_id, .. },
                }),
            ) => {
                assert_eq!(
                    (device.as_str(), *trigger_id),
                    (names[i].as_str(), failed_id)
                );
            }
            (true, other) => panic!("{}: expected a missing frame, got {other:?}", names[i]),
            (false, Ok(f)) => assert_eq!(f.trigger_id, failed_id),
            (false, Err(e)) => panic!("{}: {e}", names[i]),
        }
    }
    // What the executor does: disarm, wait for the device, take the step again.
    cams.disarm().await;
    fakes.restart(victim);
    cams.arm().await;
    cams.configure(EXPOSURE_S, 1.0).await;
    for id in failed_id..=after {
        pace.wait().await;
        tally.record(&names, id, cams.shoot(id).await);
    }
    cams.disarm().await;
    assert_eq!(tally.lost(), 0, "{:?}", tally.missing);
    for (i, frames) in tally.frames.iter().enumerate() {
        let want: BTreeMap<u64, u32> = (1..=after).map(|id| (id, 1)).collect();
        assert_eq!(frames, &want, "{}", names[i]);
    }
    let counters = cams.counters();
    for (i, c) in counters.iter().enumerate() {
        assert_eq!(c.reopens, u64::from(i == victim), "{}: {c:?}", names[i]);
    }
}

/// 1 % of GVSP packets lost: every trigger ends as an intact frame or a missing-frame error
/// naming the camera and the trigger, never a corrupt frame; the stream counts the packets.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lost_packets_are_missing_frames_never_corrupt_ones() {
    let Some(_fakes) = FakeCameras::start(ONE_PERCENT) else {
        return;
    };
    let specs = rig_cameras();
    let names = ids(&specs);
    let cams = Cameras::open(&specs);
    cams.configure(EXPOSURE_S, 1.0).await;
    cams.arm().await;
    let n = 30u64;
    let mut pace = Pace::new(specs[0].fps);
    let mut tally = Tally::new();
    for id in 1..=n {
        pace.wait().await;
        tally.record(&names, id, cams.shoot(id).await);
    }
    cams.disarm().await;
    let counters = cams.counters();
    for (i, name) in names.iter().enumerate() {
        let frames: u32 = tally.frames[i].values().sum();
        assert!(tally.frames[i].values().all(|&k| k == 1), "{name}");
        assert_eq!(
            u64::from(frames) + tally.missing[i].len() as u64,
            n,
            "{name}: every trigger is a frame or an error",
        );
    }
    // Not one count per lost trigger: a frame whose leader was lost can come out of aravis as
    // more than one partial buffer (seen once: 28 incomplete buffers for 26 lost triggers).
    // What matters is above: every trigger is an intact frame or a typed error.
    let missing_packets: u64 = counters.iter().map(|c| c.missing_packets).sum();
    assert!(missing_packets > 0, "{counters:?}");
    let incomplete: u64 = counters.iter().map(|c| c.incomplete_frames).sum();
    assert!(tally.lost() == 0 || incomplete > 0, "{counters:?}");
    eprintln!(
        "1 % loss: {} of {} frames lost (typed), {} delivered intact; packets missing {missing_packets}, resent {}",
        tally.lost(),
        n * CAMERAS as u64,
        tally.delivered(),
        counters.iter().map(|c| c.resent_packets).sum::<u64>()
    );
}

/// Figures for 8 cameras at the rig's trigger rate (and unpaced), at 0 % and 1 % packet loss.
/// `STAGEHAND_GIGE_TRIGGERS` sets the triggers per run (default 150).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "measurement: run with --ignored --nocapture"]
async fn measure_eight_cameras() {
    let triggers: u64 = std::env::var("STAGEHAND_GIGE_TRIGGERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(150);
    let specs = rig_cameras();
    let names = ids(&specs);
    let rig_fps = specs[0].fps;
    let mut rows = Vec::new();
    for (loss, rate) in [
        (0.0, Some(rig_fps)),
        (ONE_PERCENT, Some(rig_fps)),
        (0.0, None),
    ] {
        let Some(fakes) = FakeCameras::start(loss) else {
            return;
        };
        let cams = Cameras::open(&specs);
        cams.configure(EXPOSURE_S, 1.0).await;
        cams.arm().await;
        let mut pace = rate.map(Pace::new);
        let mut tally = Tally::new();
        tally.pixels = false;
        let start = Instant::now();
        for id in 1..=triggers {
            if let Some(p) = pace.as_mut() {
                p.wait().await;
            }
            tally.record(&names, id, cams.shoot(id).await);
        }
        let elapsed = start.elapsed().as_secs_f64();
        cams.disarm().await;
        let c = cams.counters();
        let sum = |f: fn(&StreamCounters) -> u64| c.iter().map(f).sum::<u64>();
        let shots = triggers * CAMERAS as u64;
        rows.push(format!(
            "| {:.0} % | {} | {triggers} | {:.1} | {:.1} | {} | {} | {} | {} of {shots} ({:.1} %) |",
            loss / 10.0,
            rate.map_or("unpaced".to_string(), |r| format!("{r} Hz")),
            triggers as f64 / elapsed,
            f64::from(tally.delivered()) / elapsed,
            sum(|c| c.resent_packets),
            sum(|c| c.missing_packets),
            sum(|c| c.incomplete_frames),
            tally.lost(),
            100.0 * tally.lost() as f64 / shots as f64,
        ));
        drop(cams);
        drop(fakes);
    }
    println!(
        "\n8 fake GigE cameras (512×512 Mono8, software trigger), {triggers} triggers per run\n\
         | packet loss | trigger rate | triggers | triggers/s | frames/s (all cameras) | packets resent | packets missing | incomplete frames | frames lost |\n\
         |---|---|---|---|---|---|---|---|---|"
    );
    for r in rows {
        println!("{r}");
    }
}
