//! Command-line interface. Exit codes: 0 done, 1 failed or aborted, 2 bad input.

mod calibrate;
mod calibrate_colour;
mod calibrate_geometry;
mod calibrate_laser_planes;
mod calibrate_reflectometer;
mod devices;
mod operator;
mod process;
mod process_dipole;
mod progress;
mod remote;
mod sim;

use std::path::PathBuf;
use std::sync::Arc;

use clap::{Parser, Subcommand};
use tokio::sync::broadcast;

use crate::dry_run::{render_report_with_renderer, renderer_line};
use crate::executor::{AutoConfirm, Operator, RunControl, Summary};
use crate::rig::Emulation;
use crate::rig::RigSource;
use crate::script::{ScriptSource, parse_set};
use crate::session::{self, DEFAULT_RESERVE_BYTES, SessionError, Wiring};

/// stagehand: runs capture scripts on an appearance-capture light stage (or its simulation).
#[derive(Parser, Debug)]
#[command(name = "stagehand", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Real-time priority of the rig's threads (Linux SCHED_FIFO, 1-99; default 10, where the
    /// system allows it), so that paced triggers fire on time while the frame writer keeps the
    /// cores busy; `off` keeps normal scheduling. Needs CAP_SYS_NICE or an RLIMIT_RTPRIO at
    /// least this high (README: "Installing on a lab PC").
    #[arg(long, global = true, value_name = "PRIORITY|off", value_parser = stagehand_devices::realtime::parse_choice)]
    realtime_priority: Option<stagehand_devices::realtime::Choice>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a capture script and write a dataset.
    Run {
        /// Capture script (.rhai).
        script: PathBuf,
        /// Rig: `lightstage` (default, simulated), `reflectometer` (simulated) or a rig TOML file.
        #[arg(long)]
        rig: Option<String>,
        /// Directory that receives the run directory.
        #[arg(long, default_value = "runs")]
        out: PathBuf,
        /// Seed of the simulated sensor noise (default 1; with --remote, the daemon's).
        #[arg(long)]
        seed: Option<u64>,
        /// Override a script parameter: NAME=VALUE (repeatable).
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Confirm every operator prompt automatically.
        #[arg(long, short = 'y')]
        yes: bool,
        /// Free space to keep on the dataset's disk, in MiB.
        #[arg(long, default_value_t = DEFAULT_RESERVE_BYTES >> 20)]
        reserve_mib: u64,
        /// Run the real serial drivers against firmware emulators on pseudo-terminals instead
        /// of the rig's ports, and render the cameras from the simulated world.
        #[arg(long)]
        emulate: bool,
        /// Run on the daemon at URL (`stagehand serve`), which owns the rig: upload the
        /// script, start the run there and follow it here.
        #[arg(long, value_name = "URL", conflicts_with_all = ["rig", "out", "reserve_mib", "emulate"])]
        remote: Option<String>,
        /// The daemon's operator token for --remote (default: $STAGEHAND_TOKEN; it is in
        /// tokens.json in the daemon's data directory).
        #[arg(long, requires = "remote")]
        token: Option<String>,
    },
    /// Dry run: build and check the plan, estimate time, frames and bytes. Nothing moves.
    Plan {
        script: PathBuf,
        #[arg(long)]
        rig: Option<String>,
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Print the plan as JSON instead of the report.
        #[arg(long)]
        json: bool,
    },
    /// Tools for the simulated rig (render accuracy vs time).
    Sim {
        #[command(subcommand)]
        command: sim::SimCommand,
    },
    /// List serial ports, HID relays and cameras with rig-file snippets.
    Devices(devices::DevicesArgs),
    /// Run the daemon: own the rig's devices and serve the HTTP API, live events and the
    /// dashboard.
    Serve {
        /// Rig: `lightstage` (default, simulated), `reflectometer` (simulated) or a rig TOML file.
        #[arg(long)]
        rig: Option<String>,
        /// Address to listen on (loopback unless told otherwise).
        #[arg(long, default_value = "127.0.0.1:8080")]
        listen: std::net::SocketAddr,
        /// Data directory: API tokens, run directories and uploaded scripts.
        #[arg(long, default_value = "stagehand-data")]
        data: PathBuf,
        /// Directory of scripts offered on the dashboard (default: `sequences` if it exists).
        #[arg(long)]
        scripts: Option<PathBuf>,
        /// Seed of the simulated sensor noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run the real serial drivers against firmware emulators (see `run --emulate`).
        #[arg(long)]
        emulate: bool,
    },
    /// Finish an interrupted run (after a crash, kill, abort or full disk), or with --retake
    /// capture damaged steps of a run again.
    Resume {
        run_dir: PathBuf,
        /// Capture these steps again (comma-separated step numbers, as `stagehand verify`
        /// prints them): their frames are removed from the index, then the run resumes.
        #[arg(long, value_name = "STEPS", value_delimiter = ',')]
        retake: Vec<usize>,
        #[arg(long, short = 'y')]
        yes: bool,
        #[arg(long, default_value_t = DEFAULT_RESERVE_BYTES >> 20)]
        reserve_mib: u64,
        /// Resume against firmware emulators (a run started with `--emulate`).
        #[arg(long)]
        emulate: bool,
    },
    /// Compute a calibration from a run and store it (versioned, content-addressed) in
    /// `calibrations/` beside the run.
    Calibrate {
        #[command(subcommand)]
        command: calibrate::CalibrateCommand,
    },
    /// Make products from a run's frames with stored calibrations (HDR radiance, rectified images, the BTF), written
    /// into the run and indexed; an interrupted process resumes.
    Process(process::ProcessArgs),
    /// List or show stored calibrations.
    Calibrations {
        #[command(subcommand)]
        command: calibrate::CalibrationsCommand,
    },
    /// Measure a simulated run's calibrations against the simulator's ground truth
    /// (`as_built.json`; rigs with `[sim.as_built]`) and print the figures as JSON.
    Evaluate { run_dir: PathBuf },
    /// Check a run directory: every file against the index (present, size, SHA-256,
    /// decodable), every index row against the plan, no stray or temp files. Exit 0 when all
    /// is well, 1 on any problem (with the retake command that repairs damaged steps).
    Verify {
        run_dir: PathBuf,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// Runs the CLI and returns the process exit code.
pub fn main() -> i32 {
    // Before any thread starts: frame buffers are recycled, not refaulted, at the rig's rates.
    stagehand_dataset::keep_frame_memory();
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    stagehand_devices::realtime::choose(cli.realtime_priority);
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("STAGEHAND_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .try_init();
    match dispatch(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
    }
}

fn overrides(set: &[String]) -> Result<Vec<(String, String)>, SessionError> {
    set.iter()
        .map(|s| parse_set(s).map_err(SessionError::from))
        .collect()
}

fn dispatch(command: Command) -> Result<i32, SessionError> {
    let started = std::time::Instant::now();
    match command {
        Command::Sim { command } => Ok(sim::run(command)),
        Command::Calibrate { command } => calibrate::calibrate(command),
        Command::Calibrations { command } => calibrate::calibrations(command),
        Command::Process(args) => process::process(args),
        Command::Evaluate { run_dir } => calibrate::evaluate(&run_dir),
        Command::Serve {
            rig,
            listen,
            data,
            scripts,
            seed,
            emulate,
        } => {
            let scripts = scripts.or_else(|| {
                let default = PathBuf::from("sequences");
                default.is_dir().then_some(default)
            });
            let opts = crate::daemon::ServeOptions {
                rig,
                listen,
                data,
                scripts,
                seed,
                emulation: emulation(emulate)?,
            };
            crate::daemon::serve(opts)
                .map(|()| 0)
                .map_err(|e| SessionError::Io(e.to_string()))
        }
        Command::Devices(args) => devices::run(args)
            .map(|fit| if fit { 0 } else { 1 })
            .map_err(|e| SessionError::Io(e.to_string())),
        Command::Plan {
            script,
            rig,
            set,
            json,
        } => {
            let rig = RigSource::load(rig.as_deref())?;
            let script = ScriptSource::from_file(&script)?;
            let plan = crate::script::build_plan(&script, &overrides(&set)?, &rig.spec)?;
            let violations = crate::validate::validate(&plan, &rig.spec);
            let estimate = crate::estimate::estimate(&plan, &rig.spec);
            if json {
                print_json(&plan)?;
            } else {
                let renderer = renderer_line(&rig.spec);
                print!(
                    "{}",
                    render_report_with_renderer(
                        &script.name,
                        &plan,
                        &estimate,
                        &violations,
                        renderer.as_deref()
                    )
                );
            }
            let bad = violations
                .iter()
                .any(|v| v.severity == crate::validate::Severity::Error);
            Ok(if bad { 2 } else { 0 })
        }
        Command::Run {
            script,
            rig,
            out,
            seed,
            set,
            yes,
            reserve_mib,
            emulate,
            remote,
            token,
        } => {
            if let Some(url) = remote {
                return Ok(remote::run(remote::RemoteRun {
                    url,
                    token,
                    script,
                    set,
                    seed,
                    yes,
                }));
            }
            let seed = seed.unwrap_or(1);
            let rig = RigSource::load(rig.as_deref())?;
            let script = ScriptSource::from_file(&script)?;
            let prepared = session::prepare(script, &overrides(&set)?, rig)?;
            for w in &prepared.warnings {
                eprintln!(
                    "{}",
                    session::format_violations(&prepared.script.name, std::slice::from_ref(w))
                );
            }
            if !emulate {
                // Refused before a run directory exists when another process (the daemon)
                // holds the rig's ports; the rig takes the locks again when it opens.
                drop(crate::rig::lock_real_ports(&prepared.rig.spec)?);
            }
            let runtime =
                session::runtime_for(&prepared.rig).map_err(|e| SessionError::Io(e.to_string()))?;
            let store = session::create_run(&prepared, &out, seed)?;
            let dir = store.dir().to_path_buf();
            eprintln!("run directory: {}", dir.display());
            let emulation = emulation(emulate)?;
            let result = runtime.block_on(async move {
                let (wiring, ui) = wire(yes, reserve_mib);
                let r = match session::open_rig(&prepared.rig, seed, emulation.as_ref()) {
                    Ok(rig) => session::run(prepared, store, rig, wiring).await,
                    Err(e) => Err(e),
                };
                ui.finish().await;
                r
            });
            report(&dir, started, result)
        }
        Command::Verify { run_dir, json } => {
            let report = crate::storage::verify::verify_run(&run_dir)?;
            if json {
                print_json(&report)?;
            } else {
                print!("{}", report.render());
            }
            Ok(if report.ok { 0 } else { 1 })
        }
        Command::Resume {
            run_dir,
            retake,
            yes,
            reserve_mib,
            emulate,
        } => {
            let mut reopened = session::reopen(&run_dir)?;
            if !retake.is_empty() {
                let reset = reopened.store.retake(&reopened.plan, &retake)?;
                eprintln!(
                    "retaking step(s) {}: {} step(s) to run again",
                    retake
                        .iter()
                        .map(usize::to_string)
                        .collect::<Vec<_>>()
                        .join(","),
                    reset.len()
                );
            }
            let runtime =
                session::runtime_for(&reopened.rig).map_err(|e| SessionError::Io(e.to_string()))?;
            eprintln!("resuming {}", run_dir.display());
            let emulation = emulation(emulate)?;
            let result = runtime.block_on(async move {
                let (wiring, ui) = wire(yes, reserve_mib);
                let r = session::resume(reopened, wiring, emulation.as_ref()).await;
                ui.finish().await;
                r
            });
            report(&run_dir, started, result)
        }
    }
}

/// Prints `value` as pretty JSON on stdout (`--json`).
fn print_json(value: &impl serde::Serialize) -> Result<(), SessionError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| SessionError::Io(e.to_string()))?;
    println!("{text}");
    Ok(())
}

