//! The capture API a script sees: rig queries, parameters, blocks and the functions that
//! append steps to the plan. Nothing here touches a device.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};

use rhai::{Dynamic, Engine, EvalAltResult, FnPtr, ImmutableString, Map, NativeCallContext};
use stagehand_devices::rig::{LampKind, RigSpec};
use stagehand_simulator::render::config::SimSpec;

use super::error::ScriptError;
use super::params::{describe, kind_of, normalise, parse_value, to_json, valid_name};
use crate::plan::{Action, SourcePos, Step};

/// The builder state shared by every registered function.
pub(crate) type Shared = Arc<Mutex<Builder>>;

type RhaiResult = Result<Dynamic, Box<EvalAltResult>>;

/// A parameter the script declared.
struct Declared {
    at: SourcePos,
    default_json: serde_json::Value,
    value: Dynamic,
}

/// Everything a running script has produced so far.
pub(crate) struct Builder {
    pub(crate) file: String,
    rig: Arc<RigSpec>,
    pub(crate) steps: Vec<Step>,
    blocks: Vec<String>,
    pub(crate) params: BTreeMap<String, serde_json::Value>,
    declared: BTreeMap<String, Declared>,
    overrides: BTreeMap<String, String>,
    /// The laser colour last switched on or fitted by a prompt.
    colour_nm: Option<u32>,
    /// The first API error; it wins over whatever Rhai reports (a script may catch it).
    pub(crate) error: Option<ScriptError>,
    max_steps: usize,
}

/// Why an API call failed.
pub(crate) enum Fail {
    /// Misuse: wrong types, options or values. The message says what and what to do.
    Api(String),
    /// A builder limit.
    Limit {
        limit: &'static str,
        message: String,
    },
    /// A `--set` value that does not parse as the parameter's type.
    Param {
        name: String,
        value: String,
        expected: String,
    },
}

type Res<T> = Result<T, Fail>;

fn api<T>(message: impl Into<String>) -> Res<T> {
    Err(Fail::Api(message.into()))
}

impl Builder {
    pub(crate) fn new(
        file: String,
        rig: Arc<RigSpec>,
        overrides: BTreeMap<String, String>,
        max_steps: usize,
    ) -> Self {
        Builder {
            file,
            rig,
            steps: Vec::new(),
            blocks: Vec::new(),
            params: BTreeMap::new(),
            declared: BTreeMap::new(),
            overrides,
            colour_nm: None,
            error: None,
            max_steps,
        }
    }

    /// Names of every declared parameter, sorted.
    pub(crate) fn declared(&self) -> Vec<String> {
        self.declared.keys().cloned().collect()
    }

    fn step_limit(&self, more: usize) -> Res<()> {
        if self.steps.len().saturating_add(more) > self.max_steps {
            return Err(Fail::Limit {
                limit: "max_steps",
                message: format!(
                    "the plan would grow beyond {} steps; scale the loops down with --set or split the capture into several scripts (limit max_steps)",
                    self.max_steps
                ),
            });
        }
        Ok(())
    }

    fn push(&mut self, at: SourcePos, action: Action) -> Res<()> {
        self.step_limit(1)?;
        let index = self.steps.len();
        self.steps.push(Step {
            index,
            block: self.blocks.join("/"),
            at,
            action,
        });
        Ok(())
    }

    fn all_lamp_ids(&self) -> Vec<String> {
        self.rig.lamps.iter().map(|l| l.id.clone()).collect()
    }

    // ---- parameters -------------------------------------------------------------------------

    fn param(&mut self, at: SourcePos, name: Dynamic, default: Dynamic) -> Res<Dynamic> {
        let name = string("the parameter name", &name)?;
        if !valid_name(&name) {
            return api(format!(
                "`{name}` is not a valid parameter name; use letters, digits and _ so it can be set with --set NAME=VALUE"
            ));
        }
        let kind = kind_of(&default).map_err(|e| Fail::Api(e.to_string()))?;
        let default = normalise(kind, default);
        let default_json = to_json(&default);
        if let Some(d) = self.declared.get(&name) {
            if d.default_json != default_json {
                return api(format!(
                    "parameter `{name}` was already declared at {}:{} with default {}; declare it once or with the same default",
                    d.at.line, d.at.col, d.default_json
                ));
            }
            return Ok(d.value.clone());
        }
        let value = match self.overrides.get(&name) {
            Some(text) => parse_value(kind, text).ok_or_else(|| Fail::Param {
                name: name.clone(),
                value: text.clone(),
                expected: kind.expected(),
            })?,
            None => default,
        };
        self.params.insert(name.clone(), to_json(&value));
        self.declared.insert(
            name,
            Declared {
                at,
                default_json,
                value: value.clone(),
            },
        );
        Ok(value)
    }

