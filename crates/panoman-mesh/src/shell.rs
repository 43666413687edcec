//! Discrete-shell refinement of vertex positions toward target edge lengths and dihedral angles
//! (docs/design/shell-fit.md §2.1–3.4, restricted to the vertex unknowns V).
//!
//! `g` (docs/design/rla-and-g.md §3) is exact for integrable RL/RA but amplifies non-integrable errors; the
//! paper uses it only as an initializer. [`ShellSolver`] minimises
//!
//! ```text
//! E(V) = Σ_e w_L,e (ℓ_e(V)/ℓ*_e − 1)²  +  Σ_{e interior} w_A,e wrap(φ_e(V) − φ*_e)²
//!        + Σ_h w_h |x_h − x̂_h|²
//! ```
//!
//! with Levenberg–Marquardt: residuals `r_L,e = √w_L,e (ℓ_e/ℓ*_e − 1)` (Jacobian row
//! `√w_L,e/ℓ*_e · (−ê, ê)` on (x_i, x_j), docs/design/rla-and-g.md §2.2), `r_A,e = √w_A,e wrap(φ_e − φ*_e)` (row
//! `√w_A,e ∇φ_e` on (x_i, x_j, x_k, x_l), docs/design/rla-and-g.md §2.2), `r_h = √w_h (x_h − x̂_h)` (row `√w_h I`).
//! With `g = Jᵀr` (so `∇E = 2g`) each iteration solves
//!
//! ```text
//! (JᵀJ + μ D) δ = −g,    D = max(diag JᵀJ, 1e−8·max diag JᵀJ)        (docs/design/shell-fit.md §3.3, Marquardt scaling)
//! ```
//!
//! JᵀJ has a fixed pattern of 3×3 blocks over the vertex pairs in edges ∪ diamond diagonals
//! (k, l) ∪ diagonal (docs/design/shell-fit.md §3.2); it is stored as a scalar lower-triangular CSC matrix of size 3|V|,
//! analysed symbolically once, and filled through a per-edge *scatter map* of value slots (docs/design/shell-fit.md §3.3).
//! The damping μ follows Nielsen's rule (docs/design/shell-fit.md §3.4). Default weights: `w_L = 1`,
//! `w_A = c_B² ω_e²` with the dimensionless Fröhlich–Botsch weight
//! `ω_e = ℓ*_e / sqrt((A_fL + A_fR)/3)` measured on the initial mesh (docs/design/shell-fit.md §2.1).

use crate::error::{MeshError, Result};
use crate::geom::{V3, cross, dot, norm, scale, sub};
use crate::rla::{
    RestGeometry, Rla, check_positions, dihedral_angle, dihedral_gradient, wrap_angle,
};
use crate::sparse::SpdFactor;
use crate::topology::{NONE, Topology};
use faer::MatMut;
use faer::dyn_stack::MemBuffer;
use faer::sparse::{SparseColMat, SparseColMatRef, SymbolicSparseColMat};
use rayon::prelude::*;
use std::time::Instant;

/// Edges per rayon task in the residual/Jacobian evaluation.
const EDGE_CHUNK: usize = 2048;

/// Vertices per task of the PCG's vector operations (fixed chunks: the dot products are summed
/// per chunk, then in chunk order, so the iterates do not depend on the thread count).
const PCG_CHUNK: usize = 2048;

/// Fixed ranges of vertex blocks the normal-matrix product is split into (one rayon task
/// each; a fixed count keeps the sum order, and so the result, independent of the threads).
pub const PRODUCT_PARTS: usize = 4;

/// Smallest damping factor μ (keeps the rigid null space of JᵀJ damped, docs/design/shell-fit.md §8.3).
const MU_MIN: f64 = 1e-10;

/// Largest damping factor μ before the solver gives up (steps are then vanishingly small).
const MU_MAX: f64 = 1e16;

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
    fn mean_length(&self) -> f64 {
        self.lengths.iter().sum::<f64>() / self.lengths.len().max(1) as f64
    }
}

