//! Sparse localized decomposition of per-edge scalar data (docs/design/splocs-model.md §3; PanoMan §4.2,
//! SPLOCS of Neumann et al. 2013 rewritten for scalars).
//!
//! Data: X ∈ ℝ^{N×M}, one row per sample (RL or RA of the M edges of a part mask, docs/design/splocs-model.md §3.2), f32.
//! After centring and scaling, X ← s·(X − X̄) with s = 1/std(X) (docs/design/splocs-model.md §3.2), the decomposition solves
//! (docs/design/splocs-model.md §3.1)
//!
//! ```text
//! min_{W,C}  ½‖X − W C‖²_F + Σ_k Σ_e Λ_{k,e} |C_{k,e}|,   W ∈ 𝒲,  C ∈ ℝ^{K×M}
//! Λ_{k,e} = λ · clamp((d(e, centre_k) − d_min,k) / (d_max,k − d_min,k), 0, 1)
//! ```
//!
//! by alternating a weight update (block coordinate descent with the Gram trick, docs/design/splocs-model.md §3.6) and a
//! component update (ADMM with a K×K Cholesky, docs/design/splocs-model.md §3.7), from a greedy initialization that never
//! forms the residual (docs/design/splocs-model.md §3.5), with adaptive support radii (docs/design/splocs-model.md §3.4), a residual-free objective
//! (docs/design/splocs-model.md §3.8) and re-seeding of dead components (docs/design/splocs-model.md §3.8). The model of a sample is
//! `x ≈ X̄ + Σ_k β_k C_k` with the training β = rows of W: the `X̄ + M·β` terms of the RLA model
//! (PanoMan Eq. 2–8 as in docs/design/shell-fit.md §2.1; X̄ is PanoMan's X̄_{YZ}, M = Cᵀ).
//!
//! Numerics (docs/design/rla-and-g.md §1, docs/design/splocs-model.md §3.9): X stays f32; every product with X is computed
//! in f64 on column panels of X converted on the fly (faer GEMM, `Par::rayon(0)`), so Gram
//! matrices, objectives and the ADMM state are f64-accurate. All reductions use fixed chunks
//! summed in order, so the output is bit-identical for the same input, independent of the
//! number of threads. The algorithm has no random choice (argmax ties go to the lowest index).
//!
//! The ADMM solve `C = (WᵀW + ρI)⁻¹(F + ρ(Z − U))` (docs/design/splocs-model.md §3.7) uses the f64 Cholesky factor of the
//! K×K matrix to form its explicit inverse once per outer iteration, then applies it as a GEMM
//! against the M columns: cond(WᵀW + ρI) ≤ 1 + λ_max(WᵀW)/ρ is small, so this is as accurate as
//! two triangular solves and measured 2.4× faster (K = 250, M = 40,000).
//!
//! Memory: X (4·N·M bytes) plus eight K×M f64 arrays (C, Z, U, F = WᵀX, two scratch, Λ and the
//! distance maps): measured peak RSS 1.37 GB for N = 4000, M = 40,000, K = 250 (plus the
//! caller's copy of X when [`fit`] is used instead of [`fit_col_major`]).

use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

mod kernels;
mod output;
mod solver;

pub use kernels::objective_residual_free;
pub use output::{BlockEncoder, Decomposition, IterationRecord, SparseRows};
pub use solver::{fit, fit_col_major};

/// Columns per task in element-wise passes and reductions over K×M arrays. Fixed, so that
/// reductions (summed chunk by chunk, in order) do not depend on the thread count (docs/design/splocs-model.md §3.9).
const COL_CHUNK: usize = 256;

/// Distances between the columns of the data (edges of a part), used for the support maps Λ
/// (docs/design/splocs-model.md §3.1, §3.3, §3.4). [`crate::geodesic::PartGeodesics`] is the mesh implementation.
pub trait ColumnDistances: Sync {
    /// Per-thread scratch space of a query.
    type Workspace: Send;
    /// Number of columns M.
    fn n_columns(&self) -> usize;
    /// A fresh workspace.
    fn new_workspace(&self) -> Self::Workspace;
    /// `out[j]` = distance from column `centre` to column `j` (`out[centre] = 0`), exact
    /// where ≤ `max_radius` and +∞ elsewhere (+∞ is allowed everywhere beyond the radius).
    /// `out.len() == self.n_columns()`.
    fn distances_from(
        &self,
        centre: usize,
        max_radius: f64,
        ws: &mut Self::Workspace,
        out: &mut [f64],
    );
}

