//! Errors of the script builder: every one names the script file and, where there is one, the
//! line and column, then says what is wrong and what to do.

use thiserror::Error;

/// Why a script could not be turned into a plan.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ScriptError {
    /// The script file could not be read.
    #[error("{file}: cannot read the script: {reason}; check the path")]
    Read {
        /// Path as the user typed it.
        file: String,
        /// What the operating system said.
        reason: String,
    },
    /// The script does not parse (or uses an undeclared variable, or nests too deeply).
    #[error("{file}:{line}:{col}: {message}")]
    Syntax {
        /// Script name.
        file: String,
        /// Line, from 1.
        line: u32,
        /// Column, from 1.
        col: u32,
        /// What is wrong and what to do.
        message: String,
    },
    /// A capture-API function was called with wrong arguments or options.
    #[error("{file}:{line}:{col}: {message}")]
    Api {
        /// Script name.
        file: String,
        /// Line, from 1.
        line: u32,
        /// Column, from 1.
        col: u32,
        /// What is wrong and what to do.
        message: String,
    },
    /// The script failed while running (a `throw`, an unknown function, a type mismatch...).
    #[error("{}: {message}", located(.file, *.at))]
    Runtime {
        /// Script name.
        file: String,
        /// Line and column, when Rhai knows them.
        at: Option<(u32, u32)>,
        /// What is wrong and what to do.
        message: String,
    },
    /// The script ran into one of the builder's limits (operations, call depth, sizes, plan
    /// steps, wall-clock time).
    #[error("{}: {message}", located(.file, *.at))]
    Limit {
        /// Script name.
        file: String,
        /// Line and column where the limit was hit, when known.
        at: Option<(u32, u32)>,
        /// Name of the limit (a field of [`super::ScriptLimits`]).
        limit: &'static str,
        /// Which limit was hit and what to fix or raise.
        message: String,
    },
    /// `--set` named parameters the script never declared with `param(...)`.
    #[error(
        "{file}: --set {}: the script declares no parameter {}; declared parameters: {}; check the spelling",
        .unknown.join(", "),
        quoted(.unknown),
        if .declared.is_empty() { "none".to_string() } else { .declared.join(", ") }
    )]
    UnknownParam {
        /// Script name.
        file: String,
        /// The `--set` names that match no `param(...)`.
        unknown: Vec<String>,
        /// Every parameter the script declared, sorted.
        declared: Vec<String>,
    },
    /// A `--set` value does not parse as the type of the parameter's default.
    #[error(
        "{file}:{line}:{col}: --set {name}={value}: parameter `{name}` expects {expected}; fix the value"
    )]
    BadParamValue {
        /// Script name.
        file: String,
        /// Line of the `param(...)` call.
        line: u32,
        /// Column of the `param(...)` call.
        col: u32,
        /// Parameter name.
        name: String,
        /// The value given on the command line.
        value: String,
        /// The expected type, in words.
        expected: String,
    },
    /// A `--set` argument is not of the form `NAME=VALUE`.
    #[error("--set {arg}: {message}")]
    BadSet {
        /// The argument as given.
        arg: String,
        /// What is wrong and what to do.
        message: String,
    },
}

fn located(file: &str, at: Option<(u32, u32)>) -> String {
    match at {
        Some((line, col)) => format!("{file}:{line}:{col}"),
        None => file.to_string(),
    }
}

fn quoted(names: &[String]) -> String {
    names
        .iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl ScriptError {
    /// Line and column (1-based) in the script, when the error has a position.
    pub fn position(&self) -> Option<(u32, u32)> {
        match self {
            ScriptError::Syntax { line, col, .. }
            | ScriptError::Api { line, col, .. }
            | ScriptError::BadParamValue { line, col, .. } => Some((*line, *col)),
            ScriptError::Runtime { at, .. } | ScriptError::Limit { at, .. } => *at,
            ScriptError::Read { .. }
            | ScriptError::UnknownParam { .. }
            | ScriptError::BadSet { .. } => None,
        }
    }
}