    // ---- rig queries ------------------------------------------------------------------------

    fn lamps_of_kind(&self, kind: Dynamic) -> Res<Dynamic> {
        let kind = string("the lamp kind", &kind)?;
        let kind = match kind.as_str() {
            "halogen" => LampKind::Halogen,
            "tube" => LampKind::Tube,
            "backlight" => LampKind::Backlight,
            "all" => return Ok(ids(self.rig.lamps.iter().map(|l| l.id.as_str()))),
            other => {
                return api(format!(
                    "unknown lamp kind `{other}`; use \"halogen\", \"tube\", \"backlight\" or \"all\""
                ));
            }
        };
        Ok(ids(self
            .rig
            .lamps
            .iter()
            .filter(|l| l.kind == kind)
            .map(|l| l.id.as_str())))
    }

    fn laser(&self) -> Res<&stagehand_devices::rig::LaserSpec> {
        match &self.rig.laser {
            Some(l) => Ok(l),
            None => api(format!(
                "rig `{}` has no laser; guard laser steps with `if has_laser() {{ ... }}` or use a rig with a laser",
                self.rig.rig.name
            )),
        }
    }

    // ---- motion -----------------------------------------------------------------------------

    fn home(&mut self, at: SourcePos, which: Option<Dynamic>) -> Res<()> {
        let axes = match which {
            None => {
                let all: Vec<String> = self.rig.axes.iter().map(|a| a.id.clone()).collect();
                if all.is_empty() {
                    // A rig without axes has nothing to home.
                    return Ok(());
                }
                all
            }
            Some(v) if v.is_string() => vec![string("the axis", &v)?],
            Some(v) if v.is_array() => {
                let list = strings("the axes", &v)?;
                if list.is_empty() {
                    return api(
                        "the list of axes is empty; name at least one axis or call home() for all",
                    );
                }
                list
            }
            Some(v) => {
                return api(format!(
                    "expected an axis id or a list of axis ids, got {}",
                    describe(&v)
                ));
            }
        };
        self.push(at, Action::Home { axes })
    }

    fn move_axis(&mut self, at: SourcePos, axis: Dynamic, deg: Dynamic) -> Res<()> {
        let axis = string("the axis", &axis)?;
        let deg = number("the angle in degrees", &deg)?;
        self.push(
            at,
            Action::Move {
                targets: BTreeMap::from([(axis, deg)]),
            },
        )
    }

    fn move_map(&mut self, at: SourcePos, targets: Dynamic) -> Res<()> {
        let Ok(map) = targets.as_map_ref() else {
            return api(format!(
                "expected an axis id and an angle, or a map #{{axis: degrees, ...}}, got {}",
                describe(&targets)
            ));
        };
        if map.is_empty() {
            return api("the map of targets is empty; name at least one axis");
        }
        let mut out = BTreeMap::new();
        for (axis, deg) in map.iter() {
            out.insert(
                axis.to_string(),
                number(&format!("the angle of `{axis}`"), deg)?,
            );
        }
        drop(map);
        self.push(at, Action::Move { targets: out })
    }

    // ---- lamps ------------------------------------------------------------------------------

    fn lamp(&mut self, at: SourcePos, id: Dynamic, on: Dynamic) -> Res<()> {
        let id = string("the lamp id", &id)?;
        let Ok(on) = on.as_bool() else {
            return api(format!(
                "the lamp state must be true or false, got {}",
                describe(&on)
            ));
        };
        self.push(
            at,
            Action::Lamps {
                states: BTreeMap::from([(id, on)]),
            },
        )
    }

    fn lamps_on(&mut self, at: SourcePos, list: Dynamic) -> Res<()> {
        if !list.is_array() {
            return api(format!(
                "expected a list of lamp ids, got {}",
                describe(&list)
            ));
        }
        let list = strings("the lamp ids", &list)?;
        if list.is_empty() {
            return api("the list of lamps is empty; name at least one lamp, or use lamps_off()");
        }
        self.push(
            at,
            Action::Lamps {
                states: list.into_iter().map(|id| (id, true)).collect(),
            },
        )
    }

