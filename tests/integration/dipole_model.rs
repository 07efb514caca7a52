//! The dipole processing fits (`stagehand_processing::dipole`) is the one the simulator renders
//! subsurface scattering with (`stagehand_simulator::materials::dipole`): two implementations
//! of Jensen et al. 2001, written apart, agree, so a fit of simulated captures measures the
//! fit and not a difference of conventions (η, the boundary term, the source depths).

use stagehand_processing::dipole::DipoleMedium;
use stagehand_simulator::materials::dipole::Dipole;

#[test]
fn processing_and_simulator_share_one_dipole() {
    let _turn = crate::grbl_peer::alongside();
    for alpha_p in [0.01, 0.425, 0.9, 0.99] {
        for sigma_t_p in [0.05, 1.0, 10.0] {
            for eta in [1.0, 1.3, 1.5] {
                let ours = DipoleMedium {
                    alpha_p,
                    sigma_t_p,
                    eta,
                };
                let theirs = Dipole::from_reduced_albedo(alpha_p, sigma_t_p, eta);
                for r in [0.0, 0.05, 1.0, 7.0] {
                    let (a, b) = (ours.rd(r), theirs.rd(r));
                    assert!(
                        (a - b).abs() <= 1e-9 * b.max(1e-300),
                        "α′ {alpha_p}, σ′t {sigma_t_p}, η {eta}, r {r}: {a} vs {b}"
                    );
                }
            }
        }
    }
}

/// The Fresnel factors the dipole product divides by are the ones the simulator's exit lobe
/// multiplies by: F_t at every angle and c(η), written apart in each crate.
#[test]
fn processing_and_simulator_share_the_fresnel_factors() {
    let _turn = crate::grbl_peer::alongside();
    use stagehand_processing::dipole::{fresnel_transmittance, hemispherical_transmittance};
    use stagehand_simulator::materials::fresnel;
    for eta in [1.0, 1.3, 1.5, 2.0] {
        for k in 0..=100 {
            let cos = f64::from(k) / 100.0;
            let (a, b) = (
                fresnel_transmittance(cos, eta),
                fresnel::fresnel_transmittance(cos, eta),
            );
            assert!((a - b).abs() < 1e-12, "η {eta}, cos {cos}: {a} vs {b}");
        }
        let (a, b) = (
            hemispherical_transmittance(eta),
            fresnel::hemispherical_transmittance(eta, 2000),
        );
        assert!((a - b).abs() < 1e-12, "η {eta}: c {a} vs {b}");
    }
}
