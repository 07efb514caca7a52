use glam::Vec3A;
use stagehand_devices::rig::{BUILTIN_LIGHTSTAGE, parse_rig};
use stagehand_simulator::render::{geometry::{CameraPose, ToSample, spherical}, sample::Sample};
fn cpu_ns() -> u64 { std::fs::read_to_string("/proc/thread-self/schedstat").unwrap().split_whitespace().next().unwrap().parse().unwrap() }
fn main() {
    let rig = parse_rig(BUILTIN_LIGHTSTAGE, "x").unwrap();
    let s = Sample::build("bumps", 80.0, 0.2).unwrap();
    let g = s.grid.as_ref().unwrap();
    let lamp = spherical(0.0, 40.0, 800.0);
    for cam in ["cam1", "cam5", "cam8"] {
        let pose = CameraPose::new(rig.camera(cam).unwrap(), ToSample::new(0.0));
        let mut hits = Vec::new();
        let c0 = cpu_ns();
        let mut n = 0u64;
        for y in 0..768 { for x in 0..1024 {
            let d = pose.ray(x as f32 + 0.5, y as f32 + 0.5);
            n += 1;
            if let Some(h) = g.first_hit(pose.origin, d, 0.0, f32::INFINITY) { hits.push(pose.origin + d * h.t); }
        }}
        let c1 = cpu_ns();
        let mut occ = 0;
        for p in &hits {
            let n = g.normal_at(p.x, p.y);
            let v = lamp - *p; let r = v.length();
            if g.occluded(*p + n * 0.02, v / r, 0.0, r) { occ += 1; }
        }
        let c2 = cpu_ns();
        let mut nsum = Vec3A::ZERO;
        for p in &hits { nsum += g.normal_at(p.x, p.y) + s.material_at(p.x, p.y).albedo; }
        let c3 = cpu_ns();
        println!("{cam}: primary {:.0} ns/ray ({} hits of {n}), shadow {:.0} ns/ray ({occ} blocked), normal+material {:.0} ns {nsum}",
            (c1 - c0) as f64 / n as f64, hits.len(), (c2 - c1) as f64 / hits.len() as f64, (c3 - c2) as f64 / hits.len() as f64);
    }
}
