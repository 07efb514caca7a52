//! The mesostructure entrance function f(ω_i) of a quasi-homogeneous material (seed 004
//! eq. 5.61, L1184): how much of the laser's light enters the sample from each direction,
//! relative to normal incidence. The seed sums every camera's pixels over every line of a
//! step-1 sweep and divides by the same sum at normal incidence. Here each oblique line's
//! falloff is fitted by the dipole fitted at normal incidence (step 2), in the same units:
//! its amplitude is that ratio, and the clipped core the plain sum would misread is left out.
//! The directions' values are averaged over lines, then over cameras, as the seed does.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::dipole::DipoleMedium;
use crate::dipole_fit::blurred_profile;

/// Least pixels outside the core for a line's amplitude.
const MIN_PIXELS: usize = 20;

/// The entrance function in one direction of incidence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EntranceDirection {
    /// The laser's mount on the light arc, degrees of elevation.
    pub mount_deg: f64,
    /// The light arc's angle less the turntable's: the incidence's azimuth on the sample,
    /// degrees.
    pub azimuth_deg: f64,
    /// The angle of incidence from the sample's normal, degrees (90° less the mount).
    pub incidence_deg: f64,
    /// f(ω_i): the mean over cameras of each camera's mean over lines.
    pub entrance: f64,
    /// Each camera's mean over its lines.
    pub cameras: BTreeMap<String, f64>,
    /// Lines (frames) used.
    pub lines: usize,
}

/// The line's amplitude against the normal-incidence profile: Σv·m / Σm² over the pixels
/// (distance s, value v in the profile's units) outside the core, m the fitted medium's
/// profile blurred by the line's width. An error says why there is none.
pub(crate) fn line_amplitude(
    pixels: &[(f64, f64)],
    medium: &DipoleMedium,
    line_width_mm: f64,
    core_mm: f64,
) -> Result<f64, String> {
    let (mut vm, mut mm, mut used) = (0.0, 0.0, 0);
    for &(s, v) in pixels.iter().filter(|(s, _)| s.abs() > core_mm) {
        let m = blurred_profile(medium, s, line_width_mm);
        if m > 0.0 && m.is_finite() && v.is_finite() {
            vm += v * m;
            mm += m * m;
            used += 1;
        }
    }
    if used < MIN_PIXELS || mm <= 0.0 {
        return Err(format!(
            "{used} pixels beside the line's core (it needs {MIN_PIXELS}): the line is off the sample's centre or hidden"
        ));
    }
    Ok(vm / mm)
}

/// The amplitudes of a colour's oblique lines, gathered by direction and camera.
#[derive(Debug, Default)]
pub(crate) struct Directions {
    /// (mount, azimuth) in thousandths of a degree → camera → amplitudes.
    lines: BTreeMap<(i64, i64), BTreeMap<String, Vec<f64>>>,
}

impl Directions {
    /// Adds one line's amplitude seen by `camera` with the laser at `mount_deg` and
    /// `azimuth_deg`.
    pub(crate) fn add(&mut self, mount_deg: f64, azimuth_deg: f64, camera: &str, amplitude: f64) {
        let key = |d: f64| (d * 1000.0).round() as i64;
        let azimuth = azimuth_deg.rem_euclid(360.0);
        self.lines
            .entry((key(mount_deg), key(azimuth)))
            .or_default()
            .entry(camera.to_string())
            .or_default()
            .push(amplitude);
    }

    /// The entrance function of every direction seen.
    pub(crate) fn finish(self) -> Vec<EntranceDirection> {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        self.lines
            .into_iter()
            .map(|((mount, azimuth), cameras)| {
                let lines = cameras.values().map(Vec::len).sum();
                let cameras: BTreeMap<String, f64> =
                    cameras.iter().map(|(c, v)| (c.clone(), mean(v))).collect();
                let per_camera: Vec<f64> = cameras.values().copied().collect();
                let mount_deg = mount as f64 / 1000.0;
                EntranceDirection {
                    mount_deg,
                    azimuth_deg: azimuth as f64 / 1000.0,
                    incidence_deg: 90.0 - mount_deg,
                    entrance: mean(&per_camera),
                    cameras,
                    lines,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn felt() -> DipoleMedium {
        DipoleMedium {
            alpha_p: 0.4248,
            sigma_t_p: 1.0,
            eta: 1.3,
        }
    }

    #[test]
    fn a_scaled_profile_gives_its_scale_and_too_few_pixels_are_refused() {
        let medium = felt();
        let pixels: Vec<(f64, f64)> = (-100..=100)
            .map(|k| {
                let s = 0.1 * k as f64;
                (s, 0.8 * blurred_profile(&medium, s, 0.3))
            })
            .collect();
        let k = line_amplitude(&pixels, &medium, 0.3, 1.0).expect("an amplitude");
        assert!((k - 0.8).abs() < 1e-12, "{k}");
        // The core alone, or nothing: no amplitude, and the reason.
        let core: Vec<(f64, f64)> = pixels.iter().copied().filter(|p| p.0.abs() < 1.0).collect();
        let e = line_amplitude(&core, &medium, 0.3, 1.0).expect_err("only the core");
        assert!(e.contains("pixels beside the line's core"), "{e}");
        assert!(line_amplitude(&[], &medium, 0.3, 1.0).is_err());
    }

    #[test]
    fn directions_average_lines_then_cameras() {
        let mut d = Directions::default();
        d.add(15.0, 0.0, "cam1", 0.7);
        d.add(15.0, 360.0, "cam1", 0.9);
        d.add(15.0, 0.0, "cam2", 0.5);
        d.add(75.0, 30.0, "cam1", 1.0);
        let out = d.finish();
        assert_eq!(out.len(), 2);
        let low = &out[0];
        assert_eq!((low.mount_deg, low.azimuth_deg, low.lines), (15.0, 0.0, 3));
        assert!((low.incidence_deg - 75.0).abs() < 1e-12);
        // cam1: (0.7 + 0.9)/2 = 0.8; cam2: 0.5; their mean 0.65.
        assert!((low.entrance - 0.65).abs() < 1e-12, "{low:?}");
        assert_eq!(out[1].lines, 1);
    }
}
