//! The per-pixel fit of the linear-light reflectometer (Gardner et al. 2003; seed 004 §2.4):
//! isotropic Ward ρd (RGB), ρs and α from a pixel's response to the tube at each cart stop.
//!
//! The response is linear in the ρ's for a given α ([`crate::ward_tube`]), so for each α the
//! four ρ's are solved in closed form (least squares, none negative) and α alone is searched:
//! a log grid over the whole range (the integrals coarse, the misfit's slope beside its
//! value), then a cubic on the misfit and its slope in α (the integrals fine). Gardner starts
//! a non-linear fit from the diffuse and specular peaks; the grid over the whole range needs
//! no start, and finds the basin of a misfit with one. What the data cannot say is flagged,
//! never hidden.

use serde::{Deserialize, Serialize};

use crate::error::ProcessingError;
use crate::line_search::{Probe, sloped_log_search};
use crate::ward_tube::{Lobe, Quadrature, Tube, ViewPoint};

/// One cart stop of one pixel: where the tube was and what the pixel saw (radiance per unit
/// of the tube's calibrated intensity per millimetre, per channel).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WardSample {
    /// The tube's x (cart position less half the travel), mm.
    pub tube_x_mm: f64,
    /// Radiance over the tube's per-mm intensity of each channel.
    pub rgb: [f64; 3],
    /// The pixel clipped in this frame: left out of the fit.
    pub saturated: bool,
}

/// Settings of [`fit_ward`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WardFitOptions {
    /// The α search interval.
    pub alpha_range: [f64; 2],
    /// A pixel whose brightest sample is below this (in sample units) is black.
    pub black_level: f64,
    /// A fit whose RMS residual exceeds this fraction of the data's RMS is flagged.
    pub poor_fit_rms: f64,
}

impl Default for WardFitOptions {
    fn default() -> Self {
        WardFitOptions {
            alpha_range: [0.005, 1.0],
            black_level: 1e-6,
            poor_fit_rms: 0.1,
        }
    }
}

/// Why a pixel's parameters are weakly determined or not at all.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum WardFlag {
    /// Nothing above the black level: every ρ is 0 and α means nothing.
    Black,
    /// No specular light found (ρs ≈ 0, or a lobe no stronger than the noise): α is not
    /// determined.
    NoSpecular,
    /// The mirror direction meets the tube outside the sweep (or beyond the tube's ends): the
    /// specular peak was never seen, so ρs and α rest on a tail.
    SpecularPeakOutsideSweep,
    /// α is narrower than the angle between two cart stops: the peak falls between samples and
    /// α is an upper bound at best (ρs·α² is what is measured).
    AlphaBelowStopSpacing,
    /// α ended at an end of its search interval.
    AlphaAtSearchEnd,
    /// Some samples clipped and were left out.
    Saturated,
    /// Isotropic Ward does not explain the data (RMS residual above the option's fraction).
    PoorFit,
    /// Two scans with the sample turned 90° between them disagree on α: the surface is
    /// anisotropic and isotropic Ward does not describe it (the numbers are the two scans'
    /// means). One scan cannot tell: the tube integrates the lobe along its length, and any
    /// lobe's profile across the sweep is matched by some isotropic α.
    Anisotropic,
}

/// A pixel's fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WardFit {
    /// Diffuse albedo per channel.
    pub rho_d: [f64; 3],
    /// Specular albedo (grey).
    pub rho_s: f64,
    /// Roughness α.
    pub alpha: f64,
    /// RMS of (data − model) over the samples used, relative to the data's RMS.
    pub relative_rms: f64,
    /// Samples used (not clipped).
    pub samples: usize,
    /// Weak determinations.
    pub flags: Vec<WardFlag>,
}

/// Least usable samples for a fit (four ρ's and α).
pub const MIN_SAMPLES: usize = 6;
/// Least F statistic of a specular lobe (its two parameters against the residual's variance)
/// for the fit to report one: well above the 1 %-level critical value (about 4.6), so that
/// noise on a matte sample is not read as a faint lobe.
const MIN_LOBE_F: f64 = 10.0;
/// The α search: a grid of 6 points over the range (steps of about 2.9× over the default
/// range), then the sloped refinement to 10⁻⁴ in ln α.
const GRID: usize = 6;
const ALPHA_TOLERANCE: f64 = 1e-4;

