//! The step of one Levenberg–Marquardt iteration: the sparse Cholesky step, the PCG step and the
//! quasi-definite system of dense supports (docs/design/shell-fit.md §3.3–3.6).

use super::*;

/// Point-to-point constraints `W_k |Γ_k x − t̄_k|²` on registered supports Γ_k that couple many
/// vertices (keypoint regressors of a few hundred vertices). Their block `Γᵀ W Γ` would add a
/// dense clique per support to JᵀJ; instead each step solves the equivalent quasi-definite
/// system (a regularised KKT system; eliminating s gives back `(H + Γᵀ W Γ) δ = −g`)
///
/// ```text
/// [ JᵀJ + μD   Γᵀ    ] [δ]   [ −(g − Γᵀ W (Γx − t̄)) ]
/// [ Γ         −W⁻¹   ] [s] = [ −(Γx − t̄)            ]
/// ```
///
/// whose pattern adds only one row per support coordinate, and whose `L D Lᵀ` exists for any
/// ordering (quasi-definiteness, μ > 0).
pub(super) struct DenseSupports {
    /// Per support: merged `(vertex, b)` pairs, sorted by vertex.
    pub(super) rows: Vec<Vec<(u32, f64)>>,
    /// The rows of each support as given (a constraint matches when its rows are equal).
    pub(super) given: Vec<Vec<(u32, f64)>>,
    /// (first vertex, length) of the given rows → candidate supports.
    pub(super) index: std::collections::HashMap<(u32, usize), Vec<usize>>,
    /// Pattern of the quasi-definite matrix (lower CSC, size 3|V| + 3K).
    pub(super) pattern: SymbolicSparseColMat<usize>,
    pub(super) values: Vec<f64>,
    /// Per support and member: the value offsets of the couplings (s_{k,c}, x_{m,c}), c = 0..3.
    pub(super) coupling_slots: Vec<Vec<[u32; 3]>>,
    /// Per support: the value offsets of the three diagonal entries of s_k.
    pub(super) diag_slots: Vec<[u32; 3]>,
    pub(super) factor: SpdFactor,
    pub(super) factor_scratch: Option<(bool, MemBuffer)>,
    pub(super) solve_scratch: MemBuffer,
    pub(super) rhs: Vec<f64>,
    /// Per support, from the last linearisation: total weight W_k and offset Γ_k x − t̄_k.
    pub(super) weight: Vec<f64>,
    pub(super) offset: Vec<V3>,
}

impl ShellSolver {
    /// Solves `(JᵀJ + μD) δ = −g` for the last linearisation by a numeric refactorization with
    /// the symbolic analysis from [`ShellSolver::new`] (docs/design/shell-fit.md §3.3). `delta` has length
    /// 3|V|. Fails if the damped matrix is not numerically positive definite.
    pub fn step(&mut self, mu: f64, parallel: bool, delta: &mut [f64]) -> Result<()> {
        assert!(self.linearized && delta.len() == self.n);
        let cp = self.pattern.col_ptr();
        self.damped.copy_from_slice(&self.jtj);
        for c in 0..self.n {
            self.damped[cp[c]] += mu * self.diag_scale[c];
        }
        if let Some(ds) = &mut self.dense {
            return ds.step(&self.pattern, &self.damped, &self.grad, parallel, delta);
        }
        let factor = self
            .factor
            .as_mut()
            .expect("analysed when there are no dense supports");
        let a = SparseColMatRef::new(self.pattern.as_ref(), &self.damped);
        factor.refactor_cached(a, parallel, &mut self.factor_scratch)?;
        for (d, g) in delta.iter_mut().zip(&self.grad) {
            *d = -g;
        }
        let n = self.n;
        factor.solve_in_place(
            MatMut::from_column_major_slice_mut(delta, n, 1),
            &mut self.solve_scratch,
        );
        Ok(())
    }

    /// Solves `(JᵀJ + μD) δ = −g` for the last linearisation inexactly by preconditioned
    /// conjugate gradients ([`PcgOptions`]; block-Jacobi preconditioner of the damped
    /// matrix's 3×3 vertex blocks, the dense supports' diagonal `W b_m² I` included; the
    /// supports' couplings enter through the product of [`ShellSolver::normal_matrix_mul`]).
    /// `None` when the tolerance is not reached within the cap or a block is not positive
    /// definite (then `delta` is unspecified; use [`ShellSolver::step`]).
    pub fn step_pcg(
        &mut self,
        mu: f64,
        opts: &PcgOptions,
        delta: &mut [f64],
    ) -> Option<PcgOutcome> {
        assert!(self.linearized && delta.len() == self.n);
        let mut ws = std::mem::take(&mut self.pcg);
        let out = self.pcg_iterate(mu, opts, delta, &mut ws);
        self.pcg = ws;
        out
    }

