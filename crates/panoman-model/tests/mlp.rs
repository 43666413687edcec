//! Tests of the MLP toolkit (docs/design/splocs-model.md §7): overfitting, PCA-head orthonormality,
//! Jacobian vs finite differences, bit-exact serialization, determinism across thread counts,
//! metric-loss gradients, early stopping.

use std::ops::ControlFlow;

use faer::Mat;
use panoman_model::ModelError;
use panoman_model::mlp::{
    EpochStats, Loss, Mlp, MlpDataset, MlpTrainConfig, OutputNorm, PcaHead, PcaHeadOptions,
    TensorData, TensorStore, cosine_lr, evaluate, loss_gradient, train,
};

/// Small deterministic generator for test data (xorshift64*).
struct Gen(u64);

impl Gen {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
    fn mat(&mut self, n: usize, d: usize, scale: f64) -> Mat<f32> {
        Mat::from_fn(n, d, |_, _| (self.normal() * scale) as f32)
    }
}

fn go_on(_: &EpochStats) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

/// A smooth nonlinear regression target `y_k = sin(a_k·x) + 0.5 (b_k·x)²` with offsets.
fn regression(g: &mut Gen, n: usize, din: usize, dout: usize, noise: f64) -> (Mat<f32>, Mat<f32>) {
    let a = g.mat(dout, din, 1.0 / (din as f64).sqrt());
    let b = g.mat(dout, din, 1.0 / (din as f64).sqrt());
    let x = Mat::<f32>::from_fn(n, din, |i, j| {
        (g.normal() * (1.0 + j as f64) + i as f64 * 0.0) as f32
    });
    let mut y = Mat::<f32>::zeros(n, dout);
    for i in 0..n {
        for k in 0..dout {
            let (mut sa, mut sb) = (0.0f64, 0.0f64);
            for j in 0..din {
                let xv = f64::from(x[(i, j)]) / (1.0 + j as f64);
                sa += f64::from(a[(k, j)]) * xv;
                sb += f64::from(b[(k, j)]) * xv;
            }
            y[(i, k)] = ((2.0 * sa).sin() + 0.5 * sb * sb + k as f64 + noise * g.normal()) as f32;
        }
    }
    (x, y)
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).abs())
        .fold(0.0, f64::max)
}

#[test]
fn overfits_32_samples() {
    // docs/design/splocs-model.md §7: overfit 32 samples to a normalized MSE < 1e−6, i.e. an rms error of 1e−3 standard
    // deviations: ~4 orders of magnitude above f32 resolution, so f32 is no obstacle.
    let mut g = Gen(7);
    let (x, y) = regression(&mut g, 32, 10, 4, 0.0);
    let data = MlpDataset::new(x.as_ref(), y.as_ref()).unwrap();
    let mut model = Mlp::new(&[10, 128, 4], 1).unwrap();
    let cfg = MlpTrainConfig {
        epochs: 3000,
        batch_size: 32,
        lr_max: 3e-3,
        lr_min: 1e-6,
        weight_decay: 0.0,
        patience: None,
        ..MlpTrainConfig::default()
    };
    let report = train(&mut model, &data, None, &cfg, &mut go_on).unwrap();
    let loss = evaluate(&model, &data, &Loss::Mse).unwrap();
    eprintln!(
        "overfit: normalized MSE {loss:e} after {} steps",
        report.steps
    );
    assert!(
        loss < 1e-6,
        "overfit loss {loss:e} (first epoch {:e})",
        report.history[0].train_loss
    );
    assert_eq!(report.steps, 3000);
    assert!(report.best_epoch.is_none());
}

/// f64 copy of the network's parameters and the reference forward pass used by the gradient
/// checks (independent of the crate's own f64 path).
struct Ref64 {
    sizes: Vec<usize>,
    norm: [Vec<f64>; 4],
}

impl Ref64 {
    fn new(m: &Mlp) -> Self {
        let c = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
        Self {
            sizes: m.sizes().to_vec(),
            norm: [
                c(m.input_mean()),
                c(m.input_scale()),
                c(m.output_mean()),
                c(m.output_scale()),
            ],
        }
    }

