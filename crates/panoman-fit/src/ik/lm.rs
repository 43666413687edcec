//! The projected Levenberg–Marquardt iteration: variables, normal equations, objective,
//! the damped step with its active set (dense Cholesky by faer).

use super::grid::phen_cell;

use super::jacobian::Jacobian;
use super::keypoint_model::{Ctx, Current, PointModel, PtEval};
use super::solver::IkSolver;
use super::{IkConfig, IkState};
use panoman_mesh::geom::{V3, dot, matmul, norm, scale, sub};
use panoman_mesh::rotation::axis_angle;
use rayon::prelude::*;
use std::sync::Arc;
/// A target in solver terms.
#[derive(Clone, Copy, Debug)]
pub(super) struct Row {
    pub(super) row: usize,
    pub(super) target: V3,
    pub(super) weight: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Var {
    Trans(usize),
    Rot(usize),
    Angle {
        bone: usize,
        axis: usize,
        lo: f64,
        hi: f64,
        /// Prior factor `1/s²` (see [`Posable::prior`]).
        prior: f64,
    },
    Phen(usize),
    Unit(usize),
}

/// The free variables of a stage with their column indices.
#[derive(Clone, Debug)]
pub(super) struct VarSet {
    pub(super) vars: Vec<Var>,
    pub(super) trans: [Option<usize>; 3],
    pub(super) rot: [Option<usize>; 3],
    pub(super) bone: Vec<[Option<usize>; 3]>,
    pub(super) phen: [Option<usize>; 6],
    pub(super) unit: [Option<usize>; 52],
}

impl VarSet {
    pub(super) fn new(n_bones: usize) -> VarSet {
        VarSet {
            vars: Vec::new(),
            trans: [None; 3],
            rot: [None; 3],
            bone: vec![[None; 3]; n_bones],
            phen: [None; 6],
            unit: [None; 52],
        }
    }

