//! Reading a `panoman track`-style folder of per-frame meshes as one sequence.

mod common;

use panoman_interchange::glb::{self, GlbOptions};
use panoman_interchange::sequence::Sequence;
use panoman_mesh::TriMesh;
use panoman_mesh::io::write_mesh;

fn tetra(shift: f64) -> TriMesh {
    TriMesh::new(
        vec![
            [shift, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
}

#[test]
fn frames_are_read_in_name_order() {
    let dir = common::scratch("sequence_order");
    // Written out of order, with a summary and params beside them as `track` leaves them.
    for (name, s) in [
        ("frame_002.obj", 0.2),
        ("frame_000.obj", 0.0),
        ("frame_001.ply", 0.1),
    ] {
        write_mesh(&dir.join(name), &tetra(s)).unwrap();
    }
    std::fs::write(dir.join("summary.json"), "{}").unwrap();
    std::fs::write(dir.join("frame_000.params.json"), "{}").unwrap();
    let seq = Sequence::read(&dir).unwrap();
    assert_eq!(seq.frames.len(), 3);
    let xs: Vec<f64> = seq.frames.iter().map(|f| f[0][0]).collect();
    assert_eq!(xs, vec![0.0, 0.1, 0.2]);
    assert!(seq.files[1].ends_with("frame_001.ply"));
    let bytes = glb::export_glb(&seq.faces, &seq.frames, None, &GlbOptions::default()).unwrap();
    let (doc, _) = glb::split_glb(&bytes).unwrap();
    assert_eq!(
        doc["meshes"][0]["primitives"][0]["targets"]
            .as_array()
            .unwrap()
            .len(),
        2
    );
}

#[test]
fn mismatched_frames_name_the_file() {
    let dir = common::scratch("sequence_mismatch");
    write_mesh(&dir.join("a.obj"), &tetra(0.0)).unwrap();
    let mut other = tetra(0.0);
    other.positions.push([2.0, 2.0, 2.0]);
    write_mesh(&dir.join("b.obj"), &other).unwrap();
    let e = Sequence::read(&dir).unwrap_err().to_string();
    assert!(
        e.contains("b.obj") && e.contains("5 vertices") && e.contains("has 4"),
        "{e}"
    );

    let mut flipped = tetra(0.0);
    flipped.faces[0] = [0, 1, 2];
    write_mesh(&dir.join("b.obj"), &flipped).unwrap();
    let e = Sequence::read(&dir).unwrap_err().to_string();
    assert!(
        e.contains("b.obj") && e.contains("face list differs"),
        "{e}"
    );

    let empty = common::scratch("sequence_empty");
    let e = Sequence::read(&empty).unwrap_err().to_string();
    assert!(
        e.contains("sequence_empty") && e.contains("no .obj or .ply"),
        "{e}"
    );
}
