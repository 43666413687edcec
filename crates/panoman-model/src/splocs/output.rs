//! Output types of the decomposition: sparse components, iteration records, the encoder.

use super::kernels::{cholesky, cholesky_solve, gram_of_rows};
use super::*;

/// Sparse K×M matrix stored by rows (CSR) with f32 values: the components C (docs/design/splocs-model.md §3.9, "make C
/// sparse"), keeping only the exact non-zeros left by the soft-thresholding.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SparseRows {
    /// Number of columns M.
    pub n_cols: usize,
    /// Row offsets, length K + 1.
    pub row_ptr: Vec<usize>,
    /// Column index of each stored value, ascending within a row.
    pub col_idx: Vec<u32>,
    /// Stored values.
    pub values: Vec<f32>,
}

impl SparseRows {
    /// Number of rows K.
    pub fn n_rows(&self) -> usize {
        self.row_ptr.len() - 1
    }

    /// Number of stored non-zeros.
    pub fn nnz(&self) -> usize {
        self.values.len()
    }

    /// Column indices and values of row `k`.
    pub fn row(&self, k: usize) -> (&[u32], &[f32]) {
        let (s, e) = (self.row_ptr[k], self.row_ptr[k + 1]);
        (&self.col_idx[s..e], &self.values[s..e])
    }

    /// Row `k` as a dense vector of length M.
    pub fn dense_row(&self, k: usize) -> Vec<f32> {
        let mut out = vec![0.0f32; self.n_cols];
        let (idx, val) = self.row(k);
        for (&j, &v) in idx.iter().zip(val) {
            out[j as usize] = v;
        }
        out
    }

    /// `Cᵀ·β` (length M) in f64.
    pub fn transpose_mul(&self, beta: &[f64]) -> Vec<f64> {
        assert_eq!(beta.len(), self.n_rows());
        let mut out = vec![0.0f64; self.n_cols];
        for (k, &b) in beta.iter().enumerate() {
            let (idx, val) = self.row(k);
            for (&j, &v) in idx.iter().zip(val) {
                out[j as usize] += v as f64 * b;
            }
        }
        out
    }

    /// `C·y` (length K) in f64.
    pub fn mul(&self, y: &[f64]) -> Vec<f64> {
        assert_eq!(y.len(), self.n_cols);
        (0..self.n_rows())
            .map(|k| {
                let (idx, val) = self.row(k);
                idx.iter()
                    .zip(val)
                    .map(|(&j, &v)| v as f64 * y[j as usize])
                    .sum()
            })
            .collect()
    }

    /// `C·Cᵀ` (K×K, column-major, f64): a dense f64 GEMM when more than 5 % of the entries
    /// are stored, otherwise accumulated column by column of C (sparse outer products).
    pub fn gram(&self) -> Vec<f64> {
        let k = self.n_rows();
        if self.nnz() as f64 > 0.05 * (k * self.n_cols) as f64 {
            let mut dense = vec![0.0f64; k * self.n_cols];
            for r in 0..k {
                let (idx, val) = self.row(r);
                for (&j, &v) in idx.iter().zip(val) {
                    dense[j as usize * k + r] = v as f64;
                }
            }
            return gram_of_rows(&dense, k, self.n_cols);
        }
        // Column lists (CSC) of the CSR matrix.
        let mut cnt = vec![0usize; self.n_cols + 1];
        for &j in &self.col_idx {
            cnt[j as usize + 1] += 1;
        }
        for j in 0..self.n_cols {
            cnt[j + 1] += cnt[j];
        }
        let mut pos = cnt.clone();
        let mut rows = vec![0u32; self.nnz()];
        let mut vals = vec![0.0f64; self.nnz()];
        for r in 0..k {
            let (idx, val) = self.row(r);
            for (&j, &v) in idx.iter().zip(val) {
                let p = &mut pos[j as usize];
                rows[*p] = r as u32;
                vals[*p] = v as f64;
                *p += 1;
            }
        }
        let mut g = vec![0.0f64; k * k];
        for j in 0..self.n_cols {
            let (s, e) = (cnt[j], cnt[j + 1]);
            for a in s..e {
                let (ra, va) = (rows[a] as usize, vals[a]);
                for b in s..e {
                    g[ra * k + rows[b] as usize] += va * vals[b];
                }
            }
        }
        g
    }
}

/// One outer iteration of [`fit`] (objective values in scaled units, docs/design/splocs-model.md §3.8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
    /// Outer iteration t (0-based).
    pub iteration: usize,
    /// Objective entering the iteration (current W, C, Λ).
    pub objective_start: f64,
    /// Objective after the weight update (docs/design/splocs-model.md §3.6).
    pub objective_after_weights: f64,
    /// Objective after the component update (docs/design/splocs-model.md §3.7): ≤ the two values above.
    pub objective: f64,
    /// ½‖X − WC‖² after the component update.
    pub fit: f64,
    /// Σ Λ|C| after the component update.
    pub penalty: f64,
    /// (objective_start − objective) / |objective_start|.
    pub relative_decrease: f64,
    /// Weight columns that took the safeguarded (box-projected) step.
    pub weight_safeguards: usize,
    /// Whether the ADMM result was rejected because it did not decrease the objective.
    pub admm_rejected: bool,
    /// Components whose centre or radius changed after this iteration (docs/design/splocs-model.md §3.4).
    pub support_changes: usize,
    /// Components re-seeded after this iteration (docs/design/splocs-model.md §3.8).
    pub reseeded: usize,
    /// Wall time of the iteration, seconds.
    pub seconds: f64,
}

