//! Approximate geodesic distances between edges of a mesh (docs/design/splocs-model.md §3.3).
//!
//! The support maps of the sparse localized decomposition (docs/design/splocs-model.md §3.1, §3.4) need, for each
//! component, the geodesic distance from its centre edge to every other edge, measured on the
//! mean rest shape V̄. This module computes them with a multi-source Dijkstra over the
//! vertices:
//!
//! * graph: the mesh edges plus the *diamond diagonals* k–l of every interior edge
//!   (docs/design/rla-and-g.md §1 diamond), each weighted by its Euclidean length on V̄; the diagonals
//!   add more directions and so reduce the metrication error of pure edge paths;
//! * by default ([`Propagation::Unfolding`], an addition to docs/design/splocs-model.md §3.3) each settled vertex also
//!   updates its triangles' far vertices by planar unfolding (the fast-marching update), which
//!   removes most of the remaining metrication error: measured mean/max relative error beyond
//!   10 edge lengths 0.15 %/0.55 % on a 10k-vertex sphere, against 2 %/9 % for plain Dijkstra
//!   ([`Propagation::Dijkstra`], exactly docs/design/splocs-model.md §3.3), which on triangulated quads is off by up to
//!   11 % in some directions;
//! * sources: the two endpoints a, b of the centre edge c, both at distance ℓ_c/2 (the
//!   distance from the edge's midpoint);
//! * edge distance: `d(e) = ½(d(a) + d(b))` for `e = (a, b)`, and `d(c) = 0` for the centre
//!   edge itself (the formula would give ℓ_c/2 there).
//!
//! Expansion stops at a caller-given radius, so a query costs time proportional to the area
//! inside that radius (plus one O(#E) pass to write the output). Nothing of size #E × #E is
//! ever built (that would be 5.6 GB in f32 for the body, docs/design/splocs-model.md §3.3).
//!
//! The structure is built once per topology and positions ([`EdgeGeodesics::new`]); queries
//! reuse a [`GeodesicWorkspace`] and allocate nothing once the workspace has warmed up.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use panoman_mesh::Topology;
use panoman_mesh::topology::NONE;

use crate::error::{ModelError, Result};
use crate::splocs::ColumnDistances;

/// How distances propagate in [`EdgeGeodesics`] (docs/design/splocs-model.md §3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Propagation {
    /// Plain Dijkstra on the mesh edges plus the diamond diagonals k–l (docs/design/splocs-model.md §3.3).
    /// On triangulated quads (every quad split the same way) the link directions leave a 45°
    /// gap, so distances in some directions are overestimated by up to ≈ 10 %.
    Dijkstra,
    /// The same graph, plus a planar-unfolding update across each triangle (the first-order
    /// fast-marching update of Kimmel–Sethian): when a vertex v is settled, every incident
    /// triangle (v, a, b) with a settled and b not gives b the distance from the virtual
    /// source that is at d(v) from v and d(a) from a, if the straight ray from that source to
    /// b crosses the edge v–a. This removes most of the metrication error (≈ 1 % on
    /// triangulated quads and spheres). The centre edge's endpoints, both at ℓ_c/2, put the
    /// virtual source exactly at its midpoint.
    Unfolding,
}

/// Vertex graph of a mesh (edges + diamond diagonals, Euclidean weights) for edge-to-edge
/// geodesic distances (docs/design/splocs-model.md §3.3).
#[derive(Clone, Debug)]
pub struct EdgeGeodesics {
    n_vertices: usize,
    edges: Vec<[u32; 2]>,
    edge_len: Vec<f64>,
    max_edge_len: f64,
    /// CSR offsets into `nbr`/`wgt`, length #V + 1.
    offsets: Vec<u32>,
    nbr: Vec<u32>,
    wgt: Vec<f64>,
    propagation: Propagation,
    /// Positions (for the unfolding update).
    pos: Vec<[f64; 3]>,
    /// Vertex → incident faces CSR (unfolding only; empty otherwise).
    vf_offsets: Vec<u32>,
    vf_faces: Vec<u32>,
    faces: Vec<[u32; 3]>,
}

