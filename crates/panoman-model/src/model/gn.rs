//! The vertex-error encoder: β by Gauss–Newton on the mesh error through `g`
//! (docs/design/splocs-model.md §8).
//!
//! The least-squares encoder ([`Evaluator::encode`]) fits RL/RA; what is measured is the
//! vertex error of `g(RL(β), RA(β), B_S(α))`, and small RA errors integrate along the body's
//! chains. [`Evaluator::refine_beta`] minimises, from that start,
//!
//! ```text
//! f(β) = Σ_v |x_v(β) − T x̂_v|²,   x(β) = g(RL(β), RA(β), B_S(α)),   T = Kabsch(x̂ → x(β))
//! ```
//!
//! over all β (α fixed) by Levenberg–Marquardt: each outer iteration re-aligns the target
//! rigidly (T), linearizes `g` at its solution ([`panoman_mesh::GLinearization`]:
//! `J = J_g · ∂(ℓ*, φ*)/∂β` with `∂ℓ*_e/∂β_k = ℓ_r,e M_k,e` on RL blocks and
//! `∂φ*_e/∂β_k = M_k,e` on RA blocks; 0 where the length floor is active), and solves the
//! damped step `min_δ ‖J δ − r‖² + Σ_b λ_b ‖δ_b‖²` by CGLS (each iteration one product `J p`
//! and one `Jᵀ s`, i.e. four sparse back-substitutions, no g solve). The damping is scaled per
//! block, `λ_b = μ ρ_b` with `ρ_b` the curvature of `JᵀJ` along the block's part of the
//! gradient: a body component moves a limb, a face component a millimetre of lip, and one λ
//! for all would freeze the face and hands. A trial that lowers `f` (one g solve) is taken and
//! μ divided by 3; otherwise μ grows 8× and the step is solved again on the same
//! linearization. With the correction MLP, `R(β)` is evaluated at every iterate; by default
//! it is held fixed inside the linearization (a quasi-Gauss–Newton step; the acceptance test
//! on the true `f` keeps the iteration monotone). [`GnOptions::correction_jacobian`] adds its
//! Jacobian `∂R/∂β = (P G) ⊘ w` (`G` the ReLU network's input Jacobian at the current β, dense
//! rank × #β_B, formed once per linearization; `P`, `w` the PCA head's basis and column
//! weights) to the body blocks' RL/RA directions — exact within the current activation
//! pattern, but measured worse on held-out rows (the network extrapolates along it).

use super::{Evaluator, Params, Quantity};
use crate::error::{ModelError, Result};
use faer::Par;
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{V3, add, cross, matvec_t, sub};
use panoman_mesh::rla::MIN_RELATIVE_LENGTH;
use panoman_mesh::{GDerivative, GLinearization, Gauge, RestGeometry};

/// Options of [`Evaluator::refine_beta`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnOptions {
    /// Accepted outer iterations at most (each: one linearization, then damped CGLS and one g
    /// solve per trial until a trial lowers `f`).
    pub max_iterations: usize,
    /// CGLS iterations per outer iteration.
    pub cg_iterations: usize,
    /// Stop when an outer iteration lowers `f` by less than this fraction.
    pub tolerance: f64,
    /// Initial Levenberg–Marquardt damping μ (dimensionless: block `b`'s unknowns get
    /// `λ_b = μ ρ_b`, `ρ_b` the curvature of `JᵀJ` along the block's gradient): divided by 3
    /// after an accepted step, multiplied by 8 (at least 10⁻⁶) after a rejected one.
    pub damping: f64,
    /// Rejected trials (each one CGLS and one g solve) per linearization before giving up
    /// (10, the default, lets μ grow by 8¹⁰ ≈ 10⁹: a step taken at a tiny μ can need many).
    pub max_rejections: usize,
    /// With the correction MLP: put its Jacobian `∂R/∂β` into the linearization (`true`) or
    /// hold `R` fixed there, evaluating it only at the trial points (`false`, the default:
    /// measured better on held-out rows, docs/design/splocs-model.md §8).
    pub correction_jacobian: bool,
    /// With the correction MLP: a second start — the same iteration first without the
    /// correction, then with it from there — and the result with the lower error kept
    /// (`true`, the default; docs/design/splocs-model.md §8). About 3× the cost of one start.
    pub correction_two_start: bool,
}

impl Default for GnOptions {
    /// 20 outer iterations, 25 CGLS iterations, 10⁻⁵ relative decrease, μ₀ = 10⁻⁴, 10
    /// rejections (docs/design/splocs-model.md §8: the measured choice; the stop at 0.1 % and
    /// 4 rejections before it ended some rows on a plateau where μ had grown, short of the
    /// minimum the next iterations reach).
    fn default() -> Self {
        Self {
            max_iterations: 20,
            cg_iterations: 25,
            tolerance: 1e-5,
            damping: 1e-4,
            max_rejections: 10,
            correction_jacobian: false,
            correction_two_start: true,
        }
    }
}

/// What [`Evaluator::refine_beta`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnReport {
    /// Accepted outer iterations.
    pub iterations: usize,
    /// RMS vertex error (m, after rigid alignment) at the start (the given β).
    pub rms_start: f64,
    /// RMS vertex error (m) at the end.
    pub rms: f64,
    /// g solves (the start and every trial step, accepted or rejected).
    pub g_solves: usize,
}