    fn only_lamp(&mut self, at: SourcePos, id: Dynamic) -> Res<()> {
        let id = string("the lamp id", &id)?;
        let mut states: BTreeMap<String, bool> = self
            .all_lamp_ids()
            .into_iter()
            .map(|l| (l, false))
            .collect();
        states.insert(id, true);
        self.push(at, Action::Lamps { states })
    }

    fn lamps_off(&mut self, at: SourcePos) -> Res<()> {
        let states: BTreeMap<String, bool> = self
            .all_lamp_ids()
            .into_iter()
            .map(|l| (l, false))
            .collect();
        if states.is_empty() {
            // A rig without lamps has nothing to switch off.
            return Ok(());
        }
        self.push(at, Action::Lamps { states })
    }

    // ---- laser ------------------------------------------------------------------------------

    fn laser_on(&mut self, at: SourcePos, colour: Dynamic) -> Res<()> {
        let colour_nm = wavelength("the laser colour", &colour)?;
        self.colour_nm = Some(colour_nm);
        self.push(
            at,
            Action::Laser {
                on: true,
                colour_nm,
            },
        )
    }

    fn laser_off(&mut self, at: SourcePos) -> Res<()> {
        let colour_nm = match self.colour_nm {
            Some(c) => c,
            None => self.laser()?.fitted_nm,
        };
        self.push(
            at,
            Action::Laser {
                on: false,
                colour_nm,
            },
        )
    }

    // ---- capture ----------------------------------------------------------------------------

    fn default_cameras(&self) -> Res<Vec<String>> {
        let cams: Vec<String> = self.rig.cameras.iter().map(|c| c.id.clone()).collect();
        if cams.is_empty() {
            return api(format!(
                "rig `{}` has no cameras to capture with",
                self.rig.rig.name
            ));
        }
        Ok(cams)
    }

    fn capture(&mut self, at: SourcePos, exposures: Dynamic, opts: Option<Dynamic>) -> Res<()> {
        let exposures_s = exposure_list(&exposures)?;
        let mut cameras = None;
        let mut gain = 1.0;
        let mut hdr = exposures_s.len() > 1;
        let mut label = None;
        let mut min_interval_s = 0.0;
        if let Some(opts) = opts {
            let map = options(
                &opts,
                &["cameras", "gain", "hdr", "label", "min_interval_s"],
                &[],
            )?;
            for (key, v) in map.iter() {
                match key.as_str() {
                    "cameras" => cameras = Some(camera_list(v)?),
                    "gain" => gain = number("gain", v)?,
                    "hdr" => hdr = boolean("hdr", v)?,
                    "label" => label = Some(string("label", v)?),
                    _ => min_interval_s = non_negative("min_interval_s", v)?,
                }
            }
        }
        let cameras = match cameras {
            Some(c) => c,
            None => self.default_cameras()?,
        };
        let label = label.unwrap_or_else(|| self.blocks.join("/"));
        self.push(
            at,
            Action::Capture {
                exposures_s,
                cameras,
                gain,
                hdr,
                label,
                min_interval_s,
            },
        )
    }

    fn laser_sweep(&mut self, at: SourcePos, opts: Dynamic) -> Res<()> {
        let required = ["from_deg", "to_deg", "lines", "rate_hz", "exposure_s"];
        let map = options(&opts, &["cameras", "label", "gain"], &required)?;
        let mut from = 0.0;
        let mut to = 0.0;
        let mut lines = 0;
        let mut rate_hz = 0.0;
        let mut exposure_s = 0.0;
        let mut cameras = None;
        let mut label = None;
        let mut gain = 1.0;
        for (key, v) in map.iter() {
            match key.as_str() {
                "from_deg" => from = number("from_deg", v)?,
                "to_deg" => to = number("to_deg", v)?,
                "lines" => {
                    let n = integer("lines", v)?;
                    if n < 1 {
                        return api(format!("lines must be at least 1, got {n}"));
                    }
                    lines = usize::try_from(n).unwrap_or(usize::MAX);
                }
                "rate_hz" => {
                    rate_hz = number("rate_hz", v)?;
                    if rate_hz <= 0.0 {
                        return api(format!("rate_hz must be a positive number, got {rate_hz}"));
                    }
                }
                "exposure_s" => exposure_s = number("exposure_s", v)?,
                "cameras" => cameras = Some(camera_list(v)?),
                "label" => label = Some(string("label", v)?),
                _ => gain = number("gain", v)?,
            }
        }
        let tilt = self.laser()?.tilt_axis.clone();
        self.step_limit(lines.saturating_mul(2))?;
        let cameras = match cameras {
            Some(c) => c,
            None => self.default_cameras()?,
        };
        let base = label.unwrap_or_else(|| self.blocks.join("/"));
        let min_interval_s = 1.0 / rate_hz;
        for i in 0..lines {
            let deg = if lines == 1 {
                from
            } else {
                from + (to - from) * i as f64 / (lines - 1) as f64
            };
            self.push(
                at,
                Action::Move {
                    targets: BTreeMap::from([(tilt.clone(), deg)]),
                },
            )?;
            let label = if base.is_empty() {
                format!("line {i}")
            } else {
                format!("{base} line {i}")
            };
            self.push(
                at,
                Action::Capture {
                    exposures_s: vec![exposure_s],
                    cameras: cameras.clone(),
                    gain,
                    hdr: false,
                    label,
                    min_interval_s,
                },
            )?;
        }
        Ok(())
    }

