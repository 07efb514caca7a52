//! The Ward lobe the reflectometer fit uses (`stagehand_processing::ward`) is the one the
//! simulator renders with (`stagehand_simulator::materials::ward`): two implementations of
//! Ward 1992, written apart, agree over the hemisphere, at grazing angles and for tiny and
//! huge α, so a fit of simulated reflectometer scans measures the fit, not a convention.

use glam::DVec3;
use nalgebra::Vector3;
use stagehand_processing::ward::ward_iso as ours;
use stagehand_simulator::materials::ward::ward_iso as theirs;

fn dir(theta: f64, phi: f64) -> (Vector3<f64>, DVec3) {
    let v = (
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    );
    (Vector3::new(v.0, v.1, v.2), DVec3::new(v.0, v.1, v.2))
}

#[test]
fn processing_and_simulator_share_one_ward_lobe() {
    let thetas = [0.0, 0.3, 0.9, 1.4, std::f64::consts::FRAC_PI_2 - 1e-4, 2.0];
    let (n, dn) = dir(0.0, 0.0);
    let mut compared = 0;
    for alpha in [1e-3, 0.01, 0.1, 0.5, 2.0] {
        for (i, ti) in thetas.iter().enumerate() {
            for to in &thetas[i..] {
                for phi in [0.0, 1.0, std::f64::consts::PI] {
                    let ((wi, dwi), (wo, dwo)) = (dir(*ti, 0.0), dir(*to, phi));
                    let (a, b) = (ours(&n, &wi, &wo, alpha), theirs(dn, dwi, dwo, alpha));
                    assert!(
                        (a - b).abs() <= 1e-12 * b.max(1e-300),
                        "α {alpha}, θi {ti}, θo {to}, φ {phi}: {a} vs {b}"
                    );
                    compared += usize::from(b > 0.0);
                }
            }
        }
    }
    assert!(compared > 100, "{compared} non-zero comparisons");
}