/// Reusable scratch space of the Dijkstra queries of [`EdgeGeodesics`]: per-vertex tentative
/// distances (kept at +∞ between queries), the list of vertices touched by the last query and
/// the binary heap. Create one per thread with [`EdgeGeodesics::workspace`].
#[derive(Clone, Debug)]
pub struct GeodesicWorkspace {
    dist: Vec<f64>,
    settled: Vec<bool>,
    touched: Vec<u32>,
    heap: BinaryHeap<HeapItem>,
}

/// Min-heap entry: ordered by distance, then vertex id (so pops are deterministic).
#[derive(Clone, Copy, Debug)]
struct HeapItem {
    d: f64,
    v: u32,
}

impl PartialEq for HeapItem {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for HeapItem {}
impl PartialOrd for HeapItem {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for HeapItem {
    fn cmp(&self, other: &Self) -> Ordering {
        // Reversed: BinaryHeap is a max-heap and we want the smallest distance first.
        other
            .d
            .total_cmp(&self.d)
            .then_with(|| other.v.cmp(&self.v))
    }
}

fn dist3(p: [f64; 3], q: [f64; 3]) -> f64 {
    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

impl EdgeGeodesics {
    /// Builds the weighted vertex graph of `topology` embedded at `positions` (V̄, meters):
    /// every mesh edge and every diamond diagonal k–l of an interior edge, with its Euclidean
    /// length (docs/design/splocs-model.md §3.3). Parallel links (a diagonal that is also an edge, or shared by two
    /// diamonds) keep the shortest length. Queries use [`Propagation::Unfolding`] (Dijkstra on
    /// that graph plus triangle unfolding updates, ≈ 10× more accurate than plain Dijkstra at
    /// about the same cost); see [`Self::with_propagation`] for plain Dijkstra.
    ///
    /// Errors: `positions.len() != topology.n_vertices`, or a non-finite coordinate.
    pub fn new(topology: &Topology, positions: &[[f64; 3]]) -> Result<EdgeGeodesics> {
        Self::with_propagation(topology, positions, Propagation::Unfolding)
    }

    /// As [`Self::new`], with the chosen [`Propagation`].
    ///
    /// Errors: `positions.len() != topology.n_vertices`, or a non-finite coordinate.
    pub fn with_propagation(
        topology: &Topology,
        positions: &[[f64; 3]],
        propagation: Propagation,
    ) -> Result<EdgeGeodesics> {
        let nv = topology.n_vertices;
        if positions.len() != nv {
            return Err(ModelError::Invalid(format!(
                "geodesics: {} positions for a topology of {} vertices",
                positions.len(),
                nv
            )));
        }
        if let Some(i) = positions
            .iter()
            .position(|p| !p.iter().all(|x| x.is_finite()))
        {
            return Err(ModelError::Invalid(format!(
                "geodesics: vertex {i} has a non-finite coordinate"
            )));
        }
        let edges = topology.edges.clone();
        let edge_len: Vec<f64> = edges
            .iter()
            .map(|&[a, b]| dist3(positions[a as usize], positions[b as usize]))
            .collect();
        let max_edge_len = edge_len.iter().copied().fold(0.0, f64::max);

        // Directed links (src, dst, weight), both directions.
        let mut links: Vec<(u32, u32, f64)> = Vec::with_capacity(4 * edges.len());
        let mut push = |a: u32, b: u32, w: f64| {
            links.push((a, b, w));
            links.push((b, a, w));
        };
        for (e, &[a, b]) in edges.iter().enumerate() {
            push(a, b, edge_len[e]);
            let [k, l] = topology.edge_opposite[e];
            if l != NONE && k != NONE && k != l {
                push(k, l, dist3(positions[k as usize], positions[l as usize]));
            }
        }
        links.sort_unstable_by(|x, y| x.0.cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.total_cmp(&y.2)));
        links.dedup_by(|later, first| later.0 == first.0 && later.1 == first.1);

        let mut offsets = vec![0u32; nv + 1];
        for &(a, _, _) in &links {
            offsets[a as usize + 1] += 1;
        }
        for i in 0..nv {
            offsets[i + 1] += offsets[i];
        }
        let nbr = links.iter().map(|l| l.1).collect();
        let wgt: Vec<f64> = links.iter().map(|l| l.2).collect();
        let (mut vf_offsets, mut vf_faces, mut faces, mut pos) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        if propagation == Propagation::Unfolding {
            faces = topology.faces.clone();
            pos = positions.to_vec();
            vf_offsets = vec![0u32; nv + 1];
            for t in &faces {
                for &v in t {
                    vf_offsets[v as usize + 1] += 1;
                }
            }
            for i in 0..nv {
                vf_offsets[i + 1] += vf_offsets[i];
            }
            let mut fill = vf_offsets.clone();
            vf_faces = vec![0u32; faces.len() * 3];
            for (f, t) in faces.iter().enumerate() {
                for &v in t {
                    vf_faces[fill[v as usize] as usize] = f as u32;
                    fill[v as usize] += 1;
                }
            }
        }
        Ok(EdgeGeodesics {
            n_vertices: nv,
            edges,
            edge_len,
            max_edge_len,
            offsets,
            nbr,
            wgt,
            propagation,
            pos,
            vf_offsets,
            vf_faces,
            faces,
        })
    }

    /// Number of mesh edges #E (the length of a full [`Self::edge_distances_from_edge`] output).
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }

