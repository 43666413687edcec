//! Robust multi-view triangulation of one keypoint from calibrated views.
//!
//! Input: observations `(camera index, pixel [u, v], confidence c ≥ 0)`; `c = 0` means "not
//! seen" and the observation is ignored.
//!
//! 1. **Undistort**: each pixel → normalized `(x, y)` with [`Camera::undistort_point`].
//! 2. **Weighted DLT**: with `Pᵢ = [Rᵢ | tᵢ]` (rows `p₁, p₂, p₃`), each view adds the rows
//!    `cᵢ·(x p₃ − p₁)` and `cᵢ·(y p₃ − p₂)` to `A`; the homogeneous point is the unit
//!    eigenvector of the smallest eigenvalue of the 4×4 `AᵀA` (cyclic Jacobi), `X = X̃[..3]/X̃[3]`.
//! 3. **RANSAC over views**, exhaustive and deterministic: the DLT of every pair of views
//!    (`n(n−1)/2` pairs; cheap for the tens of views of a capture rig) is scored by its
//!    inliers, the views whose reprojection error is below [`TriangulateOptions::threshold_px`]
//!    with the point in front of the camera; the best pair has the most inliers, then the
//!    lowest mean inlier error (ties: the first pair in index order). The DLT is refitted on
//!    the inliers and the inlier set recomputed once.
//! 4. **Refinement**: Levenberg–Marquardt on `Σᵢ cᵢ ‖πᵢ(X) − uᵢ‖²` over the inliers (pixels),
//!    with the 2×3 Jacobians of [`Camera::project_with_jacobian`]; a step is kept only if it
//!    lowers the cost and leaves the point in front of every inlier camera.
//!
//! A point behind any camera used is rejected; the result is `None` when fewer than
//! [`TriangulateOptions::min_views`] (≥ 2) views agree. `reprojection_px` is the mean pixel
//! error over the views used and `confidence` their mean confidence.

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use panoman_mesh::geom::V3;

/// One 2-D observation of a keypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index of the camera in the camera list.
    pub camera: usize,
    /// Pixel `[u, v]` (distorted, as detected in the image).
    pub pixel: [f64; 2],
    /// Detector confidence, ≥ 0 (0 = not seen).
    pub confidence: f64,
}

/// Options of [`triangulate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangulateOptions {
    /// Inlier threshold on the reprojection error, pixels (default 20).
    pub threshold_px: f64,
    /// Least number of agreeing views for a result (default 2; values below 2 act as 2).
    pub min_views: usize,
    /// Levenberg–Marquardt iterations of the refinement (default 10; 0 = plain DLT).
    pub refine_iterations: usize,
}

impl Default for TriangulateOptions {
    fn default() -> Self {
        TriangulateOptions {
            threshold_px: 20.0,
            min_views: 2,
            refine_iterations: 10,
        }
    }
}

/// A triangulated keypoint.
#[derive(Debug, Clone, PartialEq)]
pub struct Triangulated {
    /// World position, metres.
    pub position: V3,
    /// Indices of the cameras used (the inliers), increasing.
    pub views: Vec<usize>,
    /// Mean reprojection error over `views`, pixels.
    pub reprojection_px: f64,
    /// Mean confidence of `views`.
    pub confidence: f64,
}

/// An observation ready for the solver.
#[derive(Clone, Copy)]
struct View {
    camera: usize,
    pixel: [f64; 2],
    normalized: [f64; 2],
    weight: f64,
}

/// Triangulates one keypoint (see the module doc). Errors on invalid input: an unknown camera
/// index, a camera observed twice, a non-finite pixel, a negative or non-finite confidence,
/// an invalid camera, a non-positive threshold.
pub fn triangulate(
    cameras: &[Camera],
    observations: &[Observation],
    options: &TriangulateOptions,
) -> Result<Option<Triangulated>> {
    check_options(options)?;
    for c in cameras {
        c.validate()?;
    }
    triangulate_checked(cameras, observations, options)
}

/// [`triangulate`] for many keypoints (e.g. every joint of a frame, or every frame), in order;
/// the cameras are validated once.
pub fn triangulate_many(
    cameras: &[Camera],
    keypoints: &[Vec<Observation>],
    options: &TriangulateOptions,
) -> Result<Vec<Option<Triangulated>>> {
    check_options(options)?;
    for c in cameras {
        c.validate()?;
    }
    keypoints
        .iter()
        .enumerate()
        .map(|(k, obs)| {
            triangulate_checked(cameras, obs, options).map_err(|e| match e {
                CaptureError::Invalid(w) => CaptureError::Invalid(format!("keypoint {k}: {w}")),
                other => other,
            })
        })
        .collect()
}

