//! Converting the capture API's arguments (Rhai `Dynamic`s) to plan values: strings, numbers,
//! wavelengths, exposure and camera lists and options maps. A wrong argument is a
//! [`Fail::Api`](super::builder::Fail::Api) saying what was expected and what came.

use rhai::{Dynamic, ImmutableString, Map};
use stagehand_devices::fixture_pose::FixturePose;

use super::builder::{Res, api};
use super::params::describe;

/// A Rhai array of the ids.
pub(crate) fn ids<'a>(it: impl Iterator<Item = &'a str>) -> Dynamic {
    Dynamic::from_array(
        it.map(|s| Dynamic::from(ImmutableString::from(s)))
            .collect(),
    )
}

/// A string argument.
pub(crate) fn string(what: &str, v: &Dynamic) -> Res<String> {
    match v.as_immutable_string_ref() {
        Ok(s) => Ok(s.to_string()),
        Err(_) => api(format!("{what} must be a string, got {}", describe(v))),
    }
}

/// A list of strings.
pub(crate) fn strings(what: &str, v: &Dynamic) -> Res<Vec<String>> {
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

/// A finite number; an integer is accepted too.
pub(crate) fn number(what: &str, v: &Dynamic) -> Res<f64> {
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

/// A finite number that is not negative.
pub(crate) fn non_negative(what: &str, v: &Dynamic) -> Res<f64> {
    let x = number(what, v)?;
    if x < 0.0 {
        return api(format!("{what} must not be negative, got {x}"));
    }
    Ok(x)
}

/// An integer; a float with an integral value (e.g. `3.0`) is accepted too.
pub(crate) fn integer(what: &str, v: &Dynamic) -> Res<i64> {
    let v = v.flatten_clone();
    if let Ok(i) = v.as_int() {
        return Ok(i);
    }
    match v.as_float() {
        Ok(f) if f.is_finite() && f.fract() == 0.0 && f.abs() < 9.0e15 => Ok(f as i64),
        _ => api(format!("{what} must be an integer, got {}", describe(&v))),
    }
}

/// `true` or `false`.
pub(crate) fn boolean(what: &str, v: &Dynamic) -> Res<bool> {
    match v.flatten_clone().as_bool() {
        Ok(b) => Ok(b),
        Err(_) => api(format!("{what} must be true or false, got {}", describe(v))),
    }
}

/// A positive wavelength in nm (an integer).
pub(crate) fn wavelength(what: &str, v: &Dynamic) -> Res<u32> {
    let n = integer(&format!("{what} (nm)"), v)?;
    match u32::try_from(n) {
        Ok(nm) if nm > 0 => Ok(nm),
        _ => api(format!(
            "{what} must be a positive wavelength in nm, got {n}"
        )),
    }
}

/// One exposure in seconds or a non-empty list of them.
pub(crate) fn exposure_list(v: &Dynamic) -> Res<Vec<f64>> {
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

/// A non-empty list of camera ids.
pub(crate) fn camera_list(v: &Dynamic) -> Res<Vec<String>> {
    let list = strings("cameras", v)?;
    if list.is_empty() {
        return api("cameras is empty; name at least one camera or leave the option out for all");
    }
    Ok(list)
}

/// An options map: every key must be in `optional` or `required`, and every required key present.
/// A fixture placement `#{tilt_deg, tilt_toward_deg, turn_deg, x_mm, y_mm, lift_mm}` (every
/// key optional, 0 when left out), checked for sense.
pub(crate) fn fixture_pose(v: &Dynamic) -> Res<FixturePose> {
    let keys = [
        "tilt_deg",
        "tilt_toward_deg",
        "turn_deg",
        "x_mm",
        "y_mm",
        "lift_mm",
    ];
    let map = options(v, &keys, &[])?;
    let mut pose = FixturePose::default();
    for (key, v) in map.iter() {
        let value = number(key, v)?;
        let field = match key.as_str() {
            "tilt_deg" => &mut pose.tilt_deg,
            "tilt_toward_deg" => &mut pose.tilt_toward_deg,
            "turn_deg" => &mut pose.turn_deg,
            "x_mm" => &mut pose.x_mm,
            "y_mm" => &mut pose.y_mm,
            _ => &mut pose.lift_mm,
        };
        *field = value;
    }
    match pose.problem() {
        Some(problem) => api(format!("placement: {problem}")),
        None => Ok(pose),
    }
}

pub(crate) fn options(v: &Dynamic, optional: &[&str], required: &[&str]) -> Res<Map> {
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
