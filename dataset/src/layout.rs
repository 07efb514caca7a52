//! Run directory naming and the fixed layout inside a run directory.
//!
//! ```text
//! <root>/<run_id>/
//!     manifest.json     written last by `create`: its presence marks a complete run directory
//!     plan.json         the plan's canonical JSON (the exact bytes its hash is taken over)
//!     <script file>     a copy of the capture script
//!     rig.toml          the rig description used
//!     scene.toml        the scene of the rig's sample (simulated rigs; see `Manifest::sim`)
//!     index.sqlite      runs / steps / frames index and step journal (WAL)
//!     frames/           s{step:06}_{camera}_e{i}.png (raw) and s{step:06}_{camera}_hdr.exr (HDR);
//!                       with sim.ground_truth, beside each camera's first exposure of a capture:
//!                       s{step:06}_{camera}_e0.{depth,normal,radiance,material}.exr (f32)
//!     .lock             advisory lock held by the one process writing the run
//! ```
//! `run_id` is `<script stem>-<UTC yyyymmdd-hhmmss>-<first 8 of plan hash>`, with `-2`, `-3`, …
//! appended when the name is taken.

use std::path::Path;

/// Manifest file name.
pub const MANIFEST: &str = "manifest.json";
/// Plan file name.
pub const PLAN: &str = "plan.json";
/// Rig description file name.
pub const RIG: &str = "rig.toml";
/// Scene file name (simulated rigs).
pub const SCENE: &str = "scene.toml";
/// The simulated rig as built (ground truth for evaluation only; simulated rigs with
/// `[sim.as_built]`).
pub const AS_BUILT: &str = "as_built.json";
/// SQLite index file name.
pub const INDEX: &str = "index.sqlite";
/// Frames directory name.
pub const FRAMES_DIR: &str = "frames";
/// Lock file name.
pub const LOCK: &str = ".lock";
/// Directory of the products processing writes (`products/<kind>/<file>`).
pub const PRODUCTS_DIR: &str = "products";

/// True for `frames/<file name>`: the only form of path the index records for a file (a
/// relative path with no `..`, no root and no deeper directories).
pub fn is_frame_path(rel: &str) -> bool {
    use std::path::Component;
    let mut parts = Path::new(rel).components();
    matches!(
        (parts.next(), parts.next(), parts.next()),
        (Some(Component::Normal(dir)), Some(Component::Normal(_)), None) if dir == FRAMES_DIR
    )
}

/// Names the script copy may not take, because the layout uses them.
const RESERVED: [&str; 8] = [
    MANIFEST,
    PLAN,
    RIG,
    SCENE,
    AS_BUILT,
    INDEX,
    FRAMES_DIR,
    PRODUCTS_DIR,
];

/// Replaces every character outside `[A-Za-z0-9_-]` with `_` (and maps "" to `fallback`), so
/// ids from scripts and rig files are safe in file names.
pub fn sanitize(name: &str, fallback: &str) -> String {
    let cleaned: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if cleaned.is_empty() {
        fallback.to_string()
    } else {
        cleaned
    }
}

/// The script's file stem, sanitised (`sequences/brdf scan.rhai` → `brdf_scan`).
pub fn script_stem(script_name: &str) -> String {
    let stem = Path::new(script_name)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("");
    sanitize(stem, "run")
}

/// File name of the script copy inside the run directory: the script's own file name, with
/// unsafe characters replaced, prefixed with `script-` if it would clash with the layout.
pub fn script_copy_name(script_name: &str) -> String {
    let stem = Path::new(script_name)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("");
    let ext = Path::new(script_name)
        .extension()
        .and_then(|s| s.to_str())
        .unwrap_or("rhai");
    let name = format!("{}.{}", sanitize(stem, "script"), sanitize(ext, "rhai"));
    if RESERVED.contains(&name.as_str()) {
        format!("script-{name}")
    } else {
        name
    }
}

/// The base run id (without a uniqueness suffix).
pub fn run_id(script_name: &str, created_unix_s: f64, plan_hash: &str) -> String {
    let hash8: String = plan_hash.chars().take(8).collect();
    format!(
        "{}-{}-{}",
        script_stem(script_name),
        utc_stamp(created_unix_s),
        sanitize(&hash8, "nohash")
    )
}

/// The `n`-th candidate directory name for `base` (1 → `base`, 2 → `base-2`, …).
pub fn candidate(base: &str, n: u32) -> String {
    if n <= 1 {
        base.to_string()
    } else {
        format!("{base}-{n}")
    }
}

/// `yyyymmdd-hhmmss` in UTC for a Unix time in seconds (non-finite or negative times map to
/// the epoch).
pub fn utc_stamp(unix_s: f64) -> String {
    let secs = if unix_s.is_finite() && unix_s > 0.0 {
        unix_s.floor() as i64
    } else {
        0
    };
    let days = secs.div_euclid(86_400);
    let rem = secs.rem_euclid(86_400);
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        (rem % 3600) / 60,
        rem % 60
    )
}

/// Gregorian date from days since 1970-01-01 (Howard Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_utc() {
        assert_eq!(utc_stamp(0.0), "19700101-000000");
        // 2026-11-21 13:45:07 UTC
        assert_eq!(utc_stamp(1_795_268_707.9), "20261121-134507");
        // leap day
        assert_eq!(utc_stamp(951_782_400.0), "20000229-000000");
    }

    #[test]
    fn run_ids_and_names() {
        assert_eq!(
            run_id("sequences/brdf scan.rhai", 0.0, "0123456789abcdef"),
            "brdf_scan-19700101-000000-01234567"
        );
        assert_eq!(candidate("x", 1), "x");
        assert_eq!(candidate("x", 3), "x-3");
        assert_eq!(script_copy_name("a/b/scan.rhai"), "scan.rhai");
        assert_eq!(script_copy_name("plan.json"), "script-plan.json");
        assert_eq!(sanitize("cam/5 ", "c"), "cam_5_");
        assert_eq!(sanitize("", "c"), "c");
        assert!(is_frame_path("frames/s000001_cam1_e0.png"));
        for bad in [
            "",
            "frames",
            "frames/a/b.png",
            "../frames/a.png",
            "/frames/a.png",
            "x/a.png",
        ] {
            assert!(!is_frame_path(bad), "{bad:?}");
        }
    }
}
