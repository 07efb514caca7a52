//! What a GRBL board's settings (`$$`) and build options (`$I`) mean for the rig: how rig
//! degrees map onto machine coordinates, how long homing may take, and which settings cannot
//! work for the rig (refused at connect with the `$N=` to send).
//!
//! GRBL machine space after homing is negative: with `$23` bit clear the axis homes toward +,
//! the switch is machine 0 and the axis rests at −`$27` afterwards; with the bit set it homes
//! toward −, and rests at −`$13x` + `$27`. Soft limits (`$20=1`) allow only −`$13x`…0. A rig
//! file places its range in that space with `home_deg` (the angle after homing) and
//! `machine_sign`.

use std::collections::BTreeMap;

use super::codec::AXIS_LETTERS;
use crate::rig::AxisSpec;

/// `HOMING_AXIS_LOCATE_SCALAR` of GRBL 1.1: the locate phase travels 5 × `$27`.
const LOCATE_SCALAR: f64 = 5.0;
/// `HOMING_AXIS_SEARCH_SCALAR`: the seek phase travels at most 1.5 × `$13x`.
const SEARCH_SCALAR: f64 = 1.5;

/// The board's answer to `$I`: `[VER:1.1h.20190830:]` and `[OPT:V,15,128]`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BuildInfo {
    /// `1.1h.20190830`.
    pub version: String,
    /// The option letters before the first comma (`V`, `H`, `Z`, …).
    pub options: String,
}

impl BuildInfo {
    /// Takes one `$I` message line (without brackets); other lines are ignored.
    pub fn absorb(&mut self, message: &str) {
        if let Some(v) = message.strip_prefix("VER:") {
            self.version = v.split(':').next().unwrap_or("").to_string();
        } else if let Some(o) = message.strip_prefix("OPT:") {
            self.options = o.split(',').next().unwrap_or("").to_string();
        }
    }

    /// Built with `HOMING_SINGLE_AXIS_COMMANDS` (`$HX`, `$HY`, `$HZ`).
    pub fn single_axis_homing(&self) -> bool {
        self.options.contains('H')
    }

    /// Built with `HOMING_FORCE_SET_ORIGIN`: the axis reads 0 after homing.
    pub fn force_origin(&self) -> bool {
        self.options.contains('Z')
    }
}

/// The `$N=value` settings a board reported.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Settings(pub BTreeMap<u32, f64>);

impl Settings {
    pub fn get(&self, n: u32) -> Option<f64> {
        self.0.get(&n).copied()
    }

    fn flag(&self, n: u32) -> bool {
        self.get(n).is_some_and(|v| v != 0.0)
    }

    fn mask_bit(&self, n: u32, bit: usize) -> bool {
        self.get(n).is_some_and(|v| (v as u32) & (1 << bit) != 0)
    }

    /// `$22`: homing cycle enabled.
    pub fn homing_enabled(&self) -> bool {
        self.flag(22)
    }

    /// `$20`: soft limits.
    pub fn soft_limits(&self) -> bool {
        self.flag(20)
    }

    /// `$32`: laser mode (the spindle output is on only during G1/G2/G3 motion).
    pub fn laser_mode(&self) -> bool {
        self.flag(32)
    }

    /// `$10` bit 0: status reports carry `MPos` (else `WPos`).
    pub fn reports_machine_position(&self) -> bool {
        self.mask_bit(10, 0)
    }

    /// `$23` bit of axis `idx`: homes toward − (the switch at the − end of travel).
    pub fn homes_negative(&self, idx: usize) -> bool {
        self.mask_bit(23, idx)
    }

    /// `$27` homing pull-off.
    pub fn pulloff(&self) -> f64 {
        self.get(27).unwrap_or(1.0)
    }

    /// `$13x` maximum travel of axis `idx`.
    pub fn max_travel(&self, idx: usize) -> f64 {
        self.get(130 + idx as u32).unwrap_or(200.0)
    }

    /// The machine coordinate axis `idx` rests at after homing, in whole steps as GRBL sets
    /// it (`lround(-$27 × $10x)` steps, so −0.998 for a 1.000 pull-off at 142.222 steps).
    pub fn home_machine(&self, idx: usize, build: &BuildInfo) -> f64 {
        let raw = if build.force_origin() {
            0.0
        } else if self.homes_negative(idx) {
            -self.max_travel(idx) + self.pulloff()
        } else {
            -self.pulloff()
        };
        match self.get(100 + idx as u32).filter(|s| *s > 0.0) {
            Some(steps) => (raw * steps).round() / steps,
            None => raw,
        }
    }