    // ---- operator, cart, time ---------------------------------------------------------------

    fn prompt(&mut self, at: SourcePos, message: Dynamic, opts: Option<Dynamic>) -> Res<()> {
        let message = string("the message", &message)?;
        let mut fixture = None;
        let mut laser_mount_deg = None;
        let mut laser_fit_nm = None;
        if let Some(opts) = opts {
            let map = options(&opts, &["fixture", "laser_mount_deg", "laser_fit_nm"], &[])?;
            for (key, v) in map.iter() {
                match key.as_str() {
                    "fixture" => fixture = Some(string("fixture", v)?),
                    "laser_mount_deg" => laser_mount_deg = Some(number("laser_mount_deg", v)?),
                    _ => laser_fit_nm = Some(wavelength("laser_fit_nm", v)?),
                }
            }
        }
        if laser_fit_nm.is_some() {
            self.colour_nm = laser_fit_nm;
        }
        self.push(
            at,
            Action::Prompt {
                message,
                fixture,
                laser_mount_deg,
                laser_fit_nm,
            },
        )
    }
}

// ---- argument helpers -------------------------------------------------------------------------

fn ids<'a>(it: impl Iterator<Item = &'a str>) -> Dynamic {
    Dynamic::from_array(
        it.map(|s| Dynamic::from(ImmutableString::from(s)))
            .collect(),
    )
}

fn string(what: &str, v: &Dynamic) -> Res<String> {
    match v.as_immutable_string_ref() {
        Ok(s) => Ok(s.to_string()),
        Err(_) => api(format!("{what} must be a string, got {}", describe(v))),
    }
}

fn strings(what: &str, v: &Dynamic) -> Res<Vec<String>> {
    let Ok(items) = v.as_array_ref() else {
        return api(format!(
            "{what} must be a list of strings, got {}",
            describe(v)
        ));
    };
    items
        .iter()
        .map(|item| {
            let item = item.flatten_clone();
            match item.as_immutable_string_ref() {
                Ok(s) => Ok(s.to_string()),
                Err(_) => api(format!(
                    "{what} must be a list of strings, but it holds {}",
                    describe(&item)
                )),
            }
        })
        .collect()
}

fn number(what: &str, v: &Dynamic) -> Res<f64> {
    let v = v.flatten_clone();
    let x = match (v.as_int(), v.as_float()) {
        (Ok(i), _) => i as f64,
        (_, Ok(f)) => f,
        _ => return api(format!("{what} must be a number, got {}", describe(&v))),
    };
    if !x.is_finite() {
        return api(format!("{what} must be a finite number, got {x}"));
    }
    Ok(x)
}

fn non_negative(what: &str, v: &Dynamic) -> Res<f64> {
    let x = number(what, v)?;
    if x < 0.0 {
        return api(format!("{what} must not be negative, got {x}"));
    }
    Ok(x)
}

/// An integer; a float with an integral value (e.g. `3.0`) is accepted too.
fn integer(what: &str, v: &Dynamic) -> Res<i64> {
    let v = v.flatten_clone();
    if let Ok(i) = v.as_int() {
        return Ok(i);
    }
    match v.as_float() {
        Ok(f) if f.is_finite() && f.fract() == 0.0 && f.abs() < 9.0e15 => Ok(f as i64),
        _ => api(format!("{what} must be an integer, got {}", describe(&v))),
    }
}

