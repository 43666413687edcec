//! The reconstruction `g`: target edge lengths and dihedral angles (from RL, RA and a rest
//! shape) → vertex positions (PanoMan Appendix A; docs/design/rla-and-g.md §3).
//!
//! 1. **Local triangle coordinates.** Face `t = (p0, p1, p2)` gets `q0 = 0`, `q1 = (ℓ01, 0, 0)`,
//!    `q2 = (c, h, 0)` with `c = (ℓ01² + ℓ02² − ℓ12²)/(2ℓ01)`, `h = sqrt(max(ℓ02² − c², ε ℓ01²))`,
//!    so that `x_b − x_a = R_t (q_b − q_a)` for the triangle's world frame
//!    `R_t = [u v n]`, `u = (p1−p0)/|·|`, `n = (p1−p0)×(p2−p0)/|·|`, `v = n × u`.
//! 2. **Connection maps.** For interior edge `e = (i, j)` the diamond is embedded canonically
//!    from its 5 lengths and φ*: `P_i = 0`, `P_j = (ℓ,0,0)`, `P_k = (c_k, h_k, 0)`,
//!    `P_l = (c_l, −h_l cos φ, −h_l sin φ)`; with `R̃_L`, `R̃_R` the frames of fL, fR measured
//!    there by the same frame function, `Q_e = R̃_Lᵀ R̃_R`, and consistent world frames satisfy
//!    `R_fR = R_fL Q_e` (the paper prints the transposed relation).
//! 3. **Global frame solve.** `min E_F = Σ_e ‖R_fL Q_e − R_fR‖²_F` over rotations, one gauge
//!    face fixed per connected component. Start: the gauge frame propagated along a BFS tree
//!    of the dual graph (`R_child = R_parent Q_e`), exact for consistent data (no iteration).
//!    Then Gauss–Newton on SO(3) with world-frame increments `R_t ← exp([ω_t]×) R_t`: per
//!    interior edge, with `s_e = vee(skew(R_fR Q_eᵀ R_fLᵀ))`, `∇_{fL} E_F = −4 s_e`,
//!    `∇_{fR} E_F = +4 s_e`, and the Gauss–Newton Hessian `2JᵀJ` equals `4 (L ⊗ I₃)` at
//!    consistency, `L` the scalar dual-graph Laplacian (degree on the diagonal, −1 per interior
//!    edge), constant and factored once per topology; so `ω = −L⁻¹ (∇E_F/4)` (3 right-hand
//!    sides), with a backtracking line search on E_F. Unlike the linear relaxation over free
//!    3×3 matrices (`K Y = 0` with the gauge pinned), whose minimiser on non-integrable data
//!    (model RL/RA) shrinks every frame toward 0 away from the gauge so that the projection
//!    back to SO(3) is arbitrary, this minimises the frame energy over rotations themselves.
//! 4. **Poisson vertex solve.** `min Σ_t Σ_{(a→b)∈∂t} ‖x_b − x_a − R_t (q_b − q_a)‖²` with one
//!    gauge vertex fixed per component: its normal matrix is the uniform graph Laplacian
//!    (weight 2 per interior edge, 1 per boundary edge), factored once per topology.
//!
//! Everything that depends only on the topology lives in [`Reconstructor`]; per-call buffers
//! live in [`GWorkspace`], so repeated calls do not allocate.

use crate::error::{MeshError, Result};
use crate::geom::{M3, V3, cross, from_cols, matmul, normalize, sub, transpose};
use crate::rla::{RestGeometry, Rla};
use crate::sparse::SpdFactor;
use crate::topology::{NONE, Topology};
use faer::Mat;
use faer::dyn_stack::MemBuffer;
use rayon::prelude::*;

mod hessian;
mod linear;
pub use linear::{GDerivative, GLinearization};

/// Clamp ε of the triangle height: `h ≥ sqrt(ε)·ℓ01` (handles blended lengths that violate the
/// triangle inequality, docs/design/rla-and-g.md §3.6).
const HEIGHT_EPS: f64 = 1e-12;
/// Faces per rayon task.
const FACE_CHUNK: usize = 2048;
/// `‖∇E_F‖` below which the Newton polish stops: `E_F` sums O(1) terms per edge (rotation
/// matrices), so its gradient's rounding floor on ~10⁵ edges is ~10⁻¹³; one Newton step from
/// the Gauss–Newton result (~10⁻⁸) lands there.
const NEWTON_FLOOR: f64 = 1e-12;

/// The frame `[u v n]` (columns) of the triangle (p0, p1, p2), see the module docs.
#[inline]
pub fn triangle_frame(p0: V3, p1: V3, p2: V3) -> M3 {
    let a = sub(p1, p0);
    let u = normalize(a);
    let n = normalize(cross(a, sub(p2, p0)));
    let v = cross(n, u);
    from_cols(u, v, n)
}

/// Local coordinates `(c, h)` of the third corner of a triangle with side lengths
/// `ℓ01, ℓ02, ℓ12`, i.e. `q2 = (c, h, 0)` when `q0 = 0`, `q1 = (ℓ01, 0, 0)`.
#[inline]
pub fn third_corner(l01: f64, l02: f64, l12: f64) -> (f64, f64) {
    let c = (l01 * l01 + l02 * l02 - l12 * l12) / (2.0 * l01);
    let c = c.clamp(-l02, l02);
    let h = (l02 * l02 - c * c).max(HEIGHT_EPS * l01 * l01).sqrt();
    (c, h)
}

