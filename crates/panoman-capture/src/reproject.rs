//! Fitting to the 2D detections: a robust reprojection term per keypoint, anchored at the
//! model's keypoint, alternated with the model fit.
//!
//! For keypoint `k` of a frame, with observations `u_c` (pixels, confidence `w_c`) in cameras
//! `c` and the fitted model's keypoint `p` (metres), the 2D target is
//!
//! ```text
//! X* = argmin_X  Σ_c w_c ρ(‖π_c(X) − u_c‖² / s²)  +  ‖X − p‖² / σ_p²
//! ```
//!
//! with Cauchy's `ρ(t) = ln(1 + t)` (scale `s` pixels: a view disagreeing by many `s` —
//! a left/right swap, a miss — weighs almost nothing) and the model as a prior of σ_p metres.
//! It is solved by Gauss–Newton with iteratively reweighted views (`∂π/∂X` from
//! [`Camera::project_with_jacobian`]) from `X = p`. Keypoints seen in one view only (hands,
//! occluded feet) get a target too: across the ray the view decides, along it the model.
//! [`crate::capture::track_2d`] tracks the triangulated sequence, replaces its targets by the
//! `X*` of every frame at the tracked keypoints, and tracks again: Total Capture's
//! reprojection objective, solved by alternation between the per-keypoint reprojection
//! problems and the model fit.

use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::geom::V3;

use crate::camera::Camera;
use crate::triangulate::Observation;

/// Options of the 2D refinement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReprojectionOptions {
    /// Cauchy scale `s`, pixels (default 15).
    pub scale_px: f64,
    /// σ_p: the model prior's standard deviation, metres (default 0.05).
    pub prior_m: f64,
    /// Gauss–Newton iterations (default 8).
    pub iterations: usize,
    /// Least detector confidence of a view used (default 0.3).
    pub min_confidence: f64,
}

impl Default for ReprojectionOptions {
    fn default() -> Self {
        ReprojectionOptions {
            scale_px: 15.0,
            prior_m: 0.05,
            iterations: 8,
            min_confidence: 0.3,
        }
    }
}

/// The reprojection residual `π(X) − u` (pixels) and its Jacobian `∂/∂X` (2×3, pixels per
/// metre); `None` behind the camera.
pub fn reprojection_residual(
    camera: &Camera,
    x: V3,
    u: [f64; 2],
) -> Option<([f64; 2], [[f64; 3]; 2])> {
    let (p, j) = camera.project_with_jacobian(x)?;
    Some(([p[0] - u[0], p[1] - u[1]], j))
}

/// The objective of [`refine_point`] at `x` (for tests and diagnostics).
pub fn objective(
    cameras: &[Camera],
    observations: &[Observation],
    prior: V3,
    x: V3,
    o: &ReprojectionOptions,
) -> f64 {
    let s2 = o.scale_px * o.scale_px;
    let mut e: f64 =
        (0..3).map(|i| (x[i] - prior[i]).powi(2)).sum::<f64>() / (o.prior_m * o.prior_m);
    for ob in observations {
        if ob.confidence < o.min_confidence {
            continue;
        }
        if let Some((r, _)) = cameras
            .get(ob.camera)
            .and_then(|c| reprojection_residual(c, x, ob.pixel))
        {
            e += ob.confidence * (1.0 + (r[0] * r[0] + r[1] * r[1]) / s2).ln();
        }
    }
    e
}

/// A refined keypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refined {
    /// The target `X*`, metres.
    pub position: V3,
    /// Views whose final Cauchy weight is above ½ (within `s` pixels).
    pub inliers: usize,
    /// Mean confidence of those views (0 when none).
    pub confidence: f64,
}

