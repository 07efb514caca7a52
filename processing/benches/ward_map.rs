//! Time of the reflectometer's per-pixel Ward fit, projected to a 1024×768 map of a full
//! 121-stop scan (issue 15's target: under 10 s on the 2-core machine). Pixels are spread over
//! a 1024×768 view of an 80 × 60 mm sample under the rig's camera (60° elevation), with a mix
//! of matte, glossy and rough materials and 1 % noise; fitted on every core as `process` does.
//!
//! Run: `cargo bench -p stagehand-processing --bench ward_map [PIXELS]`

use std::time::Instant;

use nalgebra::Vector3;
use rayon::prelude::*;
use stagehand_processing::ward_fit::{WardFitOptions, WardSample, fit_ward};
use stagehand_processing::ward_tube::{Tube, ViewPoint};

const MAP_PIXELS: f64 = 1024.0 * 768.0;

fn main() {
    let pixels: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(20_000);
    let tube = Tube {
        height_mm: 60.0,
        length_mm: 300.0,
        radius_mm: 13.0,
    };
    let camera = Vector3::new(-300.0, 0.0, 300.0 * 3f64.sqrt());
    let materials = [
        ([0.5, 0.4, 0.3], 0.0, 0.1),
        ([0.3, 0.2, 0.1], 0.08, 0.05),
        ([0.2, 0.2, 0.2], 0.2, 0.25),
    ];
    // The scans are made first (the capture's work, not the fit's).
    let side = (pixels as f64).sqrt().ceil() as usize;
    let scans: Vec<(ViewPoint, Vec<WardSample>)> = (0..pixels)
        .into_par_iter()
        .map(|i| {
            let (u, v) = (
                (i % side) as f64 / side as f64,
                (i / side) as f64 / side as f64,
            );
            let p = Vector3::new(-40.0 + 80.0 * u, -30.0 + 60.0 * v, 0.0);
            let view = ViewPoint::seen_from(p, camera).expect("above");
            let (rho_d, rho_s, alpha) = materials[i % materials.len()];
            let mut state = i as u64 * 2654435761 + 1;
            let mut noise = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.02 * 3f64.sqrt()
            };
            let samples = (0..121)
                .map(|k| {
                    let x = -120.0 + 2.0 * k as f64;
                    let d = tube.diffuse(&view, x) / std::f64::consts::PI;
                    let s = tube.specular(&view, x, alpha);
                    WardSample {
                        tube_x_mm: x,
                        rgb: rho_d.map(|r: f64| (r * d + rho_s * s) * (1.0 + noise())),
                        saturated: false,
                    }
                })
                .collect();
            (view, samples)
        })
        .collect();
    let options = WardFitOptions::default();
    let started = Instant::now();
    let fits: Vec<_> = scans
        .par_iter()
        .map(|(view, samples)| fit_ward(&tube, view, samples, &options))
        .collect();
    let seconds = started.elapsed().as_secs_f64();
    let failed = fits.iter().filter(|f| f.is_err()).count();
    let per_pixel_us = seconds / pixels as f64 * 1e6;
    println!(
        "ward_map: {pixels} pixels × 121 stops fitted in {seconds:.2} s on {} threads: {per_pixel_us:.1} µs per pixel, {:.1} s projected for a 1024×768 map (target 10 s); {failed} errors",
        rayon::current_num_threads(),
        per_pixel_us * MAP_PIXELS / 1e6
    );
    // What the time buys: the glossy pixels' errors (1 % noise on every sample).
    let (mut rho_d, mut rho_s, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    for (i, fit) in fits.iter().enumerate() {
        let (d, s, a) = materials[i % materials.len()];
        let Ok(fit) = fit else { continue };
        rho_d.push((fit.rho_d[0] / d[0] - 1.0).abs());
        if s > 0.0 {
            rho_s.push((fit.rho_s / s - 1.0).abs());
            alpha.push((fit.alpha / a - 1.0).abs());
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN) * 100.0
    };
    println!(
        "ward_map: median relative error ρd {:.3} %, ρs {:.3} %, α {:.3} % (glossy pixels)",
        median(rho_d),
        median(rho_s),
        median(alpha)
    );
}
