//! `stagehand devices`: lists serial ports, HID relay boards and cameras, each with the rig-file
//! lines that reference it by a stable id (a `/dev/…/by-id/` link where there is one).

use clap::Args;
use stagehand_devices::discover::{Inventory, discover, render_table};

/// Arguments of `stagehand devices`.
#[derive(Args, Debug)]
pub struct DevicesArgs {
    /// Print the list as JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Looks at what is plugged in and prints it.
pub fn run(args: DevicesArgs) -> anyhow::Result<()> {
    print!("{}", render(&discover(), args.json)?);
    Ok(())
}

/// The output for `inv`: pretty JSON or the human table.
fn render(inv: &Inventory, json: bool) -> anyhow::Result<String> {
    if json {
        Ok(serde_json::to_string_pretty(inv)? + "\n")
    } else {
        Ok(render_table(inv))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stagehand_devices::discover::hid_relay_entry;

    #[test]
    fn json_and_table() {
        let inv = Inventory {
            hid_relays: vec![hid_relay_entry(
                "/dev/hidraw0".into(),
                Some("ABCDE".into()),
                Some(4),
            )],
            ..Inventory::default()
        };
        let j: serde_json::Value =
            serde_json::from_str(&render(&inv, true).expect("json")).expect("valid json");
        assert_eq!(j["hid_relays"][0]["serial"], "ABCDE");
        assert_eq!(j["serial"].as_array().map(Vec::len), Some(0));
        let t = render(&inv, false).expect("table");
        assert!(
            t.contains("HID relay boards (1):") && t.contains("/dev/hidraw0"),
            "{t}"
        );
    }
}