/// The flat β layout over the model's blocks (block order, each block's components).
struct Layout {
    offsets: Vec<usize>,
}

impl Layout {
    fn new(model: &super::PanoManModel) -> Self {
        let mut offsets = vec![0];
        for b in &model.blocks {
            offsets.push(offsets.last().unwrap() + b.n_components());
        }
        Self { offsets }
    }
    fn len(&self) -> usize {
        *self.offsets.last().unwrap()
    }
    /// [`Layout::flatten`] of a direction given by a caller: every block it names must be one
    /// of the model's, with the model's component count.
    fn flatten_checked(&self, model: &super::PanoManModel, p: &Params) -> Result<Vec<f64>> {
        for (name, v) in &p.beta {
            match model.blocks.iter().find(|b| &b.name == name) {
                Some(b) if b.n_components() == v.len() => {}
                Some(b) => {
                    return Err(ModelError::Invalid(format!(
                        "direction block {name} has {} coefficients, the model's has {}",
                        v.len(),
                        b.n_components()
                    )));
                }
                None => {
                    return Err(ModelError::Invalid(format!(
                        "direction block {name} is not a block of the model"
                    )));
                }
            }
        }
        Ok(self.flatten(model, p))
    }
    fn flatten(&self, model: &super::PanoManModel, p: &Params) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.len());
        for b in &model.blocks {
            out.extend(p.beta_of(b.name, b.n_components()));
        }
        out
    }
    fn write(&self, model: &super::PanoManModel, beta: &[f64], p: &mut Params) {
        for (i, b) in model.blocks.iter().enumerate() {
            p.beta
                .insert(b.name, beta[self.offsets[i]..self.offsets[i + 1]].to_vec());
        }
    }
}

/// `A x` in f32 (faer's product, `par` threads).
fn matvec(a: faer::MatRef<'_, f32>, x: &[f32], par: Par) -> Vec<f32> {
    let mut y = vec![0.0f32; a.nrows()];
    faer::linalg::matmul::matmul(
        faer::MatMut::from_column_major_slice_mut(&mut y, a.nrows(), 1),
        faer::Accum::Replace,
        a,
        faer::MatRef::from_column_major_slice(x, x.len(), 1),
        1.0,
        par,
    );
    y
}

/// The correction MLP linearized at one β (docs/design/splocs-model.md §5.4, §8):
/// `δR = (P G δx) ⊘ w` on the body columns (RL then RA), with `x` the MLP's input (β_LB, β_AB
/// without their mean coefficients), `G = ∂codes/∂x` (rank × #x, dense, f32) and the PCA head's
/// basis `P` and column weights `w`. A ReLU network is piecewise linear, so `G` is exact within
/// the current activation pattern and the damped step keeps the iteration near it.
struct CorrectionLin<'a> {
    g: faer::Mat<f32>,
    head: &'a crate::mlp::PcaHead,
    /// Flat β index of each MLP input (body_l components 1.., then body_a components 1..).
    inputs: Vec<usize>,
    /// Edge of each residual entry (body_l columns, then body_a columns).
    edges: Vec<u32>,
    /// Residual entries that are RL (the rest are RA).
    n_rl: usize,
}

impl<'a> CorrectionLin<'a> {
    fn new(model: &'a super::PanoManModel, lay: &Layout, params: &Params) -> Option<Self> {
        let c = model.correction.as_ref()?;
        let x = model.body_beta_f32(params);
        let (_, jac) = c.mlp.jacobian(&x);
        let (bl, ba) = (&model.blocks[0], &model.blocks[3]);
        let inputs: Vec<usize> = (1..bl.n_components())
            .map(|k| lay.offsets[0] + k)
            .chain((1..ba.n_components()).map(|k| lay.offsets[3] + k))
            .collect();
        debug_assert_eq!(inputs.len(), x.len());
        let edges: Vec<u32> = bl.columns.iter().chain(&ba.columns).copied().collect();
        Some(Self {
            g: jac.to_dense(),
            head: &c.head,
            inputs,
            edges,
            n_rl: bl.columns.len(),
        })
    }

    /// `dl += δR_RL`, `da += δR_RA` for the flat β direction `d`.
    fn apply(&self, d: &[f64], dl: &mut [f64], da: &mut [f64]) {
        let x: Vec<f32> = self.inputs.iter().map(|&i| d[i] as f32).collect();
        let c = matvec(self.g.as_ref(), &x, Par::Seq);
        let y = matvec(self.head.basis(), &c, Par::rayon(0));
        for (j, (&e, (&v, &w))) in self
            .edges
            .iter()
            .zip(y.iter().zip(self.head.weights()))
            .enumerate()
        {
            let dst = if j < self.n_rl { &mut *dl } else { &mut *da };
            dst[e as usize] += f64::from(v / w);
        }
    }

    /// `out[β] += ∂R/∂βᵀ (gl, ga)` (covectors on the edges' RL and RA).
    fn apply_t(&self, gl: &[f64], ga: &[f64], out: &mut [f64]) {
        let u: Vec<f32> = self
            .edges
            .iter()
            .zip(self.head.weights())
            .enumerate()
            .map(|(j, (&e, &w))| {
                let src = if j < self.n_rl { gl } else { ga };
                src[e as usize] as f32 / w
            })
            .collect();
        let c = matvec(self.head.basis().transpose(), &u, Par::rayon(0));
        let x = matvec(self.g.as_ref().transpose(), &c, Par::Seq);
        for (&i, &v) in self.inputs.iter().zip(&x) {
            out[i] += f64::from(v);
        }
    }
}

