//! Script parameters: `param(name, default)` and `--set NAME=VALUE` overrides parsed to the
//! default's type, plus the conversion of used values to JSON for `Plan.params`.

use rhai::{Array, Dynamic, ImmutableString};

use super::error::ScriptError;

/// The type of a parameter, taken from its default.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Int,
    Float,
    Bool,
    Str,
    /// A list whose elements are of the given scalar kind.
    List(Scalar),
}

/// The element type of a list parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    Int,
    Float,
    Bool,
    Str,
}

impl Kind {
    /// The expected type in words, for error messages.
    pub(crate) fn expected(self) -> String {
        match self {
            Kind::Int => "an integer (e.g. 12)".into(),
            Kind::Float => "a finite number (e.g. 0.5 or 2)".into(),
            Kind::Bool => "true or false".into(),
            Kind::Str => "a string".into(),
            Kind::List(s) => {
                let example = match s {
                    Scalar::Int => "1,2,3",
                    Scalar::Float => "0.01,0.04",
                    Scalar::Bool => "true,false",
                    Scalar::Str => "cam1,cam2",
                };
                format!(
                    "a comma-separated list of {} (e.g. {example} or [{example}])",
                    s.plural()
                )
            }
        }
    }
}

impl Scalar {
    fn plural(self) -> &'static str {
        match self {
            Scalar::Int => "integers",
            Scalar::Float => "finite numbers",
            Scalar::Bool => "true/false values",
            Scalar::Str => "strings",
        }
    }

    fn of(v: &Dynamic) -> Option<Scalar> {
        if v.is_int() {
            Some(Scalar::Int)
        } else if v.is_float() {
            Some(Scalar::Float)
        } else if v.is_bool() {
            Some(Scalar::Bool)
        } else if v.is_string() {
            Some(Scalar::Str)
        } else {
            None
        }
    }

    fn parse(self, text: &str) -> Option<Dynamic> {
        let t = text.trim();
        match self {
            Scalar::Int => t.parse::<i64>().ok().map(Dynamic::from_int),
            Scalar::Float => t
                .parse::<f64>()
                .ok()
                .filter(|f| f.is_finite())
                .map(Dynamic::from_float),
            Scalar::Bool => match t.to_ascii_lowercase().as_str() {
                "true" => Some(Dynamic::from_bool(true)),
                "false" => Some(Dynamic::from_bool(false)),
                _ => None,
            },
            Scalar::Str => {
                let unquoted = t
                    .strip_prefix('"')
                    .and_then(|s| s.strip_suffix('"'))
                    .or_else(|| t.strip_prefix('\'').and_then(|s| s.strip_suffix('\'')))
                    .unwrap_or(t);
                Some(Dynamic::from(ImmutableString::from(unquoted)))
            }
        }
    }
}

/// Why a value cannot be a parameter default.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum DefaultError {
    /// An infinite or NaN number.
    #[error("the default must be a finite number")]
    NotFinite,
    /// A list holding something other than integers, numbers, bools or strings.
    #[error("a list default may only hold integers, numbers, bools or strings")]
    BadListItem,
    /// A list holding an infinite or NaN number.
    #[error("the default list must hold finite numbers")]
    ListNotFinite,
    /// A list mixing types (other than integers with numbers).
    #[error("all items of a list default must have the same type")]
    MixedList,
    /// Neither a scalar nor a list; the value is described.
    #[error(
        "a parameter default must be an integer, a number, a bool, a string or a list of those, got {0}"
    )]
    Unsupported(String),
}

/// The kind of a default value, or why it cannot be a parameter default.
pub(crate) fn kind_of(default: &Dynamic) -> Result<Kind, DefaultError> {
    if default.is_int() {
        return Ok(Kind::Int);
    }
    if let Ok(f) = default.as_float() {
        if !f.is_finite() {
            return Err(DefaultError::NotFinite);
        }
        return Ok(Kind::Float);
    }
    if default.is_bool() {
        return Ok(Kind::Bool);
    }
    if default.is_string() {
        return Ok(Kind::Str);
    }
    if let Ok(items) = default.as_array_ref() {
        let mut kind: Option<Scalar> = None;
        for item in items.iter() {
            let item = item.flatten_clone();
            let Some(s) = Scalar::of(&item) else {
                return Err(DefaultError::BadListItem);
            };
            if let Ok(f) = item.as_float()
                && !f.is_finite()
            {
                return Err(DefaultError::ListNotFinite);
            }
            kind = Some(match (kind, s) {
                (None, s) => s,
                (Some(a), b) if a == b => a,
                (Some(Scalar::Int), Scalar::Float) | (Some(Scalar::Float), Scalar::Int) => {
                    Scalar::Float
                }
                _ => return Err(DefaultError::MixedList),
            });
        }
        // An empty default list takes numbers.
        return Ok(Kind::List(kind.unwrap_or(Scalar::Float)));
    }
    Err(DefaultError::Unsupported(describe(default)))
}

