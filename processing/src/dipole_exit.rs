//! The mesostructure's exit function of a view (`process --products exit`): the light each
//! point sent over what the fitted homogeneous medium sends, summed over a sweep's lines.

use crate::calibrate_geometry::CameraGeometry;
use crate::dipole::DipoleMedium;
use crate::dipole_fit::blurred_profile;

/// True when the camera sees the sample's centre at a cosine of `min_cos` or more: the
/// cameras whose views can have an exit map.
pub(crate) fn sees_steeply(geometry: Option<&CameraGeometry>, min_cos: f64) -> bool {
    geometry.is_some_and(|g| {
        let [x, y, z] = g.centre_mm;
        z / (x * x + y * y + z * z).sqrt().max(1e-9) >= min_cos
    })
}

/// One view's sums over the lines of its sweep, per pixel: the light each line sent and what
/// the fitted medium sends there (the clipped core left out). Fixed memory per view, however
/// many lines the sweep has.
#[derive(Debug, Clone)]
pub(crate) struct ExitView {
    seen: Vec<f64>,
    model: Vec<f64>,
}

/// Lines contribute to a point's exit function only while they light it at least this much of
/// the best-lit point's light (dark points are left at 0: the seed's threshold).
pub(crate) const EXIT_MIN_WEIGHT: f64 = 0.05;

impl ExitView {
    /// A view of `n` pixels, nothing summed yet.
    pub(crate) fn new(n: usize) -> ExitView {
        ExitView {
            seen: vec![0.0; n],
            model: vec![0.0; n],
        }
    }

    /// Adds pixel `index`'s value `v` at distance `s_mm` from a line: what it sent, and what
    /// `medium`'s profile (blurred by `width_mm`) predicts there; nothing inside the core.
    pub(crate) fn add(
        &mut self,
        index: usize,
        s_mm: f64,
        v: f64,
        medium: &DipoleMedium,
        width_mm: f64,
        core_mm: f64,
    ) {
        if index < self.seen.len() && s_mm.abs() > core_mm && v.is_finite() {
            self.seen[index] += v;
            self.model[index] += blurred_profile(medium, s_mm, width_mm);
        }
    }

    /// The view's exit function, interleaved (exit, weight) per pixel: the light each point
    /// sent over what the fitted homogeneous medium sends, summed over the lines (so each line
    /// weighs by how well it lit the point).
    pub(crate) fn maps(&self) -> Vec<f32> {
        let top = self.model.iter().copied().fold(0.0f64, f64::max);
        self.seen
            .iter()
            .zip(&self.model)
            .flat_map(|(&seen, &model)| {
                let weight = if top > 0.0 { model / top } else { 0.0 };
                let exit = if weight >= EXIT_MIN_WEIGHT {
                    seen / model
                } else {
                    0.0
                };
                [exit as f32, weight as f32]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_exit_function_is_the_light_sent_over_the_fitted_medium_s() {
        // Pixel k sits 0.1·k mm from one line and 0.1·k + 3 mm from another; it sends 70 % of
        // what the medium predicts. Beyond the core and where lit, the exit function is 0.7.
        let medium = DipoleMedium {
            alpha_p: 0.6,
            sigma_t_p: 1.2,
            eta: 1.3,
        };
        let mut view = ExitView::new(100);
        for k in 0..100 {
            for offset in [0.0, 3.0] {
                let s = 0.1 * k as f64 + offset;
                let v = 0.7 * blurred_profile(&medium, s, 0.2);
                view.add(k, s, v, &medium, 0.2, 0.8);
            }
        }
        let maps = view.maps();
        for k in 0..100 {
            let (exit, weight) = (maps[2 * k], maps[2 * k + 1]);
            assert!((0.0..=1.0).contains(&weight), "{k}: {weight}");
            if weight >= EXIT_MIN_WEIGHT as f32 {
                assert!((exit - 0.7).abs() < 1e-5, "{k}: {exit}");
            } else {
                assert_eq!(exit, 0.0, "{k}: unlit, {weight}");
            }
        }
        // Inside the core only the far line lights the pixel; far out, nothing does.
        assert!(maps[1] > 0.0 && maps[2 * 99 + 1] < EXIT_MIN_WEIGHT as f32);
    }
}
