//! Processing's nominal laser sheet (`processing/src/laser_sheet.rs`, from the rig file) against
//! the sheet the simulator renders (`simulator/src/render/laser.rs`): the same plane for every
//! mount, light-arc angle, tilt and turntable angle, so depth triangulated through the one
//! agrees with frames rendered by the other.

use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};
use stagehand_processing::laser_sheet::{LaserMount, nominal_sheet};
use stagehand_simulator::render::geometry::ToSample;
use stagehand_simulator::render::laser::LaserSheet;
use stagehand_simulator::world_snapshot::LaserBeam;

#[test]
fn the_nominal_sheet_is_the_plane_the_simulator_renders() {
    let _turn = crate::grbl_peer::alongside();
    let rig = parse_rig(BUILTIN_LIGHTSTAGE, "lightstage.toml").expect("built-in rig");
    let spec = rig.laser.as_ref().expect("the light stage has a laser");
    let mut checked = 0;
    for elevation in [20.0, 45.0, 80.0] {
        for arc in [0.0, 37.5, 200.0] {
            for tilt in [-4.0, 0.0, 2.5] {
                for table in [0.0, 30.0, 270.0] {
                    let beam = LaserBeam {
                        colour_nm: spec.fitted_nm,
                        tilt_deg: tilt,
                        mount_elevation_deg: elevation,
                    };
                    let sim = LaserSheet::new(spec, &beam, arc, ToSample::new(table));
                    let mount = LaserMount {
                        elevation_deg: elevation,
                        distance_mm: spec.distance_mm,
                    };
                    let ours = nominal_sheet(&mount, arc, tilt, table).expect("a sheet");
                    let n = [sim.normal.x, sim.normal.y, sim.normal.z].map(f64::from);
                    let d = n[0] * f64::from(sim.origin.x)
                        + n[1] * f64::from(sim.origin.y)
                        + n[2] * f64::from(sim.origin.z);
                    // Same plane: normals equal up to sign, offsets to match.
                    let dot: f64 = (0..3).map(|i| n[i] * ours.normal[i]).sum();
                    assert!(
                        dot.abs() > 1.0 - 1e-6,
                        "{elevation} {arc} {tilt} {table}: {dot}"
                    );
                    assert!(
                        (d * dot.signum() - ours.d).abs() < 0.01,
                        "{elevation} {arc} {tilt} {table}: {d} vs {}",
                        ours.d
                    );
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, 81);
}
