//! The rig-file wiring of USB HID relay boards: at most 8 relays (the port is optional: the
//! first board found when unnamed).

use crate::rig::span::{Problem, at};
use crate::rig::{Backend, RigSpec};

/// Channel count of every hid-relay switch bank.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    for (i, b) in spec.switch_banks.iter().enumerate() {
        if b.backend == Backend::HidRelay && b.channels > 8 {
            return Err((
                at("switch_bank", i, "channels"),
                format!(
                    "switch bank `{}`: a USB HID relay board has at most 8 relays, got {}",
                    b.id, b.channels
                ),
            ));
        }
    }
    Ok(())
}
