//! Sparse localized decomposition (docs/design/splocs-model.md §3, tests of docs/design/splocs-model.md §7): the soft-threshold prox,
//! the Gram-trick weight update against the explicit residual, the residual-free objective,
//! monotone objective, recovery of planted localized signed components on a mesh, encoding of
//! held-out samples, determinism across thread counts, input validation.

use panoman_mesh::shapes::icosphere;

use faer::Mat;
use panoman_mesh::Topology;
use panoman_model::geodesic::{EdgeGeodesics, PartGeodesics};
use panoman_model::splocs::{
    self, Decomposition, SplocsOptions, WeightNorm, objective_residual_free, soft_threshold,
    update_weights_gram,
};

type V3 = [f64; 3];

/// SplitMix64.
struct Rng(u64);
impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

fn normalize(p: V3) -> V3 {
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

// ---------------------------------------------------------------------------------------------

#[test]
fn soft_threshold_matches_brute_force() {
    let mut rng = Rng(7);
    for _ in 0..300 {
        let y = rng.range(-3.0, 3.0);
        let t = if rng.uniform() < 0.1 {
            0.0
        } else {
            rng.range(0.0, 2.0)
        };
        let obj = |z: f64| 0.5 * (z - y) * (z - y) + t * z.abs();
        // Dense grid, then golden-section refinement around the best grid point.
        let (lo, hi, steps) = (-4.0, 4.0, 8000);
        let mut best = lo;
        for i in 0..=steps {
            let z = lo + (hi - lo) * i as f64 / steps as f64;
            if obj(z) < obj(best) {
                best = z;
            }
        }
        let (mut a, mut b) = (best - 1e-3, best + 1e-3);
        let g = (5f64.sqrt() - 1.0) / 2.0;
        for _ in 0..100 {
            let (c, d) = (b - g * (b - a), a + g * (b - a));
            if obj(c) < obj(d) {
                b = d;
            } else {
                a = c;
            }
        }
        let z_bf = 0.5 * (a + b);
        let z = soft_threshold(y, t);
        assert!(
            (z - z_bf).abs() < 1e-6,
            "y {y}, t {t}: prox {z}, brute force {z_bf}"
        );
        assert!(obj(z) <= obj(z_bf) + 1e-12);
    }
    assert_eq!(soft_threshold(0.5, 0.5), 0.0);
    assert_eq!(soft_threshold(-2.0, 0.5), -1.5);
}

/// Column-major helpers for the small f64 checks.
fn random_mat(rng: &mut Rng, rows: usize, cols: usize, s: f64) -> Vec<f64> {
    (0..rows * cols).map(|_| s * rng.normal()).collect()
}

/// A·B for column-major A (r×k), B (k×c).
fn mul(a: &[f64], b: &[f64], r: usize, k: usize, c: usize) -> Vec<f64> {
    let mut out = vec![0.0; r * c];
    for j in 0..c {
        for t in 0..k {
            let bv = b[j * k + t];
            for i in 0..r {
                out[j * r + i] += a[t * r + i] * bv;
            }
        }
    }
    out
}

/// Explicit-residual BCD weight update (docs/design/splocs-model.md §3.6) with the same normalization and safeguard;
/// rescales C in place. Returns the scale factors.
#[allow(clippy::too_many_arguments)]
fn explicit_update(
    x: &[f64],
    w: &mut [f64],
    c: &mut [f64],
    n: usize,
    m: usize,
    k: usize,
    norm: WeightNorm,
    pen: Option<&[f64]>,
) -> Vec<f64> {
    let wc = mul(w, c, n, k, m);
    let mut r: Vec<f64> = x.iter().zip(&wc).map(|(a, b)| a - b).collect();
    let mut scales = vec![1.0; k];
    for kk in 0..k {
        let ck: Vec<f64> = (0..m).map(|e| c[e * k + kk]).collect();
        let gkk: f64 = ck.iter().map(|v| v * v).sum();
        let w_old: Vec<f64> = w[kk * n..(kk + 1) * n].to_vec();
        // Residual without component k.
        for e in 0..m {
            for i in 0..n {
                r[e * n + i] += w_old[i] * ck[e];
            }
        }
        let u: Vec<f64> = (0..n)
            .map(|i| (0..m).map(|e| r[e * n + i] * ck[e]).sum::<f64>() / gkk)
            .collect();
        let fit = |wv: &[f64]| -> f64 {
            let mut s = 0.0;
            for e in 0..m {
                for i in 0..n {
                    let v = r[e * n + i] - wv[i] * ck[e];
                    s += v * v;
                }
            }
            0.5 * s
        };
        let proj = |v: f64| match norm {
            WeightNorm::MaxAbs => v,
            WeightNorm::NonNegMax => v.max(0.0),
        };
        let mut wn: Vec<f64> = u.iter().map(|&v| proj(v)).collect();
        let mut mm = wn.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
        if let Some(pen) = pen {
            let delta = fit(&wn) - fit(&w_old) + (mm - 1.0) * pen[kk];
            if delta > 0.0 {
                let lo = if norm == WeightNorm::MaxAbs {
                    -1.0
                } else {
                    0.0
                };
                wn = u.iter().map(|&v| v.clamp(lo, 1.0)).collect();
                mm = wn.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
            }
        }
        for i in 0..n {
            w[kk * n + i] = wn[i] / mm;
        }
        for e in 0..m {
            c[e * k + kk] *= mm;
            for i in 0..n {
                r[e * n + i] -= w[kk * n + i] * c[e * k + kk];
            }
        }
        scales[kk] = mm;
    }
    scales
}

#[test]
fn gram_trick_weight_update_equals_explicit_residual() {
    let (n, m, k) = (30, 50, 5);
    for (seed, norm, safeguard) in [
        (1, WeightNorm::MaxAbs, false),
        (2, WeightNorm::NonNegMax, false),
        (3, WeightNorm::MaxAbs, true),
        (4, WeightNorm::NonNegMax, true),
    ] {
        let mut rng = Rng(seed);
        let x = random_mat(&mut rng, n, m, 1.0);
        let w0: Vec<f64> = (0..n * k).map(|_| rng.range(-1.0, 1.0)).collect();
        // Small components make the unnormalized weights exceed 1 (m > 1), and penalties
        // large enough make the safeguard trigger for some columns.
        let c0 = random_mat(&mut rng, k, m, 0.05);
        let pen: Vec<f64> = (0..k).map(|_| rng.range(0.0, 40.0)).collect();
        let pen_opt = if safeguard { Some(&pen[..]) } else { None };

        // Gram trick.
        let mut w_g = w0.clone();
        let ct: Vec<f64> = {
            let mut t = vec![0.0; m * k];
            for e in 0..m {
                for kk in 0..k {
                    t[kk * m + e] = c0[e * k + kk];
                }
            }
            t
        };
        let mut p = mul(&x, &ct, n, m, k); // X·Cᵀ
        let mut g = mul(&c0, &ct, k, m, k); // C·Cᵀ
        let step = update_weights_gram(&mut w_g, &mut p, &mut g, n, k, norm, pen_opt, 1e-12);

        // Explicit residual.
        let mut w_e = w0.clone();
        let mut c_e = c0.clone();
        let scales = explicit_update(&x, &mut w_e, &mut c_e, n, m, k, norm, pen_opt);

        let dw = w_g
            .iter()
            .zip(&w_e)
            .fold(0.0f64, |a, (p, q)| a.max((p - q).abs()));
        let ds = step
            .scale
            .iter()
            .zip(&scales)
            .fold(0.0f64, |a, (p, q)| a.max((p - q).abs() / q.abs()));
        eprintln!(
            "{norm:?} safeguard {safeguard}: max |ΔW| {dw:.2e}, max rel Δscale {ds:.2e}, safeguarded {}",
            step.safeguarded
        );
        assert!(dw < 1e-10, "{norm:?}: W differs by {dw}");
        assert!(ds < 1e-10, "{norm:?}: scales differ by {ds}");
        assert!(step.dead.iter().all(|d| !d));
        if safeguard {
            assert!(step.safeguarded > 0, "the safeguard was never exercised");
        }
        // The cached P and G describe the rescaled C.
        let ct_e: Vec<f64> = {
            let mut t = vec![0.0; m * k];
            for e in 0..m {
                for kk in 0..k {
                    t[kk * m + e] = c_e[e * k + kk];
                }
            }
            t
        };
        let p_e = mul(&x, &ct_e, n, m, k);
        let g_e = mul(&c_e, &ct_e, k, m, k);
        let dp = p
            .iter()
            .zip(&p_e)
            .fold(0.0f64, |a, (u, v)| a.max((u - v).abs()));
        let dg = g
            .iter()
            .zip(&g_e)
            .fold(0.0f64, |a, (u, v)| a.max((u - v).abs()));
        assert!(dp < 1e-10 && dg < 1e-10, "P {dp}, G {dg}");
        // W is normalized.
        for kk in 0..k {
            let mx = w_g[kk * n..(kk + 1) * n]
                .iter()
                .fold(0.0f64, |a, &v| a.max(v.abs()));
            assert!((mx - 1.0).abs() < 1e-12);
            if norm == WeightNorm::NonNegMax {
                assert!(w_g[kk * n..(kk + 1) * n].iter().all(|&v| v >= 0.0));
            }
        }
    }
}

#[test]
fn safeguarded_weight_update_never_increases_the_objective() {
    let (n, m, k) = (25, 40, 6);
    let mut rng = Rng(11);
    for _ in 0..20 {
        let x = random_mat(&mut rng, n, m, 1.0);
        let mut w: Vec<f64> = (0..n * k).map(|_| rng.range(-1.0, 1.0)).collect();
        let sc = rng.range(0.01, 1.0);
        let mut c = random_mat(&mut rng, k, m, sc);
        let lam: Vec<f64> = (0..k * m).map(|_| rng.range(0.0, 3.0)).collect();
        let objective = |w: &[f64], c: &[f64]| -> f64 {
            let wc = mul(w, c, n, k, m);
            let fit: f64 = x
                .iter()
                .zip(&wc)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>();
            let pen: f64 = lam.iter().zip(c).map(|(l, v)| l * v.abs()).sum();
            0.5 * fit + pen
        };
        let before = objective(&w, &c);
        let pen: Vec<f64> = (0..k)
            .map(|kk| (0..m).map(|e| lam[e * k + kk] * c[e * k + kk].abs()).sum())
            .collect();
        explicit_update(&x, &mut w, &mut c, n, m, k, WeightNorm::MaxAbs, Some(&pen));
        let after = objective(&w, &c);
        assert!(after <= before * (1.0 + 1e-12), "{before} → {after}");
    }
}

#[test]
fn residual_free_objective_equals_explicit() {
    // M spans several panels of the f64 conversion (N = 37 → 2048 columns per panel).
    let (n, m, k) = (37, 5000, 7);
    let mut rng = Rng(5);
    let x: Vec<f32> = (0..n * m).map(|_| rng.normal() as f32).collect();
    let w: Vec<f64> = (0..n * k).map(|_| rng.range(-1.0, 1.0)).collect();
    let c: Vec<f64> = (0..k * m)
        .map(|_| {
            if rng.uniform() < 0.3 {
                rng.normal() * 0.4
            } else {
                0.0
            }
        })
        .collect();
    let lam: Vec<f64> = (0..k * m).map(|_| rng.range(0.0, 2.0)).collect();
    let parts = objective_residual_free(&x, n, m, &w, &c, &lam, k);
    // Explicit residual in f64.
    let mut fit = 0.0;
    for e in 0..m {
        for i in 0..n {
            let mut r = x[e * n + i] as f64;
            for kk in 0..k {
                r -= w[kk * n + i] * c[e * k + kk];
            }
            fit += r * r;
        }
    }
    fit *= 0.5;
    let pen: f64 = lam.iter().zip(&c).map(|(l, v)| l * v.abs()).sum();
    let x_sq: f64 = x.iter().map(|&v| (v as f64) * (v as f64)).sum();
    eprintln!(
        "fit {} vs {fit}, penalty {} vs {pen}",
        parts.fit, parts.penalty
    );
    assert!(
        (parts.fit - fit).abs() < 1e-12 * x_sq,
        "fit {} vs {fit}",
        parts.fit
    );
    assert!((parts.penalty - pen).abs() < 1e-12 * pen);
    assert!((parts.total - (fit + pen)).abs() < 1e-12 * x_sq);
}

// ---------------------------------------------------------------------------------------------
// Planted localized components on a sphere mesh.

struct Planted {
    topo: Topology,
    geo: EdgeGeodesics,
    /// N×M column-major data.
    x: Vec<f32>,
    n: usize,
    /// Planted components (rows) and their supports (great-circle distance < R).
    comps: Vec<Vec<f64>>,
    support: Vec<Vec<bool>>,
}

fn planted(n: usize, noise: f64, seed: u64) -> Planted {
    let (v, f) = icosphere(4); // 2562 vertices, 7680 edges
    let topo = Topology::build(v.len(), &f).unwrap();
    let geo = EdgeGeodesics::new(&topo, &v).unwrap();
    let m = topo.n_edges();
    let mids: Vec<V3> = topo
        .edges
        .iter()
        .map(|&[a, b]| {
            let (p, q) = (v[a as usize], v[b as usize]);
            normalize([p[0] + q[0], p[1] + q[1], p[2] + q[2]])
        })
        .collect();
    let dirs: [V3; 6] = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let amp = [1.0, -0.8, 1.2, 0.9, -1.1, 0.7];
    let radius = 0.45;
    let mut comps = Vec::new();
    let mut support = Vec::new();
    for (j, d) in dirs.iter().enumerate() {
        let mut c = vec![0.0; m];
        let mut s = vec![false; m];
        for e in 0..m {
            let p = mids[e];
            let ang = (p[0] * d[0] + p[1] * d[1] + p[2] * d[2])
                .clamp(-1.0, 1.0)
                .acos();
            let t = ang / radius;
            if t < 1.0 {
                // Signed profile: positive core, negative ring.
                c[e] = amp[j] * (1.0 - t * t).powi(2) * (1.0 - 2.5 * t * t);
                s[e] = true;
            }
        }
        comps.push(c);
        support.push(s);
    }
    let mut rng = Rng(seed);
    let offset: Vec<f64> = (0..m).map(|_| rng.range(-0.5, 0.5)).collect();
    let mut x = vec![0.0f32; n * m];
    let wt: Vec<Vec<f64>> = (0..n)
        .map(|_| (0..6).map(|_| rng.range(-1.0, 1.0)).collect())
        .collect();
    for e in 0..m {
        for i in 0..n {
            let mut v = offset[e] + noise * rng.normal();
            for j in 0..6 {
                v += wt[i][j] * comps[j][e];
            }
            x[e * n + i] = v as f32;
        }
    }
    Planted {
        topo,
        geo,
        x,
        n,
        comps,
        support,
    }
}

fn options(k: usize) -> SplocsOptions {
    let mut o = SplocsOptions::new(k, [0.1, 0.5]);
    o.max_outer_iters = 40;
    o
}

fn run(p: &Planted, opts: &SplocsOptions) -> Decomposition {
    let cols: Vec<u32> = (0..p.topo.n_edges() as u32).collect();
    let part = PartGeodesics::new(&p.geo, cols).unwrap();
    splocs::fit_col_major(p.x.clone(), p.n, &part, opts, |_| {}).unwrap()
}

fn check_monotone(dec: &Decomposition) {
    let h = &dec.history;
    for (t, r) in h.iter().enumerate() {
        let tol = 1e-9 * r.objective_start.abs();
        assert!(
            r.objective_after_weights <= r.objective_start + tol,
            "iteration {t}: weight update increased the objective {} → {}",
            r.objective_start,
            r.objective_after_weights
        );
        assert!(
            r.objective <= r.objective_after_weights + tol,
            "iteration {t}: component update increased the objective {} → {}",
            r.objective_after_weights,
            r.objective
        );
        if t > 0 && h[t - 1].support_changes == 0 && h[t - 1].reseeded == 0 {
            assert!(
                (r.objective_start - h[t - 1].objective).abs() <= tol,
                "iteration {t}: start {} differs from the previous end {}",
                r.objective_start,
                h[t - 1].objective
            );
        }
    }
}

#[test]
fn planted_components_are_recovered() {
    let p = planted(400, 0.02, 3);
    let m = p.topo.n_edges();
    let t = std::time::Instant::now();
    let dec = run(&p, &options(8));
    eprintln!(
        "fit: {:.2} s ({} outer iterations), explained variance {:.4}, nnz {} of {}",
        t.elapsed().as_secs_f64(),
        dec.history.len(),
        dec.explained_variance,
        dec.components.nnz(),
        8 * m
    );
    for r in &dec.history {
        eprintln!(
            "  it {:2}: obj {:.6e} rel {:.2e} safeg {} rej {} supp {} reseed {}",
            r.iteration,
            r.objective,
            r.relative_decrease,
            r.weight_safeguards,
            r.admm_rejected,
            r.support_changes,
            r.reseeded
        );
    }
    check_monotone(&dec);
    assert!(dec.explained_variance > 0.95);
    for k in 0..8 {
        eprintln!(
            "  component {k}: centre {}, radii {:?}, nnz {}, energy {:.4}",
            dec.centres[k],
            dec.radii[k],
            dec.components.row(k).0.len(),
            dec.component_energy[k]
        );
    }
    let rows: Vec<Vec<f64>> = (0..8)
        .map(|k| {
            dec.components
                .dense_row(k)
                .iter()
                .map(|&v| v as f64)
                .collect()
        })
        .collect();
    let mut used = Vec::new();
    for (j, c) in p.comps.iter().enumerate() {
        let cn = c.iter().map(|v| v * v).sum::<f64>().sqrt();
        let (best, cos) = rows
            .iter()
            .enumerate()
            .map(|(k, r)| {
                let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
                let d: f64 = r.iter().zip(c).map(|(a, b)| a * b).sum();
                (k, if rn > 0.0 { (d / (rn * cn)).abs() } else { 0.0 })
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        let r = &rows[best];
        let tot: f64 = r.iter().map(|v| v * v).sum();
        let inside: f64 = r
            .iter()
            .zip(&p.support[j])
            .filter(|(_, s)| **s)
            .map(|(v, _)| v * v)
            .sum();
        eprintln!(
            "planted {j}: component {best}, |cos| {cos:.4}, energy inside {:.4}, radii {:?}",
            inside / tot,
            dec.radii[best]
        );
        assert!(cos > 0.9, "planted {j}: |cos| {cos}");
        assert!(inside / tot > 0.95, "planted {j}: inside {}", inside / tot);
        assert!(!used.contains(&best), "component {best} matched twice");
        used.push(best);
    }
    // W is normalized to [−1, 1].
    for k in 0..8 {
        let mx = (0..p.n).fold(0.0f32, |a, i| a.max(dec.weights[(i, k)].abs()));
        assert!(
            mx == 0.0 || (mx - 1.0).abs() < 1e-6,
            "max |W[:,{k}]| = {mx}"
        );
    }

    // encode(): a sample synthesized from the components gives back its β.
    let mut rng = Rng(99);
    let beta: Vec<f64> = (0..8)
        .map(|k| {
            if dec.components.row(k).0.is_empty() {
                0.0
            } else {
                rng.range(-1.0, 1.0)
            }
        })
        .collect();
    let x: Vec<f32> = dec.reconstruct(&beta).iter().map(|&v| v as f32).collect();
    let enc = dec.encoder(0.0).unwrap();
    let b = enc.encode(&x).unwrap();
    let err = b
        .iter()
        .zip(&beta)
        .fold(0.0f64, |a, (p, q)| a.max((p - q).abs()));
    eprintln!("encode: max |β − β̂| = {err:.2e}");
    assert!(err < 1e-3, "encode error {err}");
    // A training sample is encoded close to its W row on the planted components.
    let sample: Vec<f32> = (0..m).map(|e| p.x[e * p.n + 5]).collect();
    let b5 = dec.encode(&sample, 1e-9).unwrap();
    for &k in &used {
        let d = (b5[k] - dec.weights[(5, k)] as f64).abs();
        assert!(d < 0.05, "β5[{k}] {} vs W {}", b5[k], dec.weights[(5, k)]);
    }
    assert!(enc.encode(&x[1..]).is_err());
    // The dense and sparse Gram paths agree.
    let g = dec.components.gram();
    let mut g_ref = vec![0.0f64; 64];
    for a in 0..8 {
        for b in 0..8 {
            g_ref[a * 8 + b] = rows[a].iter().zip(&rows[b]).map(|(p, q)| p * q).sum();
        }
    }
    let scale = g_ref.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        g.iter()
            .zip(&g_ref)
            .all(|(p, q)| (p - q).abs() < 1e-12 * scale)
    );
    let sparse = splocs::SparseRows {
        n_cols: 100, // 1.3 % stored: the sparse path
        row_ptr: vec![0, 2, 2, 4],
        col_idx: vec![1, 7, 0, 7],
        values: vec![2.0, -1.0, 3.0, 4.0],
    };
    assert_eq!(
        sparse.gram(),
        vec![5.0, 0.0, -4.0, 0.0, 0.0, 0.0, -4.0, 0.0, 25.0]
    );
}

#[test]
fn objective_is_monotone_with_fixed_supports() {
    let p = planted(200, 0.05, 4);
    let mut o = options(8);
    o.adapt_until = 0; // fixed supports, no re-seeding: one fixed problem
    o.max_outer_iters = 25;
    o.rel_tol = 0.0;
    let dec = run(&p, &o);
    check_monotone(&dec);
    for w in dec.history.windows(2) {
        assert!(
            w[1].objective <= w[0].objective * (1.0 + 1e-9),
            "{} → {}",
            w[0].objective,
            w[1].objective
        );
    }
    let first = dec.history.first().unwrap().objective_start;
    let last = dec.history.last().unwrap().objective;
    eprintln!(
        "objective {first:.6e} → {last:.6e} in {} iterations",
        dec.history.len()
    );
    assert!(last < first);
    assert_eq!(dec.history.len(), 25);
}

#[test]
fn deterministic_across_thread_counts() {
    let p = planted(150, 0.05, 8);
    let mut o = options(6);
    o.max_outer_iters = 8;
    let in_pool = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run(&p, &o))
    };
    let a = in_pool(1);
    let b = in_pool(3);
    assert_eq!(a.components, b.components);
    assert_eq!(a.centres, b.centres);
    assert_eq!(a.radii, b.radii);
    assert_eq!(a.mean, b.mean);
    assert_eq!(a.scale.to_bits(), b.scale.to_bits());
    for (ra, rb) in a.history.iter().zip(&b.history) {
        assert_eq!(ra.objective.to_bits(), rb.objective.to_bits());
    }
    for i in 0..p.n {
        for k in 0..6 {
            assert_eq!(a.weights[(i, k)].to_bits(), b.weights[(i, k)].to_bits());
        }
    }
}

