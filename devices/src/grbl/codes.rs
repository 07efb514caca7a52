//! The meanings of GRBL 1.1's `error:N` and `ALARM:N` codes, so an error the operator reads
//! says what went wrong instead of a bare number.
//!
//! Wording follows the GRBL 1.1 wiki tables (short message; for the G-code parser errors
//! 23..=38, whose short message is only "Invalid gcode ID:N", the one-line description).

/// `error:N` codes of GRBL 1.1 (18 and 19 are unused by the firmware).
const ERRORS: [(u32, &str); 36] = [
    (1, "Expected command letter"),
    (2, "Bad number format"),
    (3, "Invalid statement"),
    (4, "Value < 0"),
    (5, "Setting disabled"),
    (6, "Value < 3 usec"),
    (7, "EEPROM read fail. Using defaults"),
    (8, "Not idle"),
    (9, "G-code lock"),
    (10, "Homing not enabled"),
    (11, "Line overflow"),
    (12, "Step rate > 30kHz"),
    (13, "Check Door"),
    (14, "Line length exceeded"),
    (15, "Travel exceeded"),
    (16, "Invalid jog command"),
    (17, "Setting disabled (laser mode requires PWM output)"),
    (20, "Unsupported command"),
    (21, "Modal group violation"),
    (22, "Undefined feed rate"),
    (23, "G-code command in block requires an integer value"),
    (
        24,
        "More than one g-code command that requires axis words found in block",
    ),
    (25, "Repeated g-code word found in block"),
    (
        26,
        "No axis words found in block for g-code command or current modal state which requires them",
    ),
    (27, "Line number value is invalid"),
    (28, "G-code command is missing a required value word"),
    (29, "G59.x work coordinate systems are not supported"),
    (30, "G53 only allowed with G0 and G1 motion modes"),
    (
        31,
        "Axis words found in block when no command or current modal state uses them",
    ),
    (32, "G2 and G3 arcs require at least one in-plane axis word"),
    (33, "Motion command target is invalid"),
    (34, "Arc radius value is invalid"),
    (
        35,
        "G2 and G3 arcs require at least one in-plane offset word",
    ),
    (36, "Unused value words found in block"),
    (
        37,
        "G43.1 dynamic tool length offset is not assigned to configured tool length axis",
    ),
    (38, "Tool number greater than max supported value"),
];

/// `ALARM:N` codes of GRBL 1.1.
const ALARMS: [(u32, &str); 9] = [
    (1, "Hard limit triggered; machine position is likely lost"),
    (2, "Soft limit: motion target exceeds machine travel"),
    (3, "Reset while in motion; position cannot be guaranteed"),
    (4, "Probe fail: probe not in the expected initial state"),
    (
        5,
        "Probe fail: probe did not contact within the programmed travel",
    ),
    (6, "Homing fail: reset during active homing cycle"),
    (7, "Homing fail: safety door was opened during homing"),
    (
        8,
        "Homing fail: cycle failed to clear limit switch when pulling off",
    ),
    (
        9,
        "Homing fail: could not find limit switch within search distance",
    ),
];

/// Short meaning of `error:code`, or a note that GRBL 1.1 does not define it.
pub fn error_meaning(code: u32) -> &'static str {
    lookup(&ERRORS, code).unwrap_or("unknown error code (not defined by GRBL 1.1)")
}

/// Short meaning of `ALARM:code`, or a note that GRBL 1.1 does not define it.
pub fn alarm_meaning(code: u32) -> &'static str {
    lookup(&ALARMS, code).unwrap_or("unknown alarm code (not defined by GRBL 1.1)")
}

fn lookup(table: &[(u32, &'static str)], code: u32) -> Option<&'static str> {
    table.iter().find(|(c, _)| *c == code).map(|(_, m)| *m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_defined_code_has_a_meaning_and_gaps_say_unknown() {
        for code in (1..=17).chain(20..=38) {
            assert!(!error_meaning(code).contains("unknown"), "error:{code}");
        }
        for code in [0, 18, 19, 39, 1000] {
            assert!(error_meaning(code).contains("unknown"), "error:{code}");
        }
        for code in 1..=9 {
            assert!(!alarm_meaning(code).contains("unknown"), "ALARM:{code}");
        }
        assert!(alarm_meaning(10).contains("unknown"));
        assert_eq!(error_meaning(9), "G-code lock");
        assert!(alarm_meaning(1).starts_with("Hard limit"));
    }

    #[test]
    fn tables_are_sorted_without_duplicates() {
        assert!(ERRORS.windows(2).all(|w| w[0].0 < w[1].0));
        assert!(ALARMS.windows(2).all(|w| w[0].0 < w[1].0));
    }
}
