//! Capture scripts: a Rhai script calls a small capture API (see `sequences/README.md`) that
//! appends [`Step`](crate::plan::Step)s to a [`Plan`]. Scripts never touch devices; the plan is
//! validated, estimated and executed elsewhere.
//!
//! Every step remembers the script line and column of the API call that created it and the
//! `/`-joined stack of enclosing `block(...)` names. Scripts run under limits (operations, call
//! depth, expression depth, value sizes, plan steps, wall-clock time) so a runaway script stops
//! with an error naming the file, the position and the limit.

mod args;
mod builder;
mod error;
mod params;
mod register;

#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rhai::{Dynamic, Engine, EvalAltResult, ParseError, ParseErrorType, Position};
use stagehand_devices::rig::RigSpec;

pub use error::ScriptError;
pub use params::parse_set;

use crate::plan::Plan;

/// A capture script and the name it is reported under.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScriptSource {
    /// Path as the user typed it; used in every error message and stored in the plan.
    pub name: String,
    /// The Rhai source text.
    pub text: String,
}

impl ScriptSource {
    /// Reads a script file; the path is kept as given for error messages.
    pub fn from_file(path: &Path) -> Result<ScriptSource, ScriptError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ScriptError::Read {
            file: name.clone(),
            reason: e.to_string(),
        })?;
        Ok(ScriptSource { name, text })
    }
}

/// The limits a script runs under. A script that hits one stops with a [`ScriptError::Limit`]
/// naming the field to raise.
#[derive(Debug, Clone, PartialEq)]
pub struct ScriptLimits {
    /// Rhai operations (roughly: statements and expressions evaluated); 0 for no limit.
    pub max_operations: u64,
    /// Nesting of function calls, closures and blocks.
    pub max_call_depth: usize,
    /// Nesting of expressions at the top level of the script.
    pub max_expr_depth: usize,
    /// Nesting of expressions inside functions and closures.
    pub max_fn_expr_depth: usize,
    /// Length of any string, in bytes.
    pub max_string_bytes: usize,
    /// Items in any array.
    pub max_array_items: usize,
    /// Entries in any object map.
    pub max_map_entries: usize,
    /// Steps in the plan.
    pub max_steps: usize,
    /// Wall-clock time the script may run.
    pub max_wall_time: Duration,
}

impl Default for ScriptLimits {
    fn default() -> Self {
        ScriptLimits {
            max_operations: 200_000_000,
            max_call_depth: 64,
            max_expr_depth: 128,
            max_fn_expr_depth: 64,
            max_string_bytes: 1 << 20,
            max_array_items: 1_000_000,
            max_map_entries: 100_000,
            max_steps: 2_000_000,
            max_wall_time: Duration::from_secs(30),
        }
    }
}

/// Runs the script under Rhai's limits and returns its plan. `overrides` are `--set NAME=VALUE`
/// pairs (a later pair for the same name wins).
pub fn build_plan(
    source: &ScriptSource,
    overrides: &[(String, String)],
    rig: &RigSpec,
) -> Result<Plan, ScriptError> {
    build_plan_with_limits(source, overrides, rig, &ScriptLimits::default())
}

