//! The sweep's table: `tradeoff.csv` (one row per setting, every knob) and `tradeoff.md`
//! (sorted by time, Pareto points marked, the pick for a target, the Mitsuba comparison).

use std::fmt::Write as _;
use std::path::Path;

use super::TradeoffError;
use super::equal_error::{self, Comparison};
use super::pareto::Target;
use super::sweep::{Point, Tradeoff};

/// Columns of `tradeoff.csv`.
pub const CSV_HEADER: &str = "label,knob,value,time_s,build_s,rmse,rel_rmse,max_abs,pareto,\
same_as_standard,spp_side,halogen_samples,tube_samples,bounces,bounce_rays,bounce_tolerance,\
relief_mm,shadow_maps,dipole_samples,adaptive_threshold";

/// The CSV text: a header then one row per point in sweep order.
pub fn csv(t: &Tradeoff) -> String {
    let mut out = String::from(CSV_HEADER);
    out.push('\n');
    for p in &t.points {
        let k = &p.setting.knobs;
        let _ = writeln!(
            out,
            "{},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{},{},{},{},{},{},{},{},{},{},{}",
            p.setting.label,
            p.setting.knob,
            p.setting.value,
            p.time_s,
            p.build_s,
            p.error.rmse,
            p.error.rel_rmse,
            p.error.max_abs,
            p.pareto,
            p.same_as_standard,
            k.spp_side,
            k.halogen_samples,
            k.tube_samples,
            k.bounces,
            k.bounce_rays,
            k.bounce_tolerance,
            k.relief_mm,
            k.shadow_maps,
            k.dipole_samples,
            k.adaptive_threshold
        );
    }
    out
}

/// A duration: milliseconds below one second, else seconds.
fn ms(s: f64) -> String {
    if s >= 1.0 {
        format!("{s:.2} s")
    } else {
        format!("{:.1} ms", s * 1e3)
    }
}

/// The Markdown report.
pub fn markdown(t: &Tradeoff, pick: Option<(Target, &Result<&Point, TradeoffError>)>) -> String {
    let o = &t.setup.options;
    let mut md = String::new();
    let _ = writeln!(md, "# Render accuracy vs time: `{}`\n", o.scene);
    let _ = writeln!(
        md,
        "Camera `{}` at {}×{}, lamps {} at full output, light arc {}°, turntable {}°. \
         Reference: {} ({} spp, {} halogen samples, relief {} mm, {} bounces), {} for one \
         frame; mean radiance {:.4e}. Times are the best of {} wall-clock frames on {} \
         threads, without the per-fixture sample build (`build_s` in the CSV). RMSE and max \
         are over all channel values in radiance units (white Lambert under the reference \
         lamp = 1/π); relative RMSE divides by the reference mean.\n",
        t.setup.camera,
        o.width,
        o.height,
        o.lamps.join(" + "),
        o.light_arc_deg,
        o.turntable_deg,
        t.reference_knobs.preset,
        t.reference_knobs.spp(),
        t.reference_knobs.halogen_samples,
        t.reference_knobs.relief_mm,
        t.reference_knobs.bounces,
        ms(t.reference_time_s),
        t.reference_mean,
        t.repeat,
        t.threads
    );
    let mut sorted: Vec<&Point> = t.points.iter().collect();
    sorted.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    md.push_str(
        "| | setting | time | × faster than reference | RMSE | rel. RMSE | max abs | note |\n\
         |---|---|---:|---:|---:|---:|---:|---|\n",
    );
    for p in sorted {
        let mark = if p.pareto { "★" } else { "" };
        let note = if p.same_as_standard && p.setting.knob != "preset" {
            "image identical to standard: no effect here"
        } else {
            ""
        };
        let _ = writeln!(
            md,
            "| {mark} | {} | {} | {:.0} | {:.3e} | {:.2}% | {:.3e} | {note} |",
            p.setting.label,
            ms(p.time_s),
            t.reference_time_s / p.time_s,
            p.error.rmse,
            p.error.rel_rmse * 100.0,
            p.error.max_abs
        );
    }
    md.push_str(
        "\n★ Pareto front: no other setting is both at least as fast and at least as accurate.\n",
    );
    if let Some((target, result)) = pick {
        match result {
            Ok(p) => {
                let _ = writeln!(
                    md,
                    "\n**Pick for {target}:** `{}`: {} per frame, RMSE {:.3e} ({:.2}%).",
                    p.setting.label,
                    ms(p.time_s),
                    p.error.rmse,
                    p.error.rel_rmse * 100.0
                );
            }
            Err(e) => {
                let _ = writeln!(md, "\n**Pick for {target}:** none: {e}.");
            }
        }
    }
    md
}

