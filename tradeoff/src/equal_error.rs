//! Time at equal error: for a stagehand setting with relative RMSE r, how long the peer
//! takes to reach the same r, interpolated log-log between its measured spp counts.
//!
//! Relative RMSE (each renderer against its own converged image, over that image's mean) is
//! the common scale. Beyond the peer's most converged point the Monte Carlo law (error ∝
//! spp^−½, so time ∝ r^−2) extrapolates; an error the peer beats already at its fewest
//! samples gets that point's time (it cannot render less than one sample per pixel). An error
//! more than [`MAX_EXTRAPOLATION`]× below the peer's most converged one is not compared: the
//! law would be carried too far (and a setting that reproduces the reference exactly, error
//! 0, would get an unbounded speed-up).

/// How far below the peer's most converged error the r^−2 law extrapolates.
pub const MAX_EXTRAPOLATION: f64 = 4.0;

use serde::Serialize;

use super::peer::PeerPoint;
use super::sweep::Point;

/// How the peer's time at an error was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Interp {
    /// Between two measured points.
    Interpolated,
    /// More converged than any measured point: extrapolated with time ∝ r^−2.
    Extrapolated,
    /// The peer's fewest-sample point already has a lower error; its time is used.
    AtFewest,
    /// More than [`MAX_EXTRAPOLATION`]× below the peer's most converged error: not compared
    /// (the peer's time is NaN and the row stays out of the geometric mean).
    Beyond,
}

impl Interp {
    /// A short word for tables.
    pub fn word(self) -> &'static str {
        match self {
            Interp::Interpolated => "interpolated",
            Interp::Extrapolated => "extrapolated (time ∝ error⁻²)",
            Interp::AtFewest => "peer's fewest spp already better",
            Interp::Beyond => "not compared: error beyond the peer's measured range",
        }
    }
}

/// The peer's time (seconds) to reach relative RMSE `rel`, or `None` if no peer point is
/// usable or `rel` is not finite; NaN with [`Interp::Beyond`] when `rel` is 0 or too far below
/// the peer's measured range.
pub fn time_at(points: &[PeerPoint], rel: f64) -> Option<(f64, Interp)> {
    if !(rel.is_finite() && rel >= 0.0) {
        return None;
    }
    let mut pts: Vec<&PeerPoint> = points
        .iter()
        .filter(|p| p.time_s > 0.0 && p.rel_rmse > 0.0 && p.rel_rmse.is_finite())
        .collect();
    // From least to most converged.
    pts.sort_by(|a, b| b.rel_rmse.total_cmp(&a.rel_rmse));
    let first = *pts.first()?;
    let last = *pts.last()?;
    if rel >= first.rel_rmse {
        return Some((first.time_s, Interp::AtFewest));
    }
    if rel * MAX_EXTRAPOLATION < last.rel_rmse {
        return Some((f64::NAN, Interp::Beyond));
    }
    if rel < last.rel_rmse {
        let t = last.time_s * (last.rel_rmse / rel).powi(2);
        return Some((t, Interp::Extrapolated));
    }
    for w in pts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if rel <= a.rel_rmse && rel >= b.rel_rmse {
            let span = (b.rel_rmse.ln() - a.rel_rmse.ln()).abs();
            let f = if span > 0.0 {
                (a.rel_rmse.ln() - rel.ln()) / span
            } else {
                0.0
            };
            let t = (a.time_s.ln() + f * (b.time_s.ln() - a.time_s.ln())).exp();
            return Some((t, Interp::Interpolated));
        }
    }
    Some((last.time_s, Interp::Interpolated))
}

/// One row of the equal-error comparison.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Row {
    /// The stagehand setting.
    pub label: String,
    /// Its time, seconds.
    pub time_s: f64,
    /// Its relative RMSE.
    pub rel_rmse: f64,
    /// The peer's time at that relative RMSE, seconds.
    pub peer_time_s: f64,
    /// How that time was found.
    pub how: Interp,
    /// peer time / stagehand time.
    pub speedup: f64,
}

