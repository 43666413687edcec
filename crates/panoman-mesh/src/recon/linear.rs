//! The linearization of `g` at a solution: `δx = J_g (δℓ*, δφ*)` and its transpose
//! (docs/design/rla-and-g.md §3.7).
//!
//! With the frames `R_t` and local coordinates `q_t = (ℓ01, c, h)` of the last
//! [`Reconstructor::reconstruct`] call (read from its [`GWorkspace`]):
//!
//! 1. **Connection maps.** Perturbing `Q_e ← Q_e exp([η_e]×)` moves edge `e`'s frame residual
//!    `R_fL Q_e − R_fR` by `[ζ_e]× A_e` with `A_e = R_fL Q_e` and the world rotation vector
//!    `ζ_e = A_e η_e`. `η_e = G_e (δℓ_ij, δℓ_jk, δℓ_ik, δℓ_il, δℓ_jl, δφ_e)` with the 3×6 local
//!    Jacobian `G_e = vee(Q_eᵀ ∂Q_e/∂·)` of the closed-form diamond map, taken by central
//!    differences of that 6-input function (steps 1e−6·ℓ_ij and 1e−6 rad; truncation error
//!    ~1e−12 relative) once per linearization.
//! 2. **Frames.** The frame solve minimises `E_F ≈ Σ_e 2‖ω_fL − ω_fR + ζ_e‖²` to first order
//!    (its Gauss–Newton model, exact at consistent data), so the frame increments
//!    `δR_t = [ω_t]× R_t` solve `L ω = −D ζ` with the dual-graph Laplacian `L` already factored
//!    by [`Reconstructor`] and `(Dζ)_f = Σ_{e: fL(e)=f} ζ_e − Σ_{e: fR(e)=f} ζ_e`; `ω = 0` on gauge
//!    faces.
//! 3. **Local coordinates.** `δq_t = (∂(ℓ01, c, h)/∂(ℓ01, ℓ12, ℓ20)) δℓ` analytically:
//!    `∂c = (1 − c/ℓ01) δℓ01 − (ℓ12/ℓ01) δℓ12 + (ℓ20/ℓ01) δℓ20`, `δh = (ℓ20 δℓ20 − c δc)/h`
//!    (the clamped branches of [`third_corner`] differentiate their clamped formulas).
//! 4. **Poisson.** The half-edge vectors `d = R_t (q_b − q_a)` move by
//!    `δd = ω_t × d + R_t (δq_b − δq_a)`; `δx = L_v⁻¹ δb` with `δb` assembled like `g`'s
//!    right-hand side and the vertex Laplacian `L_v` already factored (gauge vertices fixed,
//!    `δx = 0` there).
//!
//! The transpose applies the same steps backwards (`L`, `L_v` symmetric), so a gradient
//! `J_gᵀ u` costs the same two back-substitutions (3 columns each) as a product `J_g v`.
//! Cost per product: O(#E) plus two sparse triangular solves; no g solve.
//!
//! **Exact derivative** ([`GDerivative::Exact`]). Step 2 uses the Gauss–Newton model, exact
//! only at consistent data. The exact one differentiates the optimality condition
//! `∇_ω E_F = 0` (implicit function theorem) with the full Hessian. Per interior edge, with
//! `M_e = R_fL Q_e R_fRᵀ`, `m_e = vee(skew(M_e))`, `K_e = tr(M_e) I − sym(M_e)` and
//! `a = ω_fL`, `b = ω_fR`, `w = a − b + ζ_e`, the edge's energy is to second order
//! `E_e ≈ E_e⁰ + 4 w·m_e + wᵀ K_e w + 2 m_e·(a×ζ_e + a×b − b×ζ_e)`, so
//! `H_aa = H_bb = 2K_e`, `H_ab = −2K_e − 2[m_e]×`, and the mixed block sends `ζ_e` to
//! `∓C_e ζ_e` on (fL, fR) with `C_e = 2K_e − 2[m_e]×`. The frame increments solve
//! `H ω = −Σ_e (C_e ζ_e on fL, −C_e ζ_e on fR)` by conjugate gradients preconditioned with
//! `4 (L ⊗ I₃)` (the Gauss–Newton matrix, already factored; `H = 4 (L ⊗ I₃)` at consistency,
//! `K_e = 2I`, `m_e = 0`), and the transpose with `Hᵀ = H`, `C_eᵀ = 2K_e + 2[m_e]×`.
//! Exact up to the frame solve's convergence; a few preconditioned iterations per product on
//! nearly consistent data.

