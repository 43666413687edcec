//! Tests of the discrete-shell Levenberg–Marquardt solver (docs/design/shell-fit.md §3.2–3.4).
#![allow(clippy::needless_range_loop)]

mod common;

use common::{Rng, deform, grid, icosphere};
use panoman_mesh::align::aligned_error;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_mesh::rla::{dihedral_angles, edge_lengths};
use panoman_mesh::shell::{
    Handle, PcgOptions, PointConstraint, ShellOptions, ShellSolver, ShellStop, ShellTargets,
    residual_rms,
};
use panoman_mesh::sparse::SpdFactor;
use panoman_mesh::{Reconstructor, Topology};

fn deformed_sphere(subdiv: usize) -> (Vec<V3>, Topology) {
    let (v, f) = icosphere(subdiv);
    let v: Vec<V3> = v.into_iter().map(deform).collect();
    let topo = Topology::build(v.len(), &f).unwrap();
    (v, topo)
}

fn mean_edge(topo: &Topology, x: &[V3]) -> f64 {
    let l = edge_lengths(topo, x);
    l.iter().sum::<f64>() / l.len() as f64
}

fn bbox_diag(x: &[V3]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c]);
            hi[c] = hi[c].max(p[c]);
        }
    }
    norm(sub(hi, lo))
}

fn perturb(x: &[V3], sigma: f64, seed: u64) -> Vec<V3> {
    let mut rng = Rng(seed);
    x.iter()
        .map(|p| {
            let n = rng.vec3();
            [
                p[0] + sigma * n[0],
                p[1] + sigma * n[1],
                p[2] + sigma * n[2],
            ]
        })
        .collect()
}

fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

#[test]
fn own_targets_give_zero_energy_and_no_iterations() {
    for (x, topo) in [deformed_sphere(2), {
        let (v, f) = grid(8);
        let t = Topology::build(v.len(), &f).unwrap();
        (v, t)
    }] {
        let targets = ShellTargets::from_positions(&topo, &x, 1.0).unwrap();
        let mut solver = ShellSolver::new(&topo).unwrap();
        let mut y = x.clone();
        let rep = solver
            .solve(&targets, &mut y, &ShellOptions::default())
            .unwrap();
        assert_eq!(rep.energies[0], 0.0);
        assert_eq!(rep.iterations, 0);
        assert_eq!(rep.stop, ShellStop::Converged);
        assert_eq!(y, x);
        assert_eq!(rep.length_rms, 0.0);
        assert_eq!(rep.angle_rms, 0.0);
    }
}

#[test]
fn recovers_mesh_from_perturbed_start() {
    for (subdiv, seed) in [(2usize, 1u64), (3, 2)] {
        let (truth, topo) = deformed_sphere(subdiv);
        let targets = ShellTargets::from_positions(&topo, &truth, 1.0).unwrap();
        let sigma = 0.05 * mean_edge(&topo, &truth);
        let mut x = perturb(&truth, sigma, seed);
        let (start_max, _) = aligned_error(&x, &truth);
        let mut solver = ShellSolver::new(&topo).unwrap();
        let opts = ShellOptions {
            max_iterations: 50,
            ..Default::default()
        };
        let rep = solver.solve(&targets, &mut x, &opts).unwrap();
        let (max, mean) = aligned_error(&x, &truth);
        let diag = bbox_diag(&truth);
        println!(
            "subdiv {subdiv}: {} iterations ({} accepted, stop {:?}), E {:.3e} → {:.3e}, \
             error max {:.2e} (start {:.2e}) mean {:.2e} × bbox diag, {:.1} ms",
            rep.iterations,
            rep.accepted,
            rep.stop,
            rep.energies[0],
            rep.energies.last().unwrap(),
            max / diag,
            start_max / diag,
            mean / diag,
            rep.total_seconds * 1e3
        );
        assert!(max < 1e-6 * diag, "max error {max:e} vs diag {diag}");
        for w in rep.energies.windows(2) {
            assert!(w[1] <= w[0], "energy increased: {:?}", rep.energies);
        }
        assert!(rep.length_rms < 1e-8 && rep.angle_rms < 1e-8);
    }
}

