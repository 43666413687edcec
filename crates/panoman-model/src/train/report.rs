//! The training report: [`ModelReport`] (what the training measured on its own rows; stored in
//! the model file) and [`TrainReport`] (`<out>.report.json`: the model report, the preset, the
//! stage timings and the held-out representation error). Layouts: `docs/formats.md`.
//!
//! Fields are declared in alphabetical order: the model file stores the report as a JSON
//! object with sorted keys, and a struct serializes its fields in declaration order.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::RepresentationError;
use crate::model::BlockName;

/// Training rows per kind (of the training identities).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RowCounts {
    /// Body-pose rows.
    pub body: usize,
    /// Expression rows.
    pub face: usize,
    /// Hand-gesture rows.
    pub hands: usize,
}

/// The shape PCA's size and explained variance.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ShapeSummary {
    /// Number of components.
    pub components: usize,
    /// Explained variance ratio per component.
    pub explained_per_component: Vec<f64>,
    /// Their sum.
    pub explained_variance: f64,
}

/// One block's sparse localized decomposition.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BlockSummary {
    /// Edges of the block's part (columns of its data matrix).
    pub columns: usize,
    /// Components.
    pub components: usize,
    /// Explained variance ratio of the decomposition on its rows.
    pub explained_variance: f64,
    /// Median over components of the fraction of columns each supports.
    pub median_support_fraction: f64,
    /// Non-zeros of the component matrix.
    pub nnz: usize,
    /// Outer iterations run.
    pub outer_iterations: usize,
    /// Training rows.
    pub rows: usize,
}

/// The correction MLP's training.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CorrectionSummary {
    /// Best validation loss (`None`: no validation rows).
    pub best_val_loss: Option<f64>,
    /// Epochs run (early stopping included).
    pub epochs_run: usize,
    /// Training loss of the last epoch.
    pub final_train_loss: Option<f64>,
    /// Explained variance ratio of the PCA head.
    pub head_explained: f64,
    /// Rank of the PCA head.
    pub head_rank: usize,
}

/// The motion MLP θ → β_B's training.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MotionSummary {
    /// Best validation loss (`None`: no validation rows).
    pub best_val_loss: Option<f64>,
    /// Epochs run (early stopping included).
    pub epochs_run: usize,
    /// Inputs (6 per bone: the first two columns of its rotation).
    pub inputs: usize,
}

/// Per block its decomposition, and the two MLPs (the `blocks` object of the report, keyed
/// by the block names of [`crate::model::BLOCK_NAMES`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BlockSummaries {
    /// RA of the body.
    pub body_a: Option<BlockSummary>,
    /// RL of the body.
    pub body_l: Option<BlockSummary>,
    /// The correction MLP (`None`: not trained).
    pub correction: Option<CorrectionSummary>,
    /// RA of the face.
    pub face_a: Option<BlockSummary>,
    /// RL of the face.
    pub face_l: Option<BlockSummary>,
    /// RA of the hands.
    pub hands_a: Option<BlockSummary>,
    /// RL of the hands.
    pub hands_l: Option<BlockSummary>,
    /// The motion MLP (`None`: not trained).
    pub motion: Option<MotionSummary>,
}

impl BlockSummaries {
    /// The summary slot of block `name`.
    pub(super) fn slot(&mut self, name: BlockName) -> &mut Option<BlockSummary> {
        match name {
            BlockName::BodyLength => &mut self.body_l,
            BlockName::FaceLength => &mut self.face_l,
            BlockName::HandsLength => &mut self.hands_l,
            BlockName::BodyAngle => &mut self.body_a,
            BlockName::FaceAngle => &mut self.face_a,
            BlockName::HandsAngle => &mut self.hands_a,
        }
    }
}

/// What the training measured on its own rows (deterministic: no timings); stored in the
/// model file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ModelReport {
    /// Per block and MLP.
    pub blocks: BlockSummaries,
    /// Held-out identities (not trained on).
    pub held_out_identities: usize,
    /// Training rows per kind.
    pub rows: RowCounts,
    /// The shape PCA.
    pub shape: ShapeSummary,
    /// Training identities.
    pub train_identities: usize,
}

/// The training report (`<out>.report.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainReport {
    /// What the training measured ([`ModelReport`]).
    pub model: ModelReport,
    /// The configuration's preset name.
    pub preset: String,
    /// The held-out representation error (`None` until the evaluation has run: a run stopped
    /// during the evaluation leaves a report that does not read as complete).
    pub representation_error: Option<RepresentationError>,
    /// Wall time per stage (s): `shape_s`, `rla_s`, `splocs_<block>_s`, `correction_s`,
    /// `motion_s`, `total_s`, and the evaluation's `evaluation_s`, `curves_s`.
    pub timings: BTreeMap<String, f64>,
}