/// Controls of the Levenberg–Marquardt iteration (docs/design/shell-fit.md §3.4).
#[derive(Clone, Debug, PartialEq)]
pub struct ShellOptions {
    /// Iteration budget. With `retry_rejected = 0` it caps the linear solves, accepted or
    /// not; otherwise see `retry_rejected`. Default 10.
    pub max_iterations: usize,
    /// Rejected steps retried without using up the budget: after a rejected step μ is raised
    /// (Nielsen's rule, ×2, ×4, ×8, …) and the step re-solved; only the
    /// `(retry_rejected + 1)`-th rejection in a row uses one unit of `max_iterations`. So a
    /// budget of one iteration still ends with an accepted step unless `retry_rejected + 1`
    /// damping increases in a row fail (μ then grew by 2^((r+1)(r+2)/2)). 0 (default): every
    /// solve counts, the classic cap.
    pub retry_rejected: usize,
    /// Stop when the relative energy decrease `(E − E_new)/E` of accepted steps is below this
    /// twice in a row. Default 1e−6.
    pub rel_tol: f64,
    /// Stop when `‖δ‖∞ < step_tol·(‖x‖∞ + step_tol)`. Default 1e−10.
    pub step_tol: f64,
    /// Stop when `E ≤ energy_tol` (absolute; E is dimensionless). Default 1e−24.
    pub energy_tol: f64,
    /// Initial damping μ. Default 1e−4.
    pub mu_init: f64,
    /// Bend rows of diamonds with a height `h_k` or `h_l` below `degenerate_height·ℓ̄` are left
    /// out of the Jacobian (their residual still counts in E; docs/design/shell-fit.md §8.2). Default 1e−6.
    pub degenerate_height: f64,
    /// Numeric factorization on the rayon pool (`Par::rayon(0)`) instead of sequentially.
    /// Default true.
    pub parallel_factor: bool,
    /// Inexact steps by preconditioned conjugate gradients instead of a factorization
    /// ([`ShellSolver::step_pcg`]); a step whose PCG does not reach its tolerance falls back
    /// to the factorization. Default `None` (every step factored).
    pub pcg: Option<PcgOptions>,
}

/// Inexact LM steps by preconditioned conjugate gradients (Hestenes–Stiefel 1952) on
/// `(JᵀJ + μD) δ = −g`, preconditioned by the 3×3 vertex blocks of the damped matrix
/// (block Jacobi). With the Marquardt scaling D = diag JᵀJ the scaled matrix has its
/// eigenvalues in `[μ, μ + λ_max]` with `λ_max` bounded by the number of coupled unknowns
/// per row (Gershgorin, scaled entries ≤ 1), so for the strongly damped steps of warm frames
/// (μ ≈ 1) the condition number is a few tens whatever the stiffness ratio of the energy,
/// and a few tens of matrix–vector products (≈ 2 ms each on the full template) replace a
/// numeric factorization (≈ 100 ms). The gain ratio uses the model decrease of the inexact
/// step, `δᵀ(μDδ − g + ρ)` with ρ the final PCG residual (docs/design/shell-fit.md §3.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PcgOptions {
    /// Stop when `‖ρ‖ ≤ rel_tol·‖g‖` (ρ = −g − (JᵀJ + μD)δ). Default 1e−2 (on the eval's
    /// clip, warm frames: 6–14 iterations, the same tracking error as 1e−3 and as the
    /// factorization to 0.01 mm).
    pub rel_tol: f64,
    /// Iteration cap; not reaching `rel_tol` within it falls back to the factorization.
    /// Default 60.
    pub max_iterations: usize,
}

impl Default for PcgOptions {
    fn default() -> Self {
        Self {
            rel_tol: 1e-2,
            max_iterations: 60,
        }
    }
}

impl Default for ShellOptions {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            retry_rejected: 0,
            rel_tol: 1e-6,
            step_tol: 1e-10,
            energy_tol: 1e-24,
            mu_init: 1e-4,
            degenerate_height: 1e-6,
            parallel_factor: true,
            pcg: None,
        }
    }
}

/// Why [`ShellSolver::solve`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShellStop {
    /// `E ≤ energy_tol` (includes E = 0 at the start: 0 iterations).
    Converged,
    /// Relative decrease below `rel_tol` twice in a row.
    SmallDecrease,
    /// `‖δ‖∞` below `step_tol` relative to `‖x‖∞`.
    SmallStep,
    /// Iteration budget used up (see [`ShellOptions::retry_rejected`]).
    MaxIterations,
    /// μ exceeded its cap (no decrease possible at machine precision).
    DampingOverflow,
}