fn boolean(what: &str, v: &Dynamic) -> Res<bool> {
    match v.flatten_clone().as_bool() {
        Ok(b) => Ok(b),
        Err(_) => api(format!("{what} must be true or false, got {}", describe(v))),
    }
}

fn wavelength(what: &str, v: &Dynamic) -> Res<u32> {
    let n = integer(&format!("{what} (nm)"), v)?;
    match u32::try_from(n) {
        Ok(nm) if nm > 0 => Ok(nm),
        _ => api(format!(
            "{what} must be a positive wavelength in nm, got {n}"
        )),
    }
}

fn exposure_list(v: &Dynamic) -> Res<Vec<f64>> {
    if v.is_array() {
        let Ok(items) = v.as_array_ref() else {
            return api("the exposures must be a number or a list of numbers of seconds");
        };
        if items.is_empty() {
            return api("the list of exposures is empty; give at least one exposure in seconds");
        }
        items
            .iter()
            .map(|e| number("each exposure (s)", e))
            .collect()
    } else if v.is_int() || v.is_float() {
        Ok(vec![number("the exposure (s)", v)?])
    } else {
        api(format!(
            "the exposure must be a number of seconds or a list of them, got {}",
            describe(v)
        ))
    }
}

fn camera_list(v: &Dynamic) -> Res<Vec<String>> {
    let list = strings("cameras", v)?;
    if list.is_empty() {
        return api("cameras is empty; name at least one camera or leave the option out for all");
    }
    Ok(list)
}

/// An options map: every key must be in `optional` or `required`, and every required key present.
fn options(v: &Dynamic, optional: &[&str], required: &[&str]) -> Res<Map> {
    let Ok(map) = v.as_map_ref() else {
        return api(format!(
            "the options must be a map #{{...}}, got {}",
            describe(v)
        ));
    };
    let allowed = || {
        required
            .iter()
            .chain(optional)
            .map(|k| k.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    for key in map.keys() {
        if !optional.contains(&key.as_str()) && !required.contains(&key.as_str()) {
            return api(format!(
                "unknown option `{key}`; the options are {}",
                allowed()
            ));
        }
    }
    let missing: Vec<&str> = required
        .iter()
        .copied()
        .filter(|k| !map.contains_key(*k))
        .collect();
    if !missing.is_empty() {
        return api(format!(
            "missing option{} {}; the required options are {}",
            if missing.len() > 1 { "s" } else { "" },
            missing.join(", "),
            required.join(", ")
        ));
    }
    Ok(map
        .iter()
        .map(|(k, v)| (k.clone(), v.flatten_clone()))
        .collect())
}

// ---- registration -----------------------------------------------------------------------------

/// Locks the builder; a poisoned lock (a panic elsewhere) still yields the data.
pub(crate) fn lock(state: &Shared) -> MutexGuard<'_, Builder> {
    state.lock().unwrap_or_else(|e| e.into_inner())
}

fn usage(name: &str) -> &'static str {
    match name {
        "param" => "param(\"views\", 12)",
        "lamps" => "lamps() or lamps(\"tube\")",
        "block" => "block(\"view 1\", || { capture(0.01); })",
        "home" => "home(), home(\"turntable\") or home([\"turntable\", \"light_arc\"])",
        "move_to" => "move_to(\"turntable\", 30) or move_to(#{turntable: 30, light_arc: 60})",
        "lamp" => "lamp(\"lamp1\", true)",
        "lamps_on" => "lamps_on([\"lamp1\", \"lamp2\"])",
        "only_lamp" => "only_lamp(\"lamp3\")",
        "laser_on" => "laser_on(650)",
        "capture" => {
            "capture(0.01), capture([0.005, 0.02]) or capture(0.01, #{cameras: [\"cam1\"], gain: 2.0})"
        }
        "laser_sweep" => {
            "laser_sweep(#{from_deg: -4, to_deg: 4, lines: 64, rate_hz: 7.5, exposure_s: 0.002})"
        }
        "cart_to" => "cart_to(120.0)",
        "prompt" => "prompt(\"Place the checkerboard\", #{fixture: \"checkerboard\"})",
        "wait" => "wait(2.0)",
        _ => "see sequences/README.md",
    }
}

