//! Wavefront OBJ meshes as samples: a small parser for vertices and polygonal faces, and a
//! top-down rasteriser that turns the mesh into a height field (the highest surface above each
//! grid vertex). Overhangs are filled by construction: a height field sees only the top.

use rayon::prelude::*;

/// Statements carrying no geometry that the parser skips.
const IGNORED: [&str; 11] = [
    "vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib", "l", "p", "",
];

/// A triangle mesh in the units of its file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mesh {
    /// Triangles (polygons are fanned), each three (x, y, z) corners.
    pub triangles: Vec<[[f32; 3]; 3]>,
}

/// A parse error at a 1-based line of the OBJ file.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjError {
    /// 1-based line number in the OBJ file.
    pub line: usize,
    /// What is wrong and what to do.
    pub message: String,
}

/// Parses `v` and `f` statements (triangles and polygons; `i`, `i/t`, `i//n`, `i/t/n` and
/// negative, relative indices); texture, normal, grouping and material statements are
/// skipped. Faces may refer only to vertices defined before them, as the format requires.
pub fn parse_obj(text: &str) -> Result<Mesh, ObjError> {
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    let mut mesh = Mesh::default();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let err = |message: String| ObjError { line, message };
        let content = raw.split('#').next().unwrap_or("");
        let mut tokens = content.split_whitespace();
        let keyword = tokens.next().unwrap_or("");
        match keyword {
            "v" => {
                let mut xyz = [0.0f32; 3];
                for (k, c) in xyz.iter_mut().enumerate() {
                    let token = tokens.next().ok_or_else(|| {
                        err("a vertex needs x, y and z: write `v x y z`".to_string())
                    })?;
                    *c = token
                        .parse::<f32>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .ok_or_else(|| {
                            err(format!(
                                "vertex coordinate {} `{token}` is not a finite number",
                                ["x", "y", "z"][k]
                            ))
                        })?;
                }
                vertices.push(xyz);
            }
            "f" => {
                let corners = tokens
                    .map(|t| corner(t, vertices.len()).map_err(|e| err(e.to_string())))
                    .collect::<Result<Vec<usize>, ObjError>>()?;
                if corners.len() < 3 {
                    return Err(err(format!(
                        "a face needs at least 3 vertices, got {}",
                        corners.len()
                    )));
                }
                for k in 1..corners.len() - 1 {
                    mesh.triangles.push([
                        vertices[corners[0]],
                        vertices[corners[k]],
                        vertices[corners[k + 1]],
                    ]);
                }
            }
            other if IGNORED.contains(&other) => {}
            other => {
                return Err(err(format!(
                    "statement `{other}` is not supported; only polygonal meshes (v and f) can be samples"
                )));
            }
        }
    }
    if mesh.triangles.is_empty() {
        return Err(ObjError {
            line: text.lines().count().max(1),
            message: "the file has no faces; export the mesh with its faces (f statements)".into(),
        });
    }
    Ok(mesh)
}

/// A face corner that names no defined vertex.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum CornerError {
    /// The corner does not start with a number.
    #[error("face corner `{0}` does not start with a vertex index")]
    NoIndex(String),
    /// The index is 0 or beyond the vertices defined so far.
    #[error(
        "face corner `{token}` refers to vertex {index}, but {defined} vertices are defined so far"
    )]
    Undefined {
        token: String,
        index: i64,
        defined: usize,
    },
}

/// The 0-based vertex index of one face corner `i[/t[/n]]` when `defined` vertices exist.
fn corner(token: &str, defined: usize) -> Result<usize, CornerError> {
    let first = token.split('/').next().unwrap_or("");
    let index: i64 = first
        .parse()
        .map_err(|_| CornerError::NoIndex(token.to_string()))?;
    let resolved = if index > 0 {
        index - 1
    } else {
        defined as i64 + index
    };
    if index == 0 || resolved < 0 || resolved >= defined as i64 {
        return Err(CornerError::Undefined {
            token: token.to_string(),
            index,
            defined,
        });
    }
    Ok(resolved as usize)
}

