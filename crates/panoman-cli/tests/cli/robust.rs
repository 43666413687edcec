//! Bad inputs a new user runs into (issue 17): out-of-bounds targets, clouds in the wrong units,
//! truncated meshes, outputs into missing directories, a dataset given as a model, a non-PNG
//! image name, stale temporary files of a killed run. Each is one `error: <file>: …` line.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

use panoman::{Correction, Model, Params};
use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::TriMesh;

use crate::common;
use common::{TempDir, ok, one_line_error, panoman, small_model};

fn trained() -> &'static (TempDir, PathBuf, PathBuf) {
    static CELL: OnceLock<(TempDir, PathBuf, PathBuf)> = OnceLock::new();
    CELL.get_or_init(|| small_model("robust-test", 11))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A small closed mesh (tetrahedron, metres).
fn tetra() -> TriMesh {
    TriMesh::new(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
}

#[test]
fn fit_rejects_out_of_bounds_targets_naming_their_file() {
    let (dir, _data, model_path) = trained();
    let m = s(model_path);
    let model = Model::load(model_path).unwrap();
    let mesh = model.pose(&Params::default(), Correction::Apply).unwrap();
    let kp = dir.join("kp.json");
    KeypointsFile::from_all(&model.keypoints(&mesh).unwrap())
        .write(&kp)
        .unwrap();
    let out = dir.join("fit-out");
    let fit = |extra: &[&str]| {
        let mut a = vec!["fit", "--model", m, "--out", s(&out)];
        a.extend_from_slice(extra);
        panoman(&a)
    };

    // One keypoint at 1e300: PanoMan and the LBS baseline, an error naming file and keypoint.
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&kp).unwrap()).unwrap();
    doc["keypoints"]["neck"] = serde_json::json!([1e300, 0.0, 1.0]);
    let far = dir.join("far_kp.json");
    std::fs::write(&far, serde_json::to_string(&doc).unwrap()).unwrap();
    for extra in [&[][..], &["--baseline", "lbs"][..]] {
        let mut a = vec!["--keypoints", s(&far)];
        a.extend_from_slice(extra);
        let o = fit(&a);
        one_line_error(&o, &format!("{}: keypoint `neck`", far.display()));
        one_line_error(&o, "out of bounds");
        assert!(!out.join("mesh.obj").exists());
    }

    // A handle at 1e300 blames the handles file, not the keypoints.
    let handles = dir.join("handles.json");
    std::fs::write(
        &handles,
        r#"{"handles": [{"vertex": 3, "position": [0, 0, 1], "weight": 1},
                        {"vertex": 10, "position": [1e300, 0, 1], "weight": 1}]}"#,
    )
    .unwrap();
    let o = fit(&["--keypoints", s(&kp), "--handles", s(&handles)]);
    one_line_error(&o, &format!("{}: handle 1 (vertex 10)", handles.display()));
    assert!(!String::from_utf8_lossy(&o.stderr).contains("kp.json"));

    // Point clouds: in millimetres, of one point, in metres but 100 m away.
    let mm = dir.join("scan_mm.ply");
    let scaled: Vec<[f64; 3]> = mesh.iter().map(|p| p.map(|c| c * 1000.0)).collect();
    panoman_mesh::io::write_mesh(&mm, &TriMesh::new(scaled, model.faces().to_vec())).unwrap();
    one_line_error(
        &fit(&["--keypoints", s(&kp), "--points", s(&mm)]),
        &format!("{}: the point cloud spans", mm.display()),
    );
    one_line_error(
        &fit(&["--keypoints", s(&kp), "--points", s(&mm)]),
        "millimetres",
    );
    let one = dir.join("one.ply");
    std::fs::write(
        &one,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         property float z\nend_header\n0 0 1\n",
    )
    .unwrap();
    one_line_error(
        &fit(&["--keypoints", s(&kp), "--points", s(&one)]),
        &format!(
            "{}: the point cloud has 1 point, a fit needs at least 3",
            one.display()
        ),
    );
    let away = dir.join("away.ply");
    let moved: Vec<[f64; 3]> = mesh.iter().map(|p| [p[0] + 100.0, p[1], p[2]]).collect();
    panoman_mesh::io::write_mesh(&away, &TriMesh::new(moved, model.faces().to_vec())).unwrap();
    one_line_error(
        &fit(&["--keypoints", s(&kp), "--points", s(&away)]),
        &format!("{}: the point cloud's centroid is 100.", away.display()),
    );
    assert!(!out.join("mesh.obj").exists());

    // The library checks in-memory targets the same way (no file to name).
    let mut fitter = panoman::Fitter::new(&model).unwrap();
    let mut t = panoman::Targets::from_keypoints(&model.keypoints(&mesh).unwrap());
    t.handles.push(panoman::VertexHandle {
        vertex: 0,
        position: [0.0, f64::MAX, 0.0],
        weight: 1.0,
    });
    let e = fitter
        .fit(&t, &panoman::FitRequest::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("handle 0") && e.contains("out of bounds"), "{e}");
}

