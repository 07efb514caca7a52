//! The command line of `stagehand-tradeoff` (also reached as `stagehand sim tradeoff`, which
//! runs this program): measures what render accuracy costs in time (see the crate docs) and
//! optionally times Mitsuba 3 on the same scene.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use clap::Parser;

use crate::equal_error::{self, Comparison};
use crate::peer::PeerRun;
use crate::{
    Setup, SetupOptions, SweepConfig, Target, Tradeoff, TradeoffError, metrics, mitsuba, pfm, plot,
    report, sweep,
};

/// The Mitsuba peer script, written next to the exported scene so no checkout is needed.
const MITSUBA_SCRIPT: &str = include_str!("../../bench/peer/mitsuba_render.py");
/// The Mitsuba version `bench/peer/requirements.txt` pins.
const MITSUBA_PIN: &str = "mitsuba==3.9.1";

/// Measure render accuracy against time: sweep every accuracy knob, write a table and plots
/// of RMSE vs frame time with the Pareto front (optionally against Mitsuba 3).
#[derive(Parser, Debug)]
#[command(name = "stagehand sim tradeoff", version)]
pub struct TradeoffArgs {
    /// Scene (fixture) name the renderer accepts: bumps, weave, steps, flat, planes, …
    #[arg(default_value = "bumps")]
    scene: String,
    /// Output directory [default: target/tradeoff/SCENE].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Camera width in pixels (the field of view is kept).
    #[arg(long, default_value_t = 256)]
    width: u32,
    /// Camera height in pixels.
    #[arg(long, default_value_t = 192)]
    height: u32,
    /// Camera of the light stage that renders.
    #[arg(long, default_value = "cam4")]
    camera: String,
    /// Error target for the pick: an RMSE (e.g. 0.002) or a percentage of the reference
    /// mean (e.g. 1%).
    #[arg(long, value_name = "X")]
    target_rmse: Option<String>,
    /// Timed frames per setting (the best is kept).
    #[arg(long, default_value_t = 3)]
    repeat: u32,
    /// Also render the scene with Mitsuba 3 (bench/peer/mitsuba_render.py) and compare
    /// time at equal error.
    #[arg(long)]
    mitsuba: bool,
    /// Mitsuba's samples-per-pixel sweep, comma-separated.
    #[arg(long, default_value = "1,2,4,8,16,32,64,128,256", value_name = "LIST")]
    mitsuba_spp: String,
    /// Samples per pixel of Mitsuba's converged image.
    #[arg(long, default_value_t = 1024, value_name = "N")]
    mitsuba_reference_spp: u32,
    /// How Mitsuba renders a GGX sample: `sum` (stagehand's model: Lambert plus the GGX
    /// lobe) or `roughplastic` (Mitsuba's rough plastic, its diffuse base under the coating).
    #[arg(long, default_value = "sum", value_parser = ["sum", "roughplastic"])]
    mitsuba_glossy: String,
    /// Light the scene with the rig's line laser in this colour (nm, untilted) instead of
    /// the lamps: the laser-line comparison.
    #[arg(long, value_name = "NM")]
    laser: Option<u32>,
}

/// Runs the sweep `args` asks for; returns the exit code (0 done, 1 failed, 2 bad input).
pub fn run(args: &TradeoffArgs) -> i32 {
    match tradeoff_cmd(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            if e.is_bad_input() { 2 } else { 1 }
        }
    }
}

