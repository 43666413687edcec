//! Minibatch AdamW training with cosine learning-rate decay, early stopping and an MSE or
//! Gram-metric loss (docs/design/splocs-model.md §5.1–5.2).

use std::ops::ControlFlow;
use std::time::Instant;

use faer::{Accum, Mat, MatRef};
use rayon::prelude::*;

use super::gemm::{gemm, view, view_mut};
use super::net::{FORWARD_CHUNK, Mlp};
use super::rng::Rng;
use crate::error::{ModelError, Result};

/// Random stream of the per-epoch shuffles.
const SHUFFLE_STREAM: u64 = 0x5eed;
/// Elements per parallel chunk of the AdamW update (elementwise, so any chunking is exact).
const ADAM_CHUNK: usize = 1 << 14;

/// A supervised data set: inputs `x` (`N × in`) and targets `y` (`N × out`), one sample per
/// row (any strides). For early stopping the caller builds the validation set from held-out
/// **identities** (docs/design/splocs-model.md §5.1), not random samples.
#[derive(Clone, Copy, Debug)]
pub struct MlpDataset<'a> {
    /// Inputs, `N × in`.
    pub x: MatRef<'a, f32>,
    /// Targets, `N × out`.
    pub y: MatRef<'a, f32>,
}

impl<'a> MlpDataset<'a> {
    /// Pairs inputs and targets.
    ///
    /// Errors: [`ModelError::Invalid`] if the row counts differ.
    pub fn new(x: MatRef<'a, f32>, y: MatRef<'a, f32>) -> Result<Self> {
        if x.nrows() != y.nrows() {
            return Err(ModelError::Invalid(format!(
                "data set has {} input rows but {} target rows",
                x.nrows(),
                y.nrows()
            )));
        }
        Ok(Self { x, y })
    }

    /// Number of samples `N`.
    pub fn len(&self) -> usize {
        self.x.nrows()
    }

    /// Whether the set has no samples.
    pub fn is_empty(&self) -> bool {
        self.x.nrows() == 0
    }
}

/// Training loss, always evaluated on the **normalized** output `o` against the normalized
/// target `ỹ = (y − μ_y) ⊘ s_y`, with residual `e = o − ỹ = (ŷ − y) ⊘ s_y` and `K` outputs:
///
/// * `Mse`: `ℓ = ‖e‖² / K` (docs/design/splocs-model.md §5.1). With a global output scale (see [`OutputNorm::Global`]) and a
///   PCA head this is the in-span MSE of the decoded output divided by `s²`.
/// * `Metric(G)`: the RLA metric loss of docs/design/splocs-model.md §5.2, `(ŷ − y)ᵀ G (ŷ − y)` for a user-supplied SPD
///   `K × K` Gram matrix `G = MᵀM` given in **original** output units. In normalized units it
///   becomes `G̃ = S G S / (tr(S G S)/K)` (`S = diag(s_y)`; the division makes `G = c·I` give
///   exactly the MSE), and the loss is evaluated through the Cholesky factor `G̃ = L Lᵀ` as
///   `ℓ = ‖Lᵀ e‖² / K` (a sum of squares, never negative), gradient `∂ℓ/∂o = 2 L (Lᵀ e) / K`.
///   Only the lower triangle of `G` is used after a symmetry check.
///
/// The minibatch objective is the mean of `ℓ` over the batch; reported losses are means over
/// samples, accumulated in f64.
#[derive(Clone, Debug, PartialEq)]
pub enum Loss {
    /// Mean squared error on normalized outputs.
    Mse,
    /// Gram-metric loss with SPD `G` (`K × K`, original output units).
    Metric(Mat<f64>),
}

/// How the output normalization `y = μ_y + s_y ⊙ o` is fitted when
/// [`MlpTrainConfig::fit_normalization`] is set (statistics over the training set, f64).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputNorm {
    /// Per-output mean and standard deviation (floored at [`MlpTrainConfig::sigma_floor`]); the
    /// default for the motion MLP's β outputs.
    PerDim,
    /// Per-output mean and **one** scale `s = sqrt(mean_k var_k)` for all outputs. Use this for
    /// PCA-head codes: a common scale keeps the MSE proportional to the in-span MSE on `y`
    /// (docs/design/splocs-model.md §5.1), whereas per-component z-scoring would overweight the small components.
    Global,
    /// No output normalization (`μ_y = 0`, `s_y = 1`).
    Identity,
}

