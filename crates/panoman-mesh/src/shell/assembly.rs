//! Residuals, Jacobian rows and the assembly of `g = Jᵀr` and JᵀJ through the scatter map
//! (docs/design/shell-fit.md §3.2–3.3).

use super::*;

/// Residuals and Jacobian rows of one edge: the stretch row on (x_i, x_j) and the bend row on
/// (x_i, x_j, x_k, x_l) (zero on boundary edges and skipped diamonds).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct EdgeRows {
    pub(super) r_len: f64,
    pub(super) r_ang: f64,
    pub(super) j_len: [V3; 2],
    pub(super) j_ang: [V3; 4],
    pub(super) has_ang: bool,
    pub(super) skipped: bool,
}

impl ShellSolver {
    /// The energy E(x) of the module docs (parallel over fixed edge chunks, so the sum is
    /// deterministic).
    pub fn energy(&mut self, targets: &ShellTargets, x: &[V3]) -> Result<f64> {
        self.check_inputs(targets, x)?;
        self.ensure_buffers();
        Ok(energy_of(&self.topo, targets, x, &mut self.chunk_sums))
    }

    /// Evaluates the residuals and Jacobian rows at `x` and assembles `g = Jᵀr` and the lower
    /// triangle of JᵀJ into the fixed pattern through the scatter map (docs/design/shell-fit.md §3.2–3.3);
    /// returns E(x) = |r|². Near-degenerate bend rows (height < `degenerate_height·ℓ̄`) are left
    /// out of J. Fails if the assembly produced a non-finite value.
    pub fn linearize(
        &mut self,
        targets: &ShellTargets,
        x: &[V3],
        degenerate_height: f64,
    ) -> Result<f64> {
        self.check_inputs(targets, x)?;
        self.ensure_buffers();
        self.linearize_unchecked(targets, x, degenerate_height)
    }

