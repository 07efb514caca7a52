//! Why a tradeoff sweep, its outputs or the Mitsuba comparison could not be produced.

use thiserror::Error;

use stagehand_simulator::render::RenderError;

/// A failed sweep or output; `is_bad_input` tells input mistakes from failures.
#[derive(Debug, Error)]
pub enum TradeoffError {
    /// The renderer does not know the scene name.
    #[error("unknown scene `{scene}`: the renderer has no fixture of that name ({detail})")]
    UnknownScene {
        /// The name that was asked for.
        scene: String,
        /// The renderer's message (lists the fixtures it knows).
        detail: String,
    },
    /// A setting is out of range (camera size, repeat count, target, ...).
    #[error("{what} must be {expected}, got {got}")]
    InvalidInput {
        /// Which value.
        what: String,
        /// What it must be.
        expected: String,
        /// What was given.
        got: String,
    },
    /// The renderer refused a frame (unknown camera, invalid knob, ...).
    #[error(transparent)]
    Render(#[from] RenderError),
    /// Two images that should be compared differ in size.
    #[error("images differ in size: {0} vs {1} values")]
    SizeMismatch(usize, usize),
    /// No measured setting reaches the requested error.
    #[error(
        "no setting reaches {target}: the lowest error measured is {best} ({label}); \
         raise the target or the reference-grade knobs"
    )]
    Unreachable {
        /// The target as written.
        target: String,
        /// The best error measured, formatted.
        best: String,
        /// The setting with that error.
        label: String,
    },
    /// The scene uses something the Mitsuba exporter cannot express.
    #[error("cannot export for Mitsuba: {0}")]
    Export(String),
    /// The Mitsuba peer's output could not be read.
    #[error("Mitsuba peer output {path}: {detail}")]
    Peer {
        /// The file.
        path: String,
        /// What is wrong with it.
        detail: String,
    },
    /// Writing an output file failed.
    #[error("{path}: {detail}")]
    Io {
        /// The file or directory.
        path: String,
        /// The OS error or the encoder's message.
        detail: String,
    },
}

impl TradeoffError {
    /// Whether the error is the caller's input (exit code 2) rather than a failure.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            TradeoffError::UnknownScene { .. }
                | TradeoffError::InvalidInput { .. }
                | TradeoffError::Render(
                    RenderError::UnknownCamera { .. }
                        | RenderError::InvalidKnob { .. }
                        | RenderError::UnknownFixture(_)
                )
        )
    }

    /// An I/O error on `path`.
    pub fn io(path: &std::path::Path, e: impl std::fmt::Display) -> TradeoffError {
        TradeoffError::Io {
            path: path.display().to_string(),
            detail: e.to_string(),
        }
    }
}
