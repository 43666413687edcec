//! PCA output head of the correction MLP (docs/design/splocs-model.md §5.1): a weighted, centred,
//! randomized SVD of the targets, so the network predicts `r ≈ 128–256` codes instead of 2|E|
//! outputs.

use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{ComputeEigenvectors, self_adjoint_evd, self_adjoint_evd_scratch};
use faer::linalg::householder::{
    apply_block_householder_sequence_on_the_left_in_place_scratch,
    apply_block_householder_sequence_on_the_left_in_place_with_conj,
};
use faer::linalg::matmul::matmul;
use faer::linalg::qr::no_pivoting::factor::{
    qr_in_place, qr_in_place_scratch, recommended_block_size,
};
use faer::{Accum, Conj, Mat, MatMut, MatRef, Par};
use rayon::prelude::*;

use super::gemm::gemm;
use super::rng::Rng;
use crate::error::{ModelError, Result};

/// Random stream of the sketch matrix Ω.
const SKETCH_STREAM: u64 = 0x9ca;
/// Entries per row block of the streamed passes over `Y` (≈ 128 MB of f32).
const BLOCK_ENTRIES: usize = 1 << 25;

/// Options of [`PcaHead::fit`].
#[derive(Clone, Debug, PartialEq)]
pub struct PcaHeadOptions {
    /// Largest rank `r` kept (docs/design/splocs-model.md §5.1: 128–256).
    pub max_rank: usize,
    /// Smallest rank kept.
    pub min_rank: usize,
    /// Keep the smallest `r` whose estimated explained fraction of the weighted variance reaches
    /// this (docs/design/splocs-model.md §5.1: 0.95–0.99); `max_rank` caps it.
    pub target_explained: f64,
    /// Extra sketch columns beyond `max_rank` (Halko, Martinsson & Tropp 2011: 5–20).
    pub oversample: usize,
    /// Power (subspace) iterations, each re-orthonormalized (HMT Alg. 4.4).
    pub power_iters: usize,
    /// Seed of the Gaussian sketch.
    pub seed: u64,
}

impl Default for PcaHeadOptions {
    fn default() -> Self {
        Self {
            max_rank: 256,
            min_rank: 1,
            target_explained: 0.99,
            oversample: 16,
            power_iters: 2,
            seed: 0,
        }
    }
}

/// A weighted PCA output head (docs/design/splocs-model.md §5.1):
///
/// ```text
/// encode:  c = Pᵀ (w ⊙ (y − μ))        (r codes; the MLP is trained on these)
/// decode:  y = μ + (P c) ⊘ w
/// ```
///
/// `w > 0` are per-channel weights (as the fitting energy weighs its residuals: RL × 1,
/// RA × c_B·ω_e), `μ` the mean over the training samples and `P` (`D × r`) an orthonormal basis
/// (`PᵀP = I`) of the dominant subspace of the weighted, centred data `Ỹ = (Y − 1μᵀ) diag(w)`.
/// Because `P` is orthonormal, the squared error of the codes equals the **weighted** squared
/// error of the decoded output inside the span; the weighted residual Jacobian of the decoder is
/// `∂(w ⊙ y)/∂c = P` (docs/design/shell-fit.md §3.2: keep `P·G` factored).
#[derive(Clone, Debug, PartialEq)]
pub struct PcaHead {
    mean: Vec<f32>,
    weights: Vec<f32>,
    basis: Mat<f32>,
    component_variance: Vec<f64>,
    total_variance: f64,
}

/// Result of [`PcaHead::fit`].
#[derive(Clone, Debug)]
pub struct PcaHeadFit {
    /// The head.
    pub head: PcaHead,
    /// Codes of the training samples, `N × r` (`C = Ỹ P`, bit-identical to
    /// [`PcaHead::encode_batch`] on the same `Y`).
    pub codes: Mat<f32>,
    /// Exact fraction of the weighted variance captured, `‖Ỹ P‖²_F / ‖Ỹ‖²_F`.
    pub explained_ratio: f64,
    /// Randomized estimates `σ_i²/N` of the leading component variances (all sketch columns,
    /// descending); the rank was chosen from these.
    pub estimated_spectrum: Vec<f64>,
}

