//! The PanoMan model (paper §4.2–4.4, Eq. 2–5) and its file format.
//!
//! ```text
//! B_S(α)   = V̄ + S α                                                     (Eq. 2, shape PCA)
//! RL(β)    = Σ_parts X̄_L,part + M_L β_L (+ R_L(β_LB, β_AB))                (Eq. 3–5)
//! RA(β)    = Σ_parts X̄_A,part + M_A β_A (+ R_A(β_LB, β_AB))
//! B_P(α,β) = g(RL(β), RA(β), B_S(α))                                      (Appendix A)
//! ```
//!
//! β has six blocks, in this order: `body_l, face_l, hands_l, body_a, face_a, hands_a`
//! (`[β_LB, β_LF, β_LH, β_AB, β_AF, β_AH]`). **Component 0 of every block is the part's mean
//! X̄_part** (dense on the part's columns) with a free coefficient, 1 on the part's own training
//! rows; the stored block mean is 0. With the paper's fixed additive means, a row of another
//! kind (a neutral face in a body pose, a body at rest in an expression) cannot cancel the
//! other parts' mean offsets; with a coefficient it can. The MLPs see and predict β without
//! these two mean coefficients. Each block lives on a set of edges (its part's
//! columns, see `panoman_human::regions`) with a per-column mean and sparse components; a
//! block's mean and components are zero outside its columns, and the parts' contributions add
//! up on shared (margin) edges. RA uses the internal sign `RA = wrap(φ − φ_rest)` (the paper's
//! inner-angle RA is −RA). The correction MLP `R` maps `(β_LB, β_AB)` to RL/RA residuals on the
//! body columns through a PCA head; the motion MLP maps a skeleton pose θ to `(β_LB, β_AB)`.
//!
//! Model files are safetensors (see [`PanoManModel::save`]): tensors for every array and one
//! JSON header in the metadata (`panoman.model`) with names, sizes, the topology hash, the
//! keypoint names, the training configuration and report.

use crate::error::{ModelError, Result};
use crate::mlp::{Element, Mlp, PcaHead, TensorData, TensorStore};
use crate::pca::ShapePca;
use crate::splocs::SparseRows;
use faer::{Mat, Side};
use panoman_human::rigfile::RigData;
use panoman_mesh::geom::{V3, add, matvec};
use panoman_mesh::{GWorkspace, Reconstructor, RestGeometry, Rla, Topology};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

mod gn;
mod params;
pub use gn::{GnOptions, GnReport};
pub use params::{BlockName, Params};

/// Format tag of model files.
pub const MODEL_KIND: &str = "panoman.model";
/// Format version of model files.
pub const MODEL_VERSION: u32 = 1;

/// Which per-edge quantity a block describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// Relative edge lengths RL = ℓ/ℓ_rest − 1.
    Length,
    /// Relative dihedral angles RA = wrap(φ − φ_rest) (radians, internal sign).
    Angle,
}

impl Quantity {
    /// The quantity of block `b` (0..3 lengths, 3..6 angles).
    pub fn of_block(b: usize) -> Quantity {
        if b < 3 {
            Quantity::Length
        } else {
            Quantity::Angle
        }
    }
}

/// Names of the six β blocks, in β order.
pub const BLOCK_NAMES: [&str; 6] = ["body_l", "face_l", "hands_l", "body_a", "face_a", "hands_a"];

/// One β block: a part's mean and sparse localized components over its edge columns.
#[derive(Clone, Debug)]
pub struct ComponentBlock {
    /// Block name (one of [`BLOCK_NAMES`]).
    pub name: BlockName,
    /// Edge id of each column, ascending.
    pub columns: Vec<u32>,
    /// X̄ of the part on its columns.
    pub mean: Vec<f32>,
    /// Components (K × |columns|), sparse rows; `RL or RA = X̄ + Cᵀβ` on the columns.
    pub components: SparseRows,
    /// Per component, the [min, max] of the training coefficients (the range 𝒲 used to clamp
    /// β in fitting).
    pub beta_range: Vec<[f32; 2]>,
}

impl ComponentBlock {
    /// Number of components K of the block.
    pub fn n_components(&self) -> usize {
        self.components.n_rows()
    }
}

/// The correction MLP `R(β_LB, β_AB)` with its PCA output head (docs/design/splocs-model.md §5.1): the
/// output `μ + (P·mlp(β))⊘w` is the RL residual on the `body_l` columns followed by the RA
/// residual on the `body_a` columns.
#[derive(Clone, Debug)]
pub struct CorrectionMlp {
    /// The network: (K_LB + K_AB − 2) → hidden → rank(head) (inputs without the two mean
    /// coefficients, see the module docs).
    pub mlp: Mlp,
    /// The PCA head decoding codes into residuals.
    pub head: PcaHead,
}

/// The motion MLP `θ → (β_LB, β_AB)` (docs/design/splocs-model.md §5.2). Inputs: for each bone of
/// `theta_bones`, the first two columns of its local rotation matrix (6-D representation) built
/// from the dataset's Euler angles (radians, R = Rz·Ry·Rx).
#[derive(Clone, Debug)]
pub struct Motion {
    /// The network: 6·|bones| → 400 → 600 → (K_LB + K_AB − 2) (β_B without its mean
    /// coefficients, which are 1 for body poses).
    pub mlp: Mlp,
    /// Bones whose rotations form the input, in order.
    pub theta_bones: Vec<String>,
    /// Index of each of `theta_bones` in the dataset's theta layout (bone-major Euler triples).
    pub theta_index: Vec<u32>,
}

