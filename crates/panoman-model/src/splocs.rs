//! Sparse localized decomposition of per-edge scalar data (algorithms.md §3; PanoMan §4.2,
//! SPLOCS of Neumann et al. 2013 rewritten for scalars).
//!
//! Data: X ∈ ℝ^{N×M}, one row per sample (RL or RA of the M edges of a part mask, §3.2), f32.
//! After centring and scaling, X ← s·(X − X̄) with s = 1/std(X) (§3.2), the decomposition solves
//! (§3.1)
//!
//! ```text
//! min_{W,C}  ½‖X − W C‖²_F + Σ_k Σ_e Λ_{k,e} |C_{k,e}|,   W ∈ 𝒲,  C ∈ ℝ^{K×M}
//! Λ_{k,e} = λ · clamp((d(e, centre_k) − d_min,k) / (d_max,k − d_min,k), 0, 1)
//! ```
//!
//! by alternating a weight update (block coordinate descent with the Gram trick, §3.6) and a
//! component update (ADMM with a K×K Cholesky, §3.7), from a greedy initialization that never
//! forms the residual (§3.5), with adaptive support radii (§3.4), a residual-free objective
//! (§3.8) and re-seeding of dead components (§3.8). The model of a sample is
//! `x ≈ X̄ + Σ_k β_k C_k` with the training β = rows of W: the `X̄ + M·β` terms of the RLA model
//! (PanoMan Eq. 2–8 as in algorithms.md §4.1; X̄ is PanoMan's X̄_{YZ}, M = Cᵀ).
//!
//! Numerics (algorithms.md §0, §6 items 11–12): X stays f32; every product with X is computed
//! in f64 on column panels of X converted on the fly (faer GEMM, `Par::rayon(0)`), so Gram
//! matrices, objectives and the ADMM state are f64-accurate. All reductions use fixed chunks
//! summed in order, so the output is bit-identical for the same input, independent of the
//! number of threads. The algorithm has no random choice (argmax ties go to the lowest index).
//!
//! The ADMM solve `C = (WᵀW + ρI)⁻¹(F + ρ(Z − U))` (§3.7) uses the f64 Cholesky factor of the
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

/// Columns per task in element-wise passes and reductions over K×M arrays. Fixed, so that
/// reductions (summed chunk by chunk, in order) do not depend on the thread count (§6 item 15).
const COL_CHUNK: usize = 256;

/// Distances between the columns of the data (edges of a part), used for the support maps Λ
/// (§3.1, §3.3, §3.4). [`crate::geodesic::PartGeodesics`] is the mesh implementation.
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

/// Normalization of the weight columns W[:,k] after each update (§3.6). Whenever a column is
/// divided by m, the component row C_k (and the ADMM state) is multiplied by m, so W·C is
/// unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum WeightNorm {
    /// Option (b), recommended for centred RLA data: divide by max|W[:,k]|, so W ∈ [−1, 1].
    MaxAbs,
    /// Option (a), the SPLOCS reference: clip to W ≥ 0, then divide by max, so W ∈ [0, 1].
    NonNegMax,
}

/// Options of [`fit`] (algorithms.md §3.1, §3.4, §3.7, §3.8). Distances are in the units of the
/// [`ColumnDistances`] provider (meters on V̄ for [`crate::geodesic::PartGeodesics`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SplocsOptions {
    /// Number of components K (PanoMan: 250 body, 100 face, 50 hand).
    pub n_components: usize,
    /// Sparsity weight λ of the scaled problem (§3.1; reference default 2).
    pub lambda: f64,
    /// ADMM penalty ρ (§3.7; reference default 10).
    pub rho: f64,
    /// ADMM iterations per outer iteration (§3.7; default 10).
    pub admm_iters: usize,
    /// Cap on outer iterations (§3.8; 30–50).
    pub max_outer_iters: usize,
    /// Stop when an outer iteration decreases the objective by less than this, relatively
    /// (§3.8; 1e−4), and the supports did not change.
    pub rel_tol: f64,
    /// Bounds `[lo, hi]` of the support radius r_k = d_min,k (§3.4; body [0.04, 0.30] m,
    /// face and hand [0.005, 0.05] m).
    pub d_min_bounds: [f64; 2],
    /// d_max,k = ratio · d_min,k (§3.4: 4; the reference code uses 7).
    pub d_max_ratio: f64,
    /// Weight normalization (§3.6); default [`WeightNorm::MaxAbs`].
    pub weight_norm: WeightNorm,
    /// Safeguard the weight update (default true): when dividing W[:,k] by m > 1 would raise
    /// the objective (the ℓ1 penalty of C_k grows by (m − 1)·Σ_e Λ|C_k,e|, to first order in
    /// m − 1, while the fit gains only to second order), take the box-projected column
    /// clip(u, −1, 1) instead (projected BCD on W ∈ [−1, 1]^N). This makes every outer
    /// iteration non-increasing (§3.8). With false, the plain option-(a)/(b) step is always
    /// taken and the objective can rise slightly from one iteration to the next.
    pub monotone_weights: bool,
    /// Adapt centres and radii after the C updates (§3.4).
    pub adapt_supports: bool,
    /// Supports adapt, and dead components are re-seeded, only after outer iterations
    /// `t < adapt_until`; afterwards the problem is fixed and the objective decreases
    /// monotonically to convergence.
    pub adapt_until: usize,
    /// Initial radius at seeding: the smallest r at which the mean |corr| between the seed
    /// column and the columns at distance ≈ r drops below this (§3.4; 0.5).
    pub init_corr_threshold: f64,
    /// Radius growth factor when more than `far_fraction` of ‖C_k‖² lies beyond
    /// 0.8·d_max,k (§3.4; 1.25 and 0.05).
    pub grow_factor: f64,
    /// See `grow_factor`.
    pub far_fraction: f64,
    /// Radius shrink factor when `near_fraction` of ‖C_k‖² lies within 0.5·d_min,k
    /// (§3.4; 0.8 and 0.95).
    pub shrink_factor: f64,
    /// See `shrink_factor`.
    pub near_fraction: f64,
    /// A centre moves to argmax_e |C_k,e| only if that exceeds |C_k| at the old centre by this
    /// fraction (§3.4; 0.1).
    pub centre_hysteresis: f64,
    /// A component with ‖C_k‖² ≤ this (scaled units) is dead (§3.6, §3.8; 1e−12).
    pub dead_tol: f64,
}