use super::hessian::{EdgeCurvature, Pcg, edge_curvatures};
use super::{FACE_CHUNK, GWorkspace, HEIGHT_EPS, Reconstructor, diamond_edges, diamond_map};
use crate::error::{MeshError, Result};
use crate::geom::{M3, V3, cross, matmul, matvec, matvec_t, sub, transpose};
use crate::topology::NONE;
use faer::Mat;
use faer::dyn_stack::MemBuffer;
use rayon::prelude::*;

/// Relative finite-difference step of the diamond map's local Jacobian `G_e`.
const DIAMOND_STEP: f64 = 1e-6;

/// Which derivative of `g` a [`GLinearization`] applies (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GDerivative {
    /// The Gauss–Newton derivative: the frame step solves `L ω = −D ζ` (one back-substitution;
    /// exact at consistent targets only).
    #[default]
    GaussNewton,
    /// The derivative of the frame solve's minimiser (full Hessian, preconditioned conjugate
    /// gradients): what finite differences of `g` see.
    Exact,
}

/// The exact mode's data: per-edge curvature and the conjugate gradients' buffers.
struct Exact {
    edges: Vec<EdgeCurvature>,
    pcg: Pcg,
    iterations: usize,
}

/// `g` linearized at its last solution (module docs): `J_g v` ([`GLinearization::apply`])
/// and `J_gᵀ u` ([`GLinearization::apply_transpose`]) for directions `v = (δℓ*, δφ*)`
/// (#E each: metres, radians) and vertex covectors `u` (#V × 3, metres), with the gauge
/// of that call held fixed.
pub struct GLinearization {
    /// Face frames `R_t` of the solution.
    frames: Vec<M3>,
    /// Per face `(ℓ01, c, h)`.
    local: Vec<[f64; 3]>,
    /// Per face `∂(ℓ01, c, h)/∂(ℓ_fe0, ℓ_fe1, ℓ_fe2)` (rows, columns).
    local_jac: Vec<[[f64; 3]; 3]>,
    /// Per edge: the 5 edges of its diamond ([`diamond_edges`]); unused on boundary edges.
    conn_edges: Vec<[u32; 5]>,
    /// Per edge: `W_e = A_e G_e` (3 × 6), so `ζ_e = W_e (δℓ_5, δφ_e)`; zero on boundary edges.
    conn_jac: Vec<[[f64; 6]; 3]>,
    dual: Mat<f64>,
    dual_scratch: MemBuffer,
    vert: Mat<f64>,
    vert_scratch: MemBuffer,
    exact: Option<Exact>,
}

impl std::fmt::Debug for GLinearization {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GLinearization")
            .field("faces", &self.frames.len())
            .field("edges", &self.conn_edges.len())
            .field("exact", &self.exact.is_some())
            .finish()
    }
}

/// `vee(skew(M))` = `(M₂₁ − M₁₂, M₀₂ − M₂₀, M₁₀ − M₀₁)/2`.
fn vee_skew(m: &M3) -> V3 {
    [
        0.5 * (m[2][1] - m[1][2]),
        0.5 * (m[0][2] - m[2][0]),
        0.5 * (m[1][0] - m[0][1]),
    ]
}