/// Keypoints as fixed sparse combinations of vertices (docs/formats.md §3).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KeypointRows {
    /// Keypoint names (TC-133 order when complete).
    pub names: Vec<String>,
    /// Per keypoint, `(vertex, weight)` pairs; the keypoint is `Σ w·x_v`.
    pub rows: Vec<Vec<(u32, f64)>>,
}

impl KeypointRows {
    /// Evaluates every keypoint on `positions`.
    pub fn evaluate(&self, positions: &[V3]) -> Vec<V3> {
        self.rows
            .iter()
            .map(|row| {
                let mut p = [0.0; 3];
                for &(v, w) in row {
                    let x = positions[v as usize];
                    for c in 0..3 {
                        p[c] += w * x[c];
                    }
                }
                p
            })
            .collect()
    }
}

/// The trained model (see the module docs).
#[derive(Clone, Debug)]
pub struct PanoManModel {
    /// Topology name ("full" or "small").
    pub topology_name: String,
    /// Topology hash (`Topology::hash_hex`) of the template.
    pub topology_hash: String,
    /// Template triangles.
    pub faces: Vec<[u32; 3]>,
    /// Number of vertices.
    pub n_vertices: usize,
    /// Shape space (Eq. 2).
    pub shape: ShapePca,
    /// The six β blocks in [`BLOCK_NAMES`] order.
    pub blocks: Vec<ComponentBlock>,
    /// Correction MLP (optional).
    pub correction: Option<CorrectionMlp>,
    /// Motion MLP θ → β_body (optional).
    pub motion: Option<Motion>,
    /// Part of each edge (0 body, 1 face, 2 left hand, 3 right hand).
    pub edge_part: Vec<u8>,
    /// Keypoint definitions.
    pub keypoints: KeypointRows,
    /// The training configuration (`None`: not recorded, or a layout this version does not
    /// read; fields missing in older files take the default preset's values).
    pub config: Option<crate::train::TrainConfig>,
    /// What the training measured on its own rows (`None`: not recorded, or a layout this
    /// version does not read).
    pub report: Option<crate::train::ModelReport>,
    /// The LBS rig (generator and topology map) the IK initializer and the LBS baseline need,
    /// stored in the file as the `rig.postcard` byte tensor ([`RigData::to_bytes`]), so that
    /// a model file alone can pose, encode, fit and track. `None` for model files written
    /// before rigs were embedded (fitting then reads the rig from the asset tree).
    pub rig: Option<Arc<RigData>>,
}

/// Name of the byte tensor holding the embedded rig.
pub const RIG_TENSOR: &str = "rig.postcard";

#[derive(Serialize, Deserialize)]
struct Header {
    kind: String,
    version: u32,
    topology_name: String,
    topology_hash: String,
    n_vertices: usize,
    n_faces: usize,
    n_edges: usize,
    n_shape: usize,
    blocks: Vec<BlockHeader>,
    correction: bool,
    motion_bones: Option<Vec<String>>,
    keypoint_names: Vec<String>,
    config: serde_json::Value,
    report: serde_json::Value,
}

#[derive(Serialize, Deserialize)]
struct BlockHeader {
    name: String,
    n_columns: usize,
    n_components: usize,
    nnz: usize,
}

impl PanoManModel {
    /// The block `name`.
    pub fn block(&self, name: BlockName) -> &ComponentBlock {
        &self.blocks[name.index()]
    }

    /// Total number of β entries.
    pub fn n_beta(&self) -> usize {
        self.blocks.iter().map(ComponentBlock::n_components).sum()
    }

    /// Number of edges of the template.
    pub fn n_edges(&self) -> usize {
        self.edge_part.len()
    }

    /// `B_S(α)` (Eq. 2) as vertex positions; α may be empty (the mean shape).
    pub fn rest_shape(&self, alpha: &[f64]) -> Vec<V3> {
        let flat = self.shape.reconstruct(alpha);
        flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    }

    /// RL and RA of the parameters (Eq. 3–5), with or without the correction MLP.
    pub fn rla(&self, params: &Params, correction: bool) -> Rla {
        let r = if correction {
            self.correction_residual(params)
        } else {
            None
        };
        self.rla_with_residual(params, r.as_deref())
    }

