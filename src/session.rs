//! A capture session from start to end: script → plan → validation → dataset → rig → executor,
//! and resuming an interrupted run. The CLI (`run`, `resume`), the daemon's run
//! queue and the tests share this.

use std::path::Path;
use std::sync::Arc;

use stagehand_devices::clock::RigClock;
use tokio::sync::broadcast;

use crate::estimate::{Estimate, estimate};
use crate::executor::{
    Event, Execution, Operator, RunControl, RunError, Start, Summary, WriterHandle,
};
use crate::plan::Plan;
use crate::rig::Emulation;
use crate::rig::{Rig, RigSource};
use crate::script::{ScriptError, ScriptSource, build_plan};
use crate::storage::checksum::sha256_hex;
use crate::storage::{Manifest, RunStatus, RunStore, SimManifest, StorageError};
use crate::validate::{Severity, Violation, validate};
use stagehand_simulator::render::Renderer;

/// Why a session could not start or finish. `exit_code` maps it for the CLI.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{0}")]
    Script(#[from] ScriptError),
    #[error("{0}")]
    Rig(#[from] stagehand_devices::rig::RigError),
    #[error("the plan has {} error(s); nothing moved:\n{}", .0.iter().filter(|v| v.severity == Severity::Error).count(), format_violations(.1, .0))]
    Invalid(Vec<Violation>, String),
    #[error("{0}")]
    Storage(#[from] crate::storage::StorageError),
    #[error("{0}")]
    Open(#[from] crate::rig::OpenError),
    #[error("{0}")]
    Run(#[from] RunError),
    #[error("{0}")]
    Io(String),
}

impl SessionError {
    /// 2 for bad input (nothing was started), 1 for a run that failed or was aborted.
    pub fn exit_code(&self) -> i32 {
        match self {
            SessionError::Script(_)
            | SessionError::Rig(_)
            | SessionError::Invalid(..)
            | SessionError::Open(_) => 2,
            SessionError::Storage(
                StorageError::CreateRoot { .. }
                | StorageError::CreateRunDir { .. }
                | StorageError::NotARun { .. }
                | StorageError::UnsupportedFormat { .. }
                | StorageError::PlanHashMismatch { .. }
                | StorageError::RunInUse { .. }
                | StorageError::InvalidRetake { .. },
            ) => 2,
            _ => 1,
        }
    }
}

/// Formats violations as `SCRIPT:LINE:COL: error: message (step n)`.
pub fn format_violations(script: &str, violations: &[Violation]) -> String {
    violations
        .iter()
        .map(|v| {
            let sev = if v.severity == Severity::Error {
                "error"
            } else {
                "warning"
            };
            format!(
                "{script}:{}:{}: {sev}: {} (step {})",
                v.at.line, v.at.col, v.message, v.step
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// A checked plan with its estimate, ready to run.
pub struct Prepared {
    pub script: ScriptSource,
    pub rig: RigSource,
    pub plan: Plan,
    pub estimate: Estimate,
    /// Warnings only (errors stop `prepare`).
    pub warnings: Vec<Violation>,
}

/// Builds, validates and estimates a plan. Nothing moves.
pub fn prepare(
    script: ScriptSource,
    overrides: &[(String, String)],
    rig: RigSource,
) -> Result<Prepared, SessionError> {
    let plan = build_plan(&script, overrides, &rig.spec)?;
    let violations = validate(&plan, &rig.spec);
    if violations.iter().any(|v| v.severity == Severity::Error) {
        return Err(SessionError::Invalid(violations, script.name.clone()));
    }
    let estimate = estimate(&plan, &rig.spec);
    Ok(Prepared {
        script,
        rig,
        plan,
        estimate,
        warnings: violations,
    })
}

/// Where a run's events, control and prompts go.
pub struct Wiring {
    pub events: broadcast::Sender<Event>,
    pub control: RunControl,
    pub operator: Arc<dyn Operator>,
    /// Free space to keep on the dataset's file system; a step that would eat into it fails
    /// cleanly (resumable) instead of filling the disk.
    pub reserve_bytes: u64,
}

/// Default free-space reserve: 64 MiB.
pub const DEFAULT_RESERVE_BYTES: u64 = 64 << 20;

/// Creates the run directory; returns the store and its path (so callers can report it before
/// anything moves).
pub fn create_run(
    prepared: &Prepared,
    out_root: &Path,
    seed: u64,
) -> Result<RunStore, SessionError> {
    let manifest = Manifest {
        format_version: 1,
        run_id: String::new(),
        created_unix_s: crate::executor::wall_now(),
        software_version: env!("CARGO_PKG_VERSION").to_string(),
        script_name: prepared.script.name.clone(),
        script_text: prepared.script.text.clone(),
        plan_hash: prepared.plan.hash(),
        params: prepared.plan.params.clone(),
        rig_name: prepared.rig.spec.rig.name.clone(),
        rig_toml: prepared.rig.text.clone(),
        seed,
        simulated: true,
        sim: Some(sim_manifest(&prepared.rig.spec)?),
        calibrations: prepared
            .rig
            .spec
            .calibration
            .named()
            .into_iter()
            .map(|(kind, id)| (kind.to_string(), id.to_string()))
            .collect(),
    };
    Ok(RunStore::create(out_root, manifest, &prepared.plan)?)
}

/// The manifest's `sim` block for a simulated rig: the renderer's resolved knobs and the
/// scene of the rig's sample, with its SHA-256.
fn sim_manifest(spec: &stagehand_devices::rig::RigSpec) -> Result<SimManifest, SessionError> {
    let simulator = |e: stagehand_simulator::render::RenderError| {
        SessionError::Open(crate::rig::OpenError::Simulator(e.to_string()))
    };
    let renderer = Renderer::new(spec).map_err(simulator)?;
    let p = renderer
        .provenance(&renderer.sim().sample)
        .map_err(simulator)?;
    Ok(SimManifest {
        quality: p.knobs.preset.clone(),
        knobs: serde_json::to_value(&p.knobs).map_err(|e| SessionError::Io(e.to_string()))?,
        sample: p.fixture,
        sample_size_mm: f64::from(p.sample_size_mm),
        scene_name: p.scene_name,
        scene_path: p.scene_path.map(|path| path.display().to_string()),
        scene_sha256: sha256_hex(p.scene_text.as_bytes()),
        scene_text: p.scene_text,
        ground_truth: p.ground_truth,
        as_built: renderer
            .sim()
            .as_built
            .map(|_| renderer.as_built().truth(spec)),
    })
}

/// Opens the rig's devices for a new run (inside the runtime from [`runtime_for`]).
/// With `emulation`, the rig's serial devices are firmware emulators on pseudo-terminals.
pub fn open_rig(
    rig: &RigSource,
    seed: u64,
    emulation: Option<&Emulation>,
) -> Result<Rig, SessionError> {
    Ok(Rig::open_with(
        rig.spec.clone(),
        RigClock::starting_at(0.0),
        seed,
        emulation,
    )?)
}

/// Runs a prepared plan on `rig` into `store`. Must be called inside the runtime chosen by
/// [`runtime_for`].
pub async fn run(
    prepared: Prepared,
    store: RunStore,
    rig: Rig,
    wiring: Wiring,
) -> Result<Summary, SessionError> {
    run_from(prepared, store, rig, wiring, Start::Establish).await
}

/// [`run`], choosing how the rig reaches the first step: [`Start::InPlace`] takes it as it is
/// (nothing homes or switches first, and a completed run leaves it so: the daemon's single
/// capture).
pub async fn run_from(
    prepared: Prepared,
    store: RunStore,
    rig: Rig,
    wiring: Wiring,
    start: Start,
) -> Result<Summary, SessionError> {
    execute(
        rig,
        Arc::new(prepared.plan),
        prepared.script.name,
        store,
        std::collections::BTreeSet::new(),
        wiring,
        start,
    )
    .await
}

/// What `resume` found in the run directory.
pub struct Reopened {
    pub store: RunStore,
    pub manifest: Manifest,
    pub plan: Plan,
    pub rig: RigSource,
}

/// Opens an interrupted run (synchronously, before a runtime exists).
pub fn reopen(run_dir: &Path) -> Result<Reopened, SessionError> {
    let (store, manifest, plan) = RunStore::open::<crate::plan::Plan>(run_dir)?;
    let origin = format!("{}/rig.toml", run_dir.display());
    let rig = RigSource::from_text(&manifest.rig_toml, &origin)?;
    Ok(Reopened {
        store,
        manifest,
        plan,
        rig,
    })
}

/// Finishes an interrupted run: re-establishes the device state and runs the steps that are
/// not durable yet. A finished run is left as it is. Opens the run's rig with its clock
/// continuing the run's rig time.
pub async fn resume(
    reopened: Reopened,
    wiring: Wiring,
    emulation: Option<&Emulation>,
) -> Result<Summary, SessionError> {
    let rig_time = reopened.store.last_rig_time_s()?;
    let rig = Rig::open_with(
        reopened.rig.spec.clone(),
        RigClock::starting_at(rig_time),
        reopened.manifest.seed,
        emulation,
    )?;
    resume_on(reopened, rig, wiring).await
}

/// [`resume`] on a rig that is already open (the daemon's): the caller makes sure `rig` is
/// the run's rig. Its clock keeps its own time, so the resumed steps record the rig's time.
pub async fn resume_on(
    reopened: Reopened,
    rig: Rig,
    wiring: Wiring,
) -> Result<Summary, SessionError> {
    let Reopened {
        store,
        manifest,
        plan,
        rig: _,
    } = reopened;
    let done = store.done_steps()?;
    store.set_status(RunStatus::Running, None)?;
    execute(
        rig,
        Arc::new(plan),
        manifest.script_name,
        store,
        done,
        wiring,
        Start::Establish,
    )
    .await
}

async fn execute(
    rig: Rig,
    plan: Arc<Plan>,
    script_name: String,
    store: RunStore,
    done: std::collections::BTreeSet<usize>,
    wiring: Wiring,
    start: Start,
) -> Result<Summary, SessionError> {
    let writer = WriterHandle::spawn(store, wiring.events.clone(), wiring.reserve_bytes)
        .map_err(|e| SessionError::Io(format!("cannot start the writer thread: {e}")))?;
    let exec = Execution {
        rig,
        plan,
        script_name,
        events: wiring.events,
        control: wiring.control,
        operator: wiring.operator,
        writer,
        done,
        start,
    };
    Ok(exec.run().await?)
}

/// The tokio runtime a rig needs: simulated rigs run on a single thread with paused time, so
/// the virtual clock jumps to the next timer whenever every task waits; real rigs run in real
/// time on a multi-threaded runtime.
pub fn runtime_for(rig: &RigSource) -> std::io::Result<tokio::runtime::Runtime> {
    // Any real driver talks over a port in real time, so only an all-simulated rig may run on
    // the virtual clock.
    let simulated = !crate::rig::needs_real_time(&rig.spec);
    if simulated {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .on_thread_start(stagehand_devices::realtime::raise_this_thread)
            .build()
    }
}
