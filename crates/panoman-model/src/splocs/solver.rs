//! The alternating solver of the decomposition ([`fit`], [`fit_col_major`]).

use super::kernels::{
    cholesky, cholesky_inverse, dot_chunked, fit_from_p, gram_of_cols, gram_of_rows, penalties,
    wt_x, x_ct, xt_vec,
};
use super::*;

pub(super) struct Solver<'a, D: ColumnDistances> {
    pub(super) n: usize,
    pub(super) m: usize,
    pub(super) k: usize,
    pub(super) opts: &'a SplocsOptions,
    pub(super) dists: &'a D,
    /// Centred, scaled data, N×M column-major.
    pub(super) x: Vec<f32>,
    /// ‖X[:,e]‖².
    pub(super) col_sq: Vec<f64>,
    pub(super) x_sq: f64,
    /// N×K.
    pub(super) w: Vec<f64>,
    /// K×M: components, ADMM Z and U, F = WᵀX, two scratch arrays, Λ.
    pub(super) c: Vec<f64>,
    pub(super) z: Vec<f64>,
    pub(super) u: Vec<f64>,
    pub(super) f: Vec<f64>,
    pub(super) t: Vec<f64>,
    pub(super) s: Vec<f64>,
    pub(super) lam: Vec<f64>,
    /// K×M row-major (component k's distance map at k·M).
    pub(super) dist: Vec<f64>,
    /// P = X·Cᵀ (N×K), G = C·Cᵀ, A0 = WᵀW (K×K), penalties per component.
    pub(super) p: Vec<f64>,
    pub(super) g: Vec<f64>,
    pub(super) a0: Vec<f64>,
    pub(super) pen: Vec<f64>,
    pub(super) centre: Vec<usize>,
    pub(super) radius: Vec<f64>,
    pub(super) buf: Vec<f64>,
}

impl<'a, D: ColumnDistances> Solver<'a, D> {
    /// The solver over the centred and scaled column-major data `x` (N×M) with every
    /// component, weight and dual variable zero and the supports at their smallest radius.
    fn new(x: Vec<f32>, n: usize, m: usize, opts: &'a SplocsOptions, dists: &'a D) -> Self {
        let k = opts.n_components;
        let col_sq: Vec<f64> = x
            .par_chunks(n)
            .map(|col| col.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
            .collect();
        let x_sq: f64 = col_sq.chunks(1024).map(|c| c.iter().sum::<f64>()).sum();

        let km = k * m;
        Solver {
            n,
            m,
            k,
            opts,
            dists,
            x,
            col_sq,
            x_sq,
            w: vec![0.0; n * k],
            c: vec![0.0; km],
            z: vec![0.0; km],
            u: vec![0.0; km],
            f: vec![0.0; km],
            t: vec![0.0; km],
            s: vec![0.0; km],
            lam: vec![opts.lambda; km],
            dist: vec![f64::INFINITY; km],
            p: vec![0.0; n * k],
            g: vec![0.0; k * k],
            a0: vec![0.0; k * k],
            pen: vec![0.0; k],
            centre: vec![0; k],
            radius: vec![opts.d_min_bounds[0]; k],
            buf: Vec::new(),
        }
    }

    pub(super) fn d_max(&self, kk: usize) -> f64 {
        self.opts.d_max_ratio * self.radius[kk]
    }

    /// Distance cap of the cached maps: the largest possible d_max.
    pub(super) fn dist_cap(&self) -> f64 {
        self.opts.d_max_ratio * self.opts.d_min_bounds[1]
    }

    pub(super) fn ramp(d: f64, dmin: f64, dmax: f64) -> f64 {
        if d.is_nan() {
            1.0
        } else {
            ((d - dmin) / (dmax - dmin)).clamp(0.0, 1.0)
        }
    }

    /// Rewrites row k of Λ from the distance map and radius of component k.
    pub(super) fn write_lambda_row(&mut self, kk: usize) {
        let (dmin, dmax) = (self.radius[kk], self.d_max(kk));
        let (k, m, lam) = (self.k, self.m, self.opts.lambda);
        let row = &self.dist[kk * m..(kk + 1) * m];
        for (e, &d) in row.iter().enumerate() {
            self.lam[e * k + kk] = lam * Self::ramp(d, dmin, dmax);
        }
    }

    pub(super) fn recompute_pen(&mut self) {
        self.pen = penalties(&self.lam, &self.c, self.k);
    }

    pub(super) fn recompute_a0(&mut self) {
        self.a0 = gram_of_cols(&self.w, self.n, self.k);
    }

    /// Objective entering a W update: P, G, A0 and pen must be current.
    pub(super) fn objective_from_p(&self) -> (f64, f64) {
        let fit = fit_from_p(self.x_sq, &self.w, &self.p, &self.a0, &self.g);
        (fit, fit + self.pen.iter().sum::<f64>())
    }

    /// Residual column energies ‖X_e − W·C_e‖² = ‖X_e‖² − 2F_eᵀC_e + C_eᵀA0C_e (docs/design/splocs-model.md §3.5),
    /// with F = WᵀX and A0 = WᵀW current. Uses `t` as scratch.
    pub(super) fn residual_energies(&mut self) -> Vec<f64> {
        let (k, m) = (self.k, self.m);
        let a0v = MatRef::from_column_major_slice(&self.a0, k, k);
        matmul(
            MatMut::from_column_major_slice_mut(&mut self.t, k, m),
            Accum::Replace,
            a0v,
            MatRef::from_column_major_slice(&self.c, k, m),
            1.0,
            Par::rayon(0),
        );
        let (c, f, t, col_sq) = (&self.c, &self.f, &self.t, &self.col_sq);
        let mut en = vec![0.0f64; m];
        en.par_chunks_mut(COL_CHUNK)
            .enumerate()
            .for_each(|(ci, ec)| {
                for (jj, o) in ec.iter_mut().enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    let r = e * k..(e + 1) * k;
                    let mut s = col_sq[e];
                    for ((&cv, &fv), &tv) in c[r.clone()].iter().zip(&f[r.clone()]).zip(&t[r]) {
                        s += cv * (tv - 2.0 * fv);
                    }
                    *o = s.max(0.0);
                }
            });
        en
    }

