//! Topology tables of a triangle mesh, built once per connectivity and validated.
//!
//! For every undirected edge `e` the table stores the *diamond* used by RL/RA and `g`
//! (docs/design/rla-and-g.md §1, §2.1):
//!
//! ```text
//!            k                 fL = (i, j, k) contains the half-edge i→j,
//!          /   \               fR = (j, i, l) contains the half-edge j→i,
//!        i ----- j             k, l = vertices opposite to the edge in fL, fR.
//!          \   /
//!            l
//! ```
//!
//! Interior edges are stored with `i < j`. A boundary edge is stored in the direction of its
//! only face, so `fL` is always valid and `fR == NONE`, `l == NONE`.
//!
//! Validation (done by [`Topology::build`]): indices in range, no degenerate triangles, every
//! undirected edge in at most two faces (edge-manifold), every directed half-edge at most once
//! (consistent orientation), every vertex's faces forming one fan (vertex-manifold), no
//! unreferenced vertices. Connected components (of vertices, and of faces across interior
//! edges), boundary loops and the Euler characteristic are computed.

use crate::error::{MeshError, Result};

/// Marker for "no face / no vertex" in the tables (boundary edges).
pub const NONE: u32 = u32::MAX;

/// Topology tables of a validated, manifold, consistently oriented triangle mesh.
#[derive(Clone, Debug)]
pub struct Topology {
    /// Number of vertices #V.
    pub n_vertices: usize,
    /// #F triangles (counter-clockwise seen from outside).
    pub faces: Vec<[u32; 3]>,
    /// #E edges `[i, j]`: `i < j` for interior edges, face direction for boundary edges.
    pub edges: Vec<[u32; 2]>,
    /// Per edge `[fL, fR]`: the face containing i→j and the face containing j→i (or [`NONE`]).
    pub edge_faces: Vec<[u32; 2]>,
    /// Per edge `[k, l]`: the vertex opposite the edge in fL and in fR (or [`NONE`]).
    pub edge_opposite: Vec<[u32; 2]>,
    /// Per face, the edge of each slot `s`: the edge between corners `s` and `s+1 (mod 3)`.
    pub face_edges: Vec<[u32; 3]>,
    /// Ids of the interior edges (those with two faces), ascending.
    pub interior_edges: Vec<u32>,
    /// Boundary loops as closed vertex cycles (each following the faces' orientation).
    pub boundary_loops: Vec<Vec<u32>>,
    /// Connected component of each vertex (components numbered by first vertex).
    pub vertex_component: Vec<u32>,
    /// Number of vertex-connected components.
    pub n_vertex_components: usize,
    /// Component of each face in the dual graph (faces adjacent across interior edges).
    pub face_component: Vec<u32>,
    /// Number of dual-graph components.
    pub n_face_components: usize,
    /// CSR offsets of the dual graph: neighbours of face `f` are
    /// `dual_neighbors[dual_offsets[f]..dual_offsets[f+1]]`.
    pub dual_offsets: Vec<u32>,
    /// CSR neighbour lists of the dual graph, as `(face, edge)` pairs.
    pub dual_neighbors: Vec<(u32, u32)>,
}

impl Topology {
    /// Builds and validates the tables for `faces` over `n_vertices` vertices.
    ///
    /// Errors ([`MeshError::Topology`]) name the offending face, edge or vertex.
    pub fn build(n_vertices: usize, faces: &[[u32; 3]]) -> Result<Topology> {
        check_faces(n_vertices, faces)?;
        let t = EdgeTables::build(faces)?;
        check_vertex_fans(n_vertices, faces, &t)?;
        let (vertex_component, n_vertex_components) = vertex_components(n_vertices, &t.edges);
        let (dual_offsets, dual_neighbors) = dual_graph(&t);
        let (face_component, n_face_components) = face_components(&dual_offsets, &dual_neighbors);
        let boundary_loops = boundary_loops(&t)?;
        Ok(Topology {
            n_vertices,
            faces: faces.to_vec(),
            edges: t.edges,
            edge_faces: t.edge_faces,
            edge_opposite: t.edge_opposite,
            face_edges: t.face_edges,
            interior_edges: t.interior_edges,
            boundary_loops,
            vertex_component,
            n_vertex_components,
            face_component,
            n_face_components,
            dual_offsets,
            dual_neighbors,
        })
    }