impl super::PanoManModel {
    /// The correction residual's directional derivative `∂R/∂β · d` at `params`
    /// ([`PanoManModel::correction_residual`]'s layout: the body columns, RL then RA), as the
    /// vertex-error encoder linearizes it (docs/design/splocs-model.md §8); `direction` holds
    /// the β direction per block (blocks it lacks are 0). `None` without a correction MLP.
    /// Exposed for checks against finite differences.
    ///
    /// # Errors
    /// A direction block the model does not have, or with the wrong number of coefficients.
    pub fn correction_jacobian_product(
        &self,
        params: &Params,
        direction: &Params,
    ) -> Result<Option<Vec<f64>>> {
        let lay = Layout::new(self);
        let d = lay.flatten_checked(self, direction)?;
        let Some(c) = CorrectionLin::new(self, &lay, params) else {
            return Ok(None);
        };
        let ne = self.n_edges();
        let (mut dl, mut da) = (vec![0.0; ne], vec![0.0; ne]);
        c.apply(&d, &mut dl, &mut da);
        Ok(Some(
            c.edges
                .iter()
                .enumerate()
                .map(|(j, &e)| {
                    if j < c.n_rl {
                        dl[e as usize]
                    } else {
                        da[e as usize]
                    }
                })
                .collect(),
        ))
    }
}

/// A linear operator `J: ℝⁿ → ℝᵐ` with its transpose, for [`damped_cgls`].
trait LinearOperator {
    /// `y = J x` (`x`: n, `y`: m, overwritten).
    fn apply(&mut self, x: &[f64], y: &mut [f64]) -> Result<()>;
    /// `x = Jᵀ y` (overwritten).
    fn apply_t(&mut self, y: &[f64], x: &mut [f64]) -> Result<()>;
}

/// `J = ∂x/∂β` of one linearization of g (flat vertex coordinates, m = 3 #V).
struct GnOperator<'a> {
    ev: &'a Evaluator,
    lin: &'a mut GLinearization,
    lay: &'a Layout,
    dl_drl: &'a [f64],
    corr: Option<&'a CorrectionLin<'a>>,
}

impl LinearOperator for GnOperator<'_> {
    fn apply(&mut self, x: &[f64], y: &mut [f64]) -> Result<()> {
        let (y3, _) = y.as_chunks_mut::<3>();
        self.ev
            .gn_apply(self.lin, self.lay, self.dl_drl, self.corr, x, y3)
    }
    fn apply_t(&mut self, y: &[f64], x: &mut [f64]) -> Result<()> {
        let (y3, _) = y.as_chunks::<3>();
        self.ev
            .gn_apply_t(self.lin, self.lay, self.dl_drl, self.corr, y3, x)
    }
}

/// The curvature scale of `JᵀJ` per block of unknowns: for block `b` (unknowns
/// `offsets[b]..offsets[b+1]`), `ρ_b = ‖J g_b‖² / ‖g_b‖²`, the Rayleigh quotient along the
/// block's part `g_b` of the gradient `g = Jᵀ r` (given; `m` rows of `J`; one product per
/// block; 0 where `g_b = 0`).
/// Blocks move very different vertex sets (a body component moves a limb, a face component a
/// few millimetres of lip), so one damping for all would freeze the small ones.
fn block_curvatures(
    op: &mut dyn LinearOperator,
    offsets: &[usize],
    g: &[f64],
    m: usize,
) -> Result<Vec<f64>> {
    let n = g.len();
    let mut q = vec![0.0; m];
    let mut out = Vec::with_capacity(offsets.len().saturating_sub(1));
    for w in offsets.windows(2) {
        let mut gb = vec![0.0; n];
        gb[w[0]..w[1]].copy_from_slice(&g[w[0]..w[1]]);
        let gg: f64 = gb.iter().map(|v| v * v).sum();
        if gg == 0.0 {
            out.push(0.0);
            continue;
        }
        op.apply(&gb, &mut q)?;
        out.push(q.iter().map(|v| v * v).sum::<f64>() / gg);
    }
    Ok(out)
}