    /// Smallest radius r (geometric grid over the d_min bounds, ratio 1.1) at which the mean
    /// |corr| between the seed column and the columns at distance ≈ r drops below the
    /// threshold (docs/design/splocs-model.md §3.4); `hi` if it never does.
    pub(super) fn initial_radius(&self, dist_row: &[f64], corr: &[f64]) -> f64 {
        let [lo, hi] = self.opts.d_min_bounds;
        if hi <= lo {
            return lo;
        }
        let gamma: f64 = 1.1;
        let ln_g = gamma.ln();
        let nb = ((hi / lo).ln() / ln_g).floor() as usize + 1;
        let mut sum = vec![0.0f64; nb];
        let mut cnt = vec![0usize; nb];
        for (&d, &c) in dist_row.iter().zip(corr) {
            if d.is_nan() || d <= 0.0 || !d.is_finite() || c.is_nan() {
                continue;
            }
            let b = ((d / lo).ln() / ln_g).round();
            if b < 0.0 || b >= nb as f64 {
                continue;
            }
            sum[b as usize] += c.abs();
            cnt[b as usize] += 1;
        }
        for b in 0..nb {
            if cnt[b] > 0 && sum[b] / (cnt[b] as f64) < self.opts.init_corr_threshold {
                return (lo * gamma.powi(b as i32)).min(hi);
            }
        }
        hi
    }

