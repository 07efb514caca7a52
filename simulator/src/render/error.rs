//! Why a frame could not be rendered; every message says what to change.

use thiserror::Error;

/// A frame the renderer cannot produce, with a sentence saying what to do about it.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RenderError {
    /// The camera id is not one of the rig's cameras.
    #[error("camera `{camera}` is not in rig `{rig}`; use one of: {known}")]
    UnknownCamera {
        /// The id that was asked for.
        camera: String,
        /// The rig's name.
        rig: String,
        /// The rig's camera ids, comma-separated.
        known: String,
    },
    /// The fixture on the stage is neither a built-in scene nor a scene file path.
    #[error(
        "fixture `{0}` is unknown; place one of the built-in scenes ({list}) or give the path of a scene file ending in .toml",
        list = crate::scene_file::builtin::FIXTURES.join(", ")
    )]
    UnknownFixture(String),
    /// The fixture's scene file cannot be read or is invalid (the message names file:line:col).
    #[error(transparent)]
    Scene(#[from] crate::scene_file::SceneError),
    /// The rig's `[sim]` table does not read (unknown key, wrong type).
    #[error(transparent)]
    Sim(#[from] crate::render::config::SimError),
    /// The rig's `sim.quality` is not a preset the renderer knows.
    #[error("sim.quality `{0}` is unknown; set it to preview, standard or reference")]
    UnknownQuality(String),
    /// The rig's `sim.sample_size_mm` cannot be used to build a sample.
    #[error("sim.sample_size_mm must be a positive number of millimetres up to 1000, got {0}")]
    InvalidSampleSize(f64),
    /// The world snapshot says the laser emits but the rig has no laser.
    #[error(
        "the world has the laser emitting but rig `{0}` has no [laser] table; add one or switch the laser off"
    )]
    NoLaser(String),
    /// An accuracy knob is out of range.
    #[error("sim knob `{knob}` must be {expected}, got {got}")]
    InvalidKnob {
        /// The knob's name as written in `[sim.knobs]`.
        knob: &'static str,
        /// Its accepted range.
        expected: String,
        /// The value received.
        got: String,
    },
    /// A number in the request or the world snapshot is out of range or not finite.
    #[error("{what} must be {expected}, got {got}")]
    InvalidInput {
        /// Which value is wrong.
        what: String,
        /// What it must be.
        expected: &'static str,
        /// The value received.
        got: f64,
    },
}