fn tradeoff_cmd(args: &TradeoffArgs) -> Result<i32, TradeoffError> {
    let target = args.target_rmse.as_deref().map(Target::parse).transpose()?;
    if !(1..=1000).contains(&args.repeat) {
        return Err(TradeoffError::InvalidInput {
            what: "--repeat".into(),
            expected: "a count from 1 to 1000".into(),
            got: args.repeat.to_string(),
        });
    }
    let spp_list = parse_spp(&args.mitsuba_spp)?;
    let setup = Setup::new(SetupOptions {
        scene: args.scene.clone(),
        camera: args.camera.clone(),
        width: args.width,
        height: args.height,
        lamps: match args.laser {
            Some(_) => Vec::new(),
            None => SetupOptions::default().lamps,
        },
        laser_nm: args.laser,
        ..SetupOptions::default()
    })?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("target/tradeoff").join(&args.scene));
    std::fs::create_dir_all(&out).map_err(|e| TradeoffError::InvalidInput {
        what: "--out".into(),
        expected: "a directory that can be created".into(),
        got: format!("{}: {e}", out.display()),
    })?;
    eprintln!(
        "tradeoff: `{}` on {} at {}×{}, {}, best of {} on {} threads",
        args.scene,
        args.camera,
        args.width,
        args.height,
        match args.laser {
            Some(nm) => format!("line laser {nm} nm"),
            None => format!("lamps {}", setup.options.lamps.join(" + ")),
        },
        args.repeat,
        rayon::current_num_threads()
    );
    let config = SweepConfig::new(args.repeat);
    let t = sweep::run(&setup, &config, &mut |line| eprintln!("  {line}"))?;
    let pick = target.map(|tg| (tg, t.pick(tg)));
    let mut code = 0;
    let comparison = if args.mitsuba {
        match run_mitsuba(args, &t, &spp_list, &out) {
            Ok(c) => Some(c),
            Err(e) => {
                eprintln!("error: Mitsuba comparison: {e}");
                code = 1;
                None
            }
        }
    } else {
        None
    };
    report::write(
        &out,
        &t,
        pick.as_ref().map(|(tg, r)| (*tg, r)),
        comparison.as_ref(),
    )?;
    plot::write(
        &out,
        &t,
        comparison.as_ref().map(|c| c.peer.points.as_slice()),
    )?;
    print_summary(&t, &out, comparison.as_ref());
    if let Some((tg, result)) = &pick {
        match result {
            Ok(p) => println!(
                "pick for {tg}: {} ({:.2} ms, RMSE {:.3e}, {:.2}%)",
                p.setting.label,
                p.time_s * 1e3,
                p.error.rmse,
                p.error.rel_rmse * 100.0
            ),
            Err(e) => {
                eprintln!("error: {e}");
                code = 1;
            }
        }
    }
    Ok(code)
}

/// Parses the Mitsuba spp list (positive integers).
fn parse_spp(text: &str) -> Result<Vec<u32>, TradeoffError> {
    let bad = || TradeoffError::InvalidInput {
        what: "--mitsuba-spp".into(),
        expected: "comma-separated positive integers such as 1,4,16".into(),
        got: format!("`{text}`"),
    };
    let v: Vec<u32> = text
        .split(',')
        .map(|s| s.trim().parse::<u32>().map_err(|_| bad()))
        .collect::<Result<_, _>>()?;
    if v.is_empty() || v.contains(&0) {
        return Err(bad());
    }
    Ok(v)
}

fn print_summary(t: &Tradeoff, out: &Path, c: Option<&Comparison>) {
    println!(
        "reference ({} spp, {} halogen samples): {:.2} s",
        t.reference_knobs.spp(),
        t.reference_knobs.halogen_samples,
        t.reference_time_s
    );
    println!(
        "{:<24} {:>10} {:>11} {:>9}  pareto",
        "setting", "time", "RMSE", "rel"
    );
    let mut pts: Vec<_> = t.points.iter().collect();
    pts.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    for p in pts {
        println!(
            "{:<24} {:>7.2} ms {:>11.3e} {:>8.2}%  {}",
            p.setting.label,
            p.time_s * 1e3,
            p.error.rmse,
            p.error.rel_rmse * 100.0,
            if p.pareto { "*" } else { "" }
        );
    }
    if let Some(c) = c {
        println!(
            "Mitsuba {} agreement of converged images: relative RMSE {:.2}%, mean ratio {:.4}{}",
            c.peer.version,
            c.agreement.rel_rmse * 100.0,
            c.mean_ratio,
            match (c.lambert, c.ggx) {
                (true, _) => "",
                (false, Some(_)) => " (GGX lobe exported)",
                (false, None) => " (scene not Lambertian: its specular lobe is not exported)",
            }
        );
        for r in &c.rows {
            if r.how == equal_error::Interp::Beyond {
                println!(
                    "  {:<22} {:>8.2} ms at {:.2}%: {}",
                    r.label,
                    r.time_s * 1e3,
                    r.rel_rmse * 100.0,
                    r.how.word()
                );
                continue;
            }
            println!(
                "  {:<22} {:>8.2} ms at {:.2}%: Mitsuba {:>9.2} ms → {:.1}× ({})",
                r.label,
                r.time_s * 1e3,
                r.rel_rmse * 100.0,
                r.peer_time_s * 1e3,
                r.speedup,
                r.how.word()
            );
        }
        println!(
            "  geometric-mean speed-up at equal error: {:.1}×",
            equal_error::geometric_mean_speedup(&c.rows)
        );
    }
    println!(
        "wrote {0}/tradeoff.csv, tradeoff.md, tradeoff.png, tradeoff.svg",
        out.display()
    );
}

