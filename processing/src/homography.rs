//! Plane-to-image homographies by the normalised direct linear transform (Hartley): both
//! point sets are shifted to their centroid and scaled to mean distance √2 before the SVD, so
//! board millimetres and image pixels weigh alike and the solution does not depend on units.

use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::error::ProcessingError;

/// The similarity that normalises `points` (centroid to 0, mean distance √2).
fn normaliser(points: &[(f64, f64)]) -> Matrix3<f64> {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p.0 / n, y + p.1 / n));
    let mean_dist = points
        .iter()
        .map(|p| ((p.0 - mx).powi(2) + (p.1 - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if mean_dist > 0.0 {
        std::f64::consts::SQRT_2 / mean_dist
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// The homography H with image ≅ H·(board, 1), from at least 4 correspondences of which no 3
/// are collinear. Normalised so H[2,2] = 1 when possible.
pub fn fit_homography(
    board: &[(f64, f64)],
    image: &[(f64, f64)],
) -> Result<Matrix3<f64>, ProcessingError> {
    if board.len() != image.len() || board.len() < 4 {
        return Err(ProcessingError::IllPosed {
            what: "homography",
            why: format!(
                "it needs at least 4 matched points, got {} board and {} image points",
                board.len(),
                image.len()
            ),
        });
    }
    let (tb, ti) = (normaliser(board), normaliser(image));
    let mut a = DMatrix::<f64>::zeros(2 * board.len(), 9);
    for (r, (b, i)) in board.iter().zip(image).enumerate() {
        let pb = tb * Vector3::new(b.0, b.1, 1.0);
        let pi = ti * Vector3::new(i.0, i.1, 1.0);
        let (x, y) = (pb.x, pb.y);
        let (u, v) = (pi.x, pi.y);
        let row0 = [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u];
        let row1 = [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v];
        for c in 0..9 {
            a[(2 * r, c)] = row0[c];
            a[(2 * r + 1, c)] = row1[c];
        }
    }
    // The null vector of A: the right singular vector of the smallest singular value, taken
    // from the eigenvectors of AᵀA (9×9) so a tall A needs no full SVD.
    let ata = a.transpose() * &a;
    let eigen = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&i, &j| eigen.eigenvalues[i].total_cmp(&eigen.eigenvalues[j]));
    let (smallest, second) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
    let largest = eigen.eigenvalues[order[8]].abs().max(1e-300);
    // NaN fails `>=` too and is refused.
    let spans_2d = second >= 1e-12 * largest;
    if !spans_2d || !smallest.is_finite() {
        return Err(ProcessingError::IllPosed {
            what: "homography",
            why: "the points are collinear or repeated; they must span the board in 2D".into(),
        });
    }
    let h = eigen.eigenvectors.column(order[0]);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let ti_inv = ti.try_inverse().ok_or_else(|| ProcessingError::IllPosed {
        what: "homography",
        why: "the image points coincide".into(),
    })?;
    let mut hm = ti_inv * hn * tb;
    let scale = hm[(2, 2)];
    if scale.abs() > 1e-12 {
        hm /= scale;
    }
    if hm.iter().all(|v| v.is_finite()) {
        Ok(hm)
    } else {
        Err(ProcessingError::IllPosed {
            what: "homography",
            why: "the solution is not finite".into(),
        })
    }
}

/// Applies `h` to board point `(x, y)`.
pub fn apply(h: &Matrix3<f64>, x: f64, y: f64) -> (f64, f64) {
    let p = h * Vector3::new(x, y, 1.0);
    (p.x / p.z, p.y / p.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_homography_exactly() {
        let h = Matrix3::new(2.0, 0.1, 300.0, -0.05, 1.9, 200.0, 1e-4, -2e-4, 1.0);
        let board: Vec<(f64, f64)> = (0..20)
            .map(|i| ((i % 5) as f64 * 30.0, (i / 5) as f64 * 30.0))
            .collect();
        let image: Vec<(f64, f64)> = board.iter().map(|&(x, y)| apply(&h, x, y)).collect();
        let fit = fit_homography(&board, &image).unwrap();
        for (b, i) in board.iter().zip(&image) {
            let p = apply(&fit, b.0, b.1);
            assert!((p.0 - i.0).abs() < 1e-8 && (p.1 - i.1).abs() < 1e-8);
        }
    }

    #[test]
    fn collinear_points_are_refused() {
        let board: Vec<(f64, f64)> = (0..6).map(|i| (i as f64, 2.0 * i as f64)).collect();
        let image = board.clone();
        assert!(matches!(
            fit_homography(&board, &image),
            Err(ProcessingError::IllPosed {
                what: "homography",
                ..
            })
        ));
        assert!(fit_homography(&board[..3], &image[..3]).is_err());
    }
}
