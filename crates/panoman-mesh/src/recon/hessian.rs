//! The full Hessian of g's frame energy in world-frame exponential coordinates
//! (docs/design/rla-and-g.md §3.8), used by the exact derivative ([`super::GDerivative`]) and
//! the frame solve's Newton polish ([`super::GWorkspace::newton_steps`]).
//!
//! Per interior edge with `M_e = R_fL Q_e R_fRᵀ`, `m_e = vee(skew(M_e))`,
//! `K_e = tr(M_e) I − sym(M_e)`, perturbations `R_fL ← exp([a]×) R_fL`, `R_fR ← exp([b]×) R_fR`
//! and `w = a − b`: `E_e ≈ E_e⁰ + 4 w·m_e + wᵀ K_e w + 2 m_e·(a × b)`, so `H_aa = H_bb = 2K_e`
//! and `H_ab = −2K_e − 2[m_e]×` (`= 4(L ⊗ I₃)` at consistency). `H` is applied matrix-free and
//! inverted by conjugate gradients preconditioned with the factored `4(L ⊗ I₃)`.

use super::{FACE_CHUNK, Reconstructor};
use crate::error::{MeshError, Result};
use crate::geom::{M3, V3, cross, matmul, matvec, sub, transpose};
use crate::topology::{NONE, Topology};
use faer::Mat;
use faer::dyn_stack::MemBuffer;
use rayon::prelude::*;

/// Relative residual at which the conjugate gradients of a derivative stop.
pub(crate) const PCG_TOLERANCE: f64 = 1e-12;
/// Conjugate-gradient iterations at most. Preconditioned by the Gauss–Newton matrix, nearly
/// consistent data (fitted or encoded parameters) needs ~10; a solve that has not converged by
/// this count is at data so far from consistency that the caller falls back (the Gauss–Newton
/// derivative, no Newton polish) rather than spend hundreds of back-substitutions.
const PCG_MAX_ITERATIONS: usize = 60;

/// `K_e` and `m_e` of one interior edge (module docs); zero on boundary edges.
#[derive(Clone, Copy, Debug)]
pub(crate) struct EdgeCurvature {
    pub(crate) k: M3,
    pub(crate) m: V3,
}

/// `vee(skew(M))`.
fn vee_skew(m: &M3) -> V3 {
    [
        0.5 * (m[2][1] - m[1][2]),
        0.5 * (m[0][2] - m[2][0]),
        0.5 * (m[1][0] - m[0][1]),
    ]
}

/// [`EdgeCurvature`] of every edge at `frames` (#F) with connection maps `conn` (#E).
pub(crate) fn edge_curvatures(topo: &Topology, frames: &[M3], conn: &[M3]) -> Vec<EdgeCurvature> {
    (0..topo.n_edges())
        .into_par_iter()
        .with_min_len(FACE_CHUNK)
        .map(|e| {
            let [fl, fr] = topo.edge_faces[e];
            if fr == NONE {
                return EdgeCurvature {
                    k: [[0.0; 3]; 3],
                    m: [0.0; 3],
                };
            }
            let a = matmul(&frames[fl as usize], &conn[e]);
            let mm = matmul(&a, &transpose(&frames[fr as usize]));
            let tr = mm[0][0] + mm[1][1] + mm[2][2];
            let mut k = [[0.0; 3]; 3];
            for (r, row) in k.iter_mut().enumerate() {
                for (c, x) in row.iter_mut().enumerate() {
                    *x = -0.5 * (mm[r][c] + mm[c][r]) + if r == c { tr } else { 0.0 };
                }
            }
            EdgeCurvature {
                k,
                m: vee_skew(&mm),
            }
        })
        .collect()
}