/// Outcome of [`ShellSolver::solve`].
#[derive(Clone, Debug, PartialEq)]
pub struct ShellReport {
    /// Iterations (linear solves) tried, accepted or rejected.
    pub iterations: usize,
    /// Accepted iterations.
    pub accepted: usize,
    /// `energies[0]` = E at the start, `energies[t]` = E after iteration t (unchanged by a
    /// rejected step, so the sequence is non-increasing).
    pub energies: Vec<f64>,
    /// Wall time of each iteration (s): damping, factorization, solve, trial energy and, if
    /// accepted, re-linearisation.
    pub iteration_seconds: Vec<f64>,
    /// Wall time of the whole solve (s), including the first linearisation.
    pub total_seconds: f64,
    /// Final rms over all edges of `ℓ_e/ℓ*_e − 1` (unweighted).
    pub length_rms: f64,
    /// Final rms over interior edges of `wrap(φ_e − φ*_e)` (radians, unweighted).
    pub angle_rms: f64,
    /// Bend rows left out of the last Jacobian as near-degenerate (docs/design/shell-fit.md §8.2); the last
    /// linearisation, which precedes the final step when that step is not re-linearised.
    pub skipped_bend_rows: usize,
    /// Final damping μ.
    pub mu: f64,
    /// Stopping reason.
    pub stop: ShellStop,
    /// Steps solved by PCG ([`ShellOptions::pcg`]) and their conjugate-gradient iterations in
    /// all; steps where PCG missed its tolerance and the factorization was used instead.
    pub pcg_steps: usize,
    /// See `pcg_steps`.
    pub pcg_iterations: usize,
    /// See `pcg_steps`.
    pub pcg_fallbacks: usize,
}

/// Residuals and Jacobian rows of one edge: the stretch row on (x_i, x_j) and the bend row on
/// (x_i, x_j, x_k, x_l) (zero on boundary edges and skipped diamonds).
#[derive(Clone, Copy, Debug, Default)]
struct EdgeRows {
    r_len: f64,
    r_ang: f64,
    j_len: [V3; 2],
    j_ang: [V3; 4],
    has_ang: bool,
    skipped: bool,
}

/// Levenberg–Marquardt solver for the discrete-shell energy over the vertices of one topology
/// (module docs; docs/design/shell-fit.md §3.2–3.4). Construction builds the block pattern of JᵀJ, the
/// scatter map and the symbolic Cholesky factorization once; [`ShellSolver::solve`] then only
/// assembles values, refactors numerically and solves. All work buffers are allocated on the
/// first use and reused (no allocation inside the iteration loop).
pub struct ShellSolver {
    topo: Topology,
    /// 3|V|.
    n: usize,
    /// Lower-triangular scalar CSC pattern of JᵀJ (sorted rows; the diagonal is each column's
    /// first entry).
    pattern: SymbolicSparseColMat<usize>,
    /// Scatter map: per edge and vertex pair (i,j),(i,k),(i,l),(j,k),(j,l),(k,l), the value
    /// offsets of the stored (lower) 3×3 block's three columns (rows are consecutive). Pairs
    /// absent for boundary edges hold `u32::MAX`.
    slots: Vec<[[u32; 3]; 6]>,
    /// The assembly's split (`linearize`): the first vertex of the upper half; the edges whose
    /// diamond lies in the lower / upper half, and those that straddle them (ascending).
    split_vertex: usize,
    half_edges: [Vec<u32>; 2],
    straddling_edges: Vec<u32>,
    /// Per point constraint (by index), the pattern positions of its vertex pairs, kept while
    /// its vertex list stays the same ([`PointSlots`]).
    point_slots: Vec<PointSlots>,
    /// Block pairs (lo, hi), lo < hi, sorted, with per-`lo` offsets: the off-diagonal blocks of
    /// the pattern, for the slot lookup of point constraints.
    pairs: Vec<(u32, u32)>,
    nb_off: Vec<usize>,
    /// Symbolic + numeric factorization of JᵀJ + μD (`None` with dense supports, whose
    /// quasi-definite system is factored instead).
    factor: Option<SpdFactor>,
    factor_scratch: Option<(bool, MemBuffer)>,
    solve_scratch: MemBuffer,
    // Work buffers.
    rows: Vec<EdgeRows>,
    jtj: Vec<f64>,
    damped: Vec<f64>,
    diag_scale: Vec<f64>,
    grad: Vec<f64>,
    delta: Vec<f64>,
    x_trial: Vec<V3>,
    /// Per fixed edge chunk of the last [`energy_of`]: energy and the unweighted sums of
    /// [`residual_rms`].
    chunk_sums: Vec<ChunkSums>,
    /// Buffers of [`ShellSolver::step_pcg`] (sized on first use, kept across steps).
    pcg: PcgScratch,
    skipped: usize,
    linearized: bool,
    /// Point supports kept out of JᵀJ and solved through the quasi-definite system (see
    /// [`ShellSolver::with_dense_supports`]); `None` without such supports.
    dense: Option<DenseSupports>,
}

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
struct DenseSupports {
    /// Per support: merged `(vertex, b)` pairs, sorted by vertex.
    rows: Vec<Vec<(u32, f64)>>,
    /// The rows of each support as given (a constraint matches when its rows are equal).
    given: Vec<Vec<(u32, f64)>>,
    /// (first vertex, length) of the given rows → candidate supports.
    index: std::collections::HashMap<(u32, usize), Vec<usize>>,
    /// Pattern of the quasi-definite matrix (lower CSC, size 3|V| + 3K).
    pattern: SymbolicSparseColMat<usize>,
    values: Vec<f64>,
    /// Per support and member: the value offsets of the couplings (s_{k,c}, x_{m,c}), c = 0..3.
    coupling_slots: Vec<Vec<[u32; 3]>>,
    /// Per support: the value offsets of the three diagonal entries of s_k.
    diag_slots: Vec<[u32; 3]>,
    factor: SpdFactor,
    factor_scratch: Option<(bool, MemBuffer)>,
    solve_scratch: MemBuffer,
    rhs: Vec<f64>,
    /// Per support, from the last linearisation: total weight W_k and offset Γ_k x − t̄_k.
    weight: Vec<f64>,
    offset: Vec<V3>,
}