/// Damped CGLS (a Levenberg–Marquardt step): `min_δ ‖J δ − r‖² + Σ_j λ_j δ_j²` from δ = 0 by
/// at most `iters` conjugate-gradient iterations on the normal equations
/// `(JᵀJ + diag λ) δ = Jᵀ r`, each one product `J p` and one `Jᵀ s`; `g0 = Jᵀ r` is given (it
/// is the same for every trial on one linearization). Stops early when the
/// normal-equation residual has fallen by 10¹⁰ (in norm).
fn damped_cgls(
    op: &mut dyn LinearOperator,
    lambda: &[f64],
    r0: &[f64],
    g0: &[f64],
    iters: usize,
) -> Result<Vec<f64>> {
    let n = lambda.len();
    let mut res = r0.to_vec();
    let mut delta = vec![0.0; n];
    let mut s = g0.to_vec();
    let mut p = s.clone();
    let mut gamma: f64 = s.iter().map(|v| v * v).sum();
    let gamma0 = gamma;
    let mut q = vec![0.0; res.len()];
    for _ in 0..iters {
        if gamma <= 1e-20 * gamma0 || gamma == 0.0 {
            break;
        }
        op.apply(&p, &mut q)?;
        let qq: f64 = q.iter().map(|v| v * v).sum();
        let plp: f64 = p.iter().zip(lambda).map(|(v, l)| l * v * v).sum();
        let denom = qq + plp;
        if denom <= 0.0 || !denom.is_finite() {
            break;
        }
        let a = gamma / denom;
        for (d, pi) in delta.iter_mut().zip(&p) {
            *d += a * pi;
        }
        for (r, qi) in res.iter_mut().zip(&q) {
            *r -= a * qi;
        }
        op.apply_t(&res, &mut s)?;
        for ((si, d), l) in s.iter_mut().zip(&delta).zip(lambda) {
            *si -= l * d;
        }
        let g_new: f64 = s.iter().map(|v| v * v).sum();
        let bta = g_new / gamma;
        for (pi, si) in p.iter_mut().zip(&s) {
            *pi = si + bta * *pi;
        }
        gamma = g_new;
    }
    Ok(delta)
}

/// One g evaluation at `params`: the vertices, its target lengths/angles and `f`, `T x̂`.
struct Point {
    x: Vec<V3>,
    lengths: Vec<f64>,
    angles: Vec<f64>,
    /// ℓ_r ⊙ 1[length floor inactive] per edge (∂ℓ*/∂RL).
    dl_drl: Vec<f64>,
    f: f64,
    target: Vec<V3>,
}

impl Evaluator {
    fn gn_point(
        &mut self,
        params: &Params,
        correction: bool,
        rg: &RestGeometry,
        gauge: &Gauge,
        mesh: &[V3],
    ) -> Result<Point> {
        let rla = self.model.rla(params, correction);
        let mut x = vec![[0.0; 3]; self.topo.n_vertices];
        self.rec
            .reconstruct_rla(&mut self.ws, rg, &rla, gauge, &mut x)?;
        let t = rigid_align(mesh, &x, None);
        let target: Vec<V3> = mesh.iter().map(|&p| t.apply(p)).collect();
        let f = x
            .iter()
            .zip(&target)
            .map(|(a, b)| {
                let d = sub(*a, *b);
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            })
            .sum();
        let dl_drl = rg
            .lengths
            .iter()
            .zip(&rla.rl)
            .map(|(&lr, &r)| {
                if 1.0 + r >= MIN_RELATIVE_LENGTH {
                    lr
                } else {
                    0.0
                }
            })
            .collect();
        Ok(Point {
            x,
            lengths: self.ws.lengths.clone(),
            angles: self.ws.angles.clone(),
            dl_drl,
            f,
            target,
        })
    }

    /// `J δβ`: β → (δℓ*, δφ*) → δx.
    fn gn_apply(
        &self,
        lin: &mut GLinearization,
        lay: &Layout,
        dl_drl: &[f64],
        corr: Option<&CorrectionLin>,
        d: &[f64],
        out: &mut [V3],
    ) -> Result<()> {
        let ne = self.topo.n_edges();
        let (mut dl, mut da) = (vec![0.0; ne], vec![0.0; ne]);
        for (b, blk) in self.model.blocks.iter().enumerate() {
            let dst = match Quantity::of_block(b) {
                Quantity::Length => &mut dl,
                Quantity::Angle => &mut da,
            };
            for k in 0..blk.n_components() {
                let s = d[lay.offsets[b] + k];
                if s == 0.0 {
                    continue;
                }
                let (cols, vals) = blk.components.row(k);
                for (&j, &v) in cols.iter().zip(vals) {
                    dst[blk.columns[j as usize] as usize] += s * v as f64;
                }
            }
        }
        if let Some(c) = corr {
            c.apply(d, &mut dl, &mut da);
        }
        for (x, &s) in dl.iter_mut().zip(dl_drl) {
            *x *= s;
        }
        lin.apply(&self.rec, &dl, &da, out)?;
        Ok(())
    }

    /// `Jᵀ u`: δx̄ → (δℓ̄*, δφ̄*) → β̄.
    fn gn_apply_t(
        &self,
        lin: &mut GLinearization,
        lay: &Layout,
        dl_drl: &[f64],
        corr: Option<&CorrectionLin>,
        u: &[V3],
        out: &mut [f64],
    ) -> Result<()> {
        let ne = self.topo.n_edges();
        let (mut gl, mut ga) = (vec![0.0; ne], vec![0.0; ne]);
        lin.apply_transpose(&self.rec, u, &mut gl, &mut ga)?;
        self.beta_gradient(lay, dl_drl, corr, &gl, &ga, out);
        Ok(())
    }

    /// β̄ (flat, written to `out`) from the covectors `gl`, `ga` (#E) on the target lengths and
    /// angles: `∂ℓ*/∂RL = dl_drl`, the blocks' components, and the correction's transpose.
    fn beta_gradient(
        &self,
        lay: &Layout,
        dl_drl: &[f64],
        corr: Option<&CorrectionLin>,
        gl: &[f64],
        ga: &[f64],
        out: &mut [f64],
    ) {
        let gl: Vec<f64> = gl.iter().zip(dl_drl).map(|(x, s)| x * s).collect();
        for (b, blk) in self.model.blocks.iter().enumerate() {
            let src = match Quantity::of_block(b) {
                Quantity::Length => &gl,
                Quantity::Angle => ga,
            };
            for k in 0..blk.n_components() {
                let (cols, vals) = blk.components.row(k);
                out[lay.offsets[b] + k] = cols
                    .iter()
                    .zip(vals)
                    .map(|(&j, &v)| v as f64 * src[blk.columns[j as usize] as usize])
                    .sum();
            }
        }
        if let Some(c) = corr {
            c.apply_t(&gl, ga, out);
        }
    }

