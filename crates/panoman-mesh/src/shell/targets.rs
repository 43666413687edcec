//! The targets of the shell energy: edge lengths and dihedral angles with their weights,
//! vertex handles and point constraints (module docs of [`super`]).

use super::*;

/// A soft positional constraint `w |x_v − x̂|²` (docs/design/shell-fit.md §2.2, vertex handles). `weight`
/// has units 1/length², e.g. `λ_H/ℓ̄²` for a dimensionless λ_H.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Handle {
    /// Constrained vertex.
    pub vertex: u32,
    /// Target position x̂.
    pub position: V3,
    /// Weight w ≥ 0.
    pub weight: f64,
}

/// A soft constraint on a fixed linear combination of vertices (a keypoint regressor row, a
/// barycentric surface point): `p(x) = Σ_m b_m x_m`, residual `√w (p(x) − p̂)` (3 rows), or
/// `√w n̂ᵀ(p(x) − p̂)` (point-to-plane, 1 row) when `normal` is set (docs/design/shell-fit.md §2.2).
/// `weight` has units 1/length². Every vertex pair of `rows` must be in the solver's pattern
/// (see [`ShellSolver::with_extra_pairs`]; pairs of one triangle always are).
#[derive(Clone, Debug, PartialEq)]
pub struct PointConstraint {
    /// `(vertex, b_m)` pairs.
    pub rows: Vec<(u32, f64)>,
    /// Target position p̂.
    pub target: V3,
    /// Weight w ≥ 0.
    pub weight: f64,
    /// Unit normal n̂ for a point-to-plane residual; `None` for point-to-point.
    pub normal: Option<V3>,
}

impl PointConstraint {
    /// `p(x) − p̂`.
    pub fn offset(&self, x: &[V3]) -> V3 {
        let mut p = [0.0; 3];
        for &(v, b) in &self.rows {
            for c in 0..3 {
                p[c] += b * x[v as usize][c];
            }
        }
        sub(p, self.target)
    }

    /// The constraint's energy `w |p(x) − p̂|²` or `w (n̂ᵀ(p(x) − p̂))²`.
    pub fn energy(&self, x: &[V3]) -> f64 {
        let d = self.offset(x);
        match self.normal {
            Some(n) => self.weight * dot(n, d).powi(2),
            None => self.weight * dot(d, d),
        }
    }
}

/// Targets and weights of the shell energy (module docs, docs/design/shell-fit.md §2.1): per edge the
/// target length ℓ*_e > 0, target signed dihedral angle φ*_e (internal sign, docs/design/rla-and-g.md §2.1; ignored on
/// boundary edges), weights w_L,e ≥ 0 and w_A,e ≥ 0, and optional vertex handles.
#[derive(Clone, Debug, PartialEq)]
pub struct ShellTargets {
    /// Target lengths ℓ* (metres), #E, all positive.
    pub lengths: Vec<f64>,
    /// Target dihedral angles φ* (radians), #E; only interior edges are used. Need not lie in
    /// (−π, π]: only `wrap(φ − φ*)` enters.
    pub angles: Vec<f64>,
    /// Stretch weights w_L (dimensionless), #E.
    pub length_weights: Vec<f64>,
    /// Bend weights w_A (dimensionless), #E; boundary entries are ignored.
    pub angle_weights: Vec<f64>,
    /// Soft vertex handles.
    pub handles: Vec<Handle>,
    /// Soft constraints on linear combinations of vertices (keypoints, surface points).
    pub points: Vec<PointConstraint>,
}

impl ShellTargets {
    /// Targets `ℓ*`, `φ*` with the default weights: `w_L = 1`, `w_A = c_B² ω_e²`,
    /// `ω_e = ℓ*_e / sqrt((A_fL + A_fR)/3)` with the face areas of `x_init` (docs/design/shell-fit.md §2.1;
    /// see [`ShellTargets::bending_weights`]).
    pub fn new(
        topo: &Topology,
        lengths: Vec<f64>,
        angles: Vec<f64>,
        x_init: &[V3],
        c_b: f64,
    ) -> Result<Self> {
        check_positions(topo, x_init, "initial mesh")?;
        let ne = topo.n_edges();
        if lengths.len() != ne || angles.len() != ne {
            return Err(MeshError::Mismatch(format!(
                "shell targets have {} lengths and {} angles, the topology has {ne} edges",
                lengths.len(),
                angles.len()
            )));
        }
        let angle_weights = Self::bending_weights(topo, &lengths, x_init, c_b);
        let t = Self {
            length_weights: vec![1.0; ne],
            angle_weights,
            lengths,
            angles,
            handles: Vec::new(),
            points: Vec::new(),
        };
        t.validate(topo)?;
        Ok(t)
    }