    pub(super) fn linearize_unchecked(
        &mut self,
        targets: &ShellTargets,
        x: &[V3],
        degenerate_height: f64,
    ) -> Result<f64> {
        let topo = &self.topo;
        let h_min = degenerate_height * targets.mean_length();
        self.rows
            .par_chunks_mut(EDGE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                let base = c * EDGE_CHUNK;
                for (off, row) in chunk.iter_mut().enumerate() {
                    *row = edge_rows(topo, targets, x, base + off, h_min);
                }
            });
        // Assembly (docs/design/shell-fit.md §3.5.1): the vertices are split in two fixed halves;
        // an edge whose diamond lies in one half writes only entries of that half (every
        // stored entry lies in the columns of its block's smaller vertex), so the two halves'
        // edges scatter in parallel into disjoint slices, each in edge order; then the edges
        // that straddle the halves (3.6 % on the full template) in edge order. The sums do not
        // depend on the thread count.
        let col_ptr = self.pattern.col_ptr();
        let rows = &self.rows;
        let slots = &self.slots;
        let half = self.split_vertex;
        let (v_lo, v_hi) = self.jtj.split_at_mut(col_ptr[3 * half]);
        let (g_lo, g_hi) = self.grad.split_at_mut(3 * half);
        let [e_lo, e_hi] = &self.half_edges;
        rayon::join(
            || {
                v_lo.fill(0.0);
                g_lo.fill(0.0);
                scatter_edges(topo, rows, slots, col_ptr, e_lo, v_lo, g_lo, 0);
            },
            || {
                v_hi.fill(0.0);
                g_hi.fill(0.0);
                scatter_edges(topo, rows, slots, col_ptr, e_hi, v_hi, g_hi, half);
            },
        );
        scatter_edges(
            topo,
            rows,
            slots,
            col_ptr,
            &self.straddling_edges,
            &mut self.jtj,
            &mut self.grad,
            0,
        );
        let vals = &mut self.jtj;
        let grad = &mut self.grad;
        // Energy and skipped rows in edge order (sequential: a deterministic sum).
        let mut energy = 0.0;
        let mut skipped = 0;
        for row in rows.iter() {
            energy += row.r_len * row.r_len;
            skipped += row.skipped as usize;
            if row.has_ang {
                energy += row.r_ang * row.r_ang;
            }
        }
        for h in &targets.handles {
            let v = h.vertex as usize;
            let d = sub(x[v], h.position);
            energy += h.weight * dot(d, d);
            for c in 0..3 {
                vals[col_ptr[3 * v + c]] += h.weight;
                grad[3 * v + c] += h.weight * d[c];
            }
        }
        self.assemble_points(targets, x, &mut energy)?;
        let (vals, grad) = (&self.jtj, &self.grad);
        if !energy.is_finite()
            || grad.par_iter().any(|g| !g.is_finite())
            || vals.par_iter().any(|g| !g.is_finite())
        {
            return Err(MeshError::NonFinite(
                "shell solver: non-finite value after assembling JᵀJ and Jᵀr".into(),
            ));
        }
        self.marquardt_scaling(x);
        self.skipped = skipped;
        self.linearized = true;
        Ok(energy)
    }

    /// Adds the point constraints' energy (to `energy`, in constraint order), gradient and
    /// JᵀJ blocks; a dense support's share goes to its gradient and the sums of
    /// [`DenseSupports`] instead. Fails on a pair of vertices the pattern does not couple.
    fn assemble_points(
        &mut self,
        targets: &ShellTargets,
        x: &[V3],
        energy: &mut f64,
    ) -> Result<()> {
        let col_ptr = self.pattern.col_ptr();
        let vals = &mut self.jtj;
        let grad = &mut self.grad;
        if let Some(ds) = &mut self.dense {
            ds.weight.fill(0.0);
            ds.offset.fill([0.0; 3]);
        }
        let mut point_slots = std::mem::take(&mut self.point_slots);
        for (k, pc) in targets.points.iter().enumerate() {
            *energy += pc.energy(x);
            let d = pc.offset(x);
            if let Some(ds) = &mut self.dense
                && let Some(kd) = ds.lookup(pc)
            {
                // Kept out of JᵀJ: gradient here, the rest in `step` (DenseSupports).
                for &(vm, bm) in &pc.rows {
                    axpy(grad, vm as usize, d, pc.weight * bm);
                }
                ds.weight[kd] += pc.weight;
                // Accumulates Σ w_i t_i; turned into Γx − t̄ below.
                for c in 0..3 {
                    ds.offset[kd][c] += pc.weight * pc.target[c];
                }
                continue;
            }
            // Block A (I or n̂n̂ᵀ) and A·d.
            let (a, ad) = match pc.normal {
                Some(nn) => {
                    let s = dot(nn, d);
                    (
                        Some([0, 1, 2].map(|r| [0, 1, 2].map(|c| nn[r] * nn[c]))),
                        scale(nn, s),
                    )
                }
                None => (None, d),
            };
            // The pattern positions of the off-diagonal pairs (searched once per constraint
            // and kept while its vertex list is the same: keypoint rows repeat every frame).
            if point_slots.len() <= k {
                point_slots.resize_with(k + 1, PointSlots::default);
            }
            let ps = &mut point_slots[k];
            if !ps.verts.iter().copied().eq(pc.rows.iter().map(|r| r.0)) {
                ps.verts = pc.rows.iter().map(|r| r.0).collect();
                ps.q.clear();
                for (p, &(vm, _)) in pc.rows.iter().enumerate() {
                    for &(vn, _) in &pc.rows[..=p] {
                        if vm != vn {
                            let (lo, hi) = (vm.min(vn), vm.max(vn));
                            let q = self.pairs
                                [self.nb_off[lo as usize]..self.nb_off[lo as usize + 1]]
                                .binary_search(&(lo, hi))
                                .map_err(|_| {
                                    ps.verts.clear();
                                    MeshError::Mismatch(format!(
                                        "point constraint {k}: vertices {lo} and {hi} are not coupled in the solver's pattern (build it with ShellSolver::with_extra_pairs)"
                                    ))
                                })?;
                            ps.q.push(q as u32);
                        }
                    }
                }
            }
            let mut slots = ps.q.iter();
            for (p, &(vm, bm)) in pc.rows.iter().enumerate() {
                axpy(grad, vm as usize, ad, pc.weight * bm);
                for (q, &(vn, bn)) in pc.rows[..=p].iter().enumerate() {
                    // A vertex listed twice meets itself as (p, q) and (q, p).
                    let twice = if vm == vn && q != p { 2.0 } else { 1.0 };
                    let f = twice * pc.weight * bm * bn;
                    // The block f·A; for A = I only its diagonal (the zeros add nothing).
                    let base = if vm == vn {
                        let m = vm as usize;
                        [0, 1, 2].map(|c| col_ptr[3 * m + c] - c)
                    } else {
                        let lo = vm.min(vn) as usize;
                        let q = *slots.next().expect("a slot per pair") as usize;
                        [0, 1, 2].map(|c| col_ptr[3 * lo + c] + (3 - c) + 3 * q)
                    };
                    let rows_from = |c: usize| if vm == vn { c } else { 0 };
                    match &a {
                        Some(a) => {
                            for c in 0..3 {
                                for r in rows_from(c)..3 {
                                    vals[base[c] + r] += f * a[r][c];
                                }
                            }
                        }
                        None => {
                            for c in 0..3 {
                                vals[base[c] + c] += f;
                            }
                        }
                    }
                }
            }
        }
        self.point_slots = point_slots;
        Ok(())
    }

    /// The Marquardt scaling `D = max(diag JᵀJ, 1e−8·max diag)` (+ an absolute floor) of the
    /// assembled system, with the dense supports' diagonal `W b_m²` included as if they were
    /// assembled; the dense supports' target sums become the offsets `Γx − t̄`.
    pub(super) fn marquardt_scaling(&mut self, x: &[V3]) {
        let col_ptr = self.pattern.col_ptr();
        for c in 0..self.n {
            self.diag_scale[c] = self.jtj[col_ptr[c]];
        }
        if let Some(ds) = &mut self.dense {
            for (k, rows) in ds.rows.iter().enumerate() {
                let w = ds.weight[k];
                if w <= 0.0 {
                    continue;
                }
                let mut p = [0.0; 3];
                for &(v, b) in rows {
                    for c in 0..3 {
                        p[c] += b * x[v as usize][c];
                        self.diag_scale[3 * v as usize + c] += w * b * b;
                    }
                }
                let tsum = ds.offset[k];
                ds.offset[k] = [0, 1, 2].map(|c| p[c] - tsum[c] / w);
            }
        }
        let max_diag = self.diag_scale.iter().fold(0.0f64, |m, &d| m.max(d));
        let floor = 1e-8 * max_diag + f64::MIN_POSITIVE;
        for d in self.diag_scale.iter_mut() {
            *d = d.max(floor);
        }
    }

    /// `g = Jᵀr` from the last [`ShellSolver::linearize`] (`∇E = 2g`), length 3|V|, vertex-major.
    pub fn gradient(&self) -> &[f64] {
        assert!(self.linearized, "no current linearisation");
        &self.grad
    }

    /// `out = JᵀJ·v` with the assembled matrix of the last linearisation (symmetric product
    /// from the stored lower triangle). The vertex blocks are split into
    /// [`PRODUCT_PARTS`] fixed ranges, multiplied in parallel into separate buffers and summed
    /// in order, so the result does not depend on the thread count.
    pub fn normal_matrix_mul(&self, v: &[f64], out: &mut [f64]) {
        let mut parts = Vec::new();
        self.normal_matrix_mul_into(v, out, &mut parts);
    }

    /// [`ShellSolver::normal_matrix_mul`] with the buffers of parts 1.. in `parts` (resized).
    pub(super) fn normal_matrix_mul_into(
        &self,
        v: &[f64],
        out: &mut [f64],
        parts: &mut Vec<Vec<f64>>,
    ) {
        assert!(v.len() == self.n && out.len() == self.n && self.linearized);
        let nb = self.n / 3;
        parts.resize_with(PRODUCT_PARTS - 1, Vec::new);
        let mut bufs: Vec<&mut [f64]> = Vec::with_capacity(PRODUCT_PARTS);
        bufs.push(out);
        for p in parts.iter_mut() {
            p.resize(self.n, 0.0);
            bufs.push(p);
        }
        bufs.par_iter_mut().enumerate().for_each(|(part, buf)| {
            buf.fill(0.0);
            let range = part * nb / PRODUCT_PARTS..(part + 1) * nb / PRODUCT_PARTS;
            self.lower_product(v, buf, range);
        });
        let (out, rest) = bufs.split_first_mut().expect("PRODUCT_PARTS >= 1");
        out.par_chunks_mut(4096).enumerate().for_each(|(c, o)| {
            let base = c * 4096;
            for p in rest.iter() {
                for (x, y) in o.iter_mut().zip(&p[base..]) {
                    *x += y;
                }
            }
        });
        let out: &mut [f64] = out;
        if let Some(ds) = &self.dense {
            for (k, rows) in ds.rows.iter().enumerate() {
                let w = ds.weight[k];
                let mut p = [0.0; 3];
                for &(u, b) in rows {
                    for c in 0..3 {
                        p[c] += b * v[3 * u as usize + c];
                    }
                }
                for &(u, b) in rows {
                    for c in 0..3 {
                        out[3 * u as usize + c] += w * b * p[c];
                    }
                }
            }
        }
    }

    /// The contribution of vertex blocks `range` (columns) of the stored lower triangle to
    /// `out += JᵀJ·v` (both triangles).
    pub(super) fn lower_product(&self, v: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
        let cp = self.pattern.col_ptr();
        let vals = &self.jtj;
        // By 3×3 vertex blocks (the pattern's layout, `build`): column 3b+c holds the lower
        // diagonal block from row 3b+c on, then 3 rows per upper neighbour a > b.
        for b in range {
            let vb = [v[3 * b], v[3 * b + 1], v[3 * b + 2]];
            let base = [cp[3 * b], cp[3 * b + 1], cp[3 * b + 2]];
            let d = [
                [vals[base[0]], vals[base[0] + 1], vals[base[0] + 2]],
                [vals[base[0] + 1], vals[base[1]], vals[base[1] + 1]],
                [vals[base[0] + 2], vals[base[1] + 1], vals[base[2]]],
            ];
            let mut yb = [0.0; 3];
            for r in 0..3 {
                yb[r] = d[r][0] * vb[0] + d[r][1] * vb[1] + d[r][2] * vb[2];
            }
            let nbs = &self.pairs[self.nb_off[b]..self.nb_off[b + 1]];
            let deg = nbs.len();
            // The off-diagonal blocks of column c: 3 rows per neighbour, contiguous.
            let cols = [
                &vals[base[0] + 3..base[0] + 3 + 3 * deg],
                &vals[base[1] + 2..base[1] + 2 + 3 * deg],
                &vals[base[2] + 1..base[2] + 1 + 3 * deg],
            ];
            for (q, &(_, a)) in nbs.iter().enumerate() {
                let a = 3 * a as usize;
                let va: [f64; 3] = v[a..a + 3].try_into().expect("3 entries");
                let l: [[f64; 3]; 3] =
                    cols.map(|col| col[3 * q..3 * q + 3].try_into().expect("3 entries"));
                let oa: &mut [f64; 3] = (&mut out[a..a + 3]).try_into().expect("3 entries");
                for r in 0..3 {
                    // L[r][c] = l[c][r]: row 3a+r, column 3b+c.
                    let (l0, l1, l2) = (l[0][r], l[1][r], l[2][r]);
                    oa[r] += l0 * vb[0] + l1 * vb[1] + l2 * vb[2];
                    yb[0] += l0 * va[r];
                    yb[1] += l1 * va[r];
                    yb[2] += l2 * va[r];
                }
            }
            for c in 0..3 {
                out[3 * b + c] += yb[c];
            }
        }
    }

    /// Number of residuals: #E stretch rows, #E bend rows (zero on boundary edges), 3 per handle,
    /// 3 per point constraint (a point-to-plane constraint uses the first and leaves two zeros).
    pub fn n_residuals(&self, targets: &ShellTargets) -> usize {
        2 * self.topo.n_edges() + 3 * targets.handles.len() + 3 * targets.points.len()
    }

    /// The residual vector r(x) in the layout of [`ShellSolver::n_residuals`].
    pub fn residuals_into(&self, targets: &ShellTargets, x: &[V3], out: &mut [f64]) {
        let ne = self.topo.n_edges();
        assert_eq!(out.len(), self.n_residuals(targets));
        for e in 0..ne {
            let (rl, ra) = edge_residuals(&self.topo, targets, x, e);
            out[e] = rl;
            out[ne + e] = ra;
        }
        for (h, hd) in targets.handles.iter().enumerate() {
            let d = sub(x[hd.vertex as usize], hd.position);
            for c in 0..3 {
                out[2 * ne + 3 * h + c] = hd.weight.sqrt() * d[c];
            }
        }
        let base = 2 * ne + 3 * targets.handles.len();
        for (k, pc) in targets.points.iter().enumerate() {
            let d = pc.offset(x);
            let r = point_rows(pc, d);
            out[base + 3 * k..base + 3 * k + 3].copy_from_slice(&r);
        }
    }

    /// `out = J·v` with the Jacobian rows of the last linearisation (matrix-free).
    pub fn jacobian_mul(&self, targets: &ShellTargets, v: &[f64], out: &mut [f64]) {
        assert!(self.linearized && v.len() == self.n);
        let ne = self.topo.n_edges();
        let at = |u: u32| {
            [
                v[3 * u as usize],
                v[3 * u as usize + 1],
                v[3 * u as usize + 2],
            ]
        };
        for (e, row) in self.rows.iter().enumerate() {
            let [i, j] = self.topo.edges[e];
            out[e] = dot(row.j_len[0], at(i)) + dot(row.j_len[1], at(j));
            out[ne + e] = if row.has_ang {
                let [k, l] = self.topo.edge_opposite[e];
                [i, j, k, l]
                    .iter()
                    .zip(&row.j_ang)
                    .map(|(&u, g)| dot(*g, at(u)))
                    .sum()
            } else {
                0.0
            };
        }
        for (h, hd) in targets.handles.iter().enumerate() {
            let w = hd.weight.sqrt();
            let p = at(hd.vertex);
            for c in 0..3 {
                out[2 * ne + 3 * h + c] = w * p[c];
            }
        }
        let base = 2 * ne + 3 * targets.handles.len();
        for (k, pc) in targets.points.iter().enumerate() {
            let mut jv = [0.0; 3];
            for &(u, b) in &pc.rows {
                let p = at(u);
                for c in 0..3 {
                    jv[c] += b * p[c];
                }
            }
            let r = point_rows(pc, jv);
            out[base + 3 * k..base + 3 * k + 3].copy_from_slice(&r);
        }
    }

    /// The damped matrix `JᵀJ + μD` of the last linearisation as an owned lower CSC matrix
    /// (allocates; for tests and diagnostics). Dense supports' blocks are not in it.
    pub fn damped_matrix(&self, mu: f64) -> SparseColMat<usize, f64> {
        let mut vals = self.jtj.clone();
        let cp = self.pattern.col_ptr();
        for c in 0..self.n {
            vals[cp[c]] += mu * self.diag_scale[c];
        }
        SparseColMat::new(self.pattern.clone(), vals)
    }
}

