//! The network: `Linear → ReLU → … → Linear` with input z-scoring and output de-normalization
//! (docs/design/splocs-model.md §5.1–5.2).

use std::ops::Range;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};

use super::gemm::{gemm, view, view_mut};
use super::rng::Rng;
use crate::error::{ModelError, Result};

/// Random stream of the weight initialization.
const INIT_STREAM: u64 = 0x1417;

/// Samples per chunk of the batched forward pass (bounds the activation memory).
pub(crate) const FORWARD_CHUNK: usize = 1024;

/// Where one layer's weight (`fan_out × fan_in`, column-major) and bias live in the flat
/// parameter vector.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct LayerLayout {
    pub fan_in: usize,
    pub fan_out: usize,
    pub w: usize,
    pub b: usize,
}

impl LayerLayout {
    pub(crate) fn w_range(&self) -> Range<usize> {
        self.w..self.w + self.fan_in * self.fan_out
    }
    pub(crate) fn b_range(&self) -> Range<usize> {
        self.b..self.b + self.fan_out
    }
}

/// A multilayer perceptron with ReLU hidden layers and a linear output layer, including its
/// input and output normalization (docs/design/splocs-model.md §5):
///
/// ```text
/// x̃   = (x − μ_x) ⊘ σ_x                       (z-scored input; σ_x floored, docs/design/splocs-model.md §5.1)
/// h_1 = relu(W_1 x̃ + b_1),  …,  h_{L−1} = relu(W_{L−1} h_{L−2} + b_{L−1})
/// o   = W_L h_{L−1} + b_L                      (linear output layer)
/// y   = μ_y + s_y ⊙ o                          (output de-normalization)
/// ```
///
/// `W_l` is stored `out × in` (column-major) in one flat `f32` parameter vector laid out as
/// `[W_1, b_1, W_2, b_2, …]` (see [`Mlp::parameters`]). Architectures used by PanoMan:
/// correction MLP `500 → 1500 → r` on a PCA head (docs/design/splocs-model.md §5.1), motion MLP `θ → 400 → 600 → β` (docs/design/splocs-model.md §5.2).
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    sizes: Vec<usize>,
    layout: Vec<LayerLayout>,
    params: Vec<f32>,
    input_mean: Vec<f32>,
    input_scale: Vec<f32>,
    output_mean: Vec<f32>,
    output_scale: Vec<f32>,
}

/// Reusable buffers of [`Mlp::forward_one_into`] (two vectors of the widest layer), so that
/// repeated single-sample inference does not allocate.
#[derive(Clone, Debug, Default)]
pub struct ForwardScratch {
    a: Vec<f32>,
    b: Vec<f32>,
}

fn layout_of(sizes: &[usize]) -> (Vec<LayerLayout>, usize) {
    let mut layout = Vec::with_capacity(sizes.len() - 1);
    let mut off = 0;
    for pair in sizes.windows(2) {
        let (fan_in, fan_out) = (pair[0], pair[1]);
        let w = off;
        let b = w + fan_in * fan_out;
        off = b + fan_out;
        layout.push(LayerLayout {
            fan_in,
            fan_out,
            w,
            b,
        });
    }
    (layout, off)
}

/// Adds the bias to every column of `z` (`rows × cols`, column-major) and applies ReLU if asked.
pub(crate) fn bias_act(z: &mut [f32], rows: usize, bias: &[f32], relu: bool) {
    for col in z.chunks_exact_mut(rows) {
        if relu {
            for (v, &b) in col.iter_mut().zip(bias) {
                *v = (*v + b).max(0.0);
            }
        } else {
            for (v, &b) in col.iter_mut().zip(bias) {
                *v += b;
            }
        }
    }
}