/// The Mitsuba section appended to the report.
pub fn mitsuba_markdown(c: &Comparison) -> String {
    let p = &c.peer;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "\n## Mitsuba {} (`{}`, path tracer, max_depth {}) at equal error\n",
        p.version, p.variant, p.max_depth
    );
    let _ = writeln!(
        md,
        "The same scene exported for Mitsuba: the height field as a triangle mesh with vertex \
         normals, albedo as a nearest-filtered float texture on a `diffuse` BSDF, the \
         turntable as a mesh, each lit lamp as a sphere emitter of the same radius and \
         intensity, the same camera pose, field of view and resolution, box pixel filter. \
         Each renderer's error is against its own converged image (Mitsuba: {} spp, {}); \
         relative RMSE is the common scale. Scene load (meshes, texture, BVH) took {} and is \
         not in the times.\n",
        p.reference_spp,
        ms(p.reference_time_s),
        ms(p.load_s)
    );
    let _ = writeln!(
        md,
        "**Agreement of the converged images:** relative RMSE {:.2}% (max abs {:.3e}), mean \
         ratio Mitsuba/stagehand {:.4}.",
        c.agreement.rel_rmse * 100.0,
        c.agreement.max_abs,
        c.mean_ratio
    );
    if let (false, Some(g)) = (c.lambert, c.ggx) {
        let _ = writeln!(
            md,
            "\n**Glossy scene:** the sample's GGX lobe (α {}, F0 {}, a dielectric of η {:.3}) \
             is exported; Mitsuba renders it as {}. Each renderer is held to its own \
             converged image for the time comparison; the agreement above says how alike the \
             two models are.",
            g.alpha,
            g.f0,
            g.eta,
            match c.peer.glossy.as_deref() {
                Some("roughplastic") =>
                    "`roughplastic` (its diffuse base under the coating, \
                     Fresnel-weighted, where stagehand's is a plain sum)",
                _ =>
                    "stagehand's sum: `diffuse` plus a GGX `roughconductor` with the \
                     dielectric's exact Fresnel (stagehand uses Schlick's)",
            }
        );
    } else if !c.lambert {
        let _ = writeln!(
            md,
            "\n**Not a Lambertian scene:** its Ward lobe (ρs up to {:.2}) is not exported \
             (Mitsuba has no Ward BSDF), so the two converged images differ by that lobe. The \
             time comparison still holds each renderer to its own converged image, but the \
             scenes are not identical; compare on matte scenes (e.g. `planes`, \
             `checkerboard`, `colorchecker`) for a like-for-like figure.",
            c.max_ks
        );
    }
    md.push_str("\n| spp | Mitsuba time | rel. RMSE |\n|---:|---:|---:|\n");
    for q in &p.points {
        let _ = writeln!(
            md,
            "| {} | {} | {:.2}% |",
            q.spp,
            ms(q.time_s),
            q.rel_rmse * 100.0
        );
    }
    md.push_str(
        "\n| stagehand (Pareto) | time | rel. RMSE | Mitsuba at that error | speed-up | how |\n\
         |---|---:|---:|---:|---:|---|\n",
    );
    for r in &c.rows {
        if r.how == equal_error::Interp::Beyond {
            let _ = writeln!(
                md,
                "| {} | {} | {:.2}% | — | — | {} |",
                r.label,
                ms(r.time_s),
                r.rel_rmse * 100.0,
                r.how.word()
            );
            continue;
        }
        let _ = writeln!(
            md,
            "| {} | {} | {:.2}% | {} | {:.1}× | {} |",
            r.label,
            ms(r.time_s),
            r.rel_rmse * 100.0,
            ms(r.peer_time_s),
            r.speedup,
            r.how.word()
        );
    }
    let _ = writeln!(
        md,
        "\nGeometric-mean speed-up over the Pareto points: {:.1}× (target ≥ 10×).",
        equal_error::geometric_mean_speedup(&c.rows)
    );
    md
}

/// Writes `tradeoff.csv`, `tradeoff.md`, the converged reference (`reference.pfm`, linear
/// float RGB) and its knobs and notes (`reference.json`) into `dir`.
pub fn write(
    dir: &Path,
    t: &Tradeoff,
    pick: Option<(Target, &Result<&Point, TradeoffError>)>,
    mitsuba: Option<&Comparison>,
) -> Result<(), TradeoffError> {
    let put = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| TradeoffError::io(&path, e))
    };
    put("tradeoff.csv", &csv(t))?;
    let reference = serde_json::json!({
        "knobs": t.reference_knobs,
        "time_s": t.reference_time_s,
        "mean": t.reference_mean,
        "notes": t.reference.notes,
    });
    super::pfm::write(
        &dir.join("reference.pfm"),
        t.reference.width,
        t.reference.height,
        &t.reference.rgb,
    )?;
    put(
        "reference.json",
        &serde_json::to_string_pretty(&reference).unwrap_or_default(),
    )?;
    let mut md = markdown(t, pick);
    if let Some(c) = mitsuba {
        md.push_str(&mitsuba_markdown(c));
    }
    put("tradeoff.md", &md)
}