/// Hyper-parameters of [`train`] (defaults = docs/design/splocs-model.md §5.1: AdamW β₁ 0.9, β₂ 0.999,
/// ε 1e−8, weight decay 1e−5, cosine decay 1e−3 → 1e−5, batch 128).
#[derive(Clone, Debug, PartialEq)]
pub struct MlpTrainConfig {
    /// Number of epochs `E` (the cosine schedule spans all of them even if training stops early).
    pub epochs: usize,
    /// Minibatch size (the last batch of an epoch may be smaller).
    pub batch_size: usize,
    /// Initial learning rate of the cosine schedule.
    pub lr_max: f64,
    /// Final learning rate of the cosine schedule.
    pub lr_min: f64,
    /// Decoupled (AdamW) weight decay; applied to weights, not to biases.
    pub weight_decay: f64,
    /// Adam first-moment decay β₁.
    pub beta1: f64,
    /// Adam second-moment decay β₂.
    pub beta2: f64,
    /// Adam ε.
    pub eps: f64,
    /// Seed of the per-epoch shuffles (the initialization seed is given to [`Mlp::new`]).
    pub seed: u64,
    /// Early stopping: stop after this many epochs without a validation improvement and restore
    /// the best weights; `None` trains all epochs (the best weights are still restored when a
    /// validation set is given).
    pub patience: Option<usize>,
    /// An epoch improves when `val < best·(1 − min_rel_improvement)`.
    pub min_rel_improvement: f64,
    /// Loss function.
    pub loss: Loss,
    /// Refit the input/output normalization from the training set before training.
    pub fit_normalization: bool,
    /// Output normalization kind when `fit_normalization` is set.
    pub output_norm: OutputNorm,
    /// Floor of every fitted standard deviation (docs/design/splocs-model.md §5.1: 1e−3).
    pub sigma_floor: f32,
}

impl Default for MlpTrainConfig {
    fn default() -> Self {
        Self {
            epochs: 300,
            batch_size: 128,
            lr_max: 1e-3,
            lr_min: 1e-5,
            weight_decay: 1e-5,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            seed: 0,
            patience: Some(30),
            min_rel_improvement: 0.0,
            loss: Loss::Mse,
            fit_normalization: true,
            output_norm: OutputNorm::PerDim,
            sigma_floor: 1e-3,
        }
    }
}

/// Progress of one epoch, passed to the callback of [`train`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpochStats {
    /// Epoch number, starting at 1.
    pub epoch: usize,
    /// Mean training loss over the epoch's minibatches (running, during the epoch).
    pub train_loss: f64,
    /// Mean validation loss after the epoch, if a validation set was given.
    pub val_loss: Option<f64>,
    /// Learning rate of the epoch's last step.
    pub lr: f64,
    /// Seconds since training started.
    pub seconds: f64,
}

