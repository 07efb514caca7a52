use std::collections::BTreeMap;
use std::time::Instant;
use stagehand_devices::rig::{BUILTIN_REFLECTOMETER, parse_rig};
use stagehand_simulator::render::Renderer;
use stagehand_simulator::world_state::WorldSnapshot;
fn main() {
    let rig = parse_rig(BUILTIN_REFLECTOMETER, "x").unwrap();
    let r = Renderer::new(&rig).unwrap();
    for cart in [100.0, 110.0, 120.0, 130.0] {
        let w = WorldSnapshot { rig_time_s: 0.0, axes: BTreeMap::new(), lamps: [("tube".to_string(), 1.0)].into(), laser: None, cart_mm: cart, fixture: "weave".into() };
        let t = Instant::now();
        let o = r.render(&w, "cam1", 0.02, 1.0, 0).unwrap();
        println!("cart {cart}: {:.0} ms {}", t.elapsed().as_secs_f64() * 1e3, o.notes["stats"]);
    }
}