    /// The residual `r = T x̂ − x(β)` at `pt` (flat, m = 3 #V).
    fn gn_residual(pt: &Point) -> Vec<f64> {
        pt.target
            .iter()
            .zip(&pt.x)
            .flat_map(|(t, x)| sub(*t, *x))
            .collect()
    }

    /// Refines `params.beta` (α and the rigid motion untouched) by Gauss–Newton on the vertex
    /// error of `g` against `mesh` (#V, template topology, metres) up to a rigid motion, see
    /// the module docs; with `correction`, the correction MLP's residual is part of the
    /// model. Never raises the error: the returned β has `rms ≤ rms_start`. With the
    /// correction and [`GnOptions::correction_two_start`], the iteration also runs from a
    /// second start (the given β refined without the correction first) and the lower error of
    /// the two is kept; the report then counts both starts' iterations and g solves.
    ///
    /// # Errors
    /// Size mismatches, a degenerate rest shape, a failing g solve at the start.
    pub fn refine_beta(
        &mut self,
        mesh: &[V3],
        params: &mut Params,
        correction: bool,
        opts: &GnOptions,
    ) -> Result<GnReport> {
        if !(correction && opts.correction_two_start && self.model.correction.is_some()) {
            return self.refine_beta_from(mesh, params, correction, opts);
        }
        let mut second = params.clone();
        let a = self.refine_beta_from(mesh, params, true, opts)?;
        let b0 = self.refine_beta_from(mesh, &mut second, false, opts)?;
        let b = self.refine_beta_from(mesh, &mut second, true, opts)?;
        let rep = GnReport {
            iterations: a.iterations + b0.iterations + b.iterations,
            rms_start: a.rms_start,
            rms: a.rms.min(b.rms),
            g_solves: a.g_solves + b0.g_solves + b.g_solves,
        };
        if b.rms < a.rms {
            *params = second;
        }
        Ok(rep)
    }

    /// An error naming `what` unless `n` is the model's vertex count.
    fn check_vertex_count(&self, what: &str, n: usize) -> Result<()> {
        if n == self.model.n_vertices {
            return Ok(());
        }
        Err(ModelError::Invalid(format!(
            "{what} has {n} vertices, the model has {}",
            self.model.n_vertices
        )))
    }