/// The gauge of `g`: the rotation of one face and the position of one vertex per connected
/// component (g is defined up to one rigid motion per component).
#[derive(Clone, Debug, PartialEq)]
pub struct Gauge {
    /// Frame of the gauge face of each component (see [`Reconstructor::gauge_faces`]).
    pub frames: Vec<M3>,
    /// Position of the gauge vertex of each component (see [`Reconstructor::gauge_vertices`]).
    pub positions: Vec<V3>,
}

/// Statistics of one `g` call.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GStats {
    /// Gauss–Newton iterations of the frame solve (0 for exactly consistent data).
    pub frame_iterations: usize,
    /// Frame energy `E_F = Σ_e ‖R_fL Q_e − R_fR‖²_F` of the tree-propagated start.
    pub frame_energy_start: f64,
    /// Final frame energy.
    pub frame_energy: f64,
    /// Whether the frame solve met its tolerance (false: it stopped at the iteration cap or
    /// when the line search found no decrease, with the best iterate).
    pub frame_converged: bool,
    /// Newton steps kept ([`GWorkspace::newton_steps`]).
    pub newton_steps: usize,
    /// `‖∇E_F‖` at the returned frames (computed only with Newton steps; else 0).
    pub frame_gradient: f64,
    /// Target lengths raised to the floor `ℓ_r·MIN_RELATIVE_LENGTH` (RL < −1 + floor), by
    /// [`Reconstructor::reconstruct_rla`].
    pub clamped_lengths: usize,
}

/// Per-topology state of `g`: tables, gauge choice, BFS tree and the two constant Cholesky
/// factors (dual-graph Laplacian for the frame solve's Hessian, vertex Laplacian for Poisson).
pub struct Reconstructor {
    topo: Topology,
    /// Per face: slot of each edge's first vertex in the face (`faces[f][slot] == edges[e][0]`
    /// or the face runs the edge backwards).
    gauge_faces: Vec<u32>,
    gauge_vertices: Vec<u32>,
    face_red: Vec<u32>,
    vert_red: Vec<u32>,
    n_face_red: usize,
    n_vert_red: usize,
    /// BFS order over the dual graph: (face, parent face, edge); roots are the gauge faces.
    tree: Vec<(u32, u32, u32)>,
    dual_factor: SpdFactor,
    vert_factor: SpdFactor,
    /// Vertex-Laplacian couplings to gauge vertices: (reduced vertex, component, weight).
    gauge_couplings: Vec<(u32, u32, f64)>,
    /// Iteration cap of the frame solve's Gauss–Newton (integrable data needs 0; model-like
    /// blended RLA on the full template ~10–30).
    pub max_frame_iterations: usize,
    /// The frame solve stops when an iteration lowers E_F by less than this fraction.
    pub frame_tolerance: f64,
}

impl std::fmt::Debug for Reconstructor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reconstructor")
            .field("faces", &self.topo.n_faces())
            .field("vertices", &self.topo.n_vertices)
            .field("components", &self.gauge_faces.len())
            .finish()
    }
}

/// Per-call buffers of `g` (created once per [`Reconstructor`], reused across calls).
pub struct GWorkspace {
    /// Target lengths ℓ* (#E).
    pub lengths: Vec<f64>,
    /// Target angles φ* (#E).
    pub angles: Vec<f64>,
    /// Per face: (ℓ01, c, h) of the local coordinates.
    local: Vec<[f64; 3]>,
    /// Per edge: connection map Q_e (identity on boundary edges).
    conn: Vec<M3>,
    /// Face frames R_t (tree-propagated, then the frame solve's iterate).
    frames: Vec<M3>,
    /// The frames before a line-search trial.
    frames_prev: Vec<M3>,
    /// Per edge: `s_e` of the frame gradient (module docs).
    s_edge: Vec<V3>,
    /// Per edge chunk: partial sums of E_F (deterministic reduction).
    chunk_sums: Vec<f64>,
    /// Reduced face gradient / Gauss–Newton step (#non-gauge faces × 3).
    step: Mat<f64>,
    step_scratch: MemBuffer,
    vrhs: Mat<f64>,
    v_scratch: MemBuffer,
    /// Newton steps after the frame solve's Gauss–Newton iteration (0: none, the default):
    /// each solves `H ω = −∇E_F` with the full Hessian (recon/hessian.rs) and is kept while it
    /// lowers `‖∇E_F‖`, so that the frames reach the minimiser to rounding (for derivatives
    /// that finite differences must confirm, [`GDerivative::Exact`]).
    pub newton_steps: usize,
    /// The Newton polish's conjugate-gradient buffers (allocated on first use).
    newton: Option<hessian::Pcg>,
    /// Statistics of the last call.
    pub stats: GStats,
}