/// Outcome of [`train`].
#[derive(Clone, Debug, PartialEq)]
pub struct MlpTrainReport {
    /// One entry per epoch run.
    pub history: Vec<EpochStats>,
    /// Optimizer steps taken.
    pub steps: usize,
    /// Epoch whose weights were kept (best validation loss), if a validation set was given.
    pub best_epoch: Option<usize>,
    /// Best validation loss.
    pub best_val_loss: Option<f64>,
    /// Whether early stopping ended training.
    pub stopped_early: bool,
    /// Whether the callback asked to stop.
    pub cancelled: bool,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Prepared loss: MSE or the f32 Cholesky factor `L` (`K × K`, lower, column-major) of `G̃`.
enum LossImpl {
    Mse,
    Metric { k: usize, l: Vec<f32> },
}

/// Dense Cholesky `G = L Lᵀ` in f64 (row-major `n × n` input and output, lower triangle read).
fn cholesky(g: &[f64], n: usize) -> Result<Vec<f64>> {
    let mut l = vec![0.0f64; n * n];
    for j in 0..n {
        let rj = j * n;
        let d = g[rj + j] - l[rj..rj + j].iter().map(|v| v * v).sum::<f64>();
        if !(d > 0.0 && d.is_finite()) {
            return Err(ModelError::Invalid(format!(
                "metric Gram matrix is not positive definite (Cholesky pivot {j} = {d:e})"
            )));
        }
        let djj = d.sqrt();
        l[rj + j] = djj;
        for i in j + 1..n {
            let ri = i * n;
            let s: f64 = l[ri..ri + j]
                .iter()
                .zip(&l[rj..rj + j])
                .map(|(a, b)| a * b)
                .sum();
            l[ri + j] = (g[ri + j] - s) / djj;
        }
    }
    Ok(l)
}

impl LossImpl {
    fn new(loss: &Loss, out_scale: &[f32]) -> Result<Self> {
        let Loss::Metric(g) = loss else {
            return Ok(Self::Mse);
        };
        let k = out_scale.len();
        if g.nrows() != k || g.ncols() != k {
            return Err(ModelError::Invalid(format!(
                "metric Gram matrix is {}×{}, expected {k}×{k} (one row per output)",
                g.nrows(),
                g.ncols()
            )));
        }
        let mut max_abs = 0.0f64;
        for j in 0..k {
            for i in 0..k {
                let v = g[(i, j)];
                if !v.is_finite() {
                    return Err(ModelError::Invalid(format!(
                        "metric Gram matrix entry ({i}, {j}) = {v} is not finite"
                    )));
                }
                max_abs = max_abs.max(v.abs());
            }
        }
        for j in 0..k {
            for i in j + 1..k {
                if (g[(i, j)] - g[(j, i)]).abs() > 1e-9 * max_abs {
                    return Err(ModelError::Invalid(format!(
                        "metric Gram matrix is not symmetric at ({i}, {j}): {} vs {}",
                        g[(i, j)],
                        g[(j, i)]
                    )));
                }
            }
        }
        // G̃ = S G S / (tr(S G S)/K), row-major, lower triangle.
        let s: Vec<f64> = out_scale.iter().map(|&v| f64::from(v)).collect();
        let trace: f64 = (0..k).map(|i| s[i] * s[i] * g[(i, i)]).sum();
        if trace.is_nan() || trace <= 0.0 {
            return Err(ModelError::Invalid(
                "metric Gram matrix has a non-positive trace".into(),
            ));
        }
        let norm = k as f64 / trace;
        let mut gt = vec![0.0f64; k * k];
        for i in 0..k {
            for j in 0..=i {
                gt[i * k + j] = s[i] * g[(i, j)] * s[j] * norm;
            }
        }
        let lrow = cholesky(&gt, k)?;
        // Column-major f32 copy: entry (i, j) at i + j·k; row-major lrow has it at i·k + j.
        let mut l = vec![0.0f32; k * k];
        for i in 0..k {
            for j in 0..=i {
                l[i + j * k] = lrow[i * k + j] as f32;
            }
        }
        Ok(Self::Metric { k, l })
    }