/// Normalization of the weight columns W[:,k] after each update (docs/design/splocs-model.md §3.6). Whenever a column is
/// divided by m, the component row C_k (and the ADMM state) is multiplied by m, so W·C is
/// unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum WeightNorm {
    /// Option (b), recommended for centred RLA data: divide by max|W[:,k]|, so W ∈ [−1, 1].
    MaxAbs,
    /// Option (a), the SPLOCS reference: clip to W ≥ 0, then divide by max, so W ∈ [0, 1].
    NonNegMax,
}

/// Options of [`fit`] (docs/design/splocs-model.md §3.1, §3.4, §3.7, §3.8). Distances are in the units of the
/// [`ColumnDistances`] provider (meters on V̄ for [`crate::geodesic::PartGeodesics`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SplocsOptions {
    /// Number of components K (PanoMan: 250 body, 100 face, 50 hand).
    pub n_components: usize,
    /// Sparsity weight λ of the scaled problem (docs/design/splocs-model.md §3.1; reference default 2).
    pub lambda: f64,
    /// ADMM penalty ρ (docs/design/splocs-model.md §3.7; reference default 10).
    pub rho: f64,
    /// ADMM iterations per outer iteration (docs/design/splocs-model.md §3.7; default 10).
    pub admm_iters: usize,
    /// Cap on outer iterations (docs/design/splocs-model.md §3.8; 30–50).
    pub max_outer_iters: usize,
    /// Stop when an outer iteration decreases the objective by less than this, relatively
    /// (docs/design/splocs-model.md §3.8; 1e−4), and the supports did not change.
    pub rel_tol: f64,
    /// Bounds `[lo, hi]` of the support radius r_k = d_min,k (docs/design/splocs-model.md §3.4; body [0.04, 0.30] m,
    /// face and hand [0.005, 0.05] m).
    pub d_min_bounds: [f64; 2],
    /// d_max,k = ratio · d_min,k (docs/design/splocs-model.md §3.4: 4; the reference code uses 7).
    pub d_max_ratio: f64,
    /// Weight normalization (docs/design/splocs-model.md §3.6); default [`WeightNorm::MaxAbs`].
    pub weight_norm: WeightNorm,
    /// Safeguard the weight update (default true): when dividing W[:,k] by m > 1 would raise
    /// the objective (the ℓ1 penalty of C_k grows by (m − 1)·Σ_e Λ|C_k,e|, to first order in
    /// m − 1, while the fit gains only to second order), take the box-projected column
    /// clip(u, −1, 1) instead (projected BCD on W ∈ [−1, 1]^N). This makes every outer
    /// iteration non-increasing (docs/design/splocs-model.md §3.8). With false, the plain option-(a)/(b) step is always
    /// taken and the objective can rise slightly from one iteration to the next.
    pub monotone_weights: bool,
    /// Adapt centres and radii after the C updates (docs/design/splocs-model.md §3.4).
    pub adapt_supports: bool,
    /// Supports adapt, and dead components are re-seeded, only after outer iterations
    /// `t < adapt_until`; afterwards the problem is fixed and the objective decreases
    /// monotonically to convergence.
    pub adapt_until: usize,
    /// Initial radius at seeding: the smallest r at which the mean |corr| between the seed
    /// column and the columns at distance ≈ r drops below this (docs/design/splocs-model.md §3.4; 0.5).
    pub init_corr_threshold: f64,
    /// Radius growth factor when more than `far_fraction` of ‖C_k‖² lies beyond
    /// 0.8·d_max,k (docs/design/splocs-model.md §3.4; 1.25 and 0.05).
    pub grow_factor: f64,
    /// See `grow_factor`.
    pub far_fraction: f64,
    /// Radius shrink factor when `near_fraction` of ‖C_k‖² lies within 0.5·d_min,k
    /// (docs/design/splocs-model.md §3.4; 0.8 and 0.95).
    pub shrink_factor: f64,
    /// See `shrink_factor`.
    pub near_fraction: f64,
    /// A centre moves to argmax_e |C_k,e| only if that exceeds |C_k| at the old centre by this
    /// fraction (docs/design/splocs-model.md §3.4; 0.1).
    pub centre_hysteresis: f64,
    /// A component with ‖C_k‖² ≤ this (scaled units) is dead (docs/design/splocs-model.md §3.6, §3.8; 1e−12).
    pub dead_tol: f64,
}

