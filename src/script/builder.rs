//! The plan builder behind the capture API: the state a running script has produced (steps,
//! parameters, the block stack, the first error) and one method per API call that checks its
//! arguments and appends steps. Nothing here touches a device; the functions a script calls
//! are registered in `register.rs`.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};

use rhai::Dynamic;
use stagehand_devices::rig::{LampKind, RigSpec};

use super::args::{
    boolean, camera_list, exposure_list, fixture_pose, ids, integer, non_negative, number, options,
    string, strings, wavelength,
};
use super::error::ScriptError;
use super::params::{describe, kind_of, normalise, parse_value, to_json, valid_name};
use crate::plan::{Action, SourcePos, Step};

/// The builder state shared by every registered function.
pub(crate) type Shared = Arc<Mutex<Builder>>;

/// A parameter the script declared.
struct Declared {
    at: SourcePos,
    default_json: serde_json::Value,
    value: Dynamic,
}

/// Everything a running script has produced so far.
pub(crate) struct Builder {
    pub(crate) file: String,
    pub(crate) rig: Arc<RigSpec>,
    pub(crate) steps: Vec<Step>,
    /// The names of the enclosing `block(...)`s, outermost first.
    pub(crate) blocks: Vec<String>,
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

/// The result of an API call.
pub(crate) type Res<T> = Result<T, Fail>;

/// A [`Fail::Api`] with `message`.
pub(crate) fn api<T>(message: impl Into<String>) -> Res<T> {
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

    pub(crate) fn push(&mut self, at: SourcePos, action: Action) -> Res<()> {
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

    pub(crate) fn param(&mut self, at: SourcePos, name: Dynamic, default: Dynamic) -> Res<Dynamic> {
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

    pub(crate) fn lamps_of_kind(&self, kind: Dynamic) -> Res<Dynamic> {
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

    pub(crate) fn laser(&self) -> Res<&stagehand_devices::rig::LaserSpec> {
        match &self.rig.laser {
            Some(l) => Ok(l),
            None => api(format!(
                "rig `{}` has no laser; guard laser steps with `if has_laser() {{ ... }}` or use a rig with a laser",
                self.rig.rig.name
            )),
        }
    }

    // ---- motion -----------------------------------------------------------------------------

    pub(crate) fn home(&mut self, at: SourcePos, which: Option<Dynamic>) -> Res<()> {
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

    pub(crate) fn move_axis(&mut self, at: SourcePos, axis: Dynamic, deg: Dynamic) -> Res<()> {
        let axis = string("the axis", &axis)?;
        let deg = number("the angle in degrees", &deg)?;
        self.push(
            at,
            Action::Move {
                targets: BTreeMap::from([(axis, deg)]),
            },
        )
    }

    pub(crate) fn move_map(&mut self, at: SourcePos, targets: Dynamic) -> Res<()> {
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

    pub(crate) fn lamp(&mut self, at: SourcePos, id: Dynamic, on: Dynamic) -> Res<()> {
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

    pub(crate) fn lamps_on(&mut self, at: SourcePos, list: Dynamic) -> Res<()> {
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

    pub(crate) fn only_lamp(&mut self, at: SourcePos, id: Dynamic) -> Res<()> {
        let id = string("the lamp id", &id)?;
        let mut states: BTreeMap<String, bool> = self
            .all_lamp_ids()
            .into_iter()
            .map(|l| (l, false))
            .collect();
        states.insert(id, true);
        self.push(at, Action::Lamps { states })
    }

    pub(crate) fn lamps_off(&mut self, at: SourcePos) -> Res<()> {
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

    pub(crate) fn laser_on(&mut self, at: SourcePos, colour: Dynamic) -> Res<()> {
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

    pub(crate) fn laser_off(&mut self, at: SourcePos) -> Res<()> {
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

    pub(crate) fn capture(
        &mut self,
        at: SourcePos,
        exposures: Dynamic,
        opts: Option<Dynamic>,
    ) -> Res<()> {
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

    pub(crate) fn laser_sweep(&mut self, at: SourcePos, opts: Dynamic) -> Res<()> {
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

    pub(crate) fn prompt(
        &mut self,
        at: SourcePos,
        message: Dynamic,
        opts: Option<Dynamic>,
    ) -> Res<()> {
        let message = string("the message", &message)?;
        let mut fixture = None;
        let mut placement = None;
        let mut laser_mount_deg = None;
        let mut laser_fit_nm = None;
        if let Some(opts) = opts {
            let map = options(
                &opts,
                &["fixture", "placement", "laser_mount_deg", "laser_fit_nm"],
                &[],
            )?;
            for (key, v) in map.iter() {
                match key.as_str() {
                    "fixture" => fixture = Some(string("fixture", v)?),
                    "placement" => placement = Some(fixture_pose(v)?),
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
                placement,
                laser_mount_deg,
                laser_fit_nm,
            },
        )
    }
}

/// Locks the builder; a poisoned lock (a panic elsewhere) still yields the data.
pub(crate) fn lock(state: &Shared) -> MutexGuard<'_, Builder> {
    state.lock().unwrap_or_else(|e| e.into_inner())
}