    /// The body of [`ShellSolver::step_pcg`] with its buffers passed in.
    pub(super) fn pcg_iterate(
        &self,
        mu: f64,
        opts: &PcgOptions,
        delta: &mut [f64],
        ws: &mut PcgScratch,
    ) -> Option<PcgOutcome> {
        let n = self.n;
        let cp = self.pattern.col_ptr();
        ws.resize(n);
        let PcgScratch {
            inv,
            r,
            z,
            p,
            q,
            parts,
        } = ws;
        // Per vertex: the damped 3×3 diagonal block (stored first in its three columns),
        // inverted in place below.
        for (v, b) in inv.iter_mut().enumerate() {
            for c in 0..3 {
                let base = cp[3 * v + c] - c;
                for row in c..3 {
                    b[row][c] = self.jtj[base + row];
                    b[c][row] = self.jtj[base + row];
                }
            }
        }
        if let Some(ds) = &self.dense {
            for (k, rows) in ds.rows.iter().enumerate() {
                let w = ds.weight[k];
                if w <= 0.0 {
                    continue;
                }
                for &(v, bm) in rows {
                    for c in 0..3 {
                        inv[v as usize][c][c] += w * bm * bm;
                    }
                }
            }
        }
        for (v, b) in inv.iter_mut().enumerate() {
            for c in 0..3 {
                b[c][c] += mu * self.diag_scale[3 * v + c];
            }
            *b = sym3_inverse(b)?;
        }
        let inv = &*inv;
        let diag = &self.diag_scale;
        // The vector work runs over fixed chunks of `PCG_CHUNK` vertices in parallel, fused
        // where the data allow; dot products are summed per chunk and then in chunk order, so
        // the iterates do not depend on the thread count.
        let ordered_sum = |parts: Vec<f64>| parts.iter().sum::<f64>();
        // z = M⁻¹ r, returning rᵀz.
        let precond = |r: &[f64], z: &mut [f64]| -> f64 {
            ordered_sum(
                chunks(z)
                    .zip(r.par_chunks(3 * PCG_CHUNK))
                    .zip(inv.par_chunks(PCG_CHUNK))
                    .map(|((z, r), inv)| {
                        let mut rz = 0.0;
                        for ((z, r), m) in z.chunks_exact_mut(3).zip(r.chunks_exact(3)).zip(inv) {
                            for c in 0..3 {
                                z[c] = m[c][0] * r[0] + m[c][1] * r[1] + m[c][2] * r[2];
                                rz += r[c] * z[c];
                            }
                        }
                        rz
                    })
                    .collect(),
            )
        };
        for (ri, g) in r.iter_mut().zip(&self.grad) {
            *ri = -g;
        }
        let g_norm = r.iter().map(|x| x * x).sum::<f64>().sqrt();
        delta.fill(0.0);
        if g_norm == 0.0 {
            return Some(PcgOutcome {
                iterations: 0,
                residual_dot_step: 0.0,
            });
        }
        let mut rz = precond(r, z);
        p.copy_from_slice(z);
        for it in 1..=opts.max_iterations {
            self.normal_matrix_mul_into(p, q, parts);
            // q += μ D p, returning pᵀq.
            let pq = ordered_sum(
                chunks(q)
                    .zip(p.par_chunks(3 * PCG_CHUNK))
                    .zip(diag.par_chunks(3 * PCG_CHUNK))
                    .map(|((q, p), d)| {
                        let mut s = 0.0;
                        for ((q, p), d) in q.iter_mut().zip(p).zip(d) {
                            *q += mu * d * p;
                            s += p * *q;
                        }
                        s
                    })
                    .collect(),
            );
            // Not positive (or NaN): not a descent direction of an SPD system.
            if pq.is_nan() || pq <= 0.0 {
                return None;
            }
            let alpha = rz / pq;
            // δ += α p, r −= α q, returning |r|².
            let rr = ordered_sum(
                chunks(delta)
                    .zip(r.par_chunks_mut(3 * PCG_CHUNK))
                    .zip(p.par_chunks(3 * PCG_CHUNK))
                    .zip(q.par_chunks(3 * PCG_CHUNK))
                    .map(|(((d, r), p), q)| {
                        let mut s = 0.0;
                        for (((d, r), p), q) in d.iter_mut().zip(r.iter_mut()).zip(p).zip(q) {
                            *d += alpha * p;
                            *r -= alpha * q;
                            s += *r * *r;
                        }
                        s
                    })
                    .collect(),
            );
            let r_norm = rr.sqrt();
            if !r_norm.is_finite() {
                return None;
            }
            if r_norm <= opts.rel_tol * g_norm {
                let residual_dot_step = r.iter().zip(delta.iter()).map(|(a, b)| a * b).sum();
                return Some(PcgOutcome {
                    iterations: it,
                    residual_dot_step,
                });
            }
            let rz_new = precond(r, z);
            let beta = rz_new / rz;
            rz = rz_new;
            chunks(p)
                .zip(z.par_chunks(3 * PCG_CHUNK))
                .for_each(|(p, z)| {
                    for (p, z) in p.iter_mut().zip(z) {
                        *p = z + beta * *p;
                    }
                });
        }
        None
    }
}

