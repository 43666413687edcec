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

mod assembly;
mod pcg;
mod targets;

use assembly::{ChunkSums, EdgeRows, PointSlots, energy_of, rms_of_chunks};
use pcg::{DenseSupports, PcgScratch};

pub use pcg::PcgOutcome;
pub use targets::{Handle, PointConstraint, ShellTargets};

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