/// The gauge face of every face component and the gauge vertex of every vertex component
/// (the first vertex of its component's gauge face).
///
/// # Errors
/// [`MeshError::Topology`] if face and vertex components disagree.
fn gauges(topo: &Topology) -> Result<(Vec<u32>, Vec<u32>)> {
    let nf = topo.n_faces();
    let ncomp = topo.n_face_components;
    // Gauge face per component: the (approximate) centre of its dual graph — the midpoint
    // of a double-sweep BFS diameter path — which halves the longest path from the gauge
    // and so the drift of frames on non-integrable data.
    let mut gauge_faces = vec![NONE; ncomp];
    for f in 0..nf {
        let c = topo.face_component[f] as usize;
        if gauge_faces[c] == NONE {
            gauge_faces[c] = f as u32;
        }
    }
    for g in gauge_faces.iter_mut() {
        let (far, _) = dual_bfs(topo, *g);
        let (other, parent) = dual_bfs(topo, far);
        let mut path = vec![other];
        while *path.last().unwrap() != far {
            path.push(parent[*path.last().unwrap() as usize]);
        }
        *g = path[path.len() / 2];
    }
    let mut gauge_vertices = vec![NONE; ncomp];
    for (c, &f) in gauge_faces.iter().enumerate() {
        let v = topo.faces[f as usize][0];
        let vc = topo.vertex_component[v as usize] as usize;
        if gauge_vertices[vc] != NONE {
            return Err(MeshError::Topology(
                "face and vertex components disagree".into(),
            ));
        }
        gauge_vertices[vc] = v;
        let _ = c;
    }
    Ok((gauge_faces, gauge_vertices))
}

impl Reconstructor {
    /// Builds the per-topology state: gauge choice (the dual-graph centre face of each
    /// component and its first vertex), BFS tree, and the Cholesky factors of the dual-graph Laplacian and
    /// the vertex Laplacian with the gauges removed.
    pub fn new(topo: &Topology) -> Result<Self> {
        let nf = topo.n_faces();
        let nv = topo.n_vertices;
        let ncomp = topo.n_face_components;
        if topo.n_vertex_components != ncomp {
            return Err(MeshError::Topology(format!(
                "{} vertex components but {} face components",
                topo.n_vertex_components, ncomp
            )));
        }
        let (gauge_faces, gauge_vertices) = gauges(topo)?;

        // Reduced numbering (gauges removed).
        let mut face_red = vec![NONE; nf];
        let mut n_face_red = 0usize;
        let mut is_gauge_face = vec![false; nf];
        for &g in &gauge_faces {
            is_gauge_face[g as usize] = true;
        }
        for f in 0..nf {
            if !is_gauge_face[f] {
                face_red[f] = n_face_red as u32;
                n_face_red += 1;
            }
        }
        let mut vert_red = vec![NONE; nv];
        let mut gauge_comp_of_vertex = vec![NONE; nv];
        for (c, &g) in gauge_vertices.iter().enumerate() {
            gauge_comp_of_vertex[g as usize] = c as u32;
        }
        let mut n_vert_red = 0usize;
        for v in 0..nv {
            if gauge_comp_of_vertex[v] == NONE {
                vert_red[v] = n_vert_red as u32;
                n_vert_red += 1;
            }
        }

        // BFS tree over the dual graph.
        let mut tree = Vec::with_capacity(nf);
        let mut seen = is_gauge_face.clone();
        let mut queue = std::collections::VecDeque::new();
        for &g in &gauge_faces {
            queue.push_back(g);
        }
        while let Some(f) = queue.pop_front() {
            for &(o, e) in topo.dual_neighbors_of(f as usize) {
                if !seen[o as usize] {
                    seen[o as usize] = true;
                    tree.push((o, f, e));
                    queue.push_back(o);
                }
            }
        }
        debug_assert_eq!(tree.len() + ncomp, nf);

        // Dual-graph Laplacian (unit weights) without the gauge faces.
        let mut face_degree = vec![0.0; nf];
        let mut trips = Vec::with_capacity(nf + topo.n_interior_edges());
        for f in 0..nf {
            face_degree[f] = topo.dual_neighbors_of(f).len() as f64;
        }
        for f in 0..nf {
            let rf = face_red[f];
            if rf == NONE {
                continue;
            }
            trips.push((rf as usize, rf as usize, face_degree[f]));
            for &(o, _) in topo.dual_neighbors_of(f) {
                let ro = face_red[o as usize];
                if ro != NONE && ro < rf {
                    trips.push((rf as usize, ro as usize, -1.0));
                }
            }
        }
        let simplicial = true;
        let dual_factor = if n_face_red > 0 {
            SpdFactor::from_triplets_with_layout(n_face_red, &trips, simplicial)?
        } else {
            SpdFactor::from_triplets(1, &[(0, 0, 1.0)])?
        };

        // Vertex Laplacian: weight = number of faces on the edge.
        let mut vdeg = vec![0.0; nv];
        let mut trips = Vec::with_capacity(nv + topo.n_edges());
        let mut gauge_couplings = Vec::new();
        for (e, &[a, b]) in topo.edges.iter().enumerate() {
            let w = if topo.is_interior(e) { 2.0 } else { 1.0 };
            vdeg[a as usize] += w;
            vdeg[b as usize] += w;
            let (ra, rb) = (vert_red[a as usize], vert_red[b as usize]);
            match (ra != NONE, rb != NONE) {
                (true, true) => trips.push((ra.max(rb) as usize, ra.min(rb) as usize, -w)),
                (true, false) => gauge_couplings.push((ra, gauge_comp_of_vertex[b as usize], w)),
                (false, true) => gauge_couplings.push((rb, gauge_comp_of_vertex[a as usize], w)),
                (false, false) => {}
            }
        }
        for v in 0..nv {
            if vert_red[v] != NONE {
                trips.push((vert_red[v] as usize, vert_red[v] as usize, vdeg[v]));
            }
        }
        let vert_factor = if n_vert_red > 0 {
            SpdFactor::from_triplets_with_layout(n_vert_red, &trips, simplicial)?
        } else {
            SpdFactor::from_triplets(1, &[(0, 0, 1.0)])?
        };

        Ok(Self {
            topo: topo.clone(),
            gauge_faces,
            gauge_vertices,
            face_red,
            vert_red,
            n_face_red,
            n_vert_red,
            tree,
            dual_factor,
            vert_factor,
            gauge_couplings,
            max_frame_iterations: 50,
            frame_tolerance: 1e-8,
        })
    }

