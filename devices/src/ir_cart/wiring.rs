//! The rig-file wiring of the reflectometer cart's IR link: the bridge's port, and the Power
//! Functions channel, output and speed step the cart's receiver is set to.

use crate::rig::span::{Problem, key, needs_port};
use crate::rig::{Backend, RigSpec};

/// The cart's port (backend `ir-bridge`) and Power Functions settings.
pub(crate) fn check(spec: &RigSpec) -> Result<(), Problem> {
    let Some(c) = &spec.cart else {
        return Ok(());
    };
    let what = format!("cart `{}`", c.id);
    if c.backend == Backend::IrBridge {
        needs_port(key("cart", "backend"), &what, c.backend, &c.port)?;
    }
    if !(1..=4).contains(&c.ir_channel) {
        return Err((
            key("cart", "ir_channel"),
            format!(
                "{what}: ir_channel must be 1–4 (the receiver's channel switch), got {}",
                c.ir_channel
            ),
        ));
    }
    if c.ir_output != "A" && c.ir_output != "B" {
        return Err((
            key("cart", "ir_output"),
            format!(
                "{what}: ir_output must be \"A\" or \"B\", got `{}`",
                c.ir_output
            ),
        ));
    }
    if !(1..=7).contains(&c.ir_speed_step) {
        return Err((
            key("cart", "ir_speed_step"),
            format!("{what}: ir_speed_step must be 1–7, got {}", c.ir_speed_step),
        ));
    }
    Ok(())
}
