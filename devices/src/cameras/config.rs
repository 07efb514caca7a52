//! What a real camera backend needs from the rig file: the device to open (from
//! `CameraSpec.port`), the trigger mode (from the rig's trigger backend), and exposure/gain in
//! the units the library wants. Values the camera cannot take are errors, never clamped.

use std::path::PathBuf;

use crate::error::{DeviceError, DeviceErrorKind, DeviceResult};
use crate::rig::{Backend, CameraSpec, TriggerSpec};

/// How a camera learns that a trigger happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TriggerMode {
    /// A hardware line (opto-isolated input, e.g. GenICam `Line1`) fires the exposure.
    Hardware,
    /// The driver itself starts each exposure when told to expect a trigger.
    Software,
}

impl TriggerMode {
    /// Software when the rig has no trigger source or its backend is `software`; otherwise
    /// the trigger source drives a line into the camera.
    pub fn from_rig(trigger: Option<&TriggerSpec>) -> Self {
        match trigger.map(|t| t.backend) {
            None | Some(Backend::Software) => TriggerMode::Software,
            Some(_) => TriggerMode::Hardware,
        }
    }
}

fn bad(device: &str, message: impl Into<String>) -> DeviceError {
    DeviceError::new(
        device.to_string(),
        DeviceErrorKind::Other {
            message: message.into(),
        },
    )
}

fn port_of<'a>(spec: &'a CameraSpec, example: &str) -> DeviceResult<&'a str> {
    match spec.port.as_deref().map(str::trim) {
        Some(p) if !p.is_empty() => Ok(p),
        _ => Err(bad(
            &spec.id,
            format!(
                "no `port` in the rig file; set e.g. port = \"{example}\" (`stagehand devices` lists what is connected)"
            ),
        )),
    }
}

/// The V4L2 device node of a `v4l` camera: `/dev/videoN`, or (preferred, stable across
/// reboots and replugging) a `/dev/v4l/by-id/…` or `/dev/v4l/by-path/…` link.
pub fn v4l_device_path(spec: &CameraSpec) -> DeviceResult<PathBuf> {
    let port = port_of(spec, "/dev/v4l/by-id/usb-…-video-index0")?;
    let ok = port
        .strip_prefix("/dev/video")
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        || ["/dev/v4l/by-id/", "/dev/v4l/by-path/"]
            .iter()
            .any(|pre| port.strip_prefix(pre).is_some_and(valid_name));
    if ok {
        Ok(PathBuf::from(port))
    } else {
        Err(bad(
            &spec.id,
            format!(
                "port `{port}` is not a V4L2 device; use /dev/videoN or a /dev/v4l/by-id/… link (see `stagehand devices`)"
            ),
        ))
    }
}

/// A file name without separators, `..`, whitespace or control characters.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.chars().any(|c| c.is_control() || c.is_whitespace())
}

/// The GenICam device id of an `aravis` camera, as `arv-tool-0.8` lists it (`Basler-12345`,
/// `The Imaging Source Europe GmbH-12345678`, `Fake_1`).
pub fn aravis_device_id(spec: &CameraSpec) -> DeviceResult<String> {
    let port = port_of(spec, "Basler-12345678")?;
    if port.starts_with("/dev/") {
        return Err(bad(
            &spec.id,
            format!(
                "port `{port}` is a device node, but aravis cameras are named by their GenICam id (e.g. `Basler-12345678`; see `stagehand devices`)"
            ),
        ));
    }
    if port.chars().any(char::is_control) {
        return Err(bad(&spec.id, "port contains control characters"));
    }
    Ok(port.to_string())
}

/// Which camera libgphoto2 should open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Gphoto2Target {
    /// A USB port as libgphoto2 names it, `usb:BUS,DEV` (changes when replugged).
    Port(String),
    /// A model name as `gphoto2 --auto-detect` prints it (`Canon EOS 600D`); must be unique.
    Model(String),
}

/// Parses the `port` of a `gphoto2` camera: `usb:001,004` or a model name.
pub fn gphoto2_target(spec: &CameraSpec) -> DeviceResult<Gphoto2Target> {
    let port = port_of(spec, "usb:001,004")?;
    if let Some(rest) = port.strip_prefix("usb:") {
        let parts: Vec<&str> = rest.split(',').collect();
        let numeric =
            |s: &str| !s.is_empty() && s.len() <= 3 && s.bytes().all(|b| b.is_ascii_digit());
        if parts.len() == 2 && parts.iter().all(|p| numeric(p)) {
            return Ok(Gphoto2Target::Port(format!(
                "usb:{:0>3},{:0>3}",
                parts[0], parts[1]
            )));
        }
        return Err(bad(
            &spec.id,
            format!("port `{port}` is not of the form usb:BUS,DEV (e.g. usb:001,004)"),
        ));
    }
    if port.starts_with("/dev/") {
        return Err(bad(
            &spec.id,
            format!(
                "port `{port}` is a device node; gphoto2 cameras are named usb:BUS,DEV or by model (see `gphoto2 --auto-detect`)"
            ),
        ));
    }
    if port.chars().any(char::is_control) {
        return Err(bad(&spec.id, "port contains control characters"));
    }
    Ok(Gphoto2Target::Model(port.to_string()))
}