    /// The topology this reconstructor was built for.
    pub fn topology(&self) -> &Topology {
        &self.topo
    }

    /// The gauge face of each connected component.
    pub fn gauge_faces(&self) -> &[u32] {
        &self.gauge_faces
    }

    /// The gauge vertex of each connected component.
    pub fn gauge_vertices(&self) -> &[u32] {
        &self.gauge_vertices
    }

    /// The gauge that places the output like `positions` (e.g. the rest shape): the gauge faces'
    /// frames and gauge vertices' positions measured on it.
    pub fn gauge_from(&self, positions: &[V3]) -> Result<Gauge> {
        crate::rla::check_positions(&self.topo, positions, "gauge mesh")?;
        let frames = self
            .gauge_faces
            .iter()
            .map(|&f| {
                let [a, b, c] = self.topo.faces[f as usize];
                triangle_frame(
                    positions[a as usize],
                    positions[b as usize],
                    positions[c as usize],
                )
            })
            .collect();
        let positions = self
            .gauge_vertices
            .iter()
            .map(|&v| positions[v as usize])
            .collect();
        Ok(Gauge { frames, positions })
    }

    /// Adds to `grad` (#V) the gradient with respect to the vertices of `mesh` of `⟨u, x⟩`,
    /// where `x` (#V) is a `g` output placed by [`Reconstructor::gauge_from`]`(mesh)`, through
    /// that gauge alone: per component, a change of the gauge face's frame by `exp([θ]×)` and
    /// of the gauge vertex by `δp` moves the component rigidly, `δx_v = θ × (x_v − p) + δp`, so
    /// `p̄ = Σ_v u_v` and `θ̄ = Σ_v (x_v − p) × u_v`; `θ̄` reaches the gauge face's three vertices
    /// through the derivative of [`triangle_frame`] (central differences of that closed form,
    /// step 10⁻⁶ of the face's first edge; truncation ~10⁻¹² relative).
    ///
    /// # Errors
    /// [`MeshError::Mismatch`] on size mismatches.
    pub fn gauge_gradient_add(
        &self,
        mesh: &[V3],
        x: &[V3],
        u: &[V3],
        grad: &mut [V3],
    ) -> Result<()> {
        let topo = &self.topo;
        let nv = topo.n_vertices;
        if mesh.len() != nv || x.len() != nv || u.len() != nv || grad.len() != nv {
            return Err(MeshError::Mismatch(format!(
                "gauge gradient: {} / {} / {} / {} vertices for a topology of {nv}",
                mesh.len(),
                x.len(),
                u.len(),
                grad.len()
            )));
        }
        for &f in &self.gauge_faces {
            let tri = topo.faces[f as usize];
            let comp = topo.vertex_component[tri[0] as usize];
            let p = x[tri[0] as usize];
            let (mut pbar, mut tbar) = ([0.0; 3], [0.0; 3]);
            for v in 0..nv {
                if topo.vertex_component[v] != comp {
                    continue;
                }
                pbar = crate::geom::add(pbar, u[v]);
                tbar = crate::geom::add(tbar, cross(sub(x[v], p), u[v]));
            }
            for c in 0..3 {
                grad[tri[0] as usize][c] += pbar[c];
            }
            let corners = tri.map(|v| mesh[v as usize]);
            let r = triangle_frame(corners[0], corners[1], corners[2]);
            let h = 1e-6 * crate::geom::norm(sub(corners[1], corners[0]));
            for k in 0..3 {
                for d in 0..3 {
                    let eval = |s: f64| {
                        let mut q = corners;
                        q[k][d] += s;
                        triangle_frame(q[0], q[1], q[2])
                    };
                    let (rp, rm) = (eval(h), eval(-h));
                    // θ = vee(δR Rᵀ) per unit move of corner k's coordinate d.
                    let mut dr = [[0.0; 3]; 3];
                    for (a, row) in dr.iter_mut().enumerate() {
                        for (b, v) in row.iter_mut().enumerate() {
                            *v = (rp[a][b] - rm[a][b]) / (2.0 * h);
                        }
                    }
                    let w = matmul(&dr, &transpose(&r));
                    let theta = [
                        0.5 * (w[2][1] - w[1][2]),
                        0.5 * (w[0][2] - w[2][0]),
                        0.5 * (w[1][0] - w[0][1]),
                    ];
                    grad[tri[k] as usize][d] += crate::geom::dot(theta, tbar);
                }
            }
        }
        Ok(())
    }

    /// The identity gauge: gauge faces' frames = I, gauge vertices at the origin.
    pub fn identity_gauge(&self) -> Gauge {
        Gauge {
            frames: vec![crate::geom::IDENTITY; self.gauge_faces.len()],
            positions: vec![[0.0; 3]; self.gauge_faces.len()],
        }
    }

