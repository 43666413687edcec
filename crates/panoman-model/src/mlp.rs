//! The correction MLP `R(β_B)` and the motion MLP `θ → β` (docs/design/splocs-model.md §5): a small,
//! deterministic MLP toolkit on faer's GEMM (f32 parameters and activations, f64 loss and
//! statistics accumulation), following the measurements of docs/design/architecture.md §6.2–6.3 (a hand-written MLP on
//! faer beats candle ≈ 10×).
//!
//! * [`Mlp`]: `Linear → ReLU → … → Linear` with input z-scoring (σ floored at 1e−3) and output
//!   de-normalization; batched [`Mlp::forward`], allocation-light [`Mlp::forward_one`], and the
//!   input Jacobian in factored form [`Mlp::jacobian`] (docs/design/shell-fit.md §3.2: `∂R/∂β = P·G`).
//! * [`train`]: minibatch AdamW with cosine decay, early stopping on a caller-given validation
//!   split (held-out identities), MSE or the Gram-metric loss `(ŷ−y)ᵀG(ŷ−y)` of docs/design/splocs-model.md §5.2 through a
//!   Cholesky factor, seeded and bit-reproducible for any rayon pool size.
//! * [`PcaHead`]: weighted randomized PCA of the correction targets (docs/design/splocs-model.md §5.1), so the correction
//!   MLP predicts `r = 128–256` codes `c = Pᵀ(w ⊙ (y − μ))`.
//! * [`TensorStore`]: safetensors model files holding several MLPs and heads under name
//!   prefixes, with JSON configs in the header metadata.
//!
//! Determinism (docs/design/splocs-model.md §3.9): every GEMM runs as sequential faer calls over a
//! block partition that depends only on the matrix shapes, never splitting the inner
//! dimension; reductions are sequential in f64; shuffles and initializations come from seeded
//! xoshiro256** streams. Hence the same data, seed and config give bit-identical weights with
//! 1 or N threads.

mod gemm;
mod jacobian;
mod net;
mod pca_head;
mod rng;
mod store;
mod train;

pub use jacobian::FactoredJacobian;
pub use net::{ForwardScratch, Mlp};
pub use pca_head::{PcaHead, PcaHeadFit, PcaHeadOptions};
pub use store::{Element, Tensor, TensorData, TensorStore};
pub use train::{
    EpochStats, Loss, MlpDataset, MlpTrainConfig, MlpTrainReport, OutputNorm, cosine_lr, evaluate,
    loss_gradient, train,
};