/// Targets with a generic mismatch (other mesh's lengths/angles), plus handles.
fn generic_problem(x: &[V3], topo: &Topology, seed: u64) -> (ShellTargets, Vec<V3>) {
    let ml = mean_edge(topo, x);
    let other = perturb(x, 0.1 * ml, seed);
    let mut t = ShellTargets::new(
        topo,
        edge_lengths(topo, &other),
        dihedral_angles(topo, &other),
        x,
        0.7,
    )
    .unwrap();
    let mut rng = Rng(seed + 100);
    for w in t.length_weights.iter_mut() {
        *w = rng.range(0.5, 2.0);
    }
    t.handles = vec![
        Handle {
            vertex: 3,
            position: [0.1, 0.2, 0.3],
            weight: 2.0 / (ml * ml),
        },
        Handle {
            vertex: 7,
            position: x[7],
            weight: 0.5 / (ml * ml),
        },
    ];
    // A keypoint-like combination of scattered vertices and a point-to-plane surface point.
    let f0 = topo.faces[2];
    t.points = vec![
        PointConstraint {
            rows: vec![(0, 0.4), (5, 0.3), (9, 0.2), (0, 0.1)],
            target: [0.05, -0.1, 0.2],
            weight: 3.0 / (ml * ml),
            normal: None,
        },
        PointConstraint {
            rows: vec![(f0[0], 0.2), (f0[1], 0.3), (f0[2], 0.5)],
            target: [0.3, 0.1, -0.2],
            weight: 1.5 / (ml * ml),
            normal: Some([0.6, 0.0, 0.8]),
        },
    ];
    let start = perturb(x, 0.03 * ml, seed + 7);
    (t, start)
}

/// The pattern pairs the point constraints of [`generic_problem`] need.
const EXTRA_PAIRS: [(u32, u32); 3] = [(0, 5), (0, 9), (5, 9)];

#[test]
fn point_constraint_outside_the_pattern_is_an_error() {
    let (x0, topo) = deformed_sphere(2);
    let (targets, x) = generic_problem(&x0, &topo, 5);
    let mut solver = ShellSolver::new(&topo).unwrap();
    let err = solver
        .linearize(&targets, &x, 1e-6)
        .unwrap_err()
        .to_string();
    assert!(err.contains("not coupled"), "{err}");
    let mut solver = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS).unwrap();
    assert!(solver.linearize(&targets, &x, 1e-6).is_ok());
}