    /// Allocates the per-call buffers.
    pub fn workspace(&self) -> GWorkspace {
        let nf = self.topo.n_faces();
        let ne = self.topo.n_edges();
        let nfr = self.n_face_red.max(1);
        let nvr = self.n_vert_red.max(1);
        GWorkspace {
            lengths: vec![0.0; ne],
            angles: vec![0.0; ne],
            local: vec![[0.0; 3]; nf],
            conn: vec![crate::geom::IDENTITY; ne],
            frames: vec![crate::geom::IDENTITY; nf],
            frames_prev: vec![crate::geom::IDENTITY; nf],
            s_edge: vec![[0.0; 3]; ne],
            chunk_sums: vec![0.0; ne.div_ceil(FACE_CHUNK)],
            step: Mat::zeros(nfr, 3),
            step_scratch: self.dual_factor.make_scratch(3),
            vrhs: Mat::zeros(nvr, 3),
            v_scratch: self.vert_factor.make_scratch(3),
            newton_steps: 0,
            newton: None,
            stats: GStats::default(),
        }
    }

    /// `g(RL, RA, rest)`: the vertices whose edge lengths and dihedral angles best match
    /// `ℓ* = ℓ_r ⊙ (1 + RL)`, `φ* = φ_r + RA`, placed by `gauge`, written to `out` (#V).
    pub fn reconstruct_rla(
        &self,
        ws: &mut GWorkspace,
        rest: &RestGeometry,
        rla: &Rla,
        gauge: &Gauge,
        out: &mut [V3],
    ) -> Result<GStats> {
        let ne = self.topo.n_edges();
        if rla.rl.len() != ne || rla.ra.len() != ne || rest.lengths.len() != ne {
            return Err(MeshError::Mismatch(format!(
                "RLA has {} RL and {} RA values (rest: {}), the topology has {ne} edges",
                rla.rl.len(),
                rla.ra.len(),
                rest.lengths.len()
            )));
        }
        let (mut lengths, mut angles) = (
            std::mem::take(&mut ws.lengths),
            std::mem::take(&mut ws.angles),
        );
        if let Some(e) = rla.rl.iter().chain(&rla.ra).position(|x| !x.is_finite()) {
            return Err(MeshError::NonFinite(format!(
                "RLA value {e} is {}",
                if e < ne { rla.rl[e] } else { rla.ra[e - ne] }
            )));
        }
        let clamped = rest.targets_into(rla, &mut lengths, &mut angles);
        let res = self.reconstruct(ws, &lengths, &angles, gauge, out);
        ws.lengths = lengths;
        ws.angles = angles;
        ws.stats.clamped_lengths = clamped;
        res.map(|mut st| {
            st.clamped_lengths = clamped;
            st
        })
    }

    /// `g` from target lengths ℓ* (#E, > 0) and target signed dihedral angles φ* (#E; ignored
    /// on boundary edges), placed by `gauge`; writes #V positions to `out`.
    pub fn reconstruct(
        &self,
        ws: &mut GWorkspace,
        lengths: &[f64],
        angles: &[f64],
        gauge: &Gauge,
        out: &mut [V3],
    ) -> Result<GStats> {
        self.check_inputs(lengths, angles, gauge, out)?;
        let topo = &self.topo;
        let nv = topo.n_vertices;

        // 1. Local coordinates per face.
        ws.local
            .par_chunks_mut(FACE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (off, loc) in chunk.iter_mut().enumerate() {
                    let fe = topo.face_edges[c * FACE_CHUNK + off];
                    let (l01, l12, l20) = (
                        lengths[fe[0] as usize],
                        lengths[fe[1] as usize],
                        lengths[fe[2] as usize],
                    );
                    let (cx, h) = third_corner(l01, l20, l12);
                    *loc = [l01, cx, h];
                }
            });