    /// Given the residual `e = o − ỹ` (`K × b`, column-major) in `e`, writes each sample's loss
    /// into `per_sample[..b]` and, if `grad_scale` is given, overwrites `e` with
    /// `grad_scale · ∂ℓ/∂o`. `tmp` holds `Lᵀ e` for the metric loss.
    fn eval(
        &self,
        e: &mut [f32],
        kk: usize,
        b: usize,
        per_sample: &mut [f64],
        grad_scale: Option<f32>,
        tmp: &mut Vec<f32>,
    ) {
        let inv_k = 1.0 / kk as f64;
        match self {
            Self::Mse => {
                for (col, ls) in e[..kk * b].chunks_exact(kk).zip(per_sample.iter_mut()) {
                    *ls = col
                        .iter()
                        .map(|&v| f64::from(v) * f64::from(v))
                        .sum::<f64>()
                        * inv_k;
                }
                if let Some(gs) = grad_scale {
                    let c = gs * 2.0 / kk as f32;
                    for v in &mut e[..kk * b] {
                        *v *= c;
                    }
                }
            }
            Self::Metric { k, l } => {
                debug_assert_eq!(*k, kk);
                tmp.resize(kk * b, 0.0);
                let lm = view(l, kk, kk);
                gemm(
                    view_mut(tmp, kk, b),
                    Accum::Replace,
                    lm.transpose(),
                    view(e, kk, b),
                    1.0,
                );
                for (col, ls) in tmp[..kk * b].chunks_exact(kk).zip(per_sample.iter_mut()) {
                    *ls = col
                        .iter()
                        .map(|&v| f64::from(v) * f64::from(v))
                        .sum::<f64>()
                        * inv_k;
                }
                if let Some(gs) = grad_scale {
                    gemm(
                        view_mut(e, kk, b),
                        Accum::Replace,
                        lm,
                        view(tmp, kk, b),
                        gs * 2.0 / kk as f32,
                    );
                }
            }
        }
    }
}

/// Buffers of one forward/backward pass with up to `bmax` samples.
struct Workspace {
    bmax: usize,
    xb: Vec<f32>,
    yb: Vec<f32>,
    acts: Vec<Vec<f32>>,
    deltas: Vec<Vec<f32>>,
    bias_acc: Vec<f64>,
    per_sample: Vec<f64>,
    tmp: Vec<f32>,
}

impl Workspace {
    fn new(model: &Mlp, bmax: usize) -> Self {
        Self {
            bmax,
            xb: vec![0.0; model.n_inputs() * bmax],
            yb: vec![0.0; model.n_outputs() * bmax],
            acts: model.activation_buffers(bmax),
            deltas: model.activation_buffers(bmax),
            bias_acc: vec![0.0; model.max_width()],
            per_sample: vec![0.0; bmax],
            tmp: Vec::new(),
        }
    }

    /// Copies the normalized samples `idx` (columns of `xt`, `yt`) into the batch buffers.
    fn gather(&mut self, xt: &[f32], yt: &[f32], nin: usize, nout: usize, idx: &[usize]) {
        debug_assert!(idx.len() <= self.bmax);
        for (j, &s) in idx.iter().enumerate() {
            self.xb[j * nin..(j + 1) * nin].copy_from_slice(&xt[s * nin..(s + 1) * nin]);
            self.yb[j * nout..(j + 1) * nout].copy_from_slice(&yt[s * nout..(s + 1) * nout]);
        }
    }

    /// Forward + loss (+ backward into `grad` when given) on the first `b` gathered samples.
    /// Returns the **sum** of the per-sample losses; the gradient is that of their **mean**.
    fn pass(&mut self, model: &Mlp, loss: &LossImpl, b: usize, grad: Option<&mut [f32]>) -> f64 {
        let (nin, nout) = (model.n_inputs(), model.n_outputs());
        let nl = model.n_layers();
        model.forward_cols(view(&self.xb, nin, b), &mut self.acts);
        // e = o − ỹ into the last delta buffer.
        let e = &mut self.deltas[nl - 1];
        for ((d, &o), &y) in e[..nout * b]
            .iter_mut()
            .zip(&self.acts[nl - 1][..nout * b])
            .zip(&self.yb[..nout * b])
        {
            *d = o - y;
        }
        let scale = grad.as_ref().map(|_| 1.0 / b as f32);
        loss.eval(e, nout, b, &mut self.per_sample, scale, &mut self.tmp);
        let total: f64 = self.per_sample[..b].iter().sum();
        let Some(grad) = grad else {
            return total;
        };
        for l in (0..nl).rev() {
            let lay = model.layout()[l];
            let (fo, fi) = (lay.fan_out, lay.fan_in);
            let (lower, upper) = self.deltas.split_at_mut(l);
            let dz = &upper[0];
            let input = if l == 0 {
                view(&self.xb, nin, b)
            } else {
                view(&self.acts[l - 1], fi, b)
            };
            // dW = dZ · inputᵀ (k = b is never split: deterministic).
            gemm(
                view_mut(&mut grad[lay.w_range()], fo, fi),
                Accum::Replace,
                view(dz, fo, b),
                input.transpose(),
                1.0,
            );
            // db = dZ · 1 (f64 accumulation).
            let acc = &mut self.bias_acc[..fo];
            acc.fill(0.0);
            for col in dz[..fo * b].chunks_exact(fo) {
                for (a, &v) in acc.iter_mut().zip(col) {
                    *a += f64::from(v);
                }
            }
            for (g, &a) in grad[lay.b_range()].iter_mut().zip(acc.iter()) {
                *g = a as f32;
            }
            if l > 0 {
                // dA = Wᵀ dZ, then dZ_{l−1} = dA ⊙ [h_{l−1} > 0].
                let da = &mut lower[l - 1];
                gemm(
                    view_mut(da, fi, b),
                    Accum::Replace,
                    model.weight(l).transpose(),
                    view(dz, fo, b),
                    1.0,
                );
                for (d, &h) in da[..fi * b].iter_mut().zip(&self.acts[l - 1][..fi * b]) {
                    if h <= 0.0 {
                        *d = 0.0;
                    }
                }
            }
        }
        total
    }
}

/// Column-major `dim × N` copy of a data matrix (`N × dim`, rows = samples), transformed by `f`
/// per sample.
fn to_columns(m: MatRef<'_, f32>, mut f: impl FnMut(&[f32], &mut [f32])) -> Vec<f32> {
    let (n, d) = (m.nrows(), m.ncols());
    let mut out = vec![0.0f32; n * d];
    let mut row = vec![0.0f32; d];
    for i in 0..n {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[(i, j)];
        }
        f(&row, &mut out[i * d..(i + 1) * d]);
    }
    out
}

