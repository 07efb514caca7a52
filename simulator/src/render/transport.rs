//! The light-transport passes a frame's plan turns on (interreflection, subsurface), run once
//! per rig step and shared by its cameras, with the per-sample results they rest on: relief
//! statistics, the light probe's answers and the bounce passes' light-independent geometry.

use std::sync::Arc;

use serde_json::{Value, json};

use super::bounce;
use super::bounce_geometry::{BounceGeometry, geometry_bytes, texels_per_side};
use super::effects;
use super::irradiance;
use super::kept::Kept;
use super::laser::LaserSheet;
use super::lights;
use super::pass_cache::PassCache;
use super::quality::Knobs;
use super::relief_key;
use super::sample::Sample;
use super::subsurface;

/// Memory the bounce passes' geometry may hold (a fixture's is 1 MB at preview, 12 MB at
/// standard; the reference preset's, 70 MB, is traced with each pass instead).
const BOUNCE_GEOMETRY_BUDGET_BYTES: usize = 128 << 20;

/// Per-frame light-transport results shared by the cameras of one rig step (same sample,
/// same lights), per-sample relief statistics, and the bounce passes' light-independent
/// geometry per sample.
#[derive(Debug)]
pub(super) struct TransportCaches {
    pub(super) relief: PassCache<Option<bounce::ReliefStats>>,
    bounce_geometry: Kept<String, BounceGeometry>,
    bounce: PassCache<Option<bounce::BounceMap>>,
    pub(super) probe: PassCache<Option<f32>>,
    subsurface: PassCache<Option<subsurface::SubsurfaceMap>>,
}

impl Default for TransportCaches {
    fn default() -> Self {
        TransportCaches {
            relief: Default::default(),
            bounce_geometry: Kept::with_budget(BOUNCE_GEOMETRY_BUDGET_BYTES),
            bounce: Default::default(),
            probe: Default::default(),
            subsurface: Default::default(),
        }
    }
}

impl TransportCaches {
    /// Runs (or fetches, when another camera of the same step already has) the light-transport
    /// passes the plan turned on; nothing at all for passes that are off or dark frames.
    pub(super) fn run(
        &self,
        sample: &Arc<Sample>,
        lights: &[lights::Light],
        laser: Option<&LaserSheet>,
        plan: &effects::Plan,
        knobs: &Knobs,
        lit: bool,
    ) -> Transport {
        let direct = irradiance::DirectLight {
            lights,
            laser,
            grid: sample.grid.as_ref(),
            shadows: plan.shadows.on,
            tube_points: knobs.tube_samples,
        };
        // Exact description of every input: equal keys mean equal results.
        let key = |pass: &str| {
            format!(
                "{pass}|{}|{lights:?}|{laser:?}|{}|{knobs:?}",
                sample.name, plan.shadows.on
            )
        };
        let bounce = (lit && plan.interreflection.on).then(|| {
            self.bounce.get(key("bounce"), || {
                let geometry = self.bounce_geometry(sample, plan.bounces, knobs)?;
                Some(bounce::compute_with(&geometry, &direct))
            })
        });
        let subsurface = (lit && plan.subsurface.on).then(|| {
            self.subsurface.get(key("subsurface"), || {
                subsurface::compute(sample.as_ref(), &direct, knobs.dipole_samples)
            })
        });
        Transport { bounce, subsurface }
    }

    /// The light-independent geometry of `sample`'s bounce passes (`None` without a relief):
    /// kept per sample, bounce count and rays, or traced for this pass when too large to keep.
    fn bounce_geometry(
        &self,
        sample: &Arc<Sample>,
        bounces: u32,
        knobs: &Knobs,
    ) -> Option<Arc<BounceGeometry>> {
        let grid = sample.grid.as_ref()?;
        let texels = bounce::texels(grid.cells(), knobs.spp_side);
        let n = texels_per_side(grid, texels);
        let rays = knobs.bounce_rays;
        let key = format!("{}|{n}|{bounces}|{rays}", relief_key(sample));
        let bytes = geometry_bytes(n, bounces, rays);
        self.bounce_geometry
            .try_get(key, bytes, || {
                BounceGeometry::trace(sample.as_ref(), bounces, rays, texels).ok_or(())
            })
            .ok()
    }
}

/// The frame's light-transport passes, as the plan called for them (`None` when off or dark).
pub(super) struct Transport {
    pub(super) bounce: Option<Arc<Option<bounce::BounceMap>>>,
    pub(super) subsurface: Option<Arc<Option<subsurface::SubsurfaceMap>>>,
}

impl Transport {
    /// The passes' counters for the notes' `stats` (zeros for passes not run).
    pub(super) fn stats(&self) -> Value {
        let b = self.bounce.as_ref().and_then(|b| b.as_ref().as_ref());
        let s = self.subsurface.as_ref().and_then(|s| s.as_ref().as_ref());
        json!({
            "bounce_passes": b.map_or(0, |b| b.stats.bounces),
            "bounce_rays": b.map_or(0, |b| b.stats.rays),
            "bounce_texels": b.map_or(0, |b| b.stats.texels),
            "bounce_shadow_rays": b.map_or(0, |b| b.stats.shadow_rays),
            "bounce_added": b.map_or(Vec::new(), |b| b.stats.added.clone()),
            "subsurface_passes": s.map_or(0, |s| s.stats.media),
            "subsurface_texels": s.map_or(0, |s| s.stats.texels),
            "subsurface_fft": s.map_or(0, |s| s.stats.fft),
            "subsurface_shadow_rays": s.map_or(0, |s| s.stats.shadow_rays),
        })
    }
}
