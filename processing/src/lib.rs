//! Processing of captured runs into calibrated measurements: pure computation on pixel arrays,
//! with no devices and no async. Every ill-posed case is a typed error, never a NaN.
//!
//! | file | concept |
//! |---|---|
//! | [`weight`] | the hat weight of a digital number inside the usable range |
//! | [`response_curve`] | an inverse camera response g = ln f⁻¹ on knots over the DN range |
//! | [`response_samples`] | choosing pixels of a bracket for the response fit |
//! | [`response_solve`] | Debevec–Malik least squares for g |
//! | [`response_calibration`] | every camera's response from a run's bracket sweep |
//! | [`hdr_frame`] | merging RGB frames through per-channel responses and white balance |
//! | [`gray_image`] | a grayscale f32 image, bilinear sampling, Gaussian smoothing |
//! | [`corner_subpix`] | sub-pixel refinement of a checkerboard corner |
//! | [`checkerboard`] | checkerboard corner detection and grid ordering |
//! | [`camera_model`] | pinhole camera, Brown–Conrady distortion, poses |
//! | [`homography`] | plane-to-image homographies by normalised DLT |
//! | [`zhang`] | Zhang's closed-form intrinsics and poses from homographies |
//! | [`calibrate_camera`] | one camera's calibration: closed form, then Levenberg–Marquardt |
//! | [`calibrate_geometry`] | every camera calibrated and placed in the rig frame |
//! | [`rig_frame`] | the turntable axis and the rig frame from flat board placements |
//! | [`rectify`] | resampling a view onto the reference plane with area averaging |
//! | [`laser_line`] | a laser line in a frame: noise-derived threshold, sub-pixel peak |
//! | [`space_time`] | a laser sweep's per-pixel peak times (Curless–Levoy), streamed |
//! | [`laser_sheet`] | a sweep frame's laser sheet as the rig file places the laser |
//! | [`laser_planes`] | calibrated laser sheets per laser position, and the pencil a sweep turns in |
//! | [`laser_plane_calibration`] | each laser position's sheet measured on the two-height planes fixture |
//! | [`ray_plane`] | laser triangulation: a pixel's ray against the sheet that lit it |
//! | [`white_balance`] | joint camera+lamp channel scales from the colour checker |
//! | [`chart_layout`] | the colour checker's physical layout on the turntable |
//! | [`chart_locate`] | finding the colour checker in an image from a camera's geometry |
//! | [`colour_calibration`] | every camera's scales under every lamp from a colour-checker run |
//! | [`nominal_geometry`] | a camera's geometry as the rig file describes it |
//! | [`capture_products`] | `process`: captures merged once, written as HDR, rectified and BTF products |
//! | [`depth_products`] | `process --products depth`: each laser sweep triangulated per camera |
//! | [`mdf_merge`] | a view's depth images merged over laser directions, holes inpainted |
//! | [`mdf_products`] | `process --products mdf`: each view's MDF, float and 8-bit |
//! | [`surface_products`] | `process --products surface`: height map, normals and point cloud from the MDFs |
//! | [`run_frames`] | a run's raw brackets, listed and decoded one at a time |
//! | [`calibration_store`] | calibrations as content-addressed, versioned artefacts |
//! | [`zarr_array`] | Zarr v3 arrays described and encoded (uncompressed chunks) for the BTF |
//! | [`btf_layout`] | which capture fills each BTF cell, views and lights in sample-frame angles |
//! | [`dipole`] | the dipole's R_d, its total reflectance and its line-source profile |
//! | [`dipole_profile`] | a laser line's falloff on the sample plane from frames, binned and fitted |
//! | [`dipole_entrance`] | the entrance function: oblique lines' amplitude against the normal-incidence dipole |
//! | [`dipole_exit`] | a view's exit function: the light sent over the fitted medium's |
//! | [`dipole_products`] | `process --products dipole`: α′ and σ′t per laser colour from the lines at normal incidence |
//! | [`dipole_fit`] | α′ and σ′t from a laser line's lateral falloff |
//! | [`dipole_local`] | the local reflectance function: a halogen capture less the dipole's global term |
//! | [`local_products`] | `process --products local`: the local reflectance function of every step-3 capture |
//! | [`ward`] | the isotropic Ward lobe of the reflectometer fit |
//! | [`ward_tube`] | the reflectometer tube's diffuse and specular integrals at a sample point |
//! | [`ward_fit`] | a pixel's Ward ρd, ρs and α from its cart sweep, weak cases flagged |
//! | [`ward_map`] | a camera's Ward maps from a sweep's radiance frames, flag masks |
//! | [`transparency`] | the sample's transmittance from the backlight frame |
//! | [`error`] | typed errors |
#![deny(unsafe_code)]