/// Default d_min bounds of the body decomposition, meters (§3.4).
pub const BODY_D_MIN_BOUNDS: [f64; 2] = [0.04, 0.30];
/// Default d_min bounds of the face and hand decompositions, meters (§3.4).
pub const SMALL_PART_D_MIN_BOUNDS: [f64; 2] = [0.005, 0.05];

impl SplocsOptions {
    /// The defaults of §3 (λ = 2, ρ = 10, 10 ADMM iterations, 40 outer iterations, rel_tol
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

/// Soft-thresholding, the proximal map of t·|·| (§3.1):
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

/// Parts of the objective of §3.1 in scaled units: `fit = ½‖X − WC‖²_F`,
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

/// Weight update by block coordinate descent with the Gram trick (§3.6), in place.
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

// ---------------------------------------------------------------------------------------------
// Dense kernels on column-major slices.

fn panel_width(n: usize) -> usize {
    ((1usize << 21) / n.max(1)).clamp(16, 2048)
}

/// Converts columns `j0..j0+jb` of the f32 N×M matrix into the f64 panel buffer.
fn load_panel(x: &[f32], n: usize, j0: usize, jb: usize, buf: &mut [f64]) {
    buf[..n * jb]
        .par_chunks_mut(n)
        .zip(x[j0 * n..(j0 + jb) * n].par_chunks(n))
        .for_each(|(b, s)| {
            for (bi, &si) in b.iter_mut().zip(s) {
                *bi = si as f64;
            }
        });
}

/// out (K×M) = Wᵀ·X, with X f32 N×M converted to f64 panel by panel.
fn wt_x(x: &[f32], n: usize, m: usize, w: &[f64], k: usize, out: &mut [f64], buf: &mut Vec<f64>) {
    let nb = panel_width(n).min(m.max(1));
    buf.resize(n * nb, 0.0);
    let wv = MatRef::from_column_major_slice(w, n, k);
    for j0 in (0..m).step_by(nb) {
        let jb = nb.min(m - j0);
        load_panel(x, n, j0, jb, buf);
        let xp = MatRef::from_column_major_slice(&buf[..n * jb], n, jb);
        let dst = MatMut::from_column_major_slice_mut(&mut out[j0 * k..(j0 + jb) * k], k, jb);
        matmul(dst, Accum::Replace, wv.transpose(), xp, 1.0, Par::rayon(0));
    }
}

/// out (N×K) = X·Cᵀ, accumulated over panels of X in a fixed order.
fn x_ct(x: &[f32], n: usize, m: usize, c: &[f64], k: usize, out: &mut [f64], buf: &mut Vec<f64>) {
    let nb = panel_width(n).min(m.max(1));
    buf.resize(n * nb, 0.0);
    out.fill(0.0);
    for j0 in (0..m).step_by(nb) {
        let jb = nb.min(m - j0);
        load_panel(x, n, j0, jb, buf);
        let xp = MatRef::from_column_major_slice(&buf[..n * jb], n, jb);
        let cp = MatRef::from_column_major_slice(&c[j0 * k..(j0 + jb) * k], k, jb);
        let dst = MatMut::from_column_major_slice_mut(out, n, k);
        let acc = if j0 == 0 { Accum::Replace } else { Accum::Add };
        matmul(dst, acc, xp, cp.transpose(), 1.0, Par::rayon(0));
    }
}

/// out[e] = X[:,e]ᵀ·v in f64 (GEMV over the f32 data, 4 accumulators, fixed order).
fn xt_vec(x: &[f32], n: usize, v: &[f64], out: &mut [f64]) {
    out.par_chunks_mut(64).enumerate().for_each(|(ci, oc)| {
        for (jj, o) in oc.iter_mut().enumerate() {
            let j = ci * 64 + jj;
            let col = &x[j * n..(j + 1) * n];
            let mut acc = [0.0f64; 4];
            let mut it = col.chunks_exact(4).zip(v.chunks_exact(4));
            for (cx, cv) in &mut it {
                acc[0] += cx[0] as f64 * cv[0];
                acc[1] += cx[1] as f64 * cv[1];
                acc[2] += cx[2] as f64 * cv[2];
                acc[3] += cx[3] as f64 * cv[3];
            }
            let r = n - n % 4;
            let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
            for i in r..n {
                s += col[i] as f64 * v[i];
            }
            *o = s;
        }
    });
}

/// AᵀA (cols×cols) of a column-major rows×cols matrix.
fn gram_of_cols(a: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut g = vec![0.0; cols * cols];
    let av = MatRef::from_column_major_slice(a, rows, cols);
    matmul(
        MatMut::from_column_major_slice_mut(&mut g, cols, cols),
        Accum::Replace,
        av.transpose(),
        av,
        1.0,
        Par::rayon(0),
    );
    g
}

/// C·Cᵀ (K×K) of a column-major K×M matrix.
fn gram_of_rows(c: &[f64], k: usize, m: usize) -> Vec<f64> {
    let mut g = vec![0.0; k * k];
    let cv = MatRef::from_column_major_slice(c, k, m);
    matmul(
        MatMut::from_column_major_slice_mut(&mut g, k, k),
        Accum::Replace,
        cv,
        cv.transpose(),
        1.0,
        Par::rayon(0),
    );
    g
}

/// Σ_i a_i·b_i over two equally long slices, in fixed chunks summed in order.
fn dot_chunked(a: &[f64], b: &[f64]) -> f64 {
    const CH: usize = 1 << 14;
    a.par_chunks(CH)
        .zip(b.par_chunks(CH))
        .map(|(x, y)| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

/// Per component k, Σ_e Λ_{k,e}|C_{k,e}| (K×M column-major inputs).
fn penalties(lam: &[f64], c: &[f64], k: usize) -> Vec<f64> {
    let parts: Vec<Vec<f64>> = lam
        .par_chunks(COL_CHUNK * k)
        .zip(c.par_chunks(COL_CHUNK * k))
        .map(|(l, cc)| {
            let mut acc = vec![0.0f64; k];
            for (lc, ccol) in l.chunks_exact(k).zip(cc.chunks_exact(k)) {
                for ((a, &li), &ci) in acc.iter_mut().zip(lc).zip(ccol) {
                    *a += li * ci.abs();
                }
            }
            acc
        })
        .collect();
    let mut out = vec![0.0f64; k];
    for p in parts {
        for (o, v) in out.iter_mut().zip(p) {
            *o += v;
        }
    }
    out
}

/// ½‖X‖² − ⟨W, P⟩ + ½⟨WᵀW, G⟩ (the fit term of §3.8 without the residual).
fn fit_from_p(x_sq: f64, w: &[f64], p: &[f64], a0: &[f64], g: &[f64]) -> f64 {
    let wp: f64 = w.iter().zip(p).map(|(a, b)| a * b).sum();
    let ag: f64 = a0.iter().zip(g).map(|(a, b)| a * b).sum();
    0.5 * x_sq - wp + 0.5 * ag
}

/// Lower Cholesky factor (row-major n×n) of the symmetric matrix whose lower triangle is
/// read from the column-major `a`. Err(i) if the i-th pivot is not positive.
fn cholesky(a: &[f64], n: usize) -> std::result::Result<Vec<f64>, usize> {
    let mut l = vec![0.0f64; n * n];
    for i in 0..n {
        for j in 0..=i {
            // a is column-major: A[i,j] = a[j*n + i] with i ≥ j (lower triangle).
            let mut s = a[j * n + i];
            for t in 0..j {
                s -= l[i * n + t] * l[j * n + t];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 || !s.is_finite() {
                    return Err(i);
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    Ok(l)
}

/// Solves L·Lᵀ·x = b in place (L row-major lower from [`cholesky`]).
fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for t in 0..i {
            s -= l[i * n + t] * b[t];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for t in i + 1..n {
            s -= l[t * n + i] * b[t];
        }
        b[i] = s / l[i * n + i];
    }
}

/// Inverse (column-major, symmetric) of the SPD matrix with Cholesky factor `l`.
fn cholesky_inverse(l: &[f64], n: usize) -> Vec<f64> {
    let mut inv = vec![0.0f64; n * n];
    let mut col = vec![0.0f64; n];
    for j in 0..n {
        col.fill(0.0);
        col[j] = 1.0;
        cholesky_solve(l, n, &mut col);
        inv[j * n..(j + 1) * n].copy_from_slice(&col);
    }
    // Exact symmetry (the two triangles can differ in the last bit).
    for j in 0..n {
        for i in j + 1..n {
            let v = 0.5 * (inv[j * n + i] + inv[i * n + j]);
            inv[j * n + i] = v;
            inv[i * n + j] = v;
        }
    }
    inv
}

/// Objective of §3.1 without forming the residual (§3.8):
/// `½(‖X‖² − 2⟨W, X·Cᵀ⟩ + ⟨WᵀW, C·Cᵀ⟩) + Σ Λ|C|`.
///
/// `x`: N×M f32, `w`: N×K f64, `c` and `lam`: K×M f64, all column-major. Products with X are
/// computed in f64 (panel conversion), so the value agrees with the explicit residual to f64
/// rounding.
///
/// Panics on inconsistent slice lengths.
pub fn objective_residual_free(
    x: &[f32],
    n: usize,
    m: usize,
    w: &[f64],
    c: &[f64],
    lam: &[f64],
    k: usize,
) -> ObjectiveParts {
    assert_eq!(x.len(), n * m);
    assert_eq!(w.len(), n * k);
    assert_eq!(c.len(), k * m);
    assert_eq!(lam.len(), k * m);
    let x_sq: f64 = x
        .par_chunks(1 << 16)
        .map(|ch| ch.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    let mut p = vec![0.0; n * k];
    let mut buf = Vec::new();
    x_ct(x, n, m, c, k, &mut p, &mut buf);
    let a0 = gram_of_cols(w, n, k);
    let g = gram_of_rows(c, k, m);
    let fit = fit_from_p(x_sq, w, &p, &a0, &g);
    let penalty: f64 = penalties(lam, c, k).iter().sum();
    ObjectiveParts {
        fit,
        penalty,
        total: fit + penalty,
    }
}

// ---------------------------------------------------------------------------------------------
// Output types.

/// Sparse K×M matrix stored by rows (CSR) with f32 values: the components C (§3.9, "make C
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

/// One outer iteration of [`fit`] (objective values in scaled units, §3.8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
    /// Outer iteration t (0-based).
    pub iteration: usize,
    /// Objective entering the iteration (current W, C, Λ).
    pub objective_start: f64,
    /// Objective after the weight update (§3.6).
    pub objective_after_weights: f64,
    /// Objective after the component update (§3.7): ≤ the two values above.
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
    /// Components whose centre or radius changed after this iteration (§3.4).
    pub support_changes: usize,
    /// Components re-seeded after this iteration (§3.8).
    pub reseeded: usize,
    /// Wall time of the iteration, seconds.
    pub seconds: f64,
}

/// Result of [`fit`]: the model `x ≈ mean + Σ_k β_k·components_k` of one part (§3.1, §3.2;
/// the `X̄ + M·β` term of algorithms.md §4.1 with X̄ = `mean`, M_L or M_A = `components`ᵀ).
#[derive(Clone, Debug)]
pub struct Decomposition {
    /// X̄: the per-column mean of the training data (unscaled).
    pub mean: Vec<f32>,
    /// s = 1/std(X − X̄): the scaling of the problem (λ acts in scaled units). The stored
    /// components are already divided by s.
    pub scale: f64,
    /// W (N×K): the training coefficients β of each sample (rows), normalized per §3.6.
    pub weights: Mat<f32>,
    /// C (K×M) in data units (C_scaled / s), sparse.
    pub components: SparseRows,
    /// Centre column of each component (§3.4).
    pub centres: Vec<u32>,
    /// `[d_min, d_max]` of each component's support (§3.4).
    pub radii: Vec<[f64; 2]>,
    /// One record per outer iteration.
    pub history: Vec<IterationRecord>,
    /// 1 − ‖X − WC‖²/‖X‖² on the training data.
    pub explained_variance: f64,
    /// Per component, ‖W[:,k]‖²·‖C_k‖² / ‖X‖² (energy of the component alone).
    pub component_energy: Vec<f64>,
    /// Seconds spent in the greedy initialization (§3.5).
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
    pub fn encoder(&self, ridge: f64) -> Result<Encoder> {
        Encoder::new(self, ridge)
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
pub struct Encoder {
    mean: Vec<f32>,
    components: SparseRows,
    chol: Vec<f64>,
}

impl Encoder {
    /// Factors `C·Cᵀ + ridge·I` (ridge ≥ 0, in data units squared).
    ///
    /// Errors: negative/non-finite ridge, or a singular Gram matrix (collinear components with
    /// ridge 0: pass a small ridge).
    pub fn new(dec: &Decomposition, ridge: f64) -> Result<Encoder> {
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
        Ok(Encoder {
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

// ---------------------------------------------------------------------------------------------
// The solver.

struct Solver<'a, D: ColumnDistances> {
    n: usize,
    m: usize,
    k: usize,
    opts: &'a SplocsOptions,
    dists: &'a D,
    /// Centred, scaled data, N×M column-major.
    x: Vec<f32>,
    /// ‖X[:,e]‖².
    col_sq: Vec<f64>,
    x_sq: f64,
    /// N×K.
    w: Vec<f64>,
    /// K×M: components, ADMM Z and U, F = WᵀX, two scratch arrays, Λ.
    c: Vec<f64>,
    z: Vec<f64>,
    u: Vec<f64>,
    f: Vec<f64>,
    t: Vec<f64>,
    s: Vec<f64>,
    lam: Vec<f64>,
    /// K×M row-major (component k's distance map at k·M).
    dist: Vec<f64>,
    /// P = X·Cᵀ (N×K), G = C·Cᵀ, A0 = WᵀW (K×K), penalties per component.
    p: Vec<f64>,
    g: Vec<f64>,
    a0: Vec<f64>,
    pen: Vec<f64>,
    centre: Vec<usize>,
    radius: Vec<f64>,
    buf: Vec<f64>,
}

impl<'a, D: ColumnDistances> Solver<'a, D> {
    fn d_max(&self, kk: usize) -> f64 {
        self.opts.d_max_ratio * self.radius[kk]
    }

    /// Distance cap of the cached maps: the largest possible d_max.
    fn dist_cap(&self) -> f64 {
        self.opts.d_max_ratio * self.opts.d_min_bounds[1]
    }

    fn ramp(d: f64, dmin: f64, dmax: f64) -> f64 {
        if d.is_nan() {
            1.0
        } else {
            ((d - dmin) / (dmax - dmin)).clamp(0.0, 1.0)
        }
    }

    /// Rewrites row k of Λ from the distance map and radius of component k.
    fn write_lambda_row(&mut self, kk: usize) {
        let (dmin, dmax) = (self.radius[kk], self.d_max(kk));
        let (k, m, lam) = (self.k, self.m, self.opts.lambda);
        let row = &self.dist[kk * m..(kk + 1) * m];
        for (e, &d) in row.iter().enumerate() {
            self.lam[e * k + kk] = lam * Self::ramp(d, dmin, dmax);
        }
    }

    fn recompute_pen(&mut self) {
        self.pen = penalties(&self.lam, &self.c, self.k);
    }

    fn recompute_a0(&mut self) {
        self.a0 = gram_of_cols(&self.w, self.n, self.k);
    }

    /// Objective entering a W update: P, G, A0 and pen must be current.
    fn objective_from_p(&self) -> (f64, f64) {
        let fit = fit_from_p(self.x_sq, &self.w, &self.p, &self.a0, &self.g);
        (fit, fit + self.pen.iter().sum::<f64>())
    }

    /// Residual column energies ‖X_e − W·C_e‖² = ‖X_e‖² − 2F_eᵀC_e + C_eᵀA0C_e (§3.5),
    /// with F = WᵀX and A0 = WᵀW current. Uses `t` as scratch.
    fn residual_energies(&mut self) -> Vec<f64> {
        let (k, m) = (self.k, self.m);
        let a0v = MatRef::from_column_major_slice(&self.a0, k, k);
        matmul(
            MatMut::from_column_major_slice_mut(&mut self.t, k, m),
            Accum::Replace,
            a0v,
            MatRef::from_column_major_slice(&self.c, k, m),
            1.0,
            Par::rayon(0),
        );
        let (c, f, t, col_sq) = (&self.c, &self.f, &self.t, &self.col_sq);
        let mut en = vec![0.0f64; m];
        en.par_chunks_mut(COL_CHUNK)
            .enumerate()
            .for_each(|(ci, ec)| {
                for (jj, o) in ec.iter_mut().enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    let r = e * k..(e + 1) * k;
                    let mut s = col_sq[e];
                    for ((&cv, &fv), &tv) in c[r.clone()].iter().zip(&f[r.clone()]).zip(&t[r]) {
                        s += cv * (tv - 2.0 * fv);
                    }
                    *o = s.max(0.0);
                }
            });
        en
    }

    /// Smallest radius r (geometric grid over the d_min bounds, ratio 1.1) at which the mean
    /// |corr| between the seed column and the columns at distance ≈ r drops below the
    /// threshold (§3.4); `hi` if it never does.
    fn initial_radius(&self, dist_row: &[f64], corr: &[f64]) -> f64 {
        let [lo, hi] = self.opts.d_min_bounds;
        if hi <= lo {
            return lo;
        }
        let gamma: f64 = 1.1;
        let ln_g = gamma.ln();
        let nb = ((hi / lo).ln() / ln_g).floor() as usize + 1;
        let mut sum = vec![0.0f64; nb];
        let mut cnt = vec![0usize; nb];
        for (&d, &c) in dist_row.iter().zip(corr) {
            if d.is_nan() || d <= 0.0 || !d.is_finite() || c.is_nan() {
                continue;
            }
            let b = ((d / lo).ln() / ln_g).round();
            if b < 0.0 || b >= nb as f64 {
                continue;
            }
            sum[b as usize] += c.abs();
            cnt[b as usize] += 1;
        }
        for b in 0..nb {
            if cnt[b] > 0 && sum[b] / (cnt[b] as f64) < self.opts.init_corr_threshold {
                return (lo * gamma.powi(b as i32)).min(hi);
            }
        }
        hi
    }

    /// Greedy seeding of component `kk` at the max-residual column (§3.5): w = the residual
    /// column, normalized (§3.6); c = (wᵀR ⊙ (1 − support)) / (wᵀw). Row kk of W, C, U must
    /// be zero. Updates `en` (residual column energies) incrementally. False if the residual
    /// is zero.
    fn seed(&mut self, kk: usize, en: &mut [f64], ws: &mut D::Workspace) -> bool {
        let (n, m, k) = (self.n, self.m, self.k);
        // argmax, ties to the lowest index.
        let mut idx = 0;
        for (e, &v) in en.iter().enumerate() {
            if v > en[idx] {
                idx = e;
            }
        }
        if en[idx].is_nan() || en[idx] <= 1e-300 {
            return false;
        }
        // r = X_idx − W·C_idx.
        let mut r: Vec<f64> = self.x[idx * n..(idx + 1) * n]
            .iter()
            .map(|&v| v as f64)
            .collect();
        for j in 0..k {
            let cj = self.c[idx * k + j];
            if cj != 0.0 {
                for (ri, &wi) in r.iter_mut().zip(&self.w[j * n..(j + 1) * n]) {
                    *ri -= cj * wi;
                }
            }
        }
        let r_sq: f64 = r.iter().map(|v| v * v).sum();
        if r_sq.is_nan() || r_sq <= 1e-300 {
            return false;
        }
        // g_e = R_eᵀ r = (Xᵀr)_e − C_eᵀ(Wᵀr).
        let mut g = vec![0.0f64; m];
        let wr = self.wt_vec(&r);
        xt_vec(&self.x, n, &r, &mut g);
        self.sub_ct_vec(&wr, &mut g);

        // Distances from the seed, initial radius from correlations (§3.4).
        let cap = self.dist_cap();
        {
            let row = &mut self.dist[kk * m..(kk + 1) * m];
            self.dists.distances_from(idx, cap, ws, row);
        }
        let corr: Vec<f64> = g
            .iter()
            .zip(en.iter())
            .map(|(&gv, &ev)| {
                if ev > 1e-300 {
                    gv / (r_sq * ev).sqrt()
                } else {
                    f64::NAN
                }
            })
            .collect();
        let r0 = self.initial_radius(&self.dist[kk * m..(kk + 1) * m], &corr);
        self.radius[kk] = r0;
        self.centre[kk] = idx;
        self.write_lambda_row(kk);

        // Normalized weight column and wᵀR.
        let (w, gw) = match self.opts.weight_norm {
            WeightNorm::MaxAbs => {
                let mx = r.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
                let w: Vec<f64> = r.iter().map(|&v| v / mx).collect();
                let gw: Vec<f64> = g.iter().map(|&v| v / mx).collect();
                (w, gw)
            }
            WeightNorm::NonNegMax => {
                let pmax = r.iter().fold(0.0f64, |a, &v| a.max(v));
                let nmax = r.iter().fold(0.0f64, |a, &v| a.max(-v));
                let sgn = if nmax > pmax { -1.0 } else { 1.0 };
                let mx = pmax.max(nmax);
                let w: Vec<f64> = r.iter().map(|&v| (sgn * v).max(0.0) / mx).collect();
                let wr = self.wt_vec(&w);
                let mut gw = vec![0.0f64; m];
                xt_vec(&self.x, n, &w, &mut gw);
                self.sub_ct_vec(&wr, &mut gw);
                (w, gw)
            }
        };
        let ww: f64 = w.iter().map(|v| v * v).sum();
        if ww.is_nan() || ww <= 0.0 {
            return false;
        }
        let (dmin, dmax) = (self.radius[kk], self.d_max(kk));
        for e in 0..m {
            let mask = 1.0 - Self::ramp(self.dist[kk * m + e], dmin, dmax);
            let ce = gw[e] * mask / ww;
            self.c[e * k + kk] = ce;
            self.u[e * k + kk] = 0.0;
            en[e] = (en[e] - 2.0 * ce * gw[e] + ce * ce * ww).max(0.0);
        }
        self.w[kk * n..(kk + 1) * n].copy_from_slice(&w);
        true
    }

    /// Wᵀv (length K).
    fn wt_vec(&self, v: &[f64]) -> Vec<f64> {
        let n = self.n;
        (0..self.k)
            .map(|j| {
                self.w[j * n..(j + 1) * n]
                    .iter()
                    .zip(v)
                    .map(|(a, b)| a * b)
                    .sum()
            })
            .collect()
    }

    /// out_e −= C_eᵀ·v for every column e.
    fn sub_ct_vec(&self, v: &[f64], out: &mut [f64]) {
        let k = self.k;
        let c = &self.c;
        out.par_chunks_mut(COL_CHUNK)
            .enumerate()
            .for_each(|(ci, oc)| {
                for (jj, o) in oc.iter_mut().enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    let s: f64 = c[e * k..(e + 1) * k]
                        .iter()
                        .zip(v)
                        .map(|(a, b)| a * b)
                        .sum();
                    *o -= s;
                }
            });
    }

    /// Scales row k of C and U by `scale[k]` (after a weight normalization, §3.6).
    fn rescale_rows(&mut self, scale: &[f64]) {
        let k = self.k;
        let f = |arr: &mut Vec<f64>| {
            arr.par_chunks_mut(COL_CHUNK * k).for_each(|ch| {
                for col in ch.chunks_exact_mut(k) {
                    for (v, &s) in col.iter_mut().zip(scale) {
                        *v *= s;
                    }
                }
            })
        };
        f(&mut self.c);
        f(&mut self.u);
    }

    /// Component update by ADMM (§3.7), safeguarded: the result replaces C only if it does not
    /// increase the objective. Requires A0 = WᵀW current; computes F = WᵀX. Returns
    /// (objective, fit, rejected).
    fn c_step(&mut self, obj_before: f64) -> Result<(f64, f64, bool)> {
        let (n, m, k) = (self.n, self.m, self.k);
        let rho = self.opts.rho;
        wt_x(&self.x, n, m, &self.w, k, &mut self.f, &mut self.buf);
        let mut a = self.a0.clone();
        for i in 0..k {
            a[i * k + i] += rho;
        }
        let l = cholesky(&a, k).map_err(|i| {
            ModelError::Numerical(format!(
                "splocs: WᵀW + ρI is not positive definite (pivot {i})"
            ))
        })?;
        let ainv = cholesky_inverse(&l, k);
        let ainv = MatRef::from_column_major_slice(&ainv, k, k);
        self.z.copy_from_slice(&self.c);
        let cs = COL_CHUNK * k;
        let inv_rho = 1.0 / rho;
        // T = F + ρ(Z − U)
        {
            let (f, z, u) = (&self.f, &self.z, &self.u);
            self.t.par_chunks_mut(cs).enumerate().for_each(|(ci, tc)| {
                let o = ci * cs;
                for (i, tv) in tc.iter_mut().enumerate() {
                    *tv = f[o + i] + rho * (z[o + i] - u[o + i]);
                }
            });
        }
        for _ in 0..self.opts.admm_iters {
            // S = (WᵀW + ρI)⁻¹ T
            matmul(
                MatMut::from_column_major_slice_mut(&mut self.s, k, m),
                Accum::Replace,
                ainv,
                MatRef::from_column_major_slice(&self.t, k, m),
                1.0,
                Par::rayon(0),
            );
            // Z = soft(S + U, Λ/ρ), U = U + S − Z, and the next T = F + ρ(Z − U), fused.
            {
                let (s, lam, f) = (&self.s, &self.lam, &self.f);
                self.z
                    .par_chunks_mut(cs)
                    .zip(self.u.par_chunks_mut(cs))
                    .zip(self.t.par_chunks_mut(cs))
                    .enumerate()
                    .for_each(|(ci, ((zc, uc), tc))| {
                        let o = ci * cs;
                        for (i, ((zv, uv), tv)) in zc
                            .iter_mut()
                            .zip(uc.iter_mut())
                            .zip(tc.iter_mut())
                            .enumerate()
                        {
                            let v = s[o + i] + *uv;
                            let zz = soft_threshold(v, lam[o + i] * inv_rho);
                            let un = v - zz;
                            *zv = zz;
                            *uv = un;
                            *tv = f[o + i] + rho * (zz - un);
                        }
                    });
            }
        }
        // Candidate C = Z (exactly sparse).
        let g_new = gram_of_rows(&self.z, k, m);
        let fz = dot_chunked(&self.f, &self.z);
        let ag: f64 = self.a0.iter().zip(&g_new).map(|(a, b)| a * b).sum();
        let fit_new = 0.5 * self.x_sq - fz + 0.5 * ag;
        let pen_new = penalties(&self.lam, &self.z, k);
        let obj_new = fit_new + pen_new.iter().sum::<f64>();
        if obj_new <= obj_before {
            std::mem::swap(&mut self.c, &mut self.z);
            self.g = g_new;
            self.pen = pen_new;
            Ok((obj_new, fit_new, false))
        } else {
            let fit_old = obj_before - self.pen.iter().sum::<f64>();
            Ok((obj_before, fit_old, true))
        }
    }

    /// Adaptive supports (§3.4): radius growth/shrink from the energy distribution of C_k, and
    /// centre moves with hysteresis. Returns the number of components that changed.
    fn update_supports(&mut self, ws_pool: &mut Vec<D::Workspace>) -> usize {
        let (m, k) = (self.m, self.k);
        let o = self.opts;
        let [lo, hi] = o.d_min_bounds;
        struct Change {
            kk: usize,
            centre: usize,
            radius: f64,
            moved: bool,
        }
        let c = &self.c;
        let dist = &self.dist;
        let centre = &self.centre;
        let radius = &self.radius;
        let changes: Vec<Change> = (0..k)
            .into_par_iter()
            .filter_map(|kk| {
                let row = &dist[kk * m..(kk + 1) * m];
                let (dmin, dmax) = (radius[kk], o.d_max_ratio * radius[kk]);
                let (mut tot, mut far, mut near) = (0.0f64, 0.0f64, 0.0f64);
                let mut best = 0usize;
                let mut best_v = -1.0f64;
                for (e, &d) in row.iter().enumerate() {
                    let v = c[e * k + kk];
                    let v2 = v * v;
                    tot += v2;
                    if d.is_nan() || d > 0.8 * dmax {
                        far += v2;
                    } else if d <= 0.5 * dmin {
                        near += v2;
                    }
                    if v.abs() > best_v {
                        best_v = v.abs();
                        best = e;
                    }
                }
                if tot.is_nan() || tot <= o.dead_tol {
                    return None;
                }
                let mut r = radius[kk];
                if far > o.far_fraction * tot {
                    r *= o.grow_factor;
                } else if near >= o.near_fraction * tot {
                    r *= o.shrink_factor;
                }
                let r = r.clamp(lo, hi);
                let old_v = c[centre[kk] * k + kk].abs();
                let moved = best != centre[kk] && best_v > (1.0 + o.centre_hysteresis) * old_v;
                if moved || r != radius[kk] {
                    Some(Change {
                        kk,
                        centre: if moved { best } else { centre[kk] },
                        radius: r,
                        moved,
                    })
                } else {
                    None
                }
            })
            .collect();
        if changes.is_empty() {
            return 0;
        }
        // Recompute the distance maps of moved components (parallel, one workspace per task).
        let cap = self.dist_cap();
        let moved: Vec<(usize, usize)> = changes
            .iter()
            .filter(|ch| ch.moved)
            .map(|ch| (ch.kk, ch.centre))
            .collect();
        if !moved.is_empty() {
            let dists = self.dists;
            let mut rows: Vec<(usize, &mut [f64])> = self
                .dist
                .chunks_mut(m)
                .enumerate()
                .filter(|(kk, _)| moved.iter().any(|&(mk, _)| mk == *kk))
                .collect();
            while ws_pool.len() < rayon::current_num_threads().max(1) {
                ws_pool.push(dists.new_workspace());
            }
            let per = rows.len().div_ceil(ws_pool.len());
            rows.par_chunks_mut(per)
                .zip(ws_pool.par_iter_mut())
                .for_each(|(group, ws)| {
                    for (kk, row) in group.iter_mut() {
                        let ctr = moved.iter().find(|&&(mk, _)| mk == *kk).unwrap().1;
                        dists.distances_from(ctr, cap, ws, row);
                    }
                });
        }
        for ch in &changes {
            self.centre[ch.kk] = ch.centre;
            self.radius[ch.kk] = ch.radius;
        }
        // Λ rows of the changed components, written in one pass over the columns.
        let lam_v = o.lambda;
        let rows: Vec<(usize, f64, f64)> = changes
            .iter()
            .map(|ch| (ch.kk, ch.radius, o.d_max_ratio * ch.radius))
            .collect();
        let dist = &self.dist;
        self.lam
            .par_chunks_mut(COL_CHUNK * k)
            .enumerate()
            .for_each(|(ci, lc)| {
                for (jj, col) in lc.chunks_exact_mut(k).enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    for &(kk, dmin, dmax) in &rows {
                        col[kk] = lam_v * Self::ramp(dist[kk * m + e], dmin, dmax);
                    }
                }
            });
        changes.len()
    }

    /// Re-seeds dead components (‖C_k‖² ≤ dead_tol) at the max-residual column (§3.8).
    /// Requires F = WᵀX and A0 = WᵀW current. Returns how many were re-seeded.
    fn reseed_dead(&mut self, ws: &mut D::Workspace) -> usize {
        let (n, k) = (self.n, self.k);
        let dead: Vec<usize> = (0..k)
            .filter(|&kk| {
                self.g[kk * k + kk] <= self.opts.dead_tol
                    || self.w[kk * n..(kk + 1) * n].iter().all(|&v| v == 0.0)
            })
            .collect();
        if dead.is_empty() {
            return 0;
        }
        for &kk in &dead {
            self.w[kk * n..(kk + 1) * n].fill(0.0);
            for e in 0..self.m {
                self.c[e * k + kk] = 0.0;
                self.u[e * k + kk] = 0.0;
            }
        }
        let mut en = self.residual_energies();
        let mut count = 0;
        for &kk in &dead {
            if self.seed(kk, &mut en, ws) {
                count += 1;
            }
        }
        count
    }
}

/// Sparse localized decomposition of `x` (N×M, rows = samples, columns = part edges), §3.
/// Copies X; see [`fit_col_major`] to hand over a buffer instead.
pub fn fit<D: ColumnDistances>(
    x: MatRef<'_, f32>,
    dists: &D,
    opts: &SplocsOptions,
) -> Result<Decomposition> {
    let (n, m) = (x.nrows(), x.ncols());
    let mut data = Vec::with_capacity(n * m);
    for j in 0..m {
        data.extend(x.col(j).iter().copied());
    }
    fit_col_major(data, n, dists, opts, |_| {})
}

/// Sparse localized decomposition (§3.1–3.8) of the N×M data given column-major in `x`
/// (`x[j·N + i]` = sample i, column j), consumed to avoid a copy. `progress` is called after
/// every outer iteration.
///
/// Steps: centre and scale (§3.2); greedy initialization without the residual (§3.5); then
/// per outer iteration: weight update by BCD with the Gram trick and normalization (§3.6),
/// component update by ADMM (§3.7), residual-free objective (§3.8), support adaptation (§3.4)
/// and re-seeding of dead components (§3.8), until the relative decrease is below `rel_tol`
/// or `max_outer_iters`. Finally C ← C/s, stored sparse.
///
/// Deterministic: no random choice is made (the greedy seeds are argmaxes, ties to the lowest
/// index), and all reductions use fixed chunks, so the same input gives bit-identical output
/// for any number of rayon threads. There is therefore no `seed` option.
///
/// Errors: sizes (N < 2, M = 0, `x.len() != N·M`, distance provider with another M), invalid
/// options, non-finite or constant data, or a failed factorization.
pub fn fit_col_major<D: ColumnDistances>(
    mut x: Vec<f32>,
    n: usize,
    dists: &D,
    opts: &SplocsOptions,
    mut progress: impl FnMut(&IterationRecord),
) -> Result<Decomposition> {
    let t_total = Instant::now();
    opts.validate()?;
    if n < 2 {
        return Err(ModelError::Invalid(
            "splocs: need at least 2 samples".into(),
        ));
    }
    if x.is_empty() || !x.len().is_multiple_of(n) {
        return Err(ModelError::Invalid(format!(
            "splocs: data length {} is not a positive multiple of N = {n}",
            x.len()
        )));
    }
    let m = x.len() / n;
    if dists.n_columns() != m {
        return Err(ModelError::Invalid(format!(
            "splocs: the distance provider has {} columns, the data {m}",
            dists.n_columns()
        )));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Invalid(
            "splocs: non-finite value in the data".into(),
        ));
    }
    let k = opts.n_components;

    // §3.2: centre and scale.
    let mean: Vec<f32> = x
        .par_chunks(n)
        .map(|col| (col.iter().map(|&v| v as f64).sum::<f64>() / n as f64) as f32)
        .collect();
    x.par_chunks_mut(n).zip(&mean).for_each(|(col, &mu)| {
        for v in col.iter_mut() {
            *v -= mu;
        }
    });
    let ss: f64 = x
        .par_chunks(n * 16)
        .map(|ch| ch.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    let std = (ss / (n * m) as f64).sqrt();
    if std.is_nan() || std <= 0.0 {
        return Err(ModelError::Invalid("splocs: the data are constant".into()));
    }
    // s rounded to f32 first, so that the stored scale is exactly the one applied to X.
    let sf = (1.0 / std) as f32;
    let scale = sf as f64;
    x.par_chunks_mut(1 << 16).for_each(|ch| {
        for v in ch {
            *v *= sf;
        }
    });
    let col_sq: Vec<f64> = x
        .par_chunks(n)
        .map(|col| col.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
        .collect();
    let x_sq: f64 = col_sq.chunks(1024).map(|c| c.iter().sum::<f64>()).sum();

    let km = k * m;
    let mut sv = Solver {
        n,
        m,
        k,
        opts,
        dists,
        x,
        col_sq,
        x_sq,
        w: vec![0.0; n * k],
        c: vec![0.0; km],
        z: vec![0.0; km],
        u: vec![0.0; km],
        f: vec![0.0; km],
        t: vec![0.0; km],
        s: vec![0.0; km],
        lam: vec![opts.lambda; km],
        dist: vec![f64::INFINITY; km],
        p: vec![0.0; n * k],
        g: vec![0.0; k * k],
        a0: vec![0.0; k * k],
        pen: vec![0.0; k],
        centre: vec![0; k],
        radius: vec![opts.d_min_bounds[0]; k],
        buf: Vec::new(),
    };

    // §3.5: greedy initialization.
    let t_init = Instant::now();
    let mut ws = dists.new_workspace();
    let mut en = sv.col_sq.clone();
    for kk in 0..k {
        sv.seed(kk, &mut en, &mut ws);
    }
    let init_seconds = t_init.elapsed().as_secs_f64();

    let mut ws_pool = vec![ws];
    let mut history = Vec::new();
    // Invariants entering an iteration: P = X·Cᵀ, G = C·Cᵀ, pen current.
    sv.g = gram_of_rows(&sv.c, k, m);
    x_ct(&sv.x, n, m, &sv.c, k, &mut sv.p, &mut sv.buf);
    sv.recompute_pen();
    sv.recompute_a0();
    let mut obj_start = sv.objective_from_p().1;

    for it in 0..opts.max_outer_iters {
        let t_it = Instant::now();
        // §3.6 weight update.
        let step = update_weights_gram(
            &mut sv.w,
            &mut sv.p,
            &mut sv.g,
            n,
            k,
            opts.weight_norm,
            opts.monotone_weights.then_some(&sv.pen[..]),
            opts.dead_tol,
        );
        sv.rescale_rows(&step.scale);
        for (pk, &s) in sv.pen.iter_mut().zip(&step.scale) {
            *pk *= s;
        }
        sv.recompute_a0();
        let obj_w = sv.objective_from_p().1;
        // §3.7 component update.
        let (obj, fit_v, rejected) = sv.c_step(obj_w)?;
        let rel = (obj_start - obj) / obj_start.abs().max(f64::MIN_POSITIVE);
        // §3.4 supports and §3.8 dead components.
        let adapt = it < opts.adapt_until && it + 1 < opts.max_outer_iters;
        let support_changes = if adapt && opts.adapt_supports {
            sv.update_supports(&mut ws_pool)
        } else {
            0
        };
        let reseeded = if adapt {
            sv.reseed_dead(&mut ws_pool[0])
        } else {
            0
        };
        let rec = IterationRecord {
            iteration: it,
            objective_start: obj_start,
            objective_after_weights: obj_w,
            objective: obj,
            fit: fit_v,
            penalty: obj - fit_v,
            relative_decrease: rel,
            weight_safeguards: step.safeguarded,
            admm_rejected: rejected,
            support_changes,
            reseeded,
            seconds: 0.0,
        };
        let changed = support_changes > 0 || reseeded > 0;
        let done = (rel < opts.rel_tol && !changed) || it + 1 == opts.max_outer_iters;
        if reseeded > 0 {
            sv.g = gram_of_rows(&sv.c, k, m);
        }
        if changed {
            sv.recompute_pen();
        }
        if !done {
            x_ct(&sv.x, n, m, &sv.c, k, &mut sv.p, &mut sv.buf);
            if changed {
                sv.recompute_a0();
                obj_start = sv.objective_from_p().1;
            } else {
                obj_start = obj;
            }
        }
        let rec = IterationRecord {
            seconds: t_it.elapsed().as_secs_f64(),
            ..rec
        };
        progress(&rec);
        history.push(rec);
        if done {
            break;
        }
    }
    // Final fit ½‖X − WC‖²: the last record's (W and C unchanged since); without iterations,
    // from the Gram formulas.
    let fit_final = match history.last() {
        Some(r) => r.fit,
        None => sv.objective_from_p().0,
    };
    let a0 = gram_of_cols(&sv.w, n, k);
    let explained_variance = 1.0 - 2.0 * fit_final / sv.x_sq;
    let component_energy: Vec<f64> = (0..k)
        .map(|kk| a0[kk * k + kk] * sv.g[kk * k + kk] / sv.x_sq)
        .collect();

    // Output: C / s as sparse rows, W as f32.
    let inv_s = 1.0 / scale;
    let mut row_ptr = Vec::with_capacity(k + 1);
    let mut col_idx = Vec::new();
    let mut values = Vec::new();
    row_ptr.push(0);
    for kk in 0..k {
        for e in 0..m {
            let v = sv.c[e * k + kk];
            if v != 0.0 {
                col_idx.push(e as u32);
                values.push((v * inv_s) as f32);
            }
        }
        row_ptr.push(values.len());
    }
    let weights = Mat::<f32>::from_fn(n, k, |i, j| sv.w[j * n + i] as f32);
    Ok(Decomposition {
        mean,
        scale,
        weights,
        components: SparseRows {
            n_cols: m,
            row_ptr,
            col_idx,
            values,
        },
        centres: sv.centre.iter().map(|&c| c as u32).collect(),
        radii: (0..k)
            .map(|kk| [sv.radius[kk], opts.d_max_ratio * sv.radius[kk]])
            .collect(),
        history,
        explained_variance,
        component_energy,
        init_seconds,
        total_seconds: t_total.elapsed().as_secs_f64(),
    })
}