fn check_finite(m: MatRef<'_, f32>, what: &str) -> Result<()> {
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            if !m[(i, j)].is_finite() {
                return Err(ModelError::Invalid(format!(
                    "{what} entry (sample {i}, column {j}) = {} is not finite",
                    m[(i, j)]
                )));
            }
        }
    }
    Ok(())
}

fn check_data(model: &Mlp, data: &MlpDataset<'_>, what: &str) -> Result<()> {
    if data.x.ncols() != model.n_inputs() || data.y.ncols() != model.n_outputs() {
        return Err(ModelError::Invalid(format!(
            "{what} set is {}→{}, the MLP is {}→{}",
            data.x.ncols(),
            data.y.ncols(),
            model.n_inputs(),
            model.n_outputs()
        )));
    }
    if data.x.nrows() != data.y.nrows() {
        return Err(ModelError::Invalid(format!(
            "{what} set has {} input rows but {} target rows",
            data.x.nrows(),
            data.y.nrows()
        )));
    }
    check_finite(data.x, &format!("{what} input"))?;
    check_finite(data.y, &format!("{what} target"))
}

/// Column means and population standard deviations (f64).
fn column_stats(m: MatRef<'_, f32>) -> (Vec<f64>, Vec<f64>) {
    let n = m.nrows() as f64;
    (0..m.ncols())
        .map(|j| {
            let mean = (0..m.nrows()).map(|i| f64::from(m[(i, j)])).sum::<f64>() / n;
            let var = (0..m.nrows())
                .map(|i| (f64::from(m[(i, j)]) - mean).powi(2))
                .sum::<f64>()
                / n;
            (mean, var.sqrt())
        })
        .unzip()
}

/// Fits the normalization of `model` to the training set (docs/design/splocs-model.md §5.1: z-scored inputs, σ floored).
fn fit_normalization(model: &mut Mlp, data: &MlpDataset<'_>, cfg: &MlpTrainConfig) -> Result<()> {
    let floor = f64::from(cfg.sigma_floor);
    let (xm, xs) = column_stats(data.x);
    let (ym, ys) = column_stats(data.y);
    let to32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let xs: Vec<f64> = xs.iter().map(|&s| s.max(floor)).collect();
    let nout = ys.len();
    let (ym, ys) = match cfg.output_norm {
        OutputNorm::PerDim => (ym, ys.iter().map(|&s| s.max(floor)).collect()),
        OutputNorm::Global => {
            let s = (ys.iter().map(|s| s * s).sum::<f64>() / nout as f64)
                .sqrt()
                .max(floor);
            (ym, vec![s; nout])
        }
        OutputNorm::Identity => (vec![0.0; nout], vec![1.0; nout]),
    };
    model.set_normalization(&to32(&xm), &to32(&xs), &to32(&ym), &to32(&ys))
}