        // 2. Connection maps per interior edge.
        ws.conn
            .par_chunks_mut(FACE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (off, q) in chunk.iter_mut().enumerate() {
                    let e = c * FACE_CHUNK + off;
                    if topo.is_interior(e) {
                        *q = connection_map(topo, e, lengths, angles[e]);
                    }
                }
            });

        // 3a. Tree-propagated frames (exact for consistent data).
        for (comp, &g) in self.gauge_faces.iter().enumerate() {
            ws.frames[g as usize] = gauge.frames[comp];
        }
        for &(f, parent, e) in &self.tree {
            let rp = ws.frames[parent as usize];
            let q = &ws.conn[e as usize];
            ws.frames[f as usize] = if topo.edge_faces[e as usize][0] == parent {
                matmul(&rp, q)
            } else {
                matmul(&rp, &transpose(q))
            };
        }
        // 3b. Gauss–Newton on SO(3) (module docs).
        let frame_stats = self.frame_solve(ws)?;

        // 5. Poisson vertex solve.
        let frames = &ws.frames;
        let vrhs = &mut ws.vrhs;
        vrhs.fill(0.0);
        let mut add = |v: u32, d: V3, sgn: f64| {
            let rv = self.vert_red[v as usize];
            if rv != NONE {
                for c in 0..3 {
                    vrhs[(rv as usize, c)] += sgn * d[c];
                }
            }
        };
        for (f, tri) in topo.faces.iter().enumerate() {
            let [l01, cx, h] = ws.local[f];
            let r = &frames[f];
            // Half-edge vectors in world: R (q_b − q_a).
            let d01 = [r[0][0] * l01, r[1][0] * l01, r[2][0] * l01];
            let d02 = [
                r[0][0] * cx + r[0][1] * h,
                r[1][0] * cx + r[1][1] * h,
                r[2][0] * cx + r[2][1] * h,
            ];
            let d12 = sub(d02, d01);
            add(tri[1], d01, 1.0);
            add(tri[0], d01, -1.0);
            add(tri[2], d12, 1.0);
            add(tri[1], d12, -1.0);
            add(tri[0], d02, -1.0); // half-edge 2→0 carries −d02
            add(tri[2], d02, 1.0);
        }
        for &(rv, comp, w) in &self.gauge_couplings {
            let x = gauge.positions[comp as usize];
            for c in 0..3 {
                vrhs[(rv as usize, c)] += w * x[c];
            }
        }
        if self.n_vert_red > 0 {
            self.vert_factor
                .solve_in_place(vrhs.as_mut(), &mut ws.v_scratch);
        }
        for v in 0..nv {
            let rv = self.vert_red[v];
            if rv != NONE {
                out[v] = [
                    vrhs[(rv as usize, 0)],
                    vrhs[(rv as usize, 1)],
                    vrhs[(rv as usize, 2)],
                ];
            }
        }
        for (comp, &g) in self.gauge_vertices.iter().enumerate() {
            out[g as usize] = gauge.positions[comp];
        }
        if let Some(v) = out.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(MeshError::Numerical(format!(
                "g produced a non-finite position at vertex {v}"
            )));
        }
        ws.stats = frame_stats;
        Ok(ws.stats)
    }

    /// The size and finiteness checks of [`Reconstructor::reconstruct`].
    fn check_inputs(
        &self,
        lengths: &[f64],
        angles: &[f64],
        gauge: &Gauge,
        out: &[V3],
    ) -> Result<()> {
        let topo = &self.topo;
        let (ne, nv) = (topo.n_edges(), topo.n_vertices);
        if lengths.len() != ne || angles.len() != ne {
            return Err(MeshError::Mismatch(format!(
                "{} target lengths and {} angles for {ne} edges",
                lengths.len(),
                angles.len()
            )));
        }
        if out.len() != nv {
            return Err(MeshError::Mismatch(format!(
                "output has {} vertices, the topology has {nv}",
                out.len()
            )));
        }
        if gauge.frames.len() != self.gauge_faces.len()
            || gauge.positions.len() != self.gauge_faces.len()
        {
            return Err(MeshError::Mismatch(format!(
                "gauge has {} frames / {} positions for {} components",
                gauge.frames.len(),
                gauge.positions.len(),
                self.gauge_faces.len()
            )));
        }
        if let Some(e) = lengths.iter().position(|l| !(l.is_finite() && *l > 0.0)) {
            return Err(MeshError::NonFinite(format!(
                "target length of edge {e} is {} (must be finite and > 0)",
                lengths[e]
            )));
        }
        if let Some(e) = angles.iter().position(|a| !a.is_finite()) {
            return Err(MeshError::NonFinite(format!(
                "target angle of edge {e} is {}",
                angles[e]
            )));
        }
        Ok(())
    }

    /// E_F of `frames` (deterministic chunked sum).
    fn frame_energy(&self, frames: &[M3], conn: &[M3], chunk_sums: &mut [f64]) -> f64 {
        let topo = &self.topo;
        chunk_sums.par_iter_mut().enumerate().for_each(|(c, sum)| {
            let lo = c * FACE_CHUNK;
            let hi = (lo + FACE_CHUNK).min(topo.n_edges());
            *sum = (lo..hi)
                .filter(|&e| topo.edge_faces[e][1] != NONE)
                .map(|e| {
                    let [fl, fr] = topo.edge_faces[e];
                    let a = matmul(&frames[fl as usize], &conn[e]);
                    crate::geom::frobenius_diff(&a, &frames[fr as usize]).powi(2)
                })
                .sum();
        });
        chunk_sums.iter().sum()
    }

    /// E_F of `frames` (as [`Reconstructor::frame_energy`], the same sums) and, in the same
    /// pass, `s_e` per edge into `s_edge` (module docs; 0 on boundary edges).
    fn energy_and_s(
        &self,
        frames: &[M3],
        conn: &[M3],
        chunk_sums: &mut [f64],
        s_edge: &mut [V3],
    ) -> f64 {
        let topo = &self.topo;
        chunk_sums
            .par_iter_mut()
            .zip(s_edge.par_chunks_mut(FACE_CHUNK))
            .enumerate()
            .for_each(|(c, (sum, chunk))| {
                *sum = chunk
                    .iter_mut()
                    .enumerate()
                    .filter_map(|(off, s)| {
                        let e = c * FACE_CHUNK + off;
                        let [fl, fr] = topo.edge_faces[e];
                        if fr == NONE {
                            *s = [0.0; 3];
                            return None;
                        }
                        let a = matmul(&frames[fl as usize], &conn[e]);
                        let b = &frames[fr as usize];
                        let m = matmul(b, &transpose(&a));
                        *s = [
                            0.5 * (m[2][1] - m[1][2]),
                            0.5 * (m[0][2] - m[2][0]),
                            0.5 * (m[1][0] - m[0][1]),
                        ];
                        Some(crate::geom::frobenius_diff(&a, b).powi(2))
                    })
                    .sum();
            });
        chunk_sums.iter().sum()
    }

    /// `∇E_F / 4` at `ws.frames` into `ws.step` (reduced faces × 3), with `s_e` in `ws.s_edge`.
    fn gradient_into(&self, ws: &mut GWorkspace) {
        self.energy_and_s(&ws.frames, &ws.conn, &mut ws.chunk_sums, &mut ws.s_edge);
        self.accumulate_gradient(ws);
    }

    /// `∇E_F / 4` into `ws.step` from the `s_e` in `ws.s_edge`.
    fn accumulate_gradient(&self, ws: &mut GWorkspace) {
        let topo = &self.topo;
        for f in 0..topo.n_faces() {
            let rf = self.face_red[f];
            if rf == NONE {
                continue;
            }
            let mut g = [0.0; 3];
            for &(_, edge) in topo.dual_neighbors_of(f) {
                let s = ws.s_edge[edge as usize];
                let sign = if topo.edge_faces[edge as usize][0] as usize == f {
                    -1.0
                } else {
                    1.0
                };
                for c in 0..3 {
                    g[c] += sign * s[c];
                }
            }
            for c in 0..3 {
                ws.step[(rf as usize, c)] = g[c];
            }
        }
    }

    /// Applies `R_f ← exp([−t·step_f]×) R_f` to `ws.frames` from `ws.frames_prev`.
    fn rotate_frames(&self, ws: &mut GWorkspace, t: f64) {
        let (step, prev) = (&ws.step, &ws.frames_prev);
        ws.frames
            .par_chunks_mut(FACE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (off, r) in chunk.iter_mut().enumerate() {
                    let f = c * FACE_CHUNK + off;
                    let rf = self.face_red[f];
                    if rf == NONE {
                        continue;
                    }
                    let w = [0, 1, 2].map(|k| -t * step[(rf as usize, k)]);
                    let a = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                    *r = if a > 0.0 {
                        matmul(&crate::rotation::axis_angle(w, a), &prev[f])
                    } else {
                        prev[f]
                    };
                }
            });
    }

    /// `‖∇E_F‖` from `ws.step` holding `∇E_F / 4`.
    fn gradient_norm(ws: &GWorkspace) -> f64 {
        4.0 * (0..3)
            .map(|c| ws.step.col(c).iter().map(|x| x * x).sum::<f64>())
            .sum::<f64>()
            .sqrt()
    }

    /// The Newton polish ([`GWorkspace::newton_steps`]): steps `ω = −H⁻¹ ∇E_F`, each kept
    /// only if it lowers `‖∇E_F‖`.
    fn newton_polish(&self, ws: &mut GWorkspace, stats: &mut GStats) {
        self.gradient_into(ws);
        let mut gnorm = Self::gradient_norm(ws);
        let mut pcg = ws
            .newton
            .take()
            .unwrap_or_else(|| hessian::Pcg::new(self.n_face_red.max(1)));
        for _ in 0..ws.newton_steps {
            if gnorm == 0.0 {
                break;
            }
            let edges = hessian::edge_curvatures(&self.topo, &ws.frames, &ws.conn);
            // H ω = −4 (∇E_F/4); `rotate_frames` applies −t·step, so solve for −ω. Inexact
            // Newton: the linear residual need only fall below a tenth of the floor.
            ws.step *= faer::Scale(4.0);
            let tolerance = (0.1 * NEWTON_FLOOR / gnorm).clamp(hessian::PCG_TOLERANCE, 0.1);
            if pcg
                .solve(self, &edges, &mut ws.step, &mut ws.step_scratch, tolerance)
                .is_err()
            {
                break;
            }
            ws.frames_prev.copy_from_slice(&ws.frames);
            self.rotate_frames(ws, 1.0);
            self.gradient_into(ws);
            let g_new = Self::gradient_norm(ws);
            if g_new.partial_cmp(&gnorm) != Some(std::cmp::Ordering::Less) {
                ws.frames.copy_from_slice(&ws.frames_prev);
                self.gradient_into(ws);
                break;
            }
            gnorm = g_new;
            stats.newton_steps += 1;
            if gnorm <= NEWTON_FLOOR {
                break;
            }
        }
        stats.frame_gradient = gnorm;
        ws.newton = Some(pcg);
    }

    /// Gauss–Newton on SO(3) for the frames in `ws.frames` (module docs, step 3): the
    /// constant Hessian `4 (L ⊗ I₃)` through the dual-graph factor, backtracking on E_F.
    fn frame_solve(&self, ws: &mut GWorkspace) -> Result<GStats> {
        let topo = &self.topo;
        // E_F and s_e in one pass: an accepted trial's pass leaves the next gradient's s_e.
        let mut e = self.energy_and_s(&ws.frames, &ws.conn, &mut ws.chunk_sums, &mut ws.s_edge);
        let mut stats = GStats {
            frame_energy_start: e,
            frame_energy: e,
            frame_converged: true,
            ..GStats::default()
        };
        if self.n_face_red == 0 || e <= 1e-24 * topo.n_edges() as f64 {
            return Ok(stats);
        }
        stats.frame_converged = false;
        for _ in 0..self.max_frame_iterations {
            self.accumulate_gradient(ws);
            self.dual_factor
                .solve_in_place(ws.step.as_mut(), &mut ws.step_scratch);
            ws.frames_prev.copy_from_slice(&ws.frames);
            let mut accepted = false;
            let mut t = 1.0;
            for _ in 0..8 {
                self.rotate_frames(ws, t);
                let e_new =
                    self.energy_and_s(&ws.frames, &ws.conn, &mut ws.chunk_sums, &mut ws.s_edge);
                if e_new.is_finite() && e_new < e {
                    stats.frame_iterations += 1;
                    let rel = (e - e_new) / e;
                    e = e_new;
                    accepted = true;
                    if rel < self.frame_tolerance {
                        stats.frame_converged = true;
                    }
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                // No decrease along the Gauss–Newton direction even at 1/128 of the step:
                // stop with the best iterate; `frame_converged` stays false.
                ws.frames.copy_from_slice(&ws.frames_prev);
                break;
            }
            if stats.frame_converged {
                break;
            }
        }
        if !e.is_finite() {
            return Err(MeshError::Numerical(
                "frame solve diverged (non-finite energy)".into(),
            ));
        }
        // The polish refines a Gauss–Newton result that converged or stopped at the energy's
        // rounding (no decrease); at the iteration cap the frames are not near a minimum (far
        // from consistent data) and Newton would not help.
        if ws.newton_steps > 0
            && (stats.frame_converged || stats.frame_iterations < self.max_frame_iterations)
        {
            self.newton_polish(ws, &mut stats);
            e = self.frame_energy(&ws.frames, &ws.conn, &mut ws.chunk_sums);
        }
        stats.frame_energy = e;
        Ok(stats)
    }
}

