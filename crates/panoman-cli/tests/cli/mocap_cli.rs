//! `panoman mocap solve | retarget | export` through the binary on the committed excerpts
//! of the real captures, with the library's small model.

use crate::common;

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
    let truth = rig_joints(&m, &out, &b);
    let ours: Vec<Vec<[f64; 3]>> = (0..b.n_frames()).map(|f| b.joint_positions(f)).collect();
    let d_ours = max_joint_difference(&truth, &ours);
    assert!(d_ours < 1e-6, "our reader: max joint difference {d_ours} m");
    match python_bvh_joints(&bvh, &b) {
        Some(theirs) => {
            let d_py = max_joint_difference(&truth, &theirs);
            assert!(
                d_py < 1e-6,
                "PyPI `bvh` reader: max joint difference {d_py} m"
            );
        }
        None => eprintln!(
            "\n*** SKIPPED the second BVH reader: no Python with the PyPI `bvh` package (scripts/python-setup.sh installs it into target/python; PANOMAN_PY_TESTS=1 makes this an error) ***\n"
        ),
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// The rig's posed bone heads (m) of the solve's `params_*.json`, per frame, in the BVH's
/// joint order.
fn rig_joints(model: &str, solve: &Path, b: &panoman_mocap::bvh::Bvh) -> Vec<Vec<[f64; 3]>> {
    let model = panoman::Model::load(model).unwrap();
    let g = model.rig().unwrap().generator.clone();
    let mut files: Vec<PathBuf> = std::fs::read_dir(solve)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("params_"))
        })
        .collect();
    files.sort();
    let params: Vec<_> = files.iter().map(|p| g.read_params(p).unwrap()).collect();
    let identity = g.identity(&params[0].shape).unwrap();
    params
        .iter()
        .map(|p| {
            let heads = identity.pose(&p.pose).bone_heads;
            b.joints
                .iter()
                .map(|j| heads[g.bone_names().iter().position(|n| *n == j.name).unwrap()])
                .collect()
        })
        .collect()
}

fn max_joint_difference(a: &[Vec<[f64; 3]>], b: &[Vec<[f64; 3]>]) -> f64 {
    assert_eq!(a.len(), b.len(), "frame counts");
    let mut worst = 0.0f64;
    for (fa, fb) in a.iter().zip(b) {
        assert_eq!(fa.len(), fb.len(), "joint counts");
        for (p, q) in fa.iter().zip(fb) {
            let d = (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt();
            worst = worst.max(if d.is_finite() { d } else { f64::INFINITY });
        }
    }
    worst
}

/// Joint positions of `bvh` by `tools/python/bvh_fk.py` (the PyPI `bvh` package as reader),
/// per frame in the joint order of `b`; `None` when no Python with that package is found
/// (`$PANOMAN_PYTHON`, else `target/python/bin/python`, the venv of scripts/python-setup.sh), which `PANOMAN_PY_TESTS=1` turns
/// into a failure.
fn python_bvh_joints(bvh: &Path, b: &panoman_mocap::bvh::Bvh) -> Option<Vec<Vec<[f64; 3]>>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = std::env::var_os("PANOMAN_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target/python/bin/python"));
    let required = std::env::var("PANOMAN_PY_TESTS").is_ok_and(|v| v == "1");
    let has_bvh = std::process::Command::new(&python)
        .args(["-c", "import bvh"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_bvh {
        assert!(
            !required,
            "PANOMAN_PY_TESTS=1 but {} cannot import the `bvh` package",
            python.display()
        );
        return None;
    }
    let json = bvh.with_extension("py.json");
    let o = std::process::Command::new(&python)
        .arg(root.join("tools/python/bvh_fk.py"))
        .arg(bvh)
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "bvh_fk.py: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["frames"].as_u64(), Some(b.n_frames() as u64));
    let joint = |name: &str, f: usize| -> [f64; 3] {
        let p = &v["joints"][name][f];
        [0, 1, 2].map(|k| p[k].as_f64().unwrap_or(f64::NAN))
    };
    Some(
        (0..b.n_frames())
            .map(|f| b.joints.iter().map(|j| joint(&j.name, f)).collect())
            .collect(),
    )
}

#[test]
fn retarget_writes_params_and_summary() {
    let d = dir("retarget");
    let (bvh, m) = (excerpt("01_01_head.bvh"), model());
    // `mocap retarget` of the excerpt into `out` with `extra` arguments.
    let retarget = |out: &Path, extra: &[&str]| {
        let mut args = vec!["mocap", "retarget", "--bvh", &bvh, "--model", &m];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        ok(panoman(&args));
    };
    retarget(&d, &["--shape-frames", "4"]);
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("summary.json")).unwrap()).unwrap();
    let mean = s["joint_error_mm"]["mean"].as_f64().unwrap();
    assert!(mean > 0.0 && mean < 25.0, "{mean}");
    assert!(d.join("params_00000.json").is_file());
    // Tracked from the TC-133 keypoints (feet included) after a shape calibration from two
    // frames.
    let t = d.join("track");
    let track = [
        "--shape-frames",
        "0",
        "--track",
        "0::10",
        "--calibrate-shape",
        "2",
    ];
    retarget(&t, &track);
    let tr: serde_json::Value =
        serde_json::from_slice(&std::fs::read(t.join("track.json")).unwrap()).unwrap();
    assert_eq!(tr["layout"], "TC-133");
    assert_eq!(tr["targets"], "TC-133 keypoints");
    let c = &tr["shape_calibration"];
    assert_eq!(c["frames"].as_array().unwrap().len(), 2);
    assert_eq!(c["knobs"].as_array().unwrap().len(), 9);
    assert!(tr["panoman"]["mean_mm"].as_f64().unwrap().is_finite());
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
    for (flag, needle) in [
        ("--temporal-prior=-1", "--temporal-prior"),
        ("--patch-sigma=nan", "--patch-sigma"),
        ("--glitch-m=-0.04", "--glitch-m"),
        ("--glitch-low-m=nan", "--glitch-low-m"),
        ("--pose-placement-ridge=-0.05", "--pose-placement-ridge"),
        ("--forearm-roll-deg=200", "--forearm-roll-deg"),
    ] {
        one_line_error(
            &panoman(&[
                "mocap",
                "solve",
                "--markers",
                &excerpt("nick_freeform_001_head.c3d"),
                "--model",
                &m,
                flag,
                "--out",
                o.to_str().unwrap(),
            ]),
            needle,
        );
        assert!(!o.exists(), "nothing written on error ({flag})");
    }
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

