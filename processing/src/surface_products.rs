//! `stagehand process --products surface`: the sample's surface from every view's MDF
//! ([`crate::mdf_products`]): each measured pixel's point (camera centre + D along its ray) in
//! the sample frame, binned onto the square grid of the reference plane the rectified images
//! use, the mean height per cell, holes inpainted, and normals from the heights' central
//! differences. Three products: `height/height.exr` (`Z` height above the reference plane, mm;
//! `S` 2 measured, 1 inpainted, 0 none; `K` points in the cell), `normal/normal.exr` (`X`,
//! `Y`, `Z` of the unit normal, sample frame; 0 where unknown) and `cloud/sample.ply` (the
//! measured cells as a binary PLY point cloud with normals, mm).

use std::collections::BTreeMap;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use serde_json::json;
use stagehand_dataset::exr_planes::{decode_exr_planes, encode_exr_planes};
use stagehand_dataset::products::{NewProduct, ProductStore};

use crate::calibrate_geometry::CameraGeometry;
use crate::error::ProcessingError;
use crate::mdf_merge::{MergedDepth, inpaint, source};
use crate::ray_plane::pixel_ray;
use crate::rectify::RectifyGrid;
use crate::rig_frame::sample_to_camera;
use crate::run_frames::dataset_err;

/// What the surface pass did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SurfaceSummary {
    /// MDF views used.
    pub views: usize,
    /// Points binned.
    pub points: usize,
    /// Of the grid's cells, the fraction some point fell in.
    pub measured_fraction: f64,
    /// Whether the products were written now (false: already current).
    pub written: bool,
}

/// The surface's grid of heights.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    /// The grid.
    pub grid: RectifyGrid,
    /// Height per cell, mm (rows along +y).
    pub height: Vec<f32>,
    /// [`source`] per cell.
    pub source: Vec<u8>,
    /// Points per cell.
    pub points: Vec<u32>,
}

impl HeightMap {
    /// The unit normal of each cell from its neighbours' heights (central differences, one-
    /// sided at the border); zero where a neighbour needed is unknown.
    pub fn normals(&self) -> Vec<[f32; 3]> {
        let n = self.grid.pixels;
        let step = self.grid.size_mm / n as f64;
        let known = |i: usize| self.source[i] != source::NONE;
        (0..n * n)
            .map(|i| {
                let (x, y) = (i % n, i / n);
                let slope = |a: usize, b: usize, cells: f64| {
                    (known(a) && known(b))
                        .then(|| f64::from(self.height[b] - self.height[a]) / (cells * step))
                };
                let (xa, xb) = (x.saturating_sub(1), (x + 1).min(n - 1));
                let (ya, yb) = (y.saturating_sub(1), (y + 1).min(n - 1));
                let dx = slope(y * n + xa, y * n + xb, (xb - xa) as f64);
                let dy = slope(ya * n + x, yb * n + x, (yb - ya) as f64);
                match (dx, dy) {
                    (Some(dx), Some(dy)) if known(i) && n > 1 => {
                        let v = Vector3::new(-dx, -dy, 1.0).normalize();
                        [v.x as f32, v.y as f32, v.z as f32]
                    }
                    _ => [0.0; 3],
                }
            })
            .collect()
    }
}

/// Bins `points` (sample frame, mm) onto `grid` and inpaints the cells no point fell in.
pub fn height_map(grid: RectifyGrid, points: &[Vector3<f64>]) -> HeightMap {
    let n = grid.pixels;
    let step = grid.size_mm / n as f64;
    let (x0, y0) = grid.plane_point(0.0, 0.0);
    let mut sum = vec![0.0f64; n * n];
    let mut count = vec![0u32; n * n];
    for p in points {
        let (i, j) = ((p.x - x0) / step, (p.y - y0) / step);
        if !(i >= 0.0 && j >= 0.0 && i < n as f64 && j < n as f64 && p.z.is_finite()) {
            continue;
        }
        let cell = j as usize * n + i as usize;
        sum[cell] += p.z;
        count[cell] += 1;
    }
    let mut merged = MergedDepth {
        width: n,
        depth: sum
            .iter()
            .zip(&count)
            .map(|(s, c)| {
                if *c > 0 {
                    (s / f64::from(*c)) as f32
                } else {
                    0.0
                }
            })
            .collect(),
        source: count
            .iter()
            .map(|c| {
                if *c > 0 {
                    source::MEASURED
                } else {
                    source::NONE
                }
            })
            .collect(),
        agreeing: vec![0; n * n],
        weight: vec![0.0; n * n],
        conflicts: 0,
    };
    inpaint(&mut merged, &vec![true; n * n]);
    HeightMap {
        grid,
        height: merged.depth,
        source: merged.source,
        points: count,
    }
}