#[test]
fn gradient_and_gauss_newton_matrix_match_finite_differences() {
    let meshes = [deformed_sphere(2), {
        let (v, f) = grid(6);
        let t = Topology::build(v.len(), &f).unwrap();
        (v, t)
    }];
    for (x0, topo) in meshes {
        let (targets, x) = generic_problem(&x0, &topo, 5);
        let mut solver = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS).unwrap();
        let e0 = solver.linearize(&targets, &x, 1e-6).unwrap();
        assert!(e0 > 0.0);
        let n = 3 * x.len();
        // ∇E = 2 Jᵀr against central differences of E.
        let h = 1e-6 * mean_edge(&topo, &x);
        let mut fd = vec![0.0; n];
        let mut y = x.clone();
        for c in 0..n {
            let (v, d) = (c / 3, c % 3);
            y[v][d] = x[v][d] + h;
            let ep = solver.energy(&targets, &y).unwrap();
            y[v][d] = x[v][d] - h;
            let em = solver.energy(&targets, &y).unwrap();
            y[v][d] = x[v][d];
            fd[c] = (ep - em) / (2.0 * h);
        }
        let g2: Vec<f64> = solver.gradient().iter().map(|g| 2.0 * g).collect();
        let eg = rel_err(&g2, &fd);
        println!("gradient relative error {eg:.2e}");
        assert!(eg < 1e-6, "gradient relative error {eg:e}");

        // J·v against the central difference of the residual vector.
        let mut rng = Rng(11);
        let v: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let m = solver.n_residuals(&targets);
        let (mut rp, mut rm, mut jv) = (vec![0.0; m], vec![0.0; m], vec![0.0; m]);
        let t = 1e-7 * mean_edge(&topo, &x);
        let shifted = |s: f64| -> Vec<V3> {
            x.iter()
                .enumerate()
                .map(|(i, p)| {
                    [
                        p[0] + s * v[3 * i],
                        p[1] + s * v[3 * i + 1],
                        p[2] + s * v[3 * i + 2],
                    ]
                })
                .collect()
        };
        solver.residuals_into(&targets, &shifted(t), &mut rp);
        solver.residuals_into(&targets, &shifted(-t), &mut rm);
        let fdj: Vec<f64> = rp
            .iter()
            .zip(&rm)
            .map(|(a, b)| (a - b) / (2.0 * t))
            .collect();
        solver.jacobian_mul(&targets, &v, &mut jv);
        let ej = rel_err(&jv, &fdj);
        println!("J·v relative error {ej:.2e}");
        assert!(ej < 1e-6, "J·v relative error {ej:e}");

        // The scatter-assembled JᵀJ against the matrix-free rows: vᵀ(JᵀJ)v = |Jv|², and
        // (JᵀJ)·e_c column sums against Jᵀ(J e_c) for a few columns.
        let mut hv = vec![0.0; n];
        solver.normal_matrix_mul(&v, &mut hv);
        let vhv: f64 = v.iter().zip(&hv).map(|(a, b)| a * b).sum();
        let jv2: f64 = jv.iter().map(|a| a * a).sum();
        assert!(
            (vhv - jv2).abs() < 1e-12 * jv2,
            "vᵀJᵀJv {vhv} vs |Jv|² {jv2}"
        );
        // The product is split into fixed parts summed in order: bit-identical whatever the
        // number of threads.
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut hv_t = vec![0.0; n];
            pool.install(|| solver.normal_matrix_mul(&v, &mut hv_t));
            assert!(
                hv_t.iter()
                    .zip(&hv)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "JᵀJ·v with {threads} threads differs from the default pool's"
            );
        }
        let mut rng = Rng(12);
        for _ in 0..20 {
            let w: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
            let mut jw = vec![0.0; m];
            solver.jacobian_mul(&targets, &w, &mut jw);
            let whv: f64 = w.iter().zip(&hv).map(|(a, b)| a * b).sum();
            let jwjv: f64 = jw.iter().zip(&jv).map(|(a, b)| a * b).sum();
            assert!(
                (whv - jwjv).abs() < 1e-11 * (jv2 + jw.iter().map(|a| a * a).sum::<f64>()),
                "wᵀJᵀJv {whv} vs (Jw)·(Jv) {jwjv}"
            );
        }

        // At a zero-residual point the directional derivative of g = Jᵀr is exactly JᵀJ·v.
        let own = ShellTargets::from_positions(&topo, &x0, 1.0).unwrap();
        solver.linearize(&own, &x0, 1e-6).unwrap();
        solver.normal_matrix_mul(&v, &mut hv);
        let t = 1e-6 * mean_edge(&topo, &x0);
        let xs: Vec<V3> = x0
            .iter()
            .enumerate()
            .map(|(i, p)| {
                [
                    p[0] + t * v[3 * i],
                    p[1] + t * v[3 * i + 1],
                    p[2] + t * v[3 * i + 2],
                ]
            })
            .collect();
        solver.linearize(&own, &xs, 1e-6).unwrap();
        let gp = solver.gradient().to_vec();
        let xs: Vec<V3> = x0
            .iter()
            .enumerate()
            .map(|(i, p)| {
                [
                    p[0] - t * v[3 * i],
                    p[1] - t * v[3 * i + 1],
                    p[2] - t * v[3 * i + 2],
                ]
            })
            .collect();
        solver.linearize(&own, &xs, 1e-6).unwrap();
        let fdh: Vec<f64> = gp
            .iter()
            .zip(solver.gradient())
            .map(|(a, b)| (a - b) / (2.0 * t))
            .collect();
        let eh = rel_err(&hv, &fdh);
        println!("JᵀJ·v vs d(Jᵀr)/dv at zero residual: relative error {eh:.2e}");
        assert!(eh < 1e-6, "JᵀJ·v relative error {eh:e}");
    }
}