/// Stretch and bend residuals of edge `e` (bend 0 on boundary edges).
#[inline]
pub(super) fn edge_residuals(topo: &Topology, t: &ShellTargets, x: &[V3], e: usize) -> (f64, f64) {
    let (rl, ra, _) = edge_residuals_raw(topo, t, x, e);
    (rl, ra)
}

/// The weighted residuals of [`edge_residuals`] and, for an interior edge, the unweighted
/// angle residual `wrap(φ − φ*)` (the length one is the weighted one over `√w`; see
/// [`residual_rms`]).
#[inline]
pub(super) fn edge_residuals_raw(
    topo: &Topology,
    t: &ShellTargets,
    x: &[V3],
    e: usize,
) -> (f64, f64, Option<f64>) {
    let [i, j] = topo.edges[e];
    let (xi, xj) = (x[i as usize], x[j as usize]);
    let rl = t.length_weights[e].sqrt() * (norm(sub(xj, xi)) / t.lengths[e] - 1.0);
    let [k, l] = topo.edge_opposite[e];
    if l == NONE {
        return (rl, 0.0, None);
    }
    let phi = dihedral_angle(xi, xj, x[k as usize], x[l as usize]);
    let raw = wrap_angle(phi - t.angles[e]);
    let ra = if t.angle_weights[e] == 0.0 {
        0.0
    } else {
        t.angle_weights[e].sqrt() * raw
    };
    (rl, ra, Some(raw))
}