    /// One start of [`Evaluator::refine_beta`].
    fn refine_beta_from(
        &mut self,
        mesh: &[V3],
        params: &mut Params,
        correction: bool,
        opts: &GnOptions,
    ) -> Result<GnReport> {
        self.check_vertex_count("mesh", mesh.len())?;
        let correction = correction && self.model.correction.is_some();
        let rest = self.model.rest_shape(&params.alpha);
        let rg = RestGeometry::new(&self.topo, &rest)?;
        let gauge = self.rec.gauge_from(&rest)?;
        let lay = Layout::new(&self.model);
        let nv = mesh.len() as f64;
        let model = self.model.clone();
        let mut pt = self.gn_point(params, correction, &rg, &gauge, mesh)?;
        let mut rep = GnReport {
            rms_start: (pt.f / nv).sqrt(),
            g_solves: 1,
            ..GnReport::default()
        };
        let mut beta = lay.flatten(&self.model, params);
        let mut mu = opts.damping;
        'outer: for _ in 0..opts.max_iterations {
            // The workspace holds the accepted point's g solution (its last solve).
            let mut lin = self.rec.linearize(&self.ws, &pt.lengths, &pt.angles)?;
            let r = Self::gn_residual(&pt);
            let corr_lin = if correction && opts.correction_jacobian {
                let mut cur = params.clone();
                lay.write(&self.model, &beta, &mut cur);
                CorrectionLin::new(&model, &lay, &cur)
            } else {
                None
            };
            let mut op = GnOperator {
                ev: self,
                lin: &mut lin,
                lay: &lay,
                dl_drl: &pt.dl_drl,
                corr: corr_lin.as_ref(),
            };
            // The gradient Jᵀ r and the block curvatures: once per linearization.
            let mut g = vec![0.0; lay.len()];
            op.apply_t(&r, &mut g)?;
            let rho = block_curvatures(&mut op, &lay.offsets, &g, r.len())?;
            let mut accepted = None;
            for _ in 0..=opts.max_rejections {
                let lambda: Vec<f64> = lay
                    .offsets
                    .windows(2)
                    .zip(&rho)
                    .flat_map(|(w, &c)| std::iter::repeat_n(mu * c, w[1] - w[0]))
                    .collect();
                let mut op = GnOperator {
                    ev: self,
                    lin: &mut lin,
                    lay: &lay,
                    dl_drl: &pt.dl_drl,
                    corr: corr_lin.as_ref(),
                };
                let delta = damped_cgls(&mut op, &lambda, &r, &g, opts.cg_iterations)?;
                let trial: Vec<f64> = beta.iter().zip(&delta).map(|(b, d)| b + d).collect();
                let mut p = params.clone();
                lay.write(&self.model, &trial, &mut p);
                rep.g_solves += 1;
                // A failing g solve at a trial step counts as no decrease.
                if let Ok(np) = self.gn_point(&p, correction, &rg, &gauge, mesh)
                    && np.f.is_finite()
                    && np.f < pt.f
                {
                    accepted = Some((trial, np));
                    mu = (mu / 3.0).max(1e-9);
                    break;
                }
                mu = (mu * 8.0).max(1e-6);
            }
            let Some((trial, np)) = accepted else {
                break 'outer;
            };
            let rel = (pt.f - np.f) / pt.f.max(1e-300);
            beta = trial;
            pt = np;
            rep.iterations += 1;
            if rel < opts.tolerance {
                break;
            }
        }
        lay.write(&self.model, &beta, params);
        rep.rms = (pt.f / nv).sqrt();
        Ok(rep)
    }

    /// What [`Evaluator::vertex_jacobian_product`] and its transpose linearize: the layout,
    /// the g point at `params` (gauge of its rest shape), g's linearization there and, with
    /// `correction` and a correction MLP, the correction's (borrowing `model`, this
    /// evaluator's model).
    fn linearization_at<'m>(
        &mut self,
        model: &'m super::PanoManModel,
        params: &Params,
        correction: bool,
    ) -> Result<(Layout, Point, GLinearization, Option<CorrectionLin<'m>>)> {
        let correction = correction && model.correction.is_some();
        let rest = model.rest_shape(&params.alpha);
        let rg = RestGeometry::new(&self.topo, &rest)?;
        let gauge = self.rec.gauge_from(&rest)?;
        let lay = Layout::new(&self.model);
        let pt = self.gn_point(params, correction, &rg, &gauge, &rest)?;
        let lin = self.rec.linearize(&self.ws, &pt.lengths, &pt.angles)?;
        let corr = if correction {
            CorrectionLin::new(model, &lay, params)
        } else {
            None
        };
        Ok((lay, pt, lin, corr))
    }

    /// The directional derivative `J d = ∂x/∂β · d` that [`Evaluator::refine_beta`] linearizes
    /// with: `x(β) = g(RL(β), RA(β), B_S(α))` at `params` (rigid placement ignored, gauge of the
    /// rest shape, as [`Evaluator::pose`] without its rigid motion), with the correction MLP's
    /// Jacobian when `correction` (#V × 3, metres per unit of `d`). `direction` holds the
    /// β direction per block (blocks it lacks are 0; α is ignored). Exposed for checks against
    /// finite differences of [`Evaluator::pose`].
    ///
    /// # Errors
    /// A direction block the model does not have or of the wrong length, a degenerate rest
    /// shape, a failing g solve at `params`.
    pub fn vertex_jacobian_product(
        &mut self,
        params: &Params,
        correction: bool,
        direction: &Params,
    ) -> Result<Vec<V3>> {
        let model = self.model.clone();
        let (lay, pt, mut lin, corr) = self.linearization_at(&model, params, correction)?;
        let d = lay.flatten_checked(&self.model, direction)?;
        let mut out = vec![[0.0; 3]; self.topo.n_vertices];
        self.gn_apply(&mut lin, &lay, &pt.dl_drl, corr.as_ref(), &d, &mut out)?;
        Ok(out)
    }

    /// The adjoint of [`Evaluator::vertex_jacobian_product`]: `Jᵀ u` for a vertex covector `u`
    /// (#V × 3), as β per block (α and the rigid placement 0). `⟨J d, u⟩ = ⟨d, Jᵀ u⟩` is what the
    /// encoder's CGLS relies on.
    ///
    /// # Errors
    /// As [`Evaluator::vertex_jacobian_product`], and a `u` of the wrong length.
    pub fn vertex_jacobian_transpose_product(
        &mut self,
        params: &Params,
        correction: bool,
        u: &[V3],
    ) -> Result<Params> {
        self.check_vertex_count("covector", u.len())?;
        let model = self.model.clone();
        let (lay, pt, mut lin, corr) = self.linearization_at(&model, params, correction)?;
        let mut g = vec![0.0; lay.len()];
        self.gn_apply_t(&mut lin, &lay, &pt.dl_drl, corr.as_ref(), u, &mut g)?;
        let mut out = Params {
            alpha: vec![0.0; params.alpha.len()],
            ..params.clone()
        };
        out.translation = [0.0; 3];
        out.rotation = [0.0; 3];
        lay.write(&self.model, &g, &mut out);
        Ok(out)
    }

    /// [`Evaluator::encode`] followed by [`Evaluator::refine_beta`]: the parameters whose posed
    /// mesh is closest to `mesh` (vertex error up to a rigid motion), not the ones whose RL/RA
    /// are.
    ///
    /// # Errors
    /// As [`Evaluator::encode`] and [`Evaluator::refine_beta`].
    pub fn encode_gn(
        &mut self,
        mesh: &[V3],
        rest: Option<&[V3]>,
        correction: bool,
        opts: &GnOptions,
    ) -> Result<(Params, GnReport)> {
        let mut p = self.encode(mesh, rest, correction)?;
        let rep = self.refine_beta(mesh, &mut p, correction, opts)?;
        Ok((p, rep))
    }
}