fn source_pos(pos: rhai::Position) -> SourcePos {
    let line = pos.line().and_then(|l| u32::try_from(l).ok()).unwrap_or(0);
    let col = pos
        .position()
        .and_then(|c| u32::try_from(c).ok())
        .unwrap_or(0);
    SourcePos { line, col }
}

/// Runs one API call against the builder; a failure is recorded (the first one wins) and
/// returned to Rhai as a runtime error at the call position.
fn with(
    state: &Shared,
    ctx: &NativeCallContext,
    f: impl FnOnce(&mut Builder, SourcePos) -> Res<Dynamic>,
) -> RhaiResult {
    let pos = ctx.call_position();
    let at = source_pos(pos);
    let mut b = lock(state);
    match f(&mut b, at) {
        Ok(v) => Ok(v),
        Err(fail) => {
            let file = b.file.clone();
            let name = ctx.fn_name();
            let err = match fail {
                Fail::Api(message) => ScriptError::Api {
                    file,
                    line: at.line,
                    col: at.col,
                    message: format!("{name}(): {message} (usage: {})", usage(name)),
                },
                Fail::Limit { limit, message } => ScriptError::Limit {
                    file,
                    at: Some((at.line, at.col)),
                    limit,
                    message,
                },
                Fail::Param {
                    name,
                    value,
                    expected,
                } => ScriptError::BadParamValue {
                    file,
                    line: at.line,
                    col: at.col,
                    name,
                    value,
                    expected,
                },
            };
            let message = err.to_string();
            if b.error.is_none() {
                b.error = Some(err);
            }
            Err(Box::new(EvalAltResult::ErrorRuntime(message.into(), pos)))
        }
    }
}

/// Registers a capture-API function: the closure gets the builder, the call position and the
/// (flattened) `Dynamic` arguments, and returns the script value or a [`Fail`].
macro_rules! reg {
    ($engine:expr, $state:expr, $name:literal, |$b:ident, $at:ident $(, $arg:ident)*| $body:expr) => {{
        let s = $state.clone();
        $engine.register_fn($name, move |ctx: NativeCallContext $(, $arg: Dynamic)*| -> RhaiResult {
            $(let $arg = $arg.flatten();)*
            with(&s, &ctx, |$b: &mut Builder, $at: SourcePos| -> Res<Dynamic> { $body })
        });
    }};
}

fn unit(r: Res<()>) -> Res<Dynamic> {
    r.map(|()| Dynamic::UNIT)
}