/// Per fixed edge chunk: the energy of its rows and the unweighted sums of [`residual_rms`]
/// (Σ RL², Σ RA² over interior edges, their count).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct ChunkSums {
    pub(super) energy: f64,
    pub(super) len_sq: f64,
    pub(super) ang_sq: f64,
    pub(super) n_ang: usize,
}

/// [`residual_rms`] from the chunk sums of the last [`energy_of`] (the same sums in the same
/// order: equal to it bit for bit).
pub(super) fn rms_of_chunks(chunks: &[ChunkSums], ne: usize) -> (f64, f64) {
    let (sl, sa, na) = chunks.iter().fold((0.0, 0.0, 0), |a, b| {
        (a.0 + b.len_sq, a.1 + b.ang_sq, a.2 + b.n_ang)
    });
    (
        (sl / ne.max(1) as f64).sqrt(),
        (sa / na.max(1) as f64).sqrt(),
    )
}

/// E(x), summed per fixed chunk of edges in parallel, then sequentially; the chunks also
/// keep the unweighted residual sums of [`residual_rms`].
pub(super) fn energy_of(
    topo: &Topology,
    t: &ShellTargets,
    x: &[V3],
    chunk_sums: &mut [ChunkSums],
) -> f64 {
    let ne = topo.n_edges();
    chunk_sums.par_iter_mut().enumerate().for_each(|(c, s)| {
        let mut acc = ChunkSums::default();
        for e in c * EDGE_CHUNK..((c + 1) * EDGE_CHUNK).min(ne) {
            let (rl, ra, raw) = edge_residuals_raw(topo, t, x, e);
            acc.energy += rl * rl + ra * ra;
            let [i, j] = topo.edges[e];
            let rl_raw = norm(sub(x[j as usize], x[i as usize])) / t.lengths[e] - 1.0;
            acc.len_sq += rl_raw * rl_raw;
            if let Some(a) = raw {
                acc.ang_sq += a * a;
                acc.n_ang += 1;
            }
        }
        *s = acc;
    });
    let mut energy: f64 = chunk_sums.iter().map(|c| c.energy).sum();
    for h in &t.handles {
        let d = sub(x[h.vertex as usize], h.position);
        energy += h.weight * dot(d, d);
    }
    for pc in &t.points {
        energy += pc.energy(x);
    }
    energy
}