#[test]
fn fit_from_matref_and_bad_input() {
    let p = planted(40, 0.05, 9);
    let m = p.topo.n_edges();
    let cols: Vec<u32> = (0..m as u32).collect();
    let part = PartGeodesics::new(&p.geo, cols).unwrap();
    let mut o = options(3);
    o.max_outer_iters = 2;
    let xm = Mat::<f32>::from_fn(p.n, m, |i, j| p.x[j * p.n + i]);
    let a = splocs::fit(xm.as_ref(), &part, &o).unwrap();
    let b = splocs::fit_col_major(p.x.clone(), p.n, &part, &o, |_| {}).unwrap();
    assert_eq!(a.components, b.components);

    // Wrong sizes, bad options, non-finite or constant data.
    assert!(splocs::fit_col_major(p.x[1..].to_vec(), p.n, &part, &o, |_| {}).is_err());
    assert!(splocs::fit_col_major(p.x[..m].to_vec(), 1, &part, &o, |_| {}).is_err());
    let mut bad = o.clone();
    bad.n_components = 0;
    assert!(splocs::fit_col_major(p.x.clone(), p.n, &part, &bad, |_| {}).is_err());
    let mut bad = o.clone();
    bad.d_min_bounds = [0.5, 0.1];
    assert!(splocs::fit_col_major(p.x.clone(), p.n, &part, &bad, |_| {}).is_err());
    let mut nan = p.x.clone();
    nan[17] = f32::NAN;
    assert!(splocs::fit_col_major(nan, p.n, &part, &o, |_| {}).is_err());
    assert!(splocs::fit_col_major(vec![1.5; p.n * m], p.n, &part, &o, |_| {}).is_err());
    let small = PartGeodesics::new(&p.geo, vec![0, 1, 2]).unwrap();
    assert!(splocs::fit_col_major(p.x.clone(), p.n, &small, &o, |_| {}).is_err());
}
