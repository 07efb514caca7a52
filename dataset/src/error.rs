//! Typed storage errors. Every variant says what failed, where, and what to do about it.

use std::path::PathBuf;

/// Everything that can go wrong while creating, writing or reading a run dataset.
#[derive(Debug, thiserror::Error)]
pub enum StorageError {
    /// The dataset root (the `--out` directory) could not be created or is not a directory.
    #[error(
        "cannot create the dataset root {path}: {source}; choose a writable directory \
         (e.g. with --out) that is not below a regular file"
    )]
    CreateRoot {
        /// The root that was asked for.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },

    /// The run directory itself could not be created.
    #[error(
        "cannot create the run directory {path}: {source}; check that its parent is writable \
         and the disk is not full"
    )]
    CreateRunDir {
        /// The run directory that was attempted.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },

    /// Every candidate run directory name was already taken.
    #[error(
        "cannot find a free run directory name for {base} (tried {tries} suffixes); \
         clean up old runs under {root} or use another --out"
    )]
    NoFreeRunName {
        /// The dataset root.
        root: PathBuf,
        /// The base run id that was tried with suffixes.
        base: String,
        /// How many names were tried.
        tries: u32,
    },

    /// A file system operation failed.
    #[error("cannot {op} {path}: {source}; check that the disk is mounted, writable and not full")]
    Io {
        /// What was being done ("write", "fsync", "rename to", ...).
        op: &'static str,
        /// The file or directory involved.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },

    /// A JSON document of the run could not be written or read.
    #[error("cannot {op} JSON {path}: {source}; the file may be damaged or from another program")]
    Json {
        /// "encode" or "decode".
        op: &'static str,
        /// The file (or the column, for JSON stored in SQLite).
        path: PathBuf,
        /// The serde_json error, with line and column when decoding.
        #[source]
        source: serde_json::Error,
    },

    /// The SQLite index failed.
    #[error(
        "index database {path}: {what} failed: {source}; check the disk, and that no other \
         program holds the database locked"
    )]
    Sqlite {
        /// The `index.sqlite` file.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// The rusqlite error.
        #[source]
        source: rusqlite::Error,
    },

    /// The index database holds something this version does not understand.
    #[error("index database {path} is inconsistent: {reason}; the run may be damaged")]
    CorruptIndex {
        /// The `index.sqlite` file.
        path: PathBuf,
        /// What was found.
        reason: String,
    },

    /// The directory is not a (complete) run directory.
    #[error(
        "{path} is not a complete stagehand run directory: {missing} is missing; pass the \
         directory printed when the run was created (an interrupted creation leaves an \
         incomplete directory that can be deleted)"
    )]
    NotARun {
        /// The directory that was opened.
        path: PathBuf,
        /// The file that should have been there.
        missing: &'static str,
    },

    /// The run was written by a newer dataset format.
    #[error(
        "run {path} has dataset format {found}, this stagehand understands up to {supported}; \
         resume it with a newer stagehand"
    )]
    UnsupportedFormat {
        /// The run directory.
        path: PathBuf,
        /// The format version in its manifest.
        found: u32,
        /// The newest version this build can read.
        supported: u32,
    },

    /// The plan on disk (or the plan given) does not match the manifest's plan hash.
    #[error(
        "plan hash mismatch in {path}: the manifest records {expected}, the plan hashes to \
         {found}; the plan was changed after the run was created, so it cannot be resumed \
         safely — start a new run"
    )]
    PlanHashMismatch {
        /// The run directory (or plan file).
        path: PathBuf,
        /// Hash recorded in the manifest.
        expected: String,
        /// Hash of the plan that was found.
        found: String,
    },

    /// The run's index has a schema version this build cannot read.
    #[error(
        "run {path}: its index has schema version {found}, this stagehand reads versions 1 to \
         {supported}; read it with a newer stagehand (version 0 is a run whose creation was \
         interrupted: it holds no frames and can be deleted)"
    )]
    UnsupportedSchema {
        /// The run directory.
        path: PathBuf,
        /// The version in the index (`PRAGMA user_version`).
        found: i32,
        /// The newest version this build reads.
        supported: i32,
    },

    /// Another process holds the run open for writing.
    #[error(
        "run {path} is already open for writing by another stagehand process; stop that \
         process first (the lock is {lock})"
    )]
    RunInUse {
        /// The run directory.
        path: PathBuf,
        /// The lock file.
        lock: PathBuf,
    },

    /// A step record or frame handed to `commit_step` is inconsistent.
    #[error("cannot commit step {step} of run {run}: {reason}; this is a bug in the caller")]
    InvalidCommit {
        /// The step being committed.
        step: usize,
        /// The run directory.
        run: PathBuf,
        /// What is wrong.
        reason: String,
    },

    /// A step given to `resume --retake` cannot be captured again.
    #[error(
        "cannot retake step {step} of run {run}: {reason}; `stagehand verify {run}` names the \
         capture steps whose files are damaged"
    )]
    InvalidRetake {
        /// The step asked for.
        step: usize,
        /// The run directory.
        run: PathBuf,
        /// Why not.
        reason: String,
    },

    /// The frame's pixels do not match its size or kind.
    #[error("frame {name}: {reason}")]
    InvalidFrame {
        /// The frame's file name.
        name: String,
        /// What is wrong.
        reason: String,
    },

    /// A product cannot be written as described.
    #[error("product {key}: {reason}")]
    InvalidProduct {
        /// The product's key.
        key: String,
        /// What is wrong.
        reason: String,
    },

    /// PNG encoding failed.
    #[error("cannot encode PNG {name}: {source}")]
    PngEncode {
        /// The frame's file name.
        name: String,
        /// The png crate's error.
        #[source]
        source: png::EncodingError,
    },

    /// PNG decoding failed.
    #[error("cannot decode PNG {name}: {source}; the file may be truncated or damaged")]
    PngDecode {
        /// The file that was read.
        name: String,
        /// The png crate's error.
        #[source]
        source: png::DecodingError,
    },

    /// OpenEXR encoding or decoding failed.
    #[error("cannot {op} OpenEXR {name}: {source}")]
    Exr {
        /// "encode" or "decode".
        op: &'static str,
        /// The frame's file name.
        name: String,
        /// The exr crate's error.
        #[source]
        source: exr::error::Error,
    },

    /// The frames given to the HDR merge cannot be merged.
    #[error("cannot merge HDR bracket: {0}")]
    Merge(String),
}

/// Shorthand for storage results.
pub type Result<T> = std::result::Result<T, StorageError>;

impl StorageError {
    /// Builds an [`StorageError::Io`] for `op` on `path`.
    pub(crate) fn io(op: &'static str, path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        StorageError::Io {
            op,
            path: path.into(),
            source,
        }
    }
}
