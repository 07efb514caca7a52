//! Plan builders shared by the unit tests of the plan passes (validate, estimate, dry run).

use std::collections::BTreeMap;

use crate::plan::{Action, Plan, SourcePos, Step};

/// A plan of `actions` from `script`, step `i` created at `at(i)` in block "b".
pub(crate) fn plan_at(script: &str, actions: Vec<Action>, at: impl Fn(usize) -> SourcePos) -> Plan {
    let steps = actions
        .into_iter()
        .enumerate()
        .map(|(index, action)| Step {
            index,
            block: "b".into(),
            at: at(index),
            action,
        })
        .collect();
    Plan {
        script: script.into(),
        params: BTreeMap::new(),
        steps,
    }
}

/// A move of the named axes to absolute angles.
pub(crate) fn mv(targets: &[(&str, f64)]) -> Action {
    Action::Move {
        targets: targets.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
    }
}

/// Lamp switches by id.
pub(crate) fn lamps(states: &[(&str, bool)]) -> Action {
    Action::Lamps {
        states: states.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
    }
}