impl std::fmt::Debug for ShellSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ShellSolver {{ n: {}, nnz(JᵀJ lower): {}, {:?} }}",
            self.n,
            self.jtj.len(),
            self.factor
        )
    }
}

/// The local vertex pairs of a diamond (i, j, k, l) in scatter-map order.
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

impl ShellSolver {
    /// Builds the fixed pattern of JᵀJ (3×3 blocks over edges ∪ diamond diagonals ∪ diagonal,
    /// docs/design/shell-fit.md §3.2), the scatter map and the symbolic factorization (docs/design/shell-fit.md §3.3).
    ///
    /// Fails on a diamond whose two opposite vertices coincide (k = l).
    pub fn new(topo: &Topology) -> Result<Self> {
        Self::with_extra_pairs(topo, &[])
    }

    /// As [`ShellSolver::new`], with the vertex pairs `extra` added to the pattern, so that
    /// [`PointConstraint`]s whose supports couple non-adjacent vertices (keypoint regressors)
    /// can be assembled. The pattern, and hence the symbolic factorization, is fixed here.
    pub fn with_extra_pairs(topo: &Topology, extra: &[(u32, u32)]) -> Result<Self> {
        Self::with_dense_supports(topo, extra, &[])
    }

    /// As [`ShellSolver::with_extra_pairs`], plus *dense supports*: linear combinations of many
    /// vertices (keypoint regressors). A point-to-point [`PointConstraint`] whose `rows` equal a
    /// registered support (same vertices in the same order, same coefficients) is kept out of
    /// JᵀJ and solved through a quasi-definite system (one extra unknown per support
    /// coordinate instead of a dense vertex clique in the factor; see the type-level docs of
    /// the solver module). The minimised energy and the steps are the same as with the pairs.
    pub fn with_dense_supports(
        topo: &Topology,
        extra: &[(u32, u32)],
        dense: &[Vec<(u32, f64)>],
    ) -> Result<Self> {
        let mut this = Self::build(topo, extra, dense.is_empty())?;
        if !dense.is_empty() {
            this.dense = Some(DenseSupports::new(&this, dense)?);
        }
        Ok(this)
    }

