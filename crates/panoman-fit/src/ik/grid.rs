//! The phenotype grids: rest quantities at the 288 anchor points of the phenotype hat
//! functions, per keypoint pair ([`PhenGrid`]) and per vertex for point targets
//! ([`VertexGrid`]), with their exact multilinear interpolation.

use super::solver::{IkSolver, rel_mean};
use super::{IK_PHENOTYPE, N_UNITS};
use crate::error::Result;
use panoman_human::outputs::OutputTopology;
use panoman_human::params::ShapeParams;
use panoman_mesh::geom::{V3, sub};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;
/// Phenotype derivative of the rest quantities (one column).
#[derive(Clone, Debug)]
pub(super) struct PhenColumn {
    /// `∂X_kb/∂β_i` per pair.
    pub(super) x: Vec<V3>,
    pub(super) heads: Vec<V3>,
    pub(super) tails: Vec<V3>,
}

/// Anchors of the phenotype hat functions within `[0, 1]` ([`panoman_human::phenotype`]): gender,
/// height, proportions `{0, 1}`; age `{0, 1/3, 2/3, 1}`; muscle, weight `{0, ½, 1}`. Every
/// phenotype coefficient is a product of hat weights of distinct features, so the rest mesh
/// is multilinear in `β` inside each cell of this grid (2 × 4 × 3 × 3 × 2 × 2 = 288 points)
/// and has kinks on the interior anchors.
pub(super) const PHEN_AXES: [&[f64]; 6] = [
    &[0.0, 1.0],
    &[0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0],
    &[0.0, 0.5, 1.0],
    &[0.0, 0.5, 1.0],
    &[0.0, 1.0],
    &[0.0, 1.0],
];

/// The rest quantities `[X_kb (pairs) | heads | tails]` at every phenotype grid point
/// ([`PHEN_AXES`], row-major, last axis fastest), for one set of non-fitted shape values.
#[derive(Debug)]
pub(super) struct PhenGrid {
    pub(super) points: Vec<Vec<V3>>,
}

impl PhenGrid {
    /// Row-major strides of the grid axes.
    pub(super) fn strides() -> [usize; 6] {
        let mut st = [1usize; 6];
        for d in (0..5).rev() {
            st[d] = st[d + 1] * PHEN_AXES[d + 1].len();
        }
        st
    }

    /// Multilinear interpolation of the grid at `beta` (its derivative along axis `deriv`
    /// when given). On an interior anchor, `side[d] < 0` takes the cell below, else the cell
    /// above (the value is the same; the derivative along `d` is one-sided).
    ///
    /// In the cell `[a_k, a_{k+1}]` of axis `d` with `t_d = (β_d − a_k)/(a_{k+1} − a_k)`:
    /// `f(β) = Σ_{corners c} Π_d ℓ_d(c_d) f(c)`, `ℓ_d = t_d` (upper) or `1 − t_d` (lower); the
    /// derivative replaces the factor of `deriv` by `±1/(a_{k+1} − a_k)`.
    pub(super) fn interp(&self, beta: &[f64; 6], side: &[i8; 6], deriv: Option<usize>) -> Vec<V3> {
        let len = self.points[0].len();
        let mut out = vec![[0.0; 3]; len];
        for (idx, w) in corner_weights(beta, side, deriv) {
            for (o, p) in out.iter_mut().zip(&self.points[idx]) {
                o[0] += w * p[0];
                o[1] += w * p[1];
                o[2] += w * p[2];
            }
        }
        out
    }

    /// [`PhenGrid::interp`] of several derivatives at once, `requests[r] = (axis, side)`: the
    /// derivative along `axis` with that axis' kink side (the other axes take side +1). One
    /// pass over the grid points in parallel chunks of entries (a warm IK iteration asks for
    /// six or more), each output summed over the corners in the same order as
    /// [`PhenGrid::interp`], so the values are identical to separate calls.
    pub(super) fn interp_derivatives(
        &self,
        beta: &[f64; 6],
        requests: &[(usize, i8)],
    ) -> Vec<Vec<V3>> {
        let len = self.points[0].len();
        let weights = derivative_weights(beta, requests);
        // Entry chunks in parallel, every request per chunk (each corner's chunk is read once
        // while it is in cache); entry-major `[entry][request]`, split at the end.
        const CHUNK: usize = 128;
        let k = requests.len();
        if k == 0 {
            return Vec::new();
        }
        let mut flat = vec![[0.0; 3]; len * k];
        flat.par_chunks_mut(CHUNK * k)
            .enumerate()
            .for_each(|(chunk, out)| {
                let start = chunk * CHUNK;
                let end = start + out.len() / k;
                for (r, w) in weights.iter().enumerate() {
                    for &(idx, c) in w {
                        for (o, p) in out[r..]
                            .iter_mut()
                            .step_by(k)
                            .zip(&self.points[idx][start..end])
                        {
                            o[0] += c * p[0];
                            o[1] += c * p[1];
                            o[2] += c * p[2];
                        }
                    }
                }
            });
        let outs: Vec<Vec<V3>> = (0..k)
            .map(|r| flat.iter().skip(r).step_by(k).copied().collect())
            .collect();
        outs
    }
}