/// Default d_min bounds of the body decomposition, meters (docs/design/splocs-model.md §3.4).
pub const BODY_D_MIN_BOUNDS: [f64; 2] = [0.04, 0.30];
/// Default d_min bounds of the face and hand decompositions, meters (docs/design/splocs-model.md §3.4).
pub const SMALL_PART_D_MIN_BOUNDS: [f64; 2] = [0.005, 0.05];

impl SplocsOptions {
    /// The defaults of docs/design/splocs-model.md §3 (λ = 2, ρ = 10, 10 ADMM iterations, 40 outer iterations, rel_tol
    /// 1e−4, d_max = 4·d_min, option (b), adaptive supports for 20 iterations) for K components
    /// and the given d_min bounds.
    pub fn new(n_components: usize, d_min_bounds: [f64; 2]) -> SplocsOptions {
        SplocsOptions {
            n_components,
            lambda: 2.0,
            rho: 10.0,
            admm_iters: 10,
            max_outer_iters: 40,
            rel_tol: 1e-4,
            d_min_bounds,
            d_max_ratio: 4.0,
            weight_norm: WeightNorm::MaxAbs,
            monotone_weights: true,
            adapt_supports: true,
            adapt_until: 20,
            init_corr_threshold: 0.5,
            grow_factor: 1.25,
            far_fraction: 0.05,
            shrink_factor: 0.8,
            near_fraction: 0.95,
            centre_hysteresis: 0.1,
            dead_tol: 1e-12,
        }
    }

    fn validate(&self) -> Result<()> {
        let bad = |what: &str| Err(ModelError::Invalid(format!("splocs options: {what}")));
        let [lo, hi] = self.d_min_bounds;
        if self.n_components == 0 {
            return bad("n_components must be ≥ 1");
        }
        if !(self.lambda.is_finite() && self.lambda >= 0.0) {
            return bad("lambda must be finite and ≥ 0");
        }
        if !(self.rho.is_finite() && self.rho > 0.0) {
            return bad("rho must be finite and > 0");
        }
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo <= hi) {
            return bad("d_min_bounds must satisfy 0 < lo ≤ hi");
        }
        if !(self.d_max_ratio.is_finite() && self.d_max_ratio > 1.0) {
            return bad("d_max_ratio must be > 1");
        }
        if !(self.grow_factor >= 1.0 && self.shrink_factor > 0.0 && self.shrink_factor <= 1.0) {
            return bad("grow_factor must be ≥ 1 and shrink_factor in (0, 1]");
        }
        if !(self.dead_tol >= 0.0 && self.rel_tol >= 0.0) {
            return bad("dead_tol and rel_tol must be ≥ 0");
        }
        Ok(())
    }
}

/// Soft-thresholding, the proximal map of t·|·| (docs/design/splocs-model.md §3.1):
/// `argmin_z ½(z − y)² + t|z| = sign(y)·max(|y| − t, 0)` for t ≥ 0.
#[inline]
pub fn soft_threshold(y: f64, t: f64) -> f64 {
    if y > t {
        y - t
    } else if y < -t {
        y + t
    } else {
        0.0
    }
}

/// Parts of the objective of docs/design/splocs-model.md §3.1 in scaled units: `fit = ½‖X − WC‖²_F`,
/// `penalty = Σ Λ|C|`, `total = fit + penalty`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectiveParts {
    /// ½‖X − WC‖²_F.
    pub fit: f64,
    /// Σ_k Σ_e Λ_{k,e}|C_{k,e}|.
    pub penalty: f64,
    /// fit + penalty.
    pub total: f64,
}

/// What [`update_weights_gram`] did: the factor m_k each column was divided by (multiply C_k
/// and the ADMM state by it), dead columns, and how many columns took the safeguarded step.
#[derive(Clone, Debug, Default)]
pub struct WeightStep {
    /// Per component k, the factor W[:,k] was divided by (1 for dead columns).
    pub scale: Vec<f64>,
    /// Per component, whether it is dead (G_kk ≤ dead_tol, or the new column is 0); W[:,k] = 0.
    pub dead: Vec<bool>,
    /// Columns where the plain normalized step would have increased the objective and the
    /// box-projected step was taken instead.
    pub safeguarded: usize,
}