/// Newton steps of g's frame solve in [`Evaluator::pose_precise`] and
/// [`Evaluator::pose_vjp`] (each kept only while it lowers the frame gradient; two or three
/// reach rounding from the Gauss–Newton result).
const NEWTON_STEPS: usize = 4;

impl Evaluator {
    /// [`Evaluator::pose`] with g's frames polished to the frame solve's minimiser by Newton
    /// steps ([`panoman_mesh::GWorkspace::newton_steps`]): the function whose gradient
    /// [`Evaluator::pose_vjp`] is. It differs from `pose` by the Gauss–Newton tolerance.
    ///
    /// # Errors
    /// As [`Evaluator::pose`].
    pub fn pose_precise(&mut self, params: &Params, correction: bool) -> Result<Vec<V3>> {
        self.ws.newton_steps = NEWTON_STEPS;
        let out = self.pose(params, correction);
        self.ws.newton_steps = 0;
        out
    }

    /// The gradient of `⟨u, B_P(α, β, rotation, translation)⟩` ([`Evaluator::pose_precise`]) with
    /// respect to the parameters, for a vertex covector `u` (#V × 3): the vector–Jacobian
    /// product of reverse-mode differentiation. β through the blocks, the length floor and the
    /// correction MLP (exact within its ReLU pattern); α through the rest shape's edge lengths
    /// and dihedral angles and g's gauge (measured on the rest shape); g by its exact
    /// derivative ([`panoman_mesh::GDerivative::Exact`]); `rotation` through the left Jacobian
    /// of SO(3). Costs one precise g solve and one exact transpose product. Where g's frame
    /// solve stops short of a minimum (its Hessian indefinite: RL/RA far from any training
    /// pose, e.g. β drawn at random over its whole range), the Gauss–Newton derivative
    /// replaces the exact one (a descent direction still, no longer exact). α's gradient has
    /// every shape component, whatever the length of `params.alpha`.
    ///
    /// # Errors
    /// A `u` of the wrong length or non-finite, parameters that do not fit, a failing g solve
    /// or derivative.
    pub fn pose_vjp(&mut self, params: &Params, correction: bool, u: &[V3]) -> Result<Params> {
        self.check_vertex_count("covector", u.len())?;
        if let Some(v) = u.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(ModelError::Invalid(format!(
                "covector of vertex {v} is not finite"
            )));
        }
        let model = self.model.clone();
        let correction = correction && model.correction.is_some();
        let rest = model.rest_shape(&params.alpha);
        let rg = RestGeometry::new(&self.topo, &rest)?;
        let gauge = self.rec.gauge_from(&rest)?;
        let lay = Layout::new(&model);
        self.ws.newton_steps = NEWTON_STEPS;
        let pt = self.gn_point(params, correction, &rg, &gauge, &rest);
        self.ws.newton_steps = 0;
        let pt = pt?;
        // At the iteration cap the frames are not at a minimum: the implicit derivative would
        // not be the derivative of what was returned, so Gauss–Newton's is taken directly.
        let st = self.ws.stats;
        let at_minimum = st.frame_converged || st.frame_iterations < self.rec.max_frame_iterations;
        let mode = if at_minimum {
            GDerivative::Exact
        } else {
            GDerivative::GaussNewton
        };
        let mut lin = self
            .rec
            .linearize_with(&self.ws, &pt.lengths, &pt.angles, mode)?;
        let corr = if correction {
            CorrectionLin::new(&model, &lay, params)
        } else {
            None
        };
        // Rigid placement: y = R x + t.
        let r = panoman_mesh::rotation::from_rotation_vector(params.rotation);
        let mut xbar = vec![[0.0; 3]; u.len()];
        let (mut tbar, mut thbar) = ([0.0; 3], [0.0; 3]);
        for ((xb, &uv), &xv) in xbar.iter_mut().zip(u).zip(&pt.x) {
            *xb = matvec_t(&r, uv);
            tbar = add(tbar, uv);
            thbar = add(thbar, cross(panoman_mesh::geom::matvec(&r, xv), uv));
        }
        let jl = panoman_mesh::rotation::left_jacobian(params.rotation);
        // β through g's exact transpose.
        let ne = self.topo.n_edges();
        let (mut gl, mut ga) = (vec![0.0; ne], vec![0.0; ne]);
        if lin
            .apply_transpose(&self.rec, &xbar, &mut gl, &mut ga)
            .is_err()
        {
            // The frame solve stopped short of a minimum (its Hessian is indefinite there:
            // RL/RA far from any training pose): the Gauss–Newton derivative, always defined.
            lin = self.rec.linearize_with(
                &self.ws,
                &pt.lengths,
                &pt.angles,
                GDerivative::GaussNewton,
            )?;
            lin.apply_transpose(&self.rec, &xbar, &mut gl, &mut ga)?;
        }
        let mut gb = vec![0.0; lay.len()];
        self.beta_gradient(&lay, &pt.dl_drl, corr.as_ref(), &gl, &ga, &mut gb);
        // α: ℓ* = ℓ_r (1 + RL) (floored), φ* = φ_r + RA, and the gauge of the rest shape.
        let glr: Vec<f64> = gl
            .iter()
            .zip(pt.lengths.iter().zip(&rg.lengths))
            .map(|(g, (l, lr))| g * l / lr)
            .collect();
        let mut grest = vec![[0.0; 3]; u.len()];
        panoman_mesh::rla::geometry_gradient_add(&self.topo, &rest, &glr, &ga, &mut grest);
        self.rec
            .gauge_gradient_add(&rest, &pt.x, &xbar, &mut grest)?;
        let flat: Vec<f64> = grest.iter().flatten().copied().collect();
        let comps = &model.shape.components;
        let alpha = (0..model.shape.n_components())
            .map(|j| {
                comps
                    .col(j)
                    .iter()
                    .zip(&flat)
                    .map(|(s, g)| s * g)
                    .sum::<f64>()
            })
            .collect();
        let mut out = Params {
            alpha,
            translation: tbar,
            rotation: matvec_t(&jl, thbar),
            ..params.clone()
        };
        lay.write(&model, &gb, &mut out);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense m × n matrix (row-major) as an operator.
    struct Dense {
        m: usize,
        n: usize,
        a: Vec<f64>,
    }