    /// Number of vertices #V.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Euclidean length ℓ_e of edge `e` on V̄.
    pub fn edge_length(&self, e: usize) -> f64 {
        self.edge_len[e]
    }

    /// Number of directed links of the graph (2 × (edges + distinct extra diagonals)).
    pub fn n_links(&self) -> usize {
        self.nbr.len()
    }

    /// A fresh workspace for queries on this graph (one per thread).
    pub fn workspace(&self) -> GeodesicWorkspace {
        GeodesicWorkspace {
            dist: vec![f64::INFINITY; self.n_vertices],
            settled: vec![false; self.n_vertices],
            touched: Vec::new(),
            heap: BinaryHeap::new(),
        }
    }

    /// Vertex distances `d(v)` from the midpoint of edge `centre` (sources: its endpoints at
    /// ℓ_c/2, docs/design/splocs-model.md §3.3), exact for the graph wherever `d(v) ≤ limit`; all other vertices are +∞.
    /// The result lives in the workspace until its next query.
    ///
    /// Panics if `centre` is out of range or `ws` was made for another graph.
    pub fn vertex_distances_from_edge<'w>(
        &self,
        centre: usize,
        limit: f64,
        ws: &'w mut GeodesicWorkspace,
    ) -> &'w [f64] {
        assert!(centre < self.edges.len(), "centre edge out of range");
        assert_eq!(ws.dist.len(), self.n_vertices, "workspace of another graph");
        for &v in &ws.touched {
            ws.dist[v as usize] = f64::INFINITY;
            ws.settled[v as usize] = false;
        }
        ws.touched.clear();
        ws.heap.clear();
        let half = 0.5 * self.edge_len[centre];
        for v in self.edges[centre] {
            if half < ws.dist[v as usize] {
                if ws.dist[v as usize] == f64::INFINITY {
                    ws.touched.push(v);
                }
                ws.dist[v as usize] = half;
                ws.heap.push(HeapItem { d: half, v });
            }
        }
        while let Some(HeapItem { d, v }) = ws.heap.pop() {
            if d > ws.dist[v as usize] {
                continue; // stale entry
            }
            if d > limit {
                break;
            }
            ws.settled[v as usize] = true;
            let (s, t) = (
                self.offsets[v as usize] as usize,
                self.offsets[v as usize + 1] as usize,
            );
            for i in s..t {
                let nd = d + self.wgt[i];
                Self::relax(ws, self.nbr[i], nd);
            }
            if self.propagation == Propagation::Unfolding {
                self.unfold_from(v, ws);
            }
        }
        // Tentative values beyond the limit are not final: report them as +∞.
        for &v in &ws.touched {
            if ws.dist[v as usize] > limit {
                ws.dist[v as usize] = f64::INFINITY;
            }
        }
        &ws.dist
    }

    #[inline]
    fn relax(ws: &mut GeodesicWorkspace, u: u32, nd: f64) {
        let du = &mut ws.dist[u as usize];
        if nd < *du {
            if *du == f64::INFINITY {
                ws.touched.push(u);
            }
            *du = nd;
            ws.heap.push(HeapItem { d: nd, v: u });
        }
    }

    /// Planar-unfolding updates from the just-settled vertex v (see [`Propagation::Unfolding`]).
    fn unfold_from(&self, v: u32, ws: &mut GeodesicWorkspace) {
        let (s, t) = (
            self.vf_offsets[v as usize] as usize,
            self.vf_offsets[v as usize + 1] as usize,
        );
        for &f in &self.vf_faces[s..t] {
            let tri = self.faces[f as usize];
            let (a, b) = match tri.iter().position(|&x| x == v) {
                Some(0) => (tri[1], tri[2]),
                Some(1) => (tri[2], tri[0]),
                _ => (tri[0], tri[1]),
            };
            for (known, target) in [(a, b), (b, a)] {
                if ws.settled[known as usize]
                    && !ws.settled[target as usize]
                    && let Some(nd) = self.unfold(v, known, target, ws)
                {
                    Self::relax(ws, target, nd);
                }
            }
        }
    }

    /// Distance of `b` from the virtual source at d(v) from v and d(a) from a, on the other
    /// side of the line v–a, if the ray from the source to b crosses the segment v–a; at least
    /// d(v).
    fn unfold(&self, v: u32, a: u32, b: u32, ws: &GeodesicWorkspace) -> Option<f64> {
        let (pv, pa, pb) = (
            self.pos[v as usize],
            self.pos[a as usize],
            self.pos[b as usize],
        );
        let (dv, da) = (ws.dist[v as usize], ws.dist[a as usize]);
        let e = [pa[0] - pv[0], pa[1] - pv[1], pa[2] - pv[2]];
        let l = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        if l.is_nan() || l <= 0.0 {
            return None;
        }
        let e = [e[0] / l, e[1] / l, e[2] / l];
        let r = [pb[0] - pv[0], pb[1] - pv[1], pb[2] - pv[2]];
        let bx = r[0] * e[0] + r[1] * e[1] + r[2] * e[2];
        let by2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2] - bx * bx;
        if by2.is_nan() || by2 <= 0.0 {
            return None;
        }
        let by = by2.sqrt();
        let sx = (dv * dv - da * da + l * l) / (2.0 * l);
        let h2 = dv * dv - sx * sx;
        if h2.is_nan() || h2 < 0.0 {
            return None;
        }
        let sy = -h2.sqrt();
        // Crossing of the ray s→b with the line y = 0.
        let x = sx + (bx - sx) * (-sy) / (by - sy);
        if !(0.0..=l).contains(&x) {
            return None;
        }
        // Never below d(v): keeps the pops monotone (label-setting), so settled values are
        // final and the radius cut-off is exact.
        Some(((bx - sx).powi(2) + (by - sy).powi(2)).sqrt().max(dv))
    }

    /// Vertex limit that makes every edge distance ≤ `max_radius` exact: if ½(d(a)+d(b)) ≤ r
    /// then max(d(a), d(b)) ≤ r + ℓ_ab/2, because |d(a) − d(b)| ≤ ℓ_ab.
    fn vertex_limit(&self, max_radius: f64) -> f64 {
        max_radius + 0.5 * self.max_edge_len * (1.0 + 1e-12)
    }

    fn edge_distance(&self, dv: &[f64], centre: usize, e: usize, max_radius: f64) -> f64 {
        if e == centre {
            return 0.0;
        }
        let [a, b] = self.edges[e];
        let d = 0.5 * (dv[a as usize] + dv[b as usize]);
        if d <= max_radius { d } else { f64::INFINITY }
    }

    /// Edge distances from edge `centre` (docs/design/splocs-model.md §3.3): `out[e] = ½(d(a)+d(b))` for every edge
    /// `e = (a, b)` with that value ≤ `max_radius`, +∞ for the others, and `out[centre] = 0`.
    /// Vertices farther than `max_radius + max ℓ/2` are never expanded. `max_radius` may be
    /// `f64::INFINITY` (the whole connected component).
    ///
    /// Panics if `out.len() != #E`, `centre` is out of range or `ws` belongs to another graph.
    pub fn edge_distances_from_edge(
        &self,
        centre: usize,
        max_radius: f64,
        ws: &mut GeodesicWorkspace,
        out: &mut [f64],
    ) {
        assert_eq!(out.len(), self.edges.len(), "output length must be #E");
        let dv = self.vertex_distances_from_edge(centre, self.vertex_limit(max_radius), ws);
        for (e, o) in out.iter_mut().enumerate() {
            *o = self.edge_distance(dv, centre, e, max_radius);
        }
    }

    /// As [`Self::edge_distances_from_edge`], but only for the edges listed in `edges`
    /// (`out[j]` is the distance of edge `edges[j]`), e.g. the columns of a part mask (docs/design/splocs-model.md §3.2).
    ///
    /// Panics if `out.len() != edges.len()` or an edge id is out of range.
    pub fn edge_distances_subset(
        &self,
        centre: usize,
        max_radius: f64,
        ws: &mut GeodesicWorkspace,
        edges: &[u32],
        out: &mut [f64],
    ) {
        assert_eq!(
            out.len(),
            edges.len(),
            "output length must equal the subset size"
        );
        let dv = self.vertex_distances_from_edge(centre, self.vertex_limit(max_radius), ws);
        for (o, &e) in out.iter_mut().zip(edges) {
            *o = self.edge_distance(dv, centre, e as usize, max_radius);
        }
    }
}