/// Fits a pixel seen at `view` under `tube` to its `samples`. Errors when a sample is not
/// finite or too few samples are usable; every weaker case is a flag on the result.
pub fn fit_ward(
    tube: &Tube,
    view: &ViewPoint,
    samples: &[WardSample],
    options: &WardFitOptions,
) -> Result<WardFit, ProcessingError> {
    let [lo, hi] = options.alpha_range;
    if !(lo > 0.0
        && hi > lo
        && hi.is_finite()
        && options.black_level >= 0.0
        && options.black_level.is_finite()
        && options.poor_fit_rms > 0.0)
    {
        return Err(ProcessingError::IllPosed {
            what: "Ward fit",
            why: format!(
                "the options (α range [{lo}, {hi}], black level {}, poor-fit RMS {}) need an ordered positive α range, a black level of 0 or more and a poor-fit RMS above 0",
                options.black_level, options.poor_fit_rms
            ),
        });
    }
    if let Some(bad) = samples
        .iter()
        .find(|s| !s.tube_x_mm.is_finite() || s.rgb.iter().any(|v| !v.is_finite()))
    {
        return Err(ProcessingError::IllPosed {
            what: "Ward fit",
            why: format!(
                "the sample at tube x {} mm is not finite ({:?}); check the frame and its calibration",
                bad.tube_x_mm, bad.rgb
            ),
        });
    }
    let used: Vec<&WardSample> = samples.iter().filter(|s| !s.saturated).collect();
    if used.len() < MIN_SAMPLES {
        return Err(ProcessingError::IllPosed {
            what: "Ward fit",
            why: format!(
                "{} usable samples ({} clipped) where it needs {MIN_SAMPLES}; scan more cart stops or shorten the exposure",
                used.len(),
                samples.len() - used.len()
            ),
        });
    }
    let mut flags = Vec::new();
    if used.len() < samples.len() {
        flags.push(WardFlag::Saturated);
    }
    let brightest = used.iter().flat_map(|s| s.rgb).fold(0.0f64, f64::max);
    if brightest <= options.black_level {
        flags.insert(0, WardFlag::Black);
        return Ok(WardFit {
            rho_d: [0.0; 3],
            rho_s: 0.0,
            alpha: options.alpha_range[1],
            relative_rms: 0.0,
            samples: used.len(),
            flags,
        });
    }
    let diffuse: Vec<f64> = used
        .iter()
        .map(|s| tube.diffuse(view, s.tube_x_mm) / std::f64::consts::PI)
        .collect();
    let data_sq: f64 = used.iter().flat_map(|s| s.rgb).map(|v| v * v).sum();
    let lobes: Vec<Lobe> = used.iter().map(|s| tube.lobe(view, s.tube_x_mm)).collect();
    let probe = |alpha: f64, quadrature: Quadrature| {
        let row: Vec<(f64, f64)> = lobes
            .iter()
            .map(|lobe| tube.specular_of(view, lobe, alpha, quadrature))
            .collect();
        let specular: Vec<f64> = row.iter().map(|r| r.0).collect();
        let solution = Sums::new(&used, &diffuse, &specular).solve();
        // dSSE/d(ln α) with the ρ's held at their optimum (where SSE is flat in them):
        // −2ρs·Σ_k (Σ_c residual_kc)·dS_k/d(ln α).
        let rho_d_sum: f64 = solution.rho_d.iter().sum();
        let slope = -2.0
            * solution.rho_s
            * used
                .iter()
                .zip(&diffuse)
                .zip(&row)
                .map(|((s, a), (b, db))| {
                    (s.rgb.iter().sum::<f64>() - a * rho_d_sum - 3.0 * solution.rho_s * b) * db
                })
                .sum::<f64>();
        Probe {
            value: solution.sse,
            slope,
            payload: solution,
        }
    };
    let (alpha, best) = sloped_log_search(
        &|a| probe(a, Quadrature::Coarse),
        &|a| probe(a, Quadrature::Fine),
        lo,
        hi,
        GRID,
        ALPHA_TOLERANCE,
    );
    let best = best.payload;
    let relative_rms = (best.sse.max(0.0) / data_sq.max(f64::MIN_POSITIVE)).sqrt();

    // What the data cannot say.
    let (mirror_x, mirror_y) = view.mirror_point(tube.height_mm);
    let (first, last) = used
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.tube_x_mm), b.max(s.tube_x_mm))
        });
    let peak_seen = mirror_x >= first && mirror_x <= last && mirror_y.abs() <= 0.5 * tube.length_mm;
    let specular_peak = best.rho_s * tube.specular(view, mirror_x, alpha);
    let diffuse_peak = best.rho_d.iter().fold(0.0f64, |m, v| m.max(*v))
        * tube.diffuse(view, mirror_x)
        / std::f64::consts::PI;
    if !peak_seen {
        flags.push(WardFlag::SpecularPeakOutsideSweep);
    }
    // Does the lobe explain more than noise would? The F statistic of adding ρs and α to a
    // diffuse-only fit, over the 3 channels' samples.
    let diffuse_only = Sums::new(&used, &diffuse, &vec![0.0; used.len()]).solve();
    let dof = (3 * used.len()).saturating_sub(5).max(1) as f64;
    let lobe_f = (diffuse_only.sse - best.sse).max(0.0)
        / 2.0
        / (best.sse.max(0.0) / dof).max(f64::MIN_POSITIVE);
    if best.rho_s <= 0.0
        || specular_peak < 1e-3 * diffuse_peak.max(options.black_level)
        || lobe_f < MIN_LOBE_F
    {
        flags.push(WardFlag::NoSpecular);
    } else {
        if alpha < stop_angle(tube, view, samples, mirror_x) {
            flags.push(WardFlag::AlphaBelowStopSpacing);
        }
        if alpha < lo * 1.01 || alpha > hi / 1.01 {
            flags.push(WardFlag::AlphaAtSearchEnd);
        }
    }
    if relative_rms > options.poor_fit_rms {
        flags.push(WardFlag::PoorFit);
    }
    Ok(WardFit {
        rho_d: best.rho_d,
        rho_s: best.rho_s,
        alpha,
        relative_rms,
        samples: used.len(),
        flags,
    })
}