/// Writes the surface products from the run's MDFs in `store`; `None` when it has none.
pub fn surface_products(
    store: &mut ProductStore,
    geometry: (&BTreeMap<String, CameraGeometry>, &str),
    grid: RectifyGrid,
    software: &str,
) -> Result<Option<SurfaceSummary>, ProcessingError> {
    let run_dir = store.dir().to_path_buf();
    let bad = |message: String| ProcessingError::Dataset {
        run: run_dir.display().to_string(),
        message,
    };
    let mdfs: Vec<_> = store
        .products()
        .map_err(dataset_err(&run_dir))?
        .into_iter()
        .filter(|p| p.made.kind == "mdf")
        .collect();
    if mdfs.is_empty() {
        return Ok(None);
    }
    let (cameras, _) = geometry;
    let mut inputs: Vec<String> = mdfs.iter().map(|p| p.path.clone()).collect();
    inputs.sort();
    let calibrations = mdfs[0].made.calibrations.clone();
    let new = |kind: &str, file: &str| NewProduct {
        kind: kind.into(),
        key: format!("{kind}/{}", file.split('.').next().unwrap_or(file)),
        file_name: file.into(),
        inputs: inputs.clone(),
        calibrations: calibrations.clone(),
        software: software.to_string(),
        parameters: json!({"grid": grid, "height": "mean of the measured points per cell, mm above the reference plane"}),
    };
    let products = [
        new("height", "height.exr"),
        new("normal", "normal.exr"),
        new("cloud", "sample.ply"),
    ];
    let mut summary = SurfaceSummary {
        views: mdfs.len(),
        ..SurfaceSummary::default()
    };
    let mut current = true;
    for p in &products {
        current &= store.is_current(p).map_err(dataset_err(&run_dir))?;
    }
    if current {
        // The figures are in the current height map's metadata: no MDF needs reading.
        let height = store
            .products()
            .map_err(dataset_err(&run_dir))?
            .into_iter()
            .find(|p| p.made.kind == "height")
            .ok_or_else(|| bad("the current height product is not indexed".into()))?;
        let bytes = std::fs::read(run_dir.join(&height.path))
            .map_err(|e| bad(format!("{}: {e}", height.path)))?;
        let planes = decode_exr_planes(&height.path, &bytes).map_err(dataset_err(&run_dir))?;
        let meta: serde_json::Value = planes
            .metadata
            .as_deref()
            .and_then(|m| serde_json::from_str(m).ok())
            .ok_or_else(|| bad(format!("{} lacks its metadata", height.path)))?;
        let (Some(points), Some(measured)) =
            (meta["points"].as_u64(), meta["measured_fraction"].as_f64())
        else {
            return Err(bad(format!("{}'s metadata lacks its figures", height.path)));
        };
        summary.points = points as usize;
        summary.measured_fraction = measured;
        return Ok(Some(summary));
    }
    let mut points = Vec::new();
    for p in &mdfs {
        let camera = p.made.parameters["camera"].as_str().unwrap_or_default();
        let table = p.made.parameters["turntable_deg"].as_f64().unwrap_or(0.0);
        let geometry = cameras.get(camera).ok_or_else(|| {
            bad(format!(
                "MDF {} is of camera `{camera}`, which the geometry calibration lacks",
                p.path
            ))
        })?;
        let bytes =
            std::fs::read(run_dir.join(&p.path)).map_err(|e| bad(format!("{}: {e}", p.path)))?;
        let planes = decode_exr_planes(&p.path, &bytes).map_err(dataset_err(&run_dir))?;
        let (Some(d), Some(s)) = (planes.channel("D"), planes.channel("S")) else {
            return Err(bad(format!("{} lacks its D or S channel", p.path)));
        };
        let w = planes.width as usize;
        let pose = sample_to_camera(&geometry.rig_to_camera, table);
        for (i, (&dist, &src)) in d.iter().zip(s).enumerate() {
            if src != f32::from(source::MEASURED) || dist <= 0.0 {
                continue;
            }
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            if let Some((c, dir)) = pixel_ray(&geometry.model, &pose, (u, v)) {
                points.push(c + dir * f64::from(dist));
            }
        }
    }
    let map = height_map(grid, &points);
    let cells = map.height.len();
    summary.points = map.points.iter().map(|c| *c as usize).sum();
    summary.measured_fraction = map
        .source
        .iter()
        .filter(|s| **s == source::MEASURED)
        .count() as f64
        / cells.max(1) as f64;
    let normals = map.normals();
    let n = grid.pixels as u32;
    let metadata = json!({"grid": grid, "views": mdfs.len(), "points": summary.points, "measured_fraction": summary.measured_fraction}).to_string();
    let mut hs = Vec::with_capacity(3 * cells);
    for i in 0..cells {
        hs.extend([
            map.height[i],
            f32::from(map.source[i]),
            map.points[i] as f32,
        ]);
    }
    let height = encode_exr_planes(
        "height.exr",
        n,
        n,
        &["Z", "S", "K"].map(String::from),
        &hs,
        &metadata,
    )
    .map_err(dataset_err(&run_dir))?;
    let ns: Vec<f32> = normals.iter().flatten().copied().collect();
    let normal = encode_exr_planes(
        "normal.exr",
        n,
        n,
        &["X", "Y", "Z"].map(String::from),
        &ns,
        &metadata,
    )
    .map_err(dataset_err(&run_dir))?;
    let cloud = ply(&map, &normals);
    let [h, nm, c] = products;
    store.write(h, &height).map_err(dataset_err(&run_dir))?;
    store.write(nm, &normal).map_err(dataset_err(&run_dir))?;
    store.write(c, &cloud).map_err(dataset_err(&run_dir))?;
    summary.written = true;
    Ok(Some(summary))
}