/// BFS over the dual graph from `start`: the last face reached (a farthest one) and the BFS
/// parent of every reached face.
fn dual_bfs(topo: &Topology, start: u32) -> (u32, Vec<u32>) {
    let mut parent = vec![NONE; topo.n_faces()];
    parent[start as usize] = start;
    let mut queue = std::collections::VecDeque::from([start]);
    let mut last = start;
    while let Some(f) = queue.pop_front() {
        last = f;
        for &(o, _) in topo.dual_neighbors_of(f as usize) {
            if parent[o as usize] == NONE {
                parent[o as usize] = f;
                queue.push_back(o);
            }
        }
    }
    (last, parent)
}

/// `Q_e` of interior edge `e` from its five target lengths and its target angle φ*, by the
/// canonical diamond embedding (see the module docs).
pub fn connection_map(topo: &Topology, e: usize, lengths: &[f64], phi: f64) -> M3 {
    let (sl, sr, ids) = diamond_edges(topo, e);
    diamond_map(sl, sr, ids.map(|k| lengths[k as usize]), phi)
}

/// The diamond of interior edge `e = (i, j)`: the slot of `i` in fL, the slot of `j` in fR, and
/// the edges whose lengths `Q_e` reads, in the order `[ij, jk, ik, il, jl]` (fL = (i, j, k),
/// fR = (j, i, l)).
pub(crate) fn diamond_edges(topo: &Topology, e: usize) -> (usize, usize, [u32; 5]) {
    let [i, j] = topo.edges[e];
    let [fl, fr] = topo.edge_faces[e];
    let tl = topo.faces[fl as usize];
    let tr = topo.faces[fr as usize];
    let sl = tl.iter().position(|&v| v == i).unwrap_or(0);
    let sr = tr.iter().position(|&v| v == j).unwrap_or(0);
    let fel = topo.face_edges[fl as usize];
    let fer = topo.face_edges[fr as usize];
    // fL = (i, j, k) from slot sl: slot sl+1 is j→k, slot sl+2 is k→i.
    // fR = (j, i, l) from slot sr: slot sr+1 is i→l, slot sr+2 is l→j.
    (
        sl,
        sr,
        [
            e as u32,
            fel[(sl + 1) % 3],
            fel[(sl + 2) % 3],
            fer[(sr + 1) % 3],
            fer[(sr + 2) % 3],
        ],
    )
}

