//! The sensor model in rendered frames: determinism per seed, saturation, exposure, dark frames.

use super::*;

#[test]
fn same_seed_is_bit_identical_and_another_seed_differs() {
    let (r, _) = lightstage("bumps");
    let w = world("bumps", &[("lamp2", 1.0)]);
    let a = r.render(&w, "cam3", 0.02, 1.0, 42).expect("render");
    let b = r.render(&w, "cam3", 0.02, 1.0, 42).expect("render");
    assert_eq!(a, b);
    let c = r.render(&w, "cam3", 0.02, 1.0, 43).expect("render");
    assert_ne!(a.pixels, c.pixels);
    assert_eq!(a.notes, c.notes, "notes do not depend on the noise seed");
    // Thread count does not matter either.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .expect("pool");
    let d = one
        .install(|| r.render(&w, "cam3", 0.02, 1.0, 42))
        .expect("render");
    let e = three
        .install(|| r.render(&w, "cam3", 0.02, 1.0, 42))
        .expect("render");
    assert_eq!(a, d);
    assert_eq!(a, e);
}

#[test]
fn saturation_clamps_at_the_bit_depth_maximum() {
    let (r, _) = lightstage("flat");
    let out = r
        .render(&world("flat", &[("lamp5", 1.0)]), "cam5", 4.0, 16.0, 7)
        .expect("render");
    let max = *out.pixels.iter().max().unwrap_or(&0);
    assert_eq!(max, 4095);
    let centre_px = out.pixels[((24 * W + 32) * 3) as usize];
    assert_eq!(centre_px, 4095, "the lit sample clips");
    let mut rig = small(BUILTIN_LIGHTSTAGE, "flat");
    rig.cameras[4].bit_depth = 8;
    let r8 = Renderer::new(&rig).expect("renderer");
    let out8 = r8
        .render(&world("flat", &[("lamp5", 1.0)]), "cam5", 4.0, 16.0, 7)
        .expect("render");
    assert_eq!(out8.pixels.iter().max(), Some(&255));
}

#[test]
fn doubling_exposure_roughly_doubles_signal() {
    let (r, _) = lightstage("flat");
    let w = world("flat", &[("lamp4", 1.0)]);
    let black = r.black_level_dn("cam4");
    let a = r.render(&w, "cam4", 0.005, 1.0, 1).expect("render");
    let b = r.render(&w, "cam4", 0.010, 1.0, 2).expect("render");
    let (sa, sb) = (
        mean_signal(&a, black, 0, centre),
        mean_signal(&b, black, 0, centre),
    );
    assert!(sa > 50.0, "signal {sa}");
    let ratio = sb / sa;
    assert!((1.9..2.15).contains(&ratio), "ratio {ratio}");
}

#[test]
fn lamp_at_zero_warm_up_gives_a_dark_frame() {
    let (r, _) = lightstage("bumps");
    let black = r.black_level_dn("cam3");
    let out = r
        .render(&world("bumps", &[("lamp3", 0.0)]), "cam3", 0.5, 1.0, 1)
        .expect("render");
    let mean = out.pixels.iter().map(|&p| p as f64).sum::<f64>() / out.pixels.len() as f64;
    assert!((mean - black).abs() < 0.5, "mean {mean} vs black {black}");
    assert!(out.pixels.iter().all(|&p| (p as f64 - black).abs() < 15.0));
    assert_eq!(out.notes["sensor"]["light_integrated"], false);
    // Warming up: half output gives about half the signal of full output.
    let half = r
        .render(&world("bumps", &[("lamp3", 0.5)]), "cam3", 0.02, 1.0, 1)
        .expect("render");
    let full = r
        .render(&world("bumps", &[("lamp3", 1.0)]), "cam3", 0.02, 1.0, 1)
        .expect("render");
    let ratio = mean_signal(&half, black, 1, centre) / mean_signal(&full, black, 1, centre);
    assert!((0.45..0.55).contains(&ratio), "ratio {ratio}");
}

#[test]
fn zero_exposure_is_black_level_plus_noise() {
    let (r, _) = lightstage("flat");
    let out = r
        .render(&world("flat", &[("lamp4", 1.0)]), "cam4", 0.0, 1.0, 1)
        .expect("render");
    let mean = out.pixels.iter().map(|&p| p as f64).sum::<f64>() / out.pixels.len() as f64;
    assert!((mean - 82.0).abs() < 0.5, "{mean}");
    assert!(out.pixels.iter().any(|&p| p != 82), "read noise is present");
}