/// The measured cells as a binary little-endian PLY: x y z nx ny nz (float32, mm).
fn ply(map: &HeightMap, normals: &[[f32; 3]]) -> Vec<u8> {
    let n = map.grid.pixels;
    let cells: Vec<usize> = (0..n * n)
        .filter(|&i| map.source[i] == source::MEASURED)
        .collect();
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment stagehand: the sample's measured surface, sample frame, mm\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n",
        cells.len()
    )
    .into_bytes();
    for i in cells {
        let (x, y) = map
            .grid
            .plane_point((i % n) as f64 + 0.5, (i / n) as f64 + 0.5);
        for v in [x as f32, y as f32, map.height[i]]
            .iter()
            .chain(&normals[i])
        {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_on_a_slope_give_its_heights_and_normal() {
        let grid = RectifyGrid {
            centre_mm: (0.0, 0.0),
            size_mm: 10.0,
            pixels: 10,
        };
        // z = 0.5 x on a 0.25 mm lattice, except a hole in the middle.
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (
                    -5.0 + 0.125 + 0.25 * f64::from(i),
                    -5.0 + 0.125 + 0.25 * f64::from(j),
                );
                if x.abs() < 1.0 && y.abs() < 1.0 {
                    continue;
                }
                points.push(Vector3::new(x, y, 0.5 * x));
            }
        }
        let map = height_map(grid, &points);
        assert_eq!(
            map.source
                .iter()
                .filter(|s| **s == source::INPAINTED)
                .count(),
            4
        );
        for j in 0..10 {
            for i in 0..10 {
                let x = -5.0 + 0.5 + f64::from(i);
                let cell = j * 10 + i as usize;
                assert!(
                    (f64::from(map.height[cell]) - 0.5 * x).abs() < 0.26,
                    "{i},{j}"
                );
            }
        }
        let normals = map.normals();
        let expected = Vector3::new(-0.5, 0.0, 1.0).normalize();
        let n = normals[0];
        assert!((f64::from(n[0]) - expected.x).abs() < 1e-3, "{n:?}");
        let ply = ply(&map, &normals);
        let header = String::from_utf8_lossy(&ply[..200]);
        assert!(header.contains("element vertex 96"), "{header}");
    }
}
