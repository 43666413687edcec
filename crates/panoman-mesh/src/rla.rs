//! The RLA representation (PanoMan §4.1): relative edge lengths and relative dihedral angles.
//!
//! For edge `e = (i, j)` with diamond vertices `k` (in fL) and `l` (in fR), see
//! [`crate::topology`]:
//!
//! ```text
//! ℓ_e = |x_j − x_i|,  ê = (x_j − x_i)/ℓ_e
//! N1 = (x_j − x_i) × (x_k − x_i),  N2 = (x_i − x_j) × (x_l − x_j),  n1 = N1/|N1|,  n2 = N2/|N2|
//! φ_e = atan2(ê·(n1 × n2), n1·n2) ∈ (−π, π]          (signed bending angle)
//! RL_e = ℓ_e/ℓ_r,e − 1,   RA_e = wrap(φ_e − φ_r,e)    (relative to the rest shape r)
//! ```
//!
//! `φ` is 0 on a flat diamond and positive on convex edges of an outward-oriented surface. The
//! paper's "inner included angle" is `a = π − φ`, so the paper's RA is `−RA` here (internal
//! sign convention, docs/design/rla-and-g.md §2.1). RA is 0 on boundary edges.
//!
//! The hinge gradients (docs/design/rla-and-g.md §2.2) are [`length_gradient`] and [`dihedral_gradient`].

use crate::error::{MeshError, Result};
use crate::geom::{V3, cross, dot, norm, scale, sub};
use crate::topology::{NONE, Topology};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Smallest target length relative to the rest length that [`RestGeometry::targets_into`]
/// produces (`1 + RL` is clamped to at least this).
pub const MIN_RELATIVE_LENGTH: f64 = 1e-3;

/// Edges per rayon task: per-edge work is ~20 ns, so small chunks only add overhead.
const EDGE_CHUNK: usize = 4096;

/// `wrap(x) = x − 2π·round(x/2π)`, the representative of an angle difference in [−π, π].
#[inline]
pub fn wrap_angle(x: f64) -> f64 {
    x - 2.0 * PI * (x / (2.0 * PI)).round()
}

/// Signed dihedral (bending) angle φ of the diamond (i, j, k, l), see the module docs.
#[inline]
pub fn dihedral_angle(xi: V3, xj: V3, xk: V3, xl: V3) -> f64 {
    let e = sub(xj, xi);
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    // atan2 is scale-invariant in both arguments, so unnormalised N1, N2 and e suffice:
    // ê·(n1×n2) = e·(N1×N2)/(ℓ|N1||N2|),  n1·n2 = N1·N2/(|N1||N2|).
    let y = dot(e, cross(n1, n2)) / norm(e);
    let x = dot(n1, n2);
    y.atan2(x)
}

/// Edge lengths ℓ_e of all edges, written into `out` (length #E).
pub fn edge_lengths_into(topo: &Topology, positions: &[V3], out: &mut [f64]) {
    assert_eq!(out.len(), topo.n_edges());
    out.par_chunks_mut(EDGE_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * EDGE_CHUNK;
            for (o, &[i, j]) in chunk.iter_mut().zip(&topo.edges[base..]) {
                *o = norm(sub(positions[j as usize], positions[i as usize]));
            }
        });
}

/// Signed dihedral angles φ_e of all edges, written into `out` (length #E; 0 on boundary edges).
pub fn dihedral_angles_into(topo: &Topology, positions: &[V3], out: &mut [f64]) {
    assert_eq!(out.len(), topo.n_edges());
    out.par_chunks_mut(EDGE_CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * EDGE_CHUNK;
            for (off, o) in chunk.iter_mut().enumerate() {
                let e = base + off;
                let [k, l] = topo.edge_opposite[e];
                *o = if l == NONE {
                    0.0
                } else {
                    let [i, j] = topo.edges[e];
                    dihedral_angle(
                        positions[i as usize],
                        positions[j as usize],
                        positions[k as usize],
                        positions[l as usize],
                    )
                };
            }
        });
}

/// Edge lengths of all edges (allocating form of [`edge_lengths_into`]).
pub fn edge_lengths(topo: &Topology, positions: &[V3]) -> Vec<f64> {
    let mut out = vec![0.0; topo.n_edges()];
    edge_lengths_into(topo, positions, &mut out);
    out
}

/// Dihedral angles of all edges (allocating form of [`dihedral_angles_into`]).
pub fn dihedral_angles(topo: &Topology, positions: &[V3]) -> Vec<f64> {
    let mut out = vec![0.0; topo.n_edges()];
    dihedral_angles_into(topo, positions, &mut out);
    out
}

