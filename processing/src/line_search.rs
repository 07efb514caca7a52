//! One-dimensional minimisation shared by the fits that search one non-linear parameter with
//! the others solved in closed form (the dipole's σ′t, Ward's α): a log-spaced grid finds the
//! basin, golden section refines it; or, where the misfit's slope comes cheaply (Ward's α), a
//! coarser grid and a safeguarded cubic on value and slope.

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

/// One evaluation of a sloped search: the misfit, its slope d(misfit)/d(ln x), and what the
/// caller computed along the way.
pub(crate) struct Probe<T> {
    /// The misfit.
    pub value: f64,
    /// Its derivative in ln x.
    pub slope: f64,
    /// The caller's result at this x.
    pub payload: T,
}

/// The minimum of `fine` over [`lo`, `hi`] (both > 0) in ln x, where it gives its slope too:
/// a grid of `grid` points of `coarse` (a cheaper approximation of `fine`, good enough to
/// find the basin) finds the least value and the side its slope points to; then a cubic on
/// `fine`'s values and slopes at the bracket's ends, safeguarded by bisection, until the
/// bracket is narrower than `tolerance` in ln x. Returns the best x `fine` evaluated and its
/// probe. A minimum beyond an end returns that end.
pub(crate) fn sloped_log_search<T>(
    coarse: &impl Fn(f64) -> Probe<T>,
    fine: &impl Fn(f64) -> Probe<T>,
    lo: f64,
    hi: f64,
    grid: usize,
    tolerance: f64,
) -> (f64, Probe<T>) {
    let (llo, lhi) = (lo.ln(), hi.ln());
    let points = grid.max(2);
    let step = (lhi - llo) / (points - 1) as f64;
    let basin: Vec<Probe<T>> = (0..points)
        .map(|i| coarse((llo + step * i as f64).exp()))
        .collect();
    let least = |probes: &[(f64, Probe<T>)]| {
        probes
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.1.value.total_cmp(&b.1.1.value))
            .map_or(0, |(i, _)| i)
    };
    let i = basin
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.value.total_cmp(&b.1.value))
        .map_or(0, |(i, _)| i);
    let at = |i: usize| {
        let l = llo + step * i as f64;
        (l, fine(l.exp()))
    };
    // The bracket: from the least grid point towards where its slope descends.
    let mut probes = match basin[i].slope {
        g if g > 0.0 && i > 0 => vec![at(i - 1), at(i)],
        g if g < 0.0 && i + 1 < points => vec![at(i), at(i + 1)],
        _ => {
            let (l, probe) = at(i);
            return (l.exp(), probe);
        }
    };
    let (mut a, mut b) = (0, 1);
    for _ in 0..MAX_REFINEMENTS {
        let (la, pa) = (&probes[a].0, &probes[a].1);
        let (lb, pb) = (&probes[b].0, &probes[b].1);
        let width = lb - la;
        if width < tolerance {
            break;
        }
        // The cubic through both ends' values and slopes (Nocedal & Wright eq. 3.59);
        // bisection when it has no minimum inside, or would land near an end.
        let d1 = pa.slope + pb.slope - 3.0 * (pa.value - pb.value) / (la - lb);
        let root = d1 * d1 - pa.slope * pb.slope;
        let cubic = root.sqrt();
        let trial = lb - width * (pb.slope + cubic - d1) / (pb.slope - pa.slope + 2.0 * cubic);
        let margin = 0.05 * width;
        let l = if root >= 0.0 && trial.is_finite() {
            trial.clamp(la + margin, lb - margin)
        } else {
            la + 0.5 * width
        };
        let probe = fine(l.exp());
        let slope = probe.slope;
        let value = probe.value;
        let (fa, fb) = (pa.value, pb.value);
        probes.push((l, probe));
        let new = probes.len() - 1;
        // Keep the side the minimum is on: descending at l, it lies beyond l (unless l is
        // already above the far end's value, a bump between); else before l.
        if slope < 0.0 && value <= fb {
            a = new;
        } else if slope > 0.0 && value <= fa {
            b = new;
        } else if value > fa.min(fb) {
            // A bump: the lower end's side.
            if fa <= fb {
                b = new;
            } else {
                a = new;
            }
        } else {
            break;
        }
    }
    let best = least(&probes);
    let (l, probe) = probes.swap_remove(best);
    (l.exp(), probe)
}

/// Most refinements of [`sloped_log_search`] (the cubic converges in a few; bisection alone
/// halves a grid step of 1 to 10⁻⁴ in 14).
const MAX_REFINEMENTS: usize = 20;

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

    #[test]
    fn the_sloped_search_finds_a_log_parabola_in_few_steps_and_stops_at_the_ends() {
        let count = std::cell::Cell::new(0);
        for truth in [0.0051, 0.011, 0.3, 0.77] {
            count.set(0);
            let f = |x: f64| {
                count.set(count.get() + 1);
                let d = x.ln() - f64::ln(truth);
                // Not a parabola: a quartic term, as a misfit far from its minimum grows.
                Probe {
                    value: d * d + 0.3 * d.powi(4),
                    slope: 2.0 * d + 1.2 * d.powi(3),
                    payload: x,
                }
            };
            let (x, probe) = sloped_log_search(&f, &f, 0.005, 1.0, 6, 1e-5);
            assert!((x / truth - 1.0).abs() < 1e-5, "{x} vs {truth}");
            assert_eq!(probe.payload, x);
            assert!(count.get() <= 14, "{} evaluations", count.get());
        }
        let rising = |x: f64| Probe {
            value: x,
            slope: x,
            payload: (),
        };
        let end = sloped_log_search(&rising, &rising, 0.01, 10.0, 6, 1e-5).0;
        assert!((end / 0.01 - 1.0).abs() < 1e-12);
        let falling = |x: f64| Probe {
            value: -x,
            slope: -x,
            payload: (),
        };
        let end = sloped_log_search(&falling, &falling, 0.01, 10.0, 6, 1e-5).0;
        assert!((end / 10.0 - 1.0).abs() < 1e-12);
    }
}