/// Registers the whole capture API on `engine`.
pub(crate) fn register(engine: &mut Engine, state: &Shared) {
    // Parameters.
    reg!(engine, state, "param", |b, at, name, default| b
        .param(at, name, default));

    // Rig queries.
    reg!(engine, state, "cameras", |b, _at| Ok(ids(b
        .rig
        .cameras
        .iter()
        .map(|c| c.id.as_str()))));
    reg!(engine, state, "lamps", |b, _at| {
        Ok(ids(b
            .rig
            .lamps
            .iter()
            .filter(|l| l.kind == LampKind::Halogen)
            .map(|l| l.id.as_str())))
    });
    reg!(engine, state, "lamps", |b, _at, kind| b.lamps_of_kind(kind));
    reg!(engine, state, "axes", |b, _at| Ok(ids(b
        .rig
        .axes
        .iter()
        .map(|a| a.id.as_str()))));
    reg!(engine, state, "has_laser", |b, _at| Ok(Dynamic::from_bool(
        b.rig.laser.is_some()
    )));
    reg!(engine, state, "has_cart", |b, _at| Ok(Dynamic::from_bool(
        b.rig.cart.is_some()
    )));
    reg!(engine, state, "block_path", |b, _at| {
        Ok(Dynamic::from(ImmutableString::from(b.blocks.join("/"))))
    });
    reg!(engine, state, "rig_sample", |b, _at| {
        Ok(Dynamic::from(ImmutableString::from(SimSpec::sample_of(
            &b.rig,
        ))))
    });
    reg!(engine, state, "rig_name", |b, _at| {
        Ok(Dynamic::from(ImmutableString::from(
            b.rig.rig.name.as_str(),
        )))
    });
    reg!(engine, state, "laser_colours", |b, _at| {
        let colours = b
            .rig
            .laser
            .as_ref()
            .map(|l| l.colours_nm.clone())
            .unwrap_or_default();
        Ok(Dynamic::from_array(
            colours
                .into_iter()
                .map(|c| Dynamic::from_int(i64::from(c)))
                .collect(),
        ))
    });
    reg!(engine, state, "laser_fitted", |b, _at| Ok(
        Dynamic::from_int(i64::from(b.laser()?.fitted_nm))
    ));
    reg!(engine, state, "laser_tilt_axis", |b, _at| {
        Ok(Dynamic::from(ImmutableString::from(
            b.laser()?.tilt_axis.as_str(),
        )))
    });
    reg!(
        engine,
        state,
        "cart_travel_mm",
        |b, _at| match &b.rig.cart {
            Some(c) => Ok(Dynamic::from_float(c.travel_mm)),
            None => api(format!(
                "rig `{}` has no cart; guard cart steps with `if has_cart() {{ ... }}` or use the reflectometer rig",
                b.rig.rig.name
            )),
        }
    );

    // Motion.
    reg!(engine, state, "home", |b, at| unit(b.home(at, None)));
    reg!(engine, state, "home", |b, at, which| unit(
        b.home(at, Some(which))
    ));
    reg!(engine, state, "move_to", |b, at, targets| unit(
        b.move_map(at, targets)
    ));
    reg!(engine, state, "move_to", |b, at, axis, deg| unit(
        b.move_axis(at, axis, deg)
    ));

    // Lamps.
    reg!(engine, state, "lamp", |b, at, id, on| unit(
        b.lamp(at, id, on)
    ));
    reg!(engine, state, "lamps_on", |b, at, list| unit(
        b.lamps_on(at, list)
    ));
    reg!(engine, state, "only_lamp", |b, at, id| unit(
        b.only_lamp(at, id)
    ));
    reg!(engine, state, "lamps_off", |b, at| unit(b.lamps_off(at)));

    // Laser.
    reg!(engine, state, "laser_arm", |b, at| unit(
        b.push(at, Action::LaserArm)
    ));
    reg!(engine, state, "laser_on", |b, at, colour| unit(
        b.laser_on(at, colour)
    ));
    reg!(engine, state, "laser_off", |b, at| unit(b.laser_off(at)));
    reg!(engine, state, "laser_disarm", |b, at| unit(
        b.push(at, Action::LaserDisarm)
    ));
    reg!(engine, state, "laser_sweep", |b, at, opts| unit(
        b.laser_sweep(at, opts)
    ));

    // Capture.
    reg!(engine, state, "capture", |b, at, exposures| unit(
        b.capture(at, exposures, None)
    ));
    reg!(engine, state, "capture", |b, at, exposures, opts| {
        unit(b.capture(at, exposures, Some(opts)))
    });

    // Cart, operator, time.
    reg!(engine, state, "cart_to", |b, at, mm| {
        let position_mm = number("the cart position (mm)", &mm)?;
        unit(b.push(at, Action::CartTo { position_mm }))
    });
    reg!(engine, state, "prompt", |b, at, message| unit(
        b.prompt(at, message, None)
    ));
    reg!(engine, state, "prompt", |b, at, message, opts| unit(
        b.prompt(at, message, Some(opts))
    ));
    reg!(engine, state, "wait", |b, at, seconds| {
        let seconds = non_negative("the wait (s)", &seconds)?;
        unit(b.push(at, Action::Wait { seconds }))
    });

    // Blocks: push the name, run the closure without holding the lock, pop the name.
    let s = state.clone();
    engine.register_fn(
        "block",
        move |ctx: NativeCallContext, name: Dynamic, body: Dynamic| -> RhaiResult {
            let (name, body) = (name.flatten(), body.flatten());
            let body = with(&s, &ctx, |b, _at| {
                let name = string("the block name", &name)?;
                if name.is_empty() || name.contains('/') {
                    return api(format!(
                        "block name `{name}` must be non-empty and must not contain `/` (it separates nested blocks)"
                    ));
                }
                if !body.is_fnptr() {
                    return api(format!("the block body must be a closure `|| {{ ... }}`, got {}", describe(&body)));
                }
                b.blocks.push(name);
                Ok(body)
            })?;
            let result = match body.try_cast::<FnPtr>() {
                Some(f) => f.call_within_context::<Dynamic>(&ctx, ()),
                None => Ok(Dynamic::UNIT),
            };
            lock(&s).blocks.pop();
            result
        },
    );
}