    /// Greedy seeding of component `kk` at the max-residual column (docs/design/splocs-model.md §3.5): w = the residual
    /// column, normalized (docs/design/splocs-model.md §3.6); c = (wᵀR ⊙ (1 − support)) / (wᵀw). Row kk of W, C, U must
    /// be zero. Updates `en` (residual column energies) incrementally. False if the residual
    /// is zero.
    pub(super) fn seed(&mut self, kk: usize, en: &mut [f64], ws: &mut D::Workspace) -> bool {
        let (n, m, k) = (self.n, self.m, self.k);
        // argmax, ties to the lowest index.
        let mut idx = 0;
        for (e, &v) in en.iter().enumerate() {
            if v > en[idx] {
                idx = e;
            }
        }
        if en[idx].is_nan() || en[idx] <= 1e-300 {
            return false;
        }
        // r = X_idx − W·C_idx.
        let mut r: Vec<f64> = self.x[idx * n..(idx + 1) * n]
            .iter()
            .map(|&v| v as f64)
            .collect();
        for j in 0..k {
            let cj = self.c[idx * k + j];
            if cj != 0.0 {
                for (ri, &wi) in r.iter_mut().zip(&self.w[j * n..(j + 1) * n]) {
                    *ri -= cj * wi;
                }
            }
        }
        let r_sq: f64 = r.iter().map(|v| v * v).sum();
        if r_sq.is_nan() || r_sq <= 1e-300 {
            return false;
        }
        // g_e = R_eᵀ r = (Xᵀr)_e − C_eᵀ(Wᵀr).
        let mut g = vec![0.0f64; m];
        let wr = self.wt_vec(&r);
        xt_vec(&self.x, n, &r, &mut g);
        self.sub_ct_vec(&wr, &mut g);

        // Distances from the seed, initial radius from correlations (docs/design/splocs-model.md §3.4).
        let cap = self.dist_cap();
        {
            let row = &mut self.dist[kk * m..(kk + 1) * m];
            self.dists.distances_from(idx, cap, ws, row);
        }
        let corr: Vec<f64> = g
            .iter()
            .zip(en.iter())
            .map(|(&gv, &ev)| {
                if ev > 1e-300 {
                    gv / (r_sq * ev).sqrt()
                } else {
                    f64::NAN
                }
            })
            .collect();
        let r0 = self.initial_radius(&self.dist[kk * m..(kk + 1) * m], &corr);
        self.radius[kk] = r0;
        self.centre[kk] = idx;
        self.write_lambda_row(kk);

        // Normalized weight column and wᵀR.
        let (w, gw) = match self.opts.weight_norm {
            WeightNorm::MaxAbs => {
                let mx = r.iter().fold(0.0f64, |a, &v| a.max(v.abs()));
                let w: Vec<f64> = r.iter().map(|&v| v / mx).collect();
                let gw: Vec<f64> = g.iter().map(|&v| v / mx).collect();
                (w, gw)
            }
            WeightNorm::NonNegMax => {
                let pmax = r.iter().fold(0.0f64, |a, &v| a.max(v));
                let nmax = r.iter().fold(0.0f64, |a, &v| a.max(-v));
                let sgn = if nmax > pmax { -1.0 } else { 1.0 };
                let mx = pmax.max(nmax);
                let w: Vec<f64> = r.iter().map(|&v| (sgn * v).max(0.0) / mx).collect();
                let wr = self.wt_vec(&w);
                let mut gw = vec![0.0f64; m];
                xt_vec(&self.x, n, &w, &mut gw);
                self.sub_ct_vec(&wr, &mut gw);
                (w, gw)
            }
        };
        let ww: f64 = w.iter().map(|v| v * v).sum();
        if ww.is_nan() || ww <= 0.0 {
            return false;
        }
        let (dmin, dmax) = (self.radius[kk], self.d_max(kk));
        for e in 0..m {
            let mask = 1.0 - Self::ramp(self.dist[kk * m + e], dmin, dmax);
            let ce = gw[e] * mask / ww;
            self.c[e * k + kk] = ce;
            self.u[e * k + kk] = 0.0;
            en[e] = (en[e] - 2.0 * ce * gw[e] + ce * ce * ww).max(0.0);
        }
        self.w[kk * n..(kk + 1) * n].copy_from_slice(&w);
        true
    }

    /// Wᵀv (length K).
    pub(super) fn wt_vec(&self, v: &[f64]) -> Vec<f64> {
        let n = self.n;
        (0..self.k)
            .map(|j| {
                self.w[j * n..(j + 1) * n]
                    .iter()
                    .zip(v)
                    .map(|(a, b)| a * b)
                    .sum()
            })
            .collect()
    }

