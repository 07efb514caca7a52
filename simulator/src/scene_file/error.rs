//! Why a scene file could not be used; every message names file:line:col and says what to do.

use thiserror::Error;

/// A scene file that could not be read or is invalid.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SceneError {
    /// The scene file itself could not be read.
    #[error(
        "{path}: cannot read the scene file: {reason}; check the path (relative paths are taken from the working directory)"
    )]
    Read {
        /// The path as given.
        path: String,
        /// The operating system's reason.
        reason: String,
    },
    /// A key, value or referenced file is wrong; `line` and `col` (1-based) point at it.
    #[error("{path}:{line}:{col}: {message}")]
    Invalid {
        /// The scene file.
        path: String,
        /// 1-based line of the offending key or value.
        line: usize,
        /// 1-based column (in characters).
        col: usize,
        /// What is wrong and what to do about it.
        message: String,
    },
}
