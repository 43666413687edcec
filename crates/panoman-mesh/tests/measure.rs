//! Tests of the basic mesh measures against closed-form values.

use panoman_mesh::TriMesh;
use panoman_mesh::measure::{
    bbox, bbox_diagonal, enclosed_volume, face_areas, face_normals, mean_edge_length, surface_area,
    vertex_normals,
};

/// Unit cube [0,1]³, 12 triangles, counter-clockwise seen from outside.
fn unit_cube() -> TriMesh {
    let positions = (0..8)
        .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
        .collect();
    // Vertex i = (x, y, z) with x = bit 0, y = bit 1, z = bit 2.
    let faces = vec![
        [0, 2, 3],
        [0, 3, 1], // z = 0, normal −z
        [4, 5, 7],
        [4, 7, 6], // z = 1, +z
        [0, 1, 5],
        [0, 5, 4], // y = 0, −y
        [2, 6, 7],
        [2, 7, 3], // y = 1, +y
        [0, 4, 6],
        [0, 6, 2], // x = 0, −x
        [1, 3, 7],
        [1, 7, 5], // x = 1, +x
    ];
    TriMesh::new(positions, faces)
}

/// Regular tetrahedron with edge 2√2 (alternate corners of the cube [−1,1]³), outward faces.
fn tetrahedron() -> TriMesh {
    TriMesh::new(
        vec![
            [1.0, 1.0, 1.0],
            [1.0, -1.0, -1.0],
            [-1.0, 1.0, -1.0],
            [-1.0, -1.0, 1.0],
        ],
        vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
    )
}

fn reversed(m: &TriMesh) -> TriMesh {
    TriMesh::new(
        m.positions.clone(),
        m.faces.iter().map(|f| [f[0], f[2], f[1]]).collect(),
    )
}

fn transformed(m: &TriMesh, s: f64, t: [f64; 3]) -> TriMesh {
    TriMesh::new(
        m.positions
            .iter()
            .map(|p| [s * p[0] + t[0], s * p[1] + t[1], s * p[2] + t[2]])
            .collect(),
        m.faces.clone(),
    )
}

fn centroid(points: &[[f64; 3]]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for p in points {
        for k in 0..3 {
            c[k] += p[k] / points.len() as f64;
        }
    }
    c
}

/// Every face normal is unit length and points away from the mesh centroid (for convex meshes).
fn assert_outward_unit_normals(m: &TriMesh, sign: f64) {
    let c = centroid(&m.positions);
    for (f, n) in m.faces.iter().zip(face_normals(m)) {
        let fc = centroid(&f.map(|v| m.positions[v as usize]));
        let d = [fc[0] - c[0], fc[1] - c[1], fc[2] - c[2]];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-15, "{f:?}: |n| = {len}");
        assert!(
            sign * (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) > 0.0,
            "{f:?}: {n:?}"
        );
    }
}

#[test]
fn unit_cube_volume_area_normals() {
    let cube = unit_cube();
    assert!((enclosed_volume(&cube) - 1.0).abs() < 1e-15);
    assert!((surface_area(&cube) - 6.0).abs() < 1e-15);
    for a in face_areas(&cube) {
        assert!((a - 0.5).abs() < 1e-16, "{a}");
    }
    assert_outward_unit_normals(&cube, 1.0);
    // Axis-aligned normals exactly.
    let n = face_normals(&cube);
    assert_eq!(n[0], [0.0, 0.0, -1.0]);
    assert_eq!(n[11], [1.0, 0.0, 0.0]);
}

#[test]
fn volume_sign_flips_and_normals_reverse_when_faces_are_reversed() {
    for m in [unit_cube(), tetrahedron()] {
        let r = reversed(&m);
        let (v, vr) = (enclosed_volume(&m), enclosed_volume(&r));
        assert!(v > 0.0);
        assert!((v + vr).abs() < 1e-15 * v, "{v} {vr}");
        assert_eq!(surface_area(&m), surface_area(&r));
        assert_outward_unit_normals(&r, -1.0);
    }
}

#[test]
fn regular_tetrahedron_closed_forms() {
    let t = tetrahedron();
    let a = 2.0 * 2f64.sqrt();
    let v_exact = a.powi(3) / (6.0 * 2f64.sqrt()); // = 8/3
    let area_exact = 3f64.sqrt() * a * a; // 4 faces × (√3/4)a²
    assert!(
        (enclosed_volume(&t) - v_exact).abs() < 1e-14,
        "{}",
        enclosed_volume(&t)
    );
    assert!((surface_area(&t) - area_exact).abs() < 1e-14);
    assert_outward_unit_normals(&t, 1.0);
    assert!((mean_edge_length(&t) - a).abs() < 1e-15);
    // By symmetry the area-weighted vertex normal of a corner points along the corner.
    for (p, n) in t.positions.iter().zip(vertex_normals(&t)) {
        for k in 0..3 {
            assert!((n[k] - p[k] / 3f64.sqrt()).abs() < 1e-15, "{p:?} {n:?}");
        }
    }
}