/// Result of [`fit`]: the model `x ≈ mean + Σ_k β_k·components_k` of one part (docs/design/splocs-model.md §3.1, §3.2;
/// the `X̄ + M·β` term of docs/design/shell-fit.md §2.1 with X̄ = `mean`, M_L or M_A = `components`ᵀ).
#[derive(Clone, Debug)]
pub struct Decomposition {
    /// X̄: the per-column mean of the training data (unscaled).
    pub mean: Vec<f32>,
    /// s = 1/std(X − X̄): the scaling of the problem (λ acts in scaled units). The stored
    /// components are already divided by s.
    pub scale: f64,
    /// W (N×K): the training coefficients β of each sample (rows), normalized per docs/design/splocs-model.md §3.6.
    pub weights: Mat<f32>,
    /// C (K×M) in data units (C_scaled / s), sparse.
    pub components: SparseRows,
    /// Centre column of each component (docs/design/splocs-model.md §3.4).
    pub centres: Vec<u32>,
    /// `[d_min, d_max]` of each component's support (docs/design/splocs-model.md §3.4).
    pub radii: Vec<[f64; 2]>,
    /// One record per outer iteration.
    pub history: Vec<IterationRecord>,
    /// 1 − ‖X − WC‖²/‖X‖² on the training data.
    pub explained_variance: f64,
    /// Per component, ‖W[:,k]‖²·‖C_k‖² / ‖X‖² (energy of the component alone).
    pub component_energy: Vec<f64>,
    /// Seconds spent in the greedy initialization (docs/design/splocs-model.md §3.5).
    pub init_seconds: f64,
    /// Total seconds of [`fit`].
    pub total_seconds: f64,
}

impl Decomposition {
    /// Number of components K.
    pub fn n_components(&self) -> usize {
        self.components.n_rows()
    }

    /// Number of columns M.
    pub fn n_columns(&self) -> usize {
        self.mean.len()
    }

    /// `X̄ + Cᵀβ` (length M, f64).
    pub fn reconstruct(&self, beta: &[f64]) -> Vec<f64> {
        let mut out = self.components.transpose_mul(beta);
        for (o, &mu) in out.iter_mut().zip(&self.mean) {
            *o += mu as f64;
        }
        out
    }

    /// Least-squares encoder of new samples on the components (see [`Encoder`]).
    pub fn encoder(&self, ridge: f64) -> Result<BlockEncoder> {
        BlockEncoder::new(self, ridge)
    }

    /// β = argmin ‖x − X̄ − Cᵀβ‖² + ridge·‖β‖² (f64 normal equations): projects a held-out
    /// sample onto the model. Builds an [`Encoder`]; keep one for many samples.
    pub fn encode(&self, x: &[f32], ridge: f64) -> Result<Vec<f64>> {
        self.encoder(ridge)?.encode(x)
    }
}

/// Projection of samples onto a decomposition: solves the normal equations
/// `(C·Cᵀ + ridge·I) β = C·(x − X̄)` with a K×K Cholesky factor in f64, built once.
/// Dead components (zero rows of C) get β_k = 0.
#[derive(Clone, Debug)]
pub struct BlockEncoder {
    pub(super) mean: Vec<f32>,
    pub(super) components: SparseRows,
    pub(super) chol: Vec<f64>,
}

impl BlockEncoder {
    /// Factors `C·Cᵀ + ridge·I` (ridge ≥ 0, in data units squared).
    ///
    /// Errors: negative/non-finite ridge, or a singular Gram matrix (collinear components with
    /// ridge 0: pass a small ridge).
    pub fn new(dec: &Decomposition, ridge: f64) -> Result<BlockEncoder> {
        if !(ridge.is_finite() && ridge >= 0.0) {
            return Err(ModelError::Invalid(
                "encoder ridge must be finite and ≥ 0".into(),
            ));
        }
        let k = dec.n_components();
        let mut g = dec.components.gram();
        for i in 0..k {
            if g[i * k + i] == 0.0 {
                g[i * k + i] = 1.0;
            } else {
                g[i * k + i] += ridge;
            }
        }
        let chol = cholesky(&g, k).map_err(|i| {
            ModelError::Numerical(format!(
                "encoder: the component Gram matrix is singular at pivot {i}; use a ridge > 0"
            ))
        })?;
        Ok(BlockEncoder {
            mean: dec.mean.clone(),
            components: dec.components.clone(),
            chol,
        })
    }

    /// β of one sample `x` (length M).
    ///
    /// Errors: wrong length or non-finite values.
    pub fn encode(&self, x: &[f32]) -> Result<Vec<f64>> {
        if x.len() != self.mean.len() {
            return Err(ModelError::Invalid(format!(
                "encode: sample has {} values, the model has {} columns",
                x.len(),
                self.mean.len()
            )));
        }
        if x.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::Invalid(
                "encode: non-finite value in the sample".into(),
            ));
        }
        let y: Vec<f64> = x
            .iter()
            .zip(&self.mean)
            .map(|(&a, &b)| a as f64 - b as f64)
            .collect();
        let mut beta = self.components.mul(&y);
        cholesky_solve(&self.chol, beta.len(), &mut beta);
        Ok(beta)
    }
}