/// Exposure in microseconds, checked against the range the camera reports (µs).
pub fn exposure_us(device: &str, exposure_s: f64, min_us: f64, max_us: f64) -> DeviceResult<f64> {
    let us = exposure_s * 1e6;
    if us.is_finite() && us >= min_us && us <= max_us {
        Ok(us)
    } else {
        Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Exposure {
                exposure_s,
                min_s: min_us / 1e6,
                max_s: max_us / 1e6,
            },
        ))
    }
}

/// V4L2 `exposure_time_absolute` value (units of 100 µs), rounded, checked against the
/// control's range.
pub fn v4l_exposure_units(device: &str, exposure_s: f64, min: i64, max: i64) -> DeviceResult<i64> {
    let units = (exposure_s * 1e4).round();
    if units.is_finite() && units >= min as f64 && units <= max as f64 {
        Ok(units as i64)
    } else {
        Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Exposure {
                exposure_s,
                min_s: min as f64 * 1e-4,
                max_s: max as f64 * 1e-4,
            },
        ))
    }
}

/// V4L2 `gain` value for linear `gain`: V4L2 gain units are device specific, so gain 1 maps to
/// the control's minimum and the rig's `max_gain` to its maximum, linearly.
pub fn v4l_gain_value(
    device: &str,
    gain: f64,
    max_gain: f64,
    min: i64,
    max: i64,
) -> DeviceResult<i64> {
    linear_gain_value(device, gain, max_gain, min, max)
}

/// A raw gain register in device-specific units (V4L2 `gain`, GenICam `GainRaw`) for linear
/// `gain`: gain 1 is the register's minimum and the rig's `max_gain` its maximum, linearly.
pub fn linear_gain_value(
    device: &str,
    gain: f64,
    max_gain: f64,
    min: i64,
    max: i64,
) -> DeviceResult<i64> {
    if !(gain.is_finite() && gain >= 1.0 && gain <= max_gain) {
        return Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Gain {
                gain,
                max: max_gain,
            },
        ));
    }
    if max_gain <= 1.0 || max <= min {
        return Ok(min);
    }
    let t = (gain - 1.0) / (max_gain - 1.0);
    Ok((min as f64 + t * (max - min) as f64).round() as i64)
}

/// GenICam `Gain` (in dB on almost every camera) for a linear gain: 20·log10(gain), checked
/// against the camera's bounds.
pub fn gain_db(device: &str, gain: f64, min_db: f64, max_db: f64) -> DeviceResult<f64> {
    let db = 20.0 * gain.log10();
    if gain.is_finite() && gain > 0.0 && db >= min_db - 1e-9 && db <= max_db + 1e-9 {
        Ok(db.clamp(min_db, max_db))
    } else {
        Err(DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Gain {
                gain,
                max: 10f64.powf(max_db / 20.0),
            },
        ))
    }
}

/// How far (in stops) a discrete setting may be from the request: a third of a stop.
pub const STOP_TOLERANCE: f64 = 1.0 / 3.0;

/// Parses a DSLR shutter-speed choice (`1/250`, `0.3`, `2`, `30"`, `2.5s`) to seconds;
/// `None` for `bulb`, `auto` and the like.
pub fn parse_shutter_s(choice: &str) -> Option<f64> {
    let c = choice.trim().trim_end_matches(['"', 's']).trim();
    let v = if let Some((n, d)) = c.split_once('/') {
        n.trim().parse::<f64>().ok()? / d.trim().parse::<f64>().ok()?
    } else {
        c.parse::<f64>().ok()?
    };
    (v.is_finite() && v > 0.0).then_some(v)
}

/// The choice nearest to `target` (log scale, i.e. in stops) whose value `parse` yields;
/// an error if none is within [`STOP_TOLERANCE`].
pub fn nearest_choice(
    choices: &[String],
    target: f64,
    parse: impl Fn(&str) -> Option<f64>,
) -> Option<(&str, f64)> {
    if !(target.is_finite() && target > 0.0) {
        return None;
    }
    choices
        .iter()
        .filter_map(|c| parse(c).map(|v| (c.as_str(), v)))
        .map(|(c, v)| (c, v, (v / target).log2().abs()))
        .filter(|&(_, _, stops)| stops <= STOP_TOLERANCE + 1e-9)
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(c, v, _)| (c, v))
}