/// The comparison for each of `front` (stagehand's Pareto points).
pub fn compare(front: &[&Point], peer: &[PeerPoint]) -> Vec<Row> {
    front
        .iter()
        .filter_map(|p| {
            let (peer_time_s, how) = time_at(peer, p.error.rel_rmse)?;
            Some(Row {
                label: p.setting.label.clone(),
                time_s: p.time_s,
                rel_rmse: p.error.rel_rmse,
                peer_time_s,
                how,
                speedup: peer_time_s / p.time_s,
            })
        })
        .collect()
}

/// Geometric mean of the speed-ups of the compared rows (1 for none).
pub fn geometric_mean_speedup(rows: &[Row]) -> f64 {
    let logs: Vec<f64> = rows
        .iter()
        .filter(|r| r.how != Interp::Beyond && r.speedup.is_finite() && r.speedup > 0.0)
        .map(|r| r.speedup.ln())
        .collect();
    if logs.is_empty() {
        return 1.0;
    }
    (logs.iter().sum::<f64>() / logs.len() as f64).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(spp: u32, time_s: f64, rel_rmse: f64) -> PeerPoint {
        PeerPoint {
            spp,
            time_s,
            rmse: rel_rmse,
            rel_rmse,
            max_abs: 0.0,
        }
    }

    #[test]
    fn log_log_interpolation_and_ends() {
        // Ideal Monte Carlo: rel = 0.4 / sqrt(spp), time = 0.01 × spp.
        let pts: Vec<PeerPoint> = [1u32, 4, 16, 64]
            .map(|s| p(s, 0.01 * s as f64, 0.4 / (s as f64).sqrt()))
            .to_vec();
        // rel 0.1 ↔ 16 spp exactly; 0.141 ↔ 8 spp between 4 and 16.
        let (t, how) = time_at(&pts, 0.1).expect("inside");
        assert!(
            (t - 0.16).abs() < 1e-9 && how == Interp::Interpolated,
            "{t}"
        );
        let (t, _) = time_at(&pts, 0.4 / 8f64.sqrt()).expect("inside");
        assert!((t - 0.08).abs() < 1e-9, "{t}");
        // Below the most converged point: extrapolated on the same law (256 spp).
        let (t, how) = time_at(&pts, 0.025).expect("beyond");
        assert!(
            (t - 2.56).abs() < 1e-9 && how == Interp::Extrapolated,
            "{t}"
        );
        // Worse than 1 spp: the 1-spp time.
        assert_eq!(time_at(&pts, 0.9), Some((0.01, Interp::AtFewest)));
        // Zero error (the reference itself) and errors far below the range: not compared.
        for rel in [0.0, 0.05 / MAX_EXTRAPOLATION - 1e-6] {
            let (t, how) = time_at(&pts, rel).expect("beyond");
            assert!(t.is_nan() && how == Interp::Beyond, "{rel}: {t}");
        }
        assert_eq!(time_at(&pts, f64::NAN), None);
        assert_eq!(time_at(&[], 0.1), None);
        let row = |speedup, how| Row {
            label: String::new(),
            time_s: 1.0,
            rel_rmse: 0.1,
            peer_time_s: speedup,
            how,
            speedup,
        };
        let rows = [
            row(4.0, Interp::Interpolated),
            row(16.0, Interp::Extrapolated),
            row(f64::NAN, Interp::Beyond),
        ];
        assert!((geometric_mean_speedup(&rows) - 8.0).abs() < 1e-9);
    }
}

/// The whole Mitsuba comparison for the report.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// What the peer measured.
    pub peer: super::peer::PeerRun,
    /// Equal-error rows for stagehand's Pareto points.
    pub rows: Vec<Row>,
    /// The peer's converged image against stagehand's converged reference (relative RMSE
    /// over stagehand's mean): how well the two renderers agree on the scene.
    pub agreement: super::metrics::ErrorMetrics,
    /// Mean of the peer's converged image over stagehand's (radiometric scale check).
    pub mean_ratio: f64,
    /// The exported scene is purely Lambertian (the only case the comparison is exact for).
    pub lambert: bool,
    /// Largest Ward ρs on the sample (dropped from the export when > 0).
    pub max_ks: f32,
    /// The sample's GGX lobe when exported as Mitsuba's `roughplastic`.
    pub ggx: Option<super::mitsuba::GgxLobe>,
}
