//! Reading rig files: TOML syntax and schema errors and impossible values are all reported at
//! file:line:col with a sentence saying what is expected. The `[sim]` table is only carried
//! here; the simulator checks it (`stagehand_simulator::render::config::check_rig`).

use std::path::Path;

use thiserror::Error;

use super::span::{Problem, Seg, at, line_col, locate};
use super::spec::{CameraSpec, LampKind, RigSpec};
use crate::lens::Intrinsics;

/// A rig file that could not be used.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum RigError {
    #[error("{path}: cannot read the rig file: {reason}; check the --rig path")]
    Read { path: String, reason: String },
    #[error("{path}:{line}:{col}: {message}")]
    Invalid {
        path: String,
        line: usize,
        col: usize,
        message: String,
    },
}

/// Reads and checks a rig file from disk.
pub fn load_rig_file(path: &Path) -> Result<RigSpec, RigError> {
    let text = std::fs::read_to_string(path).map_err(|e| RigError::Read {
        path: path.display().to_string(),
        reason: e.to_string(),
    })?;
    parse_rig(&text, &path.display().to_string())
}

/// Parses and checks rig TOML; `origin` names the file in error messages. The `[sim]` table
/// is only required to be a table: the simulator checks it (`stagehand_simulator::render::config`).
pub fn parse_rig(text: &str, origin: &str) -> Result<RigSpec, RigError> {
    let spec: RigSpec = toml::from_str(text).map_err(|e| {
        let offset = e.span().map(|s| s.start).unwrap_or(0);
        RigError::at(text, origin, offset, e.message().trim().replace('\n', " "))
    })?;
    check(&spec).map_err(|(path, message)| {
        RigError::at(text, origin, locate(text, &path).unwrap_or(0), message)
    })?;
    Ok(spec)
}

impl RigError {
    /// The problem `message` at byte `offset` of the rig file `text`, named `origin`: an
    /// [`RigError::Invalid`] with its line and column.
    pub fn at(text: &str, origin: &str, offset: usize, message: impl Into<String>) -> RigError {
        let (line, col) = line_col(text, offset);
        RigError::Invalid {
            path: origin.to_string(),
            line,
            col,
            message: message.into(),
        }
    }
}

fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

