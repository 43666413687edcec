//! Regressions of what `scripts/fault-inject.py` found: a dataset whose two files come from
//! different runs (a `synth` killed between its renames, or two writers) is refused instead of
//! loading as valid, and a `mocap solve` write error names the file once.

use crate::common;

use common::{TempDir, ok, one_line_error, panoman};
use panoman_human::dataset::Dataset;
use std::path::Path;

#[test]
fn dataset_files_of_two_runs_are_refused() {
    let d = TempDir::new("faults-dataset");
    let (a, b) = (d.join("A"), d.join("B"));
    for (out, seed) in [(&a, "0"), (&b, "1")] {
        ok(panoman(&[
            "synth",
            "--preset",
            "small",
            "--seed",
            seed,
            "--identities",
            "3",
            "--body",
            "4",
            "--face",
            "4",
            "--hand",
            "4",
            "--out",
            out.to_str().unwrap(),
        ]));
        Dataset::open(out).unwrap();
    }
    // B's description with A's tensors: same shapes, another run.
    std::fs::copy(b.join("dataset.json"), a.join("dataset.json")).unwrap();
    let e = Dataset::open(&a).unwrap_err().to_string();
    assert!(
        e.contains("dataset.safetensors") && e.contains("different runs"),
        "{e}"
    );
}

#[test]
fn mocap_write_errors_name_the_file_once() {
    let d = TempDir::new("faults-mocap");
    let out = d.join("S");
    // A directory where the first mesh goes: its write fails.
    std::fs::create_dir_all(out.join("mesh_00000.obj")).unwrap();
    let m = panoman::training::small_model(None).unwrap();
    let csm = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../panoman-mocap/tests/data/ThomasFechten_head.csm");
    let o = panoman(&[
        "mocap",
        "solve",
        "--markers",
        csm.to_str().unwrap(),
        "--model",
        m.to_str().unwrap(),
        "--method",
        "lbs",
        "--frames",
        "0:2",
        "--folds",
        "0",
        "--calibration-frames",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    let target = out.join("mesh_00000.obj").display().to_string();
    one_line_error(&o, &target);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.matches(&target).count(), 1, "{err}");
}
