//! Reliefs of the non-procedural shapes (height images, meshes, grooves, bowls) and the
//! height grid of any scene shape.

use super::procedural::Procedural;
use crate::render::heightfield::HeightGrid;
use crate::scene_file::Shape;

/// Parallel V-grooves running along y: ridges at `depth` (at the sample's −x edge and every
/// `pitch` mm after it), groove bottoms at 0 halfway between.
pub(super) fn grooves(size: f32, pitch: f32, depth: f32, x: f32) -> f32 {
    let t = (x + 0.5 * size) / pitch;
    let f = t - super::noise::floor(t);
    depth * (2.0 * f - 1.0).abs()
}

/// A block `depth` high with a spherical-cap bowl of opening radius `radius` whose bottom
/// reaches z = 0 at the centre.
pub(super) fn bowl(radius: f32, depth: f32, x: f32, y: f32) -> f32 {
    let r2 = x * x + y * y;
    if r2 >= radius * radius {
        return depth;
    }
    // Sphere through the rim (r = R, z = d) and the bottom (0, 0): Rs = (R² + d²) / 2d.
    let rs = (radius * radius + depth * depth) / (2.0 * depth);
    (rs - (rs * rs - r2).max(0.0).sqrt()).min(depth)
}

/// The height grid (n×n cells over `size` mm) of `shape`, or `None` for exactly flat shapes.
/// `procedural` is the model of a bumps, steps or weave shape.
pub(super) fn grid(
    shape: &Shape,
    n: usize,
    size: f32,
    procedural: Option<&Procedural>,
) -> Option<HeightGrid> {
    let grid = |f: &(dyn Fn(f32, f32) -> f32 + Sync)| Some(HeightGrid::build(n, size, f));
    match shape {
        Shape::Flat | Shape::Checkerboard { .. } | Shape::ColorChecker => None,
        Shape::Planes { step_mm } => grid(&|_, y| if y > 0.0 { *step_mm } else { 0.0 }),
        Shape::Bumps { .. } | Shape::Steps { .. } | Shape::Weave => {
            let model = procedural?;
            grid(&|x, y| model.height(x, y))
        }
        Shape::HeightImage {
            image,
            height_scale_mm,
        } => grid(&|x, y| image.scalar_at(x, y, size) * height_scale_mm),
        Shape::Mesh { mesh, scale } => {
            let heights = mesh.rasterise(n, size, *scale);
            let (w, cell, origin) = (n + 1, size / n as f32, -0.5 * size);
            let index = |c: f32| (((c - origin) / cell + 0.5).max(0.0) as usize).min(n);
            grid(&|x, y| heights[index(y) * w + index(x)])
        }
        Shape::Grooves { pitch_mm, depth_mm } => {
            grid(&|x, _| grooves(size, *pitch_mm, *depth_mm, x))
        }
        Shape::Bowl {
            radius_mm,
            depth_mm,
        } => grid(&|x, y| bowl(*radius_mm, *depth_mm, x, y)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grooves_and_bowl_have_the_documented_depths() {
        assert_eq!(grooves(80.0, 10.0, 8.0, -40.0), 8.0);
        assert!(grooves(80.0, 10.0, 8.0, -35.0).abs() < 1e-5);
        assert!((grooves(80.0, 10.0, 8.0, -37.5) - 4.0).abs() < 1e-4);
        assert_eq!(bowl(20.0, 10.0, 0.0, 0.0), 0.0);
        assert_eq!(bowl(20.0, 10.0, 25.0, 0.0), 10.0);
        assert!((bowl(20.0, 10.0, 19.999, 0.0) - 10.0).abs() < 0.05);
    }
}