/// `∂(ℓ01, c, h)/∂(ℓ01, ℓ12, ℓ20)` of [`super::third_corner`]`(ℓ01, ℓ20, ℓ12)`, with its clamps.
fn third_corner_jac(l01: f64, l12: f64, l20: f64) -> [[f64; 3]; 3] {
    let raw = (l01 * l01 + l20 * l20 - l12 * l12) / (2.0 * l01);
    let (c, dc) = if raw > l20 {
        (l20, [0.0, 0.0, 1.0])
    } else if raw < -l20 {
        (-l20, [0.0, 0.0, -1.0])
    } else {
        (raw, [1.0 - raw / l01, -l12 / l01, l20 / l01])
    };
    let h2 = l20 * l20 - c * c;
    let dh = if h2 > HEIGHT_EPS * l01 * l01 {
        let h = h2.sqrt();
        [-c * dc[0] / h, -c * dc[1] / h, (l20 - c * dc[2]) / h]
    } else {
        [HEIGHT_EPS.sqrt(), 0.0, 0.0]
    };
    [[1.0, 0.0, 0.0], dc, dh]
}

impl Reconstructor {
    /// Linearizes `g` at the solution of the last [`Reconstructor::reconstruct`] /
    /// [`Reconstructor::reconstruct_rla`] call on `ws`, whose target lengths ℓ* and angles φ*
    /// (#E each) are passed again (for `reconstruct_rla`: `ws.lengths`, `ws.angles`), with the
    /// Gauss–Newton derivative ([`Reconstructor::linearize_with`]).
    ///
    /// # Errors
    /// [`MeshError::Mismatch`] on a size mismatch.
    pub fn linearize(
        &self,
        ws: &GWorkspace,
        lengths: &[f64],
        angles: &[f64],
    ) -> Result<GLinearization> {
        self.linearize_with(ws, lengths, angles, GDerivative::GaussNewton)
    }

    /// [`Reconstructor::linearize`] with the derivative chosen: [`GDerivative::Exact`] is the
    /// derivative of g's minimiser (module docs), for gradients that finite differences of g
    /// must confirm.
    ///
    /// # Errors
    /// [`MeshError::Mismatch`] on a size mismatch.
    pub fn linearize_with(
        &self,
        ws: &GWorkspace,
        lengths: &[f64],
        angles: &[f64],
        derivative: GDerivative,
    ) -> Result<GLinearization> {
        let topo = &self.topo;
        let ne = topo.n_edges();
        if lengths.len() != ne || angles.len() != ne || ws.frames.len() != topo.n_faces() {
            return Err(MeshError::Mismatch(format!(
                "linearize: {} lengths and {} angles for {ne} edges",
                lengths.len(),
                angles.len()
            )));
        }
        let local_jac: Vec<[[f64; 3]; 3]> = topo
            .face_edges
            .par_iter()
            .with_min_len(FACE_CHUNK)
            .map(|fe| {
                third_corner_jac(
                    lengths[fe[0] as usize],
                    lengths[fe[1] as usize],
                    lengths[fe[2] as usize],
                )
            })
            .collect();
        let frames = &ws.frames;
        let (conn_edges, conn_jac): (Vec<[u32; 5]>, Vec<[[f64; 6]; 3]>) = (0..ne)
            .into_par_iter()
            .with_min_len(FACE_CHUNK)
            .map(|e| {
                if !topo.is_interior(e) {
                    return ([e as u32; 5], [[0.0; 6]; 3]);
                }
                let (sl, sr, ids) = diamond_edges(topo, e);
                let len = ids.map(|k| lengths[k as usize]);
                let q = ws.conn[e];
                let a = matmul(&frames[topo.edge_faces[e][0] as usize], &q);
                let qt = transpose(&q);
                let mut w = [[0.0; 6]; 3];
                for i in 0..6 {
                    let h = if i < 5 {
                        DIAMOND_STEP * len[0]
                    } else {
                        DIAMOND_STEP
                    };
                    let eval = |s: f64| {
                        let mut l = len;
                        let mut phi = angles[e];
                        if i < 5 {
                            l[i] += s;
                        } else {
                            phi += s;
                        }
                        diamond_map(sl, sr, l, phi)
                    };
                    let (qp, qm) = (eval(h), eval(-h));
                    let mut dq = [[0.0; 3]; 3];
                    for r in 0..3 {
                        for c in 0..3 {
                            dq[r][c] = (qp[r][c] - qm[r][c]) / (2.0 * h);
                        }
                    }
                    let zeta = matvec(&a, vee_skew(&matmul(&qt, &dq)));
                    for r in 0..3 {
                        w[r][i] = zeta[r];
                    }
                }
                (ids, w)
            })
            .unzip();
        let nfr = self.n_face_red.max(1);
        let nvr = self.n_vert_red.max(1);
        let exact = (derivative == GDerivative::Exact).then(|| {
            let edges = edge_curvatures(topo, frames, &ws.conn);
            Exact {
                edges,
                pcg: Pcg::new(nfr),
                iterations: 0,
            }
        });
        Ok(GLinearization {
            exact,
            frames: ws.frames.clone(),
            local: ws.local.clone(),
            local_jac,
            conn_edges,
            conn_jac,
            dual: Mat::zeros(nfr, 3),
            dual_scratch: self.dual_factor.make_scratch(3),
            vert: Mat::zeros(nvr, 3),
            vert_scratch: self.vert_factor.make_scratch(3),
        })
    }
}