    /// Longest a homing cycle of the axes in `mask` (X, Y, Z) can take: the seek over
    /// 1.5 × `$13x` at `$25`, the locate phase (pull-off, 5 × `$27` approach, pull-off) at
    /// `$24`, per axis (cycles run one after another), ×1.5 for acceleration, plus 5 s.
    pub fn homing_bound_s(&self, mask: [bool; 3]) -> f64 {
        let seek = self.get(25).unwrap_or(500.0).max(1e-3) / 60.0;
        let locate = self.get(24).unwrap_or(25.0).max(1e-3) / 60.0;
        let pull = self.pulloff();
        let mut total = 0.0;
        for (idx, _) in mask.iter().enumerate().filter(|(_, on)| **on) {
            total +=
                SEARCH_SCALAR * self.max_travel(idx) / seek + (2.0 + LOCATE_SCALAR) * pull / locate;
        }
        total * 1.5 + 5.0
    }
}

/// How one axis's rig degrees map onto its machine coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MachineMap {
    /// Rig angle after homing.
    pub home_deg: f64,
    /// +1 or −1.
    pub sign: f64,
    /// Machine coordinate after homing.
    pub home_machine: f64,
}

impl MachineMap {
    /// The map of `spec` (controller axis `idx`) on a board with `settings` and `build`.
    pub fn new(spec: &AxisSpec, idx: usize, settings: &Settings, build: &BuildInfo) -> Self {
        Self {
            home_deg: spec.home_deg,
            sign: if spec.machine_sign < 0.0 { -1.0 } else { 1.0 },
            home_machine: settings.home_machine(idx, build),
        }
    }

    /// The machine coordinate of rig angle `deg`.
    pub fn to_machine(&self, deg: f64) -> f64 {
        self.home_machine + self.sign * (deg - self.home_deg)
    }

    /// The rig angle of machine coordinate `machine`.
    pub fn to_deg(&self, machine: f64) -> f64 {
        self.home_deg + self.sign * (machine - self.home_machine)
    }
}

