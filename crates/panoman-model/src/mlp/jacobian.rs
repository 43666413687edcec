//! Input Jacobian of the network at one sample, in factored form (docs/design/shell-fit.md §3.2, docs/design/splocs-model.md §5.4).

use faer::{Accum, Mat};

use super::gemm::gemm;
use super::net::{Mlp, bias_act};

/// The Jacobian `J = ∂y/∂x` of an [`Mlp`] at one input, as a product of small dense factors
/// `J = F_0 · F_1 ⋯ F_{L−1}` (docs/design/shell-fit.md §3.2):
///
/// ```text
/// J = diag(s_y) · W_L · D_{L−1} · W_{L−1} ⋯ D_1 · W_1 · diag(1/σ_x),   D_l = diag(relu mask of layer l)
/// F_0     = diag(s_y) · W_L[:, A_{L−1}]             (out × |A_{L−1}|)
/// F_i     = W_l[A_l, A_{l−1}]                        (middle layers, l = L − i)
/// F_{L−1} = W_1[A_1, :] · diag(1/σ_x)                (|A_1| × in)
/// ```
///
/// `A_l` is the set of active units (pre-activation `> 0`; the ReLU derivative at exactly 0 is
/// taken as 0). For the correction MLP `500 → 1500 → r` this is `(s_y ⊙ W_2 restricted to the
/// active columns, the active rows of W_1 scaled by 1/σ)`. The Jacobian is piecewise constant in
/// `x` (docs/design/splocs-model.md §5.4: damp the Gauss–Newton step and clamp β). With a PCA head (docs/design/splocs-model.md §5.1) the caller's
/// `∂R/∂β = P·J` should be kept as the pair `(P, J)` with `J` densified (`r × in` is small) and
/// never expanded to `D × in`.
#[derive(Clone, Debug)]
pub struct FactoredJacobian {
    factors: Vec<Mat<f32>>,
    active: Vec<Vec<usize>>,
    nrows: usize,
    ncols: usize,
}

impl FactoredJacobian {
    /// Rows of `J` (network outputs).
    pub fn nrows(&self) -> usize {
        self.nrows
    }

    /// Columns of `J` (network inputs).
    pub fn ncols(&self) -> usize {
        self.ncols
    }

    /// The factors `F_0, …, F_{L−1}` with `J = F_0 ⋯ F_{L−1}`.
    pub fn factors(&self) -> &[Mat<f32>] {
        &self.factors
    }

    /// Active units `A_1, …, A_{L−1}` of each hidden layer (ascending indices).
    pub fn active_units(&self) -> &[Vec<usize>] {
        &self.active
    }

    /// Dense `J` in f32 (products right to left with f32 GEMMs).
    pub fn to_dense(&self) -> Mat<f32> {
        let mut acc = self.factors[self.factors.len() - 1].clone();
        for f in self.factors.iter().rev().skip(1) {
            let mut next = Mat::<f32>::zeros(f.nrows(), acc.ncols());
            gemm(next.as_mut(), Accum::Replace, f.as_ref(), acc.as_ref(), 1.0);
            acc = next;
        }
        acc
    }

    /// Dense `J` with the products formed in f64 from the (exact) f32 factors.
    pub fn to_dense_f64(&self) -> Mat<f64> {
        let cast =
            |m: &Mat<f32>| Mat::<f64>::from_fn(m.nrows(), m.ncols(), |i, j| f64::from(m[(i, j)]));
        let mut acc = cast(&self.factors[self.factors.len() - 1]);
        for f in self.factors.iter().rev().skip(1) {
            let f = cast(f);
            let mut next = Mat::<f64>::zeros(f.nrows(), acc.ncols());
            gemm(next.as_mut(), Accum::Replace, f.as_ref(), acc.as_ref(), 1.0);
            acc = next;
        }
        acc
    }

    /// `J·v` (right to left through the factors, f64 accumulation).
    ///
    /// # Panics
    /// If `v.len() != ncols()`.
    pub fn apply(&self, v: &[f32]) -> Vec<f32> {
        assert_eq!(v.len(), self.ncols, "Jacobian apply length");
        let mut cur: Vec<f64> = v.iter().map(|&x| f64::from(x)).collect();
        for f in self.factors.iter().rev() {
            let mut next = vec![0.0f64; f.nrows()];
            for (j, &c) in cur.iter().enumerate() {
                for (i, n) in next.iter_mut().enumerate() {
                    *n += f64::from(f[(i, j)]) * c;
                }
            }
            cur = next;
        }
        cur.iter().map(|&x| x as f32).collect()
    }