/// A Python that can `import mitsuba`: $STAGEHAND_MITSUBA_PYTHON, the bench venv
/// ($STAGEHAND_BENCH_VENV, ./target/bench-venv or the source tree's), then python3.
fn find_python() -> Result<PathBuf, TradeoffError> {
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Some(p) = std::env::var_os("STAGEHAND_MITSUBA_PYTHON") {
        candidates.push(PathBuf::from(p));
    }
    if let Some(v) = std::env::var_os("STAGEHAND_BENCH_VENV") {
        candidates.push(PathBuf::from(v).join("bin/python"));
    }
    candidates.push(PathBuf::from("target/bench-venv/bin/python"));
    candidates.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench-venv/bin/python"));
    candidates.push(PathBuf::from("python3"));
    for py in &candidates {
        let ok = Process::new(py)
            .args(["-c", "import mitsuba"])
            .output()
            .is_ok_and(|o| o.status.success());
        if ok {
            return Ok(py.clone());
        }
    }
    Err(TradeoffError::Export(format!(
        "no Python with Mitsuba 3 found (tried {}). Install it with `bench/peer/run.sh \
         --install` (a venv at target/bench-venv from bench/peer/requirements.txt), or \
         `pip install {MITSUBA_PIN}`, or point STAGEHAND_MITSUBA_PYTHON at a Python that has it",
        candidates
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )))
}

/// Exports the scene, runs the Mitsuba peer and compares.
fn run_mitsuba(
    args: &TradeoffArgs,
    t: &Tradeoff,
    spp: &[u32],
    out: &Path,
) -> Result<Comparison, TradeoffError> {
    let python = find_python()?;
    let dir = out.join("mitsuba");
    // Interreflection, when the renderer models it, is followed for `bounces` bounces.
    let indirect = t.reference_notes()["effects"]["interreflection"]["on"]
        .as_bool()
        .unwrap_or(false);
    let max_depth = if indirect {
        t.reference_knobs.bounces + 2
    } else {
        2
    };
    let export = mitsuba::export(
        &t.setup,
        t.reference_knobs.relief_mm,
        t.reference_knobs.halogen_samples > 1,
        max_depth,
        &dir,
    )?;
    eprintln!(
        "mitsuba: exported {} ({} vertices, {} triangles, {}² albedo texels{}), running {}",
        export.scene_json.display(),
        export.vertices,
        export.faces,
        export.texels,
        match (export.lambert, export.ggx) {
            (true, _) => String::new(),
            (false, Some(g)) =>
                format!("; GGX lobe as roughplastic (α {}, η {:.3})", g.alpha, g.eta),
            (false, None) => "; NOT Lambertian: the specular lobe is dropped".into(),
        },
        python.display()
    );
    let script = dir.join("mitsuba_render.py");
    std::fs::write(&script, MITSUBA_SCRIPT).map_err(|e| TradeoffError::io(&script, e))?;
    let json = dir.join("mitsuba.json");
    let spp_arg = spp.iter().map(u32::to_string).collect::<Vec<_>>().join(",");
    let status = Process::new(&python)
        .arg(&script)
        .arg(&export.scene_json)
        .arg(&json)
        .args(["--spp", &spp_arg])
        .args(["--reference-spp", &args.mitsuba_reference_spp.to_string()])
        .args(["--repeat", &args.repeat.to_string()])
        .args(["--glossy", &args.mitsuba_glossy])
        .status()
        .map_err(|e| TradeoffError::io(&python, e))?;
    if !status.success() {
        return Err(TradeoffError::Peer {
            path: script.display().to_string(),
            detail: format!("exited with {status}"),
        });
    }
    let peer = PeerRun::read(&json)?;
    let (w, h, theirs) = pfm::read(&dir.join(&peer.reference_image))?;
    if (w, h) != (t.reference.width, t.reference.height) {
        return Err(TradeoffError::Peer {
            path: peer.reference_image.clone(),
            detail: format!(
                "image is {w}×{h}, expected {}×{}",
                t.reference.width, t.reference.height
            ),
        });
    }
    let agreement = metrics::compare(&t.reference.rgb, &theirs)?;
    let mean_ratio = metrics::mean(&theirs) / t.reference_mean;
    let rows = equal_error::compare(&t.front(), &peer.points);
    Ok(Comparison {
        peer,
        rows,
        agreement,
        mean_ratio,
        lambert: export.lambert,
        max_ks: export.max_ks,
        ggx: export.ggx,
    })
}