/// The intrinsic geometry of a rest shape: ℓ_r and φ_r per edge.
#[derive(Clone, Debug, PartialEq)]
pub struct RestGeometry {
    /// Rest edge lengths ℓ_r (metres), #E.
    pub lengths: Vec<f64>,
    /// Rest signed dihedral angles φ_r (radians), #E, 0 on boundary edges.
    pub angles: Vec<f64>,
}

impl RestGeometry {
    /// Measures ℓ_r, φ_r on `rest`. Fails on non-finite coordinates, a vertex-count mismatch or
    /// a zero-length edge (RL would be undefined).
    pub fn new(topo: &Topology, rest: &[V3]) -> Result<Self> {
        check_positions(topo, rest, "rest shape")?;
        let lengths = edge_lengths(topo, rest);
        if let Some(e) = lengths
            .iter()
            .position(|&l| l.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
        {
            return Err(MeshError::Numerical(format!(
                "rest shape: edge {e} {:?} has zero length, RL is undefined",
                topo.edges[e]
            )));
        }
        Ok(Self {
            lengths,
            angles: dihedral_angles(topo, rest),
        })
    }

    /// Target lengths and angles `ℓ* = ℓ_r ⊙ max(1 + RL, ε)`, `φ* = φ_r + RA` (docs/design/rla-and-g.md
    /// §2.1), written into `lengths`, `angles`; returns how many lengths were clamped.
    ///
    /// Blended or model-predicted RL (linear in β) can fall below −1 on edges whose RL varies
    /// strongly (lips, eyelids); the floor [`MIN_RELATIVE_LENGTH`] keeps every target length
    /// positive so that `g` stays defined.
    pub fn targets_into(&self, rla: &Rla, lengths: &mut [f64], angles: &mut [f64]) -> usize {
        let mut clamped = 0;
        for (o, (&lr, &rl)) in lengths.iter_mut().zip(self.lengths.iter().zip(&rla.rl)) {
            let f = 1.0 + rl;
            *o = if f >= MIN_RELATIVE_LENGTH {
                lr * f
            } else {
                clamped += 1;
                lr * MIN_RELATIVE_LENGTH
            };
        }
        for (o, (&ar, &ra)) in angles.iter_mut().zip(self.angles.iter().zip(&rla.ra)) {
            *o = ar + ra;
        }
        clamped
    }
}

/// An RLA vector pair: `rl` and `ra`, both of length #E (`ra` is 0 on boundary edges).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rla {
    /// Relative edge lengths RL = ℓ/ℓ_r − 1.
    pub rl: Vec<f64>,
    /// Relative dihedral angles RA = wrap(φ − φ_r), internal sign (paper's RA = −RA).
    pub ra: Vec<f64>,
}

impl Rla {
    /// The zero RLA (the rest shape itself) for `n_edges` edges.
    pub fn zeros(n_edges: usize) -> Self {
        Self {
            rl: vec![0.0; n_edges],
            ra: vec![0.0; n_edges],
        }
    }

    /// RL/RA of `positions` with respect to `rest` (allocating form of [`Rla::compute_into`]).
    pub fn compute(topo: &Topology, rest: &RestGeometry, positions: &[V3]) -> Result<Self> {
        let mut out = Self::zeros(topo.n_edges());
        out.compute_into(topo, rest, positions)?;
        Ok(out)
    }

    /// Overwrites `self` with RL/RA of `positions` with respect to `rest`.
    pub fn compute_into(
        &mut self,
        topo: &Topology,
        rest: &RestGeometry,
        positions: &[V3],
    ) -> Result<()> {
        check_positions(topo, positions, "mesh")?;
        let ne = topo.n_edges();
        self.rl.resize(ne, 0.0);
        self.ra.resize(ne, 0.0);
        self.rl
            .par_chunks_mut(EDGE_CHUNK)
            .zip(self.ra.par_chunks_mut(EDGE_CHUNK))
            .enumerate()
            .for_each(|(c, (rl, ra))| {
                let base = c * EDGE_CHUNK;
                for off in 0..rl.len() {
                    let e = base + off;
                    let [i, j] = topo.edges[e];
                    let (xi, xj) = (positions[i as usize], positions[j as usize]);
                    rl[off] = norm(sub(xj, xi)) / rest.lengths[e] - 1.0;
                    let [k, l] = topo.edge_opposite[e];
                    ra[off] = if l == NONE {
                        0.0
                    } else {
                        let phi =
                            dihedral_angle(xi, xj, positions[k as usize], positions[l as usize]);
                        wrap_angle(phi - rest.angles[e])
                    };
                }
            });
        Ok(())
    }
}