/// [`build_plan`] with explicit limits.
pub fn build_plan_with_limits(
    source: &ScriptSource,
    overrides: &[(String, String)],
    rig: &RigSpec,
    limits: &ScriptLimits,
) -> Result<Plan, ScriptError> {
    let file = source.name.clone();
    let overrides: BTreeMap<String, String> = overrides.iter().cloned().collect();
    let state = Arc::new(Mutex::new(builder::Builder::new(
        file.clone(),
        Arc::new(rig.clone()),
        overrides.clone(),
        limits.max_steps,
    )));

    let mut engine = Engine::new();
    engine
        .set_max_operations(limits.max_operations)
        .set_max_call_levels(limits.max_call_depth)
        .set_max_expr_depths(limits.max_expr_depth, limits.max_fn_expr_depth)
        .set_max_string_size(limits.max_string_bytes)
        .set_max_array_size(limits.max_array_items)
        .set_max_map_size(limits.max_map_entries)
        .set_strict_variables(true)
        .set_fail_on_invalid_map_property(true)
        .set_module_resolver(rhai::module_resolvers::DummyModuleResolver::new());
    engine.disable_symbol("eval");
    let print_file = file.clone();
    engine
        .on_print(move |text| tracing::info!(target: "stagehand::script", "{print_file}: {text}"));
    let debug_file = file.clone();
    engine.on_debug(move |text, _source, pos| {
        let at = match (pos.line(), pos.position()) {
            (Some(l), Some(c)) => format!(":{l}:{c}"),
            _ => String::new(),
        };
        tracing::debug!(target: "stagehand::script", "{debug_file}{at}: {text}");
    });
    let started = Instant::now();
    let max_wall = limits.max_wall_time;
    engine.on_progress(move |ops| {
        if ops % 1024 == 0 && started.elapsed() > max_wall {
            Some(Dynamic::from(WALL_CLOCK))
        } else {
            None
        }
    });
    register::register(&mut engine, &state);

    let ast = engine
        .compile(&source.text)
        .map_err(|e| syntax_error(&file, e, limits))?;
    let result = engine.run_ast(&ast);
    drop(engine);

    let mut b = builder::lock(&state);
    if let Some(err) = b.error.take() {
        return Err(err);
    }
    if let Err(err) = result {
        return Err(eval_error(&file, *err, limits));
    }
    let declared = b.declared();
    let unknown: Vec<String> = overrides
        .keys()
        .filter(|k| !declared.contains(k))
        .cloned()
        .collect();
    if !unknown.is_empty() {
        return Err(ScriptError::UnknownParam {
            file,
            unknown,
            declared,
        });
    }
    Ok(Plan {
        script: file,
        params: std::mem::take(&mut b.params),
        steps: std::mem::take(&mut b.steps),
    })
}

/// The token `on_progress` stops a script with when it runs out of wall-clock time.
const WALL_CLOCK: &str = "wall-clock limit";

fn line_col(pos: Position) -> Option<(u32, u32)> {
    let line = u32::try_from(pos.line()?).ok()?;
    let col = pos
        .position()
        .and_then(|c| u32::try_from(c).ok())
        .unwrap_or(1);
    Some((line, col))
}

fn syntax_error(file: &str, err: ParseError, limits: &ScriptLimits) -> ScriptError {
    let ParseError(kind, pos) = err;
    let (line, col) = line_col(pos).unwrap_or((1, 1));
    let message = match *kind {
        ParseErrorType::ExprTooDeep => format!(
            "expressions nest more than {} levels deep ({} inside functions and closures); split the expression or raise max_expr_depth / max_fn_expr_depth",
            limits.max_expr_depth, limits.max_fn_expr_depth
        ),
        ParseErrorType::VariableUndefined(name) => {
            format!("unknown variable `{name}`; declare it with `let {name} = ...` before using it")
        }
        other => format!("syntax error: {other}; fix the script at this position"),
    };
    ScriptError::Syntax {
        file: file.to_string(),
        line,
        col,
        message,
    }
}

fn limit(file: &str, at: Option<(u32, u32)>, limit: &'static str, message: String) -> ScriptError {
    ScriptError::Limit {
        file: file.to_string(),
        at,
        limit,
        message,
    }
}