/// Residuals and Jacobian rows of edge `e` (docs/design/rla-and-g.md §2.2 hinge gradients, scaled by the weights).
#[inline]
pub(super) fn edge_rows(
    topo: &Topology,
    t: &ShellTargets,
    x: &[V3],
    e: usize,
    h_min: f64,
) -> EdgeRows {
    let [i, j] = topo.edges[e];
    let (xi, xj) = (x[i as usize], x[j as usize]);
    let d = sub(xj, xi);
    let len = norm(d);
    let wl = t.length_weights[e].sqrt();
    let mut row = EdgeRows {
        r_len: wl * (len / t.lengths[e] - 1.0),
        ..Default::default()
    };
    if len > h_min {
        let u = scale(d, wl / (len * t.lengths[e]));
        row.j_len = [scale(u, -1.0), u];
    }
    let [k, l] = topo.edge_opposite[e];
    if l == NONE || t.angle_weights[e] == 0.0 {
        return row;
    }
    let (xk, xl) = (x[k as usize], x[l as usize]);
    let wa = t.angle_weights[e].sqrt();
    let phi = dihedral_angle(xi, xj, xk, xl);
    row.r_ang = wa * wrap_angle(phi - t.angles[e]);
    row.has_ang = true;
    // Heights of k and l over the edge: |N|/ℓ.
    let hk = norm(cross(d, sub(xk, xi))) / len;
    let hl = norm(cross(d, sub(xl, xi))) / len;
    if !(len > h_min && hk > h_min && hl > h_min) {
        row.skipped = true;
        return row;
    }
    let g = dihedral_gradient(xi, xj, xk, xl);
    row.j_ang = [
        scale(g[0], wa),
        scale(g[1], wa),
        scale(g[2], wa),
        scale(g[3], wa),
    ];
    row
}