/// `y = H x` (reduced face rows × 3, gauge faces 0): per interior edge
/// `y_fL += 2K(a − b) − 2 m × b`, `y_fR += −2K(a − b) + 2 m × a`.
fn hessian_apply(rec: &Reconstructor, edges: &[EdgeCurvature], x: &Mat<f64>, y: &mut Mat<f64>) {
    let topo = &rec.topo;
    y.fill(0.0);
    let at = |f: u32| -> Option<usize> {
        let rf = rec.face_red[f as usize];
        (rf != NONE).then_some(rf as usize)
    };
    for (e, c) in edges.iter().enumerate() {
        let [fl, fr] = topo.edge_faces[e];
        if fr == NONE {
            continue;
        }
        let (il, ir) = (at(fl), at(fr));
        let get = |i: Option<usize>| i.map_or([0.0; 3], |i| [0, 1, 2].map(|k| x[(i, k)]));
        let (a, b) = (get(il), get(ir));
        let kd = matvec(&c.k, sub(a, b));
        if let Some(i) = il {
            let mb = cross(c.m, b);
            for k in 0..3 {
                y[(i, k)] += 2.0 * kd[k] - 2.0 * mb[k];
            }
        }
        if let Some(i) = ir {
            let ma = cross(c.m, a);
            for k in 0..3 {
                y[(i, k)] += -2.0 * kd[k] + 2.0 * ma[k];
            }
        }
    }
}

/// Conjugate-gradient buffers (#reduced faces × 3 each).
pub(crate) struct Pcg {
    r: Mat<f64>,
    z: Mat<f64>,
    p: Mat<f64>,
    q: Mat<f64>,
}

fn dot(a: &Mat<f64>, b: &Mat<f64>) -> f64 {
    (0..3)
        .map(|c| {
            a.col(c)
                .iter()
                .zip(b.col(c).iter())
                .map(|(x, y)| x * y)
                .sum::<f64>()
        })
        .sum()
}

impl Pcg {
    pub(crate) fn new(n_rows: usize) -> Self {
        Self {
            r: Mat::zeros(n_rows, 3),
            z: Mat::zeros(n_rows, 3),
            p: Mat::zeros(n_rows, 3),
            q: Mat::zeros(n_rows, 3),
        }
    }

    /// Solves `H x = b` in place (`x` holds `b` on entry), preconditioned with `(4L)⁻¹`, to
    /// the relative residual `tolerance`; returns the iterations.
    ///
    /// # Errors
    /// [`MeshError::Numerical`] when `H` shows non-positive curvature (not at a minimum) or
    /// the iteration does not reach `tolerance`.
    pub(crate) fn solve(
        &mut self,
        rec: &Reconstructor,
        edges: &[EdgeCurvature],
        x: &mut Mat<f64>,
        scratch: &mut MemBuffer,
        tolerance: f64,
    ) -> Result<usize> {
        if rec.n_face_red == 0 {
            return Ok(0);
        }
        let precondition = |r: &Mat<f64>, z: &mut Mat<f64>, scratch: &mut MemBuffer| {
            z.copy_from(r);
            rec.dual_factor.solve_in_place(z.as_mut(), scratch);
            *z *= faer::Scale(0.25);
        };
        self.r.copy_from(&*x);
        let b_norm = dot(&self.r, &self.r).sqrt();
        x.fill(0.0);
        if b_norm == 0.0 {
            return Ok(0);
        }
        precondition(&self.r, &mut self.z, scratch);
        self.p.copy_from(&self.z);
        let mut rz = dot(&self.r, &self.z);
        let mut iterations = 0;
        loop {
            hessian_apply(rec, edges, &self.p, &mut self.q);
            let pq = dot(&self.p, &self.q);
            if pq.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return Err(MeshError::Numerical(format!(
                    "g's frame Hessian is not positive definite here (pᵀHp = {pq:e}): the frame \
                     solve did not reach a minimum"
                )));
            }
            let alpha = rz / pq;
            *x += faer::Scale(alpha) * &self.p;
            self.r -= faer::Scale(alpha) * &self.q;
            iterations += 1;
            let r_norm = dot(&self.r, &self.r).sqrt();
            if r_norm <= tolerance * b_norm {
                return Ok(iterations);
            }
            if iterations >= PCG_MAX_ITERATIONS || !r_norm.is_finite() {
                return Err(MeshError::Numerical(format!(
                    "g's frame Hessian: conjugate gradients at relative residual {:.1e} after \
                     {iterations} iterations",
                    r_norm / b_norm
                )));
            }
            precondition(&self.r, &mut self.z, scratch);
            let rz_new = dot(&self.r, &self.z);
            let beta = rz_new / rz;
            rz = rz_new;
            self.p *= faer::Scale(beta);
            self.p += &self.z;
        }
    }
}