#[test]
fn symbolic_reuse_matches_fresh_factorization() {
    let (x0, topo) = deformed_sphere(2);
    let (targets, x1) = generic_problem(&x0, &topo, 9);
    let x2 = perturb(&x1, 0.02 * mean_edge(&topo, &x1), 33);
    let mut solver = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS).unwrap();
    let n = 3 * x1.len();
    let mut d = vec![0.0; n];
    solver.linearize(&targets, &x1, 1e-6).unwrap();
    solver.step(1e-2, false, &mut d).unwrap();
    for (mu, par) in [(1e-3, false), (1e-5, true)] {
        solver.linearize(&targets, &x2, 1e-6).unwrap();
        solver.step(mu, par, &mut d).unwrap();
        let fresh = SpdFactor::new(&solver.damped_matrix(mu)).unwrap();
        let mut rhs = faer::Mat::from_fn(n, 1, |i, _| -solver.gradient()[i]);
        let mut scratch = fresh.make_scratch(1);
        fresh.solve_in_place(rhs.as_mut(), &mut scratch);
        let r: Vec<f64> = (0..n).map(|i| rhs[(i, 0)]).collect();
        let e = rel_err(&d, &r);
        println!("μ {mu:e}: reused vs fresh relative difference {e:.2e}");
        assert!(e < 1e-10, "reused vs fresh: {e:e}");
    }
}

#[test]
fn noisy_angles_exact_lengths_stay_nearly_isometric() {
    let (truth, topo) = deformed_sphere(3);
    let lengths = edge_lengths(&topo, &truth);
    let mut angles = dihedral_angles(&topo, &truth);
    let mut rng = Rng(77);
    let noise = 0.03;
    for a in angles.iter_mut() {
        *a += noise * rng.normal();
    }
    // g from the noisy targets, gauged on the truth.
    let rec = Reconstructor::new(&topo).unwrap();
    let mut ws = rec.workspace();
    let gauge = rec.gauge_from(&truth).unwrap();
    let mut x = vec![[0.0; 3]; truth.len()];
    rec.reconstruct(&mut ws, &lengths, &angles, &gauge, &mut x)
        .unwrap();
    let x_g = x.clone();
    let (g_err, _) = aligned_error(&x_g, &truth);
    let diag = bbox_diag(&truth);
    // c_B = 1 lets bending trade stretch for angle fit; small c_B lets the (exact) lengths,
    // which nearly determine a closed surface, dominate.
    let mut results = Vec::new();
    for c_b in [1.0, 0.3, 0.1] {
        let targets = ShellTargets::new(&topo, lengths.clone(), angles.clone(), &x_g, c_b).unwrap();
        let (g_len, g_ang) = panoman_mesh::shell::residual_rms(&topo, &targets, &x_g);
        let mut x = x_g.clone();
        let mut solver = ShellSolver::new(&topo).unwrap();
        let rep = solver
            .solve(&targets, &mut x, &ShellOptions::default())
            .unwrap();
        let (s_err, s_mean) = aligned_error(&x, &truth);
        println!(
            "c_B {c_b}: g: length rms {g_len:.2e}, angle rms {g_ang:.3}, max err {:.2e}; shell: \
             length rms {:.2e}, angle rms {:.3}, max err {:.2e} mean {:.2e} (× diag), {} \
             iterations ({:?}), E {:.3e} → {:.3e}",
            g_err / diag,
            rep.length_rms,
            rep.angle_rms,
            s_err / diag,
            s_mean / diag,
            rep.iterations,
            rep.stop,
            rep.energies[0],
            rep.energies.last().unwrap()
        );
        assert!(x.iter().flatten().all(|c| c.is_finite()));
        for w in rep.energies.windows(2) {
            assert!(w[1] <= w[0]);
        }
        results.push((c_b, g_len, rep.length_rms, rep.angle_rms, s_err));
    }
    let (_, g_len, len_rms, ang_rms, s_err) = results[2];
    assert!(
        len_rms < 0.2 * g_len,
        "c_B 0.1: length rms {len_rms} vs g {g_len}"
    );
    assert!(len_rms < 0.05 * noise, "c_B 0.1: length rms {len_rms}");
    assert!(ang_rms < 1.5 * noise, "c_B 0.1: angle rms {ang_rms}");
    assert!(s_err < g_err, "c_B 0.1: shell error {s_err} vs g {g_err}");
}

/// (topology, targets, start, supports, mean edge) of [`dense_support_problem`].
type DenseSupportProblem = (Topology, ShellTargets, Vec<V3>, Vec<Vec<(u32, f64)>>, f64);