    /// The pattern, scatter map and (with `analyse`) the symbolic factorization of JᵀJ; with
    /// dense supports only the quasi-definite system is factored, so JᵀJ's own analysis is
    /// skipped.
    fn build(topo: &Topology, extra: &[(u32, u32)], analyse: bool) -> Result<Self> {
        let nv = topo.n_vertices;
        let ne = topo.n_edges();
        // Block pairs (lo, hi), lo < hi.
        let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(2 * ne);
        for e in 0..ne {
            let [i, j] = topo.edges[e];
            pairs.push((i.min(j), i.max(j)));
            let [k, l] = topo.edge_opposite[e];
            if l != NONE {
                if k == l {
                    return Err(MeshError::Topology(format!(
                        "edge {e} {:?}: both faces have the same opposite vertex {k}",
                        topo.edges[e]
                    )));
                }
                pairs.push((k.min(l), k.max(l)));
            }
        }
        for &(a, b) in extra {
            if a as usize >= nv || b as usize >= nv {
                return Err(MeshError::Mismatch(format!(
                    "extra pattern pair ({a}, {b}) out of range for {nv} vertices"
                )));
            }
            if a != b {
                pairs.push((a.min(b), a.max(b)));
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        // Per block column b: neighbours hi > b, sorted (CSR-like offsets into `pairs`).
        let mut nb_off = vec![0usize; nv + 1];
        for &(lo, _) in &pairs {
            nb_off[lo as usize + 1] += 1;
        }
        for v in 0..nv {
            nb_off[v + 1] += nb_off[v];
        }
        let n = 3 * nv;
        let mut col_ptr = vec![0usize; n + 1];
        for b in 0..nv {
            let deg = nb_off[b + 1] - nb_off[b];
            for c in 0..3 {
                col_ptr[3 * b + c + 1] = col_ptr[3 * b + c] + (3 - c) + 3 * deg;
            }
        }
        let nnz = col_ptr[n];
        if nnz >= u32::MAX as usize {
            return Err(MeshError::Numerical(
                "JᵀJ pattern too large for the scatter map".into(),
            ));
        }
        let mut row_idx = Vec::with_capacity(nnz);
        for b in 0..nv {
            let nbs = &pairs[nb_off[b]..nb_off[b + 1]];
            for c in 0..3 {
                for r in c..3 {
                    row_idx.push(3 * b + r);
                }
                for &(_, a) in nbs {
                    for r in 0..3 {
                        row_idx.push(3 * a as usize + r);
                    }
                }
            }
        }
        let slot_of = |a: u32, b: u32| -> [u32; 3] {
            let (lo, hi) = (a.min(b) as usize, a.max(b));
            let nbs = &pairs[nb_off[lo]..nb_off[lo + 1]];
            let q = nbs
                .binary_search(&(lo as u32, hi))
                .expect("pair in pattern");
            let mut s = [0u32; 3];
            for c in 0..3 {
                s[c] = (col_ptr[3 * lo + c] + (3 - c) + 3 * q) as u32;
            }
            s
        };
        let slots: Vec<[[u32; 3]; 6]> = (0..ne)
            .map(|e| {
                let [i, j] = topo.edges[e];
                let [k, l] = topo.edge_opposite[e];
                let mut s = [[u32::MAX; 3]; 6];
                if l == NONE {
                    s[0] = slot_of(i, j);
                } else {
                    let v = [i, j, k, l];
                    for (p, &(a, b)) in PAIRS.iter().enumerate() {
                        s[p] = slot_of(v[a], v[b]);
                    }
                }
                s
            })
            .collect();
        let split_vertex = nv / 2;
        let mut half_edges = [Vec::new(), Vec::new()];
        let mut straddling_edges = Vec::new();
        for e in 0..ne {
            let [i, j] = topo.edges[e];
            let [k, l] = topo.edge_opposite[e];
            let v4 = [i, j, k, l];
            let m = if l == NONE { 2 } else { 4 };
            let upper = v4[..m]
                .iter()
                .filter(|&&v| v as usize >= split_vertex)
                .count();
            match upper {
                0 => half_edges[0].push(e as u32),
                u if u == m => half_edges[1].push(e as u32),
                _ => straddling_edges.push(e as u32),
            }
        }
        let pattern = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let (factor, solve_scratch) = if analyse {
            let f = SpdFactor::symbolic_only(pattern.as_ref())?;
            let s = f.make_scratch(1);
            (Some(f), s)
        } else {
            (None, MemBuffer::new(faer::dyn_stack::StackReq::EMPTY))
        };
        Ok(Self {
            topo: topo.clone(),
            n,
            pattern,
            slots,
            split_vertex,
            half_edges,
            straddling_edges,
            point_slots: Vec::new(),
            pairs,
            nb_off,
            factor,
            factor_scratch: None,
            solve_scratch,
            rows: Vec::new(),
            jtj: Vec::new(),
            damped: Vec::new(),
            diag_scale: Vec::new(),
            grad: Vec::new(),
            delta: Vec::new(),
            x_trial: Vec::new(),
            chunk_sums: Vec::new(),
            pcg: PcgScratch::default(),
            skipped: 0,
            linearized: false,
            dense: None,
        })
    }

    /// The topology the solver was built for.
    pub fn topology(&self) -> &Topology {
        &self.topo
    }

    /// Number of stored entries of the lower triangle of JᵀJ.
    pub fn nnz(&self) -> usize {
        self.pattern.row_idx().len()
    }

    fn ensure_buffers(&mut self) {
        let ne = self.topo.n_edges();
        let nnz = self.nnz();
        if self.rows.len() != ne {
            self.rows = vec![EdgeRows::default(); ne];
            self.jtj = vec![0.0; nnz];
            self.damped = vec![0.0; nnz];
            self.diag_scale = vec![0.0; self.n];
            self.grad = vec![0.0; self.n];
            self.delta = vec![0.0; self.n];
            self.x_trial = vec![[0.0; 3]; self.topo.n_vertices];
            self.chunk_sums = vec![ChunkSums::default(); ne.div_ceil(EDGE_CHUNK)];
        }
    }

    fn check_inputs(&self, targets: &ShellTargets, x: &[V3]) -> Result<()> {
        check_positions(&self.topo, x, "shell solver start")?;
        targets.validate(&self.topo)
    }

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

    fn linearize_unchecked(
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
        if let Some(ds) = &mut self.dense {
            ds.weight.fill(0.0);
            ds.offset.fill([0.0; 3]);
        }
        let mut point_slots = std::mem::take(&mut self.point_slots);
        for (k, pc) in targets.points.iter().enumerate() {
            energy += pc.energy(x);
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

    /// The Marquardt scaling `D = max(diag JᵀJ, 1e−8·max diag)` (+ an absolute floor) of the
    /// assembled system, with the dense supports' diagonal `W b_m²` included as if they were
    /// assembled; the dense supports' target sums become the offsets `Γx − t̄`.
    fn marquardt_scaling(&mut self, x: &[V3]) {
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
    fn normal_matrix_mul_into(&self, v: &[f64], out: &mut [f64], parts: &mut Vec<Vec<f64>>) {
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
    fn lower_product(&self, v: &[f64], out: &mut [f64], range: std::ops::Range<usize>) {
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
    fn pcg_iterate(
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

    /// Minimises E from `x` (e.g. the output of `g`) by Levenberg–Marquardt (docs/design/shell-fit.md
    /// §3.3–3.4): gain ratio `ρ = (E − E_new)/(δᵀ(μDδ − g))` (the decrease predicted by the
    /// Gauss–Newton model), accept if ρ > 1e−3 with `μ ← μ·max(1/3, 1 − (2ρ − 1)³)`, `ν ← 2`,
    /// else `μ ← μν`, `ν ← 2ν`. Stops on `E ≤ energy_tol`, a relative decrease below `rel_tol`
    /// twice in a row, a small step, or the iteration cap. `x` holds the result (the best
    /// accepted iterate). A step accepted in the last allowed iteration is not re-linearised
    /// (the linearisation state is then cleared; call [`ShellSolver::linearize`] to use it).
    pub fn solve(
        &mut self,
        targets: &ShellTargets,
        x: &mut [V3],
        opts: &ShellOptions,
    ) -> Result<ShellReport> {
        let t_start = Instant::now();
        self.check_inputs(targets, x)?;
        self.ensure_buffers();
        let mut e = self.linearize_unchecked(targets, x, opts.degenerate_height)?;
        let mut report = ShellReport {
            iterations: 0,
            accepted: 0,
            energies: Vec::with_capacity(opts.max_iterations + 1),
            iteration_seconds: Vec::with_capacity(opts.max_iterations),
            total_seconds: 0.0,
            length_rms: 0.0,
            angle_rms: 0.0,
            skipped_bend_rows: 0,
            mu: opts.mu_init,
            stop: ShellStop::MaxIterations,
            pcg_steps: 0,
            pcg_iterations: 0,
            pcg_fallbacks: 0,
        };
        report.energies.push(e);
        let mut mu = opts.mu_init.max(MU_MIN);
        let mut nu = 2.0;
        let mut small = 0;
        // Budget used (accepted steps, plus one per `retry_rejected + 1` rejections in a row)
        // and the current run of rejections.
        let (mut used, mut rejected_run) = (0usize, 0usize);
        let mut delta = std::mem::take(&mut self.delta);
        let mut x_trial = std::mem::take(&mut self.x_trial);
        // The report's residual RMS at `x`, from the energy evaluation that accepted it.
        let mut rms_at_x = None;
        let result = (|| -> Result<()> {
            if e <= opts.energy_tol {
                report.stop = ShellStop::Converged;
                return Ok(());
            }
            while used < opts.max_iterations {
                let t_it = Instant::now();
                report.iterations += 1;
                // δᵀρ of an inexact (PCG) step, 0 for a factored one.
                let mut residual_term = 0.0;
                let solved = match opts.pcg {
                    Some(pcg) => match self.step_pcg(mu, &pcg, &mut delta) {
                        Some(out) => {
                            report.pcg_steps += 1;
                            report.pcg_iterations += out.iterations;
                            residual_term = out.residual_dot_step;
                            Ok(())
                        }
                        None => {
                            report.pcg_fallbacks += 1;
                            self.step(mu, opts.parallel_factor, &mut delta)
                        }
                    },
                    None => self.step(mu, opts.parallel_factor, &mut delta),
                };
                let accepted = match solved {
                    Err(MeshError::Numerical(_)) => None,
                    Err(err) => return Err(err),
                    Ok(()) => {
                        let step_inf = delta.iter().fold(0.0f64, |m, d| m.max(d.abs()));
                        let x_inf = x.iter().flatten().fold(0.0f64, |m, c| m.max(c.abs()));
                        if step_inf < opts.step_tol * (x_inf + opts.step_tol) {
                            report.iteration_seconds.push(t_it.elapsed().as_secs_f64());
                            report.energies.push(e);
                            report.stop = ShellStop::SmallStep;
                            return Ok(());
                        }
                        for (v, xt) in x_trial.iter_mut().enumerate() {
                            for c in 0..3 {
                                xt[c] = x[v][c] + delta[3 * v + c];
                            }
                        }
                        let e_new = energy_of(&self.topo, targets, &x_trial, &mut self.chunk_sums);
                        let mut pred = residual_term;
                        for c in 0..self.n {
                            pred += delta[c] * (mu * self.diag_scale[c] * delta[c] - self.grad[c]);
                        }
                        let rho = (e - e_new) / pred;
                        if e_new.is_finite() && pred > 0.0 && rho > 1e-3 {
                            Some((e_new, rho))
                        } else {
                            None
                        }
                    }
                };
                match accepted {
                    Some((e_new, rho)) => {
                        x.copy_from_slice(&x_trial);
                        rms_at_x = Some(rms_of_chunks(&self.chunk_sums, self.topo.n_edges()));
                        let rel = (e - e_new) / e;
                        used += 1;
                        rejected_run = 0;
                        // No re-linearisation after the last iteration: E(x) is e_new.
                        e = if used < opts.max_iterations {
                            self.linearize_unchecked(targets, x, opts.degenerate_height)?
                        } else {
                            self.linearized = false;
                            e_new
                        };
                        report.accepted += 1;
                        mu = (mu * (1.0 / 3.0f64).max(1.0 - (2.0 * rho - 1.0).powi(3))).max(MU_MIN);
                        nu = 2.0;
                        small = if rel < opts.rel_tol { small + 1 } else { 0 };
                    }
                    None => {
                        mu *= nu;
                        nu *= 2.0;
                        rejected_run += 1;
                        if rejected_run > opts.retry_rejected {
                            used += 1;
                            rejected_run = 0;
                        }
                    }
                }
                report.iteration_seconds.push(t_it.elapsed().as_secs_f64());
                report.energies.push(e);
                if e <= opts.energy_tol {
                    report.stop = ShellStop::Converged;
                    return Ok(());
                }
                if small >= 2 {
                    report.stop = ShellStop::SmallDecrease;
                    return Ok(());
                }
                if mu.is_nan() || mu > MU_MAX {
                    report.stop = ShellStop::DampingOverflow;
                    return Ok(());
                }
            }
            Ok(())
        })();
        self.delta = delta;
        self.x_trial = x_trial;
        result?;
        report.mu = mu;
        report.skipped_bend_rows = self.skipped;
        let (lr, ar) = rms_at_x.unwrap_or_else(|| residual_rms(&self.topo, targets, x));
        report.length_rms = lr;
        report.angle_rms = ar;
        report.total_seconds = t_start.elapsed().as_secs_f64();
        Ok(report)
    }
}

impl DenseSupports {
    fn new(solver: &ShellSolver, given: &[Vec<(u32, f64)>]) -> Result<Self> {
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
    fn lookup(&self, pc: &PointConstraint) -> Option<usize> {
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
    fn step(
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
struct PcgScratch {
    inv: Vec<[[f64; 3]; 3]>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    /// Buffers of the normal-matrix product's parts 1.. ([`PRODUCT_PARTS`]).
    parts: Vec<Vec<f64>>,
}

impl PcgScratch {
    /// Sizes the buffers for `n` unknowns (n/3 vertices); the blocks are zeroed.
    fn resize(&mut self, n: usize) {
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
fn chunks(v: &mut [f64]) -> rayon::slice::ChunksMut<'_, f64> {
    v.par_chunks_mut(3 * PCG_CHUNK)
}

fn sym3_inverse(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
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

/// Unweighted rms of `ℓ_e/ℓ*_e − 1` over all edges and of `wrap(φ_e − φ*_e)` over interior
/// edges of `x`.
pub fn residual_rms(topo: &Topology, targets: &ShellTargets, x: &[V3]) -> (f64, f64) {
    // Fixed chunks in parallel, their sums added in order: deterministic.
    let ne = topo.n_edges();
    let sums: Vec<(f64, f64, usize)> = (0..ne.div_ceil(EDGE_CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut sl, mut sa, mut na) = (0.0, 0.0, 0usize);
            for e in c * EDGE_CHUNK..((c + 1) * EDGE_CHUNK).min(ne) {
                let [i, j] = topo.edges[e];
                let (xi, xj) = (x[i as usize], x[j as usize]);
                let rl = norm(sub(xj, xi)) / targets.lengths[e] - 1.0;
                sl += rl * rl;
                let [k, l] = topo.edge_opposite[e];
                if l != NONE {
                    let phi = dihedral_angle(xi, xj, x[k as usize], x[l as usize]);
                    let ra = wrap_angle(phi - targets.angles[e]);
                    sa += ra * ra;
                    na += 1;
                }
            }
            (sl, sa, na)
        })
        .collect();
    let (sl, sa, na) = sums
        .iter()
        .fold((0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    (
        (sl / ne.max(1) as f64).sqrt(),
        (sa / na.max(1) as f64).sqrt(),
    )
}

/// Convenience (docs/design/shell-fit.md §1): refines `x` (typically `g`'s output for the same RLA) toward
/// the targets `ℓ* = ℓ_r(1 + RL)`, `φ* = φ_r + RA` with the default weights for `c_b`, building
/// a one-off [`ShellSolver`]. For repeated solves on one topology keep a solver instead.
pub fn refine(
    topo: &Topology,
    rest: &RestGeometry,
    rla: &Rla,
    x: &mut [V3],
    c_b: f64,
    opts: &ShellOptions,
) -> Result<ShellReport> {
    let targets = ShellTargets::from_rla(topo, rest, rla, x, c_b)?;
    ShellSolver::new(topo)?.solve(&targets, x, opts)
}

/// Stretch and bend residuals of edge `e` (bend 0 on boundary edges).
#[inline]
fn edge_residuals(topo: &Topology, t: &ShellTargets, x: &[V3], e: usize) -> (f64, f64) {
    let (rl, ra, _) = edge_residuals_raw(topo, t, x, e);
    (rl, ra)
}

/// The weighted residuals of [`edge_residuals`] and, for an interior edge, the unweighted
/// angle residual `wrap(φ − φ*)` (the length one is the weighted one over `√w`; see
/// [`residual_rms`]).
#[inline]
fn edge_residuals_raw(
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
struct ChunkSums {
    energy: f64,
    len_sq: f64,
    ang_sq: f64,
    n_ang: usize,
}

/// [`residual_rms`] from the chunk sums of the last [`energy_of`] (the same sums in the same
/// order: equal to it bit for bit).
fn rms_of_chunks(chunks: &[ChunkSums], ne: usize) -> (f64, f64) {
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
fn energy_of(topo: &Topology, t: &ShellTargets, x: &[V3], chunk_sums: &mut [ChunkSums]) -> f64 {
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
fn edge_rows(topo: &Topology, t: &ShellTargets, x: &[V3], e: usize, h_min: f64) -> EdgeRows {
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
struct PointSlots {
    verts: Vec<u32>,
    q: Vec<u32>,
}

/// Scatters the length and bend rows of `edges` (in their order) into `vals` and `grad`,
/// which hold the values from `col_ptr[3 v0]` and the gradient from `3 v0` on (every vertex
/// of these edges is ≥ `v0`).
#[allow(clippy::too_many_arguments)]
fn scatter_edges(
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
fn gather_diag(vals: &mut [f64], col_ptr: &[usize], val0: usize, a: usize, g: V3) {
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
fn gather_off<const N: usize>(
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
fn point_rows(pc: &PointConstraint, d: V3) -> [f64; 3] {
    let w = pc.weight.sqrt();
    match pc.normal {
        Some(n) => [w * dot(n, d), 0.0, 0.0],
        None => scale(d, w),
    }
}

/// `grad[3a..3a+3] += s·g`.
#[inline]
fn axpy(grad: &mut [f64], a: usize, g: V3, s: f64) {
    for c in 0..3 {
        grad[3 * a + c] += s * g[c];
    }
}