/// Normalized column-major copies `(x̃: in × N, ỹ: out × N)` of a data set.
fn normalized(model: &Mlp, data: &MlpDataset<'_>) -> (Vec<f32>, Vec<f32>) {
    let xt = to_columns(data.x, |x, d| model.normalize_input(x, d));
    let (m, s) = (model.output_mean(), model.output_scale());
    let yt = to_columns(data.y, |y, d| {
        for k in 0..y.len() {
            d[k] = (y[k] - m[k]) / s[k];
        }
    });
    (xt, yt)
}

/// Mean loss over all columns of normalized data, in fixed chunks (deterministic).
fn mean_loss(model: &Mlp, loss: &LossImpl, xt: &[f32], yt: &[f32], n: usize) -> f64 {
    if n == 0 {
        return f64::NAN;
    }
    let (nin, nout) = (model.n_inputs(), model.n_outputs());
    let chunk = FORWARD_CHUNK.min(n);
    let mut ws = Workspace::new(model, chunk);
    let mut total = 0.0f64;
    for s0 in (0..n).step_by(chunk) {
        let b = chunk.min(n - s0);
        ws.xb[..nin * b].copy_from_slice(&xt[s0 * nin..(s0 + b) * nin]);
        ws.yb[..nout * b].copy_from_slice(&yt[s0 * nout..(s0 + b) * nout]);
        total += ws.pass(model, loss, b, None);
    }
    total / n as f64
}

/// Mean loss of `model` on `data` under `loss`, in the normalized output units of [`Loss`],
/// using the model's current normalization (f64 accumulation, deterministic).
///
/// Errors: [`ModelError::Invalid`] on mismatched sizes, non-finite data or an invalid metric.
pub fn evaluate(model: &Mlp, data: &MlpDataset<'_>, loss: &Loss) -> Result<f64> {
    check_data(model, data, "evaluation")?;
    let li = LossImpl::new(loss, model.output_scale())?;
    let (xt, yt) = normalized(model, data);
    Ok(mean_loss(model, &li, &xt, &yt, data.len()))
}

/// Mean loss and its gradient w.r.t. the flat parameters ([`Mlp::parameters`] layout), with the
/// whole data set as one batch: the quantities one AdamW step of [`train`] uses (f32 gradient,
/// f64 loss). Exposed for gradient checks.
///
/// Errors: as [`evaluate`]; also for an empty data set.
pub fn loss_gradient(model: &Mlp, data: &MlpDataset<'_>, loss: &Loss) -> Result<(f64, Vec<f32>)> {
    check_data(model, data, "gradient")?;
    if data.is_empty() {
        return Err(ModelError::Invalid("gradient of an empty data set".into()));
    }
    let li = LossImpl::new(loss, model.output_scale())?;
    let (xt, yt) = normalized(model, data);
    let n = data.len();
    let mut ws = Workspace::new(model, n);
    ws.xb.copy_from_slice(&xt);
    ws.yb.copy_from_slice(&yt);
    let mut grad = vec![0.0f32; model.parameters().len()];
    let total = ws.pass(model, &li, n, Some(&mut grad));
    Ok((total / n as f64, grad))
}

/// Cosine learning-rate schedule `lr(t) = lr_min + ½(lr_max − lr_min)(1 + cos(π t/T))` for step
/// `t` of `T` (Loshchilov & Hutter 2017, without restarts).
pub fn cosine_lr(lr_max: f64, lr_min: f64, t: usize, total: usize) -> f64 {
    if total <= 1 {
        return lr_max;
    }
    let frac = t as f64 / (total - 1) as f64;
    lr_min + 0.5 * (lr_max - lr_min) * (1.0 + (std::f64::consts::PI * frac).cos())
}

/// Constants of one AdamW step.
#[derive(Clone, Copy)]
struct AdamStep {
    lr: f32,
    decay: f32,
    b1: f32,
    b2: f32,
    eps: f32,
    step_size: f32,
    bc2_sqrt: f32,
}

