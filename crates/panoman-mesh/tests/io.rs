//! Tests of OBJ/PLY reading and writing: bit-exact round trips, polygon triangulation, index
//! forms, malformed and truncated inputs (errors naming the file, never panics), atomic writes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use panoman_mesh::io::obj::{parse_obj, read_obj, write_obj};
use panoman_mesh::io::ply::{PlyFormat, parse_ply, parse_ply_points, read_ply, write_ply};
use panoman_mesh::io::{read_mesh, write_mesh};
use panoman_mesh::{MeshError, TriMesh};

/// splitmix64: a tiny deterministic generator for test data.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A fresh, empty directory for one test (removed by [`TempDir`]'s drop).
struct TempDir(PathBuf);
impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir =
            std::env::temp_dir().join(format!("panoman-mesh-io-{}-{}", std::process::id(), name));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn path(&self, file: &str) -> PathBuf {
        self.0.join(file)
    }
    fn entries(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(&self.0)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }
}
impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Coordinates that stress shortest round-trip formatting: random bit patterns (any finite value,
/// subnormals included), extremes, signed zeros and "decimal-unfriendly" values.
fn nasty_coordinates(rng: &mut Rng, n: usize) -> Vec<[f64; 3]> {
    let specials = [
        0.0,
        -0.0,
        f64::MIN_POSITIVE,
        -f64::MIN_POSITIVE,
        5e-324,
        -5e-324,
        2.225_073_858_507_201e-308, // largest subnormal
        f64::MAX,
        f64::MIN,
        f64::EPSILON,
        1e-5,
        9.999_999_999_999_999e-6,
        1e16,
        9_999_999_999_999_998.0,
        0.1,
        1.0 / 3.0,
        -2.0 / 3.0,
        123_456_789.123_456_79,
        1e300,
        -1e-300,
    ];
    (0..n)
        .map(|i| {
            let mut p = [0.0; 3];
            for (k, c) in p.iter_mut().enumerate() {
                *c = match (i + k) % 3 {
                    0 => specials[(i * 3 + k) % specials.len()],
                    1 => loop {
                        let x = f64::from_bits(rng.next());
                        if x.is_finite() {
                            break x;
                        }
                    },
                    _ => (rng.unit() - 0.5) * 2.0,
                };
            }
            p
        })
        .collect()
}

fn random_faces(rng: &mut Rng, nv: u32, nf: usize) -> Vec<[u32; 3]> {
    (0..nf)
        .map(|_| {
            loop {
                let f = [
                    rng.below(nv as u64) as u32,
                    rng.below(nv as u64) as u32,
                    rng.below(nv as u64) as u32,
                ];
                if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
                    break f;
                }
            }
        })
        .collect()
}

fn assert_bit_exact(a: &TriMesh, b: &TriMesh, what: &str) {
    assert_eq!(a.positions.len(), b.positions.len(), "{what}: vertex count");
    for (i, (p, q)) in a.positions.iter().zip(&b.positions).enumerate() {
        for k in 0..3 {
            assert_eq!(
                p[k].to_bits(),
                q[k].to_bits(),
                "{what}: vertex {i} coordinate {k}: wrote {:e}, read {:e}",
                p[k],
                q[k]
            );
        }
    }
    assert_eq!(a.faces, b.faces, "{what}: faces");
}

