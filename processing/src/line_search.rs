//! One-dimensional minimisation shared by the fits that search one non-linear parameter with
//! the others solved in closed form (the dipole's σ′t, Ward's α): a log-spaced grid finds the
//! basin, golden section refines it.

/// The grid point of least `f` among `points` log-spaced points over [`lo`, `hi`] (both > 0),
/// as (ln x, the grid step in ln x).
fn log_grid_minimum(f: &impl Fn(f64) -> f64, lo: f64, hi: f64, points: usize) -> (f64, f64) {
    let (llo, lhi) = (lo.ln(), hi.ln());
    let step = (lhi - llo) / (points.max(2) - 1) as f64;
    let best = (0..points.max(2))
        .map(|i| llo + step * i as f64)
        .map(|l| (l, f(l.exp())))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(llo, |(l, _)| l);
    (best, step)
}

/// The minimum of `f` on [a, b] by `steps` golden-section steps, finished by the vertex of the
/// parabola through the last two points and the bracket's middle (a smooth minimum is then
/// found far closer than the bracket; a parabola that is not convex, or whose vertex leaves
/// the bracket, gives the best of the three points instead).
fn golden_section(f: &impl Fn(f64) -> f64, mut a: f64, mut b: f64, steps: usize) -> f64 {
    let r = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - r * (b - a), a + r * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..steps {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - r * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + r * (b - a);
            fd = f(d);
        }
    }
    let m = 0.5 * (a + b);
    let fm = f(m);
    let (p, q) = ((m - c) * (fm - fd), (m - d) * (fm - fc));
    let denominator = p - q;
    let vertex = m - 0.5 * ((m - c) * p - (m - d) * q) / denominator;
    let convex = fm <= fc.max(fd) && denominator.abs() > 0.0;
    if convex && vertex.is_finite() && vertex >= a && vertex <= b {
        vertex
    } else {
        [(c, fc), (m, fm), (d, fd)]
            .into_iter()
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .map_or(m, |(x, _)| x)
    }
}

/// The minimum of `f` over [`lo`, `hi`] (both > 0) searched in ln x: the grid, then golden
/// section within a grid step of its best point.
pub(crate) fn log_search(
    f: &impl Fn(f64) -> f64,
    lo: f64,
    hi: f64,
    grid: usize,
    steps: usize,
) -> f64 {
    let (best, step) = log_grid_minimum(f, lo, hi, grid);
    let (llo, lhi) = (lo.ln(), hi.ln());
    let g = |l: f64| f(l.exp());
    golden_section(&g, (best - step).max(llo), (best + step).min(lhi), steps).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_minimum_of_a_log_parabola_is_found_across_decades() {
        for truth in [0.011, 0.3, 7.5] {
            let f = |x: f64| (x.ln() - f64::ln(truth)).powi(2);
            let x = log_search(&f, 0.01, 10.0, 41, 50);
            assert!((x / truth - 1.0).abs() < 1e-6, "{x} vs {truth}");
        }
        // A minimum beyond the interval ends at its end.
        let f = |x: f64| x;
        assert!((log_search(&f, 0.01, 10.0, 41, 50) / 0.01 - 1.0).abs() < 1e-6);
    }
}