pub mod btf_layout;
pub mod calibrate_camera;
pub mod calibrate_geometry;
pub mod calibration_store;
pub mod camera_model;
pub mod capture_products;
pub mod chart_layout;
pub mod chart_locate;
pub mod checkerboard;
pub mod colour_calibration;
pub mod corner_subpix;
pub mod depth_products;
pub mod dipole;
pub mod dipole_entrance;
pub mod dipole_exit;
pub mod dipole_fit;
pub mod dipole_local;
pub mod dipole_products;
pub mod dipole_profile;
pub mod error;
pub mod geometry_calibration;
pub mod gray_image;
pub mod hdr_frame;
pub mod homography;
pub mod laser_line;
pub mod laser_plane_calibration;
pub mod laser_planes;
pub mod laser_sheet;
pub(crate) mod line_search;
pub mod local_products;
pub mod mdf_merge;
pub mod mdf_products;
pub mod nominal_geometry;
pub mod ray_plane;
pub mod rectify;
pub mod reflectometer_calibration;
pub mod reflectometer_products;
pub mod response_calibration;
pub mod response_curve;
pub mod response_samples;
pub mod response_solve;
pub mod rig_frame;
pub mod run_frames;
pub mod space_time;
pub mod surface_products;
pub mod transparency;
pub mod ward;
pub mod ward_fit;
pub mod ward_map;
pub mod ward_tube;
pub mod weight;
pub mod white_balance;
pub mod zarr_array;
pub mod zhang;

pub use calibrate_camera::{BoardView, CalibrationOptions, CameraCalibration, calibrate_camera};
pub use camera_model::{CameraModel, Distortion, Intrinsics, Pose};
pub use checkerboard::{CheckerboardSpec, detect_checkerboard};
pub use error::ProcessingError;
pub use gray_image::GrayImage;
pub use hdr_frame::{HdrFrame, MergeWeight, PixelState, RgbExposure, merge_rgb_frames};
pub use rectify::{Image, Rectified, RectifyGrid, RectifyMap, rectify};
pub use response_curve::InverseResponse;
pub use response_samples::{Bracket, BracketImage, Sample, select_samples};
pub use response_solve::{ResponseFit, ResponseParams, solve_response};
pub use rig_frame::{TurntableAxis, rig_to_camera, turntable_axis};
pub use weight::DnRange;
pub use white_balance::{PatchMeasurement, WhiteBalance, white_balance};

#[cfg(test)]
mod tests {
    /// Processing must measure, not copy the answer: no file of this crate mentions the
    /// simulator's ground truth (`as_built.json`, ground-truth planes).
    #[test]
    fn processing_never_reads_the_simulators_ground_truth() {
        let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        for entry in std::fs::read_dir(&src).unwrap() {
            let path = entry.unwrap().path();
            let text = std::fs::read_to_string(&path).unwrap();
            // The code, not this test's own list.
            let code = text.split("#[cfg(test)]").next().unwrap_or_default();
            for forbidden in ["as_built", "AS_BUILT", "ground_truth(", "StoredGroundTruth"] {
                let hits = code
                    .lines()
                    .filter(|l| !l.trim_start().starts_with("//") && l.contains(forbidden))
                    .count();
                assert_eq!(hits, 0, "{} mentions {forbidden}", path.display());
            }
        }
    }
}