    pub(super) fn push(&mut self, v: Var) {
        let i = self.vars.len();
        match v {
            Var::Trans(a) => self.trans[a] = Some(i),
            Var::Rot(a) => self.rot[a] = Some(i),
            Var::Angle { bone, axis, .. } => self.bone[bone][axis] = Some(i),
            Var::Phen(a) => self.phen[a] = Some(i),
            Var::Unit(a) => self.unit[a] = Some(i),
        }
        self.vars.push(v);
    }
}

/// Adds one residual row `w (J r)`, `w JᵀJ` (lower triangle) to `g`, `h` (`n × n`).
pub(super) fn accumulate_row(
    jr: &[(usize, V3)],
    res: V3,
    w: f64,
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
) {
    for (a, &(i, di)) in jr.iter().enumerate() {
        let wdi = scale(di, w);
        g[i] += dot(wdi, res);
        for &(j, dj) in &jr[..=a] {
            let (hi, lo) = if i >= j { (i, j) } else { (j, i) };
            h[hi * n + lo] += dot(wdi, dj);
        }
    }
}

/// Sets `h`, `g` to `Σ w JᵀJ`, `Σ w Jᵀr` of the keypoint rows (`k`: the keypoints per set
/// row). Above 64 rows the rows' two fixed halves accumulate in parallel (the second into
/// `h2`, `g2`), summed in that order: the result does not depend on the thread count.
#[allow(clippy::too_many_arguments)]
pub(super) fn accumulate_rows(
    rows: &[Row],
    jac: &[Vec<(usize, V3)>],
    k: &[V3],
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
    h2: &mut Vec<f64>,
    g2: &mut Vec<f64>,
) {
    let run = |range: std::ops::Range<usize>, h: &mut [f64], g: &mut [f64]| {
        h.fill(0.0);
        g.fill(0.0);
        for (r, jr) in rows[range.clone()].iter().zip(&jac[range]) {
            accumulate_row(jr, sub(k[r.row], r.target), r.weight, n, h, g);
        }
    };
    let m = rows.len();
    if m <= 64 {
        run(0..m, h, g);
        return;
    }
    h2.resize(n * n, 0.0);
    g2.resize(n, 0.0);
    rayon::join(|| run(0..m / 2, h, g), || run(m / 2..m, h2, g2));
    h.iter_mut().zip(h2.iter()).for_each(|(a, b)| *a += b);
    g.iter_mut().zip(g2.iter()).for_each(|(a, b)| *a += b);
}

/// Adds one scalar residual row (`jr` in the first components) to `g`, `h`.
pub(super) fn accumulate_scalar_row(
    jr: &[(usize, V3)],
    res: f64,
    w: f64,
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
) {
    for (a, &(i, di)) in jr.iter().enumerate() {
        let wdi = w * di[0];
        g[i] += wdi * res;
        for &(j, dj) in &jr[..=a] {
            let (hi, lo) = if i >= j { (i, j) } else { (j, i) };
            h[hi * n + lo] += wdi * dj[0];
        }
    }
}

/// Adds the point rows to `h`, `g` (point-to-plane rows hold the scalars `n̂ᵀ∂` in the first
/// components, see [`IkSolver::jacobian`]): in four fixed chunks in parallel, summed in chunk
/// order (deterministic), for more than 512 points.
pub(super) fn accumulate_points(
    m: &PointModel,
    pe: &PtEval,
    jac: &[Vec<(usize, V3)>],
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
) {
    let run = |range: std::ops::Range<usize>, h: &mut [f64], g: &mut [f64]| {
        for p in range {
            let r = &m.rows[p];
            if r.weight > 0.0 {
                let d = sub(pe.p[p], r.target);
                match r.normal {
                    Some(nn) => accumulate_scalar_row(&jac[p], dot(nn, d), r.weight, n, h, g),
                    None => accumulate_row(&jac[p], d, r.weight, n, h, g),
                }
            }
        }
    };
    let np = jac.len();
    if np <= 512 {
        run(0..np, h, g);
        return;
    }
    const CHUNKS: usize = 4;
    let parts: Vec<(Vec<f64>, Vec<f64>)> = (0..CHUNKS)
        .into_par_iter()
        .map(|c| {
            let mut hc = vec![0.0; n * n];
            let mut gc = vec![0.0; n];
            run(c * np / CHUNKS..(c + 1) * np / CHUNKS, &mut hc, &mut gc);
            (hc, gc)
        })
        .collect();
    for (hc, gc) in parts {
        h.iter_mut().zip(&hc).for_each(|(a, b)| *a += b);
        g.iter_mut().zip(&gc).for_each(|(a, b)| *a += b);
    }
}

impl IkSolver {
    pub(super) fn prior(&self, st: &IkState, cfg: &IkConfig) -> f64 {
        let mut e = 0.0;
        for p in &self.posable {
            let a = st.angles[p.rig];
            for k in 0..3 {
                e += cfg.pose_prior * p.axis(k, cfg).1 * a[k] * a[k];
            }
            if let Some(t) = &cfg.temporal {
                let a0 = t.angles.get(p.rig).copied().unwrap_or([0.0; 3]);
                let w = t.weights.get(p.rig).copied().unwrap_or(0.0);
                for k in 0..3 {
                    e += w * p.axis(k, cfg).1 * (a[k] - a0[k]) * (a[k] - a0[k]);
                }
            }
        }
        for &b in &st.phenotype {
            e += cfg.phenotype_prior * (b - 0.5) * (b - 0.5);
        }
        for &f in &st.face_units {
            e += cfg.face_unit_prior * f * f;
        }
        e
    }

    pub(super) fn cost(
        &self,
        cur: &Current,
        rows: &[Row],
        pm: Option<&PointModel>,
        cfg: &IkConfig,
    ) -> f64 {
        self.data_cost(cur, rows, pm) + self.prior(&cur.state, cfg)
    }

