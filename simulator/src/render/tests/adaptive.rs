//! Adaptive sampling: one sample per pixel, the full count where neighbours differ.

use super::*;

/// Renders `fixture` on cam4 under lamps 2 and 5 with `spp_side` and `adaptive_threshold`.
fn planes_frame(spp_side: u32, threshold: f32) -> RadianceImage {
    let mut rig = small(BUILTIN_LIGHTSTAGE, "planes");
    SimSpec::edit(&mut rig, |s| {
        s.knobs.spp_side = Some(spp_side);
        s.knobs.adaptive_threshold = Some(threshold);
    })
    .expect("sim");
    let r = Renderer::new(&rig).expect("renderer");
    r.radiance(&world("planes", &[("lamp2", 1.0), ("lamp5", 1.0)]), "cam4")
        .expect("render")
}

fn rmse(a: &RadianceImage, b: &RadianceImage) -> f64 {
    let n = a.rgb.len() as f64;
    (a.rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

/// On the `planes` step (sample outline, step edge, shadow edges) adaptive sampling refines a
/// minority of pixels, and those are bit for bit the full-count pixels; the frame is far
/// closer to the full-count frame than one sample per pixel is, the same on every run, and the
/// notes count the refined pixels.
#[test]
fn adaptive_sampling_refines_edges_to_the_full_count() {
    let full = planes_frame(4, 0.0);
    let once = planes_frame(1, 0.0);
    let adaptive = planes_frame(4, 0.02);
    assert!(full.notes["stats"]["adaptive_refined_pixels"].is_null());
    let refined = adaptive.notes["stats"]["adaptive_refined_pixels"]
        .as_u64()
        .expect("refined count") as usize;
    let pixels = (W * H) as usize;
    assert!(refined > 0 && refined < pixels / 2, "{refined} of {pixels}");
    let same = adaptive
        .rgb
        .chunks_exact(3)
        .zip(full.rgb.chunks_exact(3))
        .filter(|(a, f)| a == f)
        .count();
    assert!(
        same >= refined,
        "{same} pixels equal the full count, {refined} refined"
    );
    let (near, far) = (rmse(&adaptive, &full), rmse(&once, &full));
    assert!(near < 0.25 * far, "adaptive {near} vs one sample {far}");
    assert!(adaptive.rgb.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert_eq!(planes_frame(4, 0.02).rgb, adaptive.rgb);
}

/// The mask marks both pixels on either side of a step above the threshold (relative to the
/// image mean) and nothing in a uniform image or below it.
#[test]
fn contrast_mask_marks_both_sides_of_an_edge() {
    // 4×2 image: left half 1.0, right half 3.0 (mean 2.0).
    let img: Vec<f32> = [1.0, 1.0, 3.0, 3.0, 1.0, 1.0, 3.0, 3.0]
        .iter()
        .flat_map(|&v| [v, v, v])
        .collect();
    let mask = contrast_mask(&img, 4, 2, 0.5);
    assert_eq!(
        mask,
        [false, true, true, false, false, true, true, false].to_vec()
    );
    assert!(contrast_mask(&img, 4, 2, 1.0).iter().all(|m| !m));
    assert!(contrast_mask(&[0.5; 12], 2, 2, 0.01).iter().all(|m| !m));
}
