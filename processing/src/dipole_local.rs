//! The local reflectance function of a quasi-homogeneous material (seed 004 eq. 5.67, L1232):
//! what a halogen image holds beyond the dipole's global term,
//!
//!   R(x, ω_i, ω_o) = L(x, ω_i, ω_o) − f_v(x, ω_o)·f(ω_i)·φ_L(ω_i)·∫R_d(‖x − x_i‖) dx_i,
//!
//! with negatives (noise) clamped to 0 and counted (L1234). Under a distant lamp the entering
//! light is uniform, so the integral is the medium's total diffuse reflectance R. In the
//! reflectance-factor units of a white-balanced capture (π·L/E: the colour calibration's
//! S = E/π of the lamp divides the radiance), the global term is
//!
//!   f_v(x)·f(ω_i)·F_t(η, 1)·F_t(η, cos θo)/c(η)·R,
//!
//! f_v in step 2's units (normal incidence's Fresnel factor and mean entrance in it), f(ω_i)
//! relative to normal incidence, F_t(η, cos θo)/c(η) the exit lobe
//! (`crate::dipole_products`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::dipole::fresnel_transmittance;
use crate::dipole_entrance::EntranceDirection;
use crate::dipole_exit::EXIT_MIN_WEIGHT;
use crate::hdr_frame::PixelState;

/// f(ω_i) in a lamp's direction, from step 1's directions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EntranceAt {
    /// f(ω_i).
    pub value: f64,
    /// The lamp's elevation lies outside step 1's mounts: the nearest mount's mesostructure
    /// part is used, with the Fresnel factor at the lamp's own angle.
    pub extrapolated: bool,
}

/// f(ω_i) at `elevation_deg` and `azimuth_deg` (on the sample) from step 1's `directions`.
/// The mesostructure's part g = f·F_t(η, 1)/F_t(η, cos θi) varies slowly, so it is what is
/// interpolated: linearly in azimuth within a mount (periodic), then linearly in elevation
/// between the two mounts around the lamp; the Fresnel factor is the lamp's own. An error
/// says why there is no value (no directions, a lamp at or below the horizon).
pub fn entrance_at(
    directions: &[EntranceDirection],
    eta: f64,
    elevation_deg: f64,
    azimuth_deg: f64,
) -> Result<EntranceAt, String> {
    let fresnel = |incidence_deg: f64| {
        fresnel_transmittance(incidence_deg.to_radians().cos().max(0.0), eta)
            / fresnel_transmittance(1.0, eta)
    };
    if !(elevation_deg > 0.0 && elevation_deg <= 90.0) {
        return Err(format!(
            "the lamp at {elevation_deg}° of elevation does not light the sample from above"
        ));
    }
    // Mount (thousandths of a degree) → (azimuth, g), g finite and ≥ 0.
    let mut mounts: BTreeMap<i64, Vec<(f64, f64)>> = BTreeMap::new();
    for d in directions {
        let t = fresnel(d.incidence_deg);
        if t > 0.0 && d.entrance.is_finite() && d.entrance >= 0.0 {
            mounts
                .entry((d.mount_deg * 1000.0).round() as i64)
                .or_default()
                .push((d.azimuth_deg.rem_euclid(360.0), d.entrance / t));
        }
    }
    let at_mount = |lines: &Vec<(f64, f64)>| -> f64 {
        let az = azimuth_deg.rem_euclid(360.0);
        // The nearest direction on each side, around the circle.
        let ahead = |a: f64| (a - az).rem_euclid(360.0);
        let next = lines
            .iter()
            .min_by(|a, b| ahead(a.0).total_cmp(&ahead(b.0)));
        let prev = lines
            .iter()
            .min_by(|a, b| (360.0 - ahead(a.0)).total_cmp(&(360.0 - ahead(b.0))));
        match (prev, next) {
            (Some(p), Some(n)) if p != n => {
                let (to_next, from_prev) = (ahead(n.0), (az - p.0).rem_euclid(360.0));
                let span = to_next + from_prev;
                if span > 0.0 {
                    (p.1 * to_next + n.1 * from_prev) / span
                } else {
                    p.1
                }
            }
            (_, Some(n)) => n.1,
            _ => 0.0,
        }
    };
    let elevation_key = elevation_deg * 1000.0;
    let below = mounts.range(..=elevation_key.floor() as i64).next_back();
    let above = mounts.range(elevation_key.ceil() as i64..).next();
    let (g, extrapolated) = match (below, above) {
        (Some((&lo, a)), Some((&hi, b))) if hi > lo => {
            let t = (elevation_key - lo as f64) / (hi - lo) as f64;
            (at_mount(a) * (1.0 - t) + at_mount(b) * t, false)
        }
        (Some((_, a)), Some(_)) => (at_mount(a), false),
        (Some((_, a)), None) | (None, Some((_, a))) => (at_mount(a), true),
        (None, None) => {
            return Err("step 1 measured the entrance function from no direction".into());
        }
    };
    Ok(EntranceAt {
        value: g * fresnel(90.0 - elevation_deg),
        extrapolated,
    })
}