    /// [`PanoManModel::rla`] with the correction residual given: `r` is
    /// [`PanoManModel::correction_residual`] of the same β (`None`: uncorrected), e.g. one a
    /// caller already has for these parameters.
    ///
    /// # Panics
    /// If `r` is not of the body columns' length (RL then RA).
    pub fn rla_with_residual(&self, params: &Params, r: Option<&[f32]>) -> Rla {
        let ne = self.n_edges();
        let mut rla = Rla::zeros(ne);
        if let Some(r) = r {
            assert_eq!(
                r.len(),
                self.blocks[0].columns.len() + self.blocks[3].columns.len(),
                "correction residual length"
            );
        }
        // RL and RA are written by disjoint blocks: one task each, every output summed in
        // the sequential order (blocks, then the correction).
        let fill = |out: &mut Vec<f64>, quantity: Quantity| {
            for (b, block) in self.blocks.iter().enumerate() {
                if Quantity::of_block(b) != quantity {
                    continue;
                }
                for (j, &e) in block.columns.iter().enumerate() {
                    out[e as usize] += block.mean[j] as f64;
                }
                let beta = params.beta_of(block.name, block.n_components());
                for (k, &bk) in beta.iter().enumerate() {
                    if bk == 0.0 {
                        continue;
                    }
                    let (cols, vals) = block.components.row(k);
                    for (&j, &v) in cols.iter().zip(vals) {
                        out[block.columns[j as usize] as usize] += bk * v as f64;
                    }
                }
            }
            if let Some(r) = r {
                let n1 = self.blocks[0].columns.len();
                let (block, part) = match quantity {
                    Quantity::Length => (&self.blocks[0], &r[..n1]),
                    Quantity::Angle => (&self.blocks[3], &r[n1..]),
                };
                for (&e, &x) in block.columns.iter().zip(part) {
                    out[e as usize] += x as f64;
                }
            }
        };
        let Rla { rl, ra } = &mut rla;
        rayon::join(|| fill(rl, Quantity::Length), || fill(ra, Quantity::Angle));
        rla
    }

    /// The correction MLP's residual `R(β_LB, β_AB)` on the body columns (RL then RA), if the
    /// model has one.
    pub fn correction_residual(&self, params: &Params) -> Option<Vec<f32>> {
        let c = self.correction.as_ref()?;
        let x = self.body_beta_f32(params);
        let codes = c.mlp.forward_one(&x);
        Some(c.head.decode(&codes))
    }

    /// `(β_LB, β_AB)` without their mean coefficients (component 0 of each block),
    /// concatenated as f32: the MLPs' body coefficient vector.
    pub fn body_beta_f32(&self, params: &Params) -> Vec<f32> {
        let bl = &self.blocks[0];
        let ba = &self.blocks[3];
        let mut x: Vec<f32> = params
            .beta_of(bl.name, bl.n_components())
            .iter()
            .skip(1)
            .map(|&v| v as f32)
            .collect();
        x.extend(
            params
                .beta_of(ba.name, ba.n_components())
                .iter()
                .skip(1)
                .map(|&v| v as f32),
        );
        x
    }

    /// β_B from a skeleton pose through the motion MLP (docs/design/splocs-model.md §5.2): `euler(bone)` gives
    /// a bone's local Euler angles (radians, R = Rz·Ry·Rx; `None` = rest), the input is each
    /// of the MLP's bones' 6-D rotation (first two columns of R), and the output fills
    /// `body_l` and `body_a` with their mean coefficients (component 0) set to 1. `None` when
    /// the model has no motion MLP.
    pub fn beta_from_theta(
        &self,
        euler: &dyn Fn(&str) -> Option<[f64; 3]>,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let m = self.motion.as_ref()?;
        let mut x = Vec::with_capacity(6 * m.theta_bones.len());
        for b in &m.theta_bones {
            let [ex, ey, ez] = euler(b).unwrap_or([0.0; 3]);
            let r = panoman_mesh::rotation::euler_xyz([ex, ey, ez]);
            // The first two columns of R, column-major.
            x.extend((0..6).map(|i| r[i % 3][i / 3]));
        }
        let y = m.mlp.forward_one_f64(&x);
        let kl = self.blocks[0].n_components();
        let ka = self.blocks[3].n_components();
        let mut bl = vec![0.0; kl];
        let mut ba = vec![0.0; ka];
        if kl > 0 {
            bl[0] = 1.0;
            bl[1..].copy_from_slice(&y[..kl - 1]);
        }
        if ka > 0 {
            ba[0] = 1.0;
            ba[1..].copy_from_slice(&y[kl.saturating_sub(1)..kl.saturating_sub(1) + ka - 1]);
        }
        Some((bl, ba))
    }

    /// Number of entries of [`PanoManModel::body_beta_f32`]: `K_LB + K_AB − 2`.
    pub fn n_body_mlp(&self) -> usize {
        body_mlp_len(&self.blocks)
    }

