//! Helpers shared by the benchmarks.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use stagehand::executor::{AutoConfirm, RunControl, Summary};
use stagehand::plan::{Action, SourcePos, Step};
use stagehand::session::{self, Prepared, Wiring};

/// Runs `prepared` into a new run directory under `out` (seed 1, every prompt confirmed, no
/// free-space reserve) on the runtime its rig needs. Returns the run directory, the summary
/// and the wall time in seconds from the first step to the end (creating the directory and
/// opening the rig not included).
pub fn run(prepared: Prepared, out: &Path) -> (PathBuf, Summary, f64) {
    let runtime = session::runtime_for(&prepared.rig).expect("runtime");
    let store = session::create_run(&prepared, out, 1).expect("run dir");
    let dir = store.dir().to_path_buf();
    let started = Instant::now();
    let summary = runtime
        .block_on(async move {
            let (events, _) = tokio::sync::broadcast::channel(1024);
            let wiring = Wiring {
                events,
                control: RunControl::new(),
                operator: Arc::new(AutoConfirm),
                reserve_bytes: 0,
            };
            let rig = session::open_rig(&prepared.rig, 1, None)?;
            session::run(prepared, store, rig, wiring).await
        })
        .expect("run");
    (dir, summary, started.elapsed().as_secs_f64())
}

/// Plan step `index` doing `action`, in block `bench` at line 1.
pub fn step(index: usize, action: Action) -> Step {
    Step {
        index,
        block: "bench".into(),
        at: SourcePos { line: 1, col: 1 },
        action,
    }
}