/// Number of phenotype grid points (2 × 4 × 3 × 3 × 2 × 2).
pub(super) const N_GRID: usize = 288;

/// The corner weights ([`corner_weights`]) of the derivative along `axis` for every request
/// `(axis, side)`, that axis taking the request's kink side and the others +1.
pub(super) fn derivative_weights(
    beta: &[f64; 6],
    requests: &[(usize, i8)],
) -> Vec<Vec<(usize, f64)>> {
    requests
        .iter()
        .map(|&(i, side)| {
            let mut sides = [1i8; 6];
            sides[i] = side;
            corner_weights(beta, &sides, Some(i))
        })
        .collect()
}

/// The non-zero corner weights `(grid index, weight)` of the multilinear interpolation at
/// `beta` (of its derivative along `deriv`), see [`PhenGrid::interp`].
pub(super) fn corner_weights(
    beta: &[f64; 6],
    side: &[i8; 6],
    deriv: Option<usize>,
) -> Vec<(usize, f64)> {
    let strides = PhenGrid::strides();
    let mut lo = [0usize; 6];
    let mut f = [[0.0f64; 2]; 6];
    for d in 0..6 {
        let a = PHEN_AXES[d];
        let b = beta[d].clamp(a[0], a[a.len() - 1]);
        let mut k = (0..a.len() - 1).rfind(|&k| a[k] <= b).unwrap_or(0);
        if k > 0 && b == a[k] && side[d] < 0 {
            k -= 1;
        }
        let w = a[k + 1] - a[k];
        let t = (b - a[k]) / w;
        lo[d] = k;
        f[d] = if deriv == Some(d) {
            [-1.0 / w, 1.0 / w]
        } else {
            [1.0 - t, t]
        };
    }
    let mut out = Vec::with_capacity(64);
    for corner in 0..64usize {
        let mut w = 1.0;
        let mut idx = 0;
        for d in 0..6 {
            let bit = (corner >> (5 - d)) & 1;
            w *= f[d][bit];
            idx += (lo[d] + bit) * strides[d];
        }
        if w != 0.0 {
            out.push((idx, w));
        }
    }
    out
}

/// Surface data of the point targets, per solver (built on first use): the Anny output
/// vertices a row of the solver's topology can reach ("slots"), their kept indices, and the
/// face units' displacements `B_j` at them (CSR per slot, units ascending).
#[derive(Debug)]
pub(super) struct Surface {
    pub(super) slot_of_anny: Vec<u32>,
    pub(super) kept_of_slot: Vec<u32>,
    pub(super) unit_off: Vec<u32>,
    pub(super) unit_val: Vec<(u8, V3)>,
}

/// Rest positions of every slot at every phenotype grid point ([`PHEN_AXES`]), laid out
/// `[slot][grid point]`, for one set of non-fitted shape values (face units 0).
#[derive(Debug)]
pub(super) struct VertexGrid {
    pub(super) data: Vec<V3>,
}

impl VertexGrid {
    /// [`VertexGrid::interp`] for several weight sets in one pass over the vertices (the
    /// grid reads dominate): one list per set.
    pub(super) fn interp_many(&self, verts: &[u32], sets: &[Vec<(usize, f64)>]) -> Vec<Vec<V3>> {
        let k = sets.len();
        let one = |v: &u32, out: &mut [V3]| {
            let block = &self.data[*v as usize * N_GRID..(*v as usize + 1) * N_GRID];
            for (o, w) in out.iter_mut().zip(sets) {
                let mut acc = [0.0; 3];
                for &(g, c) in w {
                    let p = block[g];
                    acc[0] += c * p[0];
                    acc[1] += c * p[1];
                    acc[2] += c * p[2];
                }
                *o = acc;
            }
        };
        let mut flat = vec![[0.0; 3]; verts.len() * k];
        if k > 0 {
            if verts.len() >= 1024 {
                flat.par_chunks_mut(k * 256)
                    .zip(verts.par_chunks(256))
                    .for_each(|(out, vs)| {
                        for (o, v) in out.chunks_mut(k).zip(vs) {
                            one(v, o);
                        }
                    });
            } else {
                for (o, v) in flat.chunks_mut(k).zip(verts) {
                    one(v, o);
                }
            }
        }
        (0..k)
            .map(|j| flat.iter().skip(j).step_by(k).copied().collect())
            .collect()
    }