    /// Number of triangles #F.
    pub fn n_faces(&self) -> usize {
        self.faces.len()
    }

    /// Number of undirected edges #E.
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }

    /// Number of edges with two faces.
    pub fn n_interior_edges(&self) -> usize {
        self.interior_edges.len()
    }

    /// Number of edges with one face.
    pub fn n_boundary_edges(&self) -> usize {
        self.edges.len() - self.interior_edges.len()
    }

    /// Whether edge `e` has two faces (and hence a dihedral angle).
    #[inline]
    pub fn is_interior(&self, e: usize) -> bool {
        self.edge_faces[e][1] != NONE
    }

    /// True when the mesh has no boundary.
    pub fn is_closed(&self) -> bool {
        self.interior_edges.len() == self.edges.len()
    }

    /// Euler characteristic χ = V − E + F.
    pub fn euler_characteristic(&self) -> i64 {
        self.n_vertices as i64 - self.edges.len() as i64 + self.faces.len() as i64
    }

    /// Genus of a connected mesh from χ = 2 − 2g − b (b boundary loops); `None` when the mesh
    /// has several components.
    pub fn genus(&self) -> Option<i64> {
        if self.n_vertex_components != 1 {
            return None;
        }
        Some((2 - self.euler_characteristic() - self.boundary_loops.len() as i64) / 2)
    }

    /// Faces adjacent to face `f` across interior edges, as `(face, edge)` pairs.
    pub fn dual_neighbors_of(&self, f: usize) -> &[(u32, u32)] {
        &self.dual_neighbors[self.dual_offsets[f] as usize..self.dual_offsets[f + 1] as usize]
    }

    /// A stable 64-bit FNV-1a hash of (#V, faces), written as 16 hex digits. Files that depend on
    /// a topology (datasets, models) store it to detect mismatches.
    pub fn hash_hex(&self) -> String {
        topology_hash(self.n_vertices, &self.faces)
    }

    /// Short human-readable summary: counts, closedness, components, genus.
    pub fn summary(&self) -> String {
        format!(
            "{} vertices, {} triangles, {} edges ({} boundary, {} loops), {} component(s){}",
            self.n_vertices,
            self.faces.len(),
            self.edges.len(),
            self.n_boundary_edges(),
            self.boundary_loops.len(),
            self.n_vertex_components,
            match self.genus() {
                Some(g) => format!(", genus {g}"),
                None => String::new(),
            }
        )
    }
}

/// The corners around each vertex as CSR lists: `corners[offsets[v]..offsets[v + 1]]` holds
/// `3 f + s` for every face `f` whose slot `s` is `v`, in face order (indices must be
/// `< n_vertices`).
pub fn vertex_corners(n_vertices: usize, faces: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; n_vertices + 1];
    for t in faces {
        for &v in t {
            offsets[v as usize + 1] += 1;
        }
    }
    for v in 0..n_vertices {
        offsets[v + 1] += offsets[v];
    }
    let mut corners = vec![0u32; offsets[n_vertices] as usize];
    let mut fill = offsets.clone();
    for (f, t) in faces.iter().enumerate() {
        for (s, &v) in t.iter().enumerate() {
            corners[fill[v as usize] as usize] = f as u32 * 3 + s as u32;
            fill[v as usize] += 1;
        }
    }
    (offsets, corners)
}