#[test]
fn eval_reports_both_methods_on_every_capture() {
    let d = dir("eval");
    let data = d.join("data");
    std::fs::create_dir_all(&data).unwrap();
    let out = d.join("out");
    // Missing captures: one line naming the file, nothing written.
    one_line_error(
        &panoman(&[
            "mocap",
            "eval",
            "--model",
            &model(),
            "--data",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]),
        "01_01.bvh",
    );
    assert!(!out.exists(), "nothing written on error");
    // The committed excerpts under the names `panoman data fetch` writes.
    for (from, to) in [
        ("nick_freeform_001_head.c3d", "nick_freeform_001.c3d"),
        ("Nick01.vsk", "Nick01.vsk"),
        ("ThomasFechten_head.csm", "ThomasFechten.csm"),
        ("01_01_head.bvh", "01_01.bvh"),
    ] {
        std::fs::copy(excerpt(from), data.join(to)).unwrap();
    }
    ok(panoman(&[
        "mocap",
        "eval",
        "--model",
        &model(),
        "--data",
        data.to_str().unwrap(),
        "--preset",
        "quick",
        "--out",
        out.to_str().unwrap(),
    ]));
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    for c in ["nick", "thomas"] {
        for m in ["panoman", "lbs"] {
            let r = &s[c]["methods"][m];
            let h = r["held_out_marker_error_mm"]["mean"].as_f64().unwrap();
            let fitted = r["fitted_residual_mm"]["mean"].as_f64().unwrap();
            assert!(
                h.is_finite() && h > 0.0 && fitted > 0.0,
                "{c} {m}: {h} {fitted}"
            );
            let j = &r["jitter_m_per_s2"];
            for k in ["mesh_vertices", "model_markers", "observed_markers"] {
                assert!(j[k].as_f64().unwrap() > 0.0, "{c} {m} {k}");
            }
        }
        assert!(out.join(format!("markers_{c}.png")).is_file());
    }
    for k in ["tc127", "tc127_contacts", "tc133"] {
        let t = &s["cmu_01_01"][k];
        assert!(t["panoman"]["mean_mm"].as_f64().unwrap().is_finite(), "{k}");
        assert_eq!(
            t["shape_calibration"]["knobs"].as_array().unwrap().len(),
            9,
            "{k}"
        );
    }
    // The contact prior found planted feet in the excerpt: it starts in a T-pose, the left
    // foot standing, the right one shuffling (3 and 0 frames down, measured).
    let c = &s["cmu_01_01"]["tc127_contacts"];
    let n = c["per_frame"].as_array().unwrap().len() as u64;
    let down: Vec<u64> = c["contacts"]["frames_down"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d.as_u64().unwrap())
        .collect();
    assert!(
        down.len() == 2 && down.iter().all(|&d| d <= n) && down.iter().sum::<u64>() > 0,
        "contacts: {down:?} of {n} frames"
    );
    for png in ["residuals.png", "cmu_track.png", "cmu_worst.png"] {
        assert!(out.join(png).is_file(), "{png}");
    }
    let _ = std::fs::remove_dir_all(&d);
}
