//! Progress events broadcast while a run executes (the CLI progress bar, and the daemon's event
//! hub, which serves them over SSE to the dashboard and `run --remote`; [`crate::client`]
//! decodes them back into this type).

use serde::{Deserialize, Deserializer, Serialize};

use crate::plan::Action;
use crate::storage::RunStatus;

/// A step kind's name, one of [`Action::KINDS`]. (An alias, not `&'static str` written out,
/// so that serde does not borrow it from the input: events deserialise from any JSON.)
pub type StepKind = &'static str;

/// Something that happened during a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    RunStarted {
        total_steps: usize,
        steps_to_do: usize,
        estimated_rig_time_s: f64,
    },
    StepStarted {
        step: usize,
        /// The step's [`Action::kind`].
        #[serde(deserialize_with = "step_kind")]
        kind: StepKind,
        block: String,
    },
    /// The step's devices are done; its frames are queued for writing.
    StepFinished {
        step: usize,
        /// The step's [`Action::kind`].
        #[serde(deserialize_with = "step_kind")]
        kind: StepKind,
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
        status: RunStatus,
        message: Option<String>,
        rig_time_s: f64,
        elapsed_rig_s: f64,
    },
}

/// Reads a step kind as the `&'static str` [`Action::kind`] gives (one of [`Action::KINDS`]).
fn step_kind<'de, D: Deserializer<'de>>(d: D) -> Result<StepKind, D::Error> {
    let name = String::deserialize(d)?;
    Action::KINDS
        .into_iter()
        .find(|k| *k == name)
        .ok_or_else(|| {
            serde::de::Error::custom(format!(
                "unknown step kind `{name}` (expected one of {})",
                Action::KINDS.join(", ")
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_read_back_as_written() -> Result<(), serde_json::Error> {
        let events = [
            Event::StepFinished {
                step: 3,
                kind: "capture",
                frames: 2,
                rig_time_s: 1.5,
                total_steps: 9,
                eta_s: 4.0,
            },
            Event::StepStarted {
                step: 0,
                kind: "laser_disarm",
                block: "scan/left".into(),
            },
            Event::RunFinished {
                status: RunStatus::Done,
                message: None,
                rig_time_s: 2.0,
                elapsed_rig_s: 2.0,
            },
        ];
        for e in events {
            let json = serde_json::to_string(&e)?;
            assert_eq!(serde_json::from_str::<Event>(&json)?, e, "{json}");
        }
        let bad = r#"{"event":"step_started","step":0,"kind":"dance","block":""}"#;
        assert!(serde_json::from_str::<Event>(bad).is_err());
        Ok(())
    }
}
