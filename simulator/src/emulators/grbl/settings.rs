//! `$$` settings: reading, checking and writing them as GRBL 1.1h does (`$N=value`,
//! integer settings, bit flags), and the machine position of home they imply.

use super::*;

impl Grbl {
    pub(super) fn setting(&self, k: u32) -> f64 {
        self.settings
            .get(&k)
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0)
    }

    pub(super) fn flag(&self, k: u32, bit: usize) -> bool {
        (self.setting(k) as u32) & (1 << bit) != 0
    }

    /// `$N=v` as GRBL stores it: error:3 for an unknown setting, error:4 for a negative value.
    pub(super) fn set_setting(&mut self, k: u32, v: f64) -> Result<(), u8> {
        if !self.settings.contains_key(&k) {
            return Err(3);
        }
        if !v.is_finite() || v < 0.0 {
            return Err(4);
        }
        let text = if INTEGER_SETTINGS.contains(&k) {
            format!("{}", v.trunc() as i64)
        } else {
            format!("{v:.3}")
        };
        self.settings.insert(k, text);
        Ok(())
    }

    /// The machine coordinate an axis rests at after homing (−`$27`, or −`$13x` + `$27`
    /// when `$23` makes it home toward −).
    pub(super) fn home_machine(&self, i: usize) -> f64 {
        let raw = if self.flag(23, i) {
            -self.setting(130 + i as u32) + self.setting(27)
        } else {
            -self.setting(27)
        };
        (raw * self.steps(i)).round() / self.steps(i)
    }
}