    /// out_e −= C_eᵀ·v for every column e.
    pub(super) fn sub_ct_vec(&self, v: &[f64], out: &mut [f64]) {
        let k = self.k;
        let c = &self.c;
        out.par_chunks_mut(COL_CHUNK)
            .enumerate()
            .for_each(|(ci, oc)| {
                for (jj, o) in oc.iter_mut().enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    let s: f64 = c[e * k..(e + 1) * k]
                        .iter()
                        .zip(v)
                        .map(|(a, b)| a * b)
                        .sum();
                    *o -= s;
                }
            });
    }

    /// Scales row k of C and U by `scale[k]` (after a weight normalization, docs/design/splocs-model.md §3.6).
    pub(super) fn rescale_rows(&mut self, scale: &[f64]) {
        let k = self.k;
        let f = |arr: &mut Vec<f64>| {
            arr.par_chunks_mut(COL_CHUNK * k).for_each(|ch| {
                for col in ch.chunks_exact_mut(k) {
                    for (v, &s) in col.iter_mut().zip(scale) {
                        *v *= s;
                    }
                }
            })
        };
        f(&mut self.c);
        f(&mut self.u);
    }

    /// Component update by ADMM (docs/design/splocs-model.md §3.7), safeguarded: the result replaces C only if it does not
    /// increase the objective. Requires A0 = WᵀW current; computes F = WᵀX. Returns
    /// (objective, fit, rejected).
    pub(super) fn c_step(&mut self, obj_before: f64) -> Result<(f64, f64, bool)> {
        let (n, m, k) = (self.n, self.m, self.k);
        let rho = self.opts.rho;
        wt_x(&self.x, n, m, &self.w, k, &mut self.f, &mut self.buf);
        let mut a = self.a0.clone();
        for i in 0..k {
            a[i * k + i] += rho;
        }
        let l = cholesky(&a, k).map_err(|i| {
            ModelError::Numerical(format!(
                "splocs: WᵀW + ρI is not positive definite (pivot {i})"
            ))
        })?;
        let ainv = cholesky_inverse(&l, k);
        let ainv = MatRef::from_column_major_slice(&ainv, k, k);
        self.z.copy_from_slice(&self.c);
        let cs = COL_CHUNK * k;
        let inv_rho = 1.0 / rho;
        // T = F + ρ(Z − U)
        {
            let (f, z, u) = (&self.f, &self.z, &self.u);
            self.t.par_chunks_mut(cs).enumerate().for_each(|(ci, tc)| {
                let o = ci * cs;
                for (i, tv) in tc.iter_mut().enumerate() {
                    *tv = f[o + i] + rho * (z[o + i] - u[o + i]);
                }
            });
        }
        for _ in 0..self.opts.admm_iters {
            // S = (WᵀW + ρI)⁻¹ T
            matmul(
                MatMut::from_column_major_slice_mut(&mut self.s, k, m),
                Accum::Replace,
                ainv,
                MatRef::from_column_major_slice(&self.t, k, m),
                1.0,
                Par::rayon(0),
            );
            // Z = soft(S + U, Λ/ρ), U = U + S − Z, and the next T = F + ρ(Z − U), fused.
            {
                let (s, lam, f) = (&self.s, &self.lam, &self.f);
                self.z
                    .par_chunks_mut(cs)
                    .zip(self.u.par_chunks_mut(cs))
                    .zip(self.t.par_chunks_mut(cs))
                    .enumerate()
                    .for_each(|(ci, ((zc, uc), tc))| {
                        let o = ci * cs;
                        for (i, ((zv, uv), tv)) in zc
                            .iter_mut()
                            .zip(uc.iter_mut())
                            .zip(tc.iter_mut())
                            .enumerate()
                        {
                            let v = s[o + i] + *uv;
                            let zz = soft_threshold(v, lam[o + i] * inv_rho);
                            let un = v - zz;
                            *zv = zz;
                            *uv = un;
                            *tv = f[o + i] + rho * (zz - un);
                        }
                    });
            }
        }
        // Candidate C = Z (exactly sparse).
        let g_new = gram_of_rows(&self.z, k, m);
        let fz = dot_chunked(&self.f, &self.z);
        let ag: f64 = self.a0.iter().zip(&g_new).map(|(a, b)| a * b).sum();
        let fit_new = 0.5 * self.x_sq - fz + 0.5 * ag;
        let pen_new = penalties(&self.lam, &self.z, k);
        let obj_new = fit_new + pen_new.iter().sum::<f64>();
        if obj_new <= obj_before {
            std::mem::swap(&mut self.c, &mut self.z);
            self.g = g_new;
            self.pen = pen_new;
            Ok((obj_new, fit_new, false))
        } else {
            let fit_old = obj_before - self.pen.iter().sum::<f64>();
            Ok((obj_before, fit_old, true))
        }
    }

    /// Adaptive supports (docs/design/splocs-model.md §3.4): radius growth/shrink from the energy distribution of C_k, and
    /// centre moves with hysteresis. Returns the number of components that changed.
    pub(super) fn update_supports(&mut self, ws_pool: &mut Vec<D::Workspace>) -> usize {
        let (m, k) = (self.m, self.k);
        let o = self.opts;
        let [lo, hi] = o.d_min_bounds;
        struct Change {
            kk: usize,
            centre: usize,
            radius: f64,
            moved: bool,
        }
        let c = &self.c;
        let dist = &self.dist;
        let centre = &self.centre;
        let radius = &self.radius;
        let changes: Vec<Change> = (0..k)
            .into_par_iter()
            .filter_map(|kk| {
                let row = &dist[kk * m..(kk + 1) * m];
                let (dmin, dmax) = (radius[kk], o.d_max_ratio * radius[kk]);
                let (mut tot, mut far, mut near) = (0.0f64, 0.0f64, 0.0f64);
                let mut best = 0usize;
                let mut best_v = -1.0f64;
                for (e, &d) in row.iter().enumerate() {
                    let v = c[e * k + kk];
                    let v2 = v * v;
                    tot += v2;
                    if d.is_nan() || d > 0.8 * dmax {
                        far += v2;
                    } else if d <= 0.5 * dmin {
                        near += v2;
                    }
                    if v.abs() > best_v {
                        best_v = v.abs();
                        best = e;
                    }
                }
                if tot.is_nan() || tot <= o.dead_tol {
                    return None;
                }
                let mut r = radius[kk];
                if far > o.far_fraction * tot {
                    r *= o.grow_factor;
                } else if near >= o.near_fraction * tot {
                    r *= o.shrink_factor;
                }
                let r = r.clamp(lo, hi);
                let old_v = c[centre[kk] * k + kk].abs();
                let moved = best != centre[kk] && best_v > (1.0 + o.centre_hysteresis) * old_v;
                if moved || r != radius[kk] {
                    Some(Change {
                        kk,
                        centre: if moved { best } else { centre[kk] },
                        radius: r,
                        moved,
                    })
                } else {
                    None
                }
            })
            .collect();
        if changes.is_empty() {
            return 0;
        }
        // Recompute the distance maps of moved components (parallel, one workspace per task).
        let cap = self.dist_cap();
        let moved: Vec<(usize, usize)> = changes
            .iter()
            .filter(|ch| ch.moved)
            .map(|ch| (ch.kk, ch.centre))
            .collect();
        if !moved.is_empty() {
            let dists = self.dists;
            let mut rows: Vec<(usize, &mut [f64])> = self
                .dist
                .chunks_mut(m)
                .enumerate()
                .filter(|(kk, _)| moved.iter().any(|&(mk, _)| mk == *kk))
                .collect();
            while ws_pool.len() < rayon::current_num_threads().max(1) {
                ws_pool.push(dists.new_workspace());
            }
            let per = rows.len().div_ceil(ws_pool.len());
            rows.par_chunks_mut(per)
                .zip(ws_pool.par_iter_mut())
                .for_each(|(group, ws)| {
                    for (kk, row) in group.iter_mut() {
                        let ctr = moved.iter().find(|&&(mk, _)| mk == *kk).unwrap().1;
                        dists.distances_from(ctr, cap, ws, row);
                    }
                });
        }
        for ch in &changes {
            self.centre[ch.kk] = ch.centre;
            self.radius[ch.kk] = ch.radius;
        }
        // Λ rows of the changed components, written in one pass over the columns.
        let lam_v = o.lambda;
        let rows: Vec<(usize, f64, f64)> = changes
            .iter()
            .map(|ch| (ch.kk, ch.radius, o.d_max_ratio * ch.radius))
            .collect();
        let dist = &self.dist;
        self.lam
            .par_chunks_mut(COL_CHUNK * k)
            .enumerate()
            .for_each(|(ci, lc)| {
                for (jj, col) in lc.chunks_exact_mut(k).enumerate() {
                    let e = ci * COL_CHUNK + jj;
                    for &(kk, dmin, dmax) in &rows {
                        col[kk] = lam_v * Self::ramp(dist[kk * m + e], dmin, dmax);
                    }
                }
            });
        changes.len()
    }

    /// Re-seeds dead components (‖C_k‖² ≤ dead_tol) at the max-residual column (docs/design/splocs-model.md §3.8).
    /// Requires F = WᵀX and A0 = WᵀW current. Returns how many were re-seeded.
    pub(super) fn reseed_dead(&mut self, ws: &mut D::Workspace) -> usize {
        let (n, k) = (self.n, self.k);
        let dead: Vec<usize> = (0..k)
            .filter(|&kk| {
                self.g[kk * k + kk] <= self.opts.dead_tol
                    || self.w[kk * n..(kk + 1) * n].iter().all(|&v| v == 0.0)
            })
            .collect();
        if dead.is_empty() {
            return 0;
        }
        for &kk in &dead {
            self.w[kk * n..(kk + 1) * n].fill(0.0);
            for e in 0..self.m {
                self.c[e * k + kk] = 0.0;
                self.u[e * k + kk] = 0.0;
            }
        }
        let mut en = self.residual_energies();
        let mut count = 0;
        for &kk in &dead {
            if self.seed(kk, &mut en, ws) {
                count += 1;
            }
        }
        count
    }
}

