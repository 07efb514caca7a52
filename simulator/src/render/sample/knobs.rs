//! The knobs frames of a scene are rendered with: the scene's `[render]` quality and knobs on
//! top of the rig's.

use crate::render::quality::SimKnobs;

use crate::render::error::RenderError;
use crate::render::quality::Knobs;
use crate::scene_file::Scene;

/// The knobs for `scene`, or `None` when it has no `[render]` settings and the renderer's own
/// knobs (`base`) apply. A scene `quality` starts from that preset with the rig's
/// `[sim.knobs]` (`rig_knobs`) reapplied; the scene's `[render.knobs]` override last.
pub fn scene_knobs(
    scene: &Scene,
    base: &Knobs,
    rig_knobs: &SimKnobs,
) -> Result<Option<Knobs>, RenderError> {
    let start = match scene.quality {
        Some(q) => q.knobs().with(rig_knobs)?,
        None if scene.knobs.is_some() => base.clone(),
        None => return Ok(None),
    };
    let knobs = match &scene.knobs {
        Some(k) => start.with(k)?,
        None => start,
    };
    Ok(Some(knobs))
}
