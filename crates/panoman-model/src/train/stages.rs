//! The training stages of [`super::train`]: shape PCA, RL/RA of the training rows, the SPLOCS
//! decompositions and the blocks, the correction MLP and the motion MLP.

use super::*;
use crate::model::BlockName;

/// The progress callback and the report sections the training stages fill.
pub(super) struct StageLog<'a> {
    pub(super) progress: &'a mut dyn FnMut(&str),
    /// `timings`: seconds per stage (`shape_s`, `rla_s`, `splocs_<block>_s`, …).
    pub(super) timings: BTreeMap<String, f64>,
    /// `model.blocks`: per block its decomposition figures, and the MLPs'.
    pub(super) blocks: BlockSummaries,
}

impl StageLog<'_> {
    /// Trains `net` on the rows of `(x, y)` with `val` false, validated on the others (none:
    /// no validation), reporting each epoch as `"{stage} (epoch e/E)"`.
    pub(super) fn train_mlp(
        &mut self,
        net: &mut Mlp,
        x: &Mat<f32>,
        y: &Mat<f32>,
        val: &[bool],
        tcfg: &mlp::MlpTrainConfig,
        stage: &str,
    ) -> Result<mlp::MlpTrainReport> {
        let (xtr, ytr, xva, yva) = split_rows(x, y, val);
        let train_set = mlp::MlpDataset::new(xtr.as_ref(), ytr.as_ref())?;
        let val_set = if xva.nrows() > 0 {
            Some(mlp::MlpDataset::new(xva.as_ref(), yva.as_ref())?)
        } else {
            None
        };
        let progress = &mut *self.progress;
        mlp::train(net, &train_set, val_set.as_ref(), tcfg, &mut |e| {
            progress(&format!("{stage} (epoch {}/{})", e.epoch, tcfg.epochs));
            ControlFlow::Continue(())
        })
    }

    pub(super) fn time(&mut self, key: impl Into<String>, since: Instant) {
        self.timings
            .insert(key.into(), since.elapsed().as_secs_f64());
    }
}

/// Stage 1: the shape PCA of the training identities' rest meshes (`rest_rows`), with
/// `min(n_shape, rows − 1)` components.
pub(super) fn shape_pca(ds: &Dataset, rest_rows: &[usize], n_shape: usize) -> Result<ShapePca> {
    if rest_rows.len() < 2 {
        return Err(ModelError::Invalid(
            "need at least 2 training identities".into(),
        ));
    }
    let nv = ds.n_vertices;
    let rest_mat = {
        let rests: Vec<Vec<V3>> = rest_rows
            .iter()
            .map(|&r| row_vertices(ds, r))
            .collect::<Result<_>>()?;
        Mat::<f64>::from_fn(rests.len(), 3 * nv, |i, j| rests[i][j / 3][j % 3])
    };
    ShapePca::fit(rest_mat.as_ref(), n_shape.min(rest_rows.len() - 1))
}

/// Stage 2: RL/RA (f32) of the rows of each kind (body, face, hands), each row against its
/// identity's rest geometry (built once per identity, in parallel).
pub(super) fn training_rla(
    ds: &Dataset,
    topo: &Topology,
    kinds_rows: &[Vec<usize>; 3],
) -> Result<Vec<Vec<RowRla>>> {
    let mut rest_ids: Vec<usize> = kinds_rows
        .iter()
        .flatten()
        .map(|&r| ds.rest_of[r] as usize)
        .collect();
    rest_ids.sort_unstable();
    rest_ids.dedup();
    let rest_geo: std::collections::HashMap<usize, RestGeometry> = rest_ids
        .par_iter()
        .map(|&r| Ok((r, RestGeometry::new(topo, &row_vertices(ds, r)?)?)))
        .collect::<Result<_>>()?;
    let rla_of = |rows: &[usize]| -> Result<Vec<RowRla>> {
        rows.par_iter()
            .map(|&r| {
                let rg = &rest_geo[&(ds.rest_of[r] as usize)];
                let mesh = row_vertices(ds, r)?;
                let x = Rla::compute(topo, rg, &mesh)?;
                Ok(RowRla {
                    rl: x.rl.iter().map(|&v| v as f32).collect(),
                    ra: x.ra.iter().map(|&v| v as f32).collect(),
                })
            })
            .collect()
    };
    kinds_rows.iter().map(|rows| rla_of(rows)).collect()
}

