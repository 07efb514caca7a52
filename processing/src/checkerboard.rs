//! Checkerboard detection: saddle points of the smoothed image (where the Hessian's
//! determinant is most negative), kept if a circle around them crosses exactly four dark/light
//! edges, refined to sub-pixel accuracy, then assembled into the board's grid by growing a
//! lattice from a seed with predictions that follow perspective and lens distortion.
//!
//! The corners come back row by row in board order: x along the `cols` direction, the board
//! seen from its front (not mirrored), and the square diagonally outside the first corner dark.
//! That last rule tells a board from its 180° turn only if `cols + rows` is odd; use such a
//! board (as OpenCV advises) where the placements turn it on the turntable.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use crate::corner_subpix::refine_corner;
use crate::error::ProcessingError;
use crate::gray_image::GrayImage;

/// A checkerboard target: its inner corners and square size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CheckerboardSpec {
    /// Inner corners along the board's x direction.
    pub cols: usize,
    /// Inner corners along the board's y direction.
    pub rows: usize,
    /// Side of a square, millimetres.
    pub square_mm: f64,
}

impl CheckerboardSpec {
    /// Board coordinates (mm, z = 0) of the inner corners, in the detector's order.
    pub fn board_points(&self) -> Vec<(f64, f64)> {
        (0..self.rows)
            .flat_map(|j| {
                (0..self.cols).map(move |i| (i as f64 * self.square_mm, j as f64 * self.square_mm))
            })
            .collect()
    }
}

/// Half-size of the sub-pixel refinement window, pixels.
const REFINE_RADIUS: usize = 6;

/// Smallest square side in the image this detector handles, pixels.
pub const MIN_SQUARE_PX: f64 = 10.0;

/// Finds the inner corners of `spec` in `image`, in board order.
pub fn detect_checkerboard(
    image: &GrayImage,
    spec: &CheckerboardSpec,
) -> Result<Vec<(f64, f64)>, ProcessingError> {
    let smooth = image.gaussian(1.5);
    let candidates = saddle_candidates(&smooth);
    // Refinement on a lightly smoothed image in a 13×13 window: the best of the variants
    // tried on rendered boards (radius 4–8, σ 0–1).
    let fine = image.gaussian(0.7);
    let refined: Vec<(f64, f64)> = candidates
        .iter()
        .filter(|&&(x, y)| crosses_four_edges(&smooth, x, y, 4.0))
        .filter_map(|&p| refine_corner(&fine, p, REFINE_RADIUS))
        .collect();
    let refined = dedupe(refined, 2.0);
    let not_found = |why: String| ProcessingError::IllPosed {
        what: "checkerboard detection",
        why,
    };
    if refined.len() < spec.cols * spec.rows {
        return Err(not_found(format!(
            "found {} corner candidates, fewer than the board's {}×{}; check the focus, exposure and that the whole board is in view",
            refined.len(),
            spec.cols,
            spec.rows
        )));
    }
    // Seeds nearest the candidates' centroid first: most likely on the board.
    let n = refined.len() as f64;
    let (mx, my) = refined
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p.0 / n, y + p.1 / n));
    let mut seeds: Vec<usize> = (0..refined.len()).collect();
    seeds.sort_by(|&a, &b| {
        let da = (refined[a].0 - mx).powi(2) + (refined[a].1 - my).powi(2);
        let db = (refined[b].0 - mx).powi(2) + (refined[b].1 - my).powi(2);
        da.total_cmp(&db)
    });
    let mut best = 0;
    for &seed in seeds.iter().take(12) {
        let Some(grid) = grow_grid(&refined, seed) else {
            continue;
        };
        best = best.max(grid.len());
        if let Some(ordered) = order_grid(&grid, &refined, spec, &smooth) {
            return Ok(ordered);
        }
    }
    Err(not_found(format!(
        "no {}×{} grid of corners found (the largest grid had {} corners); check that the whole board is in view and the pattern size in the rig file",
        spec.cols, spec.rows, best
    )))
}

/// Local maxima of the saddle response −det(Hessian), above 5 % of the image's strongest.
fn saddle_candidates(s: &GrayImage) -> Vec<(f64, f64)> {
    let (w, h) = (s.width, s.height);
    let mut resp = vec![0.0f32; w * h];
    let mut max = 0.0f32;
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let (xi, yi) = (x as isize, y as isize);
            let c = s.at(xi, yi);
            let ixx = s.at(xi + 1, yi) - 2.0 * c + s.at(xi - 1, yi);
            let iyy = s.at(xi, yi + 1) - 2.0 * c + s.at(xi, yi - 1);
            let ixy = (s.at(xi + 1, yi + 1) - s.at(xi + 1, yi - 1) - s.at(xi - 1, yi + 1)
                + s.at(xi - 1, yi - 1))
                * 0.25;
            let r = ixy * ixy - ixx * iyy;
            resp[y * w + x] = r;
            max = max.max(r);
        }
    }
    let threshold = 0.05 * max;
    let radius = 3isize;
    let mut out = Vec::new();
    for y in 3..h.saturating_sub(3) {
        for x in 3..w.saturating_sub(3) {
            let r = resp[y * w + x];
            if r <= threshold {
                continue;
            }
            let mut is_max = true;
            'window: for dy in -radius..=radius {
                for dx in -radius..=radius {
                    let v = resp[(y as isize + dy) as usize * w + (x as isize + dx) as usize];
                    if v > r || (v == r && (dy, dx) < (0, 0)) {
                        is_max = false;
                        break 'window;
                    }
                }
            }
            if is_max {
                out.push((x as f64, y as f64));
            }
        }
    }
    out
}