/// AdamW (Loshchilov & Hutter 2019) on one parameter range, elementwise:
/// `p ← p(1 − lr·λ)`, `m ← β₁m + (1−β₁)g`, `v ← β₂v + (1−β₂)g²`,
/// `p ← p − (lr/(1−β₁ᵗ))·m / (√v/√(1−β₂ᵗ) + ε)`.
fn adamw(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], h: AdamStep) {
    p.par_chunks_mut(ADAM_CHUNK)
        .zip(g.par_chunks(ADAM_CHUNK))
        .zip(m.par_chunks_mut(ADAM_CHUNK))
        .zip(v.par_chunks_mut(ADAM_CHUNK))
        .for_each(|(((p, g), m), v)| {
            let keep = 1.0 - h.lr * h.decay;
            for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
                *m = h.b1 * *m + (1.0 - h.b1) * g;
                *v = h.b2 * *v + (1.0 - h.b2) * g * g;
                *p = *p * keep - h.step_size * *m / (v.sqrt() / h.bc2_sqrt + h.eps);
            }
        });
}

fn check_config(cfg: &MlpTrainConfig) -> Result<()> {
    let bad = |what: &str| Err(ModelError::Invalid(format!("training config: {what}")));
    if cfg.batch_size == 0 {
        return bad("batch_size must be positive");
    }
    if !(cfg.lr_max > 0.0
        && cfg.lr_max.is_finite()
        && cfg.lr_min >= 0.0
        && cfg.lr_min <= cfg.lr_max)
    {
        return bad("need 0 ≤ lr_min ≤ lr_max, lr_max > 0 and finite");
    }
    if !((0.0..1.0).contains(&cfg.beta1) && (0.0..1.0).contains(&cfg.beta2)) {
        return bad("Adam betas must lie in [0, 1)");
    }
    if !(cfg.eps > 0.0 && cfg.weight_decay >= 0.0 && cfg.weight_decay.is_finite()) {
        return bad("need eps > 0 and a finite weight_decay ≥ 0");
    }
    if !(cfg.sigma_floor > 0.0 && cfg.sigma_floor.is_finite()) {
        return bad("sigma_floor must be positive");
    }
    if !(0.0..1.0).contains(&cfg.min_rel_improvement) {
        return bad("min_rel_improvement must lie in [0, 1)");
    }
    Ok(())
}