/// Thin Householder QR `A = Q R` (`m ≥ n`), sequential (deterministic), in f64.
fn thin_qr(mut a: Mat<f64>) -> (Mat<f64>, Mat<f64>) {
    let (m, n) = (a.nrows(), a.ncols());
    debug_assert!(m >= n);
    let bs = recommended_block_size::<f64>(m, n);
    let mut coeff = Mat::<f64>::zeros(bs, n);
    {
        let mut mem = MemBuffer::new(qr_in_place_scratch::<f64>(
            m,
            n,
            bs,
            Par::Seq,
            Default::default(),
        ));
        qr_in_place(
            a.as_mut(),
            coeff.as_mut(),
            Par::Seq,
            MemStack::new(&mut mem),
            Default::default(),
        );
    }
    let r = Mat::<f64>::from_fn(n, n, |i, j| if i <= j { a[(i, j)] } else { 0.0 });
    // Householder basis: unit lower trapezoid.
    for j in 0..n {
        for i in 0..j {
            a[(i, j)] = 0.0;
        }
        a[(j, j)] = 1.0;
    }
    let mut q = Mat::<f64>::identity(m, n);
    let mut mem = MemBuffer::new(
        apply_block_householder_sequence_on_the_left_in_place_scratch::<f64>(m, bs, n),
    );
    apply_block_householder_sequence_on_the_left_in_place_with_conj(
        a.as_ref(),
        coeff.as_ref(),
        Conj::No,
        q.as_mut(),
        Par::Seq,
        MemStack::new(&mut mem),
    );
    (q, r)
}

/// Symmetric eigen-decomposition (lower triangle), eigenvalues **descending**, sequential.
fn eigh_desc(a: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>)> {
    let n = a.nrows();
    let mut s = Diag::<f64>::zeros(n);
    let mut u = Mat::<f64>::zeros(n, n);
    let mut mem = MemBuffer::new(self_adjoint_evd_scratch::<f64>(
        n,
        ComputeEigenvectors::Yes,
        Par::Seq,
        Default::default(),
    ));
    self_adjoint_evd(
        a,
        s.as_mut(),
        Some(u.as_mut()),
        Par::Seq,
        MemStack::new(&mut mem),
        Default::default(),
    )
    .map_err(|e| ModelError::Numerical(format!("PCA head eigen-decomposition failed: {e:?}")))?;
    let vals: Vec<f64> = (0..n).rev().map(|i| s[i]).collect();
    let vecs = Mat::<f64>::from_fn(n, n, |i, j| u[(i, n - 1 - j)]);
    Ok((vals, vecs))
}

fn to_f32(m: &Mat<f64>) -> Mat<f32> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32)
}

fn to_f64(m: &Mat<f32>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| f64::from(m[(i, j)]))
}

/// `dst_i = (src_i − μ_i)·w_i`.
fn centre_scale(dst: &mut [f32], src: &[f32], mean: &[f32], w: &[f32]) {
    for (((d, &v), &m), &wi) in dst.iter_mut().zip(src).zip(mean).zip(w) {
        *d = (v - m) * wi;
    }
}

