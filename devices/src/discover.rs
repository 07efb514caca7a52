//! `stagehand devices`: what is plugged in — serial ports, HID relay boards, cameras — with
//! the stable path (a `/dev/…/by-id/` link where there is one) to put in the rig file.
//!
//! Every function that looks at the file system takes its root directories as arguments, so
//! the matching logic is tested on a fake `/sys` and `/dev` tree.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::rig::Backend;

/// One serial port.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SerialEntry {
    /// Kernel device node, e.g. `/dev/ttyACM0` (changes with plug order).
    pub path: String,
    /// `/dev/serial/by-id/…` link to it (stable), if udev made one.
    pub by_id: Option<String>,
    pub vid: Option<u16>,
    pub pid: Option<u16>,
    pub serial_number: Option<String>,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    /// What this USB id usually is on a stagehand rig (a guess from VID:PID).
    pub likely: Option<String>,
    /// Rig-file lines that reference the port by its stable path.
    pub rig_snippet: String,
}

/// One dcttech-compatible USB HID relay board.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HidRelayEntry {
    /// hidraw node, e.g. `/dev/hidraw3`.
    pub path: String,
    /// The board's 5-character serial (its stable id), if it could be read.
    pub serial: Option<String>,
    pub channels: Option<u32>,
    pub rig_snippet: String,
}

/// One camera.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraEntry {
    /// Rig backend: `v4l`, `aravis` or `gphoto2` (serialised as the rig file spells it).
    pub backend: Backend,
    /// Device node (`/dev/video0`), GenICam id or gphoto2 port.
    pub path: String,
    /// Stable `/dev/v4l/by-id/…` link (V4L2 only), if udev made one.
    pub by_id: Option<String>,
    /// Name the device reports.
    pub name: String,
    /// V4L2 node index within its device (0 is the capture node; others are metadata).
    pub index: Option<u32>,
    pub rig_snippet: String,
}

/// Everything found.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Inventory {
    pub serial: Vec<SerialEntry>,
    pub hid_relays: Vec<HidRelayEntry>,
    pub cameras: Vec<CameraEntry>,
}

/// Looks at the real system: serial ports, HID relays, V4L2 cameras, and aravis/gphoto2
/// cameras when those features are built in. Never panics; what cannot be read is left out.
pub fn discover() -> Inventory {
    let ports: Vec<PortFacts> = serialport::available_ports()
        .unwrap_or_default()
        .iter()
        .map(PortFacts::from)
        .collect();
    let mut cameras = v4l_cameras(Path::new("/sys"), Path::new("/dev"));
    cameras.extend(library_cameras());
    Inventory {
        serial: serial_entries(&ports, Path::new("/dev/serial/by-id")),
        hid_relays: hid_relays(),
        cameras,
    }
}

// INTEGRATOR: HID relays. Once `devices/src/hid_relay/` is in lib.rs, replace the body with:
//     crate::hid_relay::list_hid_relays().into_iter()
//         .map(|r| hid_relay_entry(r.path, r.serial, r.channels)).collect()
/// HID relay boards (see the integrator note above: empty until `hid_relay` is wired).
fn hid_relays() -> Vec<HidRelayEntry> {
    Vec::new()
}

/// A HID relay entry with its rig snippet (the board serial is the stable id).
pub fn hid_relay_entry(
    path: String,
    serial: Option<String>,
    channels: Option<u32>,
) -> HidRelayEntry {
    let port = serial.clone().unwrap_or_else(|| path.clone());
    let rig_snippet = format!(
        "[[switch_bank]]\nid = \"relays\"\nbackend = \"{}\"\nport = \"{port}\"\nchannels = {}",
        Backend::HidRelay.as_str(),
        channels.unwrap_or(8)
    );
    HidRelayEntry {
        path,
        serial,
        channels,
        rig_snippet,
    }
}