    /// `Σ_c w_c x̄_v(c)` for the slots `verts` and corner weights `w` (see
    /// [`corner_weights`]).
    pub(super) fn interp(&self, verts: &[u32], w: &[(usize, f64)]) -> Vec<V3> {
        let one = |v: &u32| -> V3 {
            let block = &self.data[*v as usize * N_GRID..(*v as usize + 1) * N_GRID];
            let mut o = [0.0; 3];
            for &(g, c) in w {
                let p = block[g];
                o[0] += c * p[0];
                o[1] += c * p[1];
                o[2] += c * p[2];
            }
            o
        };
        if verts.len() >= 2048 {
            verts.par_iter().with_min_len(512).map(one).collect()
        } else {
            verts.iter().map(one).collect()
        }
    }
}

/// `template` with its face units zeroed and the six fitted phenotype values at grid point
/// `idx` ([`PHEN_AXES`], row-major).
pub(super) fn grid_shape(template: &ShapeParams, idx: usize) -> ShapeParams {
    let strides = PhenGrid::strides();
    let mut s = template.clone();
    s.facial_actions = [0.0; 52];
    for d in 0..6 {
        let k = (idx / strides[d]) % PHEN_AXES[d].len();
        if let Some(slot) = s.phenotype.get_mut(IK_PHENOTYPE[d]) {
            *slot = PHEN_AXES[d][k];
        }
    }
    s
}

/// The grid cell `[a_k, a_{k+1}]` of phenotype value `i` at `b`; on an interior anchor the
/// cell below for `side < 0`, else the cell above.
pub(super) fn phen_cell(i: usize, b: f64, side: i8) -> (f64, f64) {
    let a = PHEN_AXES[i];
    let mut k = (0..a.len() - 1).rfind(|&k| a[k] <= b).unwrap_or(0);
    if k > 0 && b == a[k] && side < 0 {
        k -= 1;
    }
    (a[k], a[k + 1])
}

/// True if phenotype value `i` sits on an interior anchor of its axis (a kink).
pub(super) fn on_kink(i: usize, b: f64) -> bool {
    let a = PHEN_AXES[i];
    a[1..a.len() - 1].contains(&b)
}

impl IkSolver {
    /// The non-fitted part of a shape, as the key of its phenotype grid.
    pub(super) fn grid_key(template: &ShapeParams) -> String {
        let p = &template.phenotype;
        format!(
            "{:?}|{:?}",
            [p.cupsize, p.firmness, p.african, p.asian, p.caucasian],
            template.local_changes
        )
    }

    /// [`IkSolver::new`]'s last step: the phenotype grid of the default shape.
    pub(super) fn with_default_grid(mut self, t0: Instant) -> Result<Self> {
        self.grid(&ShapeParams::default())?;
        self.setup_seconds = t0.elapsed().as_secs_f64();
        Ok(self)
    }