/// Whether a circle of `radius` around `(x, y)` crosses exactly four dark/light edges, as
/// around an X junction of a checkerboard (an edge or a board's outer corner gives two).
fn crosses_four_edges(s: &GrayImage, x: f64, y: f64, radius: f64) -> bool {
    const N: usize = 24;
    let samples: Vec<f32> = (0..N)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / N as f64;
            s.sample(x + radius * a.cos(), y + radius * a.sin())
        })
        .collect();
    let (lo, hi) = samples
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    if hi - lo < 1e-3 {
        return false;
    }
    let mid = 0.5 * (lo + hi);
    let signs: Vec<bool> = samples.iter().map(|&v| v > mid).collect();
    (0..N).filter(|&k| signs[k] != signs[(k + 1) % N]).count() == 4
}

/// Merges points closer than `min_dist` (keeps the first).
fn dedupe(points: Vec<(f64, f64)>, min_dist: f64) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(points.len());
    for p in points {
        if out
            .iter()
            .all(|q| (p.0 - q.0).powi(2) + (p.1 - q.1).powi(2) >= min_dist * min_dist)
        {
            out.push(p);
        }
    }
    out
}

/// Grid cell → candidate index.
type Grid = HashMap<(i32, i32), usize>;

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
}

/// The candidate nearest `p` within `tol`, not yet in `used`.
fn nearest(points: &[(f64, f64)], p: (f64, f64), tol: f64, used: &[bool]) -> Option<usize> {
    points
        .iter()
        .enumerate()
        .filter(|(i, q)| !used[*i] && dist(**q, p) <= tol)
        .min_by(|a, b| dist(*a.1, p).total_cmp(&dist(*b.1, p)))
        .map(|(i, _)| i)
}

/// Grows a lattice of candidates from `seed`: its nearest neighbour and the most perpendicular
/// near neighbour give the first two steps, then every empty cell next to the grid is predicted
/// by extrapolating its filled neighbours and takes the candidate within 30 % of a step.
fn grow_grid(points: &[(f64, f64)], seed: usize) -> Option<Grid> {
    let s = points[seed];
    let mut near: Vec<usize> = (0..points.len()).filter(|&i| i != seed).collect();
    near.sort_by(|&a, &b| dist(points[a], s).total_cmp(&dist(points[b], s)));
    let n1 = *near.first()?;
    let v1 = (points[n1].0 - s.0, points[n1].1 - s.1);
    let l1 = dist(points[n1], s);
    if l1 < MIN_SQUARE_PX * 0.5 {
        return None;
    }
    let n2 = near
        .iter()
        .take(8)
        .copied()
        .filter(|&i| i != n1)
        .min_by(|&a, &b| {
            let cos = |i: usize| {
                let v = (points[i].0 - s.0, points[i].1 - s.1);
                let l = dist(points[i], s);
                ((v.0 * v1.0 + v.1 * v1.1) / (l * l1)).abs() + (l / l1 - 1.0).abs() * 0.5
            };
            cos(a).total_cmp(&cos(b))
        })?;
    let mut used = vec![false; points.len()];
    let mut grid = Grid::new();
    for (cell, i) in [((0, 0), seed), ((1, 0), n1), ((0, 1), n2)] {
        grid.insert(cell, i);
        used[i] = true;
    }
    loop {
        let mut added = false;
        let cells: Vec<(i32, i32)> = grid.keys().copied().collect();
        for (ci, cj) in cells {
            for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                let target = (ci + di, cj + dj);
                if grid.contains_key(&target) {
                    continue;
                }
                let Some((p, step)) = predict(&grid, points, target) else {
                    continue;
                };
                if let Some(i) = nearest(points, p, 0.3 * step, &used) {
                    grid.insert(target, i);
                    used[i] = true;
                    added = true;
                }
            }
        }
        if !added {
            break;
        }
    }
    Some(grid)
}

