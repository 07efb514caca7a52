//! `stagehand devices`: lists serial ports, HID relay boards and cameras, each with the rig-file
//! lines that reference it by a stable id (a `/dev/…/by-id/` link where there is one); with
//! `--check --rig RIG`, connects to each GRBL board of the rig and reports whether its build and
//! settings can work for the rig.

use std::collections::BTreeMap;
use std::path::PathBuf;

use clap::Args;
use stagehand_devices::discover::{Inventory, discover, render_table};
use stagehand_devices::grbl::GrblController;
use stagehand_devices::rig::{AxisSpec, Backend, GRBL_BAUD, RigSpec, load_rig_file};

/// Arguments of `stagehand devices`.
#[derive(Args, Debug)]
pub struct DevicesArgs {
    /// Print the list as JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Connect to every GRBL board of `--rig` and check its build (`$I`) and settings (`$$`)
    /// against the rig (this soft-resets each board).
    #[arg(long, requires = "rig")]
    pub check: bool,
    /// The rig file whose boards `--check` connects to.
    #[arg(long)]
    pub rig: Option<PathBuf>,
}

/// Looks at what is plugged in and prints it, or checks the rig's boards. Returns whether
/// every checked board is fit for the rig.
pub fn run(args: DevicesArgs) -> anyhow::Result<bool> {
    if args.check {
        let path = args.rig.unwrap_or_default();
        let spec = load_rig_file(&path).map_err(|e| anyhow::anyhow!("{e}"))?;
        let (text, ok) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?
            .block_on(check_boards(&spec));
        print!("{text}");
        return Ok(ok);
    }
    print!("{}", render(&discover(), args.json)?);
    Ok(true)
}

/// Connects to every GRBL port of `spec` and reports each: its build, then `ok` or the error
/// (with the `$N=` to send). The second value is true when all are fine.
async fn check_boards(spec: &RigSpec) -> (String, bool) {
    let mut ports: BTreeMap<String, Vec<AxisSpec>> = BTreeMap::new();
    for a in spec.axes.iter().filter(|a| a.backend == Backend::Grbl) {
        ports
            .entry(a.port.clone().unwrap_or_default())
            .or_default()
            .push(a.clone());
    }
    let laser = spec.laser.as_ref().filter(|l| l.backend == Backend::Grbl);
    if let Some(l) = laser {
        ports.entry(l.port.clone().unwrap_or_default()).or_default();
    }
    if ports.is_empty() {
        return (format!("rig `{}` has no GRBL board\n", spec.rig.name), true);
    }
    let mut out = String::new();
    let mut all_ok = true;
    for (port, axes) in ports {
        let ids: Vec<&str> = axes.iter().map(|a| a.id.as_str()).collect();
        let label = ids
            .first()
            .copied()
            .unwrap_or(Backend::Grbl.as_str())
            .to_string();
        let baud = axes.iter().find_map(|a| a.baud).unwrap_or(GRBL_BAUD);
        let ctl = GrblController::new(&label, &port, baud, axes.clone());
        ctl.set_keepalive(false);
        if laser.is_some_and(|l| l.port.as_deref() == Some(port.as_str())) {
            ctl.attach_laser();
        }
        out += &format!("GRBL board on {port} (axes: {})\n", ids.join(", "));
        match ctl.connect().await {
            Ok(build) => {
                let homing = if build.single_axis_homing() {
                    "single-axis homing ($HX)"
                } else {
                    "homes all axes with $H"
                };
                out += &format!(
                    "  GRBL {} (options {}): {homing}\n  ok: fit for the rig\n",
                    build.version, build.options
                );
            }
            Err(e) => {
                all_ok = false;
                out += &format!("  problem: {e}\n");
            }
        }
        if let Some(l) = laser.filter(|l| l.port.as_deref() == Some(port.as_str()))
            && let Some(w) = spec.laser_watchdog()
        {
            out += &format!("  laser `{}`: {}\n", l.id, w.describe());
        }
    }
    (out, all_ok)
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