    /// `Σ_k w_k |K_k − k̂_k|²` plus, with a point model evaluated in `cur`, the point terms
    /// `Σ_p w_p |P_p(Σ_m b_m x_m − p)|²` (`P_p` the projection on the normal, or identity).
    pub(super) fn data_cost(&self, cur: &Current, rows: &[Row], pm: Option<&PointModel>) -> f64 {
        let k: f64 = rows
            .iter()
            .map(|r| {
                let d = sub(cur.k[r.row], r.target);
                r.weight * dot(d, d)
            })
            .sum();
        match (pm, &cur.pts) {
            (Some(m), Some(pe)) => {
                let p: f64 = m
                    .rows
                    .iter()
                    .zip(&pe.p)
                    .map(|(r, x)| {
                        let d = r.proj(sub(*x, r.target));
                        r.weight * dot(d, d)
                    })
                    .sum();
                k + p
            }
            _ => k,
        }
    }

    /// Value, bounds and prior `(x, lo, hi, λ, x̄)` of a variable.
    pub(super) fn var_info(
        &self,
        v: Var,
        st: &IkState,
        cfg: &IkConfig,
    ) -> (f64, f64, f64, f64, f64) {
        let inf = f64::INFINITY;
        match v {
            Var::Trans(a) => (st.translation[a], -inf, inf, 0.0, 0.0),
            Var::Rot(_) => (0.0, -inf, inf, 0.0, 0.0),
            Var::Angle {
                bone,
                axis,
                lo,
                hi,
                prior,
            } => {
                // λ_θ x² + λ_T (x − x⁰)² = (λ_θ + λ_T)(x − x̄)² + const, x̄ = λ_T x⁰ / (λ_θ + λ_T).
                let x = st.angles[bone][axis];
                let lam = cfg.pose_prior * prior;
                let w = cfg
                    .temporal
                    .as_ref()
                    .and_then(|t| t.weights.get(bone).copied())
                    .unwrap_or(0.0);
                match &cfg.temporal {
                    Some(t) if w > 0.0 && prior > 0.0 => {
                        let x0 = t.angles.get(bone).map_or(0.0, |a| a[axis]);
                        let lt = w * prior;
                        (x, lo, hi, lam + lt, lt * x0 / (lam + lt))
                    }
                    _ => (x, lo, hi, lam, 0.0),
                }
            }
            Var::Phen(i) => (st.phenotype[i], 0.0, 1.0, cfg.phenotype_prior, 0.5),
            Var::Unit(j) => (st.face_units[j], 0.0, 1.0, cfg.face_unit_prior, 0.0),
        }
    }

    /// The state moved by `delta`, each value clamped to its step bounds `info = (x, lo, hi)`
    /// and snapped onto a bound it comes within 1e-12 of.
    pub(super) fn apply_step(
        &self,
        vs: &VarSet,
        st: &IkState,
        delta: &[f64],
        info: &[(f64, f64, f64)],
    ) -> IkState {
        let mut s = st.clone();
        let mut phi = [0.0; 3];
        for (i, &v) in vs.vars.iter().enumerate() {
            let d = delta[i];
            if d == 0.0 {
                continue;
            }
            let (x, lo, hi) = info[i];
            let mut nx = (x + d).clamp(lo, hi);
            if nx <= lo + 1e-12 {
                nx = lo;
            } else if nx >= hi - 1e-12 {
                nx = hi;
            }
            match v {
                Var::Trans(a) => s.translation[a] = nx,
                Var::Rot(a) => phi[a] = d,
                Var::Angle { bone, axis, .. } => s.angles[bone][axis] = nx,
                Var::Phen(i) => s.phenotype[i] = nx,
                Var::Unit(j) => s.face_units[j] = nx,
            }
        }
        let angle = norm(phi);
        if angle > 0.0 {
            s.rotation = matmul(&axis_angle(phi, angle), &s.rotation);
        }
        s
    }

