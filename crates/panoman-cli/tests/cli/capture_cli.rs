//! `panoman capture` on bad input: one clear error line each, nothing written. The happy path
//! (with a model) is tested in `crates/panoman-capture/tests/capture.rs`; the end-to-end run on
//! the demo videos is in `docs/results.md`.

use crate::common;

use common::{TempDir, one_line_error, panoman};
use std::path::{Path, PathBuf};

fn excerpt() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/pose2sim-excerpt")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// Runs capture on `dets` (a detection folder) into `tmp/out`; the model file exists but is
/// not a model (input errors must come before it is read).
fn capture(tmp: &Path, dets: &Path, extra: &[&str]) -> std::process::Output {
    let model = tmp.join("M.safetensors");
    std::fs::write(&model, b"not read").unwrap();
    let calib = excerpt().join("Calib.qca.txt");
    let out = tmp.join("out");
    let mut args = vec![
        "capture",
        "--calibration",
        calib.to_str().unwrap(),
        "--detections",
        dets.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    panoman(&args)
}

#[test]
fn detections_that_do_not_match_the_cameras_give_one_error_and_no_output() {
    let t = TempDir::new("capture-bad");
    let dets = t.path().join("dets");
    copy_dir(&excerpt().join("detections"), &dets);

    // A camera without detections.
    std::fs::rename(dets.join("cam04"), t.path().join("cam04-aside")).unwrap();
    let o = capture(t.path(), &dets, &[]);
    one_line_error(&o, "no detections of camera \"cam04\"");
    assert!(!t.path().join("out").exists());

    // Detections of a camera the calibration does not have.
    std::fs::rename(t.path().join("cam04-aside"), dets.join("cam05")).unwrap();
    let o = capture(t.path(), &dets, &[]);
    one_line_error(&o, "\"cam05\", which the calibration does not have");
    std::fs::rename(dets.join("cam05"), dets.join("cam04")).unwrap();

    // Frame counts that differ.
    let extra = dets.join("cam02").join("cam02_000000000099_keypoints.json");
    std::fs::copy(
        dets.join("cam02").join("cam02_000000000040_keypoints.json"),
        &extra,
    )
    .unwrap();
    let o = capture(t.path(), &dets, &[]);
    one_line_error(
        &o,
        "13 frames of camera \"cam02\" but 12 of camera \"cam01\"",
    );
    std::fs::remove_file(&extra).unwrap();

    // A detection file of another layout (COCO-18 body: 54 numbers, not BODY_25's 75).
    let f = dets.join("cam03").join("cam03_000000000045_keypoints.json");
    std::fs::write(
        &f,
        format!(
            r#"{{"version": 1.3, "people": [{{"pose_keypoints_2d": [{}]}}]}}"#,
            vec!["1.0"; 54].join(", ")
        ),
    )
    .unwrap();
    let o = capture(t.path(), &dets, &[]);
    one_line_error(&o, "cam03_000000000045_keypoints.json");
    assert!(!t.path().join("out").exists());

    // Offsets of the wrong count; an unknown held-out camera.
    std::fs::copy(
        excerpt().join("detections/cam03/cam03_000000000045_keypoints.json"),
        &f,
    )
    .unwrap();
    let o = capture(t.path(), &dets, &["--offsets", "0,1"]);
    one_line_error(&o, "--offsets: 2 values for 4 cameras");
    let o = capture(t.path(), &dets, &["--held-out-camera", "cam9"]);
    one_line_error(&o, "no camera \"cam9\" to hold out");
    assert!(!t.path().join("out").exists());
}

#[test]
fn videos_that_do_not_match_the_cameras_give_one_error() {
    let t = TempDir::new("capture-videos");
    let videos = t.path().join("videos");
    std::fs::create_dir_all(&videos).unwrap();
    for c in ["cam01", "cam02", "cam03"] {
        std::fs::write(videos.join(format!("{c}.mp4")), b"not a video").unwrap();
    }
    let model = t.path().join("M.safetensors");
    std::fs::write(&model, b"x").unwrap();
    let calib = excerpt().join("Calib.qca.txt");
    let out = t.path().join("out");
    let run = || {
        panoman(&[
            "capture",
            "--calibration",
            calib.to_str().unwrap(),
            "--videos",
            videos.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    one_line_error(&run(), "no video of camera \"cam04\"");
    std::fs::write(videos.join("cam04.mp4"), b"x").unwrap();
    std::fs::write(videos.join("cam07.mp4"), b"x").unwrap();
    one_line_error(
        &run(),
        "a video of camera \"cam07\", which the calibration does not have",
    );
    assert!(!out.exists());
}

/// An undecodable video: the detector's message becomes one error line, and the output folder
/// the run created is removed. Needs the detector's venv (`scripts/detect-setup.sh`, which CI
/// runs); skipped without it.
#[test]
fn an_undecodable_video_is_one_error_and_leaves_nothing() {
    let py = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target/detect/bin/python");
    if !py.is_file() {
        eprintln!("SKIPPED: no detector venv (bash scripts/detect-setup.sh)");
        return;
    }
    let t = TempDir::new("capture-undecodable");
    let videos = t.path().join("videos");
    std::fs::create_dir_all(&videos).unwrap();
    for c in ["cam01", "cam02", "cam03", "cam04"] {
        std::fs::write(videos.join(format!("{c}.mp4")), b"not a video").unwrap();
    }
    let model = t.path().join("M.safetensors");
    std::fs::write(&model, b"x").unwrap();
    let calib = excerpt().join("Calib.qca.txt");
    let out = t.path().join("out");
    let o = panoman(&[
        "capture",
        "--calibration",
        calib.to_str().unwrap(),
        "--videos",
        videos.to_str().unwrap(),
        "--python",
        py.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    one_line_error(&o, "cam01.mp4");
    assert!(!out.exists());
}
