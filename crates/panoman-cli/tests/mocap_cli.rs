//! `panoman mocap solve | retarget | export` through the binary on the committed excerpts
//! of the real captures, with the library's small model.

mod common;

use common::{ok, one_line_error, panoman};
use std::path::{Path, PathBuf};

fn dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("panoman-mocap-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn excerpt(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../panoman-mocap/tests/data")
        .join(name)
        .display()
        .to_string()
}

fn model() -> String {
    panoman::training::small_model(None)
        .unwrap()
        .display()
        .to_string()
}

#[test]
fn solve_then_export_as_bvh() {
    let d = dir("solve");
    let out = d.join("lbs");
    let m = model();
    let s = ok(panoman(&[
        "mocap",
        "solve",
        "--markers",
        &excerpt("ThomasFechten_head.csm"),
        "--model",
        &m,
        "--method",
        "lbs",
        "--frames",
        "0:8",
        "--folds",
        "2",
        "--held-out-step",
        "4",
        "--calibration-frames",
        "4",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(s.contains("held-out marker error"), "{s}");
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(rep["n_frames"], 8);
    assert!(rep["held_out_marker_error_mm"]["mean"].as_f64().unwrap() > 0.0);
    assert!(out.join("mesh_00007.obj").is_file() && out.join("marker_map.json").is_file());
    let bvh = d.join("lbs.bvh");
    ok(panoman(&[
        "mocap",
        "export",
        "--params",
        out.to_str().unwrap(),
        "--model",
        &m,
        "--bvh",
        bvh.to_str().unwrap(),
    ]));
    let b = panoman_mocap::bvh::read_bvh(&bvh).unwrap();
    assert_eq!(b.n_frames(), 8);
    assert_eq!(b.joints.len(), 163);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn retarget_writes_params_and_summary() {
    let d = dir("retarget");
    ok(panoman(&[
        "mocap",
        "retarget",
        "--bvh",
        &excerpt("01_01_head.bvh"),
        "--model",
        &model(),
        "--shape-frames",
        "4",
        "--out",
        d.to_str().unwrap(),
    ]));
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("summary.json")).unwrap()).unwrap();
    let mean = s["joint_error_mm"]["mean"].as_f64().unwrap();
    assert!(mean > 0.0 && mean < 25.0, "{mean}");
    assert!(d.join("params_00000.json").is_file());
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_input_is_one_line() {
    let d = dir("bad");
    let m = model();
    let o = d.join("o");
    one_line_error(
        &panoman(&[
            "mocap",
            "solve",
            "--markers",
            "/nonexistent/x.c3d",
            "--model",
            &m,
            "--out",
            o.to_str().unwrap(),
        ]),
        "/nonexistent/x.c3d",
    );
    let txt = d.join("x.trc");
    std::fs::write(&txt, "not markers").unwrap();
    one_line_error(
        &panoman(&[
            "mocap",
            "solve",
            "--markers",
            txt.to_str().unwrap(),
            "--model",
            &m,
            "--out",
            o.to_str().unwrap(),
        ]),
        "x.trc",
    );
    assert!(!o.exists(), "nothing written on error");
    one_line_error(
        &panoman(&[
            "mocap",
            "export",
            "--params",
            d.to_str().unwrap(),
            "--model",
            &m,
            "--bvh",
            d.join("b.bvh").to_str().unwrap(),
        ]),
        "no params_",
    );
    let _ = std::fs::remove_dir_all(&d);
}