/// The dense-support problem of [`dense_support_matches_the_assembled_clique`]: a deformed
/// sphere with generic shell targets, two wide point supports over a third of the vertices
/// each (one vertex listed twice), the first given twice, and a third registered support
/// without a constraint. Returns (topology, targets, start, supports, mean edge).
fn dense_support_problem() -> DenseSupportProblem {
    let (x0, topo) = deformed_sphere(2);
    let (mut targets, x) = generic_problem(&x0, &topo, 21);
    let ml = mean_edge(&topo, &x0);
    let nv = x0.len() as u32;
    // Two supports over a third of the vertices each (one vertex listed twice), and a third
    // registered support without a constraint (decoupled in the step).
    let wide: Vec<Vec<(u32, f64)>> = (0..3)
        .map(|s| {
            let mut r: Vec<(u32, f64)> = (0..nv)
                .filter(|v| v % 3 == s)
                .map(|v| (v, 1.0 + 0.1 * (v % 7) as f64))
                .collect();
            r.push((s, 0.5));
            let tot: f64 = r.iter().map(|p| p.1).sum();
            r.iter().map(|&(v, b)| (v, b / tot)).collect()
        })
        .collect();
    for (k, rows) in wide.iter().take(2).enumerate() {
        targets.points.push(PointConstraint {
            rows: rows.clone(),
            target: [0.1 * k as f64, -0.05, 0.02],
            weight: 5.0 / (ml * ml),
            normal: None,
        });
    }
    // Same support given twice with different targets (weights add, targets average).
    targets.points.push(PointConstraint {
        rows: wide[0].clone(),
        target: [0.0, 0.1, 0.0],
        weight: 2.0 / (ml * ml),
        normal: None,
    });
    (topo, targets, x, wide, ml)
}

/// A wide point support (a keypoint regressor over many vertices) kept out of JᵀJ through the
/// quasi-definite system gives the same energy, gradient, normal-matrix products, LM steps and
/// solve as assembling its dense clique into the pattern.
#[test]
fn dense_support_matches_the_assembled_clique() {
    let (topo, targets, x, wide, ml) = dense_support_problem();
    let mut pairs: Vec<(u32, u32)> = EXTRA_PAIRS.to_vec();
    for rows in &wide {
        for (p, &(a, _)) in rows.iter().enumerate() {
            for &(b, _) in &rows[..p] {
                if a != b {
                    pairs.push((a.min(b), a.max(b)));
                }
            }
        }
    }
    let mut clique = ShellSolver::with_extra_pairs(&topo, &pairs).unwrap();
    let mut dense = ShellSolver::with_dense_supports(&topo, &EXTRA_PAIRS, &wide).unwrap();
    assert!(
        dense.nnz() < clique.nnz() / 2,
        "{} vs {}",
        dense.nnz(),
        clique.nnz()
    );
    let e1 = clique.linearize(&targets, &x, 1e-6).unwrap();
    let e2 = dense.linearize(&targets, &x, 1e-6).unwrap();
    assert!((e1 - e2).abs() < 1e-12 * e1, "{e1} vs {e2}");
    let eg = rel_err(dense.gradient(), clique.gradient());
    assert!(eg < 1e-12, "gradient {eg:e}");
    let n = 3 * x.len();
    let mut rng = Rng(5);
    let v: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
    let (mut h1, mut h2) = (vec![0.0; n], vec![0.0; n]);
    clique.normal_matrix_mul(&v, &mut h1);
    dense.normal_matrix_mul(&v, &mut h2);
    let eh = rel_err(&h2, &h1);
    assert!(eh < 1e-12, "JᵀJ·v {eh:e}");
    for mu in [1e-2, 1e-6] {
        let (mut d1, mut d2) = (vec![0.0; n], vec![0.0; n]);
        clique.step(mu, false, &mut d1).unwrap();
        dense.step(mu, false, &mut d2).unwrap();
        let ed = rel_err(&d2, &d1);
        println!("μ {mu:e}: quasi-definite vs clique step, relative difference {ed:.2e}");
        assert!(ed < 1e-8, "step {ed:e}");
    }
    let opts = ShellOptions {
        max_iterations: 6,
        mu_init: 1e-3,
        parallel_factor: false,
        ..Default::default()
    };
    let (mut y1, mut y2) = (x.clone(), x.clone());
    let r1 = clique.solve(&targets, &mut y1, &opts).unwrap();
    let r2 = dense.solve(&targets, &mut y2, &opts).unwrap();
    assert_eq!(r1.accepted, r2.accepted);
    let last = |r: &panoman_mesh::shell::ShellReport| *r.energies.last().unwrap();
    assert!(last(&r1) < 0.5 * r1.energies[0]);
    assert!((last(&r1) - last(&r2)).abs() < 1e-8 * last(&r1));
    let dmax = y1
        .iter()
        .zip(&y2)
        .map(|(a, b)| norm(sub(*a, *b)))
        .fold(0.0, f64::max);
    assert!(dmax < 1e-8 * ml, "solutions differ by {dmax:e}");
}