/// The JᵀJ pattern positions of one point constraint's vertex pairs: `q[i]` is the neighbour
/// index of the i-th pair `(p, q ≤ p)` with two different vertices (in row order), for the
/// vertex list `verts`.
#[derive(Clone, Debug, Default)]
pub(super) struct PointSlots {
    pub(super) verts: Vec<u32>,
    pub(super) q: Vec<u32>,
}

/// Scatters the length and bend rows of `edges` (in their order) into `vals` and `grad`,
/// which hold the values from `col_ptr[3 v0]` and the gradient from `3 v0` on (every vertex
/// of these edges is ≥ `v0`).
#[allow(clippy::too_many_arguments)]
pub(super) fn scatter_edges(
    topo: &Topology,
    rows: &[EdgeRows],
    slots: &[[[u32; 3]; 6]],
    col_ptr: &[usize],
    edges: &[u32],
    vals: &mut [f64],
    grad: &mut [f64],
    v0: usize,
) {
    let val0 = col_ptr[3 * v0];
    for &e in edges {
        let e = e as usize;
        let row = &rows[e];
        let sl = &slots[e];
        let [i, j] = topo.edges[e];
        let vl = [i as usize, j as usize];
        for a in 0..2 {
            gather_diag(vals, col_ptr, val0, vl[a], row.j_len[a]);
            axpy(grad, vl[a] - v0, row.j_len[a], row.r_len);
        }
        gather_off(vals, val0, &sl[0], vl, 0, 1, &row.j_len);
        if row.has_ang {
            let [k, l] = topo.edge_opposite[e];
            let v4 = [i as usize, j as usize, k as usize, l as usize];
            for a in 0..4 {
                gather_diag(vals, col_ptr, val0, v4[a], row.j_ang[a]);
                axpy(grad, v4[a] - v0, row.j_ang[a], row.r_ang);
            }
            for (p, &(a, b)) in PAIRS.iter().enumerate() {
                gather_off(vals, val0, &sl[p], v4, a, b, &row.j_ang);
            }
        }
    }
}