impl Mesh {
    /// Heights at the (n+1)² vertices of an n×n grid `size` mm across centred on the origin
    /// (row-major, x fastest): the highest point of the mesh above each vertex, with mesh
    /// units scaled by `scale` mm. Vertices the mesh does not cover, and parts below the
    /// turntable, are at z = 0.
    pub fn rasterise(&self, n: usize, size: f32, scale: f32) -> Vec<f32> {
        let w = n + 1;
        let cell = size / n.max(1) as f32;
        let origin = -0.5 * size;
        // Rasterise triangles in parallel by grid row bands, each band writing its own rows.
        let mut heights = vec![0.0f32; w * w];
        heights.par_chunks_mut(w).enumerate().for_each(|(j, row)| {
            let y = origin + j as f32 * cell;
            for tri in &self.triangles {
                let p = tri.map(|c| [c[0] * scale, c[1] * scale, c[2] * scale]);
                let (ymin, ymax) = (
                    p[0][1].min(p[1][1]).min(p[2][1]),
                    p[0][1].max(p[1][1]).max(p[2][1]),
                );
                if y < ymin - EDGE_MM || y > ymax + EDGE_MM {
                    continue;
                }
                let xmin = p[0][0].min(p[1][0]).min(p[2][0]);
                let xmax = p[0][0].max(p[1][0]).max(p[2][0]);
                let i0 = (((xmin - origin) / cell).ceil().max(0.0)) as usize;
                let i1 = (((xmax - origin) / cell).floor().max(-1.0) + 1.0) as usize;
                for (i, h) in row.iter_mut().enumerate().take(i1.min(w)).skip(i0) {
                    let x = origin + i as f32 * cell;
                    if let Some(z) = height_in(&p, x, y) {
                        *h = h.max(z);
                    }
                }
            }
        });
        heights
    }
}

/// Slack on the triangle edges in mm so vertices on shared edges are never missed.
const EDGE_MM: f32 = 1.0e-4;

/// The height of triangle `p` above (x, y), if the point lies inside its xy projection.
fn height_in(p: &[[f32; 3]; 3], x: f32, y: f32) -> Option<f32> {
    let [a, b, c] = p;
    let det = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1]);
    if det.abs() < 1.0e-12 {
        // Vertical or degenerate: seen edge-on from above, it adds no area.
        return None;
    }
    let l0 = ((b[1] - c[1]) * (x - c[0]) + (c[0] - b[0]) * (y - c[1])) / det;
    let l1 = ((c[1] - a[1]) * (x - c[0]) + (a[0] - c[0]) * (y - c[1])) / det;
    let l2 = 1.0 - l0 - l1;
    let eps = -1.0e-5;
    (l0 >= eps && l1 >= eps && l2 >= eps).then(|| l0 * a[2] + l1 * b[2] + l2 * c[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_triangles_polygons_and_index_forms() {
        let obj = "# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 1\nvt 0 0\nf 1/1 2//1 3/1/1 -1\n";
        let mesh = parse_obj(obj).expect("valid");
        assert_eq!(mesh.triangles.len(), 2);
        assert_eq!(mesh.triangles[1][2], [0.0, 1.0, 1.0]);
    }

    #[test]
    fn errors_name_their_line() {
        let e = parse_obj("v 0 0 0\nv 1 0 x\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("`x`"), "{}", e.message);
        let e = parse_obj("v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap_err();
        assert_eq!(e.line, 3);
        assert!(e.message.contains("vertex 3"), "{}", e.message);
        let e = parse_obj("v 0 0 0\n").unwrap_err();
        assert!(e.message.contains("no faces"), "{}", e.message);
        let e = parse_obj("v 0 0 0\ncurv 0 1 1 2\n").unwrap_err();
        assert_eq!(e.line, 2);
    }

    #[test]
    fn rasterises_the_top_surface() {
        // Two stacked horizontal squares: the upper one wins where they overlap.
        let obj = "v -5 -5 1\nv 5 -5 1\nv 5 5 1\nv -5 5 1\nf 1 2 3 4\n\
                   v -2 -2 3\nv 2 -2 3\nv 2 2 3\nv -2 2 3\nf 5 6 7 8\n";
        let mesh = parse_obj(obj).expect("valid");
        let n = 20;
        let h = mesh.rasterise(n, 20.0, 1.0);
        let at = |i: usize, j: usize| h[j * (n + 1) + i];
        assert_eq!(at(10, 10), 3.0);
        assert_eq!(at(6, 10), 1.0);
        assert_eq!(at(0, 0), 0.0);
    }
}