/// FNV-1a hash of (#V, faces) as 16 hex digits; see [`Topology::hash_hex`].
pub fn topology_hash(n_vertices: usize, faces: &[[u32; 3]]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |x: u32| {
        for b in x.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(n_vertices as u32);
    for t in faces {
        for &v in t {
            eat(v);
        }
    }
    format!("{h:016x}")
}

/// Indices, vertex range and non-degeneracy of the faces.
fn check_faces(n_vertices: usize, faces: &[[u32; 3]]) -> Result<()> {
    if faces.is_empty() {
        return Err(MeshError::Topology("the mesh has no faces".into()));
    }
    if n_vertices >= NONE as usize {
        return Err(MeshError::Topology("too many vertices".into()));
    }
    for (f, t) in faces.iter().enumerate() {
        if let Some(&v) = t.iter().find(|&&v| v as usize >= n_vertices) {
            return Err(MeshError::Topology(format!(
                "face {f} {t:?} refers to vertex {v}, but the mesh has {n_vertices} vertices"
            )));
        }
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return Err(MeshError::Topology(format!(
                "face {f} {t:?} is degenerate (repeated vertex)"
            )));
        }
    }
    Ok(())
}

/// The edge tables of a [`Topology`]: edges, their faces and opposite vertices, each face's
/// edges, the interior edges.
struct EdgeTables {
    edges: Vec<[u32; 2]>,
    edge_faces: Vec<[u32; 2]>,
    edge_opposite: Vec<[u32; 2]>,
    face_edges: Vec<[u32; 3]>,
    interior_edges: Vec<u32>,
}

/// The face across edge `e` from face `f` ([`NONE`] on the boundary).
fn other_face(edge_faces: &[[u32; 2]], e: u32, f: u32) -> u32 {
    let [fl, fr] = edge_faces[e as usize];
    if fl == f { fr } else { fl }
}

/// Face `h / 3` and slot `h % 3` of half-edge `h`.
fn corner(h: u32) -> (u32, usize) {
    (h / 3, (h % 3) as usize)
}

impl EdgeTables {
    /// The edges from the half-edges sorted by undirected key (a group of two equal keys is an
    /// interior edge, of one a boundary edge); fails on inconsistent orientation and on
    /// non-manifold edges.
    fn build(faces: &[[u32; 3]]) -> Result<EdgeTables> {
        // Half-edges sorted by undirected key; groups of equal keys are the edges.
        let mut half: Vec<(u64, u32)> = Vec::with_capacity(faces.len() * 3);
        for (f, t) in faces.iter().enumerate() {
            for s in 0..3 {
                let (a, b) = (t[s], t[(s + 1) % 3]);
                let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
                half.push((key, (f as u32) * 3 + s as u32));
            }
        }
        half.sort_unstable();

        let n_half = half.len();
        let mut edges = Vec::with_capacity(n_half / 2 + 1);
        let mut edge_faces = Vec::with_capacity(n_half / 2 + 1);
        let mut edge_opposite = Vec::with_capacity(n_half / 2 + 1);
        let mut face_edges = vec![[NONE; 3]; faces.len()];
        let mut interior_edges = Vec::with_capacity(n_half / 2 + 1);
        let mut g = 0;
        while g < n_half {
            let mut end = g + 1;
            while end < n_half && half[end].0 == half[g].0 {
                end += 1;
            }
            let e = edges.len() as u32;
            let a = (half[g].0 >> 32) as u32;
            let b = (half[g].0 & 0xffff_ffff) as u32;
            match end - g {
                1 => {
                    let (f, s) = corner(half[g].1);
                    let t = faces[f as usize];
                    edges.push([t[s], t[(s + 1) % 3]]);
                    edge_faces.push([f, NONE]);
                    edge_opposite.push([t[(s + 2) % 3], NONE]);
                    face_edges[f as usize][s] = e;
                }
                2 => {
                    let (f0, s0) = corner(half[g].1);
                    let (f1, s1) = corner(half[g + 1].1);
                    let t0 = faces[f0 as usize];
                    let t1 = faces[f1 as usize];
                    let from0 = t0[s0];
                    let from1 = t1[s1];
                    if from0 == from1 {
                        return Err(MeshError::Topology(format!(
                            "faces {f0} {t0:?} and {f1} {t1:?} are inconsistently oriented \
                             (both contain the half-edge {}→{})",
                            from0,
                            t0[(s0 + 1) % 3]
                        )));
                    }
                    // fL holds a→b with a < b.
                    let ((fl, sl), (fr, sr)) = if from0 == a {
                        ((f0, s0), (f1, s1))
                    } else {
                        ((f1, s1), (f0, s0))
                    };
                    let tl = faces[fl as usize];
                    let tr = faces[fr as usize];
                    edges.push([a, b]);
                    edge_faces.push([fl, fr]);
                    edge_opposite.push([tl[(sl + 2) % 3], tr[(sr + 2) % 3]]);
                    face_edges[fl as usize][sl] = e;
                    face_edges[fr as usize][sr] = e;
                    interior_edges.push(e);
                }
                n => {
                    let fs: Vec<u32> = half[g..end].iter().map(|h| h.1 / 3).collect();
                    return Err(MeshError::Topology(format!(
                        "non-manifold edge ({a}, {b}) is shared by {n} faces {fs:?}"
                    )));
                }
            }
            g = end;
        }
        Ok(EdgeTables {
            edges,
            edge_faces,
            edge_opposite,
            face_edges,
            interior_edges,
        })
    }
}