    /// One Levenberg–Marquardt stage (keypoint `rows`, and the point targets of `ctx` when it
    /// has a point model). Returns the number of iterations.
    pub(super) fn lm_stage(
        &self,
        cur: &mut Current,
        vs: &VarSet,
        rows: &[Row],
        cfg: &IkConfig,
        ctx: Ctx<'_>,
        max_iter: usize,
    ) -> usize {
        let n = vs.vars.len();
        if n == 0 || rows.is_empty() {
            return 0;
        }
        let pm = ctx.pts;
        if let Some(m) = pm
            && cur.pts.is_none()
        {
            let x = Arc::new(m.shape_x(&cur.state.phenotype, &cur.state.face_units));
            cur.pts = Some(m.eval(x, &cur.kin));
        }
        let wsum: f64 = rows.iter().map(|r| r.weight).sum::<f64>()
            + pm.map_or(0.0, |m| m.rows.iter().map(|r| r.weight).sum::<f64>());
        let floor = 1e-16 * wsum;
        let mut f = self.cost(cur, rows, pm, cfg);
        let mut mu = 1e-4;
        let mut iters = 0;
        let mut h = vec![0.0; n * n];
        let mut g = vec![0.0; n];
        let (mut h2, mut g2) = (Vec::new(), Vec::new());
        while iters < max_iter {
            iters += 1;
            let prior_grad = cur.state.phenotype.map(|b| cfg.phenotype_prior * (b - 0.5));
            let Jacobian {
                rows: jac,
                pts: pt_jac,
                held,
                sides,
            } = self.jacobian(vs, cur, rows, ctx, prior_grad);
            accumulate_rows(rows, &jac, &cur.k, n, &mut h, &mut g, &mut h2, &mut g2);
            if let (Some(m), Some(pe)) = (pm, &cur.pts) {
                accumulate_points(m, pe, &pt_jac, n, &mut h, &mut g);
            }
            let mut free = Vec::with_capacity(n);
            for (i, &v) in vs.vars.iter().enumerate() {
                let (x, lo, hi, lam, x0) = self.var_info(v, &cur.state, cfg);
                h[i * n + i] += lam;
                g[i] += lam * (x - x0);
                let at_lo = x <= lo + 1e-12 && g[i] > 0.0;
                let at_hi = x >= hi - 1e-12 && g[i] < 0.0;
                if !(at_lo || at_hi || held.contains(&i)) {
                    free.push(i);
                }
            }
            if free.is_empty() {
                break;
            }
            let max_diag = free.iter().map(|&i| h[i * n + i]).fold(0.0, f64::max);
            let info: Vec<(f64, f64, f64)> = vs
                .vars
                .iter()
                .map(|&v| {
                    let (x, lo, hi, _, _) = self.var_info(v, &cur.state, cfg);
                    match v {
                        // A step stops on the kinks around the value (module docs).
                        Var::Phen(i) => {
                            let (a, b) = phen_cell(i, x, sides[i]);
                            (x, a, b)
                        }
                        _ => (x, lo, hi),
                    }
                })
                .collect();
            let mut accepted = None;
            while mu <= 1e10 {
                let Some(delta) = damped_step(&h, &g, n, &free, &info, mu, max_diag) else {
                    mu *= 10.0;
                    continue;
                };
                let trial = self.apply_step(vs, &cur.state, &delta, &info);
                let next = self.reevaluate(trial, cur, ctx);
                let ft = self.cost(&next, rows, pm, cfg);
                if ft < f {
                    accepted = Some((next, ft));
                    mu = (mu * 0.25).max(1e-12);
                    break;
                }
                mu *= 10.0;
            }
            let Some((next, ft)) = accepted else { break };
            let decrease = f - ft;
            *cur = next;
            f = ft;
            if decrease <= cfg.tolerance * (f + decrease) || self.data_cost(cur, rows, pm) < floor {
                break;
            }
        }
        iters
    }
}

/// The damped Gauss–Newton step `(H + μD) δ = −g` (`D = diag(H)`, floored) over the free
/// variables, with an active-set refinement: a variable the step would take out of its
/// bounds is set onto the bound and the system is solved again for the others (at most six
/// rounds), so the step minimises the damped quadratic model on the face of the box. `info`
/// holds `(x, lo, hi)` per variable. `None` if a system is not positive definite.
pub(super) fn damped_step(
    h: &[f64],
    g: &[f64],
    n: usize,
    free: &[usize],
    info: &[(f64, f64, f64)],
    mu: f64,
    max_diag: f64,
) -> Option<Vec<f64>> {
    let hij = |i: usize, j: usize| if i >= j { h[i * n + j] } else { h[j * n + i] };
    let mut active: Vec<usize> = free.to_vec();
    let mut delta = vec![0.0; n];
    let mut clamped: Vec<usize> = Vec::new();
    for _round in 0..6 {
        let m = active.len();
        if m == 0 {
            break;
        }
        let mut a = vec![0.0; m * m];
        let mut b = vec![0.0; m];
        for (p, &i) in active.iter().enumerate() {
            for (q, &j) in active[..=p].iter().enumerate() {
                a[p * m + q] = hij(i, j);
            }
            let d = h[i * n + i].max(1e-12 * max_diag).max(1e-18);
            a[p * m + p] += mu * d;
            b[p] = -g[i] - clamped.iter().map(|&j| hij(i, j) * delta[j]).sum::<f64>();
        }
        if !cholesky_solve(&a, m, &mut b) {
            return None;
        }
        let mut out = Vec::new();
        for (p, &i) in active.iter().enumerate() {
            let (x, lo, hi) = info[i];
            delta[i] = b[p];
            if x + b[p] < lo {
                delta[i] = lo - x;
                out.push(i);
            } else if x + b[p] > hi {
                delta[i] = hi - x;
                out.push(i);
            }
        }
        if out.is_empty() {
            break;
        }
        active.retain(|i| !out.contains(i));
        clamped.extend(out);
    }
    Some(delta)
}

/// Solves `A x = b` in place for a symmetric positive definite `A` (`n × n`, row-major, lower
/// triangle read) by faer's Cholesky factorization `A = L Lᵀ`; `b` becomes `x`. False if `A`
/// is not numerically positive definite (a pivot that is not > 0, NaN included).
///
/// Sequential on purpose: the IK's systems have a few hundred unknowns (210 in a warm frame's
/// `all` stage), where faer's default Rayon parallelism costs more in hand-offs than it
/// saves (measured: 0.38 → 0.13 ms per factorization on 2 cores, docs/design/shell-fit.md
/// §3.5.1).
pub(super) fn cholesky_solve(a: &[f64], n: usize, b: &mut [f64]) -> bool {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::cholesky::llt;
    // Row-major lower triangle = column-major upper triangle; copy it column-major lower.
    let mut l = faer::Mat::<f64>::zeros(n, n);
    for i in 0..n {
        for j in 0..=i {
            l[(i, j)] = a[i * n + j];
        }
    }
    let par = faer::Par::Seq;
    let mut mem = MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
        n,
        par,
        Default::default(),
    ));
    if llt::factor::cholesky_in_place(
        l.as_mut(),
        Default::default(),
        par,
        MemStack::new(&mut mem),
        Default::default(),
    )
    .is_err()
    {
        return false;
    }
    let rhs = faer::MatMut::from_column_major_slice_mut(b, n, 1);
    llt::solve::solve_in_place_with_conj(
        l.as_ref(),
        faer::Conj::No,
        rhs,
        par,
        MemStack::new(&mut MemBuffer::new(
            llt::solve::solve_in_place_scratch::<f64>(n, 1, par),
        )),
    );
    true
}
