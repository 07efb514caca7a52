//! The run dataset as the engine uses it: everything of [`stagehand_dataset`] (layout, index,
//! frame files, [`RunStore`], [`RunReader`]), with `verify` bound to the engine's [`Plan`].

pub use stagehand_dataset::*;

/// [`stagehand_dataset::verify`] with the run's `plan.json` read as the engine's [`Plan`].
pub mod verify {
    pub use stagehand_dataset::verify::{Problem, ProblemKind, VerifyReport, retake_command};

    use crate::plan::Plan;

    /// Verifies the run at `run_dir` against its files, its index and its plan
    /// ([`stagehand_dataset::verify::verify_run`] with the engine's plan type).
    pub fn verify_run(run_dir: &std::path::Path) -> super::error::Result<VerifyReport> {
        stagehand_dataset::verify::verify_run::<Plan>(run_dir)
    }
}
