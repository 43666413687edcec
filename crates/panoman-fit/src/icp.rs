//! Point-cloud correspondences for ICP (docs/design/shell-fit.md §2.2, "ICP"): each scan point is matched
//! to its closest point on the current surface (nearest vertex by kd-tree, then the closest
//! point on the triangles around it), giving a point-to-plane constraint
//! `√w n̂_fᵀ(Σ_m b_m x_m − p)` on the triangle's barycentric point. Pairs farther than
//! `max_distance`, and (when the scan has normals) pairs whose normals differ by more than
//! `max_normal_angle_deg`, are rejected.
use kiddo::{KdTree, SquaredEuclidean};
use panoman_human::template::closest_point_on_triangle;
use panoman_mesh::Topology;
use panoman_mesh::geom::{V3, add, cross, dot, norm, scale, sub};
use panoman_mesh::shell::PointConstraint;

/// Matching controls.
#[derive(Clone, Debug)]
pub struct IcpOptions {
    /// Pairs farther apart than this are dropped (metres). Default 0.05.
    pub max_distance: f64,
    /// With scan normals, pairs whose normals differ by more than this are dropped (degrees).
    /// Default 60.
    pub max_normal_angle_deg: f64,
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions {
            max_distance: 0.05,
            max_normal_angle_deg: 60.0,
        }
    }
}

/// Per-vertex incident faces of a topology (CSR), built once per model load.
#[derive(Clone, Debug)]
pub struct VertexFaces {
    offsets: Vec<u32>,
    faces: Vec<u32>,
}

impl VertexFaces {
    /// Incidence lists of `topo`.
    pub fn new(topo: &Topology) -> Self {
        VertexFaces::from_faces(topo.n_vertices, &topo.faces)
    }

    /// Incidence lists of the triangles `tris` over `n_vertices` vertices.
    pub fn from_faces(n_vertices: usize, tris: &[[u32; 3]]) -> Self {
        let (offsets, mut faces) = panoman_mesh::topology::vertex_corners(n_vertices, tris);
        for c in faces.iter_mut() {
            *c /= 3;
        }
        VertexFaces { offsets, faces }
    }

    /// Faces around vertex `v`.
    pub fn of(&self, v: u32) -> &[u32] {
        &self.faces[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }
}

/// Outcome of one matching pass.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MatchStats {
    /// Scan points matched.
    pub matched: usize,
    /// Dropped as too far.
    pub rejected_distance: usize,
    /// Dropped for normals more than the threshold apart.
    pub rejected_normal: usize,
    /// Mean distance of the kept pairs (mm).
    pub mean_distance_mm: f64,
}

/// Point-to-plane constraints of `points` (with optional unit `normals`) against the surface
/// `x` of the triangles `faces` (with their incidence lists `vf`), each with weight `weight`
/// (units 1/length²).
pub fn correspondences_on(
    faces: &[[u32; 3]],
    vf: &VertexFaces,
    x: &[V3],
    points: &[V3],
    normals: Option<&[V3]>,
    weight: f64,
    opts: &IcpOptions,
) -> (Vec<PointConstraint>, MatchStats) {
    let mut tree: KdTree<f64, 3> = KdTree::with_capacity(x.len());
    for (v, p) in x.iter().enumerate() {
        tree.add(p, v as u64);
    }
    let cos_max = opts.max_normal_angle_deg.to_radians().cos();
    let mut out = Vec::with_capacity(points.len());
    let mut st = MatchStats::default();
    let mut dsum = 0.0;
    for (i, &p) in points.iter().enumerate() {
        let nn = tree.nearest_one::<SquaredEuclidean>(&p);
        let v = nn.item as u32;
        let mut best: Option<(f64, u32, [f64; 3])> = None;
        for &f in vf.of(v) {
            let [a, b, c] = faces[f as usize];
            let (pa, pb, pc) = (x[a as usize], x[b as usize], x[c as usize]);
            let bc = closest_point_on_triangle(p, pa, pb, pc);
            let q = add(add(scale(pa, bc[0]), scale(pb, bc[1])), scale(pc, bc[2]));
            let d = norm(sub(p, q));
            if best.is_none_or(|(bd, _, _)| d < bd) {
                best = Some((d, f, bc));
            }
        }
        let Some((d, f, bc)) = best else { continue };
        if d > opts.max_distance {
            st.rejected_distance += 1;
            continue;
        }
        let [a, b, c] = faces[f as usize];
        let nf = cross(
            sub(x[b as usize], x[a as usize]),
            sub(x[c as usize], x[a as usize]),
        );
        let ln = norm(nf);
        if ln == 0.0 {
            continue;
        }
        let nf = scale(nf, 1.0 / ln);
        if let Some(ns) = normals
            && dot(ns[i], nf) < cos_max
        {
            st.rejected_normal += 1;
            continue;
        }
        dsum += d;
        st.matched += 1;
        out.push(PointConstraint {
            rows: vec![(a, bc[0]), (b, bc[1]), (c, bc[2])],
            target: p,
            weight,
            normal: Some(nf),
        });
    }
    st.mean_distance_mm = 1e3 * dsum / st.matched.max(1) as f64;
    (out, st)
}

