//! Where a problem in a rig file is: a path of keys and indices into the TOML document
//! ([`Seg`]), its byte offset in the text ([`locate`]) and its 1-based line and column
//! ([`line_col`]). Every rig-file check (the schema checks in `load`, the wiring checks of
//! `wiring` and of each backend beside its driver) returns a [`Problem`] built from these; the
//! simulator uses them for `[sim]`.

use toml::de::{DeTable, DeValue};

/// A step into a TOML document: a key or an index into an array (of tables or values). Paths
/// of steps name the value an error is about, for [`locate`].
#[derive(Debug, Clone)]
pub enum Seg {
    /// A key of the current table.
    Key(&'static str),
    /// An element of the current array.
    Index(usize),
}

/// A problem in a rig file: the path of the value to blame and a sentence saying what is
/// expected.
pub type Problem = (Vec<Seg>, String);

/// The path of `key` in the `index`-th `[[table]]` of the rig file.
pub fn at(table: &'static str, index: usize, key: &'static str) -> Vec<Seg> {
    vec![Seg::Key(table), Seg::Index(index), Seg::Key(key)]
}

/// The path of `key` in the single `[table]` of the rig file.
pub fn key(table: &'static str, key: &'static str) -> Vec<Seg> {
    vec![Seg::Key(table), Seg::Key(key)]
}

/// The problem of a device whose backend needs a port the rig file does not give (`what`
/// names the device, `b` its backend), blamed at `path`; `Ok` if the port is there.
pub fn needs_port(
    path: Vec<Seg>,
    what: &str,
    b: super::Backend,
    port: &Option<String>,
) -> Result<(), Problem> {
    match port {
        Some(p) if !p.trim().is_empty() => Ok(()),
        _ => Err((
            path,
            format!(
                "{what}: backend `{}` needs `port`, e.g. a /dev/serial/by-id/... path (list them with `stagehand devices`)",
                b.as_str()
            ),
        )),
    }
}

/// Byte offset in `text` of the value at `path`, or of the deepest part of it that exists;
/// `None` when the text does not parse or not even the first step exists.
pub fn locate(text: &str, path: &[Seg]) -> Option<usize> {
    let root = DeTable::parse(text).ok()?;
    let mut best = None;
    let mut table: &DeTable = root.get_ref();
    let mut current: Option<&DeValue> = None;
    for seg in path {
        let next = match (seg, current) {
            (Seg::Key(k), None) => table
                .iter()
                .find(|(key, _)| key.get_ref() == k)
                .map(|(_, v)| v),
            (Seg::Key(k), Some(DeValue::Table(t))) => {
                t.iter().find(|(key, _)| key.get_ref() == k).map(|(_, v)| v)
            }
            (Seg::Index(i), Some(DeValue::Array(a))) => a.get(*i),
            _ => None,
        };
        let Some(next) = next else { break };
        best = Some(next.span().start);
        if let DeValue::Table(t) = next.get_ref() {
            table = t;
        }
        current = Some(next.get_ref());
    }
    best
}

/// 1-based line and column (in characters) of a byte offset into `text`.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rsplit('\n')
        .next()
        .map(|l| l.chars().count())
        .unwrap_or(0)
        + 1;
    (line, col)
}