/// One channel's global term over a view: the exit function and its weight per pixel (a
/// `process --products exit` map) and the factor f(ω_i)·F_t(η, 1)/c(η)·R.
#[derive(Debug, Clone, Copy)]
pub struct GlobalTerm<'a> {
    /// f_v per pixel.
    pub exit: &'a [f32],
    /// The exit map's weight per pixel (how well step 2's lines lit the point).
    pub weight: &'a [f32],
    /// f(ω_i)·F_t(η, 1)/c(η)·R.
    pub factor: f64,
    /// η.
    pub eta: f64,
}

/// What one channel of a local map holds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LocalCounts {
    /// Pixels with a value: the exit function known, the capture measured there.
    pub known: usize,
    /// Of those, pixels whose difference was negative and was clamped to 0.
    pub clamped: usize,
    /// Pixels where the exit function is known but the capture was saturated or black in
    /// every exposure (left unknown).
    pub unmeasured: usize,
    /// Σ π·L/E over the known pixels.
    pub captured: f64,
    /// Σ global term over the known pixels.
    pub global: f64,
}

impl std::ops::AddAssign for LocalCounts {
    fn add_assign(&mut self, other: LocalCounts) {
        self.known += other.known;
        self.clamped += other.clamped;
        self.unmeasured += other.unmeasured;
        self.captured += other.captured;
        self.global += other.global;
    }
}

/// Names of a local map's planes, in [`local_map`]'s order.
pub const LOCAL_PLANES: [&str; 12] = [
    "local.R",
    "local.G",
    "local.B",
    "known.R",
    "known.G",
    "known.B",
    "global.R",
    "global.G",
    "global.B",
    "captured.R",
    "captured.G",
    "captured.B",
];