/// Stage 3: the SPLOCS decomposition of each block (RL/RA × body, face, hands; block
/// `q·3 + part`) over its part's columns, in [`BLOCK_NAMES`] order.
pub(super) fn decompose(
    topo: &Topology,
    vbar: &[V3],
    cols: &[Vec<u32>; 3],
    rlas: &[Vec<RowRla>],
    cfg: &TrainConfig,
    log: &mut StageLog<'_>,
) -> Result<Vec<Decomposition>> {
    let geo = EdgeGeodesics::new(topo, vbar)?;
    let mut decs: Vec<Option<Decomposition>> = vec![None, None, None, None, None, None];
    for part in 0..3 {
        for q in 0..2 {
            let b = q * 3 + part;
            let name = BLOCK_NAMES[b];
            (log.progress)(&format!("decomposition {name}"));
            let t = Instant::now();
            let rows = &rlas[part];
            let c = &cols[part];
            if rows.len() < 2 || c.is_empty() {
                return Err(ModelError::Invalid(format!(
                    "block {name}: {} training rows and {} columns; need ≥ 2 of each",
                    rows.len(),
                    c.len()
                )));
            }
            let n = rows.len();
            let mut data = Vec::with_capacity(n * c.len());
            for &e in c {
                for row in rows {
                    data.push(if q == 0 {
                        row.rl[e as usize]
                    } else {
                        row.ra[e as usize]
                    });
                }
            }
            let dists = PartGeodesics::new(&geo, c.clone())?;
            let bounds = if part == 0 {
                cfg.d_min_body
            } else {
                cfg.d_min_small
            };
            let mut opts =
                SplocsOptions::new(cfg.components[part].min(n.saturating_sub(1)).max(1), bounds);
            opts.max_outer_iters = cfg.splocs_outer_iters;
            opts.lambda = cfg.splocs_lambda * (n as f64 / 100.0).sqrt().max(1.0);
            let iters = opts.max_outer_iters;
            let progress = &mut *log.progress;
            let dec = splocs::fit_col_major(data, n, &dists, &opts, |rec| {
                let it = rec.iteration + 1;
                progress(&format!(
                    "decomposition {name} (outer iteration {it}/{iters})"
                ));
            })?;
            *log.blocks.slot(BlockName::ALL[b]) = Some(BlockSummary {
                rows: n,
                columns: c.len(),
                components: dec.n_components(),
                explained_variance: dec.explained_variance,
                nnz: dec.components.nnz(),
                median_support_fraction: median_support(&dec.components),
                outer_iterations: dec.history.len(),
            });
            log.time(format!("splocs_{name}_s"), t);
            decs[b] = Some(dec);
        }
    }
    Ok(decs
        .into_iter()
        .map(|d| d.expect("all blocks fitted"))
        .collect())
}

/// The model's blocks from the decompositions: component 0 the part's mean with a free
/// coefficient, then the components sorted by energy (descending), each with the range of its
/// training weights padded by 10 %. Also returns each block's order (sorted → SPLOCS index).
pub(super) fn sorted_blocks(
    decs: &[Decomposition],
    cols: &[Vec<u32>; 3],
) -> (Vec<ComponentBlock>, Vec<Vec<usize>>) {
    let mut orders = Vec::with_capacity(6);
    let mut blocks = Vec::with_capacity(6);
    for (b, dec) in decs.iter().enumerate() {
        let k = dec.n_components();
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &c| {
            dec.component_energy[c]
                .total_cmp(&dec.component_energy[a])
                .then(a.cmp(&c))
        });
        // Component 0 is the part's mean X̄ with a free coefficient (1 on the part's own rows):
        // a row of another kind (e.g. a neutral face in a body pose) can switch it off, which a
        // fixed additive mean cannot; the stored block mean is then 0.
        let mut row_ptr = vec![0usize];
        let mut col_idx: Vec<u32> = Vec::new();
        let mut values: Vec<f32> = Vec::new();
        for (j, &m) in dec.mean.iter().enumerate() {
            if m != 0.0 {
                col_idx.push(j as u32);
                values.push(m);
            }
        }
        row_ptr.push(col_idx.len());
        let mut beta_range = Vec::with_capacity(k + 1);
        beta_range.push([-0.1f32, 1.1]);
        for &kk in &order {
            let (ci, vi) = dec.components.row(kk);
            col_idx.extend_from_slice(ci);
            values.extend_from_slice(vi);
            row_ptr.push(col_idx.len());
            let w = dec.weights.col(kk);
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for i in 0..w.nrows() {
                lo = lo.min(w[i]);
                hi = hi.max(w[i]);
            }
            let pad = 0.1 * (hi - lo).max(1e-6);
            beta_range.push([lo - pad, hi + pad]);
        }
        blocks.push(ComponentBlock {
            name: BlockName::ALL[b],
            columns: cols[b % 3].clone(),
            mean: vec![0.0; dec.n_columns()],
            components: SparseRows {
                n_cols: dec.n_columns(),
                row_ptr,
                col_idx,
                values,
            },
            beta_range,
        });
        orders.push(order);
    }
    (blocks, orders)
}