/// Two scans of the same pixel, the sample turned 90° between them (Gardner et al. scan
/// twice for this), combined: the means of the two fits, flagged [`WardFlag::Anisotropic`]
/// when their α differ by more than `tolerance` (relative) and both determined α. Flags of
/// either scan carry over.
pub fn combine_turned_scans(a: &WardFit, b: &WardFit, tolerance: f64) -> WardFit {
    let mut flags: Vec<WardFlag> = a.flags.clone();
    for f in &b.flags {
        if !flags.contains(f) {
            flags.push(*f);
        }
    }
    let undetermined = |f: &WardFit| {
        f.flags.iter().any(|g| {
            matches!(
                g,
                WardFlag::Black
                    | WardFlag::NoSpecular
                    | WardFlag::SpecularPeakOutsideSweep
                    | WardFlag::AlphaBelowStopSpacing
            )
        })
    };
    let spread = (a.alpha - b.alpha).abs() / (0.5 * (a.alpha + b.alpha)).max(f64::MIN_POSITIVE);
    if !undetermined(a) && !undetermined(b) && spread > tolerance {
        flags.push(WardFlag::Anisotropic);
    }
    let mean = |x: f64, y: f64| 0.5 * (x + y);
    WardFit {
        rho_d: [0, 1, 2].map(|c| mean(a.rho_d[c], b.rho_d[c])),
        rho_s: mean(a.rho_s, b.rho_s),
        alpha: mean(a.alpha, b.alpha),
        relative_rms: a.relative_rms.max(b.relative_rms),
        samples: a.samples + b.samples,
        flags,
    }
}

/// Half the angle the tube turns through, seen from the point, between the two stops nearest
/// the mirror point (clipped or not): the half-vector's step, the finest α the sweep resolves.
fn stop_angle(tube: &Tube, view: &ViewPoint, samples: &[WardSample], mirror_x: f64) -> f64 {
    let mut xs: Vec<f64> = samples.iter().map(|s| s.tube_x_mm).collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let Some(k) = xs.windows(2).position(|w| w[1] >= mirror_x) else {
        return 0.0;
    };
    let (_, y) = view.mirror_point(tube.height_mm);
    let y = y.clamp(-0.5 * tube.length_mm, 0.5 * tube.length_mm);
    let dir = |x: f64| (nalgebra::Vector3::new(x, y, tube.height_mm) - view.p).normalize();
    0.5 * dir(xs[k]).angle(&dir(xs[k + 1]))
}

