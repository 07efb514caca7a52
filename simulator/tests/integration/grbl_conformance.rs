//! Conformance of the GRBL emulator to the real firmware: each exchange (bytes sent, replies
//! awaited) runs on a freshly powered-on real GRBL 1.1h board (`grbl_peer`) and on a fresh
//! emulator set up alike, and both transcripts must be the same, modulo numbers that depend on
//! timing (positions and feed rates while moving, holding or homing). Where they differ, the
//! emulator is wrong.

use crate::grbl_peer;

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use grbl_peer::{Board, Build, FAST, SWITCH_AT};
use serial2_tokio::SerialPort;
use stagehand_devices::clock::RigClock;
use stagehand_devices::rig::{AxisSpec, BUILTIN_LIGHTSTAGE, parse_rig};
use stagehand_simulator::World;
use stagehand_simulator::emulators::grbl::GrblBuild;
use stagehand_simulator::emulators::{Faults, GrblEmulator};

/// One step of an exchange.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// Write these bytes.
    Send(&'static str),
    /// Read until this text arrives; the chunk goes into the transcript.
    Expect(&'static str),
    /// Like `Expect`, with every number masked (the values depend on timing).
    ExpectMasked(&'static str),
    /// Read for this long: whatever arrives goes into the transcript (usually nothing).
    Silence(f64),
    /// Wait this long without reading.
    Sleep(f64),
    /// Close the port and open it again, as a host reconnecting.
    Reopen,
}

use Step::*;

struct Exchange {
    name: &'static str,
    build: Build,
    /// Whether the boards accelerate at [`FAST`]: the exchanges are about the protocol, and
    /// homing cycles and moves then take a fraction of the wall time.
    fast: bool,
    /// Settings after [`SETTINGS`] (and [`FAST`]).
    extra: &'static str,
    steps: &'static [Step],
}

const UNLOCK: &str = "unlock]\r\n";
const OK: &str = "ok\r\n";
const REPORT: &str = ">\r\n";
/// One line (an `ok` or an `error:N`).
const LINE: &str = "\r\n";

/// Reset, then `$X` (power-on with homing enabled is in Alarm).
const UNLOCKED: [Step; 4] = [Send("\x18"), Expect(UNLOCK), Send("$X\n"), Expect(OK)];

const EXCHANGES: &[Exchange] = &[
    Exchange {
        name: "banner, build info, settings and the first reports",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$I\n"),
            Expect(OK),
            Send("$$\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
            Send("G53 G0 X-1\n"),
            Expect(LINE),
            Send("$X\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("$Q\n"),
            Expect(LINE),
            Send("$999=1\n"),
            Expect(LINE),
            Send("$100=-1\n"),
            Expect(LINE),
            Send("G0 Q1\n"),
            Expect(LINE),
            Send("G0 X\n"),
            Expect(LINE),
            Send("$G\n"),
            Expect(OK),
        ],
    },
    Exchange {
        name: "stock build: $H homes every axis, silent until the cycle ends",
        build: Build::Stock,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$I\n"),
            Expect(OK),
            Send("$H\n"),
            Sleep(0.3),
            Send("?"),
            Silence(0.5),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
        ],
    },
    Exchange {
        name: "stock build: $HX is refused and leaves the firmware in Home until a reset",
        build: Build::Stock,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$HX\n"),
            Expect("\r\n"),
            Send("?"),
            Expect(REPORT),
            Send("$X\n"),
            Expect("\r\n"),
            Send("$H\n"),
            Expect("\r\n"),
            Send("$$\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("\x18"),
            Expect(UNLOCK),
            Send("?"),
            Expect(REPORT),
        ],
    },
    Exchange {
        name: "single-axis build: $HX, $HY, $HZ one at a time",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$I\n"),
            Expect(OK),
            Send("$HX\n"),
            Sleep(0.2),
            Send("?"),
            Silence(0.4),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("$HY\n"),
            Expect(OK),
            Send("$HZ\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
        ],
    },
    Exchange {
        name: "moves in machine and work coordinates, $10 and WCO",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$HX\n"),
            Expect(OK),
            Send("$HY\n"),
            Expect(OK),
            Send("$HZ\n"),
            Expect(OK),
            Send("G53 G0 X-10\n"),
            Expect(OK),
            Send("G4 P0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("G10 L2 P1 X5\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("G0 X-20\n"),
            Expect(OK),
            Send("G4 P0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("$10=0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("G53 G0 Y-3.5 Z-2\n"),
            Expect(OK),
            Send("G4 P0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("G91 G0 X-1\n"),
            Expect(OK),
            Send("G4 P0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
        ],
    },
    Exchange {
        name: "feed hold, resume and reset: idle, holding, moving",
        build: Build::SingleAxis,
        // The holds must land mid-move: at FAST the timing of its steps no longer does.
        fast: false,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$HX\n"),
            Expect(OK),
            Send("!"),
            Sleep(0.2),
            Send("?"),
            Expect(REPORT),
            Send("~"),
            Sleep(0.2),
            Send("?"),
            Expect(REPORT),
            Send("G53 G0 X-100\n"),
            Expect(OK),
            Sleep(0.5),
            Send("!"),
            Sleep(1.5),
            Send("?"),
            ExpectMasked(REPORT),
            Send("~"),
            Send("G4 P0\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("G53 G0 X-50\n"),
            Expect(OK),
            Sleep(0.3),
            Send("!"),
            Sleep(1.5),
            Send("\x18"),
            Expect("help]\r\n"),
            Send("?"),
            ExpectMasked(REPORT),
            Send("G53 G0 X-90\n"),
            Expect(OK),
            Sleep(0.3),
            Send("\x18"),
            Expect(UNLOCK),
            Send("?"),
            ExpectMasked(REPORT),
            Send("G53 G0 X-80\n"),
            Expect("\r\n"),
        ],
    },
    Exchange {
        name: "the spindle output with laser mode off and on",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            UNLOCKED[0],
            UNLOCKED[1],
            UNLOCKED[2],
            UNLOCKED[3],
            Send("M3 S1000\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
            Send("M5\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("$32=1\n"),
            Expect(OK),
            Send("M3 S1000\n"),
            Expect(OK),
            Send("?"),
            Expect(REPORT),
            Send("?"),
            Expect(REPORT),
            Send("M5\n"),
            Expect(OK),
        ],
    },
    Exchange {
        name: "a target outside the soft limits: ALARM:2, then nothing but a reset",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$HX\n"),
            Expect(OK),
            Send("G53 G0 X5\n"),
            Expect("continue]\r\n"),
            Send("?"),
            Silence(0.4),
            Send("$X\n"),
            Silence(0.3),
            Send("\x18"),
            Expect(UNLOCK),
            Send("?"),
            Expect(REPORT),
        ],
    },
    Exchange {
        name: "a homing switch out of reach: ALARM:9, ok, and a reset",
        build: Build::SingleAxis,
        fast: true,
        extra: "$130=2",
        steps: &[
            Send("\x18"),
            Expect(UNLOCK),
            Send("$HX\n"),
            Expect(UNLOCK),
            Send("?"),
            ExpectMasked(REPORT),
        ],
    },
    Exchange {
        name: "a host that reconnects finds the state kept",
        build: Build::SingleAxis,
        fast: true,
        extra: "",
        steps: &[
            UNLOCKED[0],
            UNLOCKED[1],
            UNLOCKED[2],
            UNLOCKED[3],
            Reopen,
            Send("?"),
            Expect(REPORT),
            Send("\x18"),
            Expect("help]\r\n"),
            Send("?"),
            Expect(REPORT),
        ],
    },
];

/// Masks every number (a run of digits, `.` and `-`) as `#`.
fn mask_numbers(text: &str) -> String {
    let mut out = String::new();
    let mut in_number = false;
    for c in text.chars() {
        if c.is_ascii_digit() || (in_number && c == '.') || c == '-' {
            if !in_number {
                out.push('#');
                in_number = true;
            }
        } else {
            in_number = false;
            out.push(c);
        }
    }
    out
}

/// A chunk with status reports of moving states (Run, Home, Hold, Jog) masked.
fn normalise(chunk: &str, masked: bool) -> String {
    chunk
        .split_inclusive('\n')
        .map(|line| {
            let moving = ["<Run|", "<Home|", "<Hold", "<Jog|"]
                .iter()
                .any(|p| line.starts_with(p));
            if masked || moving {
                mask_numbers(line)
            } else {
                line.to_string()
            }
        })
        .collect()
}

/// Reads and drops whatever the board still prints from its power-on (the `[MSG:...]` after
/// the banner), until it has been quiet for 0.3 s.
async fn settle(port: &SerialPort) {
    let mut buf = [0u8; 512];
    while let Ok(Ok(n)) =
        tokio::time::timeout(Duration::from_millis(300), port.read(&mut buf)).await
    {
        if n == 0 {
            break;
        }
    }
}

fn open(path: &Path) -> SerialPort {
    let port = SerialPort::open(path, 115_200).expect("open the board's port");
    let _ = port.discard_buffers();
    port
}

/// Runs `steps` on the board at `path` and returns the transcript.
async fn transcript(path: &Path, steps: &[Step]) -> Vec<String> {
    let mut port = open(path);
    settle(&port).await;
    let mut got: Vec<u8> = Vec::new();
    let mut out = Vec::new();
    for step in steps {
        match *step {
            Send(text) => {
                port.write_all(text.as_bytes()).await.expect("write");
                out.push(format!("> {text:?}"));
            }
            Expect(token) | ExpectMasked(token) => {
                let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
                let at = loop {
                    if let Some(i) = got.windows(token.len()).position(|w| w == token.as_bytes()) {
                        break i + token.len();
                    }
                    let mut buf = [0u8; 512];
                    match tokio::time::timeout_at(deadline, port.read(&mut buf)).await {
                        Ok(Ok(n)) if n > 0 => got.extend_from_slice(&buf[..n]),
                        other => {
                            out.push(format!(
                                "(no {token:?}: {other:?}; got {:?})",
                                normalise(&String::from_utf8_lossy(&got), true)
                            ));
                            return out;
                        }
                    }
                };
                let chunk: Vec<u8> = got.drain(..at).collect();
                let text = String::from_utf8_lossy(&chunk).into_owned();
                out.push(normalise(&text, matches!(step, ExpectMasked(_))));
            }
            Silence(secs) => {
                let end = tokio::time::Instant::now() + Duration::from_secs_f64(secs);
                let mut buf = [0u8; 512];
                while let Ok(Ok(n)) = tokio::time::timeout_at(end, port.read(&mut buf)).await {
                    got.extend_from_slice(&buf[..n]);
                }
                let text = String::from_utf8_lossy(&got).into_owned();
                out.push(format!("(silence: {:?})", normalise(&text, false)));
            }
            Sleep(secs) => tokio::time::sleep(Duration::from_secs_f64(secs)).await,
            Reopen => {
                drop(port);
                tokio::time::sleep(Duration::from_millis(100)).await;
                port = open(path);
                got.clear();
                out.push("(reopened)".into());
            }
        }
    }
    out
}

/// Axes like the real boards: 142.222 steps/unit, 30 units/s, 60 units/s² (600 if `fast`),
/// the switch [`SWITCH_AT`] units from power-on (home 1 unit, `$27`, before it).
fn emulated_axes(fast: bool) -> (Arc<World>, Vec<AxisSpec>) {
    let mut rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("rig");
    for (a, l) in rig.axes.iter_mut().zip(["X", "Y", "Z"]) {
        a.controller_axis = Some(l.into());
        a.steps_per_deg = 142.222;
        a.speed_deg_s = 30.0;
        a.accel_deg_s2 = if fast { 600.0 } else { 60.0 };
        a.homing_speed_deg_s = 40.0;
        a.min_deg = -1000.0;
        a.max_deg = 1000.0;
        a.home_deg = SWITCH_AT - 1.0;
        a.machine_sign = 1.0;
    }
    let axes = rig.axes.clone();
    let world = World::new(Arc::new(rig), RigClock::starting_at(0.0), 1).expect("world");
    (world, axes)
}

/// The transcript of `ex` on the emulator.
async fn on_emulator(ex: &Exchange) -> Vec<String> {
    let dir = tempfile::tempdir().expect("temp dir");
    let (world, axes) = emulated_axes(ex.fast);
    let build = GrblBuild {
        single_axis_homing: ex.build == Build::SingleAxis,
        settings: grbl_peer::settings(&extra(ex)),
    };
    let h = GrblEmulator::spawn_with(world, &axes, dir.path(), "grbl", Faults::none(), build)
        .expect("spawn emulator");
    transcript(h.path(), ex.steps).await
}

/// The settings of `ex`'s boards after [`SETTINGS`].
fn extra(ex: &Exchange) -> String {
    let fast = if ex.fast { FAST } else { "" };
    format!("{fast} {}", ex.extra)
}

/// Runs one exchange on both and returns a description of the difference, if any.
fn compare(ex: &Exchange) -> Option<Result<(), String>> {
    let board = Board::start(ex.build, &extra(ex))?;
    // Both at once: the exchange takes the same wall time on each.
    let rt = grbl_peer::runtime();
    let (real, emulated) =
        rt.block_on(async { tokio::join!(transcript(&board.link, ex.steps), on_emulator(ex)) });
    // Both waiting in vain for the same reply is no agreement: the exchange expects what the
    // firmware never sends.
    let stalled = real.last().is_some_and(|l| l.starts_with("(no "));
    if real == emulated && !stalled {
        return Some(Ok(()));
    }
    let what = if stalled {
        "waited in vain on the real firmware"
    } else {
        "differs"
    };
    let mut diff = format!("exchange `{}` ({:?}) {what}:\n", ex.name, ex.build);
    for i in 0..real.len().max(emulated.len()) {
        let (r, e) = (real.get(i), emulated.get(i));
        let mark = if r == e { "  " } else { "≠ " };
        diff += &format!("{mark}{i:2} real {r:?}\n     emul {e:?}\n");
    }
    Some(Err(diff))
}

#[test]
fn the_emulator_answers_every_exchange_as_the_real_firmware_does() {
    let _one_at_a_time = grbl_peer::exclusive();
    let mut failures = Vec::new();
    let mut ran = 0;
    for ex in EXCHANGES {
        // grbl-sim now and then loses motion or garbles a report under load (seen in CI: a
        // resumed move ending Idle 5 units short, twice in a row; 256 steps lost on three
        // fresh boards in a row, with a byte garbled in a report; on an idle machine about one
        // feed-hold exchange in five loses them); a difference counts only if four fresh
        // boards show it again. An emulator's difference shows every time.
        let mut outcome = compare(ex);
        for _ in 0..4 {
            let Some(Err(diff)) = &outcome else { break };
            eprintln!("retrying on a fresh board:\n{diff}");
            outcome = compare(ex);
        }
        match outcome {
            None => return, // peer missing (skipped; CI requires it)
            Some(Ok(())) => ran += 1,
            Some(Err(diff)) => failures.push(diff),
        }
    }
    eprintln!(
        "{ran} of {} exchanges identical on GRBL 1.1h and the emulator",
        EXCHANGES.len()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn masking_keeps_words_and_hides_numbers() {
    let _turn = grbl_peer::alongside();
    assert_eq!(
        mask_numbers("<Run|MPos:-12.500,0.000,3.1|FS:1800,0>"),
        "<Run|MPos:#,#,#|FS:#,#>"
    );
    assert_eq!(
        normalise("<Idle|MPos:1.000,0,0>\r\n<Hold:0|MPos:2,0,0>\r\n", false),
        "<Idle|MPos:1.000,0,0>\r\n<Hold:#|MPos:#,#,#>\r\n"
    );
}