/// The predicted position of `cell` and the local step length, from a line of two filled
/// cells leading to it, or from a parallelogram of three (the seed's three cells start both).
fn predict(grid: &Grid, points: &[(f64, f64)], (i, j): (i32, i32)) -> Option<((f64, f64), f64)> {
    let at = |c: (i32, i32)| grid.get(&c).map(|&k| points[k]);
    for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
        if let (Some(a), Some(b)) = (at((i - di, j - dj)), at((i - 2 * di, j - 2 * dj))) {
            return Some(((2.0 * a.0 - b.0, 2.0 * a.1 - b.1), dist(a, b)));
        }
    }
    for (di, dj) in [(1, 1), (1, -1), (-1, 1), (-1, -1)] {
        if let (Some(a), Some(b), Some(c)) =
            (at((i - di, j)), at((i, j - dj)), at((i - di, j - dj)))
        {
            let p = (a.0 + b.0 - c.0, a.1 + b.1 - c.1);
            return Some((p, dist(a, c).min(dist(b, c))));
        }
    }
    None
}

/// The grid re-indexed so that it fills its bounding box, if a shear does it. A lattice grown
/// on a steeply foreshortened board can take a diagonal for one of its steps: its cells then
/// run (i + k·j, j), a parallelogram of index space. `None` if no shear up to ±3 makes it a
/// rectangle (a hole or a stray corner).
fn rectangular(grid: &Grid) -> Option<Grid> {
    let fills = |g: &Grid| {
        let (imin, imax, jmin, jmax) = g.keys().fold(
            (i32::MAX, i32::MIN, i32::MAX, i32::MIN),
            |(a, b, c, d), k| (a.min(k.0), b.max(k.0), c.min(k.1), d.max(k.1)),
        );
        g.len() as i64 == i64::from(imax - imin + 1) * i64::from(jmax - jmin + 1)
    };
    for k in [0, 1, -1, 2, -2, 3, -3] {
        for along_i in [true, false] {
            let sheared: Grid = grid
                .iter()
                .map(|(&(i, j), &p)| {
                    let cell = if along_i {
                        (i - k * j, j)
                    } else {
                        (i, j - k * i)
                    };
                    (cell, p)
                })
                .collect();
            if sheared.len() == grid.len() && fills(&sheared) {
                return Some(sheared);
            }
        }
    }
    None
}

/// The grid's corners in board order if it is exactly `cols × rows` (either way round).
fn order_grid(
    grid: &Grid,
    points: &[(f64, f64)],
    spec: &CheckerboardSpec,
    smooth: &GrayImage,
) -> Option<Vec<(f64, f64)>> {
    let grid = &rectangular(grid)?;
    let (imin, imax) = grid.keys().fold((i32::MAX, i32::MIN), |(lo, hi), c| {
        (lo.min(c.0), hi.max(c.0))
    });
    let (jmin, jmax) = grid.keys().fold((i32::MAX, i32::MIN), |(lo, hi), c| {
        (lo.min(c.1), hi.max(c.1))
    });
    let (ni, nj) = ((imax - imin + 1) as usize, (jmax - jmin + 1) as usize);
    // Cell (a, b) in board order → grid cell, for each of the 8 orientations. A square board
    // (cols = rows) fits the grid either way round, so both ways are tried: a board turned a
    // quarter on the turntable is found only the other way round.
    let transposes: &[bool] = match (
        (ni, nj) == (spec.cols, spec.rows),
        (nj, ni) == (spec.cols, spec.rows),
    ) {
        (true, true) => &[false, true],
        (true, false) => &[false],
        (false, true) => &[true],
        (false, false) => return None,
    };
    let (cols, rows) = (spec.cols as i32, spec.rows as i32);
    for &transpose in transposes {
        let corner = |a: i32, b: i32, flip_a: bool, flip_b: bool| {
            let a = if flip_a { cols - 1 - a } else { a };
            let b = if flip_b { rows - 1 - b } else { b };
            let cell = if transpose {
                (imin + b, jmin + a)
            } else {
                (imin + a, jmin + b)
            };
            points[grid[&cell]]
        };
        for (flip_a, flip_b) in [(false, false), (true, true), (true, false), (false, true)] {
            let o = corner(0, 0, flip_a, flip_b);
            let x = corner(1, 0, flip_a, flip_b);
            let y = corner(0, 1, flip_a, flip_b);
            let (ux, uy) = ((x.0 - o.0, x.1 - o.1), (y.0 - o.0, y.1 - o.1));
            // Seen from the front: board x then y turn clockwise in the image (y down).
            if ux.0 * uy.1 - ux.1 * uy.0 <= 0.0 {
                continue;
            }
            // The square diagonally outside corner (0, 0) is dark; its neighbour along x is
            // light.
            let outside = smooth.sample(o.0 - 0.5 * (ux.0 + uy.0), o.1 - 0.5 * (ux.1 + uy.1));
            let beside = smooth.sample(o.0 + 0.5 * (ux.0 - uy.0), o.1 + 0.5 * (ux.1 - uy.1));
            if outside >= beside {
                continue;
            }
            let ordered = (0..rows)
                .flat_map(|b| (0..cols).map(move |a| (a, b)))
                .map(|(a, b)| corner(a, b, flip_a, flip_b))
                .collect();
            return Some(ordered);
        }
    }
    None
}

#[cfg(test)]
#[path = "checkerboard_tests.rs"]
mod tests;
