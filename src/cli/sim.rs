//! `stagehand sim …`: tools for the simulated rig. `sim tradeoff` (what render accuracy costs
//! in time) is its own program, `stagehand-tradeoff` (crate `tradeoff/`), so the daemon does
//! not carry plotting: this runs it with the arguments given, like git runs `git-foo` for
//! `git foo`, and returns its exit code.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::Command as Process;

use clap::Subcommand;

/// Overrides where `stagehand-tradeoff` is (else: next to this executable, then `PATH`).
pub const TRADEOFF_ENV: &str = "STAGEHAND_TRADEOFF";
/// The accuracy-vs-time program's name.
const TRADEOFF_BIN: &str = "stagehand-tradeoff";

/// Subcommands of `stagehand sim`.
#[derive(Subcommand, Debug)]
pub enum SimCommand {
    /// Measure render accuracy against time: sweep every accuracy knob, write a table and
    /// plots of RMSE vs frame time with the Pareto front (optionally against Mitsuba 3).
    /// Runs `stagehand-tradeoff`; see `stagehand sim tradeoff --help`.
    #[command(disable_help_flag = true)]
    Tradeoff {
        /// Arguments of `stagehand-tradeoff` (scene, --out, --width, …).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<OsString>,
    },
}

/// Runs a `sim` subcommand; returns the exit code (0 done, 1 failed or the program is
/// missing, 2 bad input).
pub fn run(command: SimCommand) -> i32 {
    match command {
        SimCommand::Tradeoff { args } => {
            let program = tradeoff_program();
            match Process::new(&program).args(&args).status() {
                Ok(status) => status.code().unwrap_or(1),
                Err(e) => {
                    eprintln!(
                        "error: cannot run {}: {e}; `stagehand sim tradeoff` needs the \
                         {TRADEOFF_BIN} program: build it with `cargo build --release -p \
                         stagehand-tradeoff` (it lands next to `stagehand`), or set \
                         {TRADEOFF_ENV} to its path",
                        program.display()
                    );
                    1
                }
            }
        }
    }
}

/// `$STAGEHAND_TRADEOFF`, else `stagehand-tradeoff` beside this executable, else the bare
/// name (looked up on `PATH`).
fn tradeoff_program() -> PathBuf {
    if let Some(p) = std::env::var_os(TRADEOFF_ENV).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|dir| dir.join(TRADEOFF_BIN)))
        .filter(|p| p.is_file())
        .unwrap_or_else(|| PathBuf::from(TRADEOFF_BIN))
}