    /// The phenotype grid of `template`'s non-fitted values (other phenotype values, local
    /// changes), built on first use (288 rest meshes of the generator, in parallel) and
    /// cached.
    pub(super) fn grid(&self, template: &ShapeParams) -> Result<Arc<PhenGrid>> {
        let key = IkSolver::grid_key(template);
        let mut grids = self.grids.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, g)) = grids.iter().find(|(k, _)| *k == key) {
            return Ok(g.clone());
        }
        let points = (0..N_GRID)
            .into_par_iter()
            .map(|idx| -> Result<Vec<V3>> {
                let r = self.generator.rest_mesh(&grid_shape(template, idx))?;
                let rest: Vec<V3> = self.rel_kept.iter().map(|&k| r[k as usize]).collect();
                let mut v = self.pair_x(&rest);
                v.extend(self.head_rel.iter().map(|h| rel_mean(h, &rest)));
                v.extend(self.tail_rel.iter().map(|t| rel_mean(t, &rest)));
                Ok(v)
            })
            .collect::<Result<Vec<_>>>()?;
        let g = Arc::new(PhenGrid { points });
        grids.push((key, g.clone()));
        Ok(g)
    }

    /// The surface data of point targets (built on first use, ~53 rest meshes): the Anny
    /// output vertices that rows of the solver's topology reach, their kept indices and the
    /// face units' displacements `B_j = rest(f = e_j) − rest(0)` there.
    pub(super) fn surface(&self) -> Result<Arc<Surface>> {
        let mut guard = self.surface.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = &*guard {
            return Ok(s.clone());
        }
        let n_anny = self.map.n_anny_vertices();
        let mut reach = vec![false; n_anny];
        match self.topology {
            OutputTopology::Anny => reach.iter_mut().for_each(|r| *r = true),
            OutputTopology::Full => {
                for &a in self.map.full_from_anny() {
                    reach[a as usize] = true;
                }
            }
            OutputTopology::Small => {
                for b in self.map.small_binding() {
                    for &a in &b.tri {
                        reach[a as usize] = true;
                    }
                }
            }
        }
        let kob = self.generator.kept_of_base();
        let out_base = self.generator.output_vertices();
        let mut slot_of_anny = vec![u32::MAX; n_anny];
        let mut kept_of_slot = Vec::new();
        for a in 0..n_anny {
            if reach[a] {
                slot_of_anny[a] = kept_of_slot.len() as u32;
                kept_of_slot.push(kob[out_base[a] as usize]);
            }
        }
        let default = ShapeParams::default();
        let rest0 = self.generator.rest_mesh(&default)?;
        let per_unit: Vec<Vec<(u32, V3)>> = (0..N_UNITS)
            .into_par_iter()
            .map(|j| -> Result<Vec<(u32, V3)>> {
                let mut s = default.clone();
                s.facial_actions[j] = 1.0;
                let r = self.generator.rest_mesh(&s)?;
                Ok(kept_of_slot
                    .iter()
                    .enumerate()
                    .filter_map(|(slot, &k)| {
                        let d = sub(r[k as usize], rest0[k as usize]);
                        (d != [0.0; 3]).then_some((slot as u32, d))
                    })
                    .collect())
            })
            .collect::<Result<Vec<_>>>()?;
        let n_slots = kept_of_slot.len();
        let mut unit_off = vec![0u32; n_slots + 1];
        for list in &per_unit {
            for &(slot, _) in list {
                unit_off[slot as usize + 1] += 1;
            }
        }
        for i in 0..n_slots {
            unit_off[i + 1] += unit_off[i];
        }
        let mut fill = unit_off.clone();
        let mut unit_val = vec![(0u8, [0.0; 3]); unit_off[n_slots] as usize];
        for (j, list) in per_unit.iter().enumerate() {
            for &(slot, d) in list {
                unit_val[fill[slot as usize] as usize] = (j as u8, d);
                fill[slot as usize] += 1;
            }
        }
        let s = Arc::new(Surface {
            slot_of_anny,
            kept_of_slot,
            unit_off,
            unit_val,
        });
        *guard = Some(s.clone());
        Ok(s)
    }

    /// The per-vertex phenotype grid of `template`'s non-fitted values: the rest positions
    /// of every slot of `surface` at the 288 grid points (288 rest meshes in parallel, about
    /// 24 bytes × 288 per slot: 92 MB on the full template), built on first use and cached.
    pub(super) fn vertex_grid(
        &self,
        template: &ShapeParams,
        surface: &Surface,
    ) -> Result<Arc<VertexGrid>> {
        let key = IkSolver::grid_key(template);
        let mut grids = self.vertex_grids.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, g)) = grids.iter().find(|(k, _)| *k == key) {
            return Ok(g.clone());
        }
        let n_slots = surface.kept_of_slot.len();
        let mut data = vec![[0.0; 3]; n_slots * N_GRID];
        let all: Vec<usize> = (0..N_GRID).collect();
        for chunk in all.chunks(16) {
            let meshes = chunk
                .par_iter()
                .map(|&idx| -> Result<Vec<V3>> {
                    let r = self.generator.rest_mesh(&grid_shape(template, idx))?;
                    Ok(surface
                        .kept_of_slot
                        .iter()
                        .map(|&k| r[k as usize])
                        .collect())
                })
                .collect::<Result<Vec<_>>>()?;
            for (&idx, m) in chunk.iter().zip(&meshes) {
                for (slot, p) in m.iter().enumerate() {
                    data[slot * N_GRID + idx] = *p;
                }
            }
        }
        let g = Arc::new(VertexGrid { data });
        grids.push((key, g.clone()));
        Ok(g)
    }
}
