//! Pose-dependent marker placement: per marker a surface point linear in the angles of the
//! bones around it, fitted by ridge regression on the calibration frames.

use super::*;

/// A marker's pose-dependent placement: where on the rest mesh it sits as a linear function
/// of the angles of the bones around it,
///
/// `r(θ) = a + Σ_k b_k (φ_k(θ) − μ_k)`,
///
/// `φ` the three Euler angles (radians) of the marker's bone, its parent and its children
/// (the root's unused angles left out), `μ` their mean over the calibration frames that
/// observed the marker (weighted by the frames' IRLS weights), `a` the marker's fixed
/// calibrated surface point on the rest mesh (metres; the marker step's weighted mean with
/// its prior and bound, not the regression's own centre) and `b_k` metres per radian. The
/// surface point of a frame is the point of the rest mesh closest to `r(θ)` among the
/// triangles `candidates` near `a` (which bounds how far a pose outside the calibration
/// frames' range carries it). Skin and the suit slide over the joints: an elbow marker's
/// distance to the wrist bar changes by 60 mm between a bent and a straight arm on Thomas,
/// which no fixed point of the rig's skin follows (docs/design/mocap.md, "Markers slide with
/// the pose"). PanoMan's surface patch of a marker stays around its fixed point `a`; it
/// moves by the marker's displacement like the marker's triangle.
#[derive(Clone, Debug)]
pub struct PosePlacement {
    /// `(bone, axis)` of each feature `φ_k`.
    pub features: Vec<(usize, usize)>,
    /// Mean `μ_k` of each feature over the calibration frames (IRLS-weighted; radians).
    pub mean: Vec<f64>,
    /// Rest-mesh point `a` at the mean pose (metres).
    pub at_mean: V3,
    /// `b_k` (metres per radian).
    pub slopes: Vec<V3>,
    /// Triangles searched for the closest point: the marker's fixed triangle and those with
    /// a vertex within 3 cm beyond the farthest calibration-frame placement from `a` (at most
    /// 15 cm) on the rest mesh.
    pub candidates: Vec<u32>,
}

impl PosePlacement {
    /// `r(θ)` for the bone angles `angles` (rig order, radians).
    pub fn rest_point(&self, angles: &[[f64; 3]]) -> V3 {
        let phi: Vec<f64> = self.features.iter().map(|&(b, a)| angles[b][a]).collect();
        self.at_features(&phi)
    }

    /// `a + Σ_k b_k (φ_k − μ_k)` for the feature values `phi`.
    pub(super) fn at_features(&self, phi: &[f64]) -> V3 {
        self.mean
            .iter()
            .zip(&self.slopes)
            .zip(phi)
            .fold(self.at_mean, |r, ((m, s), x)| add(r, scale(*s, x - m)))
    }
}

/// Weighted ridge regression of 3-vectors on features: the `B` (`k` rows of 3) minimising
/// `Σ_f w_f |y_f − ȳ − Bᵀ(x_f − x̄)|² + λ Σ_f w_f |B|²`, with `x̄`, `ȳ` the weighted means.
/// Returns `(x̄, B)`; `None` when the samples carry no weight or the system is singular
/// (`λ = 0` with features that do not vary).
pub fn ridge_fit(samples: &[(Vec<f64>, V3, f64)], lambda: f64) -> Option<(Vec<f64>, Vec<V3>)> {
    let k = samples.first()?.0.len();
    let wsum: f64 = samples.iter().map(|s| s.2).sum();
    if wsum.is_nan() || wsum <= 0.0 {
        return None;
    }
    let mut xbar = vec![0.0; k];
    let mut ybar = [0.0; 3];
    for (x, y, w) in samples {
        for (m, v) in xbar.iter_mut().zip(x) {
            *m += w * v / wsum;
        }
        ybar = add(ybar, scale(*y, w / wsum));
    }
    let mut a = faer::Mat::<f64>::zeros(k, k);
    let mut rhs = faer::Mat::<f64>::zeros(k, 3);
    for (x, y, w) in samples {
        let d = sub(*y, ybar);
        for p in 0..k {
            let xp = x[p] - xbar[p];
            for q in 0..k {
                a[(p, q)] += w * xp * (x[q] - xbar[q]);
            }
            for c in 0..3 {
                rhs[(p, c)] += w * xp * d[c];
            }
        }
    }
    for p in 0..k {
        a[(p, p)] += lambda * wsum;
    }
    let llt = a.llt(faer::Side::Lower).ok()?;
    let b = llt.solve(&rhs);
    let slopes: Vec<V3> = (0..k).map(|p| [b[(p, 0)], b[(p, 1)], b[(p, 2)]]).collect();
    slopes
        .iter()
        .all(|s| s.iter().all(|v| v.is_finite()))
        .then_some((xbar, slopes))
}

