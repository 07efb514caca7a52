//! Each camera's latest noise-free radiance, keyed on everything the trace depends on: the
//! camera and the world it saw (axes, lamps, laser, cart, fixture and its pose; not the
//! time), for frames that integrate light. The exposures of an HDR bracket see one world, so they share one trace and differ
//! only in the sensor: the radiance is deterministic, so the frames are bit-identical to
//! frames traced one by one. Bounded to one rig step's images (least recently used dropped).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use stagehand_devices::rig::RigSpec;

use super::RadianceImage;
use super::kept::Kept;
use crate::world_snapshot::WorldSnapshot;

/// Bytes of one camera's radiance image (three `f32` a pixel).
fn image_bytes(width: u32, height: u32) -> usize {
    width as usize * height as usize * 3 * std::mem::size_of::<f32>()
}

/// The key of camera `camera_id`'s view of `world`: every field but the time. `{:?}` prints
/// floats so that they read back exactly, so equal keys mean equal worlds; the destructuring
/// names every field, so a field added to the snapshot must be placed here to compile.
fn key_of(camera_id: &str, world: &WorldSnapshot) -> String {
    let WorldSnapshot {
        rig_time_s: _,
        axes,
        lamps,
        laser,
        cart_mm,
        fixture,
        fixture_pose,
    } = world;
    format!("{camera_id}|{axes:?}|{lamps:?}|{laser:?}|{cart_mm:?}|{fixture:?}|{fixture_pose:?}")
}

/// The radiance images a renderer keeps between frames, and how many frames reused one.
#[derive(Debug)]
pub struct KeptRadiance {
    images: Kept<String, RadianceImage>,
    reused: AtomicU64,
}

impl KeptRadiance {
    /// Room for one image per camera of `rig` (at least eight, the budget's unit), each at
    /// the size of the rig's largest camera: a whole rig step, so a bracket's second exposure
    /// finds every camera's first.
    pub fn for_rig(rig: &RigSpec) -> KeptRadiance {
        let largest = rig
            .cameras
            .iter()
            .map(|c| image_bytes(c.width, c.height))
            .max()
            .unwrap_or(0);
        KeptRadiance::with_budget(rig.cameras.len().max(8) * largest)
    }

    /// Images within `budget_bytes` (none above an eighth of it).
    pub fn with_budget(budget_bytes: usize) -> KeptRadiance {
        KeptRadiance {
            images: Kept::with_budget(budget_bytes),
            reused: AtomicU64::new(0),
        }
    }

    /// Camera `camera_id`'s radiance of `world` (`integrate`: with light), traced by `trace`
    /// unless an earlier frame (or [`Self::fill`]) saw the same world, counted in
    /// [`Self::reused`]; a trace of that world under way is waited for. An error is returned
    /// and nothing kept; an image too large to keep is traced every time, as is a dark
    /// frame's (`integrate` false: nothing is traced, nothing worth keeping).
    pub fn get<E>(
        &self,
        camera_id: &str,
        world: &WorldSnapshot,
        integrate: bool,
        size: (u32, u32),
        trace: impl FnOnce() -> Result<RadianceImage, E>,
    ) -> Result<Arc<RadianceImage>, E> {
        if !integrate {
            return trace().map(Arc::new);
        }
        let (image, traced) = self.kept(camera_id, world, size, trace)?;
        if !traced {
            self.reused.fetch_add(1, Ordering::Relaxed);
        }
        Ok(image)
    }

    /// Traces camera `camera_id`'s radiance of `world` ahead of its frame, unless kept.
    pub fn fill<E>(
        &self,
        camera_id: &str,
        world: &WorldSnapshot,
        size: (u32, u32),
        trace: impl FnOnce() -> Result<RadianceImage, E>,
    ) -> Result<(), E> {
        self.kept(camera_id, world, size, trace).map(|_| ())
    }

    /// The kept image of `world` for `camera_id`, and whether `trace` made it now.
    fn kept<E>(
        &self,
        camera_id: &str,
        world: &WorldSnapshot,
        (width, height): (u32, u32),
        trace: impl FnOnce() -> Result<RadianceImage, E>,
    ) -> Result<(Arc<RadianceImage>, bool), E> {
        let key = key_of(camera_id, world);
        let mut traced = false;
        let image = self.images.try_get(key, image_bytes(width, height), || {
            traced = true;
            trace()
        })?;
        Ok((image, traced))
    }

    /// Frames that reused a kept radiance instead of tracing, since this renderer was made.
    pub fn reused(&self) -> u64 {
        self.reused.load(Ordering::Relaxed)
    }
}
