//! `panoman keypoints` end to end (the real binary): the 133 keypoints of the full and small
//! templates, equal to the library's definitions, and one-line errors naming the file for a
//! mesh with the wrong vertex count or a missing file.

use panoman_human::keypoints::{KeypointsFile, N_KEYPOINTS, keypoint_index, load_or_build};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::io;
use std::path::Path;

use crate::common;
use common::panoman;

/// A fresh `<tmp>/panoman-test-kp-<tag>-<pid>`, removed when the guard drops.
fn tmpdir(tag: &str) -> common::TempDir {
    common::TempDir::new(&format!("kp-{tag}"))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

#[test]
fn keypoints_of_the_templates() {
    let d = tmpdir("ok");
    let assets = panoman_human::assets::ensure_default().expect("assets");
    let full = full_template(&assets).unwrap();
    let small = small_template(&assets, &full).unwrap();
    let defs = load_or_build(&assets, &full, &small).unwrap();
    for (topology, mesh) in [("full", &full.mesh), ("small", &small.mesh)] {
        let m = d.join(format!("{topology}.ply"));
        let k = d.join(format!("{topology}.json"));
        io::write_mesh(&m, mesh).unwrap();
        let o = panoman(&[
            "keypoints",
            "--mesh",
            s(&m),
            "--out",
            s(&k),
            "--topology",
            topology,
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let file = KeypointsFile::read(&k).unwrap();
        assert_eq!(file.points.len(), N_KEYPOINTS);
        let set = if topology == "full" {
            &defs.full
        } else {
            &defs.small
        };
        let expect = set.evaluate(&mesh.positions);
        for (i, p) in &file.points {
            assert_eq!(*p, expect[*i], "{topology}: keypoint {i}");
        }
        // Plausible anatomy on the template (metres, Z up, left at +x).
        let at = |n: &str| file.points[&keypoint_index(n).unwrap()];
        assert!(at("nose")[2] > at("neck")[2] && at("neck")[2] > at("body_center")[2]);
        assert!(at("l_wrist")[0] > 0.3 && at("r_wrist")[0] < -0.3);
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn wrong_vertex_count_and_missing_file_are_one_line_errors() {
    let d = tmpdir("err");
    let assets = panoman_human::assets::ensure_default().expect("assets");
    let full = full_template(&assets).unwrap();
    let small = small_template(&assets, &full).unwrap();
    let m = d.join("small.obj");
    io::write_mesh(&m, &small.mesh).unwrap();
    let out = d.join("k.json");
    let o = panoman(&["keypoints", "--mesh", s(&m), "--out", s(&out)]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.starts_with(&format!("error: {}: 1229 vertices", m.display()))
            && err.contains("13348")
            && err.contains("--topology small"),
        "{err}"
    );
    assert!(!out.exists());
    let missing = d.join("nope.obj");
    let o = panoman(&["keypoints", "--mesh", s(&missing), "--out", s(&out)]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.starts_with("error: ") && err.contains("nope.obj"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let _ = std::fs::remove_dir_all(&d);
}
