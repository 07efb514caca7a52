//! The capture API's registration on the Rhai engine: each function a script may call (see
//! `sequences/README.md`), mapped onto the [`Builder`], and the conversion of a failed call
//! into a script error at the call's position with the function's usage.

use rhai::{Dynamic, Engine, EvalAltResult, FnPtr, ImmutableString, NativeCallContext};
use stagehand_devices::rig::LampKind;
use stagehand_simulator::render::config::SimSpec;

use super::args::{ids, non_negative, number, string};
use super::builder::{Builder, Fail, Res, Shared, api, lock};
use super::error::ScriptError;
use super::params::describe;
use crate::plan::{Action, SourcePos};

type RhaiResult = Result<Dynamic, Box<EvalAltResult>>;

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
        "prompt" => {
            "prompt(\"Tilt the checkerboard\", #{fixture: \"checkerboard\", placement: #{tilt_deg: 30.0}})"
        }
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
