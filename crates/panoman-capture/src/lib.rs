//! Multi-view capture front end for panoman: calibrated cameras and robust multi-view
//! triangulation of 2-D keypoints.
//!
//! Conventions: metres and radians in the API, `f64` throughout; cameras follow OpenCV
//! (camera frame x right, y down, z forward; world → camera `x_cam = R·X + t`; pixel =
//! `K · distort(x/z, y/z)` with distortion `[k1, k2, p1, p2, k3]`; see [`camera`]). Every
//! reader converts the file's units (millimetres, centimetres, 1/64 pixel) and axis
//! conventions to these.
//!
//! Entry points:
//! * [`Camera`]: `project`, `project_with_jacobian`, `undistort_point`, `ray`, `centre`,
//!   `projection_matrix`, `validate`.
//! * Readers, each → `Vec<Camera>` in file order:
//!   - [`qualisys::read_qca`]: Qualisys `.qca.txt`;
//!   - [`toml_calib::read_toml`] / [`toml_calib::write_toml`]: Pose2Sim / anipose TOML;
//!   - [`panoptic::read_panoptic`]: CMU Panoptic `calibration_<seq>.json`;
//!   - [`opencv_yaml::read_opencv_yaml`]: OpenCV / EasyMocap `intri.yml` + `extri.yml`.
//! * [`triangulate::triangulate`] / [`triangulate::triangulate_many`]: confidence-weighted
//!   DLT, exhaustive pairwise RANSAC over views, Levenberg–Marquardt refinement.
//! * [`frame::triangulate_frame`]: one frame's 2D keypoints per camera (TC-133, e.g.
//!   `panoman_interchange::keypoints_in::read_openpose_2d`) → TC-133 3D targets.
//!
//! Every error is a [`CaptureError`] whose message names the file, the camera and the field;
//! no reader panics on malformed input.

#![warn(missing_docs)]

pub mod camera;
pub mod capture;
mod error;
pub mod fetch;
pub mod frame;
pub mod opencv_yaml;
pub mod panoptic;
pub mod qualisys;
pub mod reproject;
pub mod sequence;
pub mod toml_calib;
pub mod triangulate;

pub use camera::Camera;
pub use error::{CaptureError, Result};

use std::path::Path;

/// Error unless every camera name is distinct (names the file and the repeated name).
pub(crate) fn check_unique_names(path: &Path, cameras: &[Camera]) -> Result<()> {
    let mut seen = std::collections::HashSet::new();
    for c in cameras {
        if !seen.insert(c.name.as_str()) {
            return Err(CaptureError::format(
                path,
                format!("camera name {:?} appears twice", c.name),
            ));
        }
    }
    Ok(())
}

/// Reads a calibration in any supported format, chosen by the path: a folder holding
/// `intri.yml` + `extri.yml` (OpenCV / EasyMocap), `*.qca.txt` or `*.qca` (Qualisys, default
/// [`qualisys::QcaOptions`]), `*.toml` (Pose2Sim / anipose), `*.json` (CMU Panoptic, its HD
/// cameras when it has any).
///
/// # Errors
/// An unknown kind of path (naming it and the kinds known), and the reader's errors.
pub fn read_calibration(path: &Path) -> Result<Vec<Camera>> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    if path.is_dir() {
        let (i, e) = (path.join("intri.yml"), path.join("extri.yml"));
        if i.is_file() && e.is_file() {
            return opencv_yaml::read_opencv_yaml(&i, &e, None);
        }
        return Err(CaptureError::format(
            path,
            "a calibration folder must hold intri.yml and extri.yml (OpenCV / EasyMocap)",
        ));
    }
    if name.ends_with(".qca.txt") || name.ends_with(".qca") {
        qualisys::read_qca(path, &qualisys::QcaOptions::default())
    } else if name.ends_with(".toml") {
        toml_calib::read_toml(path, &toml_calib::TomlOptions::default())
    } else if name.ends_with(".json") {
        let all = panoptic::read_panoptic(path, None)?;
        if all.iter().any(|c| c.name.starts_with("00_")) {
            let hd = panoptic::read_panoptic(path, Some("hd"))?;
            if !hd.is_empty() {
                return Ok(hd);
            }
        }
        Ok(all)
    } else {
        Err(CaptureError::format(
            path,
            "unknown calibration format: expected *.qca.txt (Qualisys), *.toml (Pose2Sim / \
             anipose), *.json (CMU Panoptic) or a folder with intri.yml + extri.yml",
        ))
    }
}
