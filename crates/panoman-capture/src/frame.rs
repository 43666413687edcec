//! One frame of a multi-view capture: the TC-133 2D keypoints of every camera
//! ([`Keypoints2d`], e.g. read by `panoman_interchange::keypoints_in::read_openpose_2d`)
//! triangulated keypoint by keypoint ([`crate::triangulate`]) into TC-133 3D targets.
//!
//! A keypoint is a target when at least [`TriangulateOptions::min_views`] views agree within
//! the inlier threshold; its weight is the mean detector confidence of the views used, so
//! the fit trusts a point as much as its detections (metres; weights dimensionless).

use std::collections::BTreeMap;

use panoman_human::keypoints::{KeypointsFile, N_KEYPOINTS};
use panoman_interchange::keypoints_in::Keypoints2d;

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::triangulate::{Observation, TriangulateOptions, Triangulated, triangulate_many};

/// The triangulated keypoints of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangulatedFrame {
    /// TC-133 targets: position (metres) and weight (mean confidence of the views used).
    pub keypoints: KeypointsFile,
    /// Per triangulated keypoint (TC-133 index), the views used and the reprojection error.
    pub details: BTreeMap<usize, Triangulated>,
    /// Keypoints detected in at least one view but not triangulated (fewer agreeing views
    /// than needed), TC-133 indices.
    pub rejected: Vec<usize>,
}

/// Triangulates one frame: `views[i]` are the 2D keypoints seen by `cameras[i]` (pixels, as
/// detected). Keypoints seen by fewer than two cameras are left out silently; those seen by
/// two or more on which too few views agree are listed in [`TriangulatedFrame::rejected`].
///
/// # Errors
/// A view count that is not the camera count, a TC-133 index out of range, and the errors
/// of [`triangulate_many`] (invalid cameras, pixels or confidences, naming the keypoint).
pub fn triangulate_frame(
    cameras: &[Camera],
    views: &[Keypoints2d],
    options: &TriangulateOptions,
) -> Result<TriangulatedFrame> {
    if views.len() != cameras.len() {
        return Err(CaptureError::Invalid(format!(
            "{} detection sets for {} cameras",
            views.len(),
            cameras.len()
        )));
    }
    let mut per_keypoint: BTreeMap<usize, Vec<Observation>> = BTreeMap::new();
    for (camera, v) in views.iter().enumerate() {
        for (&k, &(pixel, confidence)) in v {
            if k >= N_KEYPOINTS {
                return Err(CaptureError::Invalid(format!(
                    "camera {:?}: keypoint index {k} is not a TC-133 index",
                    cameras[camera].name
                )));
            }
            per_keypoint.entry(k).or_default().push(Observation {
                camera,
                pixel,
                confidence,
            });
        }
    }
    per_keypoint.retain(|_, obs| obs.iter().filter(|o| o.confidence > 0.0).count() >= 2);
    let (index, observations): (Vec<usize>, Vec<Vec<Observation>>) =
        per_keypoint.into_iter().unzip();
    let solved = triangulate_many(cameras, &observations, options).map_err(|e| match e {
        CaptureError::Invalid(w) => CaptureError::Invalid(format!("TC-133 {w}")),
        other => other,
    })?;
    let mut out = TriangulatedFrame {
        keypoints: KeypointsFile::default(),
        details: BTreeMap::new(),
        rejected: Vec::new(),
    };
    for (k, t) in index.into_iter().zip(solved) {
        match t {
            Some(t) => {
                out.keypoints.points.insert(k, t.position);
                out.keypoints.weights.insert(k, t.confidence);
                out.details.insert(k, t);
            }
            None => out.rejected.push(k),
        }
    }
    Ok(out)
}