#[test]
fn volume_and_area_scale_and_translate_correctly() {
    let s = 0.37;
    let t = [12.5, -3.0, 7.25];
    for m in [unit_cube(), tetrahedron()] {
        let v = enclosed_volume(&m);
        let a = surface_area(&m);
        let mt = transformed(&m, s, t);
        // Closed meshes: translation does not change the volume; scaling multiplies it by s³.
        assert!(
            (enclosed_volume(&mt) - s.powi(3) * v).abs() < 1e-12 * v,
            "{}",
            enclosed_volume(&mt)
        );
        assert!((surface_area(&mt) - s * s * a).abs() < 1e-13 * a);
        assert!((mean_edge_length(&mt) - s * mean_edge_length(&m)).abs() < 1e-14);
    }
}

#[test]
fn vertex_normals_are_area_weighted() {
    // Vertex 0 is shared by a triangle of area 2 in the xy-plane (normal +z) and a triangle of
    // area 1 in the xz-plane (normal −y): n̂_0 ∝ 2·(0,0,1) + 1·(0,−1,0).
    let m = TriMesh::new(
        vec![
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [0.0, 0.0, 1.0],
            [5.0, 5.0, 5.0], // isolated
        ],
        vec![[0, 1, 2], [0, 1, 3]],
    );
    assert_eq!(face_areas(&m), vec![2.0, 1.0]);
    let n = vertex_normals(&m);
    let l = (4.0f64 + 1.0).sqrt();
    let expected = [0.0, -1.0 / l, 2.0 / l];
    for k in 0..3 {
        assert!((n[0][k] - expected[k]).abs() < 1e-15, "{:?}", n[0]);
    }
    assert_eq!(n[2], [0.0, 0.0, 1.0]);
    assert_eq!(n[3], [0.0, -1.0, 0.0]);
    assert_eq!(n[4], [0.0, 0.0, 0.0]);
}

#[test]
fn degenerate_face_has_zero_normal_and_area() {
    let m = TriMesh::new(
        vec![[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]],
        vec![[0, 1, 2]],
    );
    assert_eq!(face_normals(&m), vec![[0.0, 0.0, 0.0]]);
    assert_eq!(face_areas(&m), vec![0.0]);
    assert_eq!(vertex_normals(&m), vec![[0.0; 3]; 3]);
}

#[test]
fn bbox_and_diagonal() {
    let m = transformed(&unit_cube(), 2.0, [-1.0, 3.0, 0.5]);
    let (lo, hi) = bbox(&m);
    assert_eq!(lo, [-1.0, 3.0, 0.5]);
    assert_eq!(hi, [1.0, 5.0, 2.5]);
    assert!((bbox_diagonal(&m) - 2.0 * 3f64.sqrt()).abs() < 1e-15);
    let empty = TriMesh::default();
    assert_eq!(bbox_diagonal(&empty), 0.0);
    assert_eq!(bbox(&empty).0, [f64::INFINITY; 3]);
}

#[test]
fn mean_edge_length_counts_shared_edges_once() {
    // 3-4-5 triangle: (3 + 4 + 5) / 3.
    let tri = TriMesh::new(
        vec![[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 4.0, 0.0]],
        vec![[0, 1, 2]],
    );
    assert!((mean_edge_length(&tri) - 4.0).abs() < 1e-15);
    // Unit square split into two triangles: 4 sides of 1 and one diagonal √2 (not 6 edges).
    let sq = TriMesh::new(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    assert!((mean_edge_length(&sq) - (4.0 + 2f64.sqrt()) / 5.0).abs() < 1e-15);
    // Cube: 12 sides of 1 and 6 face diagonals of √2.
    let cube = unit_cube();
    assert!((mean_edge_length(&cube) - (12.0 + 6.0 * 2f64.sqrt()) / 18.0).abs() < 1e-15);
    assert_eq!(mean_edge_length(&TriMesh::default()), 0.0);
}

#[test]
fn sphere_measures_converge_to_closed_forms() {
    // Octahedron subdivided and projected: area → 4π, volume → 4π/3 from below.
    let mut m = TriMesh::new(
        vec![
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ],
        vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ],
    );
    for _ in 0..5 {
        let mut mid = std::collections::HashMap::new();
        let mut faces = Vec::new();
        for f in m.faces.clone() {
            let mut e = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3]));
                e[k] = *mid.entry((a, b)).or_insert_with(|| {
                    let (p, q) = (m.positions[a as usize], m.positions[b as usize]);
                    let s = [p[0] + q[0], p[1] + q[1], p[2] + q[2]];
                    let l = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
                    m.positions.push([s[0] / l, s[1] / l, s[2] / l]);
                    m.positions.len() as u32 - 1
                });
            }
            faces.extend([
                [f[0], e[0], e[2]],
                [e[0], f[1], e[1]],
                [e[2], e[1], f[2]],
                e,
            ]);
        }
        m.faces = faces;
    }
    let pi = std::f64::consts::PI;
    let (a, v) = (surface_area(&m), enclosed_volume(&m));
    assert!(v < 4.0 * pi / 3.0 && a < 4.0 * pi);
    assert!((v / (4.0 * pi / 3.0) - 1.0).abs() < 2e-3, "{v}");
    assert!((a / (4.0 * pi) - 1.0).abs() < 2e-3, "{a}");
    assert_outward_unit_normals(&m, 1.0);
}