    /// Saves the model as one safetensors file (atomic write). Tensors: `template.faces`,
    /// `shape.{mean,components,std_devs,explained}`, `edge_part`,
    /// `block.<name>.{columns,mean,row_ptr,col_idx,values,beta_range}`,
    /// `keypoints.{row_ptr,vertex,weight}`, `correction.mlp.*`, `correction.head.*`,
    /// `motion.mlp.*`, `motion.theta_index`; the JSON header in metadata `panoman.model`.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.to_store()?.save(path)
    }

    /// Builds the tensor store of [`PanoManModel::save`].
    pub fn to_store(&self) -> Result<TensorStore> {
        let mut s = TensorStore::new();
        if let Some(rig) = &self.rig {
            let bytes = rig
                .to_bytes()
                .map_err(|e| ModelError::Invalid(e.to_string()))?;
            s.insert(RIG_TENSOR, vec![bytes.len()], TensorData::U8(bytes))?;
        }
        let f: Vec<u32> = self.faces.iter().flatten().copied().collect();
        s.insert(
            "template.faces",
            vec![self.faces.len(), 3],
            TensorData::U32(f),
        )?;
        let d = self.shape.dim();
        let k = self.shape.n_components();
        s.insert(
            "shape.mean",
            vec![d],
            TensorData::F64(self.shape.mean.clone()),
        )?;
        let comps: Vec<f64> = (0..d)
            .flat_map(|i| (0..k).map(move |j| (i, j)))
            .map(|(i, j)| self.shape.components[(i, j)])
            .collect();
        s.insert("shape.components", vec![d, k], TensorData::F64(comps))?;
        s.insert(
            "shape.std_devs",
            vec![k],
            TensorData::F64(self.shape.std_devs.clone()),
        )?;
        s.insert(
            "shape.explained",
            vec![k],
            TensorData::F64(self.shape.explained_variance_ratio.clone()),
        )?;
        s.insert(
            "shape.totals",
            vec![2],
            TensorData::F64(vec![self.shape.total_variance, self.shape.n_samples as f64]),
        )?;
        s.insert(
            "edge_part",
            vec![self.edge_part.len()],
            TensorData::U32(self.edge_part.iter().map(|&p| p as u32).collect()),
        )?;
        for b in &self.blocks {
            let p = format!("block.{}", b.name);
            s.insert(
                format!("{p}.columns"),
                vec![b.columns.len()],
                TensorData::U32(b.columns.clone()),
            )?;
            s.insert(
                format!("{p}.mean"),
                vec![b.mean.len()],
                TensorData::F32(b.mean.clone()),
            )?;
            let c = &b.components;
            s.insert(
                format!("{p}.row_ptr"),
                vec![c.row_ptr.len()],
                TensorData::U32(c.row_ptr.iter().map(|&x| x as u32).collect()),
            )?;
            s.insert(
                format!("{p}.col_idx"),
                vec![c.col_idx.len()],
                TensorData::U32(c.col_idx.clone()),
            )?;
            s.insert(
                format!("{p}.values"),
                vec![c.values.len()],
                TensorData::F32(c.values.clone()),
            )?;
            let r: Vec<f32> = b.beta_range.iter().flatten().copied().collect();
            s.insert(
                format!("{p}.beta_range"),
                vec![b.beta_range.len(), 2],
                TensorData::F32(r),
            )?;
        }
        let mut ptr = vec![0u32];
        let mut vert = Vec::new();
        let mut wts = Vec::new();
        for row in &self.keypoints.rows {
            for &(v, w) in row {
                vert.push(v);
                wts.push(w);
            }
            ptr.push(vert.len() as u32);
        }
        s.insert("keypoints.row_ptr", vec![ptr.len()], TensorData::U32(ptr))?;
        s.insert("keypoints.vertex", vec![vert.len()], TensorData::U32(vert))?;
        s.insert("keypoints.weight", vec![wts.len()], TensorData::F64(wts))?;
        if let Some(c) = &self.correction {
            c.mlp.write(&mut s, "correction.mlp")?;
            c.head.write(&mut s, "correction.head")?;
        }
        if let Some(m) = &self.motion {
            m.mlp.write(&mut s, "motion.mlp")?;
            s.insert(
                "motion.theta_index",
                vec![m.theta_index.len()],
                TensorData::U32(m.theta_index.clone()),
            )?;
        }
        let header = Header {
            kind: MODEL_KIND.into(),
            version: MODEL_VERSION,
            topology_name: self.topology_name.clone(),
            topology_hash: self.topology_hash.clone(),
            n_vertices: self.n_vertices,
            n_faces: self.faces.len(),
            n_edges: self.edge_part.len(),
            n_shape: k,
            blocks: self
                .blocks
                .iter()
                .map(|b| BlockHeader {
                    name: b.name.as_str().to_string(),
                    n_columns: b.columns.len(),
                    n_components: b.n_components(),
                    nnz: b.components.nnz(),
                })
                .collect(),
            correction: self.correction.is_some(),
            motion_bones: self.motion.as_ref().map(|m| m.theta_bones.clone()),
            keypoint_names: self.keypoints.names.clone(),
            // As JSON values: objects with sorted keys, so the bytes do not depend on the
            // structs' field order.
            config: self.config.as_ref().map_or(serde_json::Value::Null, |c| {
                serde_json::to_value(c).expect("config serializes")
            }),
            report: self.report.as_ref().map_or(serde_json::Value::Null, |r| {
                serde_json::to_value(r).expect("report serializes")
            }),
        };
        s.set_metadata(
            MODEL_KIND,
            serde_json::to_string(&header).expect("header serializes"),
        );
        Ok(s)
    }

    /// Loads and validates a model file: format tag and version, tensor presence, shapes,
    /// dtypes, index ranges, finiteness and the topology hash of the stored faces. Errors
    /// name the file and what is wrong.
    ///
    /// A dataset written by `panoman synth` (`dataset.safetensors`, whose metadata say
    /// `format: panoman-dataset`) is recognized from its header alone and named as such.
    pub fn load(path: &Path) -> Result<PanoManModel> {
        if is_dataset_file(path) {
            return Err(ModelError::Format {
                path: path.to_path_buf(),
                what: "this is a dataset (safetensors written by panoman synth), not a model file"
                    .into(),
            });
        }
        let store = TensorStore::load(path)?;
        Self::from_store(&store).map_err(|e| match e {
            ModelError::Invalid(what) | ModelError::Numerical(what) => ModelError::Format {
                path: path.to_path_buf(),
                what,
            },
            ModelError::Mesh(m) => ModelError::Format {
                path: path.to_path_buf(),
                what: m.to_string(),
            },
            other => other,
        })
    }

    /// Rebuilds a model from a tensor store (see [`PanoManModel::load`]).
    pub fn from_store(s: &TensorStore) -> Result<PanoManModel> {
        let bad = |w: String| ModelError::Invalid(w);
        let rig = match s.get(RIG_TENSOR) {
            None => None,
            Some(t) => {
                let bytes = u8::slice(&t.data)
                    .ok_or_else(|| bad(format!("tensor '{RIG_TENSOR}' is not U8")))?;
                let rig = RigData::from_bytes(bytes, s.source()).map_err(|e| bad(e.to_string()))?;
                Some(Arc::new(rig))
            }
        };
        let hjson = s
            .metadata(MODEL_KIND)
            .ok_or_else(|| bad("not a panoman model (no 'panoman.model' header)".into()))?;
        let h: Header =
            serde_json::from_str(hjson).map_err(|e| bad(format!("model header: {e}")))?;
        if h.kind != MODEL_KIND || h.version != MODEL_VERSION {
            return Err(bad(format!(
                "model header is {} v{}, expected {MODEL_KIND} v{MODEL_VERSION}",
                h.kind, h.version
            )));
        }
        let faces_flat = get_u32(s, "template.faces", &[h.n_faces, 3])?;
        let faces: Vec<[u32; 3]> = faces_flat
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        if faces_flat.iter().any(|&v| v as usize >= h.n_vertices) {
            return Err(bad(
                "template.faces refers to a vertex beyond n_vertices".into()
            ));
        }
        let topo = Topology::build(h.n_vertices, &faces)?;
        if topo.hash_hex() != h.topology_hash {
            return Err(bad(format!(
                "topology hash {} of the stored faces differs from the header's {}",
                topo.hash_hex(),
                h.topology_hash
            )));
        }
        if topo.n_edges() != h.n_edges {
            return Err(bad(format!(
                "header says {} edges, the faces have {}",
                h.n_edges,
                topo.n_edges()
            )));
        }
        let shape = read_shape(s, &h)?;
        let edge_part: Vec<u8> = get_u32(s, "edge_part", &[h.n_edges])?
            .iter()
            .map(|&p| {
                if p < 4 {
                    Ok(p as u8)
                } else {
                    Err(bad(format!("edge_part value {p} > 3")))
                }
            })
            .collect::<Result<_>>()?;
        let blocks = read_blocks(s, &h)?;
        let rows = read_keypoint_rows(s, &h)?;
        let k_body = body_mlp_len(&blocks);
        let correction = if h.correction {
            let mlp = Mlp::read(s, "correction.mlp")?;
            let head = PcaHead::read(s, "correction.head")?;
            if mlp.n_inputs() != k_body || mlp.n_outputs() != head.rank() {
                return Err(bad(
                    "correction MLP sizes do not match the body blocks / head".into(),
                ));
            }
            if head.dim() != blocks[0].columns.len() + blocks[3].columns.len() {
                return Err(bad(
                    "correction head dimension does not match the body columns".into(),
                ));
            }
            Some(CorrectionMlp { mlp, head })
        } else {
            None
        };
        let motion = match &h.motion_bones {
            Some(bones) => {
                let mlp = Mlp::read(s, "motion.mlp")?;
                let theta_index = get_u32(s, "motion.theta_index", &[bones.len()])?;
                if mlp.n_inputs() != 6 * bones.len() || mlp.n_outputs() != k_body {
                    return Err(bad(
                        "motion MLP sizes do not match its bones / the body blocks".into(),
                    ));
                }
                Some(Motion {
                    mlp,
                    theta_bones: bones.clone(),
                    theta_index,
                })
            }
            None => None,
        };
        Ok(PanoManModel {
            topology_name: h.topology_name,
            topology_hash: h.topology_hash,
            faces,
            n_vertices: h.n_vertices,
            shape,
            blocks,
            correction,
            motion,
            edge_part,
            keypoints: KeypointRows {
                names: h.keypoint_names,
                rows,
            },
            config: serde_json::from_value(h.config).ok(),
            report: serde_json::from_value(h.report).ok(),
            rig,
        })
    }
}

