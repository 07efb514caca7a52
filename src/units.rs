//! Human-readable times and sizes for reports, progress and messages.

/// Seconds as h:mm:ss, rounded to the nearest second ("-" if not a time).
pub fn hms(seconds: f64) -> String {
    if !seconds.is_finite() || seconds < 0.0 {
        return "-".into();
    }
    let total = seconds.round() as u64;
    format!("{}:{:02}:{:02}", total / 3600, total / 60 % 60, total % 60)
}

/// Bytes in binary units ("512 B", "1.50 KiB"); lives with the dataset, whose verify report
/// prints sizes too.
pub use stagehand_dataset::verify::human_bytes;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_times_and_bytes() {
        assert_eq!(hms(0.0), "0:00:00");
        assert_eq!(hms(59.6), "0:01:00");
        assert_eq!(hms(3725.0), "1:02:05");
        assert_eq!(hms(100.0 * 3600.0), "100:00:00");
        assert_eq!(hms(f64::NAN), "-");
        assert_eq!(human_bytes(0), "0 B");
        assert_eq!(human_bytes(1023), "1023 B");
        assert_eq!(human_bytes(1536), "1.50 KiB");
        assert_eq!(human_bytes(3 * 1024 * 1024 * 1024), "3.00 GiB");
        assert_eq!(human_bytes(u64::MAX), "16.00 EiB");
    }
}