/// Checks that `positions` has one finite point per vertex of `topo`.
pub fn check_positions(topo: &Topology, positions: &[V3], what: &str) -> Result<()> {
    if positions.len() != topo.n_vertices {
        return Err(MeshError::Mismatch(format!(
            "{what} has {} vertices, the topology has {}",
            positions.len(),
            topo.n_vertices
        )));
    }
    if let Some(v) = positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(MeshError::NonFinite(format!(
            "{what}: vertex {v} has coordinates {:?}",
            positions[v]
        )));
    }
    Ok(())
}

/// Adds to `out` (#V) the gradient with respect to the vertices `x` of
/// `Σ_e l̄_e ℓ_e(x) + φ̄_e φ_e(x)` (`dl`, `dphi`: #E; `dphi` ignored on boundary edges), i.e. the
/// transpose of the rest geometry's derivative ([`length_gradient`], [`dihedral_gradient`]).
///
/// # Panics
/// On size mismatches.
pub fn geometry_gradient_add(topo: &Topology, x: &[V3], dl: &[f64], dphi: &[f64], out: &mut [V3]) {
    assert!(dl.len() == topo.n_edges() && dphi.len() == topo.n_edges());
    assert!(x.len() == topo.n_vertices && out.len() == topo.n_vertices);
    let acc = |out: &mut [V3], v: u32, g: V3, s: f64| {
        for c in 0..3 {
            out[v as usize][c] += s * g[c];
        }
    };
    for (e, &[i, j]) in topo.edges.iter().enumerate() {
        let (xi, xj) = (x[i as usize], x[j as usize]);
        if dl[e] != 0.0 {
            let [gi, gj] = length_gradient(xi, xj);
            acc(out, i, gi, dl[e]);
            acc(out, j, gj, dl[e]);
        }
        let [k, l] = topo.edge_opposite[e];
        if l != NONE && dphi[e] != 0.0 {
            let g = dihedral_gradient(xi, xj, x[k as usize], x[l as usize]);
            for (v, gv) in [i, j, k, l].into_iter().zip(g) {
                acc(out, v, gv, dphi[e]);
            }
        }
    }
}

/// Gradient of ℓ = |x_j − x_i| with respect to (x_i, x_j): `(−ê, ê)`.
#[inline]
pub fn length_gradient(xi: V3, xj: V3) -> [V3; 2] {
    let d = sub(xj, xi);
    let e = scale(d, 1.0 / norm(d));
    [scale(e, -1.0), e]
}

/// Gradient of the signed dihedral angle φ of the diamond (i, j, k, l) with respect to
/// (x_i, x_j, x_k, x_l) (docs/design/rla-and-g.md §2.2):
///
/// ```text
/// g_k = −(ℓ/|N1|²)·N1,   g_l = −(ℓ/|N2|²)·N2
/// t_k = (x_k−x_i)·(x_j−x_i)/ℓ²,   t_l = (x_l−x_i)·(x_j−x_i)/ℓ²
/// ∂φ/∂x_i = −(1−t_k)·g_k − (1−t_l)·g_l,   ∂φ/∂x_j = −t_k·g_k − t_l·g_l
/// ```
/// The four gradients sum to zero (translation invariance).
#[inline]
pub fn dihedral_gradient(xi: V3, xj: V3, xk: V3, xl: V3) -> [V3; 4] {
    let e = sub(xj, xi);
    let l2 = dot(e, e);
    let l = l2.sqrt();
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    let gk = scale(n1, -l / dot(n1, n1));
    let gl = scale(n2, -l / dot(n2, n2));
    let tk = dot(sub(xk, xi), e) / l2;
    let tl = dot(sub(xl, xi), e) / l2;
    let gi = [
        -(1.0 - tk) * gk[0] - (1.0 - tl) * gl[0],
        -(1.0 - tk) * gk[1] - (1.0 - tl) * gl[1],
        -(1.0 - tk) * gk[2] - (1.0 - tl) * gl[2],
    ];
    let gj = [
        -tk * gk[0] - tl * gl[0],
        -tk * gk[1] - tl * gl[1],
        -tk * gk[2] - tl * gl[2],
    ];
    [gi, gj, gk, gl]
}