/// The shape PCA of a model store (`shape.*`, sizes from the header).
fn read_shape(s: &TensorStore, h: &Header) -> Result<ShapePca> {
    let bad = |w: String| ModelError::Invalid(w);
    let d = 3 * h.n_vertices;
    let k = h.n_shape;
    let mean = get_f64(s, "shape.mean", &[d])?;
    let comps = get_f64(s, "shape.components", &[d, k])?;
    let std_devs = get_f64(s, "shape.std_devs", &[k])?;
    let explained = get_f64(s, "shape.explained", &[k])?;
    let totals = get_f64(s, "shape.totals", &[2])?;
    if std_devs.iter().any(|&x| x <= 0.0) {
        return Err(bad("shape.std_devs must be positive".into()));
    }
    Ok(ShapePca {
        mean,
        components: Mat::from_fn(d, k, |i, j| comps[i * k + j]),
        std_devs,
        explained_variance_ratio: explained,
        total_variance: totals[0],
        n_samples: totals[1] as usize,
    })
}

/// The six component blocks of a model store (`block.<name>.*`), checked against the
/// header.
fn read_blocks(s: &TensorStore, h: &Header) -> Result<Vec<ComponentBlock>> {
    let bad = |w: String| ModelError::Invalid(w);
    if h.blocks.len() != 6 || h.blocks.iter().zip(BLOCK_NAMES).any(|(b, n)| b.name != n) {
        return Err(bad(format!(
            "model must have the blocks {}",
            BLOCK_NAMES.join(", ")
        )));
    }
    let mut blocks = Vec::with_capacity(6);
    for (bh, name) in h.blocks.iter().zip(BlockName::ALL) {
        let p = format!("block.{}", bh.name);
        let columns = get_u32(s, &format!("{p}.columns"), &[bh.n_columns])?;
        if columns.iter().any(|&e| e as usize >= h.n_edges)
            || columns.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(bad(format!(
                "{p}.columns must be ascending edge ids < {}",
                h.n_edges
            )));
        }
        let mean = get_f32(s, &format!("{p}.mean"), &[bh.n_columns])?;
        let row_ptr: Vec<usize> = get_u32(s, &format!("{p}.row_ptr"), &[bh.n_components + 1])?
            .iter()
            .map(|&x| x as usize)
            .collect();
        let col_idx = get_u32(s, &format!("{p}.col_idx"), &[bh.nnz])?;
        let values = get_f32(s, &format!("{p}.values"), &[bh.nnz])?;
        if row_ptr[0] != 0
            || *row_ptr.last().unwrap() != bh.nnz
            || row_ptr.windows(2).any(|w| w[0] > w[1])
            || col_idx.iter().any(|&c| c as usize >= bh.n_columns)
        {
            return Err(bad(format!("{p}: inconsistent sparse component storage")));
        }
        let range = get_f32(s, &format!("{p}.beta_range"), &[bh.n_components, 2])?;
        blocks.push(ComponentBlock {
            name,
            columns,
            mean,
            components: SparseRows {
                n_cols: bh.n_columns,
                row_ptr,
                col_idx,
                values,
            },
            beta_range: range.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        });
    }
    Ok(blocks)
}