/// Per marker of `map`: the vertices of `rest` (`faces`) within `2σ` of its surface point,
/// with the Gaussian factor `exp(−d²/2σ²)` of their distance `d` (metres); empty lists for
/// `σ ≤ 0`. PanoMan's shell fit pulls each observed marker's patch by the marker's
/// displacement ([`SolveOptions::patch_weight`]).
pub fn marker_patches(
    faces: &[[u32; 3]],
    map: &MarkerMap,
    rest: &[V3],
    sigma: f64,
) -> Vec<Vec<(u32, f64)>> {
    map.markers
        .iter()
        .map(|m| {
            if sigma.is_nan() || sigma <= 0.0 {
                return Vec::new();
            }
            let p = surface_point(faces, rest, m.triangle, m.barycentric);
            rest.iter()
                .enumerate()
                .filter_map(|(v, q)| {
                    let d = sub(*q, p);
                    let d2 = dot(d, d);
                    (d2 < 4.0 * sigma * sigma)
                        .then(|| (v as u32, (-0.5 * d2 / (sigma * sigma)).exp()))
                })
                .collect()
        })
        .collect()
}

impl MarkerSolver {
    /// Fits each marker's [`PosePlacement`] from the calibration frames' solves `outs`: the
    /// marker step's per-frame rest-mesh points under the observation (`samples`) regressed
    /// on the angles of the marker's bone, its parent and its children ([`ridge_fit`] with
    /// [`SolveOptions::pose_placement_ridge`], the frames' IRLS weights). `None` for a
    /// marker with fewer than [`MIN_PLACEMENT_FRAMES`] frames (or no bone in the rig): it
    /// keeps its fixed place.
    pub(super) fn fit_pose_placement(
        &self,
        map: &MarkerMap,
        rest: &[V3],
        outs: &[IkOut],
        samples: &[Vec<PlacementSample>],
    ) -> Vec<Option<PosePlacement>> {
        let faces = self.faces();
        let names = self.bone_names();
        let parents = self.solver.rig().generator.bone_parents();
        let lambda = self.options.pose_placement_ridge;
        map.markers
            .iter()
            .zip(samples)
            .map(|(m, marker_samples)| {
                if marker_samples.len() < MIN_PLACEMENT_FRAMES {
                    return None;
                }
                let bone = names.iter().position(|n| *n == m.bone)?;
                let mut bones = vec![bone];
                bones.extend(parents[bone]);
                bones.extend((0..names.len()).filter(|&c| parents[c] == Some(bone)));
                // Bone 0's angles are unused (the root's rotation is the state's own).
                let features: Vec<(usize, usize)> = bones
                    .iter()
                    .filter(|&&b| b != 0)
                    .flat_map(|&b| (0..3).map(move |axis| (b, axis)))
                    .collect();
                let phi = |k: usize| -> Vec<f64> {
                    let angles = &outs[k].result.state.angles;
                    features.iter().map(|&(b, axis)| angles[b][axis]).collect()
                };
                let rows: Vec<(Vec<f64>, V3, f64)> = marker_samples
                    .iter()
                    .map(|s| (phi(s.frame), s.on_rest, s.weight))
                    .collect();
                let (mean, slopes) = ridge_fit(&rows, lambda)?;
                let mut pp = PosePlacement {
                    features,
                    mean,
                    at_mean: surface_point(faces, rest, m.triangle, m.barycentric),
                    slopes,
                    candidates: Vec::new(),
                };
                // The search reaches 3 cm beyond the calibration frames' farthest placement
                // (at most 15 cm): a pose outside their range does not carry the marker
                // further than that.
                let reach = rows
                    .iter()
                    .map(|(x, _, _)| norm(sub(pp.at_features(x), pp.at_mean)))
                    .fold(0.0, f64::max);
                let radius = (reach + 0.03).min(0.15);
                pp.candidates = (0..faces.len() as u32)
                    .filter(|&t| {
                        t == m.triangle
                            || faces[t as usize].iter().any(|&k| {
                                let d = sub(rest[k as usize], pp.at_mean);
                                dot(d, d) < radius * radius
                            })
                    })
                    .collect();
                Some(pp)
            })
            .collect()
    }
}

/// Frames a marker needs in the calibration for a pose-dependent placement (with fewer it
/// keeps its fixed surface point; the ridge keeps the slopes of a small sample small).
pub(super) const MIN_PLACEMENT_FRAMES: usize = 8;

/// One calibration frame's evidence for a marker's placement: the rest-mesh point under its
/// observation and the frame's IRLS weight.
#[derive(Clone, Debug)]
pub(super) struct PlacementSample {
    /// Index into the calibration frames.
    pub(super) frame: usize,
    pub(super) on_rest: V3,
    pub(super) weight: f64,
}
