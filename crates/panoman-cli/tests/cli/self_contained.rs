//! A model file written by `panoman train` is self-contained: `pose`, `encode`, `fit`
//! (PanoMan and the LBS baseline) and `track` run with `PANOMAN_ASSETS` pointing at an empty
//! directory, and `fit` reports its setup time.

use crate::common;

use common::{ok, small_model};
use std::path::Path;
use std::process::{Command, Output};

/// Runs `panoman` with the asset tree replaced by the empty directory `empty`.
fn without_assets(empty: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(args)
        .env("PANOMAN_ASSETS", empty)
        .output()
        .expect("run panoman")
}

#[test]
fn pose_encode_fit_and_track_need_no_assets() {
    let (dir, _data, model) = small_model("self-contained", 3);
    let m = model.to_str().unwrap();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // Inputs made while the assets are still there: a template mesh and its keypoints.
    ok(common::panoman(&[
        "template",
        "--topology",
        "small",
        "--out",
        &p("T.obj"),
    ]));
    ok(common::panoman(&[
        "keypoints",
        "--mesh",
        &p("T.obj"),
        "--topology",
        "small",
        "--out",
        &p("K.json"),
    ]));
    let empty = dir.join("no-assets");
    std::fs::create_dir_all(&empty).unwrap();
    let run = |args: &[&str]| ok(without_assets(&empty, args));

    run(&[
        "encode",
        "--model",
        m,
        "--mesh",
        &p("T.obj"),
        "--out",
        &p("P.json"),
    ]);
    run(&[
        "pose",
        "--model",
        m,
        "--params",
        &p("P.json"),
        "--out",
        &p("X.obj"),
    ]);
    run(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        &p("K.json"),
        "--out",
        &p("fit"),
    ]);
    run(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        &p("K.json"),
        "--baseline",
        "lbs",
        "--out",
        &p("lbs"),
    ]);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for f in ["a", "b", "c"] {
        std::fs::copy(dir.join("K.json"), frames.join(format!("{f}.json"))).unwrap();
    }
    run(&[
        "track",
        "--model",
        m,
        "--frames",
        &p("frames"),
        "--out",
        &p("track"),
    ]);
    // Nothing was fetched into the empty directory.
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);

    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("fit/report.json")).unwrap())
            .unwrap();
    assert_eq!(report["method"], "panoman");
    let setup = report["setup_seconds"].as_f64().expect("setup_seconds");
    assert!(setup > 0.0 && setup.is_finite());
    assert!(
        report["keypoint_residuals"]["body"]["mean_mm"]
            .as_f64()
            .unwrap()
            < 5.0
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("track/summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["frames"], 3);

    // encode keeps the rigid placement: pose(encode(T)) is already where T is, i.e. the
    // least-squares rigid motion from the re-posed mesh onto T is the identity (it is the
    // placement encode stored, up to rounding), whatever the model's representation error.
    let t = panoman_mesh::io::read_mesh(&dir.join("T.obj")).unwrap();
    let x = panoman_mesh::io::read_mesh(&dir.join("X.obj")).unwrap();
    let k = panoman_mesh::align::rigid_align(&x.positions, &t.positions, None);
    let off_identity = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (k.r[i][j] - if i == j { 1.0 } else { 0.0 }).abs())
        .fold(0.0f64, f64::max);
    let shift = k.t.iter().map(|c| c.abs()).fold(0.0f64, f64::max);
    assert!(
        off_identity < 1e-6 && shift < 1e-6,
        "re-posed mesh is not placed: |R − I| {off_identity}, |t| {shift} m"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