fn eval_error(file: &str, err: EvalAltResult, limits: &ScriptLimits) -> ScriptError {
    // Unwrap calls into script functions and closures to the error that started it, keeping
    // the outermost known position as a fallback and the named functions as context.
    let mut err = err;
    let mut fallback = Position::NONE;
    let mut chain: Vec<String> = Vec::new();
    loop {
        match err {
            EvalAltResult::ErrorInFunctionCall(name, _, inner, pos) => {
                if !pos.is_none() {
                    fallback = pos;
                    if !name.starts_with("anon$") {
                        let at = line_col(pos)
                            .map(|(l, c)| format!(" at {l}:{c}"))
                            .unwrap_or_default();
                        chain.push(format!("in function `{name}` called{at}"));
                    }
                }
                err = *inner;
            }
            EvalAltResult::ErrorInModule(_, inner, pos) => {
                if !pos.is_none() {
                    fallback = pos;
                }
                err = *inner;
            }
            other => {
                err = other;
                break;
            }
        }
    }
    let pos = if err.position().is_none() {
        fallback
    } else {
        err.position()
    };
    let at = line_col(pos);
    let context = if chain.is_empty() {
        String::new()
    } else {
        format!(" ({})", chain.join(", "))
    };
    match err {
        EvalAltResult::ErrorTooManyOperations(_) => limit(
            file,
            at,
            "max_operations",
            format!(
                "the script ran more than {} operations and was stopped{context}; look for a loop that never ends, scale the loops down with --set, or raise max_operations",
                limits.max_operations
            ),
        ),
        EvalAltResult::ErrorStackOverflow(_) => limit(
            file,
            at,
            "max_call_depth",
            format!(
                "function calls and blocks nest more than {} deep{context}; look for recursion without an end, or raise max_call_depth",
                limits.max_call_depth
            ),
        ),
        EvalAltResult::ErrorDataTooLarge(what, _) => {
            let lower = what.to_ascii_lowercase();
            let (name, size) = if lower.contains("string") {
                (
                    "max_string_bytes",
                    format!("{} bytes", limits.max_string_bytes),
                )
            } else if lower.contains("map") {
                (
                    "max_map_entries",
                    format!("{} entries", limits.max_map_entries),
                )
            } else {
                (
                    "max_array_items",
                    format!("{} items", limits.max_array_items),
                )
            };
            limit(
                file,
                at,
                name,
                format!(
                    "{what} exceeds the limit of {size}{context}; build smaller values (scale the loops down with --set), or raise {name}"
                ),
            )
        }
        EvalAltResult::ErrorTerminated(_, _) => limit(
            file,
            at,
            "max_wall_time",
            format!(
                "the script ran longer than {:.1} s and was stopped{context}; look for a loop that never ends, scale the loops down with --set, or raise max_wall_time",
                limits.max_wall_time.as_secs_f64()
            ),
        ),
        EvalAltResult::ErrorTooManyVariables(_) | EvalAltResult::ErrorTooManyModules(_) => limit(
            file,
            at,
            "max_variables",
            format!("the script declares too many variables or modules{context}; simplify it"),
        ),
        EvalAltResult::ErrorParsing(kind, pos) => {
            syntax_error(file, ParseError(Box::new(kind), pos), limits)
        }
        EvalAltResult::ErrorFunctionNotFound(signature, _) => ScriptError::Runtime {
            file: file.to_string(),
            at,
            message: format!(
                "no function matches `{signature}`{context}; check the name, the number of arguments and their types against sequences/README.md"
            ),
        },
        EvalAltResult::ErrorModuleNotFound(name, _) => ScriptError::Runtime {
            file: file.to_string(),
            at,
            message: format!(
                "cannot import `{name}`: imports are disabled so that a plan depends only on the script and its --set values; put the code in the script itself"
            ),
        },
        EvalAltResult::ErrorVariableNotFound(name, _) => ScriptError::Runtime {
            file: file.to_string(),
            at,
            message: format!(
                "unknown variable `{name}`{context}; declare it with `let` before using it"
            ),
        },
        EvalAltResult::ErrorRuntime(value, _) => ScriptError::Runtime {
            file: file.to_string(),
            at,
            message: format!("the script threw: {value}{context}; fix what it reports"),
        },
        mut other => {
            let _ = other.take_position();
            ScriptError::Runtime {
                file: file.to_string(),
                at,
                message: format!("{other}{context}; fix the script at this position"),
            }
        }
    }
}