/// Every symlink in `dir` with the canonical path it points to (links that do not resolve
/// are skipped). Sorted by link name.
pub fn resolve_links(dir: &Path) -> Vec<(PathBuf, PathBuf)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<(PathBuf, PathBuf)> = entries
        .filter_map(|e| {
            let link = e.ok()?.path();
            let target = std::fs::canonicalize(&link).ok()?;
            Some((link, target))
        })
        .collect();
    out.sort();
    out
}

/// The first link among `links` that resolves to `device`.
pub fn link_for(links: &[(PathBuf, PathBuf)], device: &Path) -> Option<PathBuf> {
    let device = std::fs::canonicalize(device).unwrap_or_else(|_| device.to_path_buf());
    links
        .iter()
        .find(|(_, target)| *target == device)
        .map(|(link, _)| link.clone())
}

/// What a USB id usually is on a stagehand rig.
pub fn likely_device(vid: u16, pid: u16) -> Option<String> {
    let (grbl, ir) = (Backend::Grbl.as_str(), Backend::IrBridge.as_str());
    let either = |board: &str| format!("{board} ({grbl}) or IR bridge ({ir})");
    match (vid, pid) {
        (0x2341, 0x0043 | 0x0001 | 0x0010 | 0x0042) => Some(either("Arduino: GRBL controller")),
        (0x1a86, 0x7523) => Some(either("CH340 USB serial: GRBL clone")),
        (0x0403, 0x6001) => Some(either("FTDI USB serial: GRBL")),
        (0x10c4, 0xea60) => Some(either("CP210x USB serial: GRBL")),
        (0x2a19, _) => Some(format!(
            "Numato relay board ({})",
            Backend::RelaySerial.as_str()
        )),
        _ => None,
    }
}

/// The backend a serial port's rig snippet proposes: a Numato board's vendor id means a
/// relay board, anything else most likely a GRBL controller.
fn likely_backend(usb: Option<(u16, u16)>) -> Backend {
    match usb {
        Some((0x2a19, _)) => Backend::RelaySerial,
        _ => Backend::Grbl,
    }
}

/// What the enumeration says about one serial port (the part of `serialport`'s info we use).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PortFacts {
    pub path: String,
    /// USB vendor/product ids, serial, manufacturer and product (USB ports only).
    pub usb: Option<(u16, u16)>,
    pub serial_number: Option<String>,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
}

impl From<&serialport::SerialPortInfo> for PortFacts {
    fn from(p: &serialport::SerialPortInfo) -> Self {
        match &p.port_type {
            serialport::SerialPortType::UsbPort(u) => Self {
                path: p.port_name.clone(),
                usb: Some((u.vid, u.pid)),
                serial_number: u.serial_number.clone(),
                manufacturer: u.manufacturer.clone(),
                product: u.product.clone(),
            },
            _ => Self {
                path: p.port_name.clone(),
                ..Self::default()
            },
        }
    }
}

/// Serial entries for `ports`, matched to the links in `by_id_dir`.
pub fn serial_entries(ports: &[PortFacts], by_id_dir: &Path) -> Vec<SerialEntry> {
    let links = resolve_links(by_id_dir);
    let mut out: Vec<SerialEntry> = ports
        .iter()
        .map(|p| {
            let by_id = link_for(&links, Path::new(&p.path)).map(|l| l.display().to_string());
            let likely = p.usb.and_then(|(v, d)| likely_device(v, d));
            let stable = by_id.clone().unwrap_or_else(|| p.path.clone());
            let backend = likely_backend(p.usb);
            let table = if backend == Backend::RelaySerial {
                "switch_bank"
            } else {
                "axis"
            };
            let rig_snippet = format!(
                "[[{table}]]\nbackend = \"{}\"\nport = \"{stable}\"",
                backend.as_str()
            );
            SerialEntry {
                path: p.path.clone(),
                by_id,
                vid: p.usb.map(|u| u.0),
                pid: p.usb.map(|u| u.1),
                serial_number: p.serial_number.clone(),
                manufacturer: p.manufacturer.clone(),
                product: p.product.clone(),
                likely,
                rig_snippet,
            }
        })
        .collect();
    out.sort_by(|a, b| a.path.cmp(&b.path));
    out
}