/// Sparse localized decomposition of `x` (N×M, rows = samples, columns = part edges), docs/design/splocs-model.md §3.
/// Copies X; see [`fit_col_major`] to hand over a buffer instead.
pub fn fit<D: ColumnDistances>(
    x: MatRef<'_, f32>,
    dists: &D,
    opts: &SplocsOptions,
) -> Result<Decomposition> {
    let (n, m) = (x.nrows(), x.ncols());
    let mut data = Vec::with_capacity(n * m);
    for j in 0..m {
        data.extend(x.col(j).iter().copied());
    }
    fit_col_major(data, n, dists, opts, |_| {})
}

/// Sparse localized decomposition (docs/design/splocs-model.md §3.1–3.8) of the N×M data given column-major in `x`
/// (`x[j·N + i]` = sample i, column j), consumed to avoid a copy. `progress` is called after
/// every outer iteration.
///
/// Steps: centre and scale (docs/design/splocs-model.md §3.2); greedy initialization without the residual (docs/design/splocs-model.md §3.5); then
/// per outer iteration: weight update by BCD with the Gram trick and normalization (docs/design/splocs-model.md §3.6),
/// component update by ADMM (docs/design/splocs-model.md §3.7), residual-free objective (docs/design/splocs-model.md §3.8), support adaptation (docs/design/splocs-model.md §3.4)
/// and re-seeding of dead components (docs/design/splocs-model.md §3.8), until the relative decrease is below `rel_tol`
/// or `max_outer_iters`. Finally C ← C/s, stored sparse.
///
/// Deterministic: no random choice is made (the greedy seeds are argmaxes, ties to the lowest
/// index), and all reductions use fixed chunks, so the same input gives bit-identical output
/// for any number of rayon threads. There is therefore no `seed` option.
///
/// Errors: sizes (N < 2, M = 0, `x.len() != N·M`, distance provider with another M), invalid
/// options, non-finite or constant data, or a failed factorization.
pub fn fit_col_major<D: ColumnDistances>(
    mut x: Vec<f32>,
    n: usize,
    dists: &D,
    opts: &SplocsOptions,
    mut progress: impl FnMut(&IterationRecord),
) -> Result<Decomposition> {
    let t_total = Instant::now();
    let m = check_data(&x, n, dists, opts)?;
    let k = opts.n_components;

    // docs/design/splocs-model.md §3.2: centre and scale.
    let (mean, sf) = centre_and_scale(&mut x, n, m)?;
    let scale = sf as f64;
    let mut sv = Solver::new(x, n, m, opts, dists);

    // docs/design/splocs-model.md §3.5: greedy initialization.
    let t_init = Instant::now();
    let mut ws = dists.new_workspace();
    let mut en = sv.col_sq.clone();
    for kk in 0..k {
        sv.seed(kk, &mut en, &mut ws);
    }
    let init_seconds = t_init.elapsed().as_secs_f64();

    let mut ws_pool = vec![ws];
    let mut history = Vec::new();
    // Invariants entering an iteration: P = X·Cᵀ, G = C·Cᵀ, pen current.
    sv.g = gram_of_rows(&sv.c, k, m);
    x_ct(&sv.x, n, m, &sv.c, k, &mut sv.p, &mut sv.buf);
    sv.recompute_pen();
    sv.recompute_a0();
    let mut obj_start = sv.objective_from_p().1;

    for it in 0..opts.max_outer_iters {
        let t_it = Instant::now();
        // docs/design/splocs-model.md §3.6 weight update.
        let step = update_weights_gram(
            &mut sv.w,
            &mut sv.p,
            &mut sv.g,
            n,
            k,
            opts.weight_norm,
            opts.monotone_weights.then_some(&sv.pen[..]),
            opts.dead_tol,
        );
        sv.rescale_rows(&step.scale);
        for (pk, &s) in sv.pen.iter_mut().zip(&step.scale) {
            *pk *= s;
        }
        sv.recompute_a0();
        let obj_w = sv.objective_from_p().1;
        // docs/design/splocs-model.md §3.7 component update.
        let (obj, fit_v, rejected) = sv.c_step(obj_w)?;
        let rel = (obj_start - obj) / obj_start.abs().max(f64::MIN_POSITIVE);
        // docs/design/splocs-model.md §3.4 supports and docs/design/splocs-model.md §3.8 dead components.
        let adapt = it < opts.adapt_until && it + 1 < opts.max_outer_iters;
        let support_changes = if adapt && opts.adapt_supports {
            sv.update_supports(&mut ws_pool)
        } else {
            0
        };
        let reseeded = if adapt {
            sv.reseed_dead(&mut ws_pool[0])
        } else {
            0
        };
        let rec = IterationRecord {
            iteration: it,
            objective_start: obj_start,
            objective_after_weights: obj_w,
            objective: obj,
            fit: fit_v,
            penalty: obj - fit_v,
            relative_decrease: rel,
            weight_safeguards: step.safeguarded,
            admm_rejected: rejected,
            support_changes,
            reseeded,
            seconds: 0.0,
        };
        let changed = support_changes > 0 || reseeded > 0;
        let done = (rel < opts.rel_tol && !changed) || it + 1 == opts.max_outer_iters;
        if reseeded > 0 {
            sv.g = gram_of_rows(&sv.c, k, m);
        }
        if changed {
            sv.recompute_pen();
        }
        if !done {
            x_ct(&sv.x, n, m, &sv.c, k, &mut sv.p, &mut sv.buf);
            if changed {
                sv.recompute_a0();
                obj_start = sv.objective_from_p().1;
            } else {
                obj_start = obj;
            }
        }
        let rec = IterationRecord {
            seconds: t_it.elapsed().as_secs_f64(),
            ..rec
        };
        progress(&rec);
        history.push(rec);
        if done {
            break;
        }
    }
    // Final fit ½‖X − WC‖²: the last record's (W and C unchanged since); without iterations,
    // from the Gram formulas.
    let fit_final = match history.last() {
        Some(r) => r.fit,
        None => sv.objective_from_p().0,
    };
    let a0 = gram_of_cols(&sv.w, n, k);
    let explained_variance = 1.0 - 2.0 * fit_final / sv.x_sq;
    let component_energy: Vec<f64> = (0..k)
        .map(|kk| a0[kk * k + kk] * sv.g[kk * k + kk] / sv.x_sq)
        .collect();

    // Output: C / s as sparse rows, W as f32.
    let components = sparse_rows(&sv.c, k, m, 1.0 / scale);
    let weights = Mat::<f32>::from_fn(n, k, |i, j| sv.w[j * n + i] as f32);
    Ok(Decomposition {
        mean,
        scale,
        weights,
        components,
        centres: sv.centre.iter().map(|&c| c as u32).collect(),
        radii: (0..k)
            .map(|kk| [sv.radius[kk], opts.d_max_ratio * sv.radius[kk]])
            .collect(),
        history,
        explained_variance,
        component_energy,
        init_seconds,
        total_seconds: t_total.elapsed().as_secs_f64(),
    })
}