/// The training β of the body rows in the blocks' sorted order.
pub(super) struct BodyCoefficients {
    /// Components of body RL and body RA (each with its mean's coefficient).
    pub(super) kl: usize,
    pub(super) ka: usize,
    /// `[β_LB | β_AB]`, rows × (kl + ka); columns 0 and kl (the means' coefficients) are 1.
    pub(super) beta_b: Mat<f32>,
    /// The MLPs' body coefficients: β_B without the two constant mean coefficients.
    pub(super) beta_mlp: Mat<f32>,
}

impl BodyCoefficients {
    pub(super) fn new(
        decs: &[Decomposition],
        orders: &[Vec<usize>],
        blocks: &[ComponentBlock],
        n_body: usize,
    ) -> Self {
        let (kl, ka) = (blocks[0].n_components(), blocks[3].n_components());
        let beta_b = Mat::<f32>::from_fn(n_body, kl + ka, |i, j| {
            if j == 0 || j == kl {
                1.0
            } else if j < kl {
                decs[0].weights[(i, orders[0][j - 1])]
            } else {
                decs[3].weights[(i, orders[3][j - kl - 1])]
            }
        });
        let beta_mlp = Mat::<f32>::from_fn(n_body, kl + ka - 2, |i, j| {
            if j < kl - 1 {
                beta_b[(i, j + 1)]
            } else {
                beta_b[(i, j + 2)]
            }
        });
        BodyCoefficients {
            kl,
            ka,
            beta_b,
            beta_mlp,
        }
    }
}

/// Stage 4: the correction MLP `R(β_B)`: a PCA head over the body rows' RL/RA residuals
/// (RA weighted by the bending weights ω), and an MLP from β_B to the head's codes.
#[allow(clippy::too_many_arguments)]
pub(super) fn train_correction(
    topo: &Topology,
    vbar: &[V3],
    blocks: &[ComponentBlock],
    body_rla: &[RowRla],
    body: &BodyCoefficients,
    val_mask: &[bool],
    cfg: &TrainConfig,
    log: &mut StageLog<'_>,
) -> Result<CorrectionMlp> {
    (log.progress)("correction MLP");
    let t = Instant::now();
    let (kl, ka, beta_b) = (body.kl, body.ka, &body.beta_b);
    let n_body = beta_b.nrows();
    let (ml, ma) = (blocks[0].columns.len(), blocks[3].columns.len());
    let mut y = Mat::<f32>::zeros(n_body, ml + ma);
    for i in 0..n_body {
        let bl: Vec<f64> = (0..kl).map(|j| beta_b[(i, j)] as f64).collect();
        let ba: Vec<f64> = (0..ka).map(|j| beta_b[(i, kl + j)] as f64).collect();
        let rl = block_reconstruct(&blocks[0], &bl);
        let ra = block_reconstruct(&blocks[3], &ba);
        for (j, &e) in blocks[0].columns.iter().enumerate() {
            y[(i, j)] = body_rla[i].rl[e as usize] - rl[j] as f32;
        }
        for (j, &e) in blocks[3].columns.iter().enumerate() {
            y[(i, ml + j)] = body_rla[i].ra[e as usize] - ra[j] as f32;
        }
    }
    let omega = bending_weights(topo, vbar);
    let mut w = vec![1.0f32; ml + ma];
    for (j, &e) in blocks[3].columns.iter().enumerate() {
        w[ml + j] = omega[e as usize] as f32;
    }
    let hopts = PcaHeadOptions {
        max_rank: cfg.correction_rank.min(n_body.saturating_sub(1)).max(1),
        min_rank: 1,
        target_explained: 0.99,
        seed: cfg.seed,
        ..PcaHeadOptions::default()
    };
    let fit = PcaHead::fit(y.as_ref(), Some(&w), &hopts)?;
    let codes = fit.codes;
    let mut net = Mlp::new(
        &[kl + ka - 2, cfg.correction_hidden, fit.head.rank()],
        cfg.seed ^ 0xC0,
    )?;
    let tcfg = mlp::MlpTrainConfig {
        epochs: cfg.correction_epochs,
        seed: cfg.seed ^ 0xC1,
        output_norm: OutputNorm::Global,
        weight_decay: cfg.correction_weight_decay,
        patience: Some(cfg.correction_patience),
        ..mlp::MlpTrainConfig::default()
    };
    let rep = log.train_mlp(
        &mut net,
        &body.beta_mlp,
        &codes,
        val_mask,
        &tcfg,
        "correction MLP",
    )?;
    log.time("correction_s", t);
    log.blocks.correction = Some(CorrectionSummary {
        head_rank: fit.head.rank(),
        head_explained: fit.explained_ratio,
        epochs_run: rep.history.len(),
        best_val_loss: rep.best_val_loss,
        final_train_loss: rep.history.last().map(|h| h.train_loss),
    });
    Ok(CorrectionMlp {
        mlp: net,
        head: fit.head,
    })
}

