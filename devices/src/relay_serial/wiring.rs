//! The rig-file wiring of serial relay boards: each names its port and has at most 32 relays.

use crate::rig::span::{Problem, at, needs_port};
use crate::rig::{Backend, RigSpec};

/// Port and channel count of every relay-serial switch bank.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    for (i, b) in spec.switch_banks.iter().enumerate() {
        if b.backend != Backend::RelaySerial {
            continue;
        }
        let what = format!("switch bank `{}`", b.id);
        needs_port(at("switch_bank", i, "backend"), &what, b.backend, &b.port)?;
        if b.channels > 32 {
            return Err((
                at("switch_bank", i, "channels"),
                format!(
                    "{what}: a serial relay board has at most 32 relays, got {}",
                    b.channels
                ),
            ));
        }
    }
    Ok(())
}