    /// Targets from an RLA pair: `ℓ* = ℓ_r ⊙ max(1 + RL, ε)`, `φ* = φ_r + RA`
    /// ([`RestGeometry::targets_into`], docs/design/rla-and-g.md §2.1), default weights as in
    /// [`ShellTargets::new`].
    pub fn from_rla(
        topo: &Topology,
        rest: &RestGeometry,
        rla: &Rla,
        x_init: &[V3],
        c_b: f64,
    ) -> Result<Self> {
        let ne = topo.n_edges();
        if rla.rl.len() != ne || rla.ra.len() != ne || rest.lengths.len() != ne {
            return Err(MeshError::Mismatch(format!(
                "RLA/rest geometry sizes ({}, {}, {}) do not match the {ne} edges",
                rla.rl.len(),
                rla.ra.len(),
                rest.lengths.len()
            )));
        }
        let mut lengths = vec![0.0; ne];
        let mut angles = vec![0.0; ne];
        rest.targets_into(rla, &mut lengths, &mut angles);
        Self::new(topo, lengths, angles, x_init, c_b)
    }

    /// The lengths and angles of `x` itself as targets (E(x) = 0), default weights.
    pub fn from_positions(topo: &Topology, x: &[V3], c_b: f64) -> Result<Self> {
        let rest = RestGeometry::new(topo, x)?;
        Self::new(topo, rest.lengths, rest.angles, x, c_b)
    }

    /// Default bend weights `w_A,e = c_B² ω_e²`, `ω_e² = 3 ℓ*_e² / (A_fL + A_fR)` with the face
    /// areas of `x` (docs/design/shell-fit.md §2.1; dimensionless, so the stretch/bend balance does not
    /// depend on units). 0 on boundary edges and on diamonds of (near-)zero area.
    pub fn bending_weights(topo: &Topology, lengths: &[f64], x: &[V3], c_b: f64) -> Vec<f64> {
        let area = |f: u32| {
            let [a, b, c] = topo.faces[f as usize];
            let (a, b, c) = (x[a as usize], x[b as usize], x[c as usize]);
            0.5 * norm(cross(sub(b, a), sub(c, a)))
        };
        // Per edge, independent: in parallel (the values do not depend on the split).
        (0..topo.n_edges())
            .into_par_iter()
            .with_min_len(4096)
            .map(|e| {
                let [fl, fr] = topo.edge_faces[e];
                if fr == NONE {
                    return 0.0;
                }
                let s = area(fl) + area(fr);
                let l2 = lengths[e] * lengths[e];
                if s > 1e-12 * l2 && s.is_finite() {
                    c_b * c_b * 3.0 * l2 / s
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// Checks sizes, positivity of ℓ*, finiteness, non-negative weights and handle indices.
    pub fn validate(&self, topo: &Topology) -> Result<()> {
        let ne = topo.n_edges();
        for (name, len) in [
            ("lengths", self.lengths.len()),
            ("angles", self.angles.len()),
            ("length_weights", self.length_weights.len()),
            ("angle_weights", self.angle_weights.len()),
        ] {
            if len != ne {
                return Err(MeshError::Mismatch(format!(
                    "shell targets: {name} has {len} entries, the topology has {ne} edges"
                )));
            }
        }
        if let Some(e) = self
            .lengths
            .iter()
            .position(|&l| !(l > 0.0 && l.is_finite()))
        {
            return Err(MeshError::Numerical(format!(
                "shell targets: target length of edge {e} is {}",
                self.lengths[e]
            )));
        }
        if let Some(e) =
            (0..ne).find(|&e| topo.edge_faces[e][1] != NONE && !self.angles[e].is_finite())
        {
            return Err(MeshError::NonFinite(format!(
                "shell targets: target angle of edge {e} is {}",
                self.angles[e]
            )));
        }
        let bad_w = |w: &f64| !(*w >= 0.0 && w.is_finite());
        if let Some(e) = self.length_weights.iter().position(bad_w) {
            return Err(MeshError::Numerical(format!(
                "shell targets: stretch weight of edge {e} is {}",
                self.length_weights[e]
            )));
        }
        if let Some(e) = self.angle_weights.iter().position(bad_w) {
            return Err(MeshError::Numerical(format!(
                "shell targets: bend weight of edge {e} is {}",
                self.angle_weights[e]
            )));
        }
        for (h, hd) in self.handles.iter().enumerate() {
            if hd.vertex as usize >= topo.n_vertices
                || bad_w(&hd.weight)
                || !hd.position.iter().all(|c| c.is_finite())
            {
                return Err(MeshError::Numerical(format!(
                    "shell targets: handle {h} {hd:?} is invalid"
                )));
            }
        }
        for (k, pc) in self.points.iter().enumerate() {
            let bad = pc.rows.is_empty()
                || bad_w(&pc.weight)
                || !pc.target.iter().all(|c| c.is_finite())
                || pc.normal.is_some_and(|n| !n.iter().all(|c| c.is_finite()))
                || pc
                    .rows
                    .iter()
                    .any(|&(v, b)| v as usize >= topo.n_vertices || !b.is_finite());
            if bad {
                return Err(MeshError::Numerical(format!(
                    "shell targets: point constraint {k} is invalid (empty, out-of-range vertex or non-finite value)"
                )));
            }
        }
        Ok(())
    }

    /// Mean target length ℓ̄.
    pub(super) fn mean_length(&self) -> f64 {
        self.lengths.iter().sum::<f64>() / self.lengths.len().max(1) as f64
    }
}