/// A simulated depth scan of a mesh (the scan case of `examples/scan_bench`, `panoman bench`'s
/// `fit_scan`): `n` points drawn area-uniformly on the triangles of `truth` (`(V, 3)` metres)
/// with isotropic Gaussian noise of `sigma` metres, then the 30 % with the largest y (the back)
/// dropped. Deterministic in `seed` (xorshift64 uniforms, Box–Muller normals); a state seeded
/// once and passed to several scans gives each its own draws.
pub fn simulated_scan(
    truth: &[V3],
    faces: &[[u32; 3]],
    n: usize,
    sigma: f64,
    state: &mut u64,
) -> Vec<V3> {
    use panoman_mesh::geom::cross;
    let mut u = || {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        (*state >> 11) as f64 / (1u64 << 53) as f64
    };
    let areas: Vec<f64> = faces
        .iter()
        .map(|f| {
            let [p, q, w] = f.map(|v| truth[v as usize]);
            0.5 * norm(cross(sub(q, p), sub(w, p)))
        })
        .collect();
    let total: f64 = areas.iter().sum();
    let mut cdf = Vec::with_capacity(areas.len());
    let mut acc = 0.0;
    for a in &areas {
        acc += a / total;
        cdf.push(acc);
    }
    let mut pts = Vec::with_capacity(n);
    for _ in 0..n {
        let x = u();
        let fi = cdf.partition_point(|&c| c < x).min(faces.len() - 1);
        let (mut b1, mut b2) = (u(), u());
        if b1 + b2 > 1.0 {
            b1 = 1.0 - b1;
            b2 = 1.0 - b2;
        }
        let [p, q, w] = faces[fi].map(|v| truth[v as usize]);
        let mut gauss = || {
            let (a, b) = (u().max(1e-300), u());
            (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        let e = [gauss(), gauss(), gauss()];
        pts.push([0, 1, 2].map(|k| p[k] + b1 * (q[k] - p[k]) + b2 * (w[k] - p[k]) + sigma * e[k]));
    }
    let mut ys: Vec<f64> = pts.iter().map(|p| p[1]).collect();
    ys.sort_by(f64::total_cmp);
    let Some(&cut) = ys.get((0.7 * ys.len() as f64) as usize) else {
        return pts;
    };
    pts.into_iter().filter(|p| p[1] <= cut).collect()
}

#[cfg(test)]
mod scan_tests {
    use super::simulated_scan;

    #[test]
    fn a_simulated_scan_keeps_the_front_70_percent_on_the_surface_and_repeats_per_seed() {
        // A unit square in the z = 0 plane (two triangles), no noise.
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let f = vec![[0, 1, 2], [0, 2, 3]];
        let (mut s1, mut s2) = (7u64, 7u64);
        let a = simulated_scan(&v, &f, 1000, 0.0, &mut s1);
        let b = simulated_scan(&v, &f, 1000, 0.0, &mut s2);
        assert_eq!(a, b);
        assert!((695..=705).contains(&a.len()), "{}", a.len());
        let cut = a.iter().map(|p| p[1]).fold(0.0f64, f64::max);
        assert!((cut - 0.7).abs() < 0.05, "back cut at y = {cut}");
        assert!(a.iter().all(|p| p[2] == 0.0 && (0.0..=1.0).contains(&p[0])));
        // The state advanced: the next scan differs.
        assert_ne!(simulated_scan(&v, &f, 1000, 0.0, &mut s1), a);
    }
}
