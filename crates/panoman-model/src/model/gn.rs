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
//! over all β (α fixed): each outer iteration re-aligns the target rigidly (T), linearizes `g`
//! at its solution ([`panoman_mesh::GLinearization`]: `J = J_g · ∂(ℓ*, φ*)/∂β` with
//! `∂ℓ*_e/∂β_k = ℓ_r,e M_k,e` on RL blocks and `∂φ*_e/∂β_k = M_k,e` on RA blocks; 0 where the
//! length floor is active), solves `min_δ ‖J δ + r‖²` by CGLS (each iteration one product
//! `J p` and one `Jᵀ s`, i.e. four sparse back-substitutions, no g solve; the iteration cap
//! truncates it to the dominant directions) and takes the first of the steps `δ, δ/2, δ/4`
//! that lowers `f` (each trial is one g solve). With the correction MLP, `R(β)` is evaluated at
//! every iterate but held fixed inside the linearization (its Jacobian is dropped), so the
//! step is a quasi-Gauss–Newton step and the line search on the true `f` keeps it monotone.

use super::{Evaluator, Params, Quantity};
use crate::error::{ModelError, Result};
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{V3, sub};
use panoman_mesh::rla::MIN_RELATIVE_LENGTH;
use panoman_mesh::{GLinearization, Gauge, RestGeometry};

/// Options of [`Evaluator::refine_beta`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GnOptions {
    /// Outer Gauss–Newton iterations (each: one linearization, CGLS, 1–3 g solves).
    pub max_iterations: usize,
    /// CGLS iterations per outer iteration.
    pub cg_iterations: usize,
    /// Stop when an outer iteration lowers `f` by less than this fraction.
    pub tolerance: f64,
}