    /// Normalized output `o` at raw input `x` with flat parameters `p`.
    fn forward(&self, p: &[f64], x: &[f64]) -> Vec<f64> {
        let mut a: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(j, &v)| (v - self.norm[0][j]) / self.norm[1][j])
            .collect();
        let mut off = 0;
        let nl = self.sizes.len() - 1;
        for l in 0..nl {
            let (fi, fo) = (self.sizes[l], self.sizes[l + 1]);
            let w = &p[off..off + fi * fo];
            let b = &p[off + fi * fo..off + fi * fo + fo];
            off += fi * fo + fo;
            let mut z = b.to_vec();
            for (j, &aj) in a.iter().enumerate() {
                for i in 0..fo {
                    z[i] += w[i + j * fo] * aj;
                }
            }
            if l + 1 < nl {
                z.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            a = z;
        }
        a
    }

    /// Mean metric loss `(1/K) eᵀ G̃ e`, `e = o − ỹ`, `G̃ = SGS/(tr(SGS)/K)` (or MSE if `g` is None).
    fn loss(&self, p: &[f64], x: &Mat<f32>, y: &Mat<f32>, g: Option<&Mat<f64>>) -> f64 {
        let k = y.ncols();
        let s = &self.norm[3];
        let gt = g.map(|g| {
            let tr: f64 = (0..k).map(|i| s[i] * s[i] * g[(i, i)]).sum();
            Mat::<f64>::from_fn(k, k, |i, j| s[i] * g[(i, j)] * s[j] * k as f64 / tr)
        });
        let mut total = 0.0;
        for i in 0..x.nrows() {
            let xi: Vec<f64> = (0..x.ncols()).map(|j| f64::from(x[(i, j)])).collect();
            let o = self.forward(p, &xi);
            let e: Vec<f64> = (0..k)
                .map(|c| o[c] - (f64::from(y[(i, c)]) - self.norm[2][c]) / s[c])
                .collect();
            total += match &gt {
                None => e.iter().map(|v| v * v).sum::<f64>(),
                Some(gt) => (0..k)
                    .map(|a| (0..k).map(|b| e[a] * gt[(a, b)] * e[b]).sum::<f64>())
                    .sum::<f64>(),
            } / k as f64;
        }
        total / x.nrows() as f64
    }
}

fn random_normalization(model: &mut Mlp, g: &mut Gen) {
    let (nin, nout) = (model.n_inputs(), model.n_outputs());
    let v = |g: &mut Gen, n: usize, pos: bool| -> Vec<f32> {
        (0..n)
            .map(|_| {
                if pos {
                    (0.3 + 2.0 * g.uniform()) as f32
                } else {
                    g.normal() as f32
                }
            })
            .collect()
    };
    let (a, b, c, d) = (
        v(g, nin, false),
        v(g, nin, true),
        v(g, nout, false),
        v(g, nout, true),
    );
    model.set_normalization(&a, &b, &c, &d).unwrap();
}