/// The keypoint rows of a model store (`keypoints.*`, CSR over template vertices).
fn read_keypoint_rows(s: &TensorStore, h: &Header) -> Result<Vec<Vec<(u32, f64)>>> {
    let bad = |w: String| ModelError::Invalid(w);
    let nkp = h.keypoint_names.len();
    let kptr = get_u32(s, "keypoints.row_ptr", &[nkp + 1])?;
    let nnz = *kptr.last().unwrap_or(&0) as usize;
    let kv = get_u32(s, "keypoints.vertex", &[nnz])?;
    let kw = get_f64(s, "keypoints.weight", &[nnz])?;
    if kptr.windows(2).any(|w| w[0] > w[1]) || kv.iter().any(|&v| v as usize >= h.n_vertices) {
        return Err(bad("keypoints: inconsistent storage".into()));
    }
    let rows = kptr
        .windows(2)
        .map(|w| {
            (w[0] as usize..w[1] as usize)
                .map(|i| (kv[i], kw[i]))
                .collect()
        })
        .collect();
    Ok(rows)
}

/// `K_LB + K_AB − 2`: the body coefficients the MLPs see (without the two mean coefficients).
fn body_mlp_len(blocks: &[ComponentBlock]) -> usize {
    (blocks[0].n_components() + blocks[3].n_components()).saturating_sub(2)
}

fn get_u32(s: &TensorStore, name: &str, shape: &[usize]) -> Result<Vec<u32>> {
    Ok(s.u32_tensor(name, shape)?.to_vec())
}

fn get_f32(s: &TensorStore, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
    Ok(s.f32_tensor(name, shape)?.to_vec())
}

fn get_f64(s: &TensorStore, name: &str, shape: &[usize]) -> Result<Vec<f64>> {
    Ok(s.f64_tensor(name, shape)?.to_vec())
}

/// Per-topology evaluator of a model: topology tables, `g`'s factorizations and workspace, and
/// the factored normal equations of the β encoder. Build once per loaded model.
pub struct Evaluator {
    /// The model (shared: evaluators of one model share it).
    pub model: Arc<PanoManModel>,
    /// Topology of the template (shared by the evaluators of one model).
    pub topo: Arc<Topology>,
    rec: Arc<Reconstructor>,
    ws: GWorkspace,
    /// Joint least-squares encoders for the RL blocks (0..3) and the RA blocks (3..6).
    encoders: [BlockEncoder; 2],
}

/// `min_β ‖A β − (x − X̄)‖² + ridge‖β‖²` over the three blocks of one quantity, where `A`
/// (E × ΣK) scatters each block's sparse components onto its edge columns. The normal matrix
/// `AᵀA + ridge·I` is dense (ΣK ≤ a few hundred) and factored once.
#[derive(Clone)]
struct BlockEncoder {
    blocks: [usize; 3],
    offsets: [usize; 4],
    llt: Option<faer::linalg::solvers::Llt<f64>>,
}