/// A one-iteration budget whose first (almost undamped) step is rejected: without retries the
/// solve ends with nothing accepted; with `retry_rejected` μ is raised and the step re-solved
/// until one lowers the energy, and the report counts the tries.
#[test]
fn rejected_steps_are_retried_within_the_budget() {
    let (truth, topo) = deformed_sphere(2);
    let targets = ShellTargets::from_positions(&topo, &truth, 1.0).unwrap();
    let sigma = 0.6 * mean_edge(&topo, &truth);
    let start = perturb(&truth, sigma, 7);
    let mut solver = ShellSolver::new(&topo).unwrap();
    let base = ShellOptions {
        max_iterations: 1,
        mu_init: 1e-10,
        ..Default::default()
    };
    let mut x = start.clone();
    let plain = solver.solve(&targets, &mut x, &base).unwrap();
    assert_eq!(plain.iterations, 1);
    assert_eq!(plain.accepted, 0, "the undamped step should be rejected");
    assert_eq!(x, start);
    let mut y = start.clone();
    let retried = solver
        .solve(
            &targets,
            &mut y,
            &ShellOptions {
                retry_rejected: 30,
                ..base
            },
        )
        .unwrap();
    assert_eq!(retried.accepted, 1, "{retried:?}");
    assert!(retried.iterations > 1);
    assert_eq!(retried.energies.len(), retried.iterations + 1);
    assert!(retried.energies.last().unwrap() < &retried.energies[0]);
    assert_eq!(retried.stop, ShellStop::MaxIterations);
}