impl DenseSupports {
    pub(super) fn new(solver: &ShellSolver, given: &[Vec<(u32, f64)>]) -> Result<Self> {
        let nv = solver.topo.n_vertices;
        let n = solver.n;
        let mut index: std::collections::HashMap<(u32, usize), Vec<usize>> =
            std::collections::HashMap::new();
        let mut rows = Vec::with_capacity(given.len());
        for (k, g) in given.iter().enumerate() {
            if g.is_empty() || g.iter().any(|&(v, b)| v as usize >= nv || !b.is_finite()) {
                return Err(MeshError::Mismatch(format!(
                    "dense support {k}: empty, out-of-range vertex or non-finite coefficient"
                )));
            }
            index.entry((g[0].0, g.len())).or_default().push(k);
            let mut m: Vec<(u32, f64)> = g.clone();
            m.sort_by_key(|r| r.0);
            let mut merged: Vec<(u32, f64)> = Vec::with_capacity(m.len());
            for (v, b) in m {
                match merged.last_mut() {
                    Some(last) if last.0 == v => last.1 += b,
                    _ => merged.push((v, b)),
                }
            }
            rows.push(merged);
        }
        let nk = rows.len();
        // Supports containing each vertex, ascending, with the member index.
        let mut of_vertex: Vec<Vec<(usize, usize)>> = vec![Vec::new(); nv];
        for (k, r) in rows.iter().enumerate() {
            for (mi, &(v, _)) in r.iter().enumerate() {
                of_vertex[v as usize].push((k, mi));
            }
        }
        let (cp, ri) = (solver.pattern.col_ptr(), solver.pattern.row_idx());
        let nk3 = n + 3 * nk;
        let mut col_ptr = vec![0usize; nk3 + 1];
        let mut row_idx =
            Vec::with_capacity(ri.len() + 3 * rows.iter().map(Vec::len).sum::<usize>() + 3 * nk);
        let mut coupling_slots: Vec<Vec<[u32; 3]>> =
            rows.iter().map(|r| vec![[0u32; 3]; r.len()]).collect();
        for j in 0..n {
            row_idx.extend_from_slice(&ri[cp[j]..cp[j + 1]]);
            let (v, c) = (j / 3, j % 3);
            for &(k, mi) in &of_vertex[v] {
                coupling_slots[k][mi][c] = row_idx.len() as u32;
                row_idx.push(n + 3 * k + c);
            }
            col_ptr[j + 1] = row_idx.len();
        }
        let mut diag_slots = vec![[0u32; 3]; nk];
        for (k, d) in diag_slots.iter_mut().enumerate() {
            for c in 0..3 {
                d[c] = row_idx.len() as u32;
                row_idx.push(n + 3 * k + c);
                col_ptr[n + 3 * k + c + 1] = row_idx.len();
            }
        }
        if row_idx.len() >= u32::MAX as usize {
            return Err(MeshError::Numerical(
                "quasi-definite pattern too large for the slot map".into(),
            ));
        }
        let values = vec![0.0; row_idx.len()];
        let pattern = SymbolicSparseColMat::new_checked(nk3, nk3, col_ptr, None, row_idx);
        let factor = SpdFactor::symbolic_only_quasi_definite(pattern.as_ref())?;
        let solve_scratch = factor.make_scratch(1);
        Ok(Self {
            rows,
            index,
            given: given.to_vec(),
            pattern,
            values,
            coupling_slots,
            diag_slots,
            factor,
            factor_scratch: None,
            solve_scratch,
            rhs: vec![0.0; nk3],
            weight: vec![0.0; nk],
            offset: vec![[0.0; 3]; nk],
        })
    }

    /// The support whose registered rows equal `pc.rows` (same vertices in the same order,
    /// same coefficients; point-to-point only). No allocation.
    pub(super) fn lookup(&self, pc: &PointConstraint) -> Option<usize> {
        if pc.normal.is_some() || pc.rows.is_empty() {
            return None;
        }
        self.index
            .get(&(pc.rows[0].0, pc.rows.len()))?
            .iter()
            .copied()
            .find(|&k| self.given[k] == pc.rows)
    }

