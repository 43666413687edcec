//! Training the PanoMan model from a dataset H (paper §4.2–4.4; docs/design/splocs-model.md §3, §5).
//!
//! Stages (each timed in the report):
//! 1. **shape**: PCA of the training identities' rest shapes (Eq. 2);
//! 2. **rla**: RL/RA of every training row w.r.t. its identity's rest row;
//! 3. **decompositions**: six sparse localized decompositions {RL, RA} × {body, face, hands},
//!    body on the body rows H_B over the body edges, face on the expression rows H_F over the
//!    face edges plus a margin, hands on the gesture rows H_H over both hands' edges plus a
//!    margin; geodesics on the mean rest shape. Components are stored sorted by their energy
//!    (so the first k are the best k);
//! 4. **correction**: residuals of the truncated body decomposition on H_B, a weighted PCA head
//!    (RL × 1, RA × ω_e with the dimensionless ω_e = ℓ_e/sqrt((A_fL + A_fR)/3) on V̄) and the MLP
//!    `(β_LB, β_AB) → codes` (Eq. 4);
//! 5. **motion**: the MLP `θ → (β_LB, β_AB)` on 6-D bone rotations with the Gram-metric loss.
//!
//! The held-out identities are never used for training; [`evaluate_representation`] measures
//! the representation error on them.

use crate::error::{ModelError, Result};
use crate::geodesic::{EdgeGeodesics, PartGeodesics};
use crate::mlp::{self, Loss, Mlp, OutputNorm, PcaHead, PcaHeadOptions};
use crate::model::{
    BLOCK_NAMES, ComponentBlock, CorrectionMlp, Evaluator, GnOptions, KeypointRows, Motion,
    PanoManModel,
};
use crate::pca::ShapePca;
use crate::splocs::{self, Decomposition, SparseRows, SplocsOptions};
use faer::Mat;
use panoman_human::dataset::Dataset;
use panoman_human::regions::{Part, Regions};
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_mesh::{RestGeometry, Rla, Topology};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::sync::Arc;
use std::time::Instant;

mod report;
mod stages;

pub use report::{
    BlockSummaries, BlockSummary, CorrectionSummary, ModelReport, MotionSummary, RowCounts,
    ShapeSummary, TrainReport,
};

use stages::{
    BodyCoefficients, StageLog, decompose, shape_pca, sorted_blocks, train_correction,
    train_motion, training_rla,
};

/// Training configuration (see [`TrainConfig::preset`]). Read back from model files with the
/// default preset's values for the fields an older file lacks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrainConfig {
    /// Preset name.
    pub preset: String,
    /// Shape components.
    pub n_shape: usize,
    /// Components per part: body, face, hands (same for RL and RA).
    pub components: [usize; 3],
    /// Ring margin added around the face and hand parts.
    pub margin_rings: usize,
    /// SPLOCS outer iterations cap.
    pub splocs_outer_iters: usize,
    /// SPLOCS sparsity weight λ at N = 100 samples; a block with N rows uses
    /// `λ·sqrt(N/100)` (the residual noise a component absorbs grows like √N, so a fixed λ
    /// leaves components dense on large data).
    pub splocs_lambda: f64,
    /// Support bounds d_min (metres): body, face/hands.
    pub d_min_body: [f64; 2],
    /// Support bounds d_min (metres) of face and hands.
    pub d_min_small: [f64; 2],
    /// Correction MLP hidden width (0 = no correction MLP).
    pub correction_hidden: usize,
    /// Maximum rank of the correction's PCA head.
    pub correction_rank: usize,
    /// Correction MLP epochs.
    pub correction_epochs: usize,
    /// Decoupled (AdamW) weight decay of the correction MLP (the MLP memorizes its training
    /// rows without it: docs/design/splocs-model.md §5.1).
    pub correction_weight_decay: f64,
    /// Early-stopping patience (epochs) of the correction MLP on the validation identities.
    pub correction_patience: usize,
    /// Motion MLP hidden widths (empty = no motion MLP).
    pub motion_hidden: Vec<usize>,
    /// Motion MLP epochs.
    pub motion_epochs: usize,
    /// Held-out rows per kind used by the evaluation (0 = all).
    pub eval_rows_per_kind: usize,
    /// Whether the evaluation also measures the Gauss–Newton encoder (the `*_gn` figures;
    /// seconds per full-template row).
    pub eval_gn: bool,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig::preset("default").expect("the default preset exists")
    }
}