fn check_options(o: &TriangulateOptions) -> Result<()> {
    if !(o.threshold_px.is_finite() && o.threshold_px > 0.0) {
        return Err(CaptureError::Invalid(format!(
            "inlier threshold must be a positive number of pixels, got {}",
            o.threshold_px
        )));
    }
    Ok(())
}

fn triangulate_checked(
    cameras: &[Camera],
    observations: &[Observation],
    options: &TriangulateOptions,
) -> Result<Option<Triangulated>> {
    let min_views = options.min_views.max(2);
    let mut seen = vec![false; cameras.len()];
    let mut views = Vec::with_capacity(observations.len());
    for o in observations {
        let Some(cam) = cameras.get(o.camera) else {
            return Err(CaptureError::Invalid(format!(
                "observation of camera {} but there are {} cameras",
                o.camera,
                cameras.len()
            )));
        };
        if std::mem::replace(&mut seen[o.camera], true) {
            return Err(CaptureError::Invalid(format!(
                "camera {} ({:?}) is observed twice",
                o.camera, cam.name
            )));
        }
        if !(o.pixel[0].is_finite() && o.pixel[1].is_finite()) {
            return Err(CaptureError::Invalid(format!(
                "camera {} ({:?}): pixel {:?} is not finite",
                o.camera, cam.name, o.pixel
            )));
        }
        if !(o.confidence.is_finite() && o.confidence >= 0.0) {
            return Err(CaptureError::Invalid(format!(
                "camera {} ({:?}): confidence {} is not a finite number ≥ 0",
                o.camera, cam.name, o.confidence
            )));
        }
        if o.confidence == 0.0 {
            continue;
        }
        if let Some(normalized) = cam.undistort_point(o.pixel) {
            views.push(View {
                camera: o.camera,
                pixel: o.pixel,
                normalized,
                weight: o.confidence,
            });
        }
    }
    if views.len() < min_views {
        return Ok(None);
    }
    views.sort_by_key(|v| v.camera);

    // Exhaustive pairwise RANSAC.
    let mut best: Option<(Vec<usize>, f64)> = None;
    for i in 0..views.len() {
        for j in i + 1..views.len() {
            let Some(x) = dlt(cameras, &[views[i], views[j]]) else {
                continue;
            };
            let (inliers, mean) = inliers_of(cameras, &views, x, options.threshold_px);
            if !inliers.contains(&i) || !inliers.contains(&j) {
                continue;
            }
            let better = match &best {
                None => true,
                Some((b, e)) => inliers.len() > b.len() || (inliers.len() == b.len() && mean < *e),
            };
            if better {
                best = Some((inliers, mean));
            }
        }
    }
    let Some((mut inliers, _)) = best else {
        return Ok(None);
    };
    if inliers.len() < min_views {
        return Ok(None);
    }
    // Refit on the inliers, then recompute the inlier set once.
    let mut x = None;
    for _ in 0..2 {
        let set: Vec<View> = inliers.iter().map(|&k| views[k]).collect();
        let Some(fit) = dlt(cameras, &set) else {
            break;
        };
        let (new_inliers, _) = inliers_of(cameras, &views, fit, options.threshold_px);
        if new_inliers.len() < min_views {
            break;
        }
        x = Some(fit);
        if new_inliers == inliers {
            break;
        }
        inliers = new_inliers;
    }
    let Some(mut x) = x else {
        return Ok(None);
    };
    let used: Vec<View> = inliers.iter().map(|&k| views[k]).collect();
    // The DLT of the final set may have left some view behind its camera or over the threshold.
    if used.iter().any(|v| cameras[v.camera].project(x).is_none()) {
        return Ok(None);
    }
    x = refine(cameras, &used, x, options.refine_iterations);
    let mut sum = 0.0;
    for v in &used {
        let Some(p) = cameras[v.camera].project(x) else {
            return Ok(None);
        };
        sum += (p[0] - v.pixel[0]).hypot(p[1] - v.pixel[1]);
    }
    let n = used.len() as f64;
    Ok(Some(Triangulated {
        position: x,
        views: used.iter().map(|v| v.camera).collect(),
        reprojection_px: sum / n,
        confidence: used.iter().map(|v| v.weight).sum::<f64>() / n,
    }))
}

/// Indices (into `views`) of the views that see `x` in front with an error below
/// `threshold`, and their mean error.
fn inliers_of(cameras: &[Camera], views: &[View], x: V3, threshold: f64) -> (Vec<usize>, f64) {
    let mut idx = Vec::new();
    let mut sum = 0.0;
    for (k, v) in views.iter().enumerate() {
        if let Some(p) = cameras[v.camera].project(x) {
            let e = (p[0] - v.pixel[0]).hypot(p[1] - v.pixel[1]);
            if e < threshold {
                idx.push(k);
                sum += e;
            }
        }
    }
    let mean = if idx.is_empty() {
        f64::INFINITY
    } else {
        sum / idx.len() as f64
    };
    (idx, mean)
}