/// A closed UV sphere of radius `r` with `rings × segments` grid (two poles), triangles only,
/// outward oriented.
fn uv_sphere(rings: u32, segments: u32, r: f64) -> TriMesh {
    let mut positions = vec![[0.0, 0.0, r]];
    for i in 1..rings {
        let th = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / segments as f64;
            positions.push([
                r * th.sin() * ph.cos(),
                r * th.sin() * ph.sin(),
                r * th.cos(),
            ]);
        }
    }
    positions.push([0.0, 0.0, -r]);
    let south = positions.len() as u32 - 1;
    let at = |i: u32, j: u32| 1 + (i - 1) * segments + (j % segments);
    let mut faces = Vec::new();
    for j in 0..segments {
        faces.push([0, at(1, j), at(1, j + 1)]);
        faces.push([south, at(rings - 1, j + 1), at(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            faces.push([a, b, c]);
            faces.push([a, c, d]);
        }
    }
    TriMesh::new(positions, faces)
}

#[test]
fn round_trip_is_bit_exact_in_every_format() {
    let mut rng = Rng(42);
    let positions = nasty_coordinates(&mut rng, 600);
    let faces = random_faces(&mut rng, 600, 1000);
    let mesh = TriMesh::new(positions, faces);
    let dir = TempDir::new("roundtrip");

    let p = dir.path("a.obj");
    write_obj(&p, &mesh).unwrap();
    assert_bit_exact(&mesh, &read_obj(&p).unwrap(), "obj");

    let p = dir.path("a_ascii.ply");
    write_ply(&p, &mesh, PlyFormat::Ascii).unwrap();
    assert_bit_exact(&mesh, &read_ply(&p).unwrap(), "ply ascii");

    let p = dir.path("a_bin.ply");
    write_ply(&p, &mesh, PlyFormat::BinaryLittleEndian).unwrap();
    assert_bit_exact(&mesh, &read_ply(&p).unwrap(), "ply binary");
    // 24 bytes per vertex and 13 per face after the header.
    let bytes = std::fs::read(&p).unwrap();
    let header_end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    assert_eq!(bytes.len() - header_end, 600 * 24 + 1000 * 13);
    assert!(String::from_utf8_lossy(&bytes[..header_end]).contains("comment generated by panoman"));

    // Dispatch by extension, case-insensitively.
    for name in ["b.obj", "b.ply", "B.OBJ", "c.Ply"] {
        let p = dir.path(name);
        write_mesh(&p, &mesh).unwrap();
        assert_bit_exact(&mesh, &read_mesh(&p).unwrap(), name);
    }
    // write_mesh .ply is binary.
    let head = std::fs::read(dir.path("b.ply")).unwrap();
    assert!(head.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    // No temporary files are left behind.
    assert!(
        dir.entries().iter().all(|e| !e.contains(".tmp")),
        "{:?}",
        dir.entries()
    );
}

#[test]
fn negative_zero_and_extremes_survive_text_formats() {
    let mesh = TriMesh::new(
        vec![
            [-0.0, 5e-324, -f64::MAX],
            [f64::MIN_POSITIVE, 1e-310, 1e308],
            [0.1 + 0.2, -1e-7, 12345.678],
        ],
        vec![[0, 1, 2]],
    );
    let dir = TempDir::new("extremes");
    let p = dir.path("x.obj");
    write_obj(&p, &mesh).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert!(
        text.contains("v -0 5e-324 -1.7976931348623157e308\n"),
        "{text}"
    );
    assert!(text.contains("\nf 1 2 3\n"), "{text}");
    assert_bit_exact(&mesh, &read_obj(&p).unwrap(), "obj extremes");
    let p = dir.path("x.ply");
    write_ply(&p, &mesh, PlyFormat::Ascii).unwrap();
    assert_bit_exact(&mesh, &read_ply(&p).unwrap(), "ply extremes");
}

fn obj(text: &str) -> panoman_mesh::Result<TriMesh> {
    parse_obj(text, Path::new("test_input.obj"))
}

#[test]
fn obj_quad_splits_along_shorter_diagonal_keeping_winding() {
    // a-c shorter than b-d: (a,b,c),(c,d,a).
    let m = obj("v 0 0 0\nv 2 -1 0\nv 1 0 0\nv 2 1 0\nf 1 2 3 4\n").unwrap();
    // |a-c| = 1, |b-d| = 2.
    assert_eq!(m.faces, vec![[0, 1, 2], [2, 3, 0]]);
    // b-d shorter: (a,b,d),(d,b,c).
    let m = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 9 9 9\nf 1 2 5 4\n").unwrap();
    assert_eq!(m.faces, vec![[0, 1, 3], [3, 1, 4]]);
    // Equal diagonals (a square) take the second split.
    let m = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
    assert_eq!(m.faces, vec![[0, 1, 3], [3, 1, 2]]);
    // Both triangles keep the quad's orientation (+z for this CCW square).
    for f in &m.faces {
        let n = panoman_mesh::measure::face_normals(&TriMesh::new(m.positions.clone(), vec![*f]));
        assert!(n[0][2] > 0.999, "{f:?} {n:?}");
    }
}

#[test]
fn obj_ngons_are_fan_triangulated() {
    let m = obj("v 1 0 0\nv 0.3 0.95 0\nv -0.8 0.6 0\nv -0.8 -0.6 0\nv 0.3 -0.95 0\nf 1 2 3 4 5\n")
        .unwrap();
    assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    let m = obj("v 0 0 0\nv 1 0 0\nv 2 0 1\nv 2 1 1\nv 1 2 0\nv 0 1 0\nf 1 2 3 4 5 6\n").unwrap();
    assert_eq!(m.faces.len(), 4);
    assert_eq!(m.faces[3], [0, 4, 5]);
}

#[test]
fn obj_index_forms_negative_indices_and_ignored_records() {
    let text = "# a comment\r\n\
                mtllib x.mtl\r\n\
                o thing\r\n\
                g group one\r\n\
                v 0 0 0 1.0\r\n\
                v 1 0 0 0.5 0.5 0.5\r\n\
                v 1 1 0\r\n\
                v 0 1 0   # trailing comment\r\n\
                \r\n\
                vt 0 0\r\nvt 1 0\r\nvt 1 1\r\n\
                vn 0 0 1\r\n\
                usemtl skin\r\n\
                s off\r\n\
                f 1/1 2/2 3/3\r\n\
                f 1//1 3//1 4//1\r\n\
                f 1/1/1 2/2/1 4/3/1\r\n\
                f -4 -3 -1  # relative\r\n\
                l 1 2\r\n\
                v 5 5 5\r\n\
                f -5/1/1 -4//1 -1\r\n";
    let m = obj(text).unwrap();
    assert_eq!(m.positions.len(), 5);
    assert_eq!(m.positions[1], [1.0, 0.0, 0.0]);
    assert_eq!(m.positions[3], [0.0, 1.0, 0.0]);
    assert_eq!(
        m.faces,
        vec![[0, 1, 2], [0, 2, 3], [0, 1, 3], [0, 1, 3], [0, 1, 4]]
    );
}

/// Asserts that `result` is a Format error naming `file` whose message contains every `needle`.
fn assert_format_error<T: std::fmt::Debug>(
    result: panoman_mesh::Result<T>,
    file: &str,
    needles: &[&str],
) {
    match result {
        Err(e @ MeshError::Format { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(file), "message does not name {file}: {msg}");
            assert!(!msg.contains('\n'), "message is not one line: {msg}");
            for n in needles {
                assert!(msg.contains(n), "message lacks '{n}': {msg}");
            }
        }
        other => panic!("expected a Format error containing {needles:?}, got {other:?}"),
    }
}

#[test]
fn obj_malformed_inputs_are_errors_naming_file_and_line() {
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let cases: Vec<(String, Vec<&str>)> = vec![
        (
            format!("{tri}v 1.0 abc 2\nf 1 2 3\n"),
            vec!["line 4", "malformed number 'abc'"],
        ),
        (
            format!("{tri}v 1.0 2.0\nf 1 2 3\n"),
            vec!["line 4", "2 coordinates"],
        ),
        (format!("{tri}v 1.0 2.\n"), vec!["line 4", "2 coordinates"]),
        (
            format!("{tri}v nan 0 0\nf 1 2 3\n"),
            vec!["line 4", "non-finite"],
        ),
        (
            format!("{tri}v 0 inf 0\nf 1 2 3\n"),
            vec!["line 4", "non-finite"],
        ),
        (
            format!("{tri}v 0 0 1e999\nf 1 2 3\n"),
            vec!["line 4", "non-finite"],
        ),
        (format!("{tri}f 1 2\n"), vec!["line 4", "2 vertices"]),
        (format!("{tri}f\n"), vec!["line 4", "0 vertices"]),
        (format!("{tri}f 0 1 2\n"), vec!["line 4", "index 0"]),
        (format!("{tri}f 1 2 4\n"), vec!["line 4", "out of range"]),
        (format!("{tri}f 1 2 -4\n"), vec!["line 4", "out of range"]),
        (
            format!("{tri}f 1 2 99999999999\n"),
            vec!["line 4", "out of range"],
        ),
        (
            format!("{tri}f 1 x 3\n"),
            vec!["line 4", "malformed vertex index 'x'"],
        ),
        (
            format!("{tri}f 1 /2 3\n"),
            vec!["line 4", "malformed vertex index"],
        ),
        (
            format!("{tri}f 1 2 1\n"),
            vec!["line 4", "repeats vertex 1"],
        ),
        (
            format!("{tri}f 1 2 3 -3\n"),
            vec!["line 4", "repeats vertex 1"],
        ),
        (tri.to_string(), vec!["no faces"]),
        ("# nothing\n".to_string(), vec!["no vertices"]),
        (String::new(), vec!["no vertices"]),
        ("f 1 2 3\n".to_string(), vec!["no vertices"]),
    ];
    for (text, needles) in cases {
        assert_format_error(obj(&text), "test_input.obj", &needles);
    }
    // Through the file reader too: the message names the real file.
    let dir = TempDir::new("obj_errors");
    let p = dir.path("broken_mesh.obj");
    std::fs::write(&p, format!("{tri}f 1 2")).unwrap();
    assert_format_error(read_mesh(&p), "broken_mesh.obj", &["line 4"]);
}

#[test]
fn unsupported_extension_and_missing_file() {
    let dir = TempDir::new("ext");
    let p = dir.path("mesh.stl");
    std::fs::write(&p, "solid x\n").unwrap();
    assert_format_error(read_mesh(&p), "mesh.stl", &[".obj", ".ply"]);
    assert_format_error(read_mesh(&dir.path("noext")), "noext", &[".obj", ".ply"]);
    let m = TriMesh::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    assert_format_error(write_mesh(&dir.path("out.gltf"), &m), "out.gltf", &[".obj"]);
    match read_mesh(&dir.path("missing.ply")) {
        Err(e @ MeshError::Io { .. }) => assert!(e.to_string().contains("missing.ply"), "{e}"),
        other => panic!("expected Io error, got {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------------
// PLY

fn ply(bytes: &[u8]) -> panoman_mesh::Result<TriMesh> {
    parse_ply(bytes, Path::new("test_input.ply"))
}

#[test]
fn ply_ascii_with_extra_properties_and_elements() {
    let text = "ply\r\n\
                format ascii 1.0\r\n\
                comment made by hand\r\n\
                obj_info nothing\r\n\
                element vertex 5\r\n\
                property float nx\r\n\
                property double x\r\n\
                property list uchar int junk\r\n\
                property float32 y\r\n\
                property uchar red\r\n\
                property int16 z\r\n\
                element face 2\r\n\
                property uchar flags\r\n\
                property list uint8 uint32 vertex_index\r\n\
                property float quality\r\n\
                element edge 1\r\n\
                property int vertex1\r\n\
                property int vertex2\r\n\
                end_header\r\n\
                0.5 0 2 7 7 0 255 0\r\n\
                0.5 1.5 0 0 255 1\r\n\
                \r\n\
                0.5 1 1 9 1 255 -2\r\n\
                0.5 0 0 1 0 3\r\n\
                0.5 9 0 9 0 9\r\n\
                1 4 0 1 2 3 0.5\r\n\
                1 3 1 2 4 0.5\r\n\
                0 1\r\n";
    let m = ply(text.as_bytes()).unwrap();
    assert_eq!(
        m.positions,
        vec![
            [0.0, 0.0, 0.0],
            [1.5, 0.0, 1.0],
            [1.0, 1.0, -2.0],
            [0.0, 1.0, 3.0],
            [9.0, 9.0, 9.0]
        ]
    );
    // Quad 0 1 2 3: |p0 − p2|² = 6 < |p1 − p3|² = 7.25 → (a,b,c),(c,d,a).
    assert_eq!(m.faces, vec![[0, 1, 2], [2, 3, 0], [1, 2, 4]]);
}

/// Builds a binary PLY with odd property types, extra properties and an extra element, in the
/// given endianness, for a known 4-vertex, 2-face (one quad) mesh.
fn handmade_binary(big_endian: bool) -> (Vec<u8>, TriMesh) {
    let enc = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut b = format!(
        "ply\nformat {enc} 1.0\ncomment x\n\
         element material 2\nproperty uchar r\nproperty list ushort int16 stuff\n\
         element vertex 4\nproperty double nx\nproperty float x\nproperty short y\n\
         property list uchar float tex\nproperty int8 k\nproperty double z\n\
         element face 2\nproperty int id\nproperty list uint uint vertex_indices\nproperty float64 w\n\
         element edge 1\nproperty uint a\nproperty uint b\nend_header\n"
    )
    .into_bytes();
    fn put<const N: usize>(b: &mut Vec<u8>, le: [u8; N], big: bool) {
        let mut x = le;
        if big {
            x.reverse();
        }
        b.extend_from_slice(&x);
    }
    let be = big_endian;
    // material: r, list(ushort count, int16 items)
    put(&mut b, 7u8.to_le_bytes(), be);
    put(&mut b, 2u16.to_le_bytes(), be);
    put(&mut b, (-5i16).to_le_bytes(), be);
    put(&mut b, 6i16.to_le_bytes(), be);
    put(&mut b, 8u8.to_le_bytes(), be);
    put(&mut b, 0u16.to_le_bytes(), be);
    let verts: [(f32, i16, f64); 4] = [
        (0.0, 0, 0.0),
        (1.5, 0, 0.25),
        (1.0, 2, -1.0),
        (-0.5, 1, 1e-300),
    ];
    for (i, &(x, y, z)) in verts.iter().enumerate() {
        put(&mut b, 9.75f64.to_le_bytes(), be);
        put(&mut b, x.to_le_bytes(), be);
        put(&mut b, y.to_le_bytes(), be);
        put(&mut b, (i as u8).to_le_bytes(), be); // list of i floats
        for _ in 0..i {
            put(&mut b, 3.5f32.to_le_bytes(), be);
        }
        put(&mut b, (-1i8).to_le_bytes(), be);
        put(&mut b, z.to_le_bytes(), be);
    }
    let faces: [&[u32]; 2] = [&[0, 1, 2, 3], &[1, 2, 3]];
    for f in faces {
        put(&mut b, 77i32.to_le_bytes(), be);
        put(&mut b, (f.len() as u32).to_le_bytes(), be);
        for &v in f {
            put(&mut b, v.to_le_bytes(), be);
        }
        put(&mut b, 0.5f64.to_le_bytes(), be);
    }
    put(&mut b, 0u32.to_le_bytes(), be);
    put(&mut b, 1u32.to_le_bytes(), be);
    let positions = verts
        .iter()
        .map(|&(x, y, z)| [x as f64, y as f64, z])
        .collect::<Vec<_>>();
    // Quad 0 1 2 3: |p0 − p2|² = 6 ≥ |p1 − p3|² = 4 + 1 + 0.0625 → (a,b,d),(d,b,c).
    let expected = TriMesh::new(positions, vec![[0, 1, 3], [3, 1, 2], [1, 2, 3]]);
    (b, expected)
}

#[test]
fn ply_binary_both_endiannesses_with_skipped_properties() {
    for be in [false, true] {
        let (bytes, expected) = handmade_binary(be);
        let m = ply(&bytes).unwrap();
        assert_eq!(m, expected, "big_endian = {be}");
        let pts = parse_ply_points(&bytes, Path::new("p.ply")).unwrap();
        assert_eq!(pts, expected.positions);
    }
}

#[test]
fn ply_points_reader_accepts_point_clouds() {
    let text = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n";
    assert_eq!(
        parse_ply_points(text, Path::new("cloud.ply")).unwrap(),
        vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    );
    // ...but a mesh needs faces.
    assert_format_error(ply(text), "test_input.ply", &["no 'face' element"]);
}

#[test]
fn ply_malformed_inputs_are_errors_naming_the_file() {
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let verts = "0 0 0\n1 0 0\n0 1 0\n";
    let cases: Vec<(String, Vec<&str>)> = vec![
        (String::new(), vec!["empty file"]),
        ("PK\u{3}\u{4}garbage".into(), vec!["not a PLY file"]),
        (
            "ply\nformat ascii 1.0\nelement vertex 3\n".into(),
            vec!["end_header"],
        ),
        (
            "ply\nformat binary_middle_endian 1.0\nend_header\n".into(),
            vec!["unsupported format"],
        ),
        (
            "ply\nformat ascii 2.0\nend_header\n".into(),
            vec!["version"],
        ),
        (
            "ply\nelement vertex 1\nproperty float x\nend_header\n".into(),
            vec!["no 'format'"],
        ),
        (
            "ply\nformat ascii 1.0\nproperty float x\nend_header\n".into(),
            vec!["before any 'element'"],
        ),
        (
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n".into(),
            vec!["unknown property type 'float128'"],
        ),
        (
            "ply\nformat ascii 1.0\nelement vertex x\nend_header\n".into(),
            vec!["invalid element count"],
        ),
        (
            "ply\nformat ascii 1.0\nbanana\nend_header\n".into(),
            vec!["unknown header keyword 'banana'"],
        ),
        (
            head.replace("property float z\n", ""),
            vec!["no 'z' property"],
        ),
        (
            head.replace("vertex_indices", "verts"),
            vec!["no 'vertex_indices'"],
        ),
        (
            head.replace("list uchar int", "list float int"),
            vec!["integer"],
        ),
        (
            head.replace("element vertex 3", "element vertex 0"),
            vec!["0 vertices"],
        ),
        (
            format!("{head}{verts}"),
            vec!["truncated: header declares 1 faces but data ends after 0"],
        ),
        (
            format!("{head}0 0 0\n1 0 0\n"),
            vec!["truncated: header declares 3 vertices but data ends after 2"],
        ),
        (format!("{head}{verts}3 0 1 3\n"), vec!["out of range"]),
        (format!("{head}{verts}3 0 1 -1\n"), vec!["out of range"]),
        (format!("{head}{verts}2 0 1\n"), vec!["2 vertices"]),
        (format!("{head}{verts}3 0 1 1\n"), vec!["repeats vertex 1"]),
        (
            format!("{head}{verts}3 0 1\n"),
            vec!["line 13", "too few values"],
        ),
        (
            format!("{head}{verts}3 0 1 2 7\n"),
            vec!["line 13", "more values"],
        ),
        (
            format!("{head}0 0 nan\n1 0 0\n0 1 0\n3 0 1 2\n"),
            vec!["non-finite"],
        ),
        (
            format!("{head}0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n"),
            vec!["line 10", "malformed number 'zero'"],
        ),
        (
            format!("{head}{verts}3 0 1 2.5\n"),
            vec!["malformed integer"],
        ),
    ];
    for (text, needles) in cases {
        assert_format_error(ply(text.as_bytes()), "test_input.ply", &needles);
    }
    // Binary: non-finite floats and absurd counts.
    let bin_head = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let mut b = bin_head.as_bytes().to_vec();
    for x in [0.0f32, f32::NAN, 1.0] {
        b.extend_from_slice(&x.to_le_bytes());
    }
    assert_format_error(ply(&b), "test_input.ply", &["non-finite"]);
    let huge = bin_head.replace("vertex 1", "vertex 18446744073709551615");
    assert_format_error(
        ply(huge.as_bytes()),
        "test_input.ply",
        &["too many vertices"],
    );
    let huge = bin_head.replace("face 1", "face 18446744073709551615");
    assert_format_error(ply(huge.as_bytes()), "test_input.ply", &["truncated"]);
    // An element without properties: its rows take no bytes, so a lying count would be
    // read for ever (a fuzz timeout); both readers refuse the header.
    let empty = bin_head.replace(
        "element vertex 1",
        "element padding 99999999999994\nelement vertex 1",
    );
    let needles = ["element 'padding' declares 99999999999994 rows but no properties"];
    assert_format_error(ply(empty.as_bytes()), "test_input.ply", &needles);
    assert_format_error(
        parse_ply_points(empty.as_bytes(), Path::new("test_input.ply")),
        "test_input.ply",
        &needles,
    );
}

#[test]
fn ply_truncated_binary_names_counts() {
    let mesh = uv_sphere(20, 30, 1.0);
    let dir = TempDir::new("trunc_msg");
    let p = dir.path("sphere.ply");
    write_ply(&p, &mesh, PlyFormat::BinaryLittleEndian).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let header_end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let cut = &bytes[..header_end + 100 * 24 + 5];
    let msg = parse_ply(cut, &p).unwrap_err().to_string();
    assert!(msg.contains("sphere.ply"), "{msg}");
    assert!(
        msg.contains(&format!(
            "truncated: header declares {} vertices but data ends after 100",
            mesh.positions.len()
        )),
        "{msg}"
    );
    let cut = &bytes[..bytes.len() - 1];
    let msg = parse_ply(cut, &p).unwrap_err().to_string();
    assert!(
        msg.contains(&format!(
            "header declares {} faces but data ends after {}",
            mesh.faces.len(),
            mesh.faces.len() - 1
        )),
        "{msg}"
    );
    // Via the file reader as well.
    std::fs::write(&p, cut).unwrap();
    assert_format_error(read_mesh(&p), "sphere.ply", &["truncated"]);
}

#[test]
fn truncation_at_every_offset_never_panics() {
    let mesh = TriMesh::new(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-0.0, 1e-300, 123.456],
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [4, 1, 2]],
    );
    let dir = TempDir::new("trunc_all");
    // Binary PLY: every strict prefix is an error.
    let p = dir.path("m.ply");
    write_ply(&p, &mesh, PlyFormat::BinaryLittleEndian).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    for k in 0..bytes.len() {
        assert!(
            ply(&bytes[..k]).is_err(),
            "binary PLY cut at {k} of {} parsed",
            bytes.len()
        );
    }
    assert_eq!(ply(&bytes).unwrap(), mesh);
    // Big-endian handmade file too.
    let (big, _) = handmade_binary(true);
    for k in 0..big.len() {
        assert!(ply(&big[..k]).is_err(), "big-endian PLY cut at {k} parsed");
    }
    // ASCII PLY and OBJ: any prefix is Ok or Err, but never a panic; an Ok result is valid.
    write_ply(&p, &mesh, PlyFormat::Ascii).unwrap();
    let ascii = std::fs::read(&p).unwrap();
    let q = dir.path("m.obj");
    write_obj(&q, &mesh).unwrap();
    let text = std::fs::read_to_string(&q).unwrap();
    for k in 0..ascii.len() {
        if let Ok(m) = ply(&ascii[..k]) {
            m.check_basic().unwrap();
        }
    }
    for k in 0..=text.len() {
        if let Ok(m) = obj(&text[..k]) {
            m.check_basic().unwrap();
        }
    }
    // Cutting the OBJ inside the last face record is an error.
    let last_f = text.rfind("\nf ").unwrap();
    for k in last_f + 2..text.len() - 1 {
        assert!(
            obj(&text[..k]).is_err(),
            "OBJ cut at {k} parsed: {:?}",
            &text[last_f..k]
        );
    }
}

#[test]
fn random_byte_corruption_never_panics() {
    let (bin, _) = handmade_binary(false);
    let mut rng = Rng(7);
    let mesh = uv_sphere(6, 8, 2.0);
    let dir = TempDir::new("corrupt");
    let p = dir.path("c.ply");
    write_ply(&p, &mesh, PlyFormat::Ascii).unwrap();
    let ascii = std::fs::read(&p).unwrap();
    let q = dir.path("c.obj");
    write_obj(&q, &mesh).unwrap();
    let text = std::fs::read(&q).unwrap();
    for _ in 0..3000 {
        for src in [&bin, &ascii, &text] {
            let mut b = src.clone();
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(b.len() as u64) as usize;
                b[i] = rng.next() as u8;
            }
            if let Ok(m) = ply(&b) {
                m.check_basic().unwrap();
            }
            if let Ok(m) = obj(&String::from_utf8_lossy(&b)) {
                m.check_basic().unwrap();
            }
        }
    }
}

#[test]
fn atomic_write_into_missing_directory_leaves_nothing() {
    let dir = TempDir::new("atomic");
    let m = TriMesh::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    let missing = dir.path("no_such_dir");
    for name in ["x.obj", "x.ply"] {
        let target = missing.join(name);
        match write_mesh(&target, &m) {
            Err(e @ MeshError::Io { .. }) => assert!(e.to_string().contains(name), "{e}"),
            other => panic!("expected Io error, got {other:?}"),
        }
        assert!(!missing.exists());
    }
    assert!(dir.entries().is_empty(), "{:?}", dir.entries());

    // Invalid meshes are refused before anything is written, and an existing file survives.
    let target = dir.path("keep.obj");
    write_mesh(&target, &m).unwrap();
    let before = std::fs::read(&target).unwrap();
    let bad = TriMesh::new(m.positions.clone(), vec![[0, 1, 5]]);
    assert!(write_mesh(&target, &bad).is_err());
    let nan = TriMesh::new(
        vec![[f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        m.faces.clone(),
    );
    let e = write_mesh(&target, &nan).unwrap_err().to_string();
    assert!(e.contains("keep.obj"), "{e}");
    assert_eq!(std::fs::read(&target).unwrap(), before);
    assert_eq!(dir.entries(), vec!["keep.obj".to_string()]);

    // Overwriting replaces the content.
    let m2 = TriMesh::new(
        vec![[0.0; 3], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
        vec![[0, 1, 2]],
    );
    write_mesh(&target, &m2).unwrap();
    assert_eq!(read_mesh(&target).unwrap(), m2);
    assert_eq!(dir.entries(), vec!["keep.obj".to_string()]);
}

#[test]
fn timing_13k_vertex_mesh() {
    // 112 rings × 116 segments: 12,878 vertices, 25,752 faces.
    let mesh = uv_sphere(112, 116, 0.9);
    let dir = TempDir::new("timing");
    let time = |f: &mut dyn FnMut()| {
        let mut best = f64::INFINITY;
        for _ in 0..5 {
            let t = Instant::now();
            f();
            best = best.min(t.elapsed().as_secs_f64() * 1e3);
        }
        best
    };
    let p_obj = dir.path("t.obj");
    let p_ply = dir.path("t.ply");
    let p_asc = dir.path("t_ascii.ply");
    let w_obj = time(&mut || write_obj(&p_obj, &mesh).unwrap());
    let w_ply = time(&mut || write_ply(&p_ply, &mesh, PlyFormat::BinaryLittleEndian).unwrap());
    let w_asc = time(&mut || write_ply(&p_asc, &mesh, PlyFormat::Ascii).unwrap());
    let r_obj = time(&mut || assert_eq!(read_obj(&p_obj).unwrap().faces.len(), mesh.faces.len()));
    let r_ply = time(&mut || assert_eq!(read_ply(&p_ply).unwrap().faces.len(), mesh.faces.len()));
    let r_asc = time(&mut || assert_eq!(read_ply(&p_asc).unwrap().faces.len(), mesh.faces.len()));
    println!(
        "{} vertices, {} faces (best of 5, incl. fsync on write): \
         OBJ write {w_obj:.2} ms read {r_obj:.2} ms; PLY binary write {w_ply:.2} ms read {r_ply:.2} ms; \
         PLY ascii write {w_asc:.2} ms read {r_asc:.2} ms",
        mesh.positions.len(),
        mesh.faces.len()
    );
    assert_bit_exact(&mesh, &read_obj(&p_obj).unwrap(), "timing obj");
    assert_bit_exact(&mesh, &read_ply(&p_ply).unwrap(), "timing ply");
}

#[test]
fn obj_cut_inside_the_face_list_is_an_error() {
    let quads = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n\
                 f 1 2 3 4\nf 1 2 6 5\n";
    // A complete file (with or without the final newline) reads.
    assert_eq!(obj(quads).unwrap().faces.len(), 4);
    assert_eq!(obj(quads.trim_end()).unwrap().faces.len(), 4);
    // A quad mesh whose last line was cut after three corners.
    let cut = format!("{quads}f 2 3 6");
    assert_format_error(
        obj(&cut),
        "test_input.obj",
        &["line 9", "incomplete last line", "truncated"],
    );
    // The same face with a newline is a complete (mixed) record and reads.
    assert_eq!(obj(&format!("{cut}\n")).unwrap().faces.len(), 5);
    // A corner cut mid-token: `4/3/1` → `4/3` (form differs) and `4/` (malformed anywhere).
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n\
               f 1/1/1 2/2/1 3/3/1\n";
    assert_format_error(
        obj(&format!("{tri}f 2/2/1 4/3/1 3/3")),
        "test_input.obj",
        &["line 10", "incomplete last line"],
    );
    for bad in ["3/", "3/3/", "3//", "3/x", "3/1/1/1"] {
        assert_format_error(
            obj(&format!("{tri}f 2/2/1 4/3/1 {bad}\n")),
            "test_input.obj",
            &["line 10", &format!("malformed vertex index '{bad}'")],
        );
    }
    // A complete unterminated triangle reads.
    assert_eq!(
        obj(&format!("{tri}f 2/2/1 4/3/1 3/3/1"))
            .unwrap()
            .faces
            .len(),
        2
    );
    // A vertex line cut before its colour columns (then faces cannot follow: still an error).
    assert!(obj("v 0 0 0 1 1 1\nv 1 0 0 1 1 1\nv 0 1 0 1").is_err());
}

#[test]
fn obj_written_by_panoman_cut_at_a_line_boundary_is_an_error() {
    let mesh = uv_sphere(6, 8, 1.0);
    let dir = TempDir::new("obj_cut_lines");
    let p = dir.path("s.obj");
    write_obj(&p, &mesh).unwrap();
    let text = std::fs::read_to_string(&p).unwrap();
    assert_eq!(obj(&text).unwrap(), mesh);
    // Drop the last k face lines (each cut ends with a newline: a complete-looking file).
    let lines: Vec<&str> = text.lines().collect();
    for k in 1..5 {
        let cut = lines[..lines.len() - k].join("\n") + "\n";
        assert_format_error(
            obj(&cut),
            "test_input.obj",
            &["header comment declares", "truncated"],
        );
    }
    // Every prefix of a panoman file that ends inside the face list is an error (panoman's files
    // end with a newline).
    let first_f = text.find("\nf ").unwrap();
    for k in first_f + 1..text.len() {
        assert!(obj(&text[..k]).is_err(), "cut at {k} parsed");
    }
}

#[test]
fn ply_with_more_data_than_the_header_declares_is_an_error() {
    let mesh = uv_sphere(6, 8, 1.0);
    let nf = mesh.faces.len();
    let nv = mesh.positions.len();
    let dir = TempDir::new("ply_extra");
    let p = dir.path("s.ply");
    for format in [PlyFormat::BinaryLittleEndian, PlyFormat::Ascii] {
        write_ply(&p, &mesh, format).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(ply(&bytes).unwrap(), mesh);
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let end = text.find("end_header\n").unwrap();
        let (header, _) = bytes.split_at(end);
        let header = String::from_utf8_lossy(header).into_owned();
        for (from, to) in [
            (
                format!("element face {nf}\n"),
                format!("element face {}\n", nf - 3),
            ),
            (
                format!("element vertex {nv}\n"),
                format!("element vertex {}\n", nv - 1),
            ),
        ] {
            let mut lying = header.replace(&from, &to).into_bytes();
            lying.extend_from_slice(&bytes[end..]);
            let e = ply(&lying).unwrap_err().to_string();
            assert!(
                e.starts_with("test_input.ply: ") && !e.contains('\n'),
                "{e}"
            );
            if from.contains("face") {
                assert!(
                    e.contains("after the last declared element"),
                    "{format:?}: {e}"
                );
            }
        }
        // Ascii files may end with blank lines.
        if format == PlyFormat::Ascii {
            let mut padded = bytes.clone();
            padded.extend_from_slice(b"\n\n");
            assert_eq!(ply(&padded).unwrap(), mesh);
        }
    }
    // The points reader checks the same.
    write_ply(&p, &mesh, PlyFormat::BinaryLittleEndian).unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    bytes.extend_from_slice(&[0u8; 24]);
    assert_format_error(
        parse_ply_points(&bytes, Path::new("pts.ply")),
        "pts.ply",
        &["24 bytes of data after the last declared element"],
    );
}

#[test]
fn writing_into_a_missing_directory_names_the_directory() {
    let dir = TempDir::new("missing_out");
    let m = TriMesh::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    let missing = dir.path("nope");
    let target = missing.join("x.obj");
    let e = write_mesh(&target, &m).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: output directory {} does not exist",
            target.display(),
            missing.display()
        )
    );
    let e = panoman_mesh::io::write_bytes_atomically(&target, b"x")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("output directory") && e.contains("does not exist"),
        "{e}"
    );
    // Up-front check: missing directory, a file as directory; a writable one passes and
    // leaves nothing behind.
    let e = panoman_mesh::io::check_output_path(&target)
        .unwrap_err()
        .to_string();
    assert!(e.contains("does not exist"), "{e}");
    std::fs::write(dir.path("file"), b"x").unwrap();
    let e = panoman_mesh::io::check_output_path(&dir.path("file").join("y.obj"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("is not a directory"), "{e}");
    panoman_mesh::io::check_output_path(&dir.path("ok.obj")).unwrap();
    assert_eq!(dir.entries(), vec!["file".to_string()]);
}

#[test]
fn stale_temp_files_of_dead_processes_are_removed_before_writing() {
    let dir = TempDir::new("stale");
    let m = TriMesh::new(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    // 999999999 is above any Linux pid_max (2^22): never a live process.
    let own = std::process::id();
    for name in [
        ".x.obj.tmp-999999999-3".to_string(),
        ".x.obj.tmp-999999999".to_string(),
        format!(".x.obj.tmp-{own}-987654"),
        ".y.obj.tmp-999999999-0".to_string(),
        ".x.obj.tmp-notapid".to_string(),
    ] {
        std::fs::write(dir.path(&name), b"partial").unwrap();
    }
    write_mesh(&dir.path("x.obj"), &m).unwrap();
    let mut want = vec![
        format!(".x.obj.tmp-{own}-987654"),
        ".x.obj.tmp-notapid".to_string(),
        ".y.obj.tmp-999999999-0".to_string(),
        "x.obj".to_string(),
    ];
    if !cfg!(target_os = "linux") {
        want.push(".x.obj.tmp-999999999-3".into());
        want.push(".x.obj.tmp-999999999".into());
    }
    want.sort();
    assert_eq!(dir.entries(), want);
}