/// PCG steps (docs/design/shell-fit.md §3.5): at a tight tolerance they equal the factored step
/// (the damped system is SPD, CG's error in the energy norm falls below the tolerance's);
/// at the warm frames' tolerance an LM solve with them lowers the energy as far as the
/// factored solve up to the inexactness; a cap that cannot be met falls back to the
/// factorization and reproduces the factored solve.
#[test]
fn pcg_steps_match_the_factored_step() {
    let (topo, targets, x, wide, _) = dense_support_problem();
    let mut solver = ShellSolver::with_dense_supports(&topo, &EXTRA_PAIRS, &wide).unwrap();
    solver.linearize(&targets, &x, 1e-6).unwrap();
    let n = 3 * x.len();
    for mu in [1.0, 1e-2] {
        let (mut d1, mut d2) = (vec![0.0; n], vec![0.0; n]);
        solver.step(mu, false, &mut d1).unwrap();
        let tight = PcgOptions {
            rel_tol: 1e-11,
            max_iterations: 20 * n,
        };
        let out = solver.step_pcg(mu, &tight, &mut d2).expect("PCG converges");
        let ed = rel_err(&d2, &d1);
        println!(
            "μ {mu:e}: {} PCG iterations, relative difference {ed:.2e}",
            out.iterations
        );
        assert!(ed < 1e-6, "μ {mu}: PCG vs factored step {ed:e}");
        assert!(
            out.iterations < n,
            "{} iterations for n = {n}",
            out.iterations
        );
        // A cap of one iteration cannot reach the tolerance: no step.
        let capped = PcgOptions {
            rel_tol: 1e-11,
            max_iterations: 1,
        };
        assert!(solver.step_pcg(mu, &capped, &mut d2).is_none());
    }
    let base = ShellOptions {
        max_iterations: 4,
        mu_init: 1.0,
        parallel_factor: false,
        ..Default::default()
    };
    let run = |opts: &ShellOptions| {
        let mut s = ShellSolver::with_dense_supports(&topo, &EXTRA_PAIRS, &wide).unwrap();
        let mut y = x.clone();
        let r = s.solve(&targets, &mut y, opts).unwrap();
        (r, y)
    };
    let (r_direct, y_direct) = run(&base);
    let (r_pcg, _) = run(&ShellOptions {
        pcg: Some(PcgOptions::default()),
        ..base
    });
    let last = |r: &panoman_mesh::shell::ShellReport| *r.energies.last().unwrap();
    println!(
        "energy {:.6e} → factored {:.6e}, PCG {:.6e} ({} steps, {} iterations, {} fallbacks)",
        r_direct.energies[0],
        last(&r_direct),
        last(&r_pcg),
        r_pcg.pcg_steps,
        r_pcg.pcg_iterations,
        r_pcg.pcg_fallbacks
    );
    assert_eq!(r_pcg.accepted, r_direct.accepted);
    assert!(r_pcg.pcg_steps >= r_pcg.accepted && r_pcg.pcg_fallbacks == 0);
    assert!(last(&r_direct) < 0.9 * r_direct.energies[0]);
    // An inexact step loses at most tol²·κ(JᵀJ + μD) of the exact step's model decrease
    // (‖e‖²_A ≤ ‖ρ‖²/λ_min, ‖δ*‖²_A ≥ ‖g‖²/λ_max); here ≈ 10⁻⁴ of it per step (measured:
    // 7·10⁻⁵ of the decrease after 4 steps). 5 % leaves room for the steps' compounding.
    let dec = r_direct.energies[0] - last(&r_direct);
    assert!(
        (last(&r_pcg) - last(&r_direct)).abs() < 0.05 * dec,
        "PCG {} vs factored {}",
        last(&r_pcg),
        last(&r_direct)
    );
    let (r_fb, y_fb) = run(&ShellOptions {
        pcg: Some(PcgOptions {
            rel_tol: 1e-11,
            max_iterations: 1,
        }),
        ..base
    });
    assert_eq!(r_fb.pcg_steps, 0);
    assert_eq!(r_fb.pcg_fallbacks, r_fb.iterations);
    assert_eq!(r_fb.energies, r_direct.energies);
    assert_eq!(y_fb, y_direct);
}

/// The report's residual RMS (taken from the energy evaluation that accepted the last step,
/// or computed afresh when no step was accepted) equals `residual_rms` at the returned
/// vertices bit for bit, with one or several accepted steps and with none; a grid mesh has
/// boundary edges (no angle row), and zero angle weights keep their angles in the RMS.
#[test]
fn report_rms_equals_residual_rms_at_the_result() {
    let (truth, topo) = deformed_sphere(2);
    let (generic, x0) = generic_problem(&truth, &topo, 5);
    let (gx, gf) = grid(6);
    let gtopo = Topology::build(gx.len(), &gf).unwrap();
    let bent: Vec<V3> = gx
        .iter()
        .map(|p| [p[0], p[1], p[2] + 0.2 * p[0] * p[1]])
        .collect();
    let mut zero_angles = ShellTargets::from_positions(&gtopo, &bent, 1.0).unwrap();
    let interior = (0..gtopo.n_edges())
        .find(|&e| zero_angles.angle_weights[e] > 0.0)
        .unwrap();
    zero_angles.angle_weights[interior] = 0.0;
    let cases: Vec<(&Topology, &ShellTargets, Vec<V3>, usize)> = vec![
        (&topo, &generic, x0.clone(), 1),
        (&topo, &generic, x0.clone(), 5),
        (&gtopo, &zero_angles, gx.clone(), 3),
    ];
    for (topo, targets, start, iterations) in cases {
        for pcg in [None, Some(PcgOptions::default())] {
            let mut x = start.clone();
            let rep = ShellSolver::with_extra_pairs(topo, &EXTRA_PAIRS)
                .unwrap()
                .solve(
                    targets,
                    &mut x,
                    &ShellOptions {
                        max_iterations: iterations,
                        pcg,
                        ..Default::default()
                    },
                )
                .unwrap();
            assert!(rep.accepted >= 1, "{rep:?}");
            let (lr, ar) = residual_rms(topo, targets, &x);
            assert_eq!((rep.length_rms, rep.angle_rms), (lr, ar));
        }
    }
    // No step taken (already at the targets' own mesh): computed afresh.
    let own = ShellTargets::from_positions(&topo, &truth, 1.0).unwrap();
    let mut x = truth.clone();
    let rep = ShellSolver::new(&topo)
        .unwrap()
        .solve(&own, &mut x, &ShellOptions::default())
        .unwrap();
    assert_eq!(rep.accepted, 0);
    assert_eq!(
        (rep.length_rms, rep.angle_rms),
        residual_rms(&topo, &own, &x)
    );
}