/// Semantic checks serde cannot express. Returns the offending key's path and a sentence.
fn check(spec: &RigSpec) -> Result<(), Problem> {
    for (kind, id) in spec.calibration.named() {
        let hash = id
            .strip_prefix(kind)
            .and_then(|rest| rest.strip_prefix('-'));
        if !hash.is_some_and(|h| h.len() == 12 && h.bytes().all(|b| b.is_ascii_hexdigit())) {
            return Err((
                super::span::key("calibration", kind),
                format!(
                    "calibration.{kind} = \"{id}\" is not a {kind} calibration id (`{kind}-` and 12 hex digits); `stagehand calibrations list` shows the stored ones"
                ),
            ));
        }
    }
    let mut ids: Vec<(&str, Vec<Seg>)> = Vec::new();
    for (i, a) in spec.axes.iter().enumerate() {
        ids.push((&a.id, at("axis", i, "id")));
        for (key, v) in [
            ("speed_deg_s", a.speed_deg_s),
            ("accel_deg_s2", a.accel_deg_s2),
            ("homing_speed_deg_s", a.homing_speed_deg_s),
            ("steps_per_deg", a.steps_per_deg),
        ] {
            if !positive(v) {
                return Err((
                    at("axis", i, key),
                    format!("axis `{}`: {key} must be a positive number, got {v}", a.id),
                ));
            }
        }
        if !(a.min_deg.is_finite() && a.max_deg.is_finite() && a.min_deg < a.max_deg) {
            return Err((
                at("axis", i, "max_deg"),
                format!(
                    "axis `{}`: soft limits need min_deg < max_deg, got [{}, {}]",
                    a.id, a.min_deg, a.max_deg
                ),
            ));
        }
        if !(a.home_deg.is_finite() && (a.min_deg..=a.max_deg).contains(&a.home_deg)) {
            return Err((
                at("axis", i, "home_deg"),
                format!(
                    "axis `{}`: the home position {}° must lie inside the soft limits [{}, {}]",
                    a.id, a.home_deg, a.min_deg, a.max_deg
                ),
            ));
        }
        if a.machine_sign != 1.0 && a.machine_sign != -1.0 {
            return Err((
                at("axis", i, "machine_sign"),
                format!(
                    "axis `{}`: machine_sign must be 1 or -1 (does the controller's coordinate grow with the angle?), got {}",
                    a.id, a.machine_sign
                ),
            ));
        }
        for (key, v) in [("backlash_deg", a.backlash_deg), ("settle_s", a.settle_s)] {
            if !(v.is_finite() && (0.0..=10.0).contains(&v)) {
                return Err((
                    at("axis", i, key),
                    format!("axis `{}`: {key} must be between 0 and 10, got {v}", a.id),
                ));
            }
        }
    }
    for (i, b) in spec.switch_banks.iter().enumerate() {
        ids.push((&b.id, at("switch_bank", i, "id")));
        if b.channels == 0 || b.channels > 64 {
            return Err((
                at("switch_bank", i, "channels"),
                format!(
                    "switch bank `{}`: channels must be between 1 and 64, got {}",
                    b.id, b.channels
                ),
            ));
        }
    }
    for (i, l) in spec.lamps.iter().enumerate() {
        ids.push((&l.id, at("lamp", i, "id")));
        let Some(bank) = spec.bank(&l.bank) else {
            return Err((
                at("lamp", i, "bank"),
                format!(
                    "lamp `{}`: no switch bank `{}`; define a [[switch_bank]] with that id",
                    l.id, l.bank
                ),
            ));
        };
        if l.channel == 0 || l.channel > bank.channels {
            return Err((
                at("lamp", i, "channel"),
                format!(
                    "lamp `{}`: channel {} does not exist on bank `{}` (channels 1..={})",
                    l.id, l.channel, bank.id, bank.channels
                ),
            ));
        }
        if spec.lamps[..i]
            .iter()
            .any(|o| o.bank == l.bank && o.channel == l.channel)
        {
            return Err((
                at("lamp", i, "channel"),
                format!(
                    "lamp `{}`: channel {} of `{}` already powers another lamp",
                    l.id, l.channel, l.bank
                ),
            ));
        }
        if l.kind == LampKind::Halogen
            && !(l.elevation_deg.is_finite() && (0.0..=90.0).contains(&l.elevation_deg))
        {
            return Err((
                at("lamp", i, "elevation_deg"),
                format!(
                    "lamp `{}`: elevation_deg must be between 0 and 90, got {}",
                    l.id, l.elevation_deg
                ),
            ));
        }
        if !positive(l.distance_mm) || !positive(l.power) {
            return Err((
                at("lamp", i, "distance_mm"),
                format!("lamp `{}`: distance_mm and power must be positive", l.id),
            ));
        }
        if l.kind == LampKind::Tube
            && !(positive(l.length_mm) && positive(l.radius_mm) && l.radius_mm < l.distance_mm)
        {
            return Err((
                at("lamp", i, "radius_mm"),
                format!(
                    "lamp `{}`: length_mm ({}) and radius_mm ({}) must be positive, and the glass must clear the sample (radius_mm below distance_mm {})",
                    l.id, l.length_mm, l.radius_mm, l.distance_mm
                ),
            ));
        }
        if !(l.warmup_s.is_finite() && (0.0..=600.0).contains(&l.warmup_s)) {
            return Err((
                at("lamp", i, "warmup_s"),
                format!(
                    "lamp `{}`: warmup_s must be between 0 and 600 s, got {}",
                    l.id, l.warmup_s
                ),
            ));
        }
    }
    for (i, c) in spec.cameras.iter().enumerate() {
        ids.push((&c.id, at("camera", i, "id")));
        if c.width == 0 || c.height == 0 || c.width > 16384 || c.height > 16384 {
            return Err((
                at("camera", i, "width"),
                format!(
                    "camera `{}`: width and height must be between 1 and 16384, got {}×{}",
                    c.id, c.width, c.height
                ),
            ));
        }
        if !(positive(c.fps) && c.fps <= 1000.0) {
            return Err((
                at("camera", i, "fps"),
                format!("camera `{}`: fps must be in (0, 1000], got {}", c.id, c.fps),
            ));
        }
        if ![8, 10, 12, 14, 16].contains(&c.bit_depth) {
            return Err((
                at("camera", i, "bit_depth"),
                format!(
                    "camera `{}`: bit_depth must be 8, 10, 12, 14 or 16, got {}",
                    c.id, c.bit_depth
                ),
            ));
        }
        if !(positive(c.fov_deg) && c.fov_deg < 170.0) {
            return Err((
                at("camera", i, "fov_deg"),
                format!(
                    "camera `{}`: fov_deg must be in (0, 170), got {}",
                    c.id, c.fov_deg
                ),
            ));
        }
        if !(c.elevation_deg.is_finite() && (0.0..=90.0).contains(&c.elevation_deg)) {
            return Err((
                at("camera", i, "elevation_deg"),
                format!(
                    "camera `{}`: elevation_deg must be between 0 and 90, got {}",
                    c.id, c.elevation_deg
                ),
            ));
        }
        if !positive(c.distance_mm) || !c.azimuth_deg.is_finite() {
            return Err((
                at("camera", i, "distance_mm"),
                format!(
                    "camera `{}`: distance_mm must be positive and azimuth_deg finite",
                    c.id
                ),
            ));
        }
        if !(positive(c.min_exposure_s)
            && c.min_exposure_s < c.max_exposure_s
            && c.max_exposure_s <= 3600.0)
        {
            return Err((
                at("camera", i, "max_exposure_s"),
                format!(
                    "camera `{}`: need 0 < min_exposure_s < max_exposure_s <= 3600",
                    c.id
                ),
            ));
        }
        if !(c.max_gain.is_finite() && c.max_gain >= 1.0) {
            return Err((
                at("camera", i, "max_gain"),
                format!("camera `{}`: max_gain must be at least 1", c.id),
            ));
        }
        check_lens(c).map_err(|(key, message)| (at("camera", i, key), message))?;
    }
    if let Some(t) = &spec.trigger {
        ids.push((&t.id, vec![Seg::Key("trigger"), Seg::Key("id")]));
    } else if !spec.cameras.is_empty() {
        return Err((
            vec![Seg::Key("camera")],
            "cameras need a [trigger] table to fire them".into(),
        ));
    }
    if let Some(l) = &spec.laser {
        ids.push((&l.id, vec![Seg::Key("laser"), Seg::Key("id")]));
        let key = |k| vec![Seg::Key("laser"), Seg::Key(k)];
        if l.colours_nm.is_empty() || l.colours_nm.iter().any(|&c| !(380..=1100).contains(&c)) {
            return Err((
                key("colours_nm"),
                "laser: colours_nm must list wavelengths between 380 and 1100 nm".into(),
            ));
        }
        if !l.colours_nm.contains(&l.fitted_nm) {
            return Err((
                key("fitted_nm"),
                format!(
                    "laser: fitted_nm {} is not one of colours_nm {:?}",
                    l.fitted_nm, l.colours_nm
                ),
            ));
        }
        match spec.axis(&l.tilt_axis) {
            Some(a) if a.role == super::spec::AxisRole::LaserTilt => {}
            Some(_) => {
                return Err((
                    key("tilt_axis"),
                    format!(
                        "laser: axis `{}` must have role = \"laser_tilt\"",
                        l.tilt_axis
                    ),
                ));
            }
            None => {
                return Err((
                    key("tilt_axis"),
                    format!(
                        "laser: no axis `{}`; define an [[axis]] with role = \"laser_tilt\"",
                        l.tilt_axis
                    ),
                ));
            }
        }
        if !(positive(l.distance_mm) && positive(l.power_mw) && positive(l.sheet_half_width_mm)) {
            return Err((
                key("power_mw"),
                "laser: distance_mm, power_mw and sheet_half_width_mm must be positive".into(),
            ));
        }
        if !(l.mount_elevation_deg.is_finite() && (0.0..=90.0).contains(&l.mount_elevation_deg)) {
            return Err((
                key("mount_elevation_deg"),
                "laser: mount_elevation_deg must be between 0 and 90".into(),
            ));
        }
    }
    if let Some(c) = &spec.cart {
        ids.push((&c.id, vec![Seg::Key("cart"), Seg::Key("id")]));
        if !(positive(c.speed_mm_s) && positive(c.travel_mm)) {
            return Err((
                vec![Seg::Key("cart"), Seg::Key("speed_mm_s")],
                "cart: speed_mm_s and travel_mm must be positive".into(),
            ));
        }
    }
    for (i, (id, path)) in ids.iter().enumerate() {
        if id.is_empty()
            || !id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            return Err((
                path.clone(),
                format!("device id `{id}` must be non-empty ASCII letters, digits, `_` or `-`"),
            ));
        }
        if ids[..i].iter().any(|(other, _)| other == id) {
            return Err((
                path.clone(),
                format!("device id `{id}` is used twice; every device needs its own id"),
            ));
        }
    }
    super::wiring::check_wiring(spec)
}