/// Parses a `--set` value to the given kind; `None` when it does not parse.
pub(crate) fn parse_value(kind: Kind, text: &str) -> Option<Dynamic> {
    match kind {
        Kind::Int => Scalar::Int.parse(text),
        Kind::Float => Scalar::Float.parse(text),
        Kind::Bool => Scalar::Bool.parse(text),
        Kind::Str => Some(Dynamic::from(ImmutableString::from(text))),
        Kind::List(s) => {
            let t = text.trim();
            let inner = t
                .strip_prefix('[')
                .and_then(|r| r.strip_suffix(']'))
                .unwrap_or(t);
            if inner.trim().is_empty() {
                return Some(Dynamic::from_array(Array::new()));
            }
            let items = inner
                .split(',')
                .map(|part| s.parse(part))
                .collect::<Option<Array>>()?;
            Some(Dynamic::from_array(items))
        }
    }
}

/// Converts a default to its kind: an integer in a float list becomes a float, so that
/// scripts see a consistent type whether or not the value was overridden.
pub(crate) fn normalise(kind: Kind, value: Dynamic) -> Dynamic {
    match kind {
        Kind::Float => match value.as_int() {
            Ok(i) => Dynamic::from_float(i as f64),
            Err(_) => value,
        },
        Kind::List(Scalar::Float) => match value.into_array() {
            Ok(items) => Dynamic::from_array(
                items
                    .into_iter()
                    .map(|v| {
                        let v = v.flatten();
                        match v.as_int() {
                            Ok(i) => Dynamic::from_float(i as f64),
                            Err(_) => v,
                        }
                    })
                    .collect(),
            ),
            Err(_) => Dynamic::UNIT,
        },
        _ => value,
    }
}

/// The JSON form of a parameter value (scalars and lists of scalars).
pub(crate) fn to_json(value: &Dynamic) -> serde_json::Value {
    let value = value.flatten_clone();
    if let Ok(i) = value.as_int() {
        return serde_json::Value::from(i);
    }
    if let Ok(f) = value.as_float() {
        return serde_json::Number::from_f64(f)
            .map(serde_json::Value::Number)
            .unwrap_or(serde_json::Value::Null);
    }
    if let Ok(b) = value.as_bool() {
        return serde_json::Value::Bool(b);
    }
    if let Ok(s) = value.as_immutable_string_ref() {
        return serde_json::Value::String(s.to_string());
    }
    if let Ok(items) = value.as_array_ref() {
        return serde_json::Value::Array(items.iter().map(to_json).collect());
    }
    serde_json::Value::Null
}

/// Whether `name` is a valid parameter name: a Rhai-style identifier.
pub(crate) fn valid_name(name: &str) -> bool {
    let mut chars = name.chars();
    match chars.next() {
        Some(c) if c.is_ascii_alphabetic() || c == '_' => {}
        _ => return false,
    }
    chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Parses one `--set NAME=VALUE` argument.
pub fn parse_set(arg: &str) -> Result<(String, String), ScriptError> {
    let Some((name, value)) = arg.split_once('=') else {
        return Err(ScriptError::BadSet {
            arg: arg.to_string(),
            message: "expected NAME=VALUE, e.g. --set views=4".into(),
        });
    };
    if !valid_name(name) {
        return Err(ScriptError::BadSet {
            arg: arg.to_string(),
            message: format!(
                "`{name}` is not a parameter name; names start with a letter or _ and hold only letters, digits and _ (e.g. --set views=4)"
            ),
        });
    }
    Ok((name.to_string(), value.to_string()))
}

/// A value's type in words, for error messages.
pub(crate) fn describe(v: &Dynamic) -> String {
    let v = v.flatten_clone();
    let what = if v.is_unit() {
        "nothing (())"
    } else if v.is_int() {
        "an integer"
    } else if v.is_float() {
        "a float"
    } else if v.is_bool() {
        "a bool"
    } else if v.is_string() {
        "a string"
    } else if v.is_char() {
        "a character"
    } else if v.is_array() {
        "an array"
    } else if v.is_map() {
        "an object map"
    } else if v.is_fnptr() {
        "a function"
    } else {
        return v.type_name().to_string();
    };
    what.to_string()
}