impl Default for GnOptions {
    /// 4 outer iterations, 25 CGLS iterations, 1 % relative decrease.
    fn default() -> Self {
        Self {
            max_iterations: 4,
            cg_iterations: 25,
            tolerance: 1e-2,
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
    /// g solves (including the line-search trials).
    pub g_solves: usize,
}

/// The flat β layout over the model's blocks (block order, each block's components).
struct Layout {
    offsets: Vec<usize>,
}

impl Layout {
    fn new(ev: &Evaluator) -> Self {
        let mut offsets = vec![0];
        for b in &ev.model.blocks {
            offsets.push(offsets.last().unwrap() + b.n_components());
        }
        Self { offsets }
    }
    fn len(&self) -> usize {
        *self.offsets.last().unwrap()
    }
    fn flatten(&self, ev: &Evaluator, p: &Params) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.len());
        for b in &ev.model.blocks {
            out.extend(p.beta_of(&b.name, b.n_components()));
        }
        out
    }
    fn write(&self, ev: &Evaluator, beta: &[f64], p: &mut Params) {
        for (i, b) in ev.model.blocks.iter().enumerate() {
            p.beta.insert(
                b.name.clone(),
                beta[self.offsets[i]..self.offsets[i + 1]].to_vec(),
            );
        }
    }
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
        u: &[V3],
        out: &mut [f64],
    ) -> Result<()> {
        let ne = self.topo.n_edges();
        let (mut gl, mut ga) = (vec![0.0; ne], vec![0.0; ne]);
        lin.apply_transpose(&self.rec, u, &mut gl, &mut ga)?;
        for (x, &s) in gl.iter_mut().zip(dl_drl) {
            *x *= s;
        }
        for (b, blk) in self.model.blocks.iter().enumerate() {
            let src = match Quantity::of_block(b) {
                Quantity::Length => &gl,
                Quantity::Angle => &ga,
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
        Ok(())
    }

    /// CGLS for `min_δ ‖J δ + r‖²` from δ = 0, `iters` iterations.
    fn gn_cgls(&self, pt: &Point, lay: &Layout, iters: usize) -> Result<Vec<f64>> {
        let mut lin = self.rec.linearize(&self.ws, &pt.lengths, &pt.angles)?;
        let nv = pt.x.len();
        let mut res: Vec<V3> = pt
            .target
            .iter()
            .zip(&pt.x)
            .map(|(t, x)| sub(*t, *x))
            .collect();
        let mut delta = vec![0.0; lay.len()];
        let mut s = vec![0.0; lay.len()];
        self.gn_apply_t(&mut lin, lay, &pt.dl_drl, &res, &mut s)?;
        let mut p = s.clone();
        let mut gamma: f64 = s.iter().map(|v| v * v).sum();
        let gamma0 = gamma;
        let mut q = vec![[0.0; 3]; nv];
        for _ in 0..iters {
            if gamma <= 1e-20 * gamma0 || gamma == 0.0 {
                break;
            }
            self.gn_apply(&mut lin, lay, &pt.dl_drl, &p, &mut q)?;
            let qq: f64 = q.iter().flatten().map(|v| v * v).sum();
            if qq <= 0.0 || !qq.is_finite() {
                break;
            }
            let a = gamma / qq;
            for (d, pi) in delta.iter_mut().zip(&p) {
                *d += a * pi;
            }
            for (r, qi) in res.iter_mut().zip(&q) {
                for c in 0..3 {
                    r[c] -= a * qi[c];
                }
            }
            self.gn_apply_t(&mut lin, lay, &pt.dl_drl, &res, &mut s)?;
            let g_new: f64 = s.iter().map(|v| v * v).sum();
            let bta = g_new / gamma;
            for (pi, si) in p.iter_mut().zip(&s) {
                *pi = si + bta * *pi;
            }
            gamma = g_new;
        }
        Ok(delta)
    }

    /// Refines `params.beta` (α and the rigid motion untouched) by Gauss–Newton on the vertex
    /// error of `g` against `mesh` (#V, template topology, metres) up to a rigid motion, see
    /// the module docs; with `correction`, the correction MLP's residual is part of the
    /// model. Never raises the error: the returned β has `rms ≤ rms_start`.
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
        if mesh.len() != self.model.n_vertices {
            return Err(ModelError::Invalid(format!(
                "mesh has {} vertices, the model has {}",
                mesh.len(),
                self.model.n_vertices
            )));
        }
        let correction = correction && self.model.correction.is_some();
        let rest = self.model.rest_shape(&params.alpha);
        let rg = RestGeometry::new(&self.topo, &rest)?;
        let gauge = self.rec.gauge_from(&rest)?;
        let lay = Layout::new(self);
        let nv = mesh.len() as f64;
        let mut pt = self.gn_point(params, correction, &rg, &gauge, mesh)?;
        let mut rep = GnReport {
            rms_start: (pt.f / nv).sqrt(),
            g_solves: 1,
            ..GnReport::default()
        };
        let mut beta = lay.flatten(self, params);
        for _ in 0..opts.max_iterations {
            let delta = self.gn_cgls(&pt, &lay, opts.cg_iterations)?;
            let mut accepted = None;
            for t in [1.0, 0.5, 0.25] {
                let trial: Vec<f64> = beta.iter().zip(&delta).map(|(b, d)| b + t * d).collect();
                let mut p = params.clone();
                lay.write(self, &trial, &mut p);
                rep.g_solves += 1;
                // A failing g solve at a trial step counts as no decrease.
                if let Ok(np) = self.gn_point(&p, correction, &rg, &gauge, mesh)
                    && np.f.is_finite()
                    && np.f < pt.f
                {
                    accepted = Some((trial, np));
                    break;
                }
            }
            let Some((trial, np)) = accepted else {
                break;
            };
            let rel = (pt.f - np.f) / pt.f.max(1e-300);
            beta = trial;
            pt = np;
            rep.iterations += 1;
            // The workspace now holds the accepted point's g solution (the last trial run),
            // which the next linearization reads.
            if rel < opts.tolerance {
                break;
            }
        }
        lay.write(self, &beta, params);
        rep.rms = (pt.f / nv).sqrt();
        Ok(rep)
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