/// Solves the per-keypoint problem of the module doc from `X = prior`. `None` when no view
/// with enough confidence sees the point in front of its camera.
pub fn refine_point(
    cameras: &[Camera],
    observations: &[Observation],
    prior: V3,
    o: &ReprojectionOptions,
) -> Option<Refined> {
    let s2 = o.scale_px * o.scale_px;
    let ip = 1.0 / (o.prior_m * o.prior_m);
    let used: Vec<&Observation> = observations
        .iter()
        .filter(|ob| ob.confidence >= o.min_confidence && ob.camera < cameras.len())
        .collect();
    let mut x = prior;
    let mut any = false;
    for _ in 0..o.iterations.max(1) {
        let mut h = [[0.0; 3]; 3];
        let mut g = [0.0; 3];
        for i in 0..3 {
            h[i][i] = ip;
            g[i] = ip * (x[i] - prior[i]);
        }
        any = false;
        for ob in &used {
            let Some((r, j)) = reprojection_residual(&cameras[ob.camera], x, ob.pixel) else {
                continue;
            };
            any = true;
            // IRLS weight of ρ(t) = ln(1 + t): ρ'(t) = 1/(1 + t).
            let t = (r[0] * r[0] + r[1] * r[1]) / s2;
            let w = ob.confidence / (s2 * (1.0 + t));
            for a in 0..3 {
                g[a] += w * (j[0][a] * r[0] + j[1][a] * r[1]);
                for b in 0..3 {
                    h[a][b] += w * (j[0][a] * j[0][b] + j[1][a] * j[1][b]);
                }
            }
        }
        if !any {
            return None;
        }
        let d = solve3(&h, [-g[0], -g[1], -g[2]])?;
        // Backtrack on the objective so that a step never makes it worse.
        let e0 = objective(cameras, observations, prior, x, o);
        let mut step = 1.0;
        let mut moved = false;
        while step > 1e-3 {
            let xn = [x[0] + step * d[0], x[1] + step * d[1], x[2] + step * d[2]];
            if objective(cameras, observations, prior, xn, o) <= e0 {
                x = xn;
                moved = true;
                break;
            }
            step *= 0.5;
        }
        if !moved || (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() * step < 1e-7 {
            break;
        }
    }
    if !any {
        return None;
    }
    let (mut n, mut conf) = (0usize, 0.0);
    for ob in &used {
        let inlier = reprojection_residual(&cameras[ob.camera], x, ob.pixel)
            .is_some_and(|(r, _)| r[0] * r[0] + r[1] * r[1] <= s2);
        if inlier {
            n += 1;
            conf += ob.confidence;
        }
    }
    Some(Refined {
        position: x,
        inliers: n,
        confidence: if n > 0 { conf / n as f64 } else { 0.0 },
    })
}

fn solve3(a: &[[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if det.abs() < 1e-300 || !det.is_finite() {
        return None;
    }
    let col = |i: usize| {
        let mut m = *a;
        for r in 0..3 {
            m[r][i] = b[r];
        }
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    Some([col(0) / det, col(1) / det, col(2) / det])
}

/// The 2D targets of one frame: every keypoint observed in `views` (per camera, TC-133
/// indices; empty for a camera left out) and predicted by the model (`predicted[k]`),
/// refined by [`refine_point`]. A keypoint is kept when at least one view is an inlier; its
/// weight is the inliers' mean confidence.
pub fn refine_frame(
    cameras: &[Camera],
    views: &[panoman_interchange::keypoints_in::Keypoints2d],
    predicted: &[V3],
    o: &ReprojectionOptions,
) -> KeypointsFile {
    let mut per: std::collections::BTreeMap<usize, Vec<Observation>> = Default::default();
    for (camera, v) in views.iter().enumerate() {
        for (&k, &(pixel, confidence)) in v {
            per.entry(k).or_default().push(Observation {
                camera,
                pixel,
                confidence,
            });
        }
    }
    let mut out = KeypointsFile::default();
    for (k, obs) in per {
        let Some(&p) = predicted.get(k) else { continue };
        if let Some(r) = refine_point(cameras, &obs, p, o).filter(|r| r.inliers > 0) {
            out.points.insert(k, r.position);
            out.weights.insert(k, r.confidence);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::look_at;
    use panoman_mesh::geom::{matvec, norm, sub};

    fn cams() -> Vec<Camera> {
        (0..3)
            .map(|i| {
                let a = 0.4 + i as f64 * 2.0;
                let c = [3.0 * a.cos(), 3.0 * a.sin(), 1.0];
                let r = look_at(c, [0.0, 0.0, 0.8], [0.0, 0.0, 1.0]);
                let t = matvec(&r, c);
                let mut cam = Camera::pinhole(
                    format!("c{i}"),
                    1200.0,
                    1210.0,
                    540.0,
                    960.0,
                    r,
                    [-t[0], -t[1], -t[2]],
                    Some([1080, 1920]),
                );
                cam.dist = [-0.05, 0.1, 0.001, -0.0005, 0.0];
                cam
            })
            .collect()
    }

    #[test]
    fn residual_jacobian_matches_central_differences() {
        let c = &cams()[1];
        let x = [0.1, -0.2, 1.1];
        let u = [500.0, 900.0];
        let (_, j) = reprojection_residual(c, x, u).unwrap();
        let h = 1e-6;
        for a in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[a] += h;
            xm[a] -= h;
            let (rp, _) = reprojection_residual(c, xp, u).unwrap();
            let (rm, _) = reprojection_residual(c, xm, u).unwrap();
            for r in 0..2 {
                let fd = (rp[r] - rm[r]) / (2.0 * h);
                // Central differences: truncation O(h²·π''') and rounding O(ε·|π|/h) ≈ 1e-6 px/m.
                assert!(
                    (fd - j[r][a]).abs() < 1e-4 * (1.0 + fd.abs()),
                    "∂r{r}/∂X{a}: {fd} vs {}",
                    j[r][a]
                );
            }
        }
    }

    #[test]
    fn exact_views_pull_a_wrong_prior_to_the_point_and_an_outlier_view_is_ignored() {
        let cs = cams();
        let x = [0.05, 0.1, 1.2];
        let mut obs: Vec<Observation> = cs
            .iter()
            .enumerate()
            .map(|(c, cam)| Observation {
                camera: c,
                pixel: cam.project(x).unwrap(),
                confidence: 1.0,
            })
            .collect();
        let o = ReprojectionOptions {
            prior_m: 1e3, // a vanishing prior
            iterations: 30,
            ..Default::default()
        };
        let prior = [0.0, 0.0, 1.25];
        let r = refine_point(&cs, &obs, prior, &o).unwrap();
        assert!(norm(sub(r.position, x)) < 1e-6, "{r:?}");
        assert_eq!(r.inliers, 3);
        // One view off by 300 px (a left/right swap): three views, two agree.
        obs.push(Observation {
            camera: 0,
            pixel: [obs[0].pixel[0] + 300.0, obs[0].pixel[1]],
            confidence: 1.0,
        });
        let r = refine_point(&cs, &obs, prior, &o).unwrap();
        assert!(norm(sub(r.position, x)) < 2e-3, "{r:?}");
        assert_eq!(r.inliers, 3);
    }

    #[test]
    fn one_view_decides_across_its_ray_and_the_prior_along_it() {
        let cs = cams();
        let x = [0.05, 0.1, 1.2];
        let obs = [Observation {
            camera: 2,
            pixel: cs[2].project(x).unwrap(),
            confidence: 1.0,
        }];
        // The prior: the point moved 10 cm along the camera's ray.
        let dir = panoman_mesh::geom::normalize(sub(x, cs[2].centre()));
        let along = [
            x[0] + 0.1 * dir[0],
            x[1] + 0.1 * dir[1],
            x[2] + 0.1 * dir[2],
        ];
        let o = ReprojectionOptions {
            iterations: 30,
            ..Default::default()
        };
        let r = refine_point(&cs, &obs, along, &o).unwrap();
        // Nothing to move along the ray: the prior is already on it.
        assert!(norm(sub(r.position, along)) < 1e-3, "{r:?}");
        // With a vanishing prior, a start 5 cm off the ray ends on it (below 0.1 px) at the
        // prior's depth (the step is across the ray: its component along the ray < 1 mm).
        let off = [along[0] + 0.05 * dir[1], along[1] - 0.05 * dir[0], along[2]];
        let o = ReprojectionOptions {
            prior_m: 1e3,
            iterations: 50,
            ..Default::default()
        };
        let r = refine_point(&cs, &obs, off, &o).unwrap();
        let (res, _) = reprojection_residual(&cs[2], r.position, obs[0].pixel).unwrap();
        assert!(res[0].hypot(res[1]) < 0.1, "{res:?}");
        let moved = sub(r.position, off);
        let along_ray = moved[0] * dir[0] + moved[1] * dir[1] + moved[2] * dir[2];
        assert!(along_ray.abs() < 1e-3, "{along_ray}");
    }
}