/// Settings of a board that cannot work for the rig's axes `axes` (letter, spec) and, if
/// `laser` is on this board, its laser; each problem says what to set. Empty when fine.
pub fn problems(
    settings: &Settings,
    build: &BuildInfo,
    axes: &[(char, AxisSpec)],
    laser: bool,
) -> Vec<String> {
    let mut out = Vec::new();
    if !build.version.is_empty() && !build.version.starts_with("1.1") {
        out.push(format!(
            "the board runs GRBL {}; stagehand needs GRBL 1.1 (flash 1.1h)",
            build.version
        ));
    }
    if !axes.is_empty() && !settings.homing_enabled() {
        out.push("homing is off; send `$22=1` (and wire the homing switches)".into());
    }
    if laser && settings.laser_mode() {
        out.push(
            "laser mode is on (`$32=1`): GRBL then keeps the output off except during G1 moves, \
             but the line laser must stay lit while the axes stand still; send `$32=0`"
                .into(),
        );
    }
    for (letter, spec) in axes {
        let Some(idx) = AXIS_LETTERS.iter().position(|l| l == letter) else {
            continue;
        };
        let n = 100 + idx as u32;
        let want = spec.steps_per_deg;
        match settings.get(n) {
            None => out.push(format!("the board did not report `${n}`")),
            Some(v) if (v - want).abs() > 1e-3 * want.abs() => out.push(format!(
                "`${n}` is {v} (steps per degree of axis {letter}) but axis `{}` has steps_per_deg {want}; send `${n}={want:.3}` or fix the rig file",
                spec.id
            )),
            Some(_) => {}
        }
        if settings.soft_limits() {
            let map = MachineMap::new(spec, idx, settings, build);
            let (a, b) = (
                map.to_machine(spec.min_deg - spec.backlash_deg),
                map.to_machine(spec.max_deg),
            );
            let (lo, hi) = (a.min(b), a.max(b));
            let travel = settings.max_travel(idx);
            let tol = 1.0 / want.max(1e-9);
            if hi > tol || lo < -travel - tol {
                let fix = if hi <= tol {
                    format!("send `${}={:.3}`", 130 + idx, (-lo).ceil() + 1.0)
                } else {
                    "set `home_deg` and `machine_sign` in the rig file so the range falls at or below 0".into()
                };
                out.push(format!(
                    "soft limits are on (`$20=1`), so axis {letter} reaches machine {:.3}…0, but axis `{}` ({}…{}°, homed at {}°, machine_sign {}) needs {lo:.3}…{hi:.3}; {fix}, or send `$20=0`",
                    -travel, spec.id, spec.min_deg, spec.max_deg, spec.home_deg, map.sign
                ));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{AxisRole, Backend};

    fn settings(pairs: &[(u32, f64)]) -> Settings {
        Settings(pairs.iter().copied().collect())
    }

    fn spec(min: f64, max: f64, home: f64, sign: f64) -> AxisSpec {
        AxisSpec {
            id: "turntable".into(),
            backend: Backend::Grbl,
            port: Some("/dev/null".into()),
            role: AxisRole::Turntable,
            speed_deg_s: 30.0,
            accel_deg_s2: 60.0,
            min_deg: min,
            max_deg: max,
            backlash_deg: 0.0,
            settle_s: 0.0,
            homing_speed_deg_s: 20.0,
            steps_per_deg: 100.0,
            controller_axis: Some("X".into()),
            baud: None,
            home_deg: home,
            machine_sign: sign,
        }
    }

    #[test]
    fn build_info_reads_version_and_option_letters() {
        let mut b = BuildInfo::default();
        b.absorb("VER:1.1h.20190830:");
        b.absorb("OPT:VH,15,128");
        assert_eq!(b.version, "1.1h.20190830");
        assert!(b.single_axis_homing() && !b.force_origin());
        b.absorb("OPT:V,15,128");
        assert!(!b.single_axis_homing());
    }

    #[test]
    fn home_position_follows_direction_pulloff_and_origin_option() {
        let s = settings(&[(23, 2.0), (27, 1.0), (130, 400.0), (131, 300.0)]);
        let b = BuildInfo::default();
        assert_eq!(s.home_machine(0, &b), -1.0);
        assert_eq!(s.home_machine(1, &b), -299.0);
        let z = BuildInfo {
            options: "VZ".into(),
            ..BuildInfo::default()
        };
        assert_eq!(s.home_machine(0, &z), 0.0);
    }

    #[test]
    fn degrees_and_machine_coordinates_round_trip() {
        let s = settings(&[(27, 2.0)]);
        let m = MachineMap::new(
            &spec(-180.0, 360.0, 0.0, -1.0),
            0,
            &s,
            &BuildInfo::default(),
        );
        assert_eq!(m.to_machine(0.0), -2.0);
        assert_eq!(m.to_machine(90.0), -92.0);
        assert_eq!(m.to_deg(m.to_machine(-37.5)), -37.5);
    }

    #[test]
    fn soft_limits_that_cut_the_rig_range_name_the_fix() {
        let b = BuildInfo::default();
        let base = [(22, 1.0), (20, 1.0), (27, 1.0), (100, 100.0), (130, 400.0)];
        let s = settings(&base);
        // Rig 0…360 homed at 0 with sign −1: machine −1…−361, inside −400…0.
        assert!(problems(&s, &b, &[('X', spec(0.0, 360.0, 0.0, -1.0))], false).is_empty());
        // Sign +1 puts the range above 0.
        let p = problems(&s, &b, &[('X', spec(0.0, 360.0, 0.0, 1.0))], false);
        assert!(p[0].contains("home_deg") && p[0].contains("$20=0"), "{p:?}");
        // Too little travel: names $130.
        let s = settings(&[(22, 1.0), (20, 1.0), (27, 1.0), (100, 100.0), (130, 100.0)]);
        let p = problems(&s, &b, &[('X', spec(0.0, 360.0, 0.0, -1.0))], false);
        assert!(p[0].contains("`$130=362.000`"), "{p:?}");
    }

    #[test]
    fn laser_mode_homing_off_and_wrong_steps_are_refused() {
        let s = settings(&[(22, 0.0), (32, 1.0), (100, 50.0)]);
        let b = BuildInfo {
            version: "1.1h.20190830".into(),
            options: "V".into(),
        };
        let p = problems(&s, &b, &[('X', spec(0.0, 10.0, 0.0, 1.0))], true);
        assert_eq!(p.len(), 3, "{p:?}");
        assert!(p[0].contains("$22=1") && p[1].contains("$32=0") && p[2].contains("$100=100.000"));
        let old = BuildInfo {
            version: "0.9j.20160726".into(),
            ..BuildInfo::default()
        };
        assert!(problems(&Settings::default(), &old, &[], false)[0].contains("GRBL 1.1"));
    }

    #[test]
    fn homing_bound_grows_with_travel_and_slow_rates() {
        let s = settings(&[
            (24, 600.0),
            (25, 2400.0),
            (27, 1.0),
            (130, 400.0),
            (131, 400.0),
            (132, 400.0),
        ]);
        let one = s.homing_bound_s([true, false, false]);
        // 1.5 × 400 / 40 = 15 s seek, 7 / 10 = 0.7 s locate → ×1.5 + 5.
        assert!((one - (15.7 * 1.5 + 5.0)).abs() < 1e-9, "{one}");
        assert!(s.homing_bound_s([true, true, true]) > 2.0 * one);
    }
}