/// Distortion coefficients and principal point of a camera: finite, the principal point
/// inside the image, and a lens that [`Intrinsics::check`] can invert over the whole image.
/// Returns the key to blame and a sentence.
fn check_lens(c: &CameraSpec) -> Result<(), (&'static str, String)> {
    for (key, v) in [
        ("k1", c.k1),
        ("k2", c.k2),
        ("k3", c.k3),
        ("p1", c.p1),
        ("p2", c.p2),
        ("cx", c.cx),
        ("cy", c.cy),
    ] {
        if !v.is_finite() {
            return Err((
                key,
                format!("camera `{}`: {key} must be a finite number, got {v}", c.id),
            ));
        }
    }
    for (key, offset, size) in [("cx", c.cx, c.width), ("cy", c.cy, c.height)] {
        if offset.abs() >= 0.5 * size as f64 {
            return Err((
                key,
                format!(
                    "camera `{}`: principal point offset {key} = {offset} px lies outside the \
                     {size} px image; it is measured from the image centre",
                    c.id
                ),
            ));
        }
    }
    Intrinsics::of(c).check().map_err(|reason| {
        let key = if c.k1 != 0.0 {
            "k1"
        } else if c.k2 != 0.0 {
            "k2"
        } else if c.k3 != 0.0 {
            "k3"
        } else if c.p1 != 0.0 {
            "p1"
        } else {
            "p2"
        };
        (key, format!("camera `{}`: {reason}", c.id))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{BUILTIN_LIGHTSTAGE, BUILTIN_REFLECTOMETER};

    #[test]
    fn builtin_rigs_parse() {
        let ls = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").unwrap();
        assert_eq!(ls.cameras.len(), 8);
        assert_eq!(
            ls.lamps
                .iter()
                .filter(|l| l.kind == LampKind::Halogen)
                .count(),
            8
        );
        assert!(ls.laser.is_some());
        let rf = parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").unwrap();
        assert_eq!(rf.cameras.len(), 1);
        assert!(rf.cart.is_some());
    }

    fn err(text: &str) -> (usize, usize, String) {
        match parse_rig(text, "x.toml") {
            Err(RigError::Invalid {
                line, col, message, ..
            }) => (line, col, message),
            other => panic!("expected an error, got {other:?}"),
        }
    }

    #[test]
    fn calibrations_are_named_by_their_ids() {
        let good =
            format!("{BUILTIN_LIGHTSTAGE}\n[calibration]\nresponse = \"response-0123456789ab\"\n");
        let rig = parse_rig(&good, "x.toml").expect("parses");
        assert_eq!(
            rig.calibration.named(),
            [("response", "response-0123456789ab")]
        );
        let bad =
            format!("{BUILTIN_LIGHTSTAGE}\n[calibration]\ncolour = \"response-0123456789ab\"\n");
        let line = bad.lines().position(|l| l.starts_with("colour =")).unwrap() + 1;
        let (l, _, m) = err(&bad);
        assert_eq!(l, line);
        assert!(m.contains("not a colour calibration id"), "{m}");
        let unknown = format!("{BUILTIN_LIGHTSTAGE}\n[calibration]\nlaser = \"x\"\n");
        assert!(err(&unknown).2.contains("laser"));
    }

    #[test]
    fn unknown_key_is_reported_at_its_line() {
        let text =
            BUILTIN_LIGHTSTAGE.replacen("speed_deg_s = 30.0", "speed_deg_s = 30.0\nspeeed = 3", 1);
        let line = text.lines().position(|l| l.starts_with("speeed")).unwrap() + 1;
        let (l, c, m) = err(&text);
        assert_eq!((l, c), (line, 1));
        assert!(m.contains("speeed"), "{m}");
    }

    #[test]
    fn wrong_type_is_reported() {
        let text = BUILTIN_LIGHTSTAGE.replacen("speed_deg_s = 30.0", "speed_deg_s = \"fast\"", 1);
        let line = text.lines().position(|l| l.contains("\"fast\"")).unwrap() + 1;
        let (l, _, m) = err(&text);
        assert_eq!(l, line);
        assert!(m.contains("float") || m.contains("invalid type"), "{m}");
    }

    #[test]
    fn impossible_value_is_reported_at_its_key() {
        let text = BUILTIN_LIGHTSTAGE.replacen("accel_deg_s2 = 60.0", "accel_deg_s2 = -5.0", 1);
        let line = text.lines().position(|l| l.contains("-5.0")).unwrap() + 1;
        let (l, c, m) = err(&text);
        assert_eq!((l, c), (line, 16));
        assert!(m.contains("accel_deg_s2 must be a positive number"), "{m}");
    }

    #[test]
    fn a_tube_whose_glass_reaches_the_sample_is_refused_at_its_key() {
        let text = BUILTIN_REFLECTOMETER.replacen("radius_mm = 13.0", "radius_mm = 70.0", 1);
        let line = text
            .lines()
            .position(|l| l.contains("radius_mm = 70.0"))
            .unwrap()
            + 1;
        let (l, _, m) = err(&text);
        assert_eq!(l, line, "{m}");
        assert!(
            m.contains("radius_mm (70)") && m.contains("distance_mm 60"),
            "{m}"
        );
        let rig = parse_rig(BUILTIN_REFLECTOMETER, "reflectometer.toml").unwrap();
        let tube = rig.lamps.iter().find(|l| l.id == "tube").unwrap();
        assert_eq!((tube.length_mm, tube.radius_mm), (300.0, 13.0));
    }

    #[test]
    fn bad_lens_coefficients_are_reported_at_their_key() {
        let cam = |extra: &str| {
            BUILTIN_LIGHTSTAGE.replacen("fov_deg = 11.0", &format!("fov_deg = 11.0\n{extra}"), 1)
        };
        let text = cam("k1 = 0.05\np2 = 0.001\ncx = 3.5");
        assert!(parse_rig(&text, "x.toml").is_ok());
        for (extra, needle) in [
            ("k1 = -900.0", "folds back"),
            ("k2 = nan", "finite"),
            ("p1 = 40.0", "cannot be inverted"),
            ("cy = 500.0", "outside"),
        ] {
            let text = cam(extra);
            let key = extra.split(' ').next().unwrap_or("");
            let line = text.lines().position(|l| l == extra).unwrap() + 1;
            let (l, c, m) = err(&text);
            assert_eq!((l, c), (line, key.len() + 4), "{extra}: {m}");
            assert!(m.contains(needle) && m.contains("cam1"), "{extra}: {m}");
        }
    }

    #[test]
    fn syntax_error_has_position() {
        let (l, _, _) = err("[rig]\nname = \"x\"\n[[axis]\n");
        assert_eq!(l, 3);
    }

    const AXIS: &str = "[rig]\nname = \"t\"\n\n[[axis]]\nid = \"turn\"\nbackend = \"grbl\"\nrole = \"turntable\"\nspeed_deg_s = 30.0\naccel_deg_s2 = 60.0\nmin_deg = 0.0\nmax_deg = 360.0\n";

    #[test]
    fn each_backend_checks_its_own_wiring_at_the_key() {
        let (l, c, m) = err(AXIS);
        assert_eq!((l, c), (6, 11));
        assert!(m.contains("backend `grbl` needs `port`"), "{m}");
        let ported = format!("{AXIS}port = \"/dev/ttyACM0\"\n");
        let (l, _, m) = err(&ported);
        assert_eq!(l, 6);
        assert!(m.contains("controller_axis"), "{m}");
        let ok = format!("{ported}controller_axis = \"X\"\n");
        assert!(parse_rig(&ok, "x.toml").is_ok());
        let hid = "[rig]\nname = \"t\"\n\n[[switch_bank]]\nid = \"b\"\nbackend = \"hid-relay\"\nchannels = 9\n";
        let (l, c, m) = err(hid);
        assert_eq!((l, c), (7, 12));
        assert!(m.contains("at most 8 relays"), "{m}");
        let camera = AXIS.replace("\"grbl\"", "\"v4l\"");
        let (l, _, m) = err(&camera);
        assert_eq!(l, 6);
        assert!(
            m.contains("cannot drive this kind of device; use one of sim, grbl"),
            "{m}"
        );
    }

    #[test]
    fn missing_file_names_path() {
        let e = load_rig_file(Path::new("/nonexistent/rig.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/rig.toml"));
    }
}
