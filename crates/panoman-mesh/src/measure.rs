//! Basic measures of a triangle mesh: normals, areas, enclosed volume, bounding box, edge lengths.
//!
//! Notation: a face `f = (a, b, c)` has corners `pa, pb, pc` and the (unnormalised) normal
//! `n_f = (pb − pa) × (pc − pa)`, with `|n_f| = 2·area(f)`. Faces are counter-clockwise seen from
//! outside, so `n_f` points outward. All functions assume the face indices are in range
//! (see [`TriMesh::check_basic`]); they panic otherwise.

use crate::geom::{add, cross, dot, norm, scale, sub};
use crate::mesh::TriMesh;

/// Corners of face `f`.
#[inline]
fn corners(mesh: &TriMesh, f: &[u32; 3]) -> [[f64; 3]; 3] {
    [
        mesh.positions[f[0] as usize],
        mesh.positions[f[1] as usize],
        mesh.positions[f[2] as usize],
    ]
}

/// `n_f = (pb − pa) × (pc − pa)`, twice the area times the unit normal.
#[inline]
fn area_vector(mesh: &TriMesh, f: &[u32; 3]) -> [f64; 3] {
    let [a, b, c] = corners(mesh, f);
    cross(sub(b, a), sub(c, a))
}

/// `v / |v|`, or the zero vector when `|v| = 0`.
#[inline]
fn unit_or_zero(v: [f64; 3]) -> [f64; 3] {
    let l = norm(v);
    if l > 0.0 { scale(v, 1.0 / l) } else { [0.0; 3] }
}

/// Unit face normals `n̂_f = n_f / |n_f|` with `n_f = (pb − pa) × (pc − pa)`: outward for
/// counter-clockwise (seen from outside) faces. Degenerate faces (zero area) get `[0, 0, 0]`.
pub fn face_normals(mesh: &TriMesh) -> Vec<[f64; 3]> {
    mesh.faces
        .iter()
        .map(|f| unit_or_zero(area_vector(mesh, f)))
        .collect()
}

/// Face areas `A_f = |(pb − pa) × (pc − pa)| / 2`.
pub fn face_areas(mesh: &TriMesh) -> Vec<f64> {
    mesh.faces
        .iter()
        .map(|f| 0.5 * norm(area_vector(mesh, f)))
        .collect()
}

/// Total surface area `Σ_f A_f`.
pub fn surface_area(mesh: &TriMesh) -> f64 {
    mesh.faces
        .iter()
        .map(|f| 0.5 * norm(area_vector(mesh, f)))
        .sum()
}

/// Signed enclosed volume by the divergence theorem: `V = Σ_f pa · (pb × pc) / 6`, the sum of the
/// signed volumes of the tetrahedra (origin, pa, pb, pc).
///
/// For a closed mesh this is independent of the origin, positive when the faces are oriented
/// outward (counter-clockwise seen from outside) and negative when every face is reversed. For an
/// open mesh it is the signed volume of the cone from the origin to the surface.
pub fn enclosed_volume(mesh: &TriMesh) -> f64 {
    mesh.faces
        .iter()
        .map(|f| {
            let [a, b, c] = corners(mesh, f);
            dot(a, cross(b, c))
        })
        .sum::<f64>()
        / 6.0
}

/// Area-weighted vertex normals: `n̂_v = normalize(Σ_{f ∋ v} n_f)` with
/// `n_f = (pb − pa) × (pc − pa) = 2·A_f·n̂_f`, i.e. the face normals of the incident faces weighted
/// by their areas. Vertices without incident faces (or whose sum vanishes) get `[0, 0, 0]`.
pub fn vertex_normals(mesh: &TriMesh) -> Vec<[f64; 3]> {
    vertex_normals_of(&mesh.faces, &mesh.positions)
}

/// [`vertex_normals`] of `positions` (metres) with the triangles `faces`, for positions held
/// apart from a [`TriMesh`] (a posed frame of a fixed topology).
pub fn vertex_normals_of(faces: &[[u32; 3]], positions: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut acc = vec![[0.0f64; 3]; positions.len()];
    for f in faces {
        let [a, b, c] = f.map(|i| positions[i as usize]);
        let n = cross(sub(b, a), sub(c, a));
        for &v in f {
            acc[v as usize] = add(acc[v as usize], n);
        }
    }
    acc.into_iter().map(unit_or_zero).collect()
}

/// Axis-aligned bounding box `(min, max)`, component-wise over all vertices. An empty mesh gives
/// `([+∞; 3], [−∞; 3])`.
pub fn bbox(mesh: &TriMesh) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Length of the bounding-box diagonal `|max − min|`; `0` for an empty mesh.
pub fn bbox_diagonal(mesh: &TriMesh) -> f64 {
    if mesh.positions.is_empty() {
        return 0.0;
    }
    let (lo, hi) = bbox(mesh);
    norm(sub(hi, lo))
}

/// Mean edge length `(1/|E|) Σ_{{i,j} ∈ E} |p_i − p_j|` over the unique undirected edges `E`
/// (an edge shared by two faces counts once); `0` for a mesh without faces.
pub fn mean_edge_length(mesh: &TriMesh) -> f64 {
    let mut edges: Vec<u64> = Vec::with_capacity(3 * mesh.faces.len());
    for f in &mesh.faces {
        for k in 0..3 {
            let (i, j) = (f[k], f[(k + 1) % 3]);
            let (lo, hi) = if i < j { (i, j) } else { (j, i) };
            edges.push(((lo as u64) << 32) | hi as u64);
        }
    }
    edges.sort_unstable();
    edges.dedup();
    if edges.is_empty() {
        return 0.0;
    }
    let total: f64 = edges
        .iter()
        .map(|&e| {
            let i = (e >> 32) as usize;
            let j = (e & 0xffff_ffff) as usize;
            norm(sub(mesh.positions[i], mesh.positions[j]))
        })
        .sum();
    total / edges.len() as f64
}