/// Vertex manifoldness and unreferenced vertices: the faces around each vertex must form a
/// single fan.
fn check_vertex_fans(n_vertices: usize, faces: &[[u32; 3]], t: &EdgeTables) -> Result<()> {
    // Vertex manifoldness and unreferenced vertices: the faces around each vertex must form
    // a single fan. Count incident faces, then walk the fan from one face.
    let (inc_off, inc) = vertex_corners(n_vertices, faces);
    if let Some(v) = (0..n_vertices).find(|&v| inc_off[v] == inc_off[v + 1]) {
        return Err(MeshError::Topology(format!(
            "vertex {v} is not used by any face"
        )));
    }
    for v in 0..n_vertices {
        let corners = &inc[inc_off[v] as usize..inc_off[v + 1] as usize];
        let n_inc = corners.len();
        // Walk across the outgoing edge (slot s) repeatedly, then across the incoming edge.
        let (f0, s0) = corner(corners[0]);
        let (forward, closed) = walk_fan(faces, t, v, (f0, s0), 0, n_inc - 1);
        let mut visited = 1 + forward;
        if !closed {
            visited += walk_fan(
                faces,
                t,
                v,
                (f0, s0),
                2,
                (n_inc - 1).saturating_sub(forward),
            )
            .0;
        }
        if visited != n_inc {
            return Err(MeshError::Topology(format!(
                "non-manifold vertex {v}: its {n_inc} faces do not form a single fan"
            )));
        }
    }
    Ok(())
}

/// Walks the fan of vertex `v` from `start` = (face, slot of `v`), stepping each time across
/// the face's edge at slot `s + step` (0: the edge leaving `v`, 2: the edge arriving at it),
/// until the boundary, a return to the start face (forward walk only) or more than `limit`
/// steps. Returns the faces stepped onto and whether the walk closed.
fn walk_fan(
    faces: &[[u32; 3]],
    t: &EdgeTables,
    v: usize,
    start: (u32, usize),
    step: usize,
    limit: usize,
) -> (usize, bool) {
    let (mut f, mut s) = start;
    let mut steps = 0;
    loop {
        let nf = other_face(&t.edge_faces, t.face_edges[f as usize][(s + step) % 3], f);
        if nf == NONE {
            return (steps, false);
        }
        if step == 0 && nf == start.0 {
            return (steps, true);
        }
        s = faces[nf as usize]
            .iter()
            .position(|&x| x as usize == v)
            .unwrap();
        f = nf;
        steps += 1;
        if steps > limit {
            return (steps, false);
        }
    }
}