impl GLinearization {
    fn check(&self, rec: &Reconstructor, ne: usize, nv: usize) -> Result<()> {
        let topo = &rec.topo;
        if self.frames.len() != topo.n_faces() || ne != topo.n_edges() || nv != topo.n_vertices {
            return Err(MeshError::Mismatch(format!(
                "linearization of {} faces applied with {ne} edge / {nv} vertex values \
                 (topology: {} edges, {} vertices)",
                self.frames.len(),
                topo.n_edges(),
                topo.n_vertices
            )));
        }
        Ok(())
    }

    /// `δx = J_g (δℓ*, δφ*)` (#E, #E → #V, written to `out`); `rec` must be the reconstructor
    /// that produced this linearization. δφ* is ignored on boundary edges.
    ///
    /// # Errors
    /// [`MeshError::Mismatch`] on a size mismatch.
    pub fn apply(
        &mut self,
        rec: &Reconstructor,
        dl: &[f64],
        dphi: &[f64],
        out: &mut [V3],
    ) -> Result<()> {
        self.check(rec, dl.len().min(dphi.len()), out.len())?;
        let topo = &rec.topo;
        // 1–2. ζ_e, then L ω = −D ζ.
        self.dual.fill(0.0);
        for e in 0..topo.n_edges() {
            let [fl, fr] = topo.edge_faces[e];
            if fr == NONE {
                continue;
            }
            let ids = self.conn_edges[e];
            let w = &self.conn_jac[e];
            let mut x = [0.0; 6];
            for i in 0..5 {
                x[i] = dl[ids[i] as usize];
            }
            x[5] = dphi[e];
            let mut zeta: V3 = [0, 1, 2].map(|r| (0..6).map(|i| w[r][i] * x[i]).sum());
            if let Some(ex) = &self.exact {
                // C_e ζ_e = 2 K_e ζ_e − 2 m_e × ζ_e.
                let EdgeCurvature { k, m } = ex.edges[e];
                let kz = matvec(&k, zeta);
                let mz = cross(m, zeta);
                zeta = [0, 1, 2].map(|c| 2.0 * kz[c] - 2.0 * mz[c]);
            }
            for (f, s) in [(fl, -1.0), (fr, 1.0)] {
                let rf = rec.face_red[f as usize];
                if rf != NONE {
                    for c in 0..3 {
                        self.dual[(rf as usize, c)] += s * zeta[c];
                    }
                }
            }
        }
        self.solve_frames(rec)?;
        // 3–4. δd per half-edge, assembled like g's right-hand side.
        self.vert.fill(0.0);
        for (f, tri) in topo.faces.iter().enumerate() {
            let rf = rec.face_red[f];
            let om: V3 = if rf == NONE {
                [0.0; 3]
            } else {
                [0, 1, 2].map(|c| self.dual[(rf as usize, c)])
            };
            let fe = topo.face_edges[f];
            let dlf = [0, 1, 2].map(|k| dl[fe[k] as usize]);
            let jq = &self.local_jac[f];
            let dq: V3 = [0, 1, 2].map(|r| (0..3).map(|k| jq[r][k] * dlf[k]).sum());
            let [l01, cx, h] = self.local[f];
            let r = &self.frames[f];
            let d01 = matvec(r, [l01, 0.0, 0.0]);
            let d02 = matvec(r, [cx, h, 0.0]);
            let dd01 = crate::geom::add(cross(om, d01), matvec(r, [dq[0], 0.0, 0.0]));
            let dd02 = crate::geom::add(cross(om, d02), matvec(r, [dq[1], dq[2], 0.0]));
            let dd12 = sub(dd02, dd01);
            for (v, d, s) in [
                (tri[1], dd01, 1.0),
                (tri[0], dd01, -1.0),
                (tri[2], dd12, 1.0),
                (tri[1], dd12, -1.0),
                (tri[0], dd02, -1.0),
                (tri[2], dd02, 1.0),
            ] {
                let rv = rec.vert_red[v as usize];
                if rv != NONE {
                    for c in 0..3 {
                        self.vert[(rv as usize, c)] += s * d[c];
                    }
                }
            }
        }
        if rec.n_vert_red > 0 {
            rec.vert_factor
                .solve_in_place(self.vert.as_mut(), &mut self.vert_scratch);
        }
        for (v, o) in out.iter_mut().enumerate() {
            let rv = rec.vert_red[v];
            *o = if rv == NONE {
                [0.0; 3]
            } else {
                [0, 1, 2].map(|c| self.vert[(rv as usize, c)])
            };
        }
        Ok(())
    }