#[test]
fn metric_and_mse_gradients_match_finite_differences() {
    let mut g = Gen(11);
    let (nin, nout, n) = (6, 5, 20);
    let mut model = Mlp::new(&[nin, 16, 12, nout], 3).unwrap();
    random_normalization(&mut model, &mut g);
    let x = g.mat(n, nin, 1.5);
    let y = g.mat(n, nout, 2.0);
    let data = MlpDataset::new(x.as_ref(), y.as_ref()).unwrap();
    let a = g.mat(nout, nout, 1.0);
    let gram = Mat::<f64>::from_fn(nout, nout, |i, j| {
        (0..nout)
            .map(|k| f64::from(a[(i, k)]) * f64::from(a[(j, k)]))
            .sum::<f64>()
            + if i == j { 0.1 } else { 0.0 }
    });
    let reference = Ref64::new(&model);
    let p64: Vec<f64> = model.parameters().iter().map(|&v| f64::from(v)).collect();
    for (loss, gm) in [(Loss::Mse, None), (Loss::Metric(gram.clone()), Some(&gram))] {
        let (l32, grad) = loss_gradient(&model, &data, &loss).unwrap();
        let l64 = reference.loss(&p64, &x, &y, gm);
        // f32 forward vs exact f64: relative 1e−5 covers ~1e−7 rounding per layer.
        assert!(
            (l32 - l64).abs() <= 1e-5 * l64,
            "{loss:?}: loss {l32} vs f64 {l64}"
        );
        assert!((evaluate(&model, &data, &loss).unwrap() - l32).abs() <= 1e-12 * l32);
        // Directional derivatives along random directions: central differences on the exact
        // f64 loss (piecewise quadratic in any direction, so truncation error vanishes unless a
        // ReLU kink is crossed within ±h); the f32 gradient is accurate to ~1e−6 relative, so
        // 1e−4 is a safe bound.
        for trial in 0..4 {
            let d: Vec<f64> = (0..p64.len()).map(|_| g.normal()).collect();
            let h = 1e-6;
            let plus: Vec<f64> = p64.iter().zip(&d).map(|(p, d)| p + h * d).collect();
            let minus: Vec<f64> = p64.iter().zip(&d).map(|(p, d)| p - h * d).collect();
            let fd = (reference.loss(&plus, &x, &y, gm) - reference.loss(&minus, &x, &y, gm))
                / (2.0 * h);
            let an: f64 = grad.iter().zip(&d).map(|(g, d)| f64::from(*g) * d).sum();
            let rel = (fd - an).abs() / fd.abs().max(1e-12);
            eprintln!("{loss:?}: directional derivative rel error {rel:e}");
            assert!(
                rel < 1e-4,
                "{loss:?} trial {trial}: fd {fd} analytic {an} rel {rel:e}"
            );
        }
        // A few single coordinates (one per layer's weights and biases).
        let mut off = 0;
        for pair in model.sizes().windows(2) {
            let (fi, fo) = (pair[0], pair[1]);
            for idx in [off + (fi * fo) / 2, off + fi * fo + fo - 1] {
                let h = 1e-6;
                let mut pp = p64.clone();
                pp[idx] += h;
                let mut pm = p64.clone();
                pm[idx] -= h;
                let fd =
                    (reference.loss(&pp, &x, &y, gm) - reference.loss(&pm, &x, &y, gm)) / (2.0 * h);
                let an = f64::from(grad[idx]);
                assert!(
                    (fd - an).abs() <= 1e-4 * fd.abs().max(1e-3 * l64),
                    "{loss:?} param {idx}: fd {fd} analytic {an}"
                );
            }
            off += fi * fo + fo;
        }
    }
    // G = c·I gives exactly the MSE objective (up to rounding in the factor).
    let eye = Mat::<f64>::from_fn(nout, nout, |i, j| if i == j { 3.7 } else { 0.0 });
    let mut m2 = model.clone();
    m2.set_normalization(
        model.input_mean(),
        model.input_scale(),
        model.output_mean(),
        &vec![1.25; nout],
    )
    .unwrap();
    let (lm, gm) = loss_gradient(&m2, &data, &Loss::Mse).unwrap();
    let (li, gi) = loss_gradient(&m2, &data, &Loss::Metric(eye)).unwrap();
    assert!((lm - li).abs() <= 1e-6 * lm);
    let gmax = gm.iter().fold(0.0f32, |a, b| a.max(b.abs()));
    assert!(max_abs_diff(&gm, &gi) <= 1e-5 * f64::from(gmax));
    // Invalid Gram matrices are rejected with a clear error.
    let mut bad = gram.clone();
    bad[(0, 0)] = -1.0;
    let e = loss_gradient(&model, &data, &Loss::Metric(bad)).unwrap_err();
    assert!(
        matches!(e, ModelError::Invalid(_)) && e.to_string().contains("positive definite"),
        "{e}"
    );
    let mut asym = gram.clone();
    asym[(1, 0)] += 1.0;
    let e = loss_gradient(&model, &data, &Loss::Metric(asym)).unwrap_err();
    assert!(e.to_string().contains("symmetric"), "{e}");
    let e = loss_gradient(&model, &data, &Loss::Metric(Mat::identity(3, 3))).unwrap_err();
    assert!(e.to_string().contains("3×3"), "{e}");
}