/// The emulators' port links go in a fresh directory under the system's temp dir.
fn emulation(emulate: bool) -> Result<Option<Emulation>, SessionError> {
    if !emulate {
        return Ok(None);
    }
    let dir = std::env::temp_dir().join(format!("stagehand-emulators-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| {
        SessionError::Io(format!(
            "cannot create the emulators' directory {}: {e}",
            dir.display()
        ))
    })?;
    eprintln!(
        "emulating the rig's serial devices; port links in {}",
        dir.display()
    );
    Ok(Some(Emulation::new(&dir)))
}

/// Progress display, Ctrl-C handling and the operator for one run.
fn wire(yes: bool, reserve_mib: u64) -> (Wiring, progress::Progress) {
    let (events, _) = broadcast::channel(1024);
    let control = RunControl::new();
    let ui = progress::Progress::start(events.subscribe());
    let operator: Arc<dyn Operator> = if yes {
        Arc::new(AutoConfirm)
    } else {
        Arc::new(operator::TerminalOperator::new(ui.bar()))
    };
    operator::answer_pauses(events.subscribe(), control.clone(), yes, ui.bar());
    let abort = control.clone();
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            eprintln!(
                "\ninterrupt: aborting to the safe state (lamps and laser off, axes stopped)…"
            );
            abort.abort();
        }
    });
    (
        Wiring {
            events,
            control,
            operator,
            reserve_bytes: reserve_mib << 20,
        },
        ui,
    )
}