impl TrainConfig {
    /// `small` (CI: minutes on the small topology) or `default` (the paper's sizes: 10 shape
    /// components, 250/100/50 components, MLPs 1500 and 400–600 wide).
    pub fn preset(name: &str) -> Result<TrainConfig> {
        match name {
            "small" => Ok(TrainConfig {
                preset: "small".into(),
                n_shape: 6,
                components: [24, 12, 8],
                margin_rings: 2,
                splocs_outer_iters: 12,
                splocs_lambda: 2.0,
                d_min_body: [0.04, 0.30],
                d_min_small: [0.005, 0.05],
                correction_hidden: 128,
                correction_rank: 16,
                correction_epochs: 150,
                correction_weight_decay: 1e-5,
                correction_patience: 30,
                motion_hidden: vec![64, 64],
                motion_epochs: 150,
                eval_rows_per_kind: 0,
                eval_gn: false,
                seed: 0,
            }),
            "default" => Ok(TrainConfig {
                preset: "default".into(),
                n_shape: 10,
                components: [250, 100, 50],
                margin_rings: 2,
                splocs_outer_iters: 30,
                splocs_lambda: 2.0,
                d_min_body: [0.04, 0.30],
                d_min_small: [0.005, 0.05],
                correction_hidden: 1500,
                correction_rank: 192,
                correction_epochs: 200,
                correction_weight_decay: 1e-5,
                correction_patience: 30,
                motion_hidden: vec![400, 600],
                motion_epochs: 300,
                eval_rows_per_kind: 40,
                eval_gn: true,
                seed: 0,
            }),
            other => Err(ModelError::Invalid(format!(
                "unknown preset '{other}' (known: small, default)"
            ))),
        }
    }
}

/// What training needs besides the dataset: the template topology and its regions.
pub struct TrainInputs<'a> {
    /// The dataset (validated).
    pub dataset: &'a Dataset,
    /// Topology name ("full" or "small").
    pub topology_name: String,
    /// Template triangles (their hash must equal the dataset's).
    pub faces: Vec<[u32; 3]>,
    /// Part labels of the template.
    pub regions: &'a Regions,
    /// Keypoint definitions to store in the model.
    pub keypoints: KeypointRows,
}

/// One point of the paper's Fig. 7: a part truncated to its first `k` components.
#[derive(Clone, Debug, Serialize)]
pub struct CurvePoint {
    /// "body", "face" or "hands".
    pub part: String,
    /// Components kept (RL and RA each).
    pub k: usize,
    /// RMS of the RL residual on the part's columns (held-out rows).
    pub rl_rms: f64,
    /// RMS of the RA residual on the part's columns (radians).
    pub ra_rms: f64,
    /// Mean per-vertex error of the rebuilt mesh on the part's region (mm).
    pub mesh_mean_mm: f64,
    /// Max per-vertex error (mm).
    pub mesh_max_mm: f64,
}

/// Representation error of one part on held-out rows.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartError {
    /// Rows evaluated.
    pub rows: usize,
    /// Mean per-vertex error on the region (mm), model rest shape B_S(α), no correction; the
    /// region is the whole mesh (body poses), the face (expressions) or each hand (gestures),
    /// each rigidly aligned on itself.
    pub mean_mm: f64,
    /// Max per-vertex error (mm), as above.
    pub max_mm: f64,
    /// Mean (mm) with the correction MLP.
    pub mean_mm_corrected: f64,
    /// Max (mm) with the correction MLP.
    pub max_mm_corrected: f64,
    /// Mean (mm) with the identity's exact rest shape instead of B_S(α) (isolates the motion
    /// model from the shape PCA), no correction.
    pub mean_mm_exact_rest: f64,
    /// Max (mm), exact rest shape.
    pub max_mm_exact_rest: f64,
    /// Mean (mm) when the whole mesh is aligned at once instead of each part on its own (for
    /// face and hands this adds the drift of the body chain to the part's error).
    pub mean_mm_whole_alignment: f64,
    /// Mean (mm), β refined by Gauss–Newton on the vertex error ([`Evaluator::refine_beta`],
    /// started from the least-squares β), no correction. 0 in reports written before it.
    #[serde(default)]
    pub mean_mm_gn: f64,
    /// Max (mm), Gauss–Newton β, no correction.
    #[serde(default)]
    pub max_mm_gn: f64,
    /// Mean (mm), Gauss–Newton β with the correction MLP.
    #[serde(default)]
    pub mean_mm_gn_corrected: f64,
    /// Max (mm), Gauss–Newton β with the correction MLP.
    #[serde(default)]
    pub max_mm_gn_corrected: f64,
    /// Index of the dataset row with the largest error (least-squares β, no correction).
    #[serde(default)]
    pub worst_row: usize,
    /// The vertex of that maximum.
    #[serde(default)]
    pub worst_vertex: usize,
}