#[test]
fn jacobian_matches_finite_differences() {
    let mut g = Gen(5);
    for sizes in [vec![12usize, 40, 7], vec![9, 30, 25, 6], vec![4, 3]] {
        let mut model = Mlp::new(&sizes, 9).unwrap();
        random_normalization(&mut model, &mut g);
        // Non-zero biases so that the active sets are not trivially half.
        for p in model.parameters_mut().iter_mut() {
            *p += 0.01;
        }
        let nin = sizes[0];
        let mut checked = 0;
        let (mut worst, mut worst32) = (0.0f64, 0.0f64);
        for _ in 0..20 {
            let x: Vec<f32> = (0..nin).map(|_| (2.0 * g.normal()) as f32).collect();
            let (y, jac) = model.jacobian(&x);
            // Same arithmetic as forward_one: bit-identical output.
            let y1 = model.forward_one(&x);
            assert!(y.iter().zip(&y1).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!((jac.nrows(), jac.ncols()), (sizes[sizes.len() - 1], nin));
            let h = 1e-6;
            let x64: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
            let mut fd = Mat::<f64>::zeros(jac.nrows(), nin);
            for j in 0..nin {
                let mut xp = x64.clone();
                xp[j] += h;
                let mut xm = x64.clone();
                xm[j] -= h;
                let (yp, ym) = (model.forward_one_f64(&xp), model.forward_one_f64(&xm));
                for i in 0..jac.nrows() {
                    fd[(i, j)] = (yp[i] - ym[i]) / (2.0 * h);
                }
            }
            let dense = jac.to_dense_f64();
            let dense32 = jac.to_dense();
            let (mut num, mut num32, mut den) = (0.0f64, 0.0f64, 0.0f64);
            for i in 0..fd.nrows() {
                for j in 0..nin {
                    num += (dense[(i, j)] - fd[(i, j)]).powi(2);
                    num32 += (f64::from(dense32[(i, j)]) - fd[(i, j)]).powi(2);
                    den += fd[(i, j)].powi(2);
                }
            }
            let (rel, rel32) = ((num / den).sqrt(), (num32 / den).sqrt());
            if rel > 1e-3 {
                continue; // a kink within ±h (FD invalid here); rare
            }
            // Factors are the f32 weights scaled once by s_y and 1/σ_x (one f32 rounding each,
            // ≤ 6e−8 relative) and multiplied in f64; the f64 FD of the exact piecewise-linear
            // function has ~1e−10 error. 1e−6 leaves a wide margin; the f32 product adds ~1e−7.
            assert!(rel < 1e-6, "{sizes:?}: factored Jacobian rel error {rel:e}");
            worst = worst.max(rel);
            worst32 = worst32.max(rel32);
            assert!(
                rel32 < 1e-5,
                "{sizes:?}: dense f32 Jacobian rel error {rel32:e}"
            );
            // apply / apply_transpose agree with the dense matrix.
            let v: Vec<f32> = (0..nin).map(|_| g.normal() as f32).collect();
            let jv = jac.apply(&v);
            for i in 0..jac.nrows() {
                let d: f64 = (0..nin).map(|j| dense[(i, j)] * f64::from(v[j])).sum();
                assert!((f64::from(jv[i]) - d).abs() <= 1e-5 * (1.0 + d.abs()));
            }
            let u: Vec<f32> = (0..jac.nrows()).map(|_| g.normal() as f32).collect();
            let jtu = jac.apply_transpose(&u);
            for j in 0..nin {
                let d: f64 = (0..jac.nrows())
                    .map(|i| dense[(i, j)] * f64::from(u[i]))
                    .sum();
                assert!((f64::from(jtu[j]) - d).abs() <= 1e-5 * (1.0 + d.abs()));
            }
            let (_, jd) = model.jacobian_dense(&x);
            assert_eq!(jd, dense32);
            checked += 1;
        }
        assert!(checked >= 15, "{sizes:?}: only {checked} points checked");
        eprintln!(
            "Jacobian {sizes:?}: {checked} points, max rel error {worst:e} (f64 product), {worst32:e} (f32)"
        );
    }
}

#[test]
fn forward_variants_agree() {
    let mut g = Gen(3);
    let mut model = Mlp::new(&[30, 50, 40, 8], 4).unwrap();
    random_normalization(&mut model, &mut g);
    let x = g.mat(2100, 30, 1.0); // > 1 forward chunk
    let y = model.forward(x.as_ref()).unwrap();
    for i in [0usize, 1023, 1024, 2099] {
        let xi: Vec<f32> = (0..30).map(|j| x[(i, j)]).collect();
        let y1 = model.forward_one(&xi);
        let y64 = model.forward_one_f64(&xi.iter().map(|&v| f64::from(v)).collect::<Vec<_>>());
        for k in 0..8 {
            assert!((f64::from(y[(i, k)]) - y64[k]).abs() <= 1e-5 * (1.0 + y64[k].abs()));
            assert!((f64::from(y1[k]) - y64[k]).abs() <= 1e-5 * (1.0 + y64[k].abs()));
        }
    }
    assert!(model.forward(g.mat(3, 29, 1.0).as_ref()).is_err());
    assert_eq!(
        Mlp::parameter_count(&[500, 1500, 256]),
        500 * 1500 + 1500 + 1500 * 256 + 256
    );
    assert!(Mlp::new(&[5], 0).is_err() && Mlp::new(&[5, 0, 2], 0).is_err());
}

/// Low-rank-plus-noise targets with a decaying spectrum.
fn low_rank_targets(
    g: &mut Gen,
    n: usize,
    d: usize,
    rank: usize,
    decay: f64,
    noise: f64,
) -> Mat<f32> {
    let u = g.mat(n, rank, 1.0);
    let v = g.mat(rank, d, 1.0);
    Mat::from_fn(n, d, |i, j| {
        let s: f64 = (0..rank)
            .map(|k| f64::from(u[(i, k)]) * f64::from(v[(k, j)]) * decay.powi(k as i32))
            .sum();
        (s + 3.0 + noise * g.normal()) as f32
    })
}

#[test]
fn pca_head_is_orthonormal_and_near_optimal() {
    let mut g = Gen(21);
    let (n, d) = (300, 3000);
    let y = low_rank_targets(&mut g, n, d, 30, 0.9, 0.05);
    let w: Vec<f32> = (0..d).map(|_| (0.5 + g.uniform()) as f32).collect();
    let opts = PcaHeadOptions {
        max_rank: 40,
        target_explained: 0.99,
        seed: 5,
        ..PcaHeadOptions::default()
    };
    let fit = PcaHead::fit(y.as_ref(), Some(&w), &opts).unwrap();
    let head = &fit.head;
    let r = head.rank();
    assert!((10..=40).contains(&r), "rank {r}");
    // ‖PᵀP − I‖_max in f64 from the f32 basis: f64-orthonormal before one f32 rounding per
    // entry, so ~1e−7; docs/design/splocs-model.md §7 asks 1e−6 (f32).
    let p = head.basis();
    let mut worst = 0.0f64;
    for a in 0..r {
        for b in 0..r {
            let dot: f64 = (0..d)
                .map(|i| f64::from(p[(i, a)]) * f64::from(p[(i, b)]))
                .sum();
            worst = worst.max((dot - if a == b { 1.0 } else { 0.0 }).abs());
        }
    }
    assert!(worst < 1e-6, "‖PᵀP − I‖_max = {worst:e}");
    eprintln!("PCA head: ‖PᵀP − I‖_max = {worst:e}, rank {r}");
    // Exact optimum: top-r eigenvalues of ỸỸᵀ (N × N, f64).
    let yt = Mat::<f64>::from_fn(n, d, |i, j| f64::from((y[(i, j)] - head.mean()[j]) * w[j]));
    let gram = &yt * yt.transpose();
    let ev = gram.self_adjoint_eigenvalues(faer::Side::Lower).unwrap();
    let mut ev: Vec<f64> = ev.into_iter().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    let total: f64 = ev.iter().sum();
    let best: f64 = ev[..r].iter().sum::<f64>() / total;
    assert!(
        fit.explained_ratio >= 0.99,
        "explained {}",
        fit.explained_ratio
    );
    eprintln!(
        "PCA head: explained {} vs optimal rank-{r} {best}",
        fit.explained_ratio
    );
    assert!(
        fit.explained_ratio >= best - 1e-4,
        "explained {} vs optimal {best}",
        fit.explained_ratio
    );
    assert!((head.explained_ratio() - fit.explained_ratio).abs() < 1e-12);
    assert!((head.total_variance() * n as f64 - total).abs() <= 1e-6 * total);
    // Codes: batch encode is bit-identical; single encode agrees to f32 accuracy.
    let codes = head.encode_batch(y.as_ref()).unwrap();
    assert_eq!(codes, fit.codes);
    let scale = head.component_variance()[0].sqrt();
    for i in [0usize, 150, 299] {
        let yi: Vec<f32> = (0..d).map(|j| y[(i, j)]).collect();
        let c = head.encode(&yi);
        let row: Vec<f32> = (0..r).map(|k| codes[(i, k)]).collect();
        assert!(max_abs_diff(&c, &row) <= 1e-4 * scale);
        // decode(encode(y)) is the weighted projection: its weighted residual is orthogonal to P.
        let rec = head.decode(&c);
        let res: Vec<f64> = (0..d).map(|j| f64::from((yi[j] - rec[j]) * w[j])).collect();
        for k in 0..r {
            let dot: f64 = (0..d).map(|j| f64::from(p[(j, k)]) * res[j]).sum();
            assert!(dot.abs() <= 1e-3 * scale, "residual not orthogonal: {dot}");
        }
    }
    // Seeded: same seed, same basis.
    let again = PcaHead::fit(y.as_ref(), Some(&w), &opts).unwrap();
    assert_eq!(again.head, fit.head);
    // A row-major Y (samples contiguous) gives the same head up to f32 rounding.
    let storage = y.transpose().to_owned(); // D × N column-major
    let y_rm = storage.as_ref().transpose(); // N × D, row-major strides
    assert_eq!(y_rm.col_stride(), 1);
    let codes_rm = head.encode_batch(y_rm).unwrap();
    let cmax = codes.col(0).iter().fold(0.0f32, |a, b| a.max(b.abs()));
    for i in 0..n {
        for k in 0..r {
            assert!((codes_rm[(i, k)] - codes[(i, k)]).abs() <= 1e-5 * cmax);
        }
    }
    let fit_rm = PcaHead::fit(y_rm, Some(&w), &opts).unwrap();
    assert_eq!(fit_rm.head.rank(), r);
    assert!((fit_rm.explained_ratio - fit.explained_ratio).abs() < 1e-6);
    // Exactly low-rank data is reconstructed.
    let y2 = low_rank_targets(&mut g, 80, 500, 6, 0.7, 0.0);
    let fit2 = PcaHead::fit(
        y2.as_ref(),
        None,
        &PcaHeadOptions {
            max_rank: 10,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(fit2.head.rank() <= 6, "rank {}", fit2.head.rank());
    let y0: Vec<f32> = (0..500).map(|j| y2[(7, j)]).collect();
    let rec = fit2.head.decode(&fit2.head.encode(&y0));
    let norm = y0
        .iter()
        .map(|v| f64::from(*v - 3.0).abs())
        .fold(0.0, f64::max);
    assert!(max_abs_diff(&rec, &y0) <= 1e-4 * norm);
    // Bad inputs.
    assert!(PcaHead::fit(y2.as_ref(), Some(&[1.0; 3]), &PcaHeadOptions::default()).is_err());
    let mut yn = y2.clone();
    yn[(4, 9)] = f32::NAN;
    let e = PcaHead::fit(yn.as_ref(), None, &PcaHeadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("sample 4, column 9"), "{e}");
}

fn small_trained(seed: u64) -> (Mlp, Mat<f32>) {
    let mut g = Gen(seed + 100);
    let (x, y) = regression(&mut g, 200, 8, 3, 0.1);
    let data = MlpDataset::new(x.as_ref(), y.as_ref()).unwrap();
    let mut model = Mlp::new(&[8, 32, 16, 3], seed).unwrap();
    let cfg = MlpTrainConfig {
        epochs: 5,
        batch_size: 64,
        ..MlpTrainConfig::default()
    };
    train(&mut model, &data, None, &cfg, &mut go_on).unwrap();
    (model, x)
}

#[test]
fn serialization_round_trip_is_bit_exact_and_validated() {
    let (a, x) = small_trained(1);
    let (b, _) = small_trained(2);
    let mut g = Gen(8);
    let yp = low_rank_targets(&mut g, 60, 200, 5, 0.7, 0.01);
    let head = PcaHead::fit(
        yp.as_ref(),
        None,
        &PcaHeadOptions {
            max_rank: 8,
            ..Default::default()
        },
    )
    .unwrap()
    .head;
    let mut store = TensorStore::new();
    a.write(&mut store, "mlp.correction").unwrap();
    b.write(&mut store, "mlp.motion").unwrap();
    head.write(&mut store, "pca.correction").unwrap();
    store
        .insert("other.indices", vec![3], TensorData::U32(vec![1, 2, 3]))
        .unwrap();
    let dir = std::env::temp_dir().join(format!("panoman-mlp-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("model.safetensors");
    store.save(&path).unwrap();
    let loaded = TensorStore::load(&path).unwrap();
    assert_eq!(loaded.source(), path.as_path());
    let a2 = Mlp::read(&loaded, "mlp.correction").unwrap();
    let b2 = Mlp::read(&loaded, "mlp.motion").unwrap();
    let head2 = PcaHead::read(&loaded, "pca.correction").unwrap();
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(a2.parameters()), bits(a.parameters()));
    assert_eq!(a2, a);
    assert_eq!(b2, b);
    assert_eq!(head2, head);
    assert_eq!(
        loaded.get("other.indices").unwrap().data,
        TensorData::U32(vec![1, 2, 3])
    );
    let (ya, ya2) = (
        a.forward(x.as_ref()).unwrap(),
        a2.forward(x.as_ref()).unwrap(),
    );
    for i in 0..x.nrows() {
        for k in 0..3 {
            assert_eq!(ya[(i, k)].to_bits(), ya2[(i, k)].to_bits());
        }
        let xi: Vec<f32> = (0..8).map(|j| x[(i, j)]).collect();
        assert_eq!(bits(&a.forward_one(&xi)), bits(&a2.forward_one(&xi)));
    }
    // Weights are stored in PyTorch's [out, in] row-major layout.
    let t = loaded.get("mlp.correction.layer0.weight").unwrap();
    assert_eq!(t.shape, vec![32, 8]);
    let TensorData::F32(w) = &t.data else {
        panic!()
    };
    assert_eq!(w[8 + 3].to_bits(), a.weight(0)[(1, 3)].to_bits());
    // Validation names the offending tensor or config.
    let expect = |s: &TensorStore, prefix: &str, needle: &str| {
        let e = Mlp::read(s, prefix).unwrap_err();
        assert!(matches!(e, ModelError::Format { .. }), "{e}");
        assert!(e.to_string().contains(needle), "'{e}' lacks '{needle}'");
    };
    let mut s = loaded.clone();
    s.remove("mlp.correction.layer1.bias");
    expect(
        &s,
        "mlp.correction",
        "missing tensor 'mlp.correction.layer1.bias'",
    );
    let mut s = loaded.clone();
    s.insert(
        "mlp.correction.layer0.weight",
        vec![8, 32],
        TensorData::F32(vec![0.0; 256]),
    )
    .unwrap();
    expect(
        &s,
        "mlp.correction",
        "'mlp.correction.layer0.weight' has shape [8, 32], expected [32, 8]",
    );
    let mut s = loaded.clone();
    let mut bad = w.clone();
    bad[17] = f32::NAN;
    s.insert(
        "mlp.correction.layer0.weight",
        vec![32, 8],
        TensorData::F32(bad),
    )
    .unwrap();
    expect(
        &s,
        "mlp.correction",
        "'mlp.correction.layer0.weight' element 17 is NaN",
    );
    let mut s = loaded.clone();
    s.insert(
        "mlp.correction.output_scale",
        vec![3],
        TensorData::F32(vec![1.0, 0.0, 1.0]),
    )
    .unwrap();
    expect(&s, "mlp.correction", "scales must be > 0");
    let mut s = loaded.clone();
    s.insert(
        "mlp.correction.layer0.bias",
        vec![32],
        TensorData::F64(vec![0.0; 32]),
    )
    .unwrap();
    expect(&s, "mlp.correction", "dtype F64, expected F32");
    expect(&loaded, "mlp.nothing", "no config 'mlp.nothing'");
    expect(&loaded, "pca.correction", "expected panoman.mlp");
    let mut s = loaded.clone();
    s.set_metadata("mlp.motion", "{not json");
    expect(&s, "mlp.motion", "config 'mlp.motion' is not valid");
    assert!(s.to_bytes().is_ok());
    s.set_metadata(
        "mlp.motion",
        r#"{"kind":"panoman.mlp","version":1,"sizes":[8,1000000000000,3],"activation":"relu"}"#,
    );
    expect(&s, "mlp.motion", "expected [1000000000000, 8]");
    s.set_metadata(
        "mlp.motion",
        r#"{"kind":"panoman.mlp","version":2,"sizes":[8,3],"activation":"relu"}"#,
    );
    expect(&s, "mlp.motion", "panoman.mlp v2, expected panoman.mlp v1");
    // A truncated file is a Format error naming the path.
    let bytes = std::fs::read(&path).unwrap();
    let e = TensorStore::from_bytes(&bytes[..bytes.len() - 10], &path).unwrap_err();
    assert!(
        matches!(e, ModelError::Format { .. }) && e.to_string().contains("model.safetensors"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

fn train_in_pool(threads: usize, seed: u64, data: &MlpDataset<'_>, cfg: &MlpTrainConfig) -> Mlp {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut model = Mlp::new(&[100, 512, 64, 20], seed).unwrap();
        train(&mut model, data, Some(data), cfg, &mut go_on).unwrap();
        model
    })
}

#[test]
fn training_and_pca_are_deterministic_across_thread_counts() {
    let mut g = Gen(31);
    let (x, y) = regression(&mut g, 512, 100, 20, 0.05);
    let data = MlpDataset::new(x.as_ref(), y.as_ref()).unwrap();
    let cfg = MlpTrainConfig {
        epochs: 3,
        seed: 77,
        ..MlpTrainConfig::default()
    };
    // Layer products here are large enough to be split into several parallel blocks.
    let one = train_in_pool(1, 4, &data, &cfg);
    let two = train_in_pool(2, 4, &data, &cfg);
    let three = train_in_pool(3, 4, &data, &cfg);
    let bits = |m: &Mlp| {
        m.parameters()
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(bits(&one), bits(&three));
    let other_shuffle = train_in_pool(
        2,
        4,
        &data,
        &MlpTrainConfig {
            seed: 78,
            ..cfg.clone()
        },
    );
    assert_ne!(bits(&one), bits(&other_shuffle));
    let other_init = train_in_pool(2, 5, &data, &cfg);
    assert_ne!(bits(&one), bits(&other_init));
    // PCA head: same seed, 1 vs 2 threads → identical basis and codes.
    let yp = low_rank_targets(&mut g, 200, 4000, 12, 0.7, 0.05);
    let fit_in = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                PcaHead::fit(
                    yp.as_ref(),
                    None,
                    &PcaHeadOptions {
                        max_rank: 24,
                        ..Default::default()
                    },
                )
                .unwrap()
            })
    };
    let (p1, p2) = (fit_in(1), fit_in(2));
    assert_eq!(p1.head, p2.head);
    assert_eq!(p1.codes, p2.codes);
}

#[test]
fn early_stopping_keeps_the_best_epoch() {
    let mut g = Gen(41);
    let (x, y) = regression(&mut g, 80, 4, 2, 0.6);
    let (xt, yt) = (x.as_ref().subrows(0, 40), y.as_ref().subrows(0, 40));
    let (xv, yv) = (x.as_ref().subrows(40, 40), y.as_ref().subrows(40, 40));
    let tr = MlpDataset::new(xt, yt).unwrap();
    let va = MlpDataset::new(xv, yv).unwrap();
    let mut model = Mlp::new(&[4, 256, 2], 2).unwrap();
    let cfg = MlpTrainConfig {
        epochs: 2000,
        batch_size: 16,
        lr_max: 1e-2,
        weight_decay: 0.0,
        patience: Some(20),
        output_norm: OutputNorm::Global,
        ..MlpTrainConfig::default()
    };
    let mut seen = 0;
    let report = train(&mut model, &tr, Some(&va), &cfg, &mut |s: &EpochStats| {
        seen += 1;
        assert!(s.val_loss.is_some() && s.train_loss.is_finite());
        ControlFlow::Continue(())
    })
    .unwrap();
    assert!(
        report.stopped_early,
        "no early stop in {} epochs",
        report.history.len()
    );
    assert_eq!(seen, report.history.len());
    let best = report.best_epoch.unwrap();
    assert_eq!(report.history.len(), best + 20);
    let best_val = report.best_val_loss.unwrap();
    assert!(
        report
            .history
            .iter()
            .all(|s| s.val_loss.unwrap() >= best_val)
    );
    // The restored weights reproduce the best validation loss exactly.
    assert_eq!(evaluate(&model, &va, &Loss::Mse).unwrap(), best_val);
    // Global output normalization: one scale for all outputs.
    assert_eq!(model.output_scale()[0], model.output_scale()[1]);
    // The callback can stop training.
    let mut m2 = Mlp::new(&[4, 8, 2], 2).unwrap();
    let r2 = train(&mut m2, &tr, None, &cfg, &mut |s: &EpochStats| {
        if s.epoch == 3 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })
    .unwrap();
    assert!(r2.cancelled && r2.history.len() == 3);
    // Bad data and configs are rejected.
    let mut xn = x.clone();
    xn[(2, 1)] = f32::INFINITY;
    let bad = MlpDataset::new(xn.as_ref(), y.as_ref()).unwrap();
    let e = train(&mut m2, &bad, None, &cfg, &mut go_on).unwrap_err();
    assert!(e.to_string().contains("sample 2, column 1"), "{e}");
    let e = train(
        &mut m2,
        &tr,
        None,
        &MlpTrainConfig {
            batch_size: 0,
            ..cfg.clone()
        },
        &mut go_on,
    )
    .unwrap_err();
    assert!(e.to_string().contains("batch_size"), "{e}");
    assert!(MlpDataset::new(x.as_ref(), y.as_ref().subrows(0, 3)).is_err());
}

#[test]
fn cosine_schedule_endpoints() {
    assert_eq!(cosine_lr(1e-3, 1e-5, 0, 100), 1e-3);
    assert!((cosine_lr(1e-3, 1e-5, 99, 100) - 1e-5).abs() < 1e-18);
    assert!((cosine_lr(1e-3, 1e-5, 33, 67) - 0.5 * (1e-3 + 1e-5)).abs() < 1e-15);
}