impl Mlp {
    /// A network with layer widths `sizes = [in, h_1, …, h_{L−1}, out]`, Kaiming/He
    /// initialization from `seed`: hidden-layer weights `~ N(0, 2/fan_in)` (He et al. 2015, for
    /// ReLU), output-layer weights `~ N(0, 1/fan_in)` (linear output), zero biases; identity
    /// normalization (`μ = 0`, `σ = s = 1`).
    ///
    /// Errors: [`ModelError::Invalid`] if fewer than two sizes are given or a size is zero.
    pub fn new(sizes: &[usize], seed: u64) -> Result<Self> {
        if sizes.len() < 2 {
            return Err(ModelError::Invalid(format!(
                "an MLP needs at least input and output sizes, got {sizes:?}"
            )));
        }
        if sizes.contains(&0) {
            return Err(ModelError::Invalid(format!(
                "MLP layer sizes must be positive, got {sizes:?}"
            )));
        }
        let (layout, n) = layout_of(sizes);
        let mut params = vec![0.0f32; n];
        let mut rng = Rng::new(seed, INIT_STREAM);
        let last = layout.len() - 1;
        for (l, lay) in layout.iter().enumerate() {
            let gain = if l == last { 1.0 } else { 2.0 };
            let std = (gain / lay.fan_in as f64).sqrt();
            for p in &mut params[lay.w_range()] {
                *p = (rng.normal() * std) as f32;
            }
        }
        let (nin, nout) = (sizes[0], sizes[sizes.len() - 1]);
        Ok(Self {
            sizes: sizes.to_vec(),
            layout,
            params,
            input_mean: vec![0.0; nin],
            input_scale: vec![1.0; nin],
            output_mean: vec![0.0; nout],
            output_scale: vec![1.0; nout],
        })
    }

    /// Assembles a network from validated parts (used by the loader).
    pub(crate) fn from_parts(sizes: Vec<usize>, params: Vec<f32>, norm: [Vec<f32>; 4]) -> Self {
        let (layout, n) = layout_of(&sizes);
        debug_assert_eq!(n, params.len());
        let [input_mean, input_scale, output_mean, output_scale] = norm;
        Self {
            sizes,
            layout,
            params,
            input_mean,
            input_scale,
            output_mean,
            output_scale,
        }
    }

    /// Number of parameters `Σ_l (in_l + 1)·out_l` of a network with widths `sizes` (weights
    /// and biases); saturates at `usize::MAX` instead of overflowing.
    pub fn parameter_count(sizes: &[usize]) -> usize {
        sizes
            .windows(2)
            .map(|p| p[0].saturating_add(1).saturating_mul(p[1]))
            .fold(0usize, usize::saturating_add)
    }

    pub(crate) fn layout(&self) -> &[LayerLayout] {
        &self.layout
    }

    /// Layer widths `[in, h_1, …, out]`.
    pub fn sizes(&self) -> &[usize] {
        &self.sizes
    }

    /// Input dimension.
    pub fn n_inputs(&self) -> usize {
        self.sizes[0]
    }

    /// Output dimension.
    pub fn n_outputs(&self) -> usize {
        self.sizes[self.sizes.len() - 1]
    }

    /// Number of linear layers `L` (hidden layers + 1).
    pub fn n_layers(&self) -> usize {
        self.layout.len()
    }

    /// Width of the widest layer (input included).
    pub fn max_width(&self) -> usize {
        self.sizes.iter().copied().max().unwrap_or(0)
    }

    /// The flat parameter vector `[W_1, b_1, …, W_L, b_L]`; each `W_l` is `out × in`
    /// column-major (entry `(i, j)` at offset `i + j·out`).
    pub fn parameters(&self) -> &[f32] {
        &self.params
    }