#[test]
fn a_dataset_given_as_model_is_named_as_such() {
    let (dir, data, _) = trained();
    let params = dir.join("empty_params.json");
    std::fs::write(&params, "{}").unwrap();
    let ds = data.join("dataset.safetensors");
    one_line_error(
        &panoman(&[
            "pose",
            "--model",
            s(&ds),
            "--params",
            s(&params),
            "--out",
            s(&dir.join("x.obj")),
        ]),
        &format!(
            "{}: this is a dataset (safetensors written by panoman synth), not a model file",
            ds.display()
        ),
    );
}

#[test]
fn train_checks_its_output_location_before_training() {
    let (dir, data, _) = trained();
    let missing = dir.join("no-such-dir");
    let target = missing.join("M.safetensors");
    let t = Instant::now();
    one_line_error(
        &common::train_small(data, &target, &[]),
        &format!(
            "{}: output directory {} does not exist",
            target.display(),
            missing.display()
        ),
    );
    assert!(t.elapsed().as_secs_f64() < 20.0, "{:?}", t.elapsed());
    // A file where the directory should be.
    let file = dir.join("a-file");
    std::fs::write(&file, "x").unwrap();
    one_line_error(
        &common::train_small(data, &file.join("M.safetensors"), &[]),
        "is not a directory",
    );
    // Checked before the data are even read.
    one_line_error(
        &common::train_small(&dir.join("no-such-data"), &target, &[]),
        "output directory",
    );
}

#[test]
fn a_killed_synth_leaves_no_stale_temporary_file_after_the_next_run() {
    let (dir, _, _) = trained();
    let data = dir.join("H2");
    std::fs::create_dir_all(&data).unwrap();
    // What a synth killed mid-write leaves (999999999 is above any Linux pid_max).
    let stale = [
        data.join(".dataset.safetensors.tmp-999999999"),
        data.join(".dataset.json.tmp-999999999"),
    ];
    for p in &stale {
        std::fs::write(p, vec![0u8; 4096]).unwrap();
    }
    ok(panoman(&[
        "synth",
        "--preset",
        "small",
        "--seed",
        "2",
        "--out",
        s(&data),
    ]));
    for p in &stale {
        assert!(!p.exists(), "{} survived", p.display());
    }
    let mut names: Vec<String> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["dataset.json", "dataset.safetensors"]);
}

#[test]
fn render_rejects_far_vertices_and_non_png_names() {
    let d = TempDir::new("robust-render");
    let good = d.join("t.obj");
    panoman_mesh::io::write_mesh(&good, &tetra()).unwrap();
    let far = d.join("far.obj");
    std::fs::write(
        &far,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e300 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let png = d.join("x.png");
    one_line_error(
        &panoman(&["render", s(&far), "--out", s(&png)]),
        &format!("{}: vertex 3 at", far.display()),
    );
    assert!(!png.exists());
    for name in ["x.jpg", "x.PNG.bak", "noext"] {
        let out = d.join(name);
        one_line_error(
            &panoman(&["render", s(&good), "--out", s(&out)]),
            &format!("{}: ", out.display()),
        );
        one_line_error(&panoman(&["render", s(&good), "--out", s(&out)]), "PNG");
        assert!(!out.exists());
    }
    ok(panoman(&[
        "render",
        s(&good),
        "--out",
        s(&d.join("ok.PNG")),
    ]));
    // A truncated OBJ (a quad mesh cut inside its last face) is refused too.
    let cut = d.join("cut.obj");
    std::fs::write(
        &cut,
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nf 1 2 3 4\nf 1 2 6 5\nf 2 3",
    )
    .unwrap();
    one_line_error(
        &panoman(&["render", s(&cut), "--out", s(&png)]),
        &format!("{}: line 9", cut.display()),
    );
}

#[test]
fn outputs_into_a_missing_directory_name_the_directory() {
    panoman_human::assets::ensure_default().expect("assets");
    let d = TempDir::new("robust-out");
    let missing = d.join("missing");
    let expect = |o: std::process::Output, file: &str| {
        let target = missing.join(file);
        one_line_error(
            &o,
            &format!(
                "{}: output directory {} does not exist",
                target.display(),
                missing.display()
            ),
        );
    };
    let t = d.join("t.obj");
    ok(panoman(&[
        "template",
        "--topology",
        "small",
        "--out",
        s(&t),
    ]));
    expect(
        panoman(&[
            "template",
            "--topology",
            "small",
            "--out",
            s(&missing.join("t.obj")),
        ]),
        "t.obj",
    );
    expect(
        panoman(&["render", s(&t), "--out", s(&missing.join("r.png"))]),
        "r.png",
    );
    expect(
        panoman(&[
            "keypoints",
            "--mesh",
            s(&t),
            "--topology",
            "small",
            "--out",
            s(&missing.join("k.json")),
        ]),
        "k.json",
    );
    let params = d.join("p.json");
    std::fs::write(&params, "{}").unwrap();
    expect(
        panoman(&[
            "generate",
            "--params",
            s(&params),
            "--out",
            s(&missing.join("g.obj")),
        ]),
        "g.obj",
    );
    assert!(!missing.exists());
}
