//! `panoman track --jobs N`: independent sequences tracked in parallel give the results of
//! tracking them one by one, with the throughput in summary.json.
use crate::common;

use common::{ok, panoman, small_model};
use panoman_human::keypoints::KeypointsFile;
use panoman_model::model::PanoManModel;
use std::path::Path;

fn files(dir: &Path) -> Vec<String> {
    let mut f: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_file())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != "summary.json")
        .collect();
    f.sort();
    f
}

#[test]
fn track_jobs_matches_one_by_one() {
    let (dir, data, model_path) = small_model("track-jobs", 11);
    let model = PanoManModel::load(&model_path).unwrap();
    let m = model_path.to_str().unwrap();
    let ds = panoman_human::dataset::Dataset::open(&data).unwrap();
    let rows: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == 1 && ds.held_out.contains(&ds.identity[r]))
        .take(3)
        .collect();
    assert_eq!(rows.len(), 3);
    // Three sequences of three frames (the held-out people in rotated orders).
    let root = dir.join("seqs");
    for s in 0..3 {
        let seq = root.join(format!("s{s}"));
        std::fs::create_dir_all(&seq).unwrap();
        for f in 0..3 {
            let r = rows[(s + f) % 3];
            let truth: Vec<[f64; 3]> = ds
                .vertices(r)
                .unwrap()
                .iter()
                .map(|p| p.map(f64::from))
                .collect();
            KeypointsFile::from_all(&model.keypoints.evaluate(&truth))
                .write(&seq.join(format!("f{f:03}.json")))
                .unwrap();
        }
    }
    // One by one.
    for s in 0..3 {
        let out = dir.join(format!("one{s}"));
        let seq = root.join(format!("s{s}"));
        let stdout = ok(panoman(&[
            "track",
            "--model",
            m,
            "--frames",
            seq.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]));
        assert!(stdout.contains("frames/s"), "{stdout}");
        let sum: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert!(sum["frames_per_second"].as_f64().unwrap() > 0.0);
    }
    // A directory of sequences on two workers, and the same sequences given one by one with
    // --frames on one worker.
    let par = dir.join("par");
    let stdout = ok(panoman(&[
        "track",
        "--model",
        m,
        "--frames",
        root.to_str().unwrap(),
        "--jobs",
        "2",
        "--out",
        par.to_str().unwrap(),
    ]));
    assert!(
        stdout.contains("3 sequences, 9 frames on 2 workers"),
        "{stdout}"
    );
    let ser = dir.join("ser");
    let seqs: Vec<String> = (0..3)
        .map(|s| root.join(format!("s{s}")).to_str().unwrap().to_string())
        .collect();
    let mut args = vec!["track", "--model", m, "--out", ser.to_str().unwrap()];
    for s in &seqs {
        args.extend(["--frames", s.as_str()]);
    }
    ok(panoman(&args));
    for (top, jobs) in [(&par, 2), (&ser, 1)] {
        let sum: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(top.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(sum["jobs"], jobs);
        assert_eq!(sum["frames"], 9);
        assert_eq!(sum["sequences"].as_array().unwrap().len(), 3);
        assert!(sum["frames_per_second"].as_f64().unwrap() > 0.0);
        for s in 0..3 {
            let one = dir.join(format!("one{s}"));
            let got = top.join(format!("s{s}"));
            let names = files(&one);
            assert_eq!(names.len(), 6, "{names:?}");
            assert_eq!(files(&got), names);
            for n in &names {
                assert_eq!(
                    std::fs::read(one.join(n)).unwrap(),
                    std::fs::read(got.join(n)).unwrap(),
                    "{} differs from one-by-one",
                    got.join(n).display()
                );
            }
        }
    }
}