    /// Mutable flat parameter vector (same layout as [`Mlp::parameters`]).
    pub fn parameters_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    /// Weight `W_l` (`out × in`) of layer `l` (0-based).
    ///
    /// # Panics
    /// If `l ≥ n_layers()`.
    pub fn weight(&self, l: usize) -> MatRef<'_, f32> {
        let lay = &self.layout[l];
        MatRef::from_column_major_slice(&self.params[lay.w_range()], lay.fan_out, lay.fan_in)
    }

    /// Bias `b_l` of layer `l` (0-based).
    ///
    /// # Panics
    /// If `l ≥ n_layers()`.
    pub fn bias(&self, l: usize) -> &[f32] {
        &self.params[self.layout[l].b_range()]
    }

    /// Input mean `μ_x`.
    pub fn input_mean(&self) -> &[f32] {
        &self.input_mean
    }

    /// Input scale `σ_x` (z-scoring divides by it).
    pub fn input_scale(&self) -> &[f32] {
        &self.input_scale
    }

    /// Output mean `μ_y`.
    pub fn output_mean(&self) -> &[f32] {
        &self.output_mean
    }

    /// Output scale `s_y` (`y = μ_y + s_y ⊙ o`).
    pub fn output_scale(&self) -> &[f32] {
        &self.output_scale
    }

    /// Sets the normalization `x̃ = (x − μ_x) ⊘ σ_x`, `y = μ_y + s_y ⊙ o`.
    ///
    /// Errors: [`ModelError::Invalid`] on a length mismatch, a non-finite value or a scale `≤ 0`.
    pub fn set_normalization(
        &mut self,
        input_mean: &[f32],
        input_scale: &[f32],
        output_mean: &[f32],
        output_scale: &[f32],
    ) -> Result<()> {
        let (nin, nout) = (self.n_inputs(), self.n_outputs());
        for (name, v, n, positive) in [
            ("input mean", input_mean, nin, false),
            ("input scale", input_scale, nin, true),
            ("output mean", output_mean, nout, false),
            ("output scale", output_scale, nout, true),
        ] {
            if v.len() != n {
                return Err(ModelError::Invalid(format!(
                    "{name} has length {}, expected {n}",
                    v.len()
                )));
            }
            if let Some(i) = v
                .iter()
                .position(|x| !x.is_finite() || (positive && *x <= 0.0))
            {
                return Err(ModelError::Invalid(format!(
                    "{name}[{i}] = {} is not {}",
                    v[i],
                    if positive { "finite and > 0" } else { "finite" }
                )));
            }
        }
        self.input_mean = input_mean.to_vec();
        self.input_scale = input_scale.to_vec();
        self.output_mean = output_mean.to_vec();
        self.output_scale = output_scale.to_vec();
        Ok(())
    }

    /// Writes `x̃_j = (x_j − μ_j)/σ_j` into `dst`.
    pub(crate) fn normalize_input(&self, x: &[f32], dst: &mut [f32]) {
        for ((d, &v), (&m, &s)) in dst
            .iter_mut()
            .zip(x)
            .zip(self.input_mean.iter().zip(&self.input_scale))
        {
            *d = (v - m) / s;
        }
    }

    /// Runs the layers on normalized inputs `xt` (`in × c`, one sample per column), writing layer
    /// `l`'s output (post-ReLU for hidden layers, `o` for the last) into `acts[l]` (column-major,
    /// `fan_out × c`). Products use the fixed-chunk parallel GEMM (bit-identical for any pool).
    pub(crate) fn forward_cols(&self, xt: MatRef<'_, f32>, acts: &mut [Vec<f32>]) {
        let c = xt.ncols();
        let last = self.layout.len() - 1;
        for (l, lay) in self.layout.iter().enumerate() {
            let (prev, cur) = acts.split_at_mut(l);
            let input = if l == 0 {
                xt
            } else {
                view(&prev[l - 1], lay.fan_in, c)
            };
            let out = &mut cur[0];
            gemm(
                view_mut(out, lay.fan_out, c),
                Accum::Replace,
                self.weight(l),
                input,
                1.0,
            );
            bias_act(
                &mut out[..lay.fan_out * c],
                lay.fan_out,
                self.bias(l),
                l < last,
            );
        }
    }

    /// Activation buffers for `forward_cols` with up to `c` columns.
    pub(crate) fn activation_buffers(&self, c: usize) -> Vec<Vec<f32>> {
        self.layout
            .iter()
            .map(|lay| vec![0.0f32; lay.fan_out * c])
            .collect()
    }

    /// Batched forward pass `Y = f(X)` for `X` of shape `N × in` (one sample per row, any
    /// strides), returning `N × out`. Samples are processed in chunks of 1024; every product uses
    /// the fixed-chunk parallel GEMM on the current rayon pool, so results do not depend on the
    /// thread count. (They may differ in the last bit from [`Mlp::forward_one`], which uses
    /// matrix–vector kernels.)
    ///
    /// Errors: [`ModelError::Invalid`] if `X` does not have `in` columns.
    pub fn forward(&self, x: MatRef<'_, f32>) -> Result<Mat<f32>> {
        let (nin, nout) = (self.n_inputs(), self.n_outputs());
        if x.ncols() != nin {
            return Err(ModelError::Invalid(format!(
                "MLP input has {} columns, expected {nin}",
                x.ncols()
            )));
        }
        let n = x.nrows();
        let mut y = Mat::<f32>::zeros(n, nout);
        let chunk = FORWARD_CHUNK.min(n.max(1));
        let mut xt = vec![0.0f32; nin * chunk];
        let mut acts = self.activation_buffers(chunk);
        let mut row = vec![0.0f32; nin];
        for r0 in (0..n).step_by(chunk) {
            let c = chunk.min(n - r0);
            for j in 0..c {
                for (f, v) in row.iter_mut().enumerate() {
                    *v = x[(r0 + j, f)];
                }
                self.normalize_input(&row, &mut xt[j * nin..(j + 1) * nin]);
            }
            self.forward_cols(view(&xt, nin, c), &mut acts);
            let o = &acts[acts.len() - 1];
            for j in 0..c {
                for k in 0..nout {
                    y[(r0 + j, k)] = self.output_mean[k] + self.output_scale[k] * o[j * nout + k];
                }
            }
        }
        Ok(y)
    }

    /// Single-sample forward pass `y = f(x)` (matrix–vector products, sequential).
    ///
    /// # Panics
    /// If `x.len() != n_inputs()`.
    pub fn forward_one(&self, x: &[f32]) -> Vec<f32> {
        let mut out = vec![0.0f32; self.n_outputs()];
        self.forward_one_into(x, &mut out, &mut ForwardScratch::default());
        out
    }

    /// Allocation-free single-sample forward pass (after the scratch has grown once): writes
    /// `f(x)` into `out`. Same arithmetic as [`Mlp::forward_one`].
    ///
    /// # Panics
    /// If `x.len() != n_inputs()` or `out.len() != n_outputs()`.
    pub fn forward_one_into(&self, x: &[f32], out: &mut [f32], scratch: &mut ForwardScratch) {
        assert_eq!(x.len(), self.n_inputs(), "MLP input length");
        assert_eq!(out.len(), self.n_outputs(), "MLP output length");
        let w = self.max_width();
        scratch.a.resize(w, 0.0);
        scratch.b.resize(w, 0.0);
        let (a, b) = (&mut scratch.a, &mut scratch.b);
        self.normalize_input(x, &mut a[..self.n_inputs()]);
        let last = self.layout.len() - 1;
        for (l, lay) in self.layout.iter().enumerate() {
            matmul(
                view_mut(b, lay.fan_out, 1),
                Accum::Replace,
                self.weight(l),
                view(a, lay.fan_in, 1),
                1.0,
                Par::Seq,
            );
            bias_act(&mut b[..lay.fan_out], lay.fan_out, self.bias(l), l < last);
            std::mem::swap(a, b);
        }
        for (k, o) in out.iter_mut().enumerate() {
            *o = self.output_mean[k] + self.output_scale[k] * a[k];
        }
    }

    /// Reference single-sample forward pass in **f64** with the same (f32) parameters cast
    /// exactly to f64: the exact function the f32 network approximates. Used for
    /// finite-difference checks of [`Mlp::jacobian`] and for f64 consumers (allocates).
    ///
    /// # Panics
    /// If `x.len() != n_inputs()`.
    pub fn forward_one_f64(&self, x: &[f64]) -> Vec<f64> {
        assert_eq!(x.len(), self.n_inputs(), "MLP input length");
        let mut a: Vec<f64> = x
            .iter()
            .zip(self.input_mean.iter().zip(&self.input_scale))
            .map(|(&v, (&m, &s))| (v - f64::from(m)) / f64::from(s))
            .collect();
        let last = self.layout.len() - 1;
        for (l, lay) in self.layout.iter().enumerate() {
            let w = &self.params[lay.w_range()];
            let mut z: Vec<f64> = self.bias(l).iter().map(|&b| f64::from(b)).collect();
            for (j, &aj) in a.iter().enumerate() {
                let col = &w[j * lay.fan_out..(j + 1) * lay.fan_out];
                for (zi, &wij) in z.iter_mut().zip(col) {
                    *zi += f64::from(wij) * aj;
                }
            }
            if l < last {
                for v in &mut z {
                    *v = v.max(0.0);
                }
            }
            a = z;
        }
        a.iter()
            .zip(self.output_mean.iter().zip(&self.output_scale))
            .map(|(&o, (&m, &s))| f64::from(m) + f64::from(s) * o)
            .collect()
    }
}