/// Held-out representation error per part ([`evaluate_representation`]); serializes as
/// `{"body": PartError, "face": …, "hands": …}`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RepresentationError {
    /// Body poses, whole mesh.
    pub body: PartError,
    /// Expressions, the face aligned on itself.
    pub face: PartError,
    /// Gestures, each hand aligned on itself.
    pub hands: PartError,
}

/// Wall times of [`evaluate`] (s).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvaluationTimings {
    /// [`evaluate_representation`].
    pub evaluation_s: f64,
    /// [`component_curves`].
    pub curves_s: f64,
}

/// What [`evaluate`] measures (the `representation_error` and timing entries of the training
/// report).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Evaluation {
    /// Held-out representation error per part.
    pub representation_error: RepresentationError,
    /// Wall times.
    pub timings: EvaluationTimings,
    /// The Fig. 7 curves.
    #[serde(skip)]
    pub curves: Vec<CurvePoint>,
}

/// Result of training.
pub struct TrainOutput {
    /// The model (its `report` holds the deterministic parts of the report).
    pub model: PanoManModel,
    /// Full training report (with timings; the representation error is filled by
    /// [`evaluate`]'s caller).
    pub report: TrainReport,
}

struct RowRla {
    rl: Vec<f32>,
    ra: Vec<f32>,
}

fn to_v3(p: &[[f32; 3]]) -> Vec<V3> {
    p.iter()
        .map(|x| [x[0] as f64, x[1] as f64, x[2] as f64])
        .collect()
}

/// Reads row `r`'s vertices (f64).
fn row_vertices(ds: &Dataset, r: usize) -> Result<Vec<V3>> {
    Ok(to_v3(
        &ds.vertices(r)
            .map_err(|e| ModelError::Invalid(e.to_string()))?,
    ))
}

/// Columns of the three parts: body = edges labelled body; face = face mask with margin;
/// hands = left ∪ right hand masks with margin.
pub fn part_columns(regions: &Regions, margin: usize) -> [Vec<u32>; 3] {
    let body: Vec<u32> = regions
        .edge_part
        .iter()
        .enumerate()
        .filter(|(_, p)| **p == Part::Body)
        .map(|(e, _)| e as u32)
        .collect();
    let face = regions.mask(Part::Face, margin).edge_ids();
    let l = regions.mask(Part::LeftHand, margin).edges;
    let r = regions.mask(Part::RightHand, margin).edges;
    let hands: Vec<u32> = (0..l.len())
        .filter(|&e| l[e] || r[e])
        .map(|e| e as u32)
        .collect();
    [body, face, hands]
}