impl Evaluator {
    /// Builds the evaluator (topology, g's factorizations, encoder normal equations).
    pub fn new(model: Arc<PanoManModel>) -> Result<Self> {
        let topo = Topology::build(model.n_vertices, &model.faces)?;
        let rec = Reconstructor::new(&topo)?;
        Self::with_kernel(model, Arc::new(topo), Arc::new(rec))
    }

    /// The per-topology part (tables and g's factorizations), to build another evaluator of a
    /// model with the same template without redoing it ([`Evaluator::with_kernel`]).
    pub fn into_kernel(self) -> (Arc<Topology>, Arc<Reconstructor>) {
        (self.topo, self.rec)
    }

    /// An evaluator from an existing per-topology kernel (see [`Evaluator::into_kernel`]);
    /// only the encoder's normal equations are built.
    pub fn with_kernel(
        model: Arc<PanoManModel>,
        topo: Arc<Topology>,
        rec: Arc<Reconstructor>,
    ) -> Result<Self> {
        if topo.n_vertices != model.n_vertices || topo.faces != model.faces {
            return Err(ModelError::Invalid(
                "evaluator kernel of another topology than the model's".into(),
            ));
        }
        let ws = rec.workspace();
        let encoders = [
            BlockEncoder::new(&model, [0, 1, 2], topo.n_edges())?,
            BlockEncoder::new(&model, [3, 4, 5], topo.n_edges())?,
        ];
        Ok(Self {
            model,
            topo,
            rec,
            ws,
            encoders,
        })
    }

    /// `B_P(α, β)` (Eq. 5): the posed vertices, placed like `B_S(α)` (g's gauge taken from
    /// the rest shape), then rotated and translated by the parameters' rigid motion.
    pub fn pose(&mut self, params: &Params, correction: bool) -> Result<Vec<V3>> {
        let rest = self.model.rest_shape(&params.alpha);
        let rla = self.model.rla(params, correction);
        let mut out = self.reconstruct(&rest, &rla)?;
        let r = panoman_mesh::rotation::from_rotation_vector(params.rotation);
        for x in out.iter_mut() {
            *x = add(matvec(&r, *x), params.translation);
        }
        Ok(out)
    }

    /// `g(RL, RA, rest)` with the gauge of `rest`.
    pub fn reconstruct(&mut self, rest: &[V3], rla: &Rla) -> Result<Vec<V3>> {
        let rg = RestGeometry::new(&self.topo, rest)?;
        let gauge = self.rec.gauge_from(rest)?;
        let mut out = vec![[0.0; 3]; self.topo.n_vertices];
        self.rec
            .reconstruct_rla(&mut self.ws, &rg, rla, &gauge, &mut out)?;
        Ok(out)
    }

    /// Encodes a registered mesh (template topology): α from `rest` when given (the PCA
    /// projection of the identity's rest shape), else the projection of `mesh` itself;
    /// β by joint least squares on its RL and RA w.r.t. `B_S(α)` (per quantity over its three
    /// blocks). With `correction`, β is refined by fixed-point iterations
    /// `β ← LS(x − R(β))` so that `X̄ + Mβ + R(β)` matches the mesh's RLA.
    pub fn encode(&self, mesh: &[V3], rest: Option<&[V3]>, correction: bool) -> Result<Params> {
        for (what, p) in [("mesh", Some(mesh)), ("rest mesh", rest)] {
            if let Some(p) = p
                && p.len() != self.model.n_vertices
            {
                return Err(ModelError::Invalid(format!(
                    "{what} has {} vertices, the model's {} topology has {}",
                    p.len(),
                    self.model.topology_name,
                    self.model.n_vertices
                )));
            }
        }
        let flat = |p: &[V3]| -> Vec<f64> { p.iter().flatten().copied().collect() };
        let alpha = self.model.shape.project(&flat(rest.unwrap_or(mesh)));
        let rest_shape = self.model.rest_shape(&alpha);
        let rg = RestGeometry::new(&self.topo, &rest_shape)?;
        let x = Rla::compute(&self.topo, &rg, mesh)?;
        let mut params = Params {
            alpha,
            ..Default::default()
        };
        self.encode_beta(&x, &mut params, None)?;
        if correction && self.model.correction.is_some() {
            for _ in 0..3 {
                let r = self
                    .model
                    .correction_residual(&params)
                    .expect("has correction");
                self.encode_beta(&x, &mut params, Some(&r))?;
            }
        }
        Ok(params)
    }