/// Stage 5: the motion MLP θ → β_B over the body bones' rotations (6-D: the first two
/// columns of each R), trained in the metric of the blocks' Gram matrices.
pub(super) fn train_motion(
    ds: &Dataset,
    body_rows: &[usize],
    blocks: &[ComponentBlock],
    body: &BodyCoefficients,
    val_mask: &[bool],
    cfg: &TrainConfig,
    log: &mut StageLog<'_>,
) -> Result<Motion> {
    (log.progress)("motion MLP θ→β");
    let t = Instant::now();
    let (kl, ka) = (body.kl, body.ka);
    let n_body = body.beta_b.nrows();
    let (bones, index): (Vec<String>, Vec<u32>) = ds
        .theta_bones
        .iter()
        .enumerate()
        .filter(|(_, n)| is_body_bone(n))
        .map(|(i, n)| (n.clone(), i as u32))
        .unzip();
    let p = ds.theta.len() / ds.n_rows.max(1);
    let x = Mat::<f32>::from_fn(n_body, 6 * index.len(), |i, j| {
        let r = body_rows[i];
        let th = &ds.theta[r * p..(r + 1) * p];
        let b = index[j / 6] as usize;
        let rot = panoman_mesh::rotation::euler_xyz(
            [th[3 * b], th[3 * b + 1], th[3 * b + 2]].map(f64::from),
        );
        // 6-D representation: the first two columns of R.
        let (col, row) = ((j % 6) / 3, (j % 6) % 3);
        rot[row][col] as f32
    });
    // Gram metric MᵀM over the MLP's outputs (components 1.. of body_l and body_a).
    let km = kl + ka - 2;
    let mut gram = Mat::<f64>::zeros(km, km);
    let gl = blocks[0].components.gram();
    let ga = blocks[3].components.gram();
    for a in 1..kl {
        for c in 1..kl {
            gram[(a - 1, c - 1)] = gl[a * kl + c];
        }
    }
    for a in 1..ka {
        for c in 1..ka {
            gram[(kl - 1 + a - 1, kl - 1 + c - 1)] = ga[a * ka + c];
        }
    }
    let tr: f64 = (0..km).map(|i| gram[(i, i)]).sum::<f64>() / km.max(1) as f64;
    for i in 0..km {
        gram[(i, i)] += 1e-3 * tr.max(1e-12);
    }
    let mut sizes = vec![6 * index.len()];
    sizes.extend_from_slice(&cfg.motion_hidden);
    sizes.push(km);
    let mut net = Mlp::new(&sizes, cfg.seed ^ 0x70)?;
    let tcfg = mlp::MlpTrainConfig {
        epochs: cfg.motion_epochs,
        seed: cfg.seed ^ 0x71,
        loss: Loss::Metric(gram),
        ..mlp::MlpTrainConfig::default()
    };
    let rep = log.train_mlp(
        &mut net,
        &x,
        &body.beta_mlp,
        val_mask,
        &tcfg,
        "motion MLP θ→β",
    )?;
    log.time("motion_s", t);
    log.blocks.motion = Some(MotionSummary {
        inputs: 6 * index.len(),
        epochs_run: rep.history.len(),
        best_val_loss: rep.best_val_loss,
    });
    Ok(Motion {
        mlp: net,
        theta_bones: bones,
        theta_index: index,
    })
}
