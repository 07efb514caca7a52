//! The Pareto front of (time, error) points and the cheapest point that meets an error target.

use std::fmt;

use super::TradeoffError;

/// What one setting costs and how far it is from the reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cost {
    /// Render time in seconds.
    pub time_s: f64,
    /// RMSE against the reference, radiance units.
    pub rmse: f64,
    /// RMSE relative to the reference mean.
    pub rel_rmse: f64,
}

/// An error target: absolute RMSE in radiance units, or RMSE relative to the reference mean.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    /// RMSE ≤ this, in radiance units (white Lambert under the reference lamp = 1/π).
    Rmse(f64),
    /// RMSE / reference mean ≤ this fraction.
    Relative(f64),
}

impl Target {
    /// Parses `0.002` (absolute RMSE) or `1.5%` (relative RMSE); must be positive and finite.
    pub fn parse(text: &str) -> Result<Target, TradeoffError> {
        let bad = || TradeoffError::InvalidInput {
            what: "--target-rmse".into(),
            expected: "a positive RMSE such as 0.002, or a percentage of the reference mean \
                       such as 1.5%"
                .into(),
            got: format!("`{text}`"),
        };
        let t = text.trim();
        let (number, relative) = match t.strip_suffix('%') {
            Some(n) => (n.trim(), true),
            None => (t, false),
        };
        let v: f64 = number.parse().map_err(|_| bad())?;
        if !(v.is_finite() && v > 0.0) {
            return Err(bad());
        }
        Ok(if relative {
            Target::Relative(v / 100.0)
        } else {
            Target::Rmse(v)
        })
    }

    /// Whether `cost` meets the target.
    pub fn met_by(&self, cost: &Cost) -> bool {
        match *self {
            Target::Rmse(t) => cost.rmse <= t,
            Target::Relative(t) => cost.rel_rmse <= t,
        }
    }

    fn error_of(&self, cost: &Cost) -> f64 {
        match self {
            Target::Rmse(_) => cost.rmse,
            Target::Relative(_) => cost.rel_rmse,
        }
    }
}

impl fmt::Display for Target {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Target::Rmse(v) => write!(f, "RMSE ≤ {v}"),
            Target::Relative(v) => write!(f, "relative RMSE ≤ {}%", v * 100.0),
        }
    }
}

/// Whether `a` dominates `b`: no slower, no less accurate, and strictly better in one.
fn dominates(a: &Cost, b: &Cost) -> bool {
    a.time_s <= b.time_s && a.rmse <= b.rmse && (a.time_s < b.time_s || a.rmse < b.rmse)
}

/// For each point, whether it is on the Pareto front: no other point is at least as fast and
/// at least as accurate while strictly better in one of the two. Points with a NaN time or
/// error are never on the front.
pub fn front(costs: &[Cost]) -> Vec<bool> {
    costs
        .iter()
        .map(|c| {
            !c.time_s.is_nan() && !c.rmse.is_nan() && !costs.iter().any(|other| dominates(other, c))
        })
        .collect()
}

/// Index of the cheapest point that meets `target` (ties: the lower error, then the first).
/// Errors if none does, naming the best error measured.
pub fn pick(costs: &[Cost], labels: &[String], target: Target) -> Result<usize, TradeoffError> {
    let best = costs
        .iter()
        .enumerate()
        .filter(|(_, c)| target.met_by(c) && !c.time_s.is_nan())
        .min_by(|(_, a), (_, b)| {
            a.time_s
                .total_cmp(&b.time_s)
                .then(target.error_of(a).total_cmp(&target.error_of(b)))
        })
        .map(|(i, _)| i);
    best.ok_or_else(|| {
        let lowest = costs
            .iter()
            .enumerate()
            .filter(|(_, c)| !target.error_of(c).is_nan())
            .min_by(|(_, a), (_, b)| target.error_of(a).total_cmp(&target.error_of(b)));
        let (best, label) = match lowest {
            None => ("nothing (no points)".to_string(), "none".to_string()),
            Some((i, c)) => (
                match target {
                    Target::Rmse(_) => format!("RMSE {:.3e}", c.rmse),
                    Target::Relative(_) => format!("relative RMSE {:.3}%", c.rel_rmse * 100.0),
                },
                labels.get(i).cloned().unwrap_or_default(),
            ),
        };
        TradeoffError::Unreachable {
            target: target.to_string(),
            best,
            label,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(time_s: f64, rmse: f64) -> Cost {
        Cost {
            time_s,
            rmse,
            rel_rmse: rmse * 10.0,
        }
    }

    #[test]
    fn front_of_a_hand_made_set() {
        let costs = [
            c(1.0, 0.10), // fastest: on the front
            c(2.0, 0.05), // on
            c(2.5, 0.08), // dominated by (2.0, 0.05)
            c(4.0, 0.01), // on
            c(4.0, 0.02), // same time, worse: dominated
            c(8.0, 0.01), // same error, slower: dominated
            c(9.0, 0.001),
            c(f64::NAN, 0.0),
        ];
        assert_eq!(
            front(&costs),
            [true, true, false, true, false, false, true, false]
        );
        // Exact duplicates do not dominate each other.
        assert_eq!(front(&[c(1.0, 0.1), c(1.0, 0.1)]), [true, true]);
        assert!(front(&[]).is_empty());
    }

    #[test]
    fn pick_cheapest_meeting_target() {
        let costs = [c(1.0, 0.10), c(2.0, 0.05), c(4.0, 0.01), c(3.0, 0.01)];
        let labels: Vec<String> = ["a", "b", "c", "d"].map(String::from).to_vec();
        assert_eq!(pick(&costs, &labels, Target::Rmse(0.05)).expect("met"), 1);
        assert_eq!(pick(&costs, &labels, Target::Rmse(0.2)).expect("met"), 0);
        assert_eq!(pick(&costs, &labels, Target::Rmse(0.01)).expect("met"), 3);
        // Relative targets use rel_rmse (10 × rmse here): 0.5 → rmse 0.05.
        assert_eq!(
            pick(&costs, &labels, Target::Relative(0.5)).expect("met"),
            1
        );
    }

    #[test]
    fn unreachable_target_names_the_best() {
        let costs = [c(1.0, 0.10), c(2.0, 0.05)];
        let labels: Vec<String> = ["fast", "slow"].map(String::from).to_vec();
        let e = pick(&costs, &labels, Target::Rmse(0.001))
            .expect_err("unreachable")
            .to_string();
        assert!(
            e.contains("RMSE ≤ 0.001") && e.contains("slow") && e.contains("5.000e-2"),
            "{e}"
        );
        let e = pick(&[], &[], Target::Relative(0.01)).expect_err("empty");
        assert!(e.to_string().contains("no points"), "{e}");
    }

    #[test]
    fn targets_parse() {
        assert_eq!(Target::parse("0.002").expect("abs"), Target::Rmse(0.002));
        assert_eq!(Target::parse("1.5%").expect("rel"), Target::Relative(0.015));
        for bad in ["0", "-1", "nan", "inf", "abc", "%", "1e400"] {
            let e = Target::parse(bad).expect_err(bad).to_string();
            assert!(e.contains("--target-rmse"), "{e}");
        }
    }
}