/// Geodesic distances restricted to the columns of a part mask (docs/design/splocs-model.md §3.2): column `j` of the
/// decomposition is mesh edge `columns[j]`; distances are measured on the whole mesh
/// ([`EdgeGeodesics`]). This is the distance provider of [`crate::splocs::fit`].
#[derive(Clone, Debug)]
pub struct PartGeodesics<'a> {
    geodesics: &'a EdgeGeodesics,
    columns: Vec<u32>,
}

impl<'a> PartGeodesics<'a> {
    /// Part view over `columns` (mesh edge ids, one per data column).
    ///
    /// Errors: an edge id out of range.
    pub fn new(geodesics: &'a EdgeGeodesics, columns: Vec<u32>) -> Result<PartGeodesics<'a>> {
        if let Some(&e) = columns.iter().find(|&&e| e as usize >= geodesics.n_edges()) {
            return Err(ModelError::Invalid(format!(
                "part column refers to edge {e}, but the mesh has {} edges",
                geodesics.n_edges()
            )));
        }
        Ok(PartGeodesics { geodesics, columns })
    }

    /// The mesh edge of each column.
    pub fn columns(&self) -> &[u32] {
        &self.columns
    }
}

impl ColumnDistances for PartGeodesics<'_> {
    type Workspace = GeodesicWorkspace;

    fn n_columns(&self) -> usize {
        self.columns.len()
    }

    fn new_workspace(&self) -> GeodesicWorkspace {
        self.geodesics.workspace()
    }

    fn distances_from(
        &self,
        centre: usize,
        max_radius: f64,
        ws: &mut GeodesicWorkspace,
        out: &mut [f64],
    ) {
        self.geodesics.edge_distances_subset(
            self.columns[centre] as usize,
            max_radius,
            ws,
            &self.columns,
            out,
        );
    }
}