/// `Q_e` from the diamond's slots (see [`diamond_edges`]), its lengths `[ℓ_ij, ℓ_jk, ℓ_ik,
/// ℓ_il, ℓ_jl]` and the angle φ*.
pub(crate) fn diamond_map(sl: usize, sr: usize, len: [f64; 5], phi: f64) -> M3 {
    let [l, l_jk, l_ik, l_il, l_jl] = len;
    let (ck, hk) = third_corner(l, l_ik, l_jk);
    let (cl, hl) = third_corner(l, l_il, l_jl);
    let (s, c) = phi.sin_cos();
    let pi = [0.0, 0.0, 0.0];
    let pj = [l, 0.0, 0.0];
    let pk = [ck, hk, 0.0];
    let pl = [cl, -hl * c, -hl * s];
    // Frames at each face's stored vertex order.
    let at_l = |s: usize| -> V3 {
        match (s + 3 - sl) % 3 {
            0 => pi,
            1 => pj,
            _ => pk,
        }
    };
    let at_r = |s: usize| -> V3 {
        match (s + 3 - sr) % 3 {
            0 => pj,
            1 => pi,
            _ => pl,
        }
    };
    let rl = triangle_frame(at_l(0), at_l(1), at_l(2));
    let rr = triangle_frame(at_r(0), at_r(1), at_r(2));
    matmul(&transpose(&rl), &rr)
}