    impl LinearOperator for Dense {
        fn apply(&mut self, x: &[f64], y: &mut [f64]) -> Result<()> {
            for (i, yi) in y.iter_mut().enumerate().take(self.m) {
                *yi = (0..self.n).map(|j| self.a[i * self.n + j] * x[j]).sum();
            }
            Ok(())
        }
        fn apply_t(&mut self, y: &[f64], x: &mut [f64]) -> Result<()> {
            for (j, xj) in x.iter_mut().enumerate().take(self.n) {
                *xj = (0..self.m).map(|i| self.a[i * self.n + j] * y[i]).sum();
            }
            Ok(())
        }
    }

    /// Solves the n × n SPD system `k x = b` by Gaussian elimination (no pivoting needed).
    fn solve_spd(mut k: Vec<f64>, mut b: Vec<f64>, n: usize) -> Vec<f64> {
        for c in 0..n {
            for r in c + 1..n {
                let f = k[r * n + c] / k[c * n + c];
                for j in c..n {
                    k[r * n + j] -= f * k[c * n + j];
                }
                b[r] -= f * b[c];
            }
        }
        let mut x = vec![0.0; n];
        for c in (0..n).rev() {
            let s: f64 = (c + 1..n).map(|j| k[c * n + j] * x[j]).sum();
            x[c] = (b[c] - s) / k[c * n + c];
        }
        x
    }

    #[test]
    fn damped_cgls_solves_the_levenberg_marquardt_normal_equations() {
        // A fixed, ill-conditioned 9 × 5 matrix (columns scaled 1 … 10⁻²) and right-hand side,
        // the unknowns in two blocks (0..2, 2..5).
        let (m, n) = (9, 5);
        let offsets = [0, 2, 5];
        let a: Vec<f64> = (0..m * n)
            .map(|k| {
                let (i, j) = ((k / n) as f64, (k % n) as f64);
                ((1.7 * i + 0.3) * (j + 1.0)).sin() * 10f64.powf(-j / 2.0)
            })
            .collect();
        let r: Vec<f64> = (0..m).map(|i| (0.9 * i as f64).cos()).collect();
        let mut op = Dense { m, n, a: a.clone() };
        let mut g = vec![0.0; n];
        op.apply_t(&r, &mut g).unwrap();
        // Block curvatures: the Rayleigh quotient of JᵀJ along each block's gradient part.
        let rho = block_curvatures(&mut op, &offsets, &g, m).unwrap();
        for (b, w) in offsets.windows(2).enumerate() {
            let mut gb = vec![0.0; n];
            gb[w[0]..w[1]].copy_from_slice(&g[w[0]..w[1]]);
            let mut jg = vec![0.0; m];
            op.apply(&gb, &mut jg).unwrap();
            let want =
                jg.iter().map(|v| v * v).sum::<f64>() / gb.iter().map(|v| v * v).sum::<f64>();
            assert!((rho[b] - want).abs() <= 1e-12 * want, "{rho:?}");
        }
        assert!(
            rho[0] > 10.0 * rho[1],
            "the scaled block is flatter: {rho:?}"
        );
        let mut norms = Vec::new();
        for mu in [0.0, 1e-3, 1e-1, 10.0] {
            let lambda: Vec<f64> = (0..n).map(|j| mu * rho[usize::from(j >= 2)]).collect();
            let mut k = vec![0.0; n * n];
            for i in 0..n {
                for j in 0..n {
                    k[i * n + j] = (0..m).map(|t| a[t * n + i] * a[t * n + j]).sum::<f64>()
                        + if i == j { lambda[i] } else { 0.0 };
                }
            }
            let exact = solve_spd(k, g.clone(), n);
            // In exact arithmetic CG ends after n iterations; 4n allow for rounding.
            let got = damped_cgls(&mut op, &lambda, &r, &g, 4 * n).unwrap();
            let scale = exact.iter().fold(0.0f64, |s, v| s.max(v.abs()));
            for (x, y) in got.iter().zip(&exact) {
                assert!(
                    (x - y).abs() <= 1e-8 * scale,
                    "mu {mu}: {got:?} vs {exact:?}"
                );
            }
            norms.push(got.iter().map(|v| v * v).sum::<f64>().sqrt());
        }
        // Damping shortens the step: ‖δ(μ)‖ decreases in μ.
        assert!(norms.windows(2).all(|w| w[0] > w[1]), "{norms:?}");
    }
}