/// V4L2 devices from `<sys_root>/class/video4linux/*` (name, index) with their nodes under
/// `dev_root` and `<dev_root>/v4l/by-id` links.
pub fn v4l_cameras(sys_root: &Path, dev_root: &Path) -> Vec<CameraEntry> {
    let Ok(entries) = std::fs::read_dir(sys_root.join("class/video4linux")) else {
        return Vec::new();
    };
    let links = resolve_links(&dev_root.join("v4l/by-id"));
    let read = |p: PathBuf| {
        std::fs::read_to_string(p)
            .ok()
            .map(|s| s.trim().to_string())
    };
    let mut out: Vec<CameraEntry> = entries
        .filter_map(|e| {
            let e = e.ok()?;
            let node = e.file_name().to_string_lossy().into_owned();
            if !node.starts_with("video") {
                return None;
            }
            let name = read(e.path().join("name")).unwrap_or_default();
            let index = read(e.path().join("index")).and_then(|s| s.parse().ok());
            let path = dev_root.join(&node);
            let by_id = link_for(&links, &path).map(|l| l.display().to_string());
            let stable = by_id.clone().unwrap_or_else(|| path.display().to_string());
            Some(CameraEntry {
                backend: Backend::V4l,
                path: path.display().to_string(),
                by_id,
                rig_snippet: format!(
                    "[[camera]]\nbackend = \"{}\"\nport = \"{stable}\"",
                    Backend::V4l.as_str()
                ),
                name,
                index,
            })
        })
        .collect();
    out.sort_by_key(|c| (c.path.len(), c.path.clone()));
    out
}

/// Cameras only the optional libraries can see.
fn library_cameras() -> Vec<CameraEntry> {
    #[allow(unused_mut)]
    let mut out = Vec::new();
    #[cfg(feature = "cam-aravis")]
    out.extend(aravis_cameras());
    #[cfg(feature = "cam-gphoto2")]
    out.extend(gphoto2_cameras());
    out
}

#[cfg(feature = "cam-aravis")]
fn aravis_cameras() -> Vec<CameraEntry> {
    crate::cameras::aravis::list_devices()
        .into_iter()
        .map(|d| {
            let serial = if d.serial.is_empty() {
                "-".to_string()
            } else {
                d.serial.clone()
            };
            // The id is stable (vendor, model, serial); the address may change with DHCP.
            let rig_snippet = format!(
                "[[camera]]\nbackend = \"{}\"\nport = \"{}\"  # or the address \"{}\" or the serial \"{}\"",
                Backend::Aravis.as_str(),
                d.id,
                d.address,
                serial
            );
            CameraEntry {
                backend: Backend::Aravis,
                name: format!(
                    "{} {} ({}) at {}, serial {serial}",
                    d.vendor, d.model, d.protocol, d.address
                ),
                path: d.id,
                by_id: None,
                index: None,
                rig_snippet,
            }
        })
        .collect()
}

#[cfg(feature = "cam-gphoto2")]
fn gphoto2_cameras() -> Vec<CameraEntry> {
    let Ok(ctx) = gphoto2::Context::new() else {
        return Vec::new();
    };
    let Ok(list) = ctx.list_cameras().wait() else {
        return Vec::new();
    };
    list.map(|d| CameraEntry {
        backend: Backend::Gphoto2,
        rig_snippet: format!(
            "[[camera]]\nbackend = \"{}\"\nport = \"{}\"  # or the model name if it is the only one",
            Backend::Gphoto2.as_str(),
            d.port
        ),
        path: d.port,
        by_id: None,
        name: d.model,
        index: None,
    })
    .collect()
}

fn opt<T: std::fmt::Display>(v: &Option<T>) -> String {
    v.as_ref()
        .map_or_else(|| "-".to_string(), |v| v.to_string())
}

