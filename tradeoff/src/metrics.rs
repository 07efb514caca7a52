//! Error of an image against a reference: RMSE, largest absolute difference and RMSE relative
//! to the reference's mean, over every channel value of the radiance image.

use serde::Serialize;

use super::TradeoffError;

/// How far an image is from the reference, in the renderer's radiance units (white Lambert
/// under the reference lamp = 1/π).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorMetrics {
    /// Root-mean-square difference over all pixels and channels.
    pub rmse: f64,
    /// Largest absolute difference of any channel of any pixel.
    pub max_abs: f64,
    /// `rmse` divided by the mean of the reference (0 when both are 0, infinite when only the
    /// reference mean is 0).
    pub rel_rmse: f64,
}

/// Mean of `values` (0 for none), accumulated in f64.
pub fn mean(values: &[f32]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64
}

/// The error of `image` against `reference` (interleaved channel values of the same size).
pub fn compare(reference: &[f32], image: &[f32]) -> Result<ErrorMetrics, TradeoffError> {
    if reference.len() != image.len() {
        return Err(TradeoffError::SizeMismatch(reference.len(), image.len()));
    }
    let (mut sum2, mut max_abs) = (0.0f64, 0.0f64);
    for (&r, &v) in reference.iter().zip(image) {
        let d = (v as f64 - r as f64).abs();
        // NaN propagates into the sum and the max (f64::max would drop it).
        sum2 += d * d;
        if d > max_abs || d.is_nan() {
            max_abs = d;
        }
    }
    let rmse = if reference.is_empty() {
        0.0
    } else {
        (sum2 / reference.len() as f64).sqrt()
    };
    let m = mean(reference);
    let rel_rmse = if rmse == 0.0 {
        0.0
    } else if m > 0.0 {
        rmse / m
    } else {
        f64::INFINITY
    };
    Ok(ErrorMetrics {
        rmse,
        max_abs,
        rel_rmse,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_zero_error() {
        let a = [0.1f32, 0.2, 0.3, 0.4];
        let m = compare(&a, &a).expect("same size");
        assert_eq!((m.rmse, m.max_abs, m.rel_rmse), (0.0, 0.0, 0.0));
    }

    #[test]
    fn known_differences() {
        // Differences 0, 0, 0, 2 → MSE 1, RMSE 1, max 2; reference mean 1 → relative 1.
        let reference = [1.0f32, 1.0, 1.0, 1.0];
        let image = [1.0f32, 1.0, 1.0, 3.0];
        let m = compare(&reference, &image).expect("same size");
        assert!((m.rmse - 1.0).abs() < 1e-12, "{m:?}");
        assert_eq!(m.max_abs, 2.0);
        assert!((m.rel_rmse - 1.0).abs() < 1e-12);
        // A uniform offset of 0.5 on a mean of 2: RMSE 0.5, relative 0.25.
        let reference = [1.0f32, 3.0, 1.0, 3.0, 2.0, 2.0];
        let image: Vec<f32> = reference.iter().map(|v| v - 0.5).collect();
        let m = compare(&reference, &image).expect("same size");
        assert!((m.rmse - 0.5).abs() < 1e-9 && (m.max_abs - 0.5).abs() < 1e-9);
        assert!((m.rel_rmse - 0.25).abs() < 1e-9);
    }

    #[test]
    fn size_mismatch_and_black_reference() {
        assert!(matches!(
            compare(&[0.0; 3], &[0.0; 6]),
            Err(TradeoffError::SizeMismatch(3, 6))
        ));
        let m = compare(&[0.0; 3], &[0.0, 0.0, 1.0]).expect("same size");
        assert!(m.rel_rmse.is_infinite() && m.max_abs == 1.0);
        assert_eq!(mean(&[]), 0.0);
        let nan = compare(&[1.0; 2], &[1.0, f32::NAN]).expect("same size");
        assert!(nan.rmse.is_nan() && nan.max_abs.is_nan());
    }
}
