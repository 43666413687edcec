//! # panoman-model
//!
//! The PanoMan model (paper §4.2, §4.4, Eq. 2–5): shape PCA `B_S(α) = V̄ + Sα`, sparse localized
//! components over per-edge RL/RA scalars (SPLOCS with ℓ1 soft-thresholding and adaptive
//! supports, docs/design/splocs-model.md §3), the correction MLP `R(β_body)` and the motion MLP `θ → β`
//! (docs/design/splocs-model.md §5), and model files.
//!
//! Large learning matrices are f32; Gram matrices, objectives and factorizations are f64.

pub mod error;
pub mod geodesic;
pub mod mlp;
pub mod model;
pub mod pca;
pub mod splocs;
pub mod train;

pub use error::{ModelError, Result};