/// Trains a model (see the module docs). `progress(stage)` is called at each stage start,
/// and within the long stages (each SPLOCS outer iteration, each MLP epoch) with
/// `"{stage} ({detail})"`: a message that extends the current stage's name followed by ` (`
/// is a detail of that stage, not a new stage.
pub fn train(
    inputs: &TrainInputs<'_>,
    cfg: &TrainConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<TrainOutput> {
    let ds = inputs.dataset;
    let t_all = Instant::now();
    let topo = Topology::build(ds.n_vertices, &inputs.faces)?;
    if topo.hash_hex() != ds.topology_hash {
        return Err(ModelError::Invalid(format!(
            "the dataset's topology hash {} differs from the {} template's {}",
            ds.topology_hash,
            inputs.topology_name,
            topo.hash_hex()
        )));
    }
    let is_train: Vec<bool> = {
        let n_id = ds
            .identity
            .iter()
            .copied()
            .max()
            .map_or(0, |m| m as usize + 1);
        let mut v = vec![false; n_id];
        for &i in &ds.train {
            v[i as usize] = true;
        }
        v
    };
    let rows_of = |kind: u8, train: bool| -> Vec<usize> {
        (0..ds.n_rows)
            .filter(|&r| ds.kind[r] == kind && is_train[ds.identity[r] as usize] == train)
            .collect()
    };
    let mut log = StageLog {
        progress,
        timings: BTreeMap::new(),
        blocks: BlockSummaries::default(),
    };

    // 1. Shape PCA.
    (log.progress)("shape PCA");
    let t = Instant::now();
    let shape = shape_pca(ds, &rows_of(0, true), cfg.n_shape)?;
    log.time("shape_s", t);
    let nv = ds.n_vertices;
    let vbar: Vec<V3> = shape
        .mean
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();

    // 2. RLA of the training rows, per kind.
    (log.progress)("RL/RA of the training rows");
    let t = Instant::now();
    let kinds_rows: [Vec<usize>; 3] = [rows_of(1, true), rows_of(2, true), rows_of(3, true)];
    let rlas = training_rla(ds, &topo, &kinds_rows)?;
    log.time("rla_s", t);

    // 3. Decompositions, then the blocks with their components sorted by energy.
    let cols = part_columns(inputs.regions, cfg.margin_rings);
    let decs = decompose(&topo, &vbar, &cols, &rlas, cfg, &mut log)?;
    let (blocks, orders) = sorted_blocks(&decs, &cols);
    let body = BodyCoefficients::new(&decs, &orders, &blocks, rlas[0].len());
    // Validation split of the training identities (for early stopping): every 7th identity.
    let body_rows = &kinds_rows[0];
    let val_mask: Vec<bool> = body_rows.iter().map(|&r| ds.identity[r] % 7 == 3).collect();

    // 4. Correction MLP.
    let correction = if cfg.correction_hidden > 0 {
        Some(train_correction(
            &topo, &vbar, &blocks, &rlas[0], &body, &val_mask, cfg, &mut log,
        )?)
    } else {
        None
    };

    // 5. Motion MLP θ → β_B.
    let motion = if !cfg.motion_hidden.is_empty() {
        Some(train_motion(
            ds, body_rows, &blocks, &body, &val_mask, cfg, &mut log,
        )?)
    } else {
        None
    };

    let explained_shape: f64 = shape.explained_variance_ratio.iter().sum();
    let det_report = ModelReport {
        train_identities: ds.train.len(),
        held_out_identities: ds.held_out.len(),
        rows: RowCounts {
            body: kinds_rows[0].len(),
            face: kinds_rows[1].len(),
            hands: kinds_rows[2].len(),
        },
        shape: ShapeSummary {
            components: shape.n_components(),
            explained_variance: explained_shape,
            explained_per_component: shape.explained_variance_ratio.clone(),
        },
        blocks: std::mem::take(&mut log.blocks),
    };
    let model = PanoManModel {
        topology_name: inputs.topology_name.clone(),
        topology_hash: topo.hash_hex(),
        faces: inputs.faces.clone(),
        n_vertices: nv,
        shape,
        blocks,
        correction,
        motion,
        edge_part: inputs
            .regions
            .edge_part
            .iter()
            .map(|p| p.index() as u8)
            .collect(),
        keypoints: inputs.keypoints.clone(),
        config: Some(cfg.clone()),
        report: Some(det_report.clone()),
        rig: None,
    };

    log.time("total_s", t_all);
    let report = TrainReport {
        preset: cfg.preset.clone(),
        model: det_report,
        representation_error: None,
        timings: log.timings,
    };
    Ok(TrainOutput { model, report })
}

/// Evaluation after training (paper §6.1): the held-out representation error
/// ([`evaluate_representation`]) and the Fig. 7 curves ([`component_curves`]); returns the
/// errors, the curve points and the timings.
pub fn evaluate(
    model: &Arc<PanoManModel>,
    ds: &Dataset,
    regions: &Regions,
    cfg: &TrainConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Evaluation> {
    let stage = "representation error (held-out identities)";
    progress(stage);
    let t = Instant::now();
    let gn = GnOptions::default();
    let gn = cfg.eval_gn.then_some(&gn);
    let eval = evaluate_representation(model, ds, regions, cfg.eval_rows_per_kind, gn, &mut |d| {
        progress(&format!("{stage} ({d})"))
    })?;
    let eval_s = t.elapsed().as_secs_f64();
    let stage = "component curves (Fig. 7)";
    progress(stage);
    let t = Instant::now();
    let curve_rows = if cfg.eval_rows_per_kind == 0 {
        0
    } else {
        cfg.eval_rows_per_kind.min(12)
    };
    let curves = component_curves(model, ds, regions, curve_rows, &mut |d| {
        progress(&format!("{stage} ({d})"))
    })?;
    Ok(Evaluation {
        representation_error: eval,
        timings: EvaluationTimings {
            evaluation_s: eval_s,
            curves_s: t.elapsed().as_secs_f64(),
        },
        curves,
    })
}

fn is_body_bone(name: &str) -> bool {
    !(name.starts_with("finger")
        || name.starts_with("metacarpal")
        || name == "jaw"
        || name.starts_with("eye"))
}

fn split_rows(
    x: &Mat<f32>,
    y: &Mat<f32>,
    val: &[bool],
) -> (Mat<f32>, Mat<f32>, Mat<f32>, Mat<f32>) {
    let tr: Vec<usize> = (0..x.nrows()).filter(|&i| !val[i]).collect();
    let va: Vec<usize> = (0..x.nrows()).filter(|&i| val[i]).collect();
    let pick = |m: &Mat<f32>, rows: &[usize]| {
        Mat::<f32>::from_fn(rows.len(), m.ncols(), |i, j| m[(rows[i], j)])
    };
    (pick(x, &tr), pick(y, &tr), pick(x, &va), pick(y, &va))
}

fn block_reconstruct(b: &ComponentBlock, beta: &[f64]) -> Vec<f64> {
    let mut out: Vec<f64> = b.mean.iter().map(|&m| m as f64).collect();
    for (k, &bk) in beta.iter().enumerate() {
        if bk == 0.0 {
            continue;
        }
        let (cols, vals) = b.components.row(k);
        for (&j, &v) in cols.iter().zip(vals) {
            out[j as usize] += bk * v as f64;
        }
    }
    out
}

/// Median over components of the fraction of the block's columns with a non-zero weight.
fn median_support(c: &SparseRows) -> f64 {
    let mut f: Vec<f64> = (0..c.n_rows())
        .map(|k| c.row(k).0.len() as f64 / c.n_cols.max(1) as f64)
        .filter(|&x| x > 0.0)
        .collect();
    if f.is_empty() {
        return 0.0;
    }
    f.sort_by(f64::total_cmp);
    f[f.len() / 2]
}

/// The dimensionless bending weight `ω_e = ℓ_e / sqrt((A_fL + A_fR)/3)` on `positions`
/// (docs/design/shell-fit.md §2.1, Fröhlich–Botsch); 0 on boundary edges.
pub fn bending_weights(topo: &Topology, positions: &[V3]) -> Vec<f64> {
    let area = |f: u32| {
        let [a, b, c] = topo.faces[f as usize];
        let (pa, pb, pc) = (
            positions[a as usize],
            positions[b as usize],
            positions[c as usize],
        );
        0.5 * norm(panoman_mesh::geom::cross(sub(pb, pa), sub(pc, pa)))
    };
    (0..topo.n_edges())
        .map(|e| {
            let [fl, fr] = topo.edge_faces[e];
            if !topo.is_interior(e) {
                return 0.0;
            }
            let [i, j] = topo.edges[e];
            let l = norm(sub(positions[j as usize], positions[i as usize]));
            l / ((area(fl) + area(fr)) / 3.0).sqrt()
        })
        .collect()
}

/// Vertex groups a row kind is evaluated on, each rigidly aligned on its own: the whole mesh
/// (body poses), the face (expressions), each hand separately (gestures) — the paper evaluates
/// its face and hand models on face and hand meshes (FaceWarehouse, MANO), so a part's error is
/// measured in the part's own frame.
fn region_groups(regions: &Regions, kind: u8) -> Vec<Vec<u32>> {
    match kind {
        2 => vec![regions.vertices_of(Part::Face)],
        3 => vec![
            regions.vertices_of(Part::LeftHand),
            regions.vertices_of(Part::RightHand),
        ],
        _ => vec![(0..regions.n_vertices() as u32).collect()],
    }
}

fn held_out_rows(ds: &Dataset, kind: u8, limit: usize) -> Vec<usize> {
    let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
    let rows: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == kind && held.contains(&ds.identity[r]))
        .collect();
    if limit == 0 || rows.len() <= limit {
        rows
    } else {
        // Evenly spaced subset (deterministic).
        (0..limit).map(|i| rows[i * rows.len() / limit]).collect()
    }
}

/// [`region_errors`] with per-group alignment, also returning the vertex of the maximum.
fn region_errors_argmax(a: &[V3], b: &[V3], groups: &[Vec<u32>]) -> (f64, f64, usize) {
    let (mut sum, mut cnt, mut max, mut arg) = (0.0, 0usize, 0.0f64, 0usize);
    for g in groups {
        let mut w = vec![0.0; a.len()];
        for &v in g {
            w[v as usize] = 1.0;
        }
        let m = rigid_align(a, b, Some(&w));
        for &v in g {
            let d = norm(sub(m.apply(a[v as usize]), b[v as usize]));
            sum += d;
            if d > max {
                max = d;
                arg = v as usize;
            }
        }
        cnt += g.len();
    }
    (sum / cnt.max(1) as f64, max, arg)
}

/// Per-vertex errors (m) of `a` against `b` over `groups`: each group is rigidly aligned on its
/// own vertices (Kabsch), or all groups by one alignment of the whole mesh when `whole`.
/// Returns (mean over all group vertices, max).
fn region_errors(a: &[V3], b: &[V3], groups: &[Vec<u32>], whole: bool) -> (f64, f64) {
    let mut sum = 0.0;
    let mut cnt = 0usize;
    let mut max = 0.0f64;
    let global = whole.then(|| rigid_align(a, b, None));
    for g in groups {
        let m = match &global {
            Some(m) => *m,
            None => {
                let mut w = vec![0.0; a.len()];
                for &v in g {
                    w[v as usize] = 1.0;
                }
                rigid_align(a, b, Some(&w))
            }
        };
        for &v in g {
            let d = norm(sub(m.apply(a[v as usize]), b[v as usize]));
            sum += d;
            max = max.max(d);
        }
        cnt += g.len();
    }
    (sum / cnt.max(1) as f64, max)
}

/// Representation error on held-out identities (see [`PartError`]): each held-out row is
/// encoded (α from its identity's rest shape, β by least squares on its RL/RA, then also
/// refined by Gauss–Newton on the vertex error with `gn` when given; the `*_gn` figures stay 0
/// otherwise), rebuilt with g, rigidly aligned to
/// the row and compared on its region. `progress(detail)` hears each row as it starts, with
/// an estimate of the time left once a row is done (`"body row 3/40, about 95 min left"`).
pub fn evaluate_representation(
    model: &Arc<PanoManModel>,
    ds: &Dataset,
    regions: &Regions,
    rows_per_kind: usize,
    gn: Option<&GnOptions>,
    progress: &mut dyn FnMut(&str),
) -> Result<RepresentationError> {
    let mut ev = Evaluator::new(model.clone())?;
    let mut out = RepresentationError::default();
    let total: usize = [1u8, 2, 3]
        .iter()
        .map(|&k| held_out_rows(ds, k, rows_per_kind).len())
        .sum();
    let (t0, mut done) = (std::time::Instant::now(), 0usize);
    for (kind, name, slot) in [
        (1u8, "body", &mut out.body),
        (2, "face", &mut out.face),
        (3, "hands", &mut out.hands),
    ] {
        let rows = held_out_rows(ds, kind, rows_per_kind);
        let region = region_groups(regions, kind);
        let mut pe = PartError {
            rows: rows.len(),
            ..Default::default()
        };
        for (i, &r) in rows.iter().enumerate() {
            let eta = remaining(t0.elapsed().as_secs_f64(), done, total);
            progress(&format!("{name} row {}/{}{eta}", i + 1, rows.len()));
            done += 1;
            let mesh = row_vertices(ds, r)?;
            let rest = row_vertices(ds, ds.rest_of[r] as usize)?;
            let p = ev.encode(&mesh, Some(&rest), false)?;
            let posed = ev.pose(&p, false)?;
            let (m, x, v) = region_errors_argmax(&posed, &mesh, &region);
            pe.mean_mm += m;
            if x > pe.max_mm {
                pe.max_mm = x;
                pe.worst_row = r;
                pe.worst_vertex = v;
            }
            pe.mean_mm_whole_alignment += region_errors(&posed, &mesh, &region, true).0;
            // Exact rest: RLA of the model added to the identity's own rest shape.
            let rla = model.rla(&p, false);
            let exact = ev.reconstruct(&rest, &rla)?;
            let (m, x) = region_errors(&exact, &mesh, &region, false);
            pe.mean_mm_exact_rest += m;
            pe.max_mm_exact_rest = pe.max_mm_exact_rest.max(x);
            // Gauss–Newton β from the least-squares start.
            if let Some(gn) = gn {
                let mut pg = p.clone();
                ev.refine_beta(&mesh, &mut pg, false, gn)?;
                let (m, x) = region_errors(&ev.pose(&pg, false)?, &mesh, &region, false);
                pe.mean_mm_gn += m;
                pe.max_mm_gn = pe.max_mm_gn.max(x);
            }
            if model.correction.is_some() {
                let mut pc = ev.encode(&mesh, Some(&rest), true)?;
                let posed = ev.pose(&pc, true)?;
                let (m, x) = region_errors(&posed, &mesh, &region, false);
                pe.mean_mm_corrected += m;
                pe.max_mm_corrected = pe.max_mm_corrected.max(x);
                if let Some(gn) = gn {
                    ev.refine_beta(&mesh, &mut pc, true, gn)?;
                    let (m, x) = region_errors(&ev.pose(&pc, true)?, &mesh, &region, false);
                    pe.mean_mm_gn_corrected += m;
                    pe.max_mm_gn_corrected = pe.max_mm_gn_corrected.max(x);
                }
            }
        }
        let n = rows.len().max(1) as f64;
        pe.mean_mm *= 1e3 / n;
        pe.mean_mm_whole_alignment *= 1e3 / n;
        pe.max_mm *= 1e3;
        pe.mean_mm_corrected *= 1e3 / n;
        pe.max_mm_corrected *= 1e3;
        pe.mean_mm_exact_rest *= 1e3 / n;
        pe.max_mm_exact_rest *= 1e3;
        pe.mean_mm_gn *= 1e3 / n;
        pe.max_mm_gn *= 1e3;
        pe.mean_mm_gn_corrected *= 1e3 / n;
        pe.max_mm_gn_corrected *= 1e3;
        *slot = pe;
    }
    Ok(out)
}

/// `", about N min left"` for `done` of `total` rows after `elapsed_s` seconds (the mean time per
/// row so far, over the rows left); empty before the first row is done.
fn remaining(elapsed_s: f64, done: usize, total: usize) -> String {
    if done == 0 || done >= total {
        return String::new();
    }
    let left = elapsed_s / done as f64 * (total - done) as f64;
    if left < 90.0 {
        format!(", about {left:.0} s left")
    } else if left < 5400.0 {
        format!(", about {:.0} min left", left / 60.0)
    } else {
        format!(", about {:.1} h left", left / 3600.0)
    }
}

/// The paper's Fig. 7 on held-out rows: for each part and k, the part's RL and RA blocks are
/// truncated to their first k components (sorted by energy), the rows are encoded and rebuilt,
/// and the RLA residual and mesh error on the part's region are recorded. `progress(detail)`
/// hears each truncation as it starts (`"body k = 25 (5/11)"`).
pub fn component_curves(
    model: &PanoManModel,
    ds: &Dataset,
    regions: &Regions,
    rows_per_kind: usize,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<CurvePoint>> {
    let mut points = Vec::new();
    // Topology tables and g's factorizations are shared by every truncated model.
    let mut kernel: Option<(Arc<Topology>, Arc<panoman_mesh::Reconstructor>)> = None;
    for (part, kind, name) in [(0usize, 1u8, "body"), (1, 2, "face"), (2, 3, "hands")] {
        let rows = held_out_rows(ds, kind, rows_per_kind);
        if rows.is_empty() {
            continue;
        }
        let region = region_groups(regions, kind);
        let kmax = model.blocks[part]
            .n_components()
            .max(model.blocks[part + 3].n_components());
        let mut ks: Vec<usize> = [
            1usize, 2, 5, 10, 25, 50, 100, 150, 200, 250, 300, 400, 500, 750, 1000,
        ]
        .iter()
        .copied()
        .filter(|&k| k < kmax)
        .collect();
        ks.push(kmax);
        let data: Vec<(Vec<V3>, Vec<V3>)> = rows
            .iter()
            .map(|&r| {
                Ok((
                    row_vertices(ds, r)?,
                    row_vertices(ds, ds.rest_of[r] as usize)?,
                ))
            })
            .collect::<Result<_>>()?;
        let n_ks = ks.len();
        for (i, k) in ks.into_iter().enumerate() {
            progress(&format!("{name} k = {k} ({}/{n_ks})", i + 1));
            let mut m = model.clone();
            m.correction = None;
            for b in [part, part + 3] {
                truncate_block(&mut m.blocks[b], k);
            }
            let m = Arc::new(m);
            let mut ev = match kernel.take() {
                Some((topo, rec)) => Evaluator::with_kernel(m.clone(), topo, rec)?,
                None => Evaluator::new(m.clone())?,
            };
            let (mut rl2, mut ra2, mut nrl, mut nra) = (0.0, 0.0, 0usize, 0usize);
            let (mut mean, mut max) = (0.0, 0.0f64);
            for (mesh, rest) in &data {
                let p = ev.encode(mesh, Some(rest), false)?;
                let rg = RestGeometry::new(ev.topology(), &m.rest_shape(&p.alpha))?;
                let x = Rla::compute(ev.topology(), &rg, mesh)?;
                let fit = m.rla(&p, false);
                for &e in &m.blocks[part].columns {
                    rl2 += (x.rl[e as usize] - fit.rl[e as usize]).powi(2);
                    nrl += 1;
                }
                for &e in &m.blocks[part + 3].columns {
                    ra2 += (x.ra[e as usize] - fit.ra[e as usize]).powi(2);
                    nra += 1;
                }
                let posed = ev.pose(&p, false)?;
                let (mm, mx) = region_errors(&posed, mesh, &region, false);
                mean += mm;
                max = max.max(mx);
            }
            points.push(CurvePoint {
                part: name.into(),
                k,
                rl_rms: (rl2 / nrl.max(1) as f64).sqrt(),
                ra_rms: (ra2 / nra.max(1) as f64).sqrt(),
                mesh_mean_mm: 1e3 * mean / data.len() as f64,
                mesh_max_mm: 1e3 * max,
            });
            kernel = Some(ev.into_kernel());
        }
    }
    Ok(points)
}

/// Keeps the first `k` components of a block.
fn truncate_block(b: &mut ComponentBlock, k: usize) {
    let k = k.min(b.n_components());
    let end = b.components.row_ptr[k];
    b.components.row_ptr.truncate(k + 1);
    b.components.col_idx.truncate(end);
    b.components.values.truncate(end);
    b.beta_range.truncate(k);
}

#[cfg(test)]
mod tests {
    use super::remaining;

    /// The estimate is the mean time per finished row times the rows left, in s, min or h.
    #[test]
    fn time_left_is_the_mean_row_time_over_the_rows_left() {
        assert_eq!(remaining(10.0, 0, 120), "");
        // 30 s a row × 118 rows = 3,540 s.
        assert_eq!(remaining(60.0, 2, 120), ", about 59 min left");
        assert_eq!(remaining(20.0, 2, 4), ", about 20 s left");
        // 75 s a row × 116 rows = 8,700 s.
        assert_eq!(remaining(300.0, 4, 120), ", about 2.4 h left");
        assert_eq!(remaining(5.0, 4, 4), "");
    }
}
