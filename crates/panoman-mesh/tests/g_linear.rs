//! The linearization of `g` ([`panoman_mesh::GLinearization`]): finite-difference check at a
//! consistent point and the adjoint (dot-product) identity at an inconsistent one.
mod common;

use common::{Rng, deform, grid, icosphere};
use panoman_mesh::geom::V3;
use panoman_mesh::{
    GDerivative, GLinearization, GWorkspace, Gauge, Reconstructor, RestGeometry, Rla, Topology,
};

/// `g(ℓ, φ)` with a tight frame solve (so that finite differences see the minimiser).
fn g(rec: &Reconstructor, ws: &mut GWorkspace, l: &[f64], a: &[f64], gauge: &Gauge) -> Vec<V3> {
    let mut out = vec![[0.0; 3]; rec.topology().n_vertices];
    rec.reconstruct(ws, l, a, gauge, &mut out).unwrap();
    out
}

/// Targets of `posed` w.r.t. `rest` (consistent: g reproduces `posed`).
fn targets(t: &Topology, rest: &[V3], posed: &[V3]) -> (Vec<f64>, Vec<f64>) {
    let rg = RestGeometry::new(t, rest).unwrap();
    let rla = Rla::compute(t, &rg, posed).unwrap();
    let mut l = vec![0.0; t.n_edges()];
    let mut a = vec![0.0; t.n_edges()];
    rg.targets_into(&rla, &mut l, &mut a);
    (l, a)
}

/// The Gauss–Newton derivative at consistent data (where it is exact) against central
/// differences of `g`.
fn fd_check(rest: &[V3], posed: &[V3], faces: &[[u32; 3]], seed: u64) {
    let t = Topology::build(rest.len(), faces).unwrap();
    let mut rec = Reconstructor::new(&t).unwrap();
    rec.max_frame_iterations = 200;
    rec.frame_tolerance = 1e-15;
    let (l, a) = targets(&t, rest, posed);
    let gauge = rec.gauge_from(posed).unwrap();
    let (num, den, _) = fd_error(&rec, &l, &a, &gauge, GDerivative::GaussNewton, seed);
    eprintln!("FD check: max |Δ| {num:.3e}, max |FD| {den:.3e}");
    assert!(den > 1e-6, "direction has no effect ({den})");
    assert!(
        num < 1e-5 * den,
        "J_g v differs from central differences: max |Δ| {num:.3e} of max |FD| {den:.3e}"
    );
}

#[test]
fn g_derivative_matches_finite_differences_closed() {
    let (rest, f) = icosphere(3);
    let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
    fd_check(&rest, &posed, &f, 1);
}

#[test]
fn g_derivative_matches_finite_differences_open() {
    let (rest, f) = grid(12);
    let posed: Vec<V3> = rest
        .iter()
        .map(|&[x, y, z]| [x + 0.1 * y * y, y, z + 0.2 * (3.0 * x).sin()])
        .collect();
    fd_check(&rest, &posed, &f, 2);
}

#[test]
fn g_transpose_is_the_adjoint_at_inconsistent_data() {
    let (rest, f) = icosphere(3);
    let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
    let t = Topology::build(rest.len(), &f).unwrap();
    let rec = Reconstructor::new(&t).unwrap();
    let (mut l, mut a) = targets(&t, &rest, &posed);
    let mut rng = Rng(7);
    for e in 0..t.n_edges() {
        l[e] *= 1.0 + 0.01 * rng.normal();
        a[e] += 0.03 * rng.normal();
    }
    let gauge = rec.gauge_from(&rest).unwrap();
    let mut ws = rec.workspace();
    let _ = g(&rec, &mut ws, &l, &a, &gauge);
    let mut lin = rec.linearize(&ws, &l, &a).unwrap();
    let (lhs, rhs) = adjoint_pair(&rec, &mut lin, &mut rng);
    assert!(
        (lhs - rhs).abs() < 1e-10 * lhs.abs().max(rhs.abs()),
        "⟨Jv, u⟩ = {lhs} but ⟨v, Jᵀu⟩ = {rhs}"
    );
}

/// `(⟨J v, u⟩, ⟨v, Jᵀ u⟩)` for random `v = (δℓ, δφ)` and `u`.
fn adjoint_pair(rec: &Reconstructor, lin: &mut GLinearization, rng: &mut Rng) -> (f64, f64) {
    let t = rec.topology();
    let dl: Vec<f64> = (0..t.n_edges()).map(|_| rng.normal()).collect();
    let da: Vec<f64> = (0..t.n_edges()).map(|_| rng.normal()).collect();
    let u: Vec<V3> = (0..t.n_vertices).map(|_| rng.vec3()).collect();
    let mut jv = vec![[0.0; 3]; t.n_vertices];
    lin.apply(rec, &dl, &da, &mut jv).unwrap();
    let (mut gl, mut ga) = (vec![0.0; t.n_edges()], vec![0.0; t.n_edges()]);
    lin.apply_transpose(rec, &u, &mut gl, &mut ga).unwrap();
    let lhs: f64 = jv
        .iter()
        .zip(&u)
        .map(|(p, q)| p[0] * q[0] + p[1] * q[1] + p[2] * q[2])
        .sum();
    let rhs: f64 = dl.iter().zip(&gl).map(|(x, y)| x * y).sum::<f64>()
        + da.iter().zip(&ga).map(|(x, y)| x * y).sum::<f64>();
    (lhs, rhs)
}