/// A whole solve — the assembly in two vertex halves plus the straddling edges, and PCG's
/// vector work in fixed chunks with ordered partial sums — gives bit-identical vertices,
/// energies and iteration counts with 1, 2 and 3 threads (PanoMan's "deterministic given a
/// seed"). The sphere (subdivision 5: 10,242 vertices) spans several PCG chunks.
#[test]
fn solve_is_bit_identical_for_any_thread_count() {
    let (truth, topo) = deformed_sphere(5);
    let (targets, start) = generic_problem(&truth, &topo, 11);
    let run = |threads: usize, pcg: Option<PcgOptions>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut x = start.clone();
            let rep = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS)
                .unwrap()
                .solve(
                    &targets,
                    &mut x,
                    &ShellOptions {
                        max_iterations: 2,
                        pcg,
                        ..Default::default()
                    },
                )
                .unwrap();
            (x, rep)
        })
    };
    for pcg in [None, Some(PcgOptions::default())] {
        let (x1, r1) = run(1, pcg);
        assert!(r1.accepted >= 1);
        if pcg.is_some() {
            assert!(r1.pcg_iterations > 1 && r1.pcg_fallbacks == 0, "{r1:?}");
        }
        for threads in [2, 3] {
            let (x, r) = run(threads, pcg);
            assert_eq!(r.energies, r1.energies, "{threads} threads, pcg {pcg:?}");
            assert_eq!(r.pcg_iterations, r1.pcg_iterations);
            assert!(
                x.iter()
                    .flatten()
                    .zip(x1.iter().flatten())
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{threads} threads, pcg {pcg:?}: vertices differ from one thread's"
            );
        }
    }
}

/// The solver keeps each point constraint's pattern positions while its vertex list stays the
/// same: re-linearising after a constraint changed its vertices (and with a constraint fewer
/// and one more) gives the same JᵀJ and gradient as a fresh solver, bit for bit.
#[test]
fn point_constraint_slots_follow_changed_vertex_lists() {
    let (truth, topo) = deformed_sphere(2);
    let (mut targets, x) = generic_problem(&truth, &topo, 3);
    let n = 3 * x.len();
    let mut reused = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS).unwrap();
    reused.linearize(&targets, &x, 1e-6).unwrap();
    let f1 = topo.faces[7];
    let variants: Vec<Vec<PointConstraint>> = vec![
        // Constraint 1 moved to another face.
        vec![
            targets.points[0].clone(),
            PointConstraint {
                rows: vec![(f1[0], 0.3), (f1[1], 0.3), (f1[2], 0.4)],
                ..targets.points[1].clone()
            },
        ],
        // Only the second one left (now at index 0), then both again plus a repeat.
        vec![targets.points[1].clone()],
        vec![
            targets.points[0].clone(),
            targets.points[1].clone(),
            targets.points[0].clone(),
        ],
    ];
    let v: Vec<f64> = (0..n).map(|i| ((i * 7919) % 13) as f64 - 6.0).collect();
    for points in variants {
        targets.points = points;
        let e_reused = reused.linearize(&targets, &x, 1e-6).unwrap();
        let mut fresh = ShellSolver::with_extra_pairs(&topo, &EXTRA_PAIRS).unwrap();
        let e_fresh = fresh.linearize(&targets, &x, 1e-6).unwrap();
        assert_eq!(e_reused, e_fresh);
        assert_eq!(reused.gradient(), fresh.gradient());
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        reused.normal_matrix_mul(&v, &mut a);
        fresh.normal_matrix_mul(&v, &mut b);
        assert_eq!(a, b);
    }
}