fn report(
    dir: &std::path::Path,
    started: std::time::Instant,
    result: Result<Summary, SessionError>,
) -> Result<i32, SessionError> {
    let summary = result?;
    let (files, bytes) = frames_on_disk(dir);
    println!("run {}: {}", summary.status, dir.display());
    println!(
        "  {files} frame files, {} on disk, wall time {:.1} s",
        crate::units::human_bytes(bytes),
        started.elapsed().as_secs_f64()
    );
    println!(
        "  steps {}/{}, frames written {}, rig time {} (estimated {})",
        summary.steps_done,
        summary.steps_total,
        summary.frames_written,
        crate::units::hms(summary.session_rig_s),
        crate::units::hms(summary.estimated_rig_time_s)
    );
    println!(
        "  index: sqlite3 {}/index.sqlite 'SELECT camera, count(*) FROM frames GROUP BY camera'",
        dir.display()
    );
    if !summary.safety_violations.is_empty() {
        for v in &summary.safety_violations {
            println!("  safety violation: {v}");
        }
        return Ok(1);
    }
    Ok(0)
}

/// Number and total size of the files in a run's `frames/` directory.
fn frames_on_disk(dir: &std::path::Path) -> (usize, u64) {
    let Ok(entries) = std::fs::read_dir(dir.join("frames")) else {
        return (0, 0);
    };
    entries
        .filter_map(|e| e.ok()?.metadata().ok())
        .filter(|m| m.is_file())
        .fold((0, 0), |(n, b), m| (n + 1, b + m.len()))
}
