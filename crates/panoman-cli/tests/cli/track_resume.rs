//! `panoman track --resume`: a track run killed (SIGKILL) mid-clip and restarted with
//! `--resume` gives byte-identical per-frame files to an uninterrupted run (bit-exact tracker
//! checkpoint) and a summary.json covering every frame; a second writer of the same output
//! directory fails at once with a one-line error.

use crate::common;

use common::{clip_keypoints, ok, one_line_error, panoman, small_model};
use panoman::{Generator, KeypointsFile, Model};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn args<'a>(m: &'a str, frames: &'a str, out: &'a str, resume: bool) -> Vec<&'a str> {
    let mut a = vec!["track", "--model", m, "--frames", frames, "--out", out];
    if resume {
        a.push("--resume");
    }
    a
}

/// Writes the `n` keypoint files of the clip into `dir`/frames.
fn write_clip(model_path: &Path, dir: &Path, n: usize) -> std::path::PathBuf {
    let model = Model::load(model_path).unwrap();
    let g = Generator::from_model(&model).unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for f in 0..n {
        KeypointsFile::from_all(&clip_keypoints(&model, &g, f, n))
            .write(&frames.join(format!("frame_{f:03}.json")))
            .unwrap();
    }
    frames
}

/// Runs `track` (with `extra` arguments) into `cut`, kills it (SIGKILL) once it has recorded
/// 5 frames, and resumes it; returns the frames recorded when it was killed.
fn kill_and_resume(m: &str, fr: &str, cut: &Path, extra: &[&str]) -> usize {
    let cut_s = cut.to_str().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(args(m, fr, cut_s, false))
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while recorded(cut) < 5 && t.elapsed() < Duration::from_secs(120) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let _ = child.kill();
    let _ = child.wait();
    let killed_after = recorded(cut);
    assert!(killed_after >= 5, "the run recorded {killed_after} frames");
    let was_partial = !cut.join("summary.json").exists();
    let mut a = args(m, fr, cut_s, true);
    a.extend_from_slice(extra);
    let o = panoman(&a);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    ok(o);
    if was_partial {
        assert!(err.contains("resuming after frame"), "{err}");
    }
    killed_after
}

/// The per-frame files of two runs are byte-identical (the tolerance of the guarantee is 0).
fn assert_same_frames(full: &Path, cut: &Path, n: usize, killed_after: usize) {
    for f in 0..n {
        for ext in ["obj", "params.json"] {
            let name = format!("frame_{f:03}.{ext}");
            assert_eq!(
                std::fs::read(full.join(&name)).unwrap(),
                std::fs::read(cut.join(&name)).unwrap(),
                "{name} differs after a resume (killed after {killed_after} frames)"
            );
        }
    }
}

/// Lines of DIR/track-resume/rows.jsonl (frames recorded so far).
fn recorded(out: &Path) -> usize {
    std::fs::read_to_string(out.join("track-resume/rows.jsonl"))
        .map(|t| t.lines().count())
        .unwrap_or(0)
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn killed_track_resumes_to_the_same_outputs() {
    let (dir, _data, model_path) = small_model("track-resume", 3);
    let n = 40;
    let frames = write_clip(&model_path, &dir, n);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (m, fr) = (s(&model_path), s(&frames));
    let full = dir.join("full");
    ok(panoman(&args(&m, &fr, &s(&full), false)));

    // Killed (SIGKILL) after a few frames, then resumed.
    let cut = dir.join("cut");
    let cut_s = s(&cut);
    let killed_after = kill_and_resume(&m, &fr, &cut, &[]);
    assert_same_frames(&full, &cut, n, killed_after);
    let (a, b) = (summary(&full), summary(&cut));
    assert_eq!(b["frames"], n);
    assert_eq!(b["per_frame"].as_array().unwrap().len(), n);
    for key in [
        "steps_tried",
        "steps_accepted",
        "not_converged",
        "ik_retried",
    ] {
        assert_eq!(a[key], b[key], "{key}");
    }
    for (ra, rb) in a["per_frame"]
        .as_array()
        .unwrap()
        .iter()
        .zip(b["per_frame"].as_array().unwrap())
    {
        assert_eq!(ra["frame"], rb["frame"]);
        assert_eq!(ra["keypoint_residuals"], rb["keypoint_residuals"]);
    }

    // Resuming a finished run redoes nothing and keeps the files.
    ok(panoman(&args(&m, &fr, &cut_s, true)));
    assert_eq!(
        std::fs::read(full.join("frame_039.obj")).unwrap(),
        std::fs::read(cut.join("frame_039.obj")).unwrap()
    );
    // Another model: refused with one line, nothing rewritten.
    let other = dir.join("other.safetensors");
    std::fs::copy(&model_path, &other).unwrap();
    let mut bytes = std::fs::read(&other).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&other, bytes).unwrap();
    one_line_error(
        &panoman(&args(&s(&other), &fr, &cut_s, true)),
        "another model file",
    );

    // A second writer of the same directory fails at once (the lock of a running track).
    let lock = std::fs::OpenOptions::new()
        .write(true)
        .open(cut.join("track-resume/lock"))
        .unwrap();
    lock.lock().unwrap();
    one_line_error(
        &panoman(&args(&m, &fr, &cut_s, false)),
        "another `panoman track` is writing",
    );
    drop(lock);
}

/// With the foot–floor contact prior (`--contacts`), whose planted-foot anchors carry state
/// from frame to frame: a killed and resumed run gives the same files (the anchors are in the
/// checkpoint, bit for bit); summary.json reports the contacts (the clip's feet stand
/// throughout); resuming it without --contacts is refused; missing --fps and a frame
/// without an ankle keypoint are one-line errors.
#[test]
fn contacts_track_resumes_to_the_same_outputs() {
    let (dir, _data, model_path) = small_model("track-resume-contacts", 3);
    let n = 30;
    let frames = write_clip(&model_path, &dir, n);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (m, fr) = (s(&model_path), s(&frames));
    let contacts = ["--contacts", "--fps", "30"];
    let full = dir.join("full");
    let mut a = args(&m, &fr, full.to_str().unwrap(), false);
    a.extend_from_slice(&contacts);
    ok(panoman(&a));
    let sum = summary(&full);
    let c = &sum["contacts"];
    assert_eq!(c["frames_down"], serde_json::json!([n, n]), "{c}");
    assert_eq!(c["weights"].as_array().unwrap().len(), n);
    let cut = dir.join("cut");
    let killed_after = kill_and_resume(&m, &fr, &cut, &contacts);
    assert_same_frames(&full, &cut, n, killed_after);
    assert_eq!(summary(&cut)["contacts"], sum["contacts"]);
    // The checkpoint was written with --contacts: a resume without it is refused.
    one_line_error(
        &panoman(&args(&m, &fr, cut.to_str().unwrap(), true)),
        "other options",
    );
    // --contacts needs --fps (clap's usage error).
    let mut a = args(&m, &fr, cut.to_str().unwrap(), false);
    a.push("--contacts");
    let o = panoman(&a);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--fps"));
    // A frame without its ankles.
    let f5 = frames.join("frame_005.json");
    let mut k = KeypointsFile::read(&f5).unwrap();
    let la = panoman::keypoint_names()
        .iter()
        .position(|n| n == "l_ankle")
        .unwrap();
    k.points.remove(&la);
    k.weights.remove(&la);
    k.write(&f5).unwrap();
    let mut a = args(&m, &fr, full.to_str().unwrap(), false);
    a.extend_from_slice(&contacts);
    one_line_error(&panoman(&a), "frame_005.json: no l_ankle keypoint");
}