    /// Assembles `[JᵀJ + μD, Γᵀ; Γ, −W⁻¹]` from the damped values, factors it and solves for
    /// δ (see the type docs). A support without constraints this time is decoupled (Γ = 0,
    /// diagonal −1).
    pub(super) fn step(
        &mut self,
        pattern: &SymbolicSparseColMat<usize>,
        damped: &[f64],
        grad: &[f64],
        parallel: bool,
        delta: &mut [f64],
    ) -> Result<()> {
        let n = grad.len();
        let (cp, kcp) = (pattern.col_ptr(), self.pattern.col_ptr());
        for j in 0..n {
            let len = cp[j + 1] - cp[j];
            self.values[kcp[j]..kcp[j] + len].copy_from_slice(&damped[cp[j]..cp[j + 1]]);
        }
        for (d, g) in self.rhs[..n].iter_mut().zip(grad) {
            *d = -g;
        }
        for (k, rows) in self.rows.iter().enumerate() {
            let w = self.weight[k];
            let active = w > 0.0;
            for (mi, &(v, b)) in rows.iter().enumerate() {
                for c in 0..3 {
                    self.values[self.coupling_slots[k][mi][c] as usize] =
                        if active { b } else { 0.0 };
                    if active {
                        // −(g − Γᵀ W (Γx − t̄)).
                        self.rhs[3 * v as usize + c] += w * b * self.offset[k][c];
                    }
                }
            }
            for c in 0..3 {
                self.values[self.diag_slots[k][c] as usize] = if active { -1.0 / w } else { -1.0 };
                self.rhs[n + 3 * k + c] = if active { -self.offset[k][c] } else { 0.0 };
            }
        }
        let a = SparseColMatRef::new(self.pattern.as_ref(), &self.values);
        self.factor
            .refactor_cached(a, parallel, &mut self.factor_scratch)?;
        let m = self.rhs.len();
        self.factor.solve_in_place(
            MatMut::from_column_major_slice_mut(&mut self.rhs, m, 1),
            &mut self.solve_scratch,
        );
        if self.rhs.iter().any(|x| !x.is_finite()) {
            return Err(MeshError::Numerical(
                "quasi-definite solve produced a non-finite step".into(),
            ));
        }
        delta.copy_from_slice(&self.rhs[..n]);
        Ok(())
    }
}

/// What [`ShellSolver::step_pcg`] did: conjugate-gradient iterations and `δᵀρ` with ρ the
/// final residual `−g − (JᵀJ + μD)δ` (the inexact step's correction to the predicted decrease).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PcgOutcome {
    /// Conjugate-gradient iterations (matrix–vector products).
    pub iterations: usize,
    /// `δᵀρ`.
    pub residual_dot_step: f64,
}

/// Buffers of [`ShellSolver::step_pcg`]: the inverted 3×3 vertex blocks of the
/// preconditioner and the CG vectors (residual r, preconditioned z, direction p, product q).
#[derive(Clone, Debug, Default)]
pub(super) struct PcgScratch {
    pub(super) inv: Vec<[[f64; 3]; 3]>,
    pub(super) r: Vec<f64>,
    pub(super) z: Vec<f64>,
    pub(super) p: Vec<f64>,
    pub(super) q: Vec<f64>,
    /// Buffers of the normal-matrix product's parts 1.. ([`PRODUCT_PARTS`]).
    pub(super) parts: Vec<Vec<f64>>,
}

impl PcgScratch {
    /// Sizes the buffers for `n` unknowns (n/3 vertices); the blocks are zeroed.
    pub(super) fn resize(&mut self, n: usize) {
        self.inv.clear();
        self.inv.resize(n / 3, [[0.0; 3]; 3]);
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.resize(n, 0.0);
        }
    }
}

/// Inverse of a symmetric 3×3 matrix by its adjugate; `None` unless positive definite
/// (leading minors > 0).
/// `v` in the PCG's fixed chunks ([`PCG_CHUNK`] vertices).
pub(super) fn chunks(v: &mut [f64]) -> rayon::slice::ChunksMut<'_, f64> {
    v.par_chunks_mut(3 * PCG_CHUNK)
}

pub(super) fn sym3_inverse(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c00 = m[1][1] * m[2][2] - m[1][2] * m[2][1];
    let c01 = m[1][2] * m[2][0] - m[1][0] * m[2][2];
    let c02 = m[1][0] * m[2][1] - m[1][1] * m[2][0];
    let det = m[0][0] * c00 + m[0][1] * c01 + m[0][2] * c02;
    let minor2 = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    if !(m[0][0] > 0.0 && minor2 > 0.0 && det > 0.0 && det.is_finite()) {
        return None;
    }
    let c11 = m[0][0] * m[2][2] - m[0][2] * m[2][0];
    let c12 = m[0][1] * m[2][0] - m[0][0] * m[2][1];
    let c22 = minor2;
    let d = 1.0 / det;
    Some([
        [c00 * d, c01 * d, c02 * d],
        [c01 * d, c11 * d, c12 * d],
        [c02 * d, c12 * d, c22 * d],
    ])
}