/// Adds the diagonal block `g gᵀ` of vertex `a` (lower triangle; column 3a+c starts with row
/// 3a+c) to `vals`, which holds the values from global offset `val0` on.
#[inline]
pub(super) fn gather_diag(vals: &mut [f64], col_ptr: &[usize], val0: usize, a: usize, g: V3) {
    for c in 0..3 {
        let base = col_ptr[3 * a + c] - c - val0;
        for r in c..3 {
            vals[base + r] += g[r] * g[c];
        }
    }
}

/// Adds the off-diagonal block of the local pair (p, q) of a row with gradients `g` on vertices
/// `v` (the stored block is rows of the larger vertex, columns of the smaller) to `vals`, which
/// holds the values from global offset `val0` on.
#[inline]
pub(super) fn gather_off<const N: usize>(
    vals: &mut [f64],
    val0: usize,
    slot: &[u32; 3],
    v: [usize; N],
    p: usize,
    q: usize,
    g: &[V3; N],
) {
    let (hi, lo) = if v[p] > v[q] { (p, q) } else { (q, p) };
    for c in 0..3 {
        let s = slot[c] as usize - val0;
        let gc = g[lo][c];
        for r in 0..3 {
            vals[s + r] += g[hi][r] * gc;
        }
    }
}

/// The 3 residual rows of a point constraint for the offset (or offset direction) `d`:
/// `√w d`, or `(√w n̂ᵀd, 0, 0)` for point-to-plane.
pub(super) fn point_rows(pc: &PointConstraint, d: V3) -> [f64; 3] {
    let w = pc.weight.sqrt();
    match pc.normal {
        Some(n) => [w * dot(n, d), 0.0, 0.0],
        None => scale(d, w),
    }
}

/// `grad[3a..3a+3] += s·g`.
#[inline]
pub(super) fn axpy(grad: &mut [f64], a: usize, g: V3, s: f64) {
    for c in 0..3 {
        grad[3 * a + c] += s * g[c];
    }
}