/// Streams `Y` in fixed row blocks, handing `f(r0, Ỹ_block)` the centred and weighted block
/// `(Y[r0.., :] − μ) ⊙ w` (f32). Block sizes depend only on the shape; the copy is elementwise
/// and parallel over fixed chunks, with contiguous fast paths for column- and row-major `Y`.
fn for_each_block(
    y: MatRef<'_, f32>,
    mean: &[f32],
    w: &[f32],
    mut f: impl FnMut(usize, MatRef<'_, f32>),
) {
    let (n, d) = (y.nrows(), y.ncols());
    let nb = (BLOCK_ENTRIES / d.max(1)).clamp(16, 4096).min(n.max(1));
    let mut buf = vec![0.0f32; nb * d];
    let row_major = y.row_stride() != 1 && y.col_stride() == 1;
    for r0 in (0..n).step_by(nb) {
        let rows = nb.min(n - r0);
        let blk = &mut buf[..rows * d];
        if row_major {
            // Block stored d × rows column-major (one sample per column), viewed transposed.
            blk.par_chunks_mut(d * 64)
                .enumerate()
                .for_each(|(c, part)| {
                    for (ii, dst) in part.chunks_exact_mut(d).enumerate() {
                        let row = y.row(r0 + c * 64 + ii).transpose();
                        match row.try_as_col_major() {
                            Some(src) => centre_scale(dst, src.as_slice(), mean, w),
                            None => unreachable!("column stride 1"),
                        }
                    }
                });
            f(
                r0,
                MatRef::from_column_major_slice(blk, d, rows).transpose(),
            );
        } else {
            // Block stored rows × d column-major.
            blk.par_chunks_mut(rows * 256)
                .enumerate()
                .for_each(|(c, part)| {
                    for (jj, dst) in part.chunks_exact_mut(rows).enumerate() {
                        let j = c * 256 + jj;
                        let col = y.col(j).subrows(r0, rows);
                        if let Some(src) = col.try_as_col_major() {
                            for (dv, &v) in dst.iter_mut().zip(src.as_slice()) {
                                *dv = (v - mean[j]) * w[j];
                            }
                        } else {
                            for (i, dv) in dst.iter_mut().enumerate() {
                                *dv = (col[i] - mean[j]) * w[j];
                            }
                        }
                    }
                });
            f(r0, MatRef::from_column_major_slice(blk, rows, d));
        }
    }
}

/// `Ỹ · B` (`N × k`) for `B` of shape `D × k`.
fn right_pass(y: MatRef<'_, f32>, mean: &[f32], w: &[f32], b: MatRef<'_, f32>) -> Mat<f32> {
    let mut z = Mat::<f32>::zeros(y.nrows(), b.ncols());
    for_each_block(y, mean, w, |r0, blk| {
        gemm(
            z.as_mut().subrows_mut(r0, blk.nrows()),
            Accum::Replace,
            blk,
            b,
            1.0,
        );
    });
    z
}

/// `Ỹᵀ · Q` (`D × k`) for `Q` of shape `N × k` (block contributions added in a fixed order).
fn left_pass(y: MatRef<'_, f32>, mean: &[f32], w: &[f32], q: MatRef<'_, f32>) -> Mat<f32> {
    let mut out = Mat::<f32>::zeros(y.ncols(), q.ncols());
    let mut first = true;
    for_each_block(y, mean, w, |r0, blk| {
        let accum = if first { Accum::Replace } else { Accum::Add };
        first = false;
        gemm(
            out.as_mut(),
            accum,
            blk.transpose(),
            q.subrows(r0, blk.nrows()),
            1.0,
        );
    });
    out
}

impl PcaHead {
    /// Fits the head to targets `Y` (`N × D`, one sample per row, f32, any strides; D up to
    /// ~80k) with optional per-column weights `w > 0` (default 1):
    ///
    /// 1. `μ` = column means (f64 accumulation, stored as f32); `Ỹ = (Y − 1μᵀ) diag(w)` is
    ///    formed block by block, never as a whole.
    /// 2. Randomized range finder (Halko–Martinsson–Tropp 2011, Alg. 4.4): `ℓ = r_max + p`
    ///    Gaussian columns `Ω` (seeded), `Q = orth(ỸΩ)`, then `q` power iterations
    ///    `Q = orth(Ỹ orth(ỸᵀQ))`, with f32 GEMM passes and f64 Householder QR.
    /// 3. `Bᵀ = ỸᵀQ = Q_b R_b` (f64 QR), `R_b R_bᵀ = U Λ Uᵀ` (f64 eigen), `P = Q_b U[:, :r]`:
    ///    orthonormal to f64 rounding before the cast to f32; `σ_i² = λ_i`.
    /// 4. `r` = smallest rank in `[min_rank, max_rank]` with `Σ_{i<r} λ_i ≥ target·‖Ỹ‖²_F`.
    /// 5. Codes `C = Ỹ P` and the exact explained fraction `‖C‖²_F / ‖Ỹ‖²_F`.
    ///
    /// Passes over `Y`: `3 + 2q`. Deterministic for a given seed and any rayon pool size.
    ///
    /// Errors: [`ModelError::Invalid`] for empty or non-finite data, bad weights or options;
    /// [`ModelError::Numerical`] if the small eigen-problem fails or all variance is zero.
    pub fn fit(
        y: MatRef<'_, f32>,
        weights: Option<&[f32]>,
        opts: &PcaHeadOptions,
    ) -> Result<PcaHeadFit> {
        let (n, d) = (y.nrows(), y.ncols());
        if n == 0 || d == 0 {
            return Err(ModelError::Invalid(format!(
                "PCA head of an empty {n}×{d} matrix"
            )));
        }
        let w = head_weights(d, weights, opts)?;
        // Column means (f64, per column: deterministic) and a finiteness check.
        let stats: Vec<(f64, bool)> = (0..d)
            .into_par_iter()
            .map(|j| {
                let col = y.col(j);
                let mut s = 0.0f64;
                let mut finite = true;
                for i in 0..n {
                    let v = col[i];
                    finite &= v.is_finite();
                    s += f64::from(v);
                }
                (s / n as f64, finite)
            })
            .collect();
        if let Some(j) = stats.iter().position(|s| !s.1) {
            let i = (0..n).find(|&i| !y[(i, j)].is_finite()).unwrap_or(0);
            return Err(ModelError::Invalid(format!(
                "PCA head target entry (sample {i}, column {j}) = {} is not finite",
                y[(i, j)]
            )));
        }
        let mean: Vec<f32> = stats.iter().map(|s| s.0 as f32).collect();
        let total_ss: f64 = (0..d)
            .into_par_iter()
            .map(|j| {
                let col = y.col(j);
                let (m, wj) = (mean[j], w[j]);
                (0..n)
                    .map(|i| f64::from((col[i] - m) * wj).powi(2))
                    .sum::<f64>()
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        if total_ss.is_nan() || total_ss <= 0.0 {
            return Err(ModelError::Numerical(
                "PCA head: the targets have zero weighted variance".into(),
            ));
        }

        let rmax = opts.max_rank.min(n).min(d);
        let l = (opts.max_rank + opts.oversample).min(n).min(d);
        let mut rng = Rng::new(opts.seed, SKETCH_STREAM);
        let mut omega = Mat::<f32>::zeros(d, l);
        for j in 0..l {
            for i in 0..d {
                omega[(i, j)] = rng.normal() as f32;
            }
        }
        let mut q = to_f32(&thin_qr(to_f64(&right_pass(y, &mean, &w, omega.as_ref()))).0);
        drop(omega);
        for _ in 0..opts.power_iters {
            let wq = to_f32(&thin_qr(to_f64(&left_pass(y, &mean, &w, q.as_ref()))).0);
            q = to_f32(&thin_qr(to_f64(&right_pass(y, &mean, &w, wq.as_ref()))).0);
        }
        let bt = to_f64(&left_pass(y, &mean, &w, q.as_ref()));
        drop(q);
        let (qb, rb) = thin_qr(bt);
        let mut rrt = Mat::<f64>::zeros(l, l);
        gemm(
            rrt.as_mut(),
            Accum::Replace,
            rb.as_ref(),
            rb.transpose(),
            1.0,
        );
        let (lam, u) = eigh_desc(rrt.as_ref())?;
        let lam: Vec<f64> = lam.iter().map(|&x| x.max(0.0)).collect();

        let target = opts.target_explained * total_ss;
        let mut r = rmax;
        let mut cum = 0.0;
        for (i, &x) in lam.iter().enumerate().take(rmax) {
            cum += x;
            if cum >= target {
                r = i + 1;
                break;
            }
        }
        let r = r.max(opts.min_rank.min(rmax));
        let mut p = Mat::<f64>::zeros(d, r);
        gemm(
            p.as_mut(),
            Accum::Replace,
            qb.as_ref(),
            u.as_ref().subcols(0, r),
            1.0,
        );
        drop(qb);
        let basis = to_f32(&p);
        drop(p);
        let codes = right_pass(y, &mean, &w, basis.as_ref());
        let component_variance: Vec<f64> = (0..r)
            .map(|k| {
                (0..n)
                    .map(|i| f64::from(codes[(i, k)]).powi(2))
                    .sum::<f64>()
                    / n as f64
            })
            .collect();
        let explained_ratio = component_variance.iter().sum::<f64>() * n as f64 / total_ss;
        let head = PcaHead {
            mean,
            weights: w,
            basis,
            component_variance,
            total_variance: total_ss / n as f64,
        };
        Ok(PcaHeadFit {
            head,
            codes,
            explained_ratio,
            estimated_spectrum: lam.iter().map(|x| x / n as f64).collect(),
        })
    }

    /// Assembles a head from validated parts (used by the loader).
    pub(crate) fn from_parts(
        mean: Vec<f32>,
        weights: Vec<f32>,
        basis: Mat<f32>,
        component_variance: Vec<f64>,
        total_variance: f64,
    ) -> Self {
        Self {
            mean,
            weights,
            basis,
            component_variance,
            total_variance,
        }
    }

    /// Output dimension `D`.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Number of codes `r`.
    pub fn rank(&self) -> usize {
        self.basis.ncols()
    }

    /// Mean `μ` (`D`).
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// Channel weights `w` (`D`).
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// Orthonormal basis `P` (`D × r`) of the weighted space.
    pub fn basis(&self) -> MatRef<'_, f32> {
        self.basis.as_ref()
    }

    /// Variance of each code over the training set, `‖C_k‖²/N` (descending up to sketch error).
    pub fn component_variance(&self) -> &[f64] {
        &self.component_variance
    }

    /// Total weighted variance of the training targets, `‖Ỹ‖²_F / N`.
    pub fn total_variance(&self) -> f64 {
        self.total_variance
    }

    /// Fraction of the training set's weighted variance captured by the `r` codes.
    pub fn explained_ratio(&self) -> f64 {
        self.component_variance.iter().sum::<f64>() / self.total_variance
    }

    /// Codes of one target, `c = Pᵀ (w ⊙ (y − μ))` (sequential f32 matrix–vector product).
    ///
    /// # Panics
    /// If `y.len() != dim()`.
    pub fn encode(&self, y: &[f32]) -> Vec<f32> {
        assert_eq!(y.len(), self.dim(), "PCA head encode length");
        let yt: Vec<f32> = y
            .iter()
            .zip(self.mean.iter().zip(&self.weights))
            .map(|(&v, (&m, &w))| (v - m) * w)
            .collect();
        let mut c = vec![0.0f32; self.rank()];
        matmul(
            MatMut::from_column_major_slice_mut(&mut c, self.rank(), 1),
            Accum::Replace,
            self.basis.transpose(),
            MatRef::from_column_major_slice(&yt, self.dim(), 1),
            1.0,
            Par::Seq,
        );
        c
    }

    /// Codes of many targets (`N × D` → `N × r`), `C = Ỹ P`, with the same block-streamed f32
    /// GEMM as [`PcaHead::fit`].
    ///
    /// Errors: [`ModelError::Invalid`] if `Y` does not have `D` columns.
    pub fn encode_batch(&self, y: MatRef<'_, f32>) -> Result<Mat<f32>> {
        if y.ncols() != self.dim() {
            return Err(ModelError::Invalid(format!(
                "PCA head input has {} columns, expected {}",
                y.ncols(),
                self.dim()
            )));
        }
        Ok(right_pass(
            y,
            &self.mean,
            &self.weights,
            self.basis.as_ref(),
        ))
    }

    /// Decoded target `y = μ + (P c) ⊘ w` (sequential f32 matrix–vector product).
    ///
    /// # Panics
    /// If `c.len() != rank()`.
    pub fn decode(&self, c: &[f32]) -> Vec<f32> {
        let mut out = vec![0.0f32; self.dim()];
        self.decode_into(c, &mut out);
        out
    }

    /// Allocation-free [`PcaHead::decode`] into `out` (`D`).
    ///
    /// # Panics
    /// If `c.len() != rank()` or `out.len() != dim()`.
    pub fn decode_into(&self, c: &[f32], out: &mut [f32]) {
        assert_eq!(c.len(), self.rank(), "PCA head decode length");
        assert_eq!(out.len(), self.dim(), "PCA head decode output length");
        let d = self.dim();
        matmul(
            MatMut::from_column_major_slice_mut(out, d, 1),
            Accum::Replace,
            self.basis.as_ref(),
            MatRef::from_column_major_slice(c, c.len(), 1),
            1.0,
            if d * c.len() >= PARALLEL_DECODE {
                Par::rayon(0)
            } else {
                Par::Seq
            },
        );
        for ((o, &m), &w) in out.iter_mut().zip(&self.mean).zip(&self.weights) {
            *o = m + *o / w;
        }
    }
}

/// Basis entries (`D × rank`) from which [`PcaHead::decode_into`] splits its product over
/// rayon's threads: the default model's correction head (35,750 × 192, 27 MB of f32) is
/// read from memory once per decode, about 3 ms on one core.
const PARALLEL_DECODE: usize = 1 << 20;

/// Checks the options of [`PcaHead::fit`] and returns the column weights (`weights`, or 1
/// for each of the `d` columns).
fn head_weights(d: usize, weights: Option<&[f32]>, opts: &PcaHeadOptions) -> Result<Vec<f32>> {
    if opts.max_rank == 0 || opts.min_rank > opts.max_rank {
        return Err(ModelError::Invalid(format!(
            "PCA head ranks: need 1 ≤ max_rank and min_rank ≤ max_rank, got {}..{}",
            opts.min_rank, opts.max_rank
        )));
    }
    if !(opts.target_explained > 0.0 && opts.target_explained <= 1.0) {
        return Err(ModelError::Invalid(format!(
            "PCA head target_explained must lie in (0, 1], got {}",
            opts.target_explained
        )));
    }
    Ok(match weights {
        None => vec![1.0; d],
        Some(w) => {
            if w.len() != d {
                return Err(ModelError::Invalid(format!(
                    "PCA head has {} weights for {d} columns",
                    w.len()
                )));
            }
            if let Some(j) = w.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(ModelError::Invalid(format!(
                    "PCA head weight {j} = {} is not finite and > 0",
                    w[j]
                )));
            }
            w.to_vec()
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A head large enough for the parallel product ([`PARALLEL_DECODE`]) decodes to
    /// `m + (P c)/w` within f32 summation error: `|ε_i| ≤ r·u·Σ_k |P_ik c_k| / w_i`
    /// (`u` = 2⁻²⁴, r products accumulated), checked against the same sum in f64.
    #[test]
    fn parallel_decode_matches_the_definition() {
        let (d, r) = (16_384, 64);
        assert!(d * r >= PARALLEL_DECODE);
        let mut s = 7u64;
        let mut rnd = || {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            ((s >> 40) as f32) / (1u64 << 24) as f32 - 0.5
        };
        let basis = Mat::<f32>::from_fn(d, r, |_, _| rnd());
        let mean: Vec<f32> = (0..d).map(|_| rnd()).collect();
        let weights: Vec<f32> = (0..d).map(|_| 1.0 + rnd().abs()).collect();
        let c: Vec<f32> = (0..r).map(|_| rnd()).collect();
        let head = PcaHead {
            mean: mean.clone(),
            weights: weights.clone(),
            basis: basis.clone(),
            component_variance: vec![1.0; r],
            total_variance: r as f64,
        };
        let mut out = vec![0.0f32; d];
        head.decode_into(&c, &mut out);
        let u = f64::from(f32::EPSILON) / 2.0;
        for i in 0..d {
            let (mut sum, mut abs) = (0.0f64, 0.0f64);
            for (k, &ck) in c.iter().enumerate() {
                let t = f64::from(basis[(i, k)]) * f64::from(ck);
                sum += t;
                abs += t.abs();
            }
            let w = f64::from(weights[i]);
            let exact = f64::from(mean[i]) + sum / w;
            // Product error, then the division and the addition (one rounding each).
            let bound = (r as f64 * u * abs) / w + 2.0 * u * (exact.abs() + abs / w) + 1e-30;
            assert!(
                (f64::from(out[i]) - exact).abs() <= bound,
                "row {i}: {} vs {exact} (bound {bound:e})",
                out[i]
            );
        }
    }
}
