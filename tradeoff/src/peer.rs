//! The Mitsuba 3 peer's measurements, as `bench/peer/mitsuba_render.py` writes them: scene
//! load time, then per samples-per-pixel count the best render time and the error against
//! Mitsuba's own high-spp converged image.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::TradeoffError;

/// Why a peer run's JSON is not usable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PeerParseError {
    #[error("{0}")]
    Json(String),
    #[error("no measured points")]
    NoPoints,
    #[error("a point has a non-positive time or a non-finite error")]
    BadPoint,
}

/// One spp count rendered by the peer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PeerPoint {
    /// Samples per pixel.
    pub spp: u32,
    /// Best wall-clock time of `mi.render`, seconds.
    pub time_s: f64,
    /// RMSE against the peer's converged image.
    pub rmse: f64,
    /// `rmse` over the peer's converged image mean.
    pub rel_rmse: f64,
    /// Largest absolute difference.
    #[serde(default)]
    pub max_abs: f64,
}

/// Everything the peer reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PeerRun {
    /// `mitsuba`.
    pub renderer: String,
    /// Package version.
    pub version: String,
    /// Variant, e.g. `scalar_rgb`.
    pub variant: String,
    /// Integrator max_depth used.
    pub max_depth: u32,
    /// Threads Mitsuba rendered with.
    #[serde(default)]
    pub threads: u32,
    /// Time to load the scene (meshes, texture, BVH), seconds; not in `time_s`.
    pub load_s: f64,
    /// Samples per pixel of the converged image.
    pub reference_spp: u32,
    /// Time of the converged image, seconds.
    pub reference_time_s: f64,
    /// Mean channel value of the converged image.
    pub reference_mean: f64,
    /// The converged image (PFM), relative to the JSON file.
    pub reference_image: String,
    /// Timed repetitions per spp.
    #[serde(default)]
    pub repeat: u32,
    /// How a GGX sample was rendered (`sum` or `roughplastic`); none for other samples.
    #[serde(default)]
    pub glossy: Option<String>,
    /// Measured spp counts, increasing.
    pub points: Vec<PeerPoint>,
}

impl PeerRun {
    /// Reads the peer's JSON file.
    pub fn read(path: &Path) -> Result<PeerRun, TradeoffError> {
        let text = std::fs::read_to_string(path).map_err(|e| TradeoffError::Peer {
            path: path.display().to_string(),
            detail: e.to_string(),
        })?;
        PeerRun::parse(&text).map_err(|e| TradeoffError::Peer {
            path: path.display().to_string(),
            detail: e.to_string(),
        })
    }

    /// Parses and checks the JSON text.
    pub fn parse(text: &str) -> Result<PeerRun, PeerParseError> {
        let mut run: PeerRun =
            serde_json::from_str(text).map_err(|e| PeerParseError::Json(e.to_string()))?;
        if run.points.is_empty() {
            return Err(PeerParseError::NoPoints);
        }
        if run
            .points
            .iter()
            .any(|p| !(p.time_s.is_finite() && p.time_s > 0.0 && p.rel_rmse.is_finite()))
        {
            return Err(PeerParseError::BadPoint);
        }
        run.points.sort_by_key(|p| p.spp);
        Ok(run)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        let ok = r#"{"renderer":"mitsuba","version":"3.9.1","variant":"scalar_rgb","max_depth":2,
            "load_s":0.5,"reference_spp":1024,"reference_time_s":30.0,"reference_mean":0.1,
            "reference_image":"ref.pfm","points":[
              {"spp":4,"time_s":0.2,"rmse":0.01,"rel_rmse":0.1},
              {"spp":1,"time_s":0.05,"rmse":0.02,"rel_rmse":0.2}]}"#;
        let run = PeerRun::parse(ok).expect("valid");
        assert_eq!(run.points[0].spp, 1, "sorted by spp");
        assert!(PeerRun::parse("{}").is_err());
        let empty = ok.replace(
            r#"{"spp":4,"time_s":0.2,"rmse":0.01,"rel_rmse":0.1},
              {"spp":1,"time_s":0.05,"rmse":0.02,"rel_rmse":0.2}"#,
            "",
        );
        assert!(
            PeerRun::parse(&empty)
                .expect_err("empty")
                .to_string()
                .contains("no measured")
        );
    }
}