/// Weight update by block coordinate descent with the Gram trick (docs/design/splocs-model.md §3.6), in place.
///
/// Inputs (all column-major f64): W (N×K), P = X·Cᵀ (N×K), G = C·Cᵀ (K×K). For each k:
/// `u = (P[:,k] − Σ_{j≠k} W[:,j]·G[j,k]) / G_kk` is the exact minimizer of ½‖X − WC‖² over
/// W[:,k] (never forming the N×M residual), then it is normalized by `norm` to W[:,k] = u'/m;
/// P[:,k], G[k,:] and G[:,k] are multiplied by m so that they describe the rescaled C_k = m·C_k,
/// which the caller must apply (with the ADMM state) from the returned `scale`.
///
/// Safeguard (when `penalty` = Σ_e Λ_{k,e}|C_{k,e}| per component is given): the exact change
/// of the objective, `½G_kk(‖u' − u‖² − ‖w_old − u‖²) + (m − 1)·penalty_k`, is evaluated; if it
/// is positive, the box-projected column (u clipped to [−1, 1], or [0, 1] for option (a)) is
/// used instead, which never increases the objective when w_old lies in the box. With
/// `penalty = None` the plain normalized step is always taken.
///
/// Panics on inconsistent slice lengths.
#[allow(clippy::too_many_arguments)]
pub fn update_weights_gram(
    w: &mut [f64],
    p: &mut [f64],
    g: &mut [f64],
    n: usize,
    k: usize,
    norm: WeightNorm,
    penalty: Option<&[f64]>,
    dead_tol: f64,
) -> WeightStep {
    assert_eq!(w.len(), n * k);
    assert_eq!(p.len(), n * k);
    assert_eq!(g.len(), k * k);
    if let Some(pen) = penalty {
        assert_eq!(pen.len(), k);
    }
    let mut step = WeightStep {
        scale: vec![1.0; k],
        dead: vec![false; k],
        safeguarded: 0,
    };
    let mut b = vec![0.0f64; n];
    for kk in 0..k {
        let gkk = g[kk * k + kk];
        if gkk <= dead_tol {
            w[kk * n..(kk + 1) * n].fill(0.0);
            step.dead[kk] = true;
            continue;
        }
        b.copy_from_slice(&p[kk * n..(kk + 1) * n]);
        for j in 0..k {
            let gjk = g[kk * k + j]; // G[j,k] (column kk of the column-major G)
            if j == kk || gjk == 0.0 {
                continue;
            }
            let wj = &w[j * n..(j + 1) * n];
            for (bi, &wi) in b.iter_mut().zip(wj) {
                *bi -= gjk * wi;
            }
        }
        let inv = 1.0 / gkk;
        for bi in b.iter_mut() {
            *bi *= inv; // b is now u
        }
        let u = &b;
        let wk = &mut w[kk * n..(kk + 1) * n];
        let (lo, proj): (f64, fn(f64) -> f64) = match norm {
            WeightNorm::MaxAbs => (-1.0, |x| x),
            WeightNorm::NonNegMax => (0.0, |x: f64| x.max(0.0)),
        };
        // Candidate 1: projection onto the sign constraint, then scale to max 1.
        let mut m = 0.0f64;
        let mut d_new = 0.0f64;
        let mut d_old = 0.0f64;
        for (&ui, &wi) in u.iter().zip(wk.iter()) {
            let v = proj(ui);
            m = m.max(v.abs());
            d_new += (v - ui) * (v - ui);
            d_old += (wi - ui) * (wi - ui);
        }
        let mut use_box = false;
        if let Some(pen) = penalty {
            let delta = 0.5 * gkk * (d_new - d_old) + (m - 1.0) * pen[kk];
            if delta > 0.0 {
                use_box = true;
            }
        }
        if use_box {
            step.safeguarded += 1;
            m = 0.0;
            for (wi, &ui) in wk.iter_mut().zip(u) {
                *wi = ui.clamp(lo, 1.0);
                m = m.max(wi.abs());
            }
        } else {
            for (wi, &ui) in wk.iter_mut().zip(u) {
                *wi = proj(ui);
            }
        }
        if m <= 0.0 || !m.is_finite() {
            wk.fill(0.0);
            step.dead[kk] = true;
            continue;
        }
        let inv_m = 1.0 / m;
        for wi in wk.iter_mut() {
            *wi *= inv_m;
        }
        step.scale[kk] = m;
        for pi in &mut p[kk * n..(kk + 1) * n] {
            *pi *= m;
        }
        for j in 0..k {
            g[kk * k + j] *= m; // column kk
            g[j * k + kk] *= m; // row kk (G_kk gets m²)
        }
    }
    step
}