/// Max |J v − FD| and max |FD| of one linearization mode at (ℓ, φ).
fn fd_error(
    rec: &Reconstructor,
    l: &[f64],
    a: &[f64],
    gauge: &Gauge,
    mode: GDerivative,
    seed: u64,
) -> (f64, f64, usize) {
    let t = rec.topology();
    let mut ws = rec.workspace();
    ws.newton_steps = 3;
    let x0 = g(rec, &mut ws, l, a, gauge);
    assert!(x0.iter().all(|p| p.iter().all(|c| c.is_finite())));
    let mut lin = rec.linearize_with(&ws, l, a, mode).unwrap();
    let mut rng = Rng(seed);
    let dl: Vec<f64> = l.iter().map(|&x| 0.05 * x * rng.normal()).collect();
    let da: Vec<f64> = (0..t.n_edges()).map(|_| 0.05 * rng.normal()).collect();
    let mut jv = vec![[0.0; 3]; t.n_vertices];
    lin.apply(rec, &dl, &da, &mut jv).unwrap();
    let iterations = lin.last_iterations();
    let h = 1e-5;
    let shifted = |s: f64| -> (Vec<f64>, Vec<f64>) {
        (
            l.iter().zip(&dl).map(|(x, d)| x + s * d).collect(),
            a.iter().zip(&da).map(|(x, d)| x + s * d).collect(),
        )
    };
    let (lp, ap) = shifted(h);
    let (lm, am) = shifted(-h);
    let xp = g(rec, &mut ws, &lp, &ap, gauge);
    let xm = g(rec, &mut ws, &lm, &am, gauge);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for v in 0..t.n_vertices {
        for c in 0..3 {
            let fd = (xp[v][c] - xm[v][c]) / (2.0 * h);
            num = num.max((fd - jv[v][c]).abs());
            den = den.max(fd.abs());
        }
    }
    (num, den, iterations)
}

/// At inconsistent targets (what a model's RL/RA are) the exact derivative matches central
/// differences of g to their truncation error (h² · third derivative, ~1e-9 relative here),
/// while the Gauss–Newton one is off by the residual's share (percent level at 1 % length and
/// 0.03 rad angle noise); both transposes are adjoints of their products.
#[test]
fn exact_derivative_matches_finite_differences_at_inconsistent_data() {
    for (name, (rest, f)) in [("closed", icosphere(3)), ("open", grid(12))] {
        let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
        let t = Topology::build(rest.len(), &f).unwrap();
        let mut rec = Reconstructor::new(&t).unwrap();
        rec.max_frame_iterations = 500;
        rec.frame_tolerance = 1e-15;
        let (mut l, mut a) = targets(&t, &rest, &posed);
        let mut rng = Rng(11);
        for e in 0..t.n_edges() {
            l[e] *= 1.0 + 0.01 * rng.normal();
            a[e] += 0.03 * rng.normal();
        }
        let gauge = rec.gauge_from(&rest).unwrap();
        let (ex, den, its) = fd_error(&rec, &l, &a, &gauge, GDerivative::Exact, 3);
        let (gn, _, _) = fd_error(&rec, &l, &a, &gauge, GDerivative::GaussNewton, 3);
        eprintln!(
            "{name}: exact {ex:.3e} ({its} CG iterations), Gauss–Newton {gn:.3e}, |FD| {den:.3e}"
        );
        assert!(den > 1e-3, "{name}: direction has no effect ({den})");
        assert!(
            ex < 1e-6 * den,
            "{name}: exact J v off by {ex:.3e} of {den:.3e}"
        );
        assert!(
            gn > 1e-3 * den,
            "{name}: the data is not inconsistent enough to tell ({gn:.3e})"
        );
        // Adjoint identity of the exact mode.
        let mut ws = rec.workspace();
        ws.newton_steps = 3;
        let _ = g(&rec, &mut ws, &l, &a, &gauge);
        let mut lin = rec.linearize_with(&ws, &l, &a, GDerivative::Exact).unwrap();
        let (lhs, rhs) = adjoint_pair(&rec, &mut lin, &mut rng);
        // Each side carries the conjugate gradients' 1e-12 relative residual.
        assert!(
            (lhs - rhs).abs() < 1e-9 * lhs.abs().max(rhs.abs()),
            "{name}: ⟨Jv, u⟩ = {lhs} but ⟨v, Jᵀu⟩ = {rhs}"
        );
    }
}