/// Connected components of the vertices (union-find over `edges`): per vertex its component,
/// numbered in order of first vertex, and their count.
fn vertex_components(n_vertices: usize, edges: &[[u32; 2]]) -> (Vec<u32>, usize) {
    // Vertex components (union-find over edges).
    let mut parent: Vec<u32> = (0..n_vertices as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for &[a, b] in edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            parent[hi as usize] = lo;
        }
    }
    let mut vertex_component = vec![NONE; n_vertices];
    let mut comp_of_root = vec![NONE; n_vertices];
    let mut n_vertex_components = 0usize;
    for v in 0..n_vertices {
        let r = find(&mut parent, v as u32) as usize;
        if comp_of_root[r] == NONE {
            comp_of_root[r] = n_vertex_components as u32;
            n_vertex_components += 1;
        }
        vertex_component[v] = comp_of_root[r];
    }
    (vertex_component, n_vertex_components)
}

/// The dual graph in CSR form: per face its neighbours across interior edges, `(face, edge)`.
fn dual_graph(t: &EdgeTables) -> (Vec<u32>, Vec<(u32, u32)>) {
    let (edge_faces, face_edges) = (&t.edge_faces, &t.face_edges);
    // Dual graph (faces adjacent across interior edges).
    let nf = face_edges.len();
    let mut dual_offsets = vec![0u32; nf + 1];
    for (f, fe) in face_edges.iter().enumerate() {
        let deg = fe
            .iter()
            .filter(|&&e| edge_faces[e as usize][1] != NONE)
            .count();
        dual_offsets[f + 1] = dual_offsets[f] + deg as u32;
    }
    let mut dual_neighbors = Vec::with_capacity(dual_offsets[nf] as usize);
    for (f, fe) in face_edges.iter().enumerate() {
        for &e in fe {
            let o = other_face(edge_faces, e, f as u32);
            if o != NONE {
                dual_neighbors.push((o, e));
            }
        }
    }
    (dual_offsets, dual_neighbors)
}

/// Connected components of the faces over the dual graph, numbered in order of first face.
fn face_components(dual_offsets: &[u32], dual_neighbors: &[(u32, u32)]) -> (Vec<u32>, usize) {
    let nf = dual_offsets.len() - 1;
    let mut face_component = vec![NONE; nf];
    let mut n_face_components = 0usize;
    let mut stack = Vec::new();
    for seed in 0..nf {
        if face_component[seed] != NONE {
            continue;
        }
        let c = n_face_components as u32;
        n_face_components += 1;
        face_component[seed] = c;
        stack.push(seed as u32);
        while let Some(f) = stack.pop() {
            let r = dual_offsets[f as usize] as usize..dual_offsets[f as usize + 1] as usize;
            for &(o, _) in &dual_neighbors[r] {
                if face_component[o as usize] == NONE {
                    face_component[o as usize] = c;
                    stack.push(o);
                }
            }
        }
    }
    (face_component, n_face_components)
}

/// The boundary loops, each from its smallest vertex; fails unless every boundary vertex has
/// exactly one outgoing boundary edge and the chains close.
fn boundary_loops(t: &EdgeTables) -> Result<Vec<Vec<u32>>> {
    let (edges, edge_faces) = (&t.edges, &t.edge_faces);
    // Boundary loops: each boundary vertex has exactly one outgoing boundary edge.
    let mut next_boundary = std::collections::HashMap::new();
    for (e, ef) in edge_faces.iter().enumerate() {
        if ef[1] == NONE {
            next_boundary.insert(edges[e][0], edges[e][1]);
        }
    }
    let mut boundary_loops = Vec::new();
    let mut starts: Vec<u32> = next_boundary.keys().copied().collect();
    starts.sort_unstable();
    let mut seen = std::collections::HashSet::new();
    for s in starts {
        if seen.contains(&s) {
            continue;
        }
        let mut lp = vec![s];
        seen.insert(s);
        let mut v = next_boundary[&s];
        while v != s {
            if !seen.insert(v) {
                return Err(MeshError::Topology(format!(
                    "boundary at vertex {v} is not a simple loop"
                )));
            }
            lp.push(v);
            v = *next_boundary
                .get(&v)
                .ok_or_else(|| MeshError::Topology(format!("open boundary chain at vertex {v}")))?;
        }
        boundary_loops.push(lp);
    }
    Ok(boundary_loops)
}
