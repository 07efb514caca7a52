//! Typed errors of processing: each says what was wrong with the data and what to do.

use thiserror::Error;

/// An error of a processing step. Ill-posed problems are errors, never NaN results.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProcessingError {
    #[error(
        "the usable DN range [{lo}, {hi}] is empty or not finite; it needs at least 2 DN between the noise floor and saturation"
    )]
    BadRange { lo: f64, hi: f64 },
    #[error("exposure {index} has time {time_s} s; exposure times must be finite and positive")]
    BadExposure { index: usize, time_s: f64 },
    #[error(
        "the bracket has {distinct} distinct exposure time(s); the response needs at least 2 differing by 10 % or more"
    )]
    TooFewExposures { distinct: usize },
    #[error("image {index} has {got} pixels but the bracket's images have {expected}")]
    SizeMismatch {
        index: usize,
        expected: usize,
        got: usize,
    },
    #[error(
        "only {usable} observations constrain the response but its {unknowns} levels need more; capture more exposures, or a scene with more tones, or fit fewer levels"
    )]
    TooFewSamples { usable: usize, unknowns: usize },
    #[error(
        "the observations cover DN {lo:.0}–{hi:.0}, less than {needed_fraction:.0} % of the usable range; the bracket must span dark to bright tones"
    )]
    NarrowCoverage {
        lo: f64,
        hi: f64,
        needed_fraction: f64,
    },
    #[error("parameter `{name}` = {value} is invalid: {why}")]
    BadParameter {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    #[error("the {what} is ill-posed: {why}")]
    IllPosed { what: &'static str, why: String },
    #[error("calibration {id} does not fit this run: {why}")]
    CalibrationMismatch { id: String, why: String },
    #[error("camera `{camera}`: {source}")]
    Camera {
        camera: String,
        source: Box<ProcessingError>,
    },
    #[error("camera `{camera}` under lamp `{lamp}`: {source}")]
    CameraLamp {
        camera: String,
        lamp: String,
        source: Box<ProcessingError>,
    },
    #[error("run {run}: {message}")]
    Dataset { run: String, message: String },
    #[error("run {run} has no {what}; {hint}")]
    MissingInput {
        run: String,
        what: String,
        hint: &'static str,
    },
}