/// The normal-equation sums of one α over the samples k of one channel, with a = D_k/π,
/// b = S_k and L the channel's data.
#[derive(Default, Clone, Copy)]
struct Channel {
    aa: f64,
    ab: f64,
    al: f64,
    bl: f64,
    ll: f64,
}

/// The sums of every channel, and Σb² (the same in each).
struct Sums {
    channels: [Channel; 3],
    bb: f64,
}

/// ρ's of one α and their sum of squared residuals.
struct Solution {
    rho_d: [f64; 3],
    rho_s: f64,
    sse: f64,
}

impl Sums {
    fn new(used: &[&WardSample], diffuse: &[f64], specular: &[f64]) -> Sums {
        let mut s = Sums {
            channels: [Channel::default(); 3],
            bb: 0.0,
        };
        for ((sample, a), b) in used.iter().zip(diffuse).zip(specular) {
            s.bb += b * b;
            for (ch, l) in s.channels.iter_mut().zip(sample.rgb) {
                ch.aa += a * a;
                ch.ab += a * b;
                ch.al += a * l;
                ch.bl += b * l;
                ch.ll += l * l;
            }
        }
        s
    }

    /// Least squares with every ρ ≥ 0: the unconstrained solution, then channels whose ρd
    /// came out negative held at 0 (and ρs at 0 if it did), re-solved until none is.
    fn solve(&self) -> Solution {
        let mut free = [true; 3];
        let mut rho_d = [0.0; 3];
        let mut rho_s = 0.0;
        // ρs is grey: its column is b in every channel, so Σb² counts three times.
        let bb3 = 3.0 * self.bb;
        for _ in 0..4 {
            let (mut num, mut den) = (0.0, bb3);
            for (ch, free) in self.channels.iter().zip(free) {
                num += ch.bl;
                if free && ch.aa > 0.0 {
                    num -= ch.ab * ch.al / ch.aa;
                    den -= ch.ab * ch.ab / ch.aa;
                }
            }
            rho_s = if den > 1e-12 * bb3 && num > 0.0 {
                num / den
            } else {
                0.0
            };
            let mut changed = false;
            for ((ch, free), rho) in self.channels.iter().zip(&mut free).zip(&mut rho_d) {
                *rho = if *free && ch.aa > 0.0 {
                    (ch.al - rho_s * ch.ab) / ch.aa
                } else {
                    0.0
                };
                if *rho < 0.0 {
                    *rho = 0.0;
                    *free = false;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let s = rho_s;
        let sse = self
            .channels
            .iter()
            .zip(rho_d)
            .map(|(ch, d)| {
                ch.ll - 2.0 * (d * ch.al + s * ch.bl)
                    + d * d * ch.aa
                    + 2.0 * d * s * ch.ab
                    + s * s * self.bb
            })
            .sum::<f64>();
        Solution { rho_d, rho_s, sse }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// The reflectometer rig's tube.
    pub(crate) const TUBE: Tube = Tube {
        height_mm: 60.0,
        length_mm: 300.0,
        radius_mm: 13.0,
    };

    /// The reflectometer camera: 60° elevation on the −x side, 600 mm away.
    fn view(x: f64, y: f64) -> ViewPoint {
        let camera = Vector3::new(-300.0, 0.0, 300.0 * 3f64.sqrt());
        ViewPoint::seen_from(Vector3::new(x, y, 0.0), camera).expect("above the sample")
    }

    /// A deterministic normal deviate stream (Box–Muller on a 64-bit LCG).
    struct Noise(u64);
    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    /// The default scan (121 stops over 240 mm) of a pixel with these parameters, each value
    /// with relative noise `noise` plus 0.2 % of the pixel's peak (the sensor's floor).
    fn scan(
        v: &ViewPoint,
        rho_d: [f64; 3],
        rho_s: f64,
        alpha: f64,
        noise: f64,
        seed: u64,
    ) -> Vec<WardSample> {
        let mut rng = Noise(seed);
        let clean: Vec<(f64, [f64; 3])> = (0..121)
            .map(|i| {
                let x = -120.0 + 2.0 * i as f64;
                let d = TUBE.diffuse(v, x) / std::f64::consts::PI;
                let s = TUBE.specular(v, x, alpha);
                (x, rho_d.map(|r| r * d + rho_s * s))
            })
            .collect();
        let peak = clean.iter().flat_map(|(_, c)| *c).fold(0.0f64, f64::max);
        clean
            .into_iter()
            .map(|(x, c)| WardSample {
                tube_x_mm: x,
                rgb: c.map(|val| {
                    val * (1.0 + noise * rng.normal()) + 0.2 * noise * peak * rng.normal()
                }),
                saturated: false,
            })
            .collect()
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a / b - 1.0).abs()
    }

    #[test]
    fn glossy_rough_and_matte_pixels_are_recovered_without_noise() {
        let v = view(3.0, -8.0);
        let options = WardFitOptions::default();
        for (rho_d, rho_s, alpha) in [
            ([0.3, 0.2, 0.1], 0.08, 0.06),
            ([0.6, 0.55, 0.5], 0.2, 0.3),
            ([0.05, 0.05, 0.05], 0.04, 0.02),
        ] {
            let fit = fit_ward(&TUBE, &v, &scan(&v, rho_d, rho_s, alpha, 0.0, 1), &options)
                .expect("fits");
            assert!(fit.flags.is_empty(), "{fit:?}");
            for (got, truth) in fit.rho_d.iter().zip(rho_d) {
                assert!(rel(*got, truth) < 1e-4, "{fit:?}");
            }
            assert!(
                rel(fit.rho_s, rho_s) < 1e-4 && rel(fit.alpha, alpha) < 1e-4,
                "{fit:?}"
            );
            assert!(fit.relative_rms < 1e-5, "{fit:?}");
        }
        let matte = fit_ward(
            &TUBE,
            &v,
            &scan(&v, [0.7, 0.4, 0.2], 0.0, 0.1, 0.0, 1),
            &options,
        )
        .expect("fits");
        assert_eq!(matte.flags, vec![WardFlag::NoSpecular], "{matte:?}");
        assert!(
            rel(matte.rho_d[0], 0.7) < 1e-6 && matte.rho_s < 1e-9,
            "{matte:?}"
        );
    }

    #[test]
    fn with_sensor_noise_the_medians_over_a_sample_meet_the_targets() {
        // The targets: ρd within 2 %, ρs and α within 5 % (median over the sample).
        let options = WardFitOptions::default();
        let (rho_d, rho_s, alpha) = ([0.4, 0.3, 0.2], 0.1, 0.1);
        let mut errors: [Vec<f64>; 3] = Default::default();
        for k in 0..25 {
            let v = view(-20.0 + 2.0 * k as f64, 0.5 * k as f64);
            let fit = fit_ward(
                &TUBE,
                &v,
                &scan(&v, rho_d, rho_s, alpha, 0.01, 7 + k),
                &options,
            )
            .expect("fits");
            errors[0].push(
                (0..3)
                    .map(|c| rel(fit.rho_d[c], rho_d[c]))
                    .fold(0.0, f64::max),
            );
            errors[1].push(rel(fit.rho_s, rho_s));
            errors[2].push(rel(fit.alpha, alpha));
        }
        let median = |e: &mut Vec<f64>| {
            e.sort_by(f64::total_cmp);
            e[e.len() / 2]
        };
        let (d, s, a) = (
            median(&mut errors[0]),
            median(&mut errors[1]),
            median(&mut errors[2]),
        );
        assert!(d < 0.02 && s < 0.05 && a < 0.05, "ρd {d}, ρs {s}, α {a}");
    }

    #[test]
    fn turned_scans_that_disagree_on_alpha_are_anisotropic_unless_alpha_is_undetermined() {
        let fit = |alpha: f64, flags: Vec<WardFlag>| WardFit {
            rho_d: [0.2; 3],
            rho_s: 0.1,
            alpha,
            relative_rms: 0.01,
            samples: 121,
            flags,
        };
        let same = combine_turned_scans(&fit(0.1, vec![]), &fit(0.105, vec![]), 0.1);
        assert!(
            same.flags.is_empty() && (same.alpha - 0.1025).abs() < 1e-12,
            "{same:?}"
        );
        let brushed = combine_turned_scans(&fit(0.05, vec![]), &fit(0.2, vec![]), 0.1);
        assert_eq!(brushed.flags, vec![WardFlag::Anisotropic]);
        // A matte scan says nothing about α: no anisotropy claimed, its flag carried.
        let matte = combine_turned_scans(
            &fit(0.05, vec![]),
            &fit(0.9, vec![WardFlag::NoSpecular]),
            0.1,
        );
        assert_eq!(matte.flags, vec![WardFlag::NoSpecular]);
    }

    #[test]
    fn a_lobe_narrower_than_the_stop_spacing_is_flagged() {
        let v = view(0.0, 0.0);
        // 2 mm stops 60 mm up turn the half vector by about 0.01 rad.
        let fit = fit_ward(
            &TUBE,
            &v,
            &scan(&v, [0.2; 3], 0.05, 0.004, 0.0, 1),
            &WardFitOptions {
                alpha_range: [0.001, 1.0],
                ..WardFitOptions::default()
            },
        )
        .expect("fits");
        assert!(
            fit.flags.contains(&WardFlag::AlphaBelowStopSpacing),
            "{fit:?}"
        );
        assert!(fit.alpha.is_finite() && fit.rho_s.is_finite(), "{fit:?}");
    }

    #[test]
    fn a_specular_peak_outside_the_sweep_is_flagged() {
        // Mirror point at x ≈ 100 + 34.6 mm, beyond the last stop at 120 mm.
        let v = view(100.0, 0.0);
        let fit = fit_ward(
            &TUBE,
            &v,
            &scan(&v, [0.3; 3], 0.1, 0.05, 0.0, 1),
            &WardFitOptions::default(),
        )
        .expect("fits");
        assert!(
            fit.flags.contains(&WardFlag::SpecularPeakOutsideSweep),
            "{fit:?}"
        );
        assert!(fit.rho_d.iter().all(|r| r.is_finite()) && fit.alpha.is_finite());
    }

    #[test]
    fn black_clipped_and_broken_pixels_are_reported() {
        let v = view(0.0, 0.0);
        let black = fit_ward(
            &TUBE,
            &v,
            &scan(&v, [0.0; 3], 0.0, 0.1, 0.0, 1),
            &WardFitOptions::default(),
        )
        .expect("a black pixel is a result");
        assert_eq!(black.flags, vec![WardFlag::Black]);
        assert_eq!((black.rho_d, black.rho_s), ([0.0; 3], 0.0));
        // The specular peak clips: the shoulders still carry it.
        let mut samples = scan(&v, [0.2; 3], 0.1, 0.1, 0.0, 1);
        let peak = samples.iter().flat_map(|s| s.rgb).fold(0.0f64, f64::max);
        for s in &mut samples {
            s.saturated = s.rgb.iter().any(|v| *v > 0.8 * peak);
        }
        assert!(samples.iter().filter(|s| s.saturated).count() >= 3);
        let clipped = fit_ward(&TUBE, &v, &samples, &WardFitOptions::default()).expect("fits");
        assert_eq!(clipped.flags, vec![WardFlag::Saturated], "{clipped:?}");
        assert!(
            rel(clipped.rho_s, 0.1) < 1e-3 && rel(clipped.alpha, 0.1) < 1e-3,
            "{clipped:?}"
        );
        // Too few usable samples, or a broken one: errors that say so.
        for s in &mut samples {
            s.saturated = true;
        }
        let e = fit_ward(&TUBE, &v, &samples[..10], &WardFitOptions::default())
            .expect_err("nothing usable");
        assert!(e.to_string().contains("usable samples"), "{e}");
        let mut broken = scan(&v, [0.2; 3], 0.1, 0.1, 0.0, 1);
        broken[4].rgb[1] = f64::NAN;
        let e = fit_ward(&TUBE, &v, &broken, &WardFitOptions::default()).expect_err("NaN");
        assert!(e.to_string().contains("not finite"), "{e}");
        for alpha_range in [[0.0, 1.0], [0.5, 0.1], [0.01, f64::INFINITY]] {
            let bad = WardFitOptions {
                alpha_range,
                ..WardFitOptions::default()
            };
            let e = fit_ward(&TUBE, &v, &samples, &bad).expect_err("bad options");
            assert!(e.to_string().contains("ordered positive α range"), "{e}");
        }
    }
}