/// Checks the sizes, options and values of [`fit_col_major`]'s input; returns M.
fn check_data<D: ColumnDistances>(
    x: &[f32],
    n: usize,
    dists: &D,
    opts: &SplocsOptions,
) -> Result<usize> {
    opts.validate()?;
    if n < 2 {
        return Err(ModelError::Invalid(
            "splocs: need at least 2 samples".into(),
        ));
    }
    if x.is_empty() || !x.len().is_multiple_of(n) {
        return Err(ModelError::Invalid(format!(
            "splocs: data length {} is not a positive multiple of N = {n}",
            x.len()
        )));
    }
    let m = x.len() / n;
    if dists.n_columns() != m {
        return Err(ModelError::Invalid(format!(
            "splocs: the distance provider has {} columns, the data {m}",
            dists.n_columns()
        )));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Invalid(
            "splocs: non-finite value in the data".into(),
        ));
    }
    Ok(m)
}

/// Centres each column of the column-major N×M `x` and scales all by `s = 1/std` (rounded to
/// f32 first, so that the stored scale is exactly the one applied); returns the column means
/// and `s`. Fails on constant data.
fn centre_and_scale(x: &mut [f32], n: usize, m: usize) -> Result<(Vec<f32>, f32)> {
    let mean: Vec<f32> = x
        .par_chunks(n)
        .map(|col| (col.iter().map(|&v| v as f64).sum::<f64>() / n as f64) as f32)
        .collect();
    x.par_chunks_mut(n).zip(&mean).for_each(|(col, &mu)| {
        for v in col.iter_mut() {
            *v -= mu;
        }
    });
    let ss: f64 = x
        .par_chunks(n * 16)
        .map(|ch| ch.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    let std = (ss / (n * m) as f64).sqrt();
    if std.is_nan() || std <= 0.0 {
        return Err(ModelError::Invalid("splocs: the data are constant".into()));
    }
    // s rounded to f32 first, so that the stored scale is exactly the one applied to X.
    let sf = (1.0 / std) as f32;
    x.par_chunks_mut(1 << 16).for_each(|ch| {
        for v in ch {
            *v *= sf;
        }
    });
    Ok((mean, sf))
}

/// The K×M row-major components `c` (`c[e·K + k]`) times `inv_s` as sparse f32 rows.
fn sparse_rows(c: &[f64], k: usize, m: usize, inv_s: f64) -> SparseRows {
    let mut row_ptr = Vec::with_capacity(k + 1);
    let mut col_idx = Vec::new();
    let mut values = Vec::new();
    row_ptr.push(0);
    for kk in 0..k {
        for e in 0..m {
            let v = c[e * k + kk];
            if v != 0.0 {
                col_idx.push(e as u32);
                values.push((v * inv_s) as f32);
            }
        }
        row_ptr.push(values.len());
    }
    SparseRows {
        n_cols: m,
        row_ptr,
        col_idx,
        values,
    }
}