/// The human-readable report: one section per kind, each entry with its rig snippet.
pub fn render_table(inv: &Inventory) -> String {
    let mut s = String::new();
    let indent = |snippet: &str| {
        snippet
            .lines()
            .map(|l| format!("      {l}\n"))
            .collect::<String>()
    };
    let _ = writeln!(s, "Serial ports ({}):", inv.serial.len());
    if inv.serial.is_empty() {
        let _ = writeln!(s, "  none (is the board plugged in? `dmesg | tail`)");
    }
    for p in &inv.serial {
        let usb = match (p.vid, p.pid) {
            (Some(v), Some(d)) => format!("{v:04x}:{d:04x}"),
            _ => "-".into(),
        };
        let _ = writeln!(
            s,
            "  {}  usb {usb}  serial {}",
            p.path,
            opt(&p.serial_number)
        );
        let _ = writeln!(s, "    {} / {}", opt(&p.manufacturer), opt(&p.product));
        let _ = writeln!(s, "    by-id: {}", opt(&p.by_id));
        if let Some(l) = &p.likely {
            let _ = writeln!(s, "    likely: {l}");
        }
        let _ = write!(s, "    rig file:\n{}", indent(&p.rig_snippet));
    }
    let _ = writeln!(s, "HID relay boards ({}):", inv.hid_relays.len());
    if inv.hid_relays.is_empty() {
        let _ = writeln!(s, "  none");
    }
    for r in &inv.hid_relays {
        let _ = writeln!(
            s,
            "  {}  serial {}  channels {}",
            r.path,
            opt(&r.serial),
            opt(&r.channels)
        );
        let _ = write!(s, "    rig file:\n{}", indent(&r.rig_snippet));
    }
    let _ = writeln!(s, "Cameras ({}):", inv.cameras.len());
    if inv.cameras.is_empty() {
        let _ = writeln!(s, "  none");
    }
    for c in &inv.cameras {
        let idx = c.index.map(|i| format!("  index {i}")).unwrap_or_default();
        let _ = writeln!(s, "  [{}] {}  {}{idx}", c.backend.as_str(), c.path, c.name);
        if c.by_id.is_some() {
            let _ = writeln!(s, "    by-id: {}", opt(&c.by_id));
        }
        if c.index.is_some_and(|i| i != 0) {
            let _ = writeln!(s, "    (not the capture node: use index 0 of this camera)");
        } else {
            let _ = write!(s, "    rig file:\n{}", indent(&c.rig_snippet));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    /// A scratch directory removed on drop (no tempfile dependency in this crate).
    struct Scratch(PathBuf);
    impl Scratch {
        fn new(tag: &str) -> Self {
            let p = std::env::temp_dir()
                .join(format!("stagehand-discover-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).expect("scratch dir");
            Self(p)
        }
    }
    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn write(p: &Path, s: &str) {
        std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
        std::fs::write(p, s).expect("write");
    }

    #[test]
    fn v4l_nodes_are_matched_to_their_by_id_links() {
        let t = Scratch::new("v4l");
        let (sys, dev) = (t.0.join("sys"), t.0.join("dev"));
        for (n, name, idx) in [
            ("video0", "HD Pro Webcam C920", 0),
            ("video1", "HD Pro Webcam C920", 1),
            ("video2", "Dummy", 0),
        ] {
            write(
                &sys.join(format!("class/video4linux/{n}/name")),
                &format!("{name}\n"),
            );
            write(
                &sys.join(format!("class/video4linux/{n}/index")),
                &format!("{idx}\n"),
            );
            write(&dev.join(n), "");
        }
        std::fs::create_dir_all(dev.join("v4l/by-id")).expect("mkdir");
        symlink(
            "../../video0",
            dev.join("v4l/by-id/usb-046d_C920_ABC-video-index0"),
        )
        .expect("link");
        symlink(
            "../../video1",
            dev.join("v4l/by-id/usb-046d_C920_ABC-video-index1"),
        )
        .expect("link");
        symlink("../../gone", dev.join("v4l/by-id/usb-broken")).expect("link");
        let cams = v4l_cameras(&sys, &dev);
        assert_eq!(cams.len(), 3);
        let c0 = &cams[0];
        assert_eq!(c0.path, dev.join("video0").display().to_string());
        assert_eq!(c0.name, "HD Pro Webcam C920");
        assert_eq!(c0.index, Some(0));
        let link = dev
            .join("v4l/by-id/usb-046d_C920_ABC-video-index0")
            .display()
            .to_string();
        assert_eq!(c0.by_id.as_deref(), Some(link.as_str()));
        assert!(c0.rig_snippet.contains(&format!("port = \"{link}\"")));
        assert!(
            cams[1]
                .by_id
                .as_deref()
                .is_some_and(|l| l.ends_with("index1"))
        );
        assert_eq!(cams[2].by_id, None);
        assert!(cams[2].rig_snippet.contains("video2"));
        let table = render_table(&Inventory {
            cameras: cams,
            ..Inventory::default()
        });
        assert!(table.contains("Cameras (3):"), "{table}");
        assert!(table.contains("not the capture node"), "{table}");
    }

    #[test]
    fn missing_sysfs_gives_nothing() {
        let t = Scratch::new("empty");
        assert!(v4l_cameras(&t.0.join("nope"), &t.0).is_empty());
        assert!(resolve_links(&t.0.join("nope")).is_empty());
    }

    #[test]
    fn serial_ports_get_their_by_id_link_and_a_guess() {
        let t = Scratch::new("serial");
        let dev = t.0.join("dev");
        write(&dev.join("ttyACM0"), "");
        write(&dev.join("ttyUSB0"), "");
        std::fs::create_dir_all(dev.join("serial/by-id")).expect("mkdir");
        symlink(
            "../../ttyACM0",
            dev.join("serial/by-id/usb-Arduino_Uno_8573-if00"),
        )
        .expect("link");
        let port = |name: &str, vid, pid| PortFacts {
            path: dev.join(name).display().to_string(),
            usb: Some((vid, pid)),
            serial_number: Some("8573".into()),
            manufacturer: Some("Arduino".into()),
            product: None,
        };
        let ports = vec![
            port("ttyUSB0", 0x2a19, 0x0c05),
            port("ttyACM0", 0x2341, 0x0043),
        ];
        let entries = serial_entries(&ports, &dev.join("serial/by-id"));
        let acm = &entries[0];
        assert!(acm.path.ends_with("ttyACM0"));
        assert!(
            acm.by_id
                .as_deref()
                .is_some_and(|l| l.ends_with("usb-Arduino_Uno_8573-if00"))
        );
        assert_eq!((acm.vid, acm.pid), (Some(0x2341), Some(0x0043)));
        assert!(acm.likely.as_deref().is_some_and(|l| l.contains("grbl")));
        assert!(acm.rig_snippet.contains("backend = \"grbl\""));
        assert!(
            acm.rig_snippet
                .contains("serial/by-id/usb-Arduino_Uno_8573-if00")
        );
        let usb0 = &entries[1];
        assert_eq!(usb0.by_id, None);
        assert!(
            usb0.rig_snippet.contains("[[switch_bank]]")
                && usb0.rig_snippet.contains("relay-serial")
        );
        let table = render_table(&Inventory {
            serial: entries.clone(),
            hid_relays: vec![hid_relay_entry(
                "/dev/hidraw3".into(),
                Some("QAAMZ".into()),
                Some(2),
            )],
            cameras: vec![],
        });
        assert!(table.contains("usb 2341:0043"), "{table}");
        assert!(table.contains("port = \"QAAMZ\""), "{table}");
        let json = serde_json::to_value(&entries).expect("json");
        assert_eq!(json[0]["vid"], 0x2341);
    }

    #[test]
    fn likely_devices() {
        assert!(likely_device(0x1a86, 0x7523).is_some());
        assert!(likely_device(0x10c4, 0xea60).is_some());
        assert!(likely_device(0x2a19, 0x1234).is_some_and(|l| l.contains("relay-serial")));
        assert_eq!(likely_device(0x1234, 0x5678), None);
    }
}