/// The shutter-speed choice for `exposure_s`, or a [`DeviceErrorKind::Exposure`] naming the
/// range the camera offers.
pub fn shutter_choice<'a>(
    device: &str,
    choices: &'a [String],
    exposure_s: f64,
) -> DeviceResult<&'a str> {
    nearest_choice(choices, exposure_s, parse_shutter_s)
        .map(|(c, _)| c)
        .ok_or_else(|| {
            let values: Vec<f64> = choices.iter().filter_map(|c| parse_shutter_s(c)).collect();
            DeviceError::new(
                device.to_string(),
                DeviceErrorKind::Exposure {
                    exposure_s,
                    min_s: values.iter().copied().fold(f64::INFINITY, f64::min),
                    max_s: values.iter().copied().fold(0.0, f64::max),
                },
            )
        })
}

/// The ISO choice for linear `gain`: the camera's lowest numeric ISO is gain 1.
pub fn iso_choice<'a>(device: &str, choices: &'a [String], gain: f64) -> DeviceResult<&'a str> {
    let parse = |c: &str| c.trim().parse::<f64>().ok().filter(|v| *v > 0.0);
    let base = choices
        .iter()
        .filter_map(|c| parse(c))
        .fold(f64::INFINITY, f64::min);
    let top = choices.iter().filter_map(|c| parse(c)).fold(0.0, f64::max);
    let err = || {
        DeviceError::new(
            device.to_string(),
            DeviceErrorKind::Gain {
                gain,
                max: if base.is_finite() { top / base } else { 1.0 },
            },
        )
    };
    if !base.is_finite() {
        return Err(err());
    }
    nearest_choice(choices, gain * base, parse)
        .map(|(c, _)| c)
        .ok_or_else(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(port: Option<&str>) -> CameraSpec {
        let toml = format!(
            "id = \"cam0\"\nbackend = \"v4l\"\n{}width = 64\nheight = 48\nfps = 10.0\nazimuth_deg = 0.0\nelevation_deg = 45.0\ndistance_mm = 500.0\nfov_deg = 30.0\n",
            port.map(|p| format!("port = \"{p}\"\n"))
                .unwrap_or_default()
        );
        toml::from_str(&toml).expect("test spec parses")
    }

    fn trigger(backend: Backend) -> TriggerSpec {
        TriggerSpec {
            id: "trig".into(),
            backend,
            port: None,
            bank: None,
            line: None,
            pulse_s: 0.001,
        }
    }

    #[test]
    fn trigger_mode_follows_the_rig_trigger() {
        assert_eq!(TriggerMode::from_rig(None), TriggerMode::Software);
        assert_eq!(
            TriggerMode::from_rig(Some(&trigger(Backend::Software))),
            TriggerMode::Software
        );
        assert_eq!(
            TriggerMode::from_rig(Some(&trigger(Backend::Switch))),
            TriggerMode::Hardware
        );
    }

    #[test]
    fn v4l_ports() {
        for ok in [
            "/dev/video0",
            "/dev/video12",
            "/dev/v4l/by-id/usb-046d_HD_Pro_Webcam_C920_ABC-video-index0",
            "/dev/v4l/by-path/pci-0000:00:14.0-usb-0:1:1.0-video-index0",
        ] {
            assert_eq!(
                v4l_device_path(&cam(Some(ok))),
                Ok(PathBuf::from(ok)),
                "{ok}"
            );
        }
        for bad in [
            "video0",
            "/dev/video",
            "/dev/videoX",
            "/dev/ttyACM0",
            "/dev/v4l/by-id/../x",
            "/dev/v4l/by-id/",
        ] {
            let e = v4l_device_path(&cam(Some(bad))).unwrap_err();
            assert!(e.to_string().contains("not a V4L2 device"), "{bad}: {e}");
        }
        let e = v4l_device_path(&cam(None)).unwrap_err();
        assert!(e.to_string().contains("no `port`"), "{e}");
        assert!(v4l_device_path(&cam(Some("  "))).is_err());
    }

    #[test]
    fn aravis_ids() {
        assert_eq!(
            aravis_device_id(&cam(Some("Basler-12345"))).as_deref(),
            Ok("Basler-12345")
        );
        assert_eq!(
            aravis_device_id(&cam(Some("Fake_1"))).as_deref(),
            Ok("Fake_1")
        );
        assert!(aravis_device_id(&cam(Some("/dev/video0"))).is_err());
        assert!(aravis_device_id(&cam(None)).is_err());
    }

    #[test]
    fn gphoto2_targets() {
        assert_eq!(
            gphoto2_target(&cam(Some("usb:001,004"))),
            Ok(Gphoto2Target::Port("usb:001,004".into()))
        );
        assert_eq!(
            gphoto2_target(&cam(Some("usb:1,4"))),
            Ok(Gphoto2Target::Port("usb:001,004".into()))
        );
        assert_eq!(
            gphoto2_target(&cam(Some("Canon EOS 600D"))),
            Ok(Gphoto2Target::Model("Canon EOS 600D".into()))
        );
        for bad in [
            "usb:",
            "usb:1",
            "usb:a,b",
            "usb:1,2,3",
            "usb:1234,1",
            "/dev/bus/usb/001/004",
        ] {
            assert!(gphoto2_target(&cam(Some(bad))).is_err(), "{bad}");
        }
    }

    #[test]
    fn exposure_conversions_reject_out_of_range() {
        assert_eq!(exposure_us("c", 0.01, 10.0, 1e7), Ok(10_000.0));
        let e = exposure_us("c", 20.0, 10.0, 1e7).unwrap_err();
        assert_eq!(
            e,
            DeviceError::new(
                "c",
                DeviceErrorKind::Exposure {
                    exposure_s: 20.0,
                    min_s: 1e-5,
                    max_s: 10.0
                }
            )
        );
        assert!(exposure_us("c", f64::NAN, 10.0, 1e7).is_err());
        assert_eq!(v4l_exposure_units("c", 0.0333, 1, 5000), Ok(333));
        assert!(v4l_exposure_units("c", 0.00001, 1, 5000).is_err());
        assert!(v4l_exposure_units("c", 1.0, 1, 5000).is_err());
    }

    #[test]
    fn gain_conversions() {
        assert_eq!(v4l_gain_value("c", 1.0, 16.0, 0, 255), Ok(0));
        assert_eq!(v4l_gain_value("c", 16.0, 16.0, 0, 255), Ok(255));
        assert_eq!(v4l_gain_value("c", 8.5, 16.0, 0, 100), Ok(50));
        assert!(v4l_gain_value("c", 0.5, 16.0, 0, 255).is_err());
        assert!(v4l_gain_value("c", 17.0, 16.0, 0, 255).is_err());
        // aravis's fake camera: GainRaw 0..=10 with max_gain 11 is gain − 1.
        assert_eq!(linear_gain_value("c", 3.0, 11.0, 0, 10), Ok(2));
        let db = gain_db("c", 10.0, 0.0, 24.0).expect("in range");
        assert!((db - 20.0).abs() < 1e-9);
        assert!(gain_db("c", 1.0, 0.0, 24.0).is_ok());
        assert!(matches!(
            gain_db("c", 100.0, 0.0, 24.0),
            Err(DeviceError {
                kind: DeviceErrorKind::Gain { .. },
                ..
            })
        ));
    }

    #[test]
    fn shutter_and_iso_choices() {
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert_eq!(parse_shutter_s("1/250"), Some(0.004));
        assert_eq!(parse_shutter_s("30\""), Some(30.0));
        assert_eq!(parse_shutter_s("2.5s"), Some(2.5));
        assert_eq!(parse_shutter_s("Bulb"), None);
        assert_eq!(parse_shutter_s("1/0"), None);
        let shutters = s(&["Bulb", "30", "1", "1/2", "1/4", "1/125", "1/250", "1/4000"]);
        assert_eq!(shutter_choice("c", &shutters, 0.004), Ok("1/250"));
        assert_eq!(shutter_choice("c", &shutters, 0.26), Ok("1/4"));
        let e = shutter_choice("c", &shutters, 0.05).unwrap_err();
        assert!(
            matches!(e, DeviceError { kind: DeviceErrorKind::Exposure { min_s, max_s, .. }, .. } if min_s == 1.0 / 4000.0 && max_s == 30.0),
            "{e:?}"
        );
        let isos = s(&["Auto", "100", "200", "400", "800", "1600"]);
        assert_eq!(iso_choice("c", &isos, 1.0), Ok("100"));
        assert_eq!(iso_choice("c", &isos, 4.0), Ok("400"));
        assert!(
            matches!(iso_choice("c", &isos, 32.0), Err(DeviceError { kind: DeviceErrorKind::Gain { max, .. }, .. }) if max == 16.0)
        );
        assert!(iso_choice("c", &s(&["Auto"]), 1.0).is_err());
    }
}
