//! Progress events broadcast while a run executes (the CLI progress bar, and the
//! daemon's event hub, which serves them over SSE to the dashboard and `run --remote`).

use serde::Serialize;

/// Something that happened during a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    RunStarted {
        total_steps: usize,
        steps_to_do: usize,
        estimated_rig_time_s: f64,
    },
    StepStarted {
        step: usize,
        kind: &'static str,
        block: String,
    },
    /// The step's devices are done; its frames are queued for writing.
    StepFinished {
        step: usize,
        kind: &'static str,
        frames: usize,
        rig_time_s: f64,
        total_steps: usize,
        eta_s: f64,
    },
    /// The step's frames are on disk and its journal row is committed.
    StepDurable {
        step: usize,
        files: usize,
    },
    Prompt {
        step: usize,
        message: String,
    },
    Paused {
        before_step: usize,
    },
    Resumed {
        before_step: usize,
    },
    Warning {
        message: String,
    },
    /// A device failed during a step; the run pauses while the rig is re-established and the
    /// step is then run again.
    DeviceFault {
        step: usize,
        device: String,
        message: String,
        attempt: u32,
    },
    /// The rig is back in the state before the step (reconnected, re-homed); the step runs again.
    Recovered {
        step: usize,
        device: String,
    },
    RunFinished {
        status: String,
        message: Option<String>,
        rig_time_s: f64,
        elapsed_rig_s: f64,
    },
}