    /// `Jᵀ·u` (left to right through the factors, f64 accumulation).
    ///
    /// # Panics
    /// If `u.len() != nrows()`.
    pub fn apply_transpose(&self, u: &[f32]) -> Vec<f32> {
        assert_eq!(u.len(), self.nrows, "Jacobian transpose-apply length");
        let mut cur: Vec<f64> = u.iter().map(|&x| f64::from(x)).collect();
        for f in &self.factors {
            let next: Vec<f64> = (0..f.ncols())
                .map(|j| (0..f.nrows()).map(|i| f64::from(f[(i, j)]) * cur[i]).sum())
                .collect();
            cur = next;
        }
        cur.iter().map(|&x| x as f32).collect()
    }
}

impl Mlp {
    /// Output `y = f(x)` and the input Jacobian `∂y/∂x` at `x` in factored form (see
    /// [`FactoredJacobian`]; docs/design/shell-fit.md §3.2). `y` equals [`Mlp::forward_one`] bit for bit.
    ///
    /// # Panics
    /// If `x.len() != n_inputs()`.
    pub fn jacobian(&self, x: &[f32]) -> (Vec<f32>, FactoredJacobian) {
        assert_eq!(x.len(), self.n_inputs(), "MLP input length");
        let nl = self.n_layers();
        // Forward pass keeping every hidden activation (same arithmetic as forward_one).
        let mut acts: Vec<Vec<f32>> = Vec::with_capacity(nl + 1);
        let mut a = vec![0.0f32; self.n_inputs()];
        self.normalize_input(x, &mut a);
        acts.push(a);
        for l in 0..nl {
            let fan_out = self.sizes()[l + 1];
            let mut z = vec![0.0f32; fan_out];
            faer::linalg::matmul::matmul(
                faer::MatMut::from_column_major_slice_mut(&mut z, fan_out, 1),
                Accum::Replace,
                self.weight(l),
                faer::MatRef::from_column_major_slice(&acts[l], acts[l].len(), 1),
                1.0,
                faer::Par::Seq,
            );
            bias_act(&mut z, fan_out, self.bias(l), l + 1 < nl);
            acts.push(z);
        }
        let o = &acts[nl];
        let y: Vec<f32> = o
            .iter()
            .enumerate()
            .map(|(k, &v)| self.output_mean()[k] + self.output_scale()[k] * v)
            .collect();
        // Active sets of the hidden layers 1..L−1 (relu(z) > 0 ⇔ z > 0).
        let active: Vec<Vec<usize>> = (1..nl)
            .map(|l| {
                acts[l]
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| **v > 0.0)
                    .map(|(i, _)| i)
                    .collect()
            })
            .collect();
        let all_in: Vec<usize> = (0..self.n_inputs()).collect();
        let all_out: Vec<usize> = (0..self.n_outputs()).collect();
        // Factor for layer l (0-based) maps A_{l} (its inputs) to A_{l+1} (its outputs).
        let rows_of = |l: usize| -> &[usize] { if l + 1 == nl { &all_out } else { &active[l] } };
        let cols_of = |l: usize| -> &[usize] { if l == 0 { &all_in } else { &active[l - 1] } };
        let mut factors = Vec::with_capacity(nl);
        for l in (0..nl).rev() {
            let (rows, cols) = (rows_of(l), cols_of(l));
            let w = self.weight(l);
            let f = Mat::<f32>::from_fn(rows.len(), cols.len(), |i, j| {
                let mut v = w[(rows[i], cols[j])];
                if l + 1 == nl {
                    v *= self.output_scale()[rows[i]];
                }
                if l == 0 {
                    v /= self.input_scale()[cols[j]];
                }
                v
            });
            factors.push(f);
        }
        let jac = FactoredJacobian {
            factors,
            active,
            nrows: self.n_outputs(),
            ncols: self.n_inputs(),
        };
        (y, jac)
    }

    /// Output and dense input Jacobian `∂y/∂x` (`out × in`, f32) at `x`; convenient for small
    /// networks (motion MLP, PCA-head correction MLP with `r × 500`).
    ///
    /// # Panics
    /// If `x.len() != n_inputs()`.
    pub fn jacobian_dense(&self, x: &[f32]) -> (Vec<f32>, Mat<f32>) {
        let (y, j) = self.jacobian(x);
        (y, j.to_dense())
    }
}