/// A capture's local reflectance function: per pixel the [`LOCAL_PLANES`] interleaved (R
/// clamped at 0, `known` 1 or 0, the global term, the capture), from its white-balanced radiance `rgb`
/// (π·L/E) and `state`, each pixel's cosine to the camera on the sample plane `cos_out` (0 off
/// it), and each channel's global term (`None`: no dipole for that channel, unknown there).
/// Every value is finite: unknown pixels hold 0.
pub fn local_map(
    rgb: &[f32],
    state: &[PixelState],
    cos_out: &[f32],
    terms: &[Option<GlobalTerm<'_>>; 3],
) -> (Vec<f32>, [LocalCounts; 3]) {
    let n = cos_out.len();
    let mut out = vec![0.0f32; n * LOCAL_PLANES.len()];
    let mut counts = [LocalCounts::default(); 3];
    for (c, term) in terms.iter().enumerate() {
        let Some(term) = term else { continue };
        let count = &mut counts[c];
        for i in 0..n {
            let (Some(&f_v), Some(&w)) = (term.exit.get(i), term.weight.get(i)) else {
                continue;
            };
            let cos = f64::from(cos_out[i]);
            if f64::from(w) < EXIT_MIN_WEIGHT || cos.is_nan() || cos <= 0.0 || !f_v.is_finite() {
                continue;
            }
            if state.get(3 * i + c) != Some(&PixelState::Measured) {
                count.unmeasured += 1;
                continue;
            }
            let captured = f64::from(rgb[3 * i + c]);
            let global =
                f64::from(f_v).max(0.0) * term.factor * fresnel_transmittance(cos, term.eta);
            let local = captured - global;
            if !(local.is_finite() && global.is_finite()) {
                continue;
            }
            count.known += 1;
            count.captured += captured;
            count.global += global;
            if local < 0.0 {
                count.clamped += 1;
            }
            let at = i * LOCAL_PLANES.len();
            out[at + c] = local.max(0.0) as f32;
            out[at + 3 + c] = 1.0;
            out[at + 6 + c] = global as f32;
            out[at + 9 + c] = captured as f32;
        }
    }
    (out, counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn direction(mount_deg: f64, azimuth_deg: f64, g: f64, eta: f64) -> EntranceDirection {
        let incidence_deg = 90.0 - mount_deg;
        let t = fresnel_transmittance(incidence_deg.to_radians().cos(), eta)
            / fresnel_transmittance(1.0, eta);
        EntranceDirection {
            mount_deg,
            azimuth_deg,
            incidence_deg,
            entrance: g * t,
            cameras: BTreeMap::new(),
            lines: 1,
        }
    }

    #[test]
    fn the_entrance_is_interpolated_in_its_mesostructure_part() {
        let eta = 1.3;
        let fresnel = |e: f64| {
            fresnel_transmittance((90.0 - e).to_radians().cos(), eta)
                / fresnel_transmittance(1.0, eta)
        };
        // A homogeneous sample (g = 1) from two mounts: every lamp's f is its own Fresnel
        // factor, inside the mounts or beyond them.
        let flat = [
            direction(15.0, 0.0, 1.0, eta),
            direction(75.0, 0.0, 1.0, eta),
        ];
        for e in [10.0, 15.0, 40.0, 75.0, 80.0, 90.0] {
            let f = entrance_at(&flat, eta, e, 123.0).expect("a value");
            assert!((f.value - fresnel(e)).abs() < 1e-12, "{e}: {f:?}");
            assert_eq!(f.extrapolated, !(15.0..=75.0).contains(&e), "{e}");
        }
        // g linear in elevation and periodic in azimuth: 0.8 at 15°, 0.6 at 75° (azimuth 0);
        // 0.4 at 75° azimuth 180.
        let meso = [
            direction(15.0, 0.0, 0.8, eta),
            direction(75.0, 0.0, 0.6, eta),
            direction(75.0, 180.0, 0.4, eta),
        ];
        let f = entrance_at(&meso, eta, 45.0, 0.0).expect("a value");
        assert!((f.value / fresnel(45.0) - 0.7).abs() < 1e-12, "{f:?}");
        // At azimuth 270 (90° from either direction of the 75° mount, across 360°): 0.5.
        let f = entrance_at(&meso, eta, 75.0, 270.0).expect("a value");
        assert!((f.value / fresnel(75.0) - 0.5).abs() < 1e-12, "{f:?}");
        let f = entrance_at(&meso, eta, 75.0, -45.0).expect("a value");
        assert!((f.value / fresnel(75.0) - 0.55).abs() < 1e-12, "{f:?}");
        // No direction, or a lamp at the horizon: an error, no number.
        assert!(entrance_at(&[], eta, 45.0, 0.0).is_err());
        assert!(entrance_at(&flat, eta, 0.0, 0.0).is_err());
        assert!(entrance_at(&flat, eta, f64::NAN, 0.0).is_err());
    }

    #[test]
    fn the_local_term_is_what_the_global_term_leaves_clamped_and_counted() {
        let eta = 1.3;
        // Four pixels: lit and bright; lit and darker than the global term (clamped); lit but
        // saturated; not lit by step 2's lines.
        let exit = [1.0f32, 1.0, 1.0, 0.0];
        let weight = [1.0f32, 0.5, 1.0, 0.0];
        let cos_out = [1.0f32, 0.5, 1.0, 1.0];
        let factor = 0.3;
        let g = |cos: f64| factor * fresnel_transmittance(cos, eta);
        let rgb = [
            (g(1.0) + 0.1) as f32,
            0.0,
            0.0,
            (g(0.5) - 0.01) as f32,
            0.0,
            0.0,
            9.0,
            0.0,
            0.0,
            1.0,
            0.0,
            0.0,
        ];
        let mut state = vec![PixelState::Measured; 12];
        state[6] = PixelState::AtLeast;
        let term = GlobalTerm {
            exit: &exit,
            weight: &weight,
            factor,
            eta,
        };
        let (map, counts) = local_map(&rgb, &state, &cos_out, &[Some(term), None, None]);
        let px = |i: usize, plane: usize| map[i * LOCAL_PLANES.len() + plane];
        assert!((px(0, 0) - 0.1).abs() < 1e-6, "{}", px(0, 0));
        assert_eq!((px(0, 3), px(0, 4)), (1.0, 0.0), "G has no dipole: unknown");
        assert!((f64::from(px(0, 6)) - g(1.0)).abs() < 1e-6);
        assert_eq!(px(0, 9), rgb[0]);
        assert_eq!((px(1, 0), px(1, 3)), (0.0, 1.0), "clamped, known");
        assert_eq!((px(2, 3), px(3, 3)), (0.0, 0.0), "saturated; unlit");
        assert_eq!(counts[0].known, 2);
        assert_eq!(counts[0].clamped, 1);
        assert_eq!(counts[0].unmeasured, 1);
        assert_eq!(counts[1], LocalCounts::default());
        assert!(map.iter().all(|v| v.is_finite()));
    }
}