    /// `(δℓ̄, δφ̄) = J_gᵀ u` (#V → #E, #E, written to `dl`, `dphi`): the gradient of `⟨u, x⟩`
    /// with respect to the target lengths and angles. Components of `u` on gauge vertices
    /// have no effect (g fixes them).
    ///
    /// # Errors
    /// [`MeshError::Mismatch`] on a size mismatch.
    pub fn apply_transpose(
        &mut self,
        rec: &Reconstructor,
        u: &[V3],
        dl: &mut [f64],
        dphi: &mut [f64],
    ) -> Result<()> {
        self.check(rec, dl.len().min(dphi.len()), u.len())?;
        let topo = &rec.topo;
        dl.fill(0.0);
        dphi.fill(0.0);
        // 5ᵀ. a = L_v⁻¹ u.
        self.vert.fill(0.0);
        for (v, x) in u.iter().enumerate() {
            let rv = rec.vert_red[v];
            if rv != NONE {
                for c in 0..3 {
                    self.vert[(rv as usize, c)] = x[c];
                }
            }
        }
        if rec.n_vert_red > 0 {
            rec.vert_factor
                .solve_in_place(self.vert.as_mut(), &mut self.vert_scratch);
        }
        let a_of = |v: u32, m: &Mat<f64>| -> V3 {
            let rv = rec.vert_red[v as usize];
            if rv == NONE {
                [0.0; 3]
            } else {
                [0, 1, 2].map(|c| m[(rv as usize, c)])
            }
        };
        // 4ᵀ, 3ᵀ. ω̄ per face (into `dual`) and δℓ̄ through the local coordinates.
        self.dual.fill(0.0);
        for (f, tri) in topo.faces.iter().enumerate() {
            let (a0, a1, a2) = (
                a_of(tri[0], &self.vert),
                a_of(tri[1], &self.vert),
                a_of(tri[2], &self.vert),
            );
            let g01 = [0, 1, 2].map(|c| 2.0 * a1[c] - a0[c] - a2[c]);
            let g02 = [0, 1, 2].map(|c| 2.0 * a2[c] - a1[c] - a0[c]);
            let [l01, cx, h] = self.local[f];
            let r = &self.frames[f];
            let d01 = matvec(r, [l01, 0.0, 0.0]);
            let d02 = matvec(r, [cx, h, 0.0]);
            let rf = rec.face_red[f];
            if rf != NONE {
                let om = crate::geom::add(cross(d01, g01), cross(d02, g02));
                for c in 0..3 {
                    self.dual[(rf as usize, c)] = om[c];
                }
            }
            let l1 = matvec_t(r, g01);
            let l2 = matvec_t(r, g02);
            let dq = [l1[0], l2[0], l2[1]];
            let jq = &self.local_jac[f];
            let fe = topo.face_edges[f];
            for k in 0..3 {
                dl[fe[k] as usize] += (0..3).map(|rr| jq[rr][k] * dq[rr]).sum::<f64>();
            }
        }
        // 2ᵀ. b = L⁻¹ ω̄ (exact: H⁻¹ ω̄); ζ̄_e = b_fR − b_fL (exact: C_eᵀ (b_fR − b_fL));
        // 1ᵀ. (δℓ̄_5, δφ̄_e) += W_eᵀ ζ̄_e.
        self.solve_frames(rec)?;
        let b_of = |f: u32, m: &Mat<f64>| -> V3 {
            let rf = rec.face_red[f as usize];
            if rf == NONE {
                [0.0; 3]
            } else {
                [0, 1, 2].map(|c| m[(rf as usize, c)])
            }
        };
        for e in 0..topo.n_edges() {
            let [fl, fr] = topo.edge_faces[e];
            if fr == NONE {
                continue;
            }
            let mut zb = sub(b_of(fr, &self.dual), b_of(fl, &self.dual));
            if let Some(ex) = &self.exact {
                let EdgeCurvature { k, m } = ex.edges[e];
                let kz = matvec(&k, zb);
                let mz = cross(m, zb);
                zb = [0, 1, 2].map(|c| 2.0 * kz[c] + 2.0 * mz[c]);
            }
            let w = &self.conn_jac[e];
            let ids = self.conn_edges[e];
            for i in 0..6 {
                let g = (0..3).map(|r| w[r][i] * zb[r]).sum::<f64>();
                if i < 5 {
                    dl[ids[i] as usize] += g;
                } else {
                    dphi[e] += g;
                }
            }
        }
        Ok(())
    }
}

impl GLinearization {
    /// Conjugate-gradient iterations of the last exact frame solve (0 in Gauss–Newton mode).
    pub fn last_iterations(&self) -> usize {
        self.exact.as_ref().map_or(0, |e| e.iterations)
    }

    /// The frame step in place on `dual` (#reduced faces × 3): `L⁻¹ ·` (Gauss–Newton) or
    /// `H⁻¹ ·` by conjugate gradients preconditioned with `(4L)⁻¹` (exact).
    fn solve_frames(&mut self, rec: &Reconstructor) -> Result<()> {
        if rec.n_face_red == 0 {
            return Ok(());
        }
        let Some(ex) = self.exact.as_mut() else {
            rec.dual_factor
                .solve_in_place(self.dual.as_mut(), &mut self.dual_scratch);
            return Ok(());
        };
        ex.iterations = ex.pcg.solve(
            rec,
            &ex.edges,
            &mut self.dual,
            &mut self.dual_scratch,
            super::hessian::PCG_TOLERANCE,
        )?;
        Ok(())
    }
}
