//! An inverse camera response g(Z) = ln f⁻¹(Z) (Debevec–Malik): the log exposure E·Δt that
//! produced digital number Z, up to one additive constant per channel (white balance fixes it).
//! It is stored on knots over the usable DN range and interpolated linearly: 8-bit data has a
//! knot per level; 12- and 16-bit data have knots evenly spaced in ln(1 + (Z − lo)/s), dense
//! near the black level where g bends most (g ≈ ln(Z − black) for a linear sensor) and sparse
//! near full scale, so linear interpolation stays far below 0.1 % everywhere.

use serde::{Deserialize, Serialize};

use crate::weight::DnRange;

/// A recovered inverse response of one channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InverseResponse {
    /// The usable DN range the knots span.
    pub range: DnRange,
    /// DN of each knot, rising, from `range.lo` to `range.hi`.
    pub knots_dn: Vec<f64>,
    /// g at each knot, ln of relative exposure.
    pub g: Vec<f64>,
    /// The DN span the fit's observations covered; outside it g is extrapolated by the
    /// smoothness term only.
    pub observed: DnRange,
}

/// Knots over `range`: one per DN if `levels` allow, else `levels` knots evenly spaced in
/// u = ln(1 + (Z − lo)/s) with s = (hi − lo)/64.
pub fn knots(range: DnRange, levels: usize) -> Vec<f64> {
    let width = range.hi - range.lo;
    let levels = levels.max(2);
    if width + 1.0 <= levels as f64 {
        let n = width.floor() as usize + 1;
        let mut k: Vec<f64> = (0..n).map(|i| range.lo + i as f64).collect();
        if let Some(last) = k.last_mut() {
            *last = range.hi;
        }
        return k;
    }
    let s = width / 64.0;
    let u_max = (1.0 + width / s).ln();
    (0..levels)
        .map(|i| {
            let u = u_max * i as f64 / (levels - 1) as f64;
            if i + 1 == levels {
                range.hi
            } else {
                range.lo + s * u.exp_m1()
            }
        })
        .collect()
}

impl InverseResponse {
    /// Knot index `k` and interpolation fraction of `z` between knots k and k + 1, clamped
    /// to the knots' span.
    pub fn locate(&self, z: f64) -> (usize, f64) {
        locate(&self.knots_dn, z)
    }

    /// g(z): ln of the relative exposure that gives DN `z` (clamped to the knots' range).
    pub fn g(&self, z: f64) -> f64 {
        match self.g.len() {
            0 => 0.0,
            1 => self.g[0],
            _ => {
                let (k, a) = self.locate(z);
                (1.0 - a) * self.g[k] + a * self.g[k + 1]
            }
        }
    }

    /// The relative exposure f⁻¹(z) = exp g(z).
    pub fn exposure(&self, z: f64) -> f64 {
        self.g(z).exp()
    }

    /// Whether g rises strictly over the observed span, as any camera's response does; a fit
    /// that is not is a sign of misregistered or moving frames.
    pub fn rises_over_observed(&self) -> bool {
        let (k0, _) = self.locate(self.observed.lo);
        let (k1, _) = self.locate(self.observed.hi);
        self.g[k0..=(k1 + 1).min(self.g.len() - 1)]
            .windows(2)
            .all(|w| w[1] > w[0])
    }
}

/// Knot index and fraction of `z` on `knots` (rising, at least 2), clamped to their span.
pub fn locate(knots: &[f64], z: f64) -> (usize, f64) {
    let n = knots.len();
    if n < 2 {
        return (0, 0.0);
    }
    let k = knots.partition_point(|&x| x <= z).clamp(1, n - 1) - 1;
    let a = ((z - knots[k]) / (knots[k + 1] - knots[k])).clamp(0.0, 1.0);
    // NaN (from a NaN z) counts as the knot itself.
    (k, if a.is_nan() { 0.0 } else { a })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_between_knots_and_clamps_outside() {
        let range = DnRange::new(0.0, 10.0).unwrap();
        let r = InverseResponse {
            range,
            knots_dn: vec![0.0, 5.0, 10.0],
            g: vec![0.0, 1.0, 4.0],
            observed: range,
        };
        assert_eq!(r.g(0.0), 0.0);
        assert_eq!(r.g(2.5), 0.5);
        assert_eq!(r.g(7.5), 2.5);
        assert_eq!(r.g(10.0), 4.0);
        assert_eq!(r.g(-3.0), 0.0);
        assert_eq!(r.g(99.0), 4.0);
        assert!(r.rises_over_observed());
        assert_eq!(r.g(f64::NAN), 0.0);
    }

    #[test]
    fn knots_are_one_per_dn_for_8_bits_and_warped_for_12() {
        let k8 = knots(DnRange::new(8.0, 250.0).unwrap(), 256);
        assert_eq!(k8.len(), 243);
        assert_eq!((k8[0], k8[1], k8[242]), (8.0, 9.0, 250.0));
        let k12 = knots(DnRange::new(112.0, 4013.0).unwrap(), 256);
        assert_eq!(k12.len(), 256);
        assert_eq!((k12[0], k12[255]), (112.0, 4013.0));
        let first = k12[1] - k12[0];
        let last = k12[255] - k12[254];
        assert!(first > 0.9 && first < 1.2, "{first}");
        assert!(last > 50.0 && last < 80.0, "{last}");
        assert!(k12.windows(2).all(|w| w[1] > w[0]));
    }
}
