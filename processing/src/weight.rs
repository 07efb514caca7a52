//! The usable range of digital numbers and the weight over it: a DN near the black level
//! drowns in read noise, a DN near full scale may be clipped, so both ends count for nothing.
//! Debevec and Malik's hat rises linearly to the middle, which halves the trust in a quarter
//! of the range that the noise floor and margin already make safe; here the weight is a
//! trapezoid instead, ramping over the outer `RAMP_FRACTION` of the range at each end.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;

/// Fraction of the usable range over which the weight ramps from 0 to 1 at each end.
pub const RAMP_FRACTION: f64 = 0.05;

/// The digital numbers a fit or a merge trusts: above the black level plus the noise floor,
/// below saturation. Values outside get weight 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DnRange {
    /// Lowest trusted DN (weight 0 here).
    pub lo: f64,
    /// Highest trusted DN (weight 0 here).
    pub hi: f64,
}

impl DnRange {
    /// A range `[lo, hi]`; it must be finite and at least 2 DN wide.
    pub fn new(lo: f64, hi: f64) -> Result<DnRange, ProcessingError> {
        if !(lo.is_finite() && hi.is_finite() && hi - lo >= 2.0) {
            return Err(ProcessingError::BadRange { lo, hi });
        }
        Ok(DnRange { lo, hi })
    }

    /// The range for a sensor of `bit_depth` with `black_dn` offset: `noise_dn` above the
    /// black level up to `saturation_margin` (a fraction of full scale) below full scale.
    pub fn for_sensor(
        bit_depth: u8,
        black_dn: f64,
        noise_dn: f64,
        saturation_margin: f64,
    ) -> Result<DnRange, ProcessingError> {
        let max = ((1u64 << bit_depth.min(16)) - 1) as f64;
        DnRange::new(black_dn + noise_dn, max * (1.0 - saturation_margin))
    }

    /// The weight of `z` in [0, 1]: 0 at and outside the ends, 1 over the middle, linear
    /// over the outer `RAMP_FRACTION` of the range at each end.
    pub fn weight(&self, z: f64) -> f64 {
        let ramp = RAMP_FRACTION * (self.hi - self.lo);
        let w = (z - self.lo).min(self.hi - z) / ramp;
        // NaN fails the comparison and weighs 0 too.
        if w > 0.0 { w.min(1.0) } else { 0.0 }
    }

    /// Whether `z` is at or above the top of the range (saturated or nearly).
    pub fn is_high(&self, z: f64) -> bool {
        z >= self.hi
    }

    /// Whether `z` is at or below the bottom of the range (black or in the noise).
    pub fn is_low(&self, z: f64) -> bool {
        z <= self.lo
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weight_is_zero_at_the_ends_and_one_in_the_middle() {
        let r = DnRange::new(100.0, 300.0).unwrap();
        assert_eq!(r.weight(100.0), 0.0);
        assert_eq!(r.weight(300.0), 0.0);
        assert_eq!(r.weight(50.0), 0.0);
        assert_eq!(r.weight(4000.0), 0.0);
        assert_eq!(r.weight(200.0), 1.0);
        assert_eq!(r.weight(111.0), 1.0);
        assert!((r.weight(105.0) - 0.5).abs() < 1e-12);
        assert!((r.weight(295.0) - 0.5).abs() < 1e-12);
        assert_eq!(r.weight(f64::NAN), 0.0);
    }

    #[test]
    fn degenerate_ranges_are_refused() {
        assert!(DnRange::new(5.0, 6.0).is_err());
        assert!(DnRange::new(f64::NAN, 6.0).is_err());
        assert!(DnRange::new(10.0, 5.0).is_err());
        let r = DnRange::for_sensor(12, 82.0, 10.0, 0.02).unwrap();
        assert_eq!(r.lo, 92.0);
        assert!((r.hi - 4095.0 * 0.98).abs() < 1e-9);
    }
}