/// Trains `model` in place by minibatch AdamW with a per-step cosine learning rate
/// (docs/design/splocs-model.md §5.1: lr 1e−3 → 1e−5, batch 128, weight decay 1e−5; docs/design/splocs-model.md §5.2 for the metric loss).
///
/// * If `cfg.fit_normalization`, the input z-scoring (σ floored at `cfg.sigma_floor`) and the
///   output normalization ([`OutputNorm`]) are first fitted to `train_set`.
/// * Each epoch visits the samples in a fresh Fisher–Yates order drawn from `cfg.seed`.
/// * After each epoch the callback gets [`EpochStats`]; returning `ControlFlow::Break(())`
///   stops training (the best weights are still restored).
/// * With a validation set, the weights of the epoch with the lowest validation loss are kept;
///   with `cfg.patience = Some(p)` training stops after `p` epochs without improvement.
/// * Determinism: same data, initial model and config ⇒ bit-identical weights for any rayon
///   pool size (fixed GEMM chunking, sequential f64 reductions, elementwise AdamW).
///
/// Errors: [`ModelError::Invalid`] for mismatched or non-finite data and bad configs;
/// [`ModelError::Numerical`] if the loss becomes non-finite.
pub fn train(
    model: &mut Mlp,
    train_set: &MlpDataset<'_>,
    val_set: Option<&MlpDataset<'_>>,
    cfg: &MlpTrainConfig,
    progress: &mut dyn FnMut(&EpochStats) -> ControlFlow<()>,
) -> Result<MlpTrainReport> {
    check_config(cfg)?;
    check_data(model, train_set, "training")?;
    if let Some(v) = val_set {
        check_data(model, v, "validation")?;
    }
    let n = train_set.len();
    if n == 0 {
        return Err(ModelError::Invalid("empty training set".into()));
    }
    if cfg.fit_normalization {
        fit_normalization(model, train_set, cfg)?;
    }
    let loss = LossImpl::new(&cfg.loss, model.output_scale())?;
    let (nin, nout) = (model.n_inputs(), model.n_outputs());
    let (xt, yt) = normalized(model, train_set);
    let val = val_set
        .filter(|v| !v.is_empty())
        .map(|v| (normalized(model, v), v.len()));

    let start = Instant::now();
    let bsz = cfg.batch_size.min(n);
    let steps_per_epoch = n.div_ceil(bsz);
    let total_steps = cfg.epochs * steps_per_epoch;
    let np = model.parameters().len();
    let (mut grad, mut m, mut v) = (vec![0.0f32; np], vec![0.0f32; np], vec![0.0f32; np]);
    let mut ws = Workspace::new(model, bsz);
    let mut rng = Rng::new(cfg.seed, SHUFFLE_STREAM);
    let mut order: Vec<usize> = (0..n).collect();
    let layout = model.layout().to_vec();

    let mut report = MlpTrainReport {
        history: Vec::new(),
        steps: 0,
        best_epoch: None,
        best_val_loss: None,
        stopped_early: false,
        cancelled: false,
        seconds: 0.0,
    };
    let mut best_params: Option<Vec<f32>> = None;
    let mut since_best = 0usize;
    let mut lr = cfg.lr_max;

    for epoch in 1..=cfg.epochs {
        rng.shuffle(&mut order);
        let mut epoch_loss = 0.0f64;
        for batch in order.chunks(bsz) {
            let b = batch.len();
            ws.gather(&xt, &yt, nin, nout, batch);
            let sum = ws.pass(model, &loss, b, Some(&mut grad));
            if !sum.is_finite() {
                return Err(ModelError::Numerical(format!(
                    "training loss became {sum} at epoch {epoch}, step {}",
                    report.steps + 1
                )));
            }
            epoch_loss += sum;
            let t = report.steps;
            lr = cosine_lr(cfg.lr_max, cfg.lr_min, t, total_steps);
            let tt = (t + 1) as i32;
            let base = AdamStep {
                lr: lr as f32,
                decay: 0.0,
                b1: cfg.beta1 as f32,
                b2: cfg.beta2 as f32,
                eps: cfg.eps as f32,
                step_size: (lr / (1.0 - cfg.beta1.powi(tt))) as f32,
                bc2_sqrt: (1.0 - cfg.beta2.powi(tt)).sqrt() as f32,
            };
            let params = model.parameters_mut();
            for lay in &layout {
                for (range, decay) in [
                    (lay.w_range(), cfg.weight_decay as f32),
                    (lay.b_range(), 0.0),
                ] {
                    adamw(
                        &mut params[range.clone()],
                        &grad[range.clone()],
                        &mut m[range.clone()],
                        &mut v[range],
                        AdamStep { decay, ..base },
                    );
                }
            }
            report.steps += 1;
        }
        let train_loss = epoch_loss / n as f64;
        let val_loss = val
            .as_ref()
            .map(|((vx, vy), vn)| mean_loss(model, &loss, vx, vy, *vn));
        let stats = EpochStats {
            epoch,
            train_loss,
            val_loss,
            lr,
            seconds: start.elapsed().as_secs_f64(),
        };
        report.history.push(stats);
        let flow = progress(&stats);
        if let Some(vl) = val_loss {
            if !vl.is_finite() {
                return Err(ModelError::Numerical(format!(
                    "validation loss became {vl} at epoch {epoch}"
                )));
            }
            let improved = match report.best_val_loss {
                None => true,
                Some(best) => vl < best * (1.0 - cfg.min_rel_improvement),
            };
            if improved {
                report.best_val_loss = Some(vl);
                report.best_epoch = Some(epoch);
                best_params = Some(model.parameters().to_vec());
                since_best = 0;
            } else {
                since_best += 1;
            }
        }
        if flow.is_break() {
            report.cancelled = true;
            break;
        }
        if cfg.patience.is_some_and(|p| since_best >= p) {
            report.stopped_early = true;
            break;
        }
    }
    if let Some(best) = best_params {
        model.parameters_mut().copy_from_slice(&best);
    }
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}