/// Confidence-weighted DLT on undistorted normalized coordinates; `None` for a degenerate
/// system or a point at infinity.
fn dlt(cameras: &[Camera], views: &[View]) -> Option<V3> {
    let mut m = [[0.0f64; 4]; 4];
    for v in views {
        let p = cameras[v.camera].extrinsic_matrix();
        let [x, y] = v.normalized;
        for (coord, prow) in [(x, p[0]), (y, p[1])] {
            let mut row = [0.0; 4];
            for (k, r) in row.iter_mut().enumerate() {
                *r = v.weight * (coord * p[2][k] - prow[k]);
            }
            for a in 0..4 {
                for b in 0..4 {
                    m[a][b] += row[a] * row[b];
                }
            }
        }
    }
    let h = smallest_eigenvector(m)?;
    if h[3].abs() < 1e-12 * (h[0].abs() + h[1].abs() + h[2].abs()) || h[3] == 0.0 {
        return None;
    }
    let x = [h[0] / h[3], h[1] / h[3], h[2] / h[3]];
    x.iter().all(|c| c.is_finite()).then_some(x)
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric 4×4 matrix (cyclic Jacobi).
fn smallest_eigenvector(mut a: [[f64; 4]; 4]) -> Option<[f64; 4]> {
    if a.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..60 {
        let off: f64 = (0..4)
            .flat_map(|p| (p + 1..4).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        let diag: f64 = (0..4).map(|i| a[i][i] * a[i][i]).sum();
        if off <= 1e-36 * diag || off == 0.0 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                let apq = a[p][q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
                // tan of the rotation angle, the smaller root (signum(0) = 1).
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // A ← Jᵀ A J with the rotation in the (p, q) plane.
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (ap, aq) = (a[p], a[q]);
                for k in 0..4 {
                    a[p][k] = c * ap[k] - s * aq[k];
                    a[q][k] = s * ap[k] + c * aq[k];
                }
                for row in v.iter_mut() {
                    let vkp = row[p];
                    let vkq = row[q];
                    row[p] = c * vkp - s * vkq;
                    row[q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let i = (0..4).min_by(|&x, &y| a[x][x].total_cmp(&a[y][y]))?;
    let e = [v[0][i], v[1][i], v[2][i], v[3][i]];
    e.iter().all(|c| c.is_finite()).then_some(e)
}

/// Levenberg–Marquardt on the confidence-weighted squared reprojection error (pixels²).
fn refine(cameras: &[Camera], views: &[View], mut x: V3, iterations: usize) -> V3 {
    let cost_of = |x: V3| -> Option<f64> {
        let mut c = 0.0;
        for v in views {
            let p = cameras[v.camera].project(x)?;
            c += v.weight * ((p[0] - v.pixel[0]).powi(2) + (p[1] - v.pixel[1]).powi(2));
        }
        Some(c)
    };
    let Some(mut cost) = cost_of(x) else {
        return x;
    };
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let mut h = [[0.0f64; 3]; 3];
        let mut g = [0.0f64; 3];
        for v in views {
            let Some((p, j)) = cameras[v.camera].project_with_jacobian(x) else {
                return x;
            };
            let r = [p[0] - v.pixel[0], p[1] - v.pixel[1]];
            for a in 0..3 {
                g[a] += v.weight * (j[0][a] * r[0] + j[1][a] * r[1]);
                for b in 0..3 {
                    h[a][b] += v.weight * (j[0][a] * j[0][b] + j[1][a] * j[1][b]);
                }
            }
        }
        if g.iter().all(|c| c.abs() == 0.0) {
            break;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut hd = h;
            for (k, row) in hd.iter_mut().enumerate() {
                row[k] += lambda * h[k][k].max(1e-12);
            }
            let Some(step) = solve3(&hd, g) else {
                lambda *= 10.0;
                continue;
            };
            let cand = [x[0] - step[0], x[1] - step[1], x[2] - step[2]];
            match cost_of(cand) {
                Some(c) if c <= cost => {
                    let small = step.iter().map(|s| s * s).sum::<f64>().sqrt()
                        <= 1e-15 * (1.0 + x.iter().map(|s| s * s).sum::<f64>().sqrt());
                    x = cand;
                    cost = c;
                    lambda = (lambda * 0.1).max(1e-12);
                    improved = !small;
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !improved {
            break;
        }
    }
    x
}

/// Solves the 3×3 system `H·s = g` by Cramer's rule; `None` when singular.
fn solve3(h: &[[f64; 3]; 3], g: [f64; 3]) -> Option<[f64; 3]> {
    let d = panoman_mesh::geom::det(h);
    if !d.is_finite() || d.abs() < 1e-300 {
        return None;
    }
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut m = *h;
        for r in 0..3 {
            m[r][k] = g[r];
        }
        *o = panoman_mesh::geom::det(&m) / d;
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}