    /// Least-squares β of an RLA (optionally minus a body-column residual `r` laid out as
    /// [`PanoManModel::correction_residual`]), written into `params.beta`.
    pub fn encode_beta(&self, x: &Rla, params: &mut Params, r: Option<&[f32]>) -> Result<()> {
        use rayon::prelude::*;
        let m = &*self.model;
        // The RL and RA encoders are independent: one rayon task each.
        let betas = self
            .encoders
            .par_iter()
            .enumerate()
            .map(|(q, enc)| {
                let data = if q == 0 { &x.rl } else { &x.ra };
                let mut target = data.clone();
                if let Some(r) = r {
                    let (blk, off) = if q == 0 {
                        (&m.blocks[0], 0)
                    } else {
                        (&m.blocks[3], m.blocks[0].columns.len())
                    };
                    for (j, &e) in blk.columns.iter().enumerate() {
                        target[e as usize] -= r[off + j] as f64;
                    }
                }
                enc.solve(m, &target)
            })
            .collect::<Vec<_>>();
        for (enc, beta) in self.encoders.iter().zip(betas) {
            let beta = beta?;
            for (i, &b) in enc.blocks.iter().enumerate() {
                params.beta.insert(
                    m.blocks[b].name,
                    beta[enc.offsets[i]..enc.offsets[i + 1]].to_vec(),
                );
            }
        }
        Ok(())
    }

    /// The topology of the model's template.
    pub fn topology(&self) -> &Topology {
        &self.topo
    }
}

impl Clone for Evaluator {
    /// Another evaluator of the same model sharing its topology tables and `g`'s
    /// factorizations (only the per-call workspace is new).
    fn clone(&self) -> Self {
        Evaluator {
            model: self.model.clone(),
            topo: self.topo.clone(),
            rec: self.rec.clone(),
            ws: self.rec.workspace(),
            encoders: self.encoders.clone(),
        }
    }
}

impl BlockEncoder {
    fn new(model: &PanoManModel, blocks: [usize; 3], n_edges: usize) -> Result<Self> {
        let mut offsets = [0usize; 4];
        for i in 0..3 {
            offsets[i + 1] = offsets[i] + model.blocks[blocks[i]].n_components();
        }
        let kt = offsets[3];
        if kt == 0 {
            return Ok(Self {
                blocks,
                offsets,
                llt: None,
            });
        }
        // Per edge, the (global component, value) pairs of all three blocks.
        let mut per_edge: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n_edges];
        for (i, &b) in blocks.iter().enumerate() {
            let blk = &model.blocks[b];
            for k in 0..blk.n_components() {
                let (cols, vals) = blk.components.row(k);
                for (&j, &v) in cols.iter().zip(vals) {
                    per_edge[blk.columns[j as usize] as usize]
                        .push(((offsets[i] + k) as u32, v as f64));
                }
            }
        }
        let mut n = Mat::<f64>::zeros(kt, kt);
        for list in &per_edge {
            for &(a, va) in list {
                for &(b, vb) in list {
                    n[(a as usize, b as usize)] += va * vb;
                }
            }
        }
        let trace: f64 = (0..kt).map(|i| n[(i, i)]).sum();
        let ridge = 1e-9 * trace / kt as f64 + 1e-300;
        for i in 0..kt {
            n[(i, i)] += ridge;
        }
        let llt = n
            .llt(Side::Lower)
            .map_err(|e| ModelError::Numerical(format!("encoder normal matrix: {e:?}")))?;
        Ok(Self {
            blocks,
            offsets,
            llt: Some(llt),
        })
    }

    fn solve(&self, model: &PanoManModel, target: &[f64]) -> Result<Vec<f64>> {
        let kt = self.offsets[3];
        let Some(llt) = &self.llt else {
            return Ok(Vec::new());
        };
        // rhs = Aᵀ (x − Σ means).
        let mut resid = target.to_vec();
        for &b in &self.blocks {
            let blk = &model.blocks[b];
            for (j, &e) in blk.columns.iter().enumerate() {
                resid[e as usize] -= blk.mean[j] as f64;
            }
        }
        let mut rhs = Mat::<f64>::zeros(kt, 1);
        for (i, &b) in self.blocks.iter().enumerate() {
            let blk = &model.blocks[b];
            for k in 0..blk.n_components() {
                let (cols, vals) = blk.components.row(k);
                let mut s = 0.0;
                for (&j, &v) in cols.iter().zip(vals) {
                    s += v as f64 * resid[blk.columns[j as usize] as usize];
                }
                rhs[(self.offsets[i] + k, 0)] = s;
            }
        }
        use faer::linalg::solvers::Solve;
        let sol = llt.solve(&rhs);
        let beta: Vec<f64> = (0..kt).map(|i| sol[(i, 0)]).collect();
        if beta.iter().any(|b| !b.is_finite()) {
            return Err(ModelError::Numerical(
                "encoder produced non-finite β".into(),
            ));
        }
        Ok(beta)
    }
}

/// Whether `path` is a safetensors file whose metadata mark it as a panoman dataset
/// (`"format": "panoman-dataset"`, see `panoman_human::dataset`). Reads the header only (at
/// most 1 MiB); any read or parse failure is `false` (the model loader then reports it).
fn is_dataset_file(path: &Path) -> bool {
    use std::io::Read;
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let mut len = [0u8; 8];
    if f.read_exact(&mut len).is_err() {
        return false;
    }
    let len = u64::from_le_bytes(len);
    if len > 1 << 20 {
        return false;
    }
    let mut header = vec![0u8; len as usize];
    if f.read_exact(&mut header).is_err() {
        return false;
    }
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(&header) else {
        return false;
    };
    v.get("__metadata__")
        .and_then(|m| m.get("format"))
        .and_then(serde_json::Value::as_str)
        == Some(panoman_human::dataset::FORMAT)
}
