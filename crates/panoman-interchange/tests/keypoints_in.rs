//! The same targets written as panoman JSON, OpenPose JSON and CMU Panoptic JSON (in the
//! layouts of docs/formats-interchange.md) read back as identical TC-133 targets; bad files give
//! one error naming the file.

mod common;

use std::path::{Path, PathBuf};

use panoman_human::keypoints::{
    FACE_OFFSET, FEET_OFFSET, KeypointGroup, KeypointsFile, LHAND_OFFSET, N_BODY, N_FACE, N_FEET,
    N_HAND,
};
use panoman_interchange::keypoints_in::{
    self, ImportOptions, KeypointFormat, OPENPOSE_BODY25_FEET, OPENPOSE_BODY25_TO_TC133, Unit,
};
use serde_json::{Value, json};

/// Deterministic pseudo-random coordinates in metres (about ±1 m).
fn coord(i: usize, c: usize) -> f64 {
    let x = ((i * 3 + c) as f64 * 0.7548776662466927).fract();
    (x - 0.5) * 2.0 + 0.001 * c as f64
}

const MISSING_BODY: [usize; 2] = [1, 13]; // nose, r_knee
const FACE_W: f64 = 0.8;
const LHAND_W: f64 = 0.625;

/// The targets: body with varied confidences and two missing, face and left hand complete
/// with one weight each (Panoptic has one score per part), right hand absent.
fn targets() -> KeypointsFile {
    let mut k = KeypointsFile::default();
    for t in 0..N_BODY {
        if !MISSING_BODY.contains(&t) {
            k.points.insert(t, [coord(t, 0), coord(t, 1), coord(t, 2)]);
            k.weights.insert(t, 0.5 + t as f64 / 32.0);
        }
    }
    for t in FACE_OFFSET..FACE_OFFSET + N_FACE {
        k.points.insert(t, [coord(t, 0), coord(t, 1), coord(t, 2)]);
        k.weights.insert(t, FACE_W);
    }
    for t in LHAND_OFFSET..LHAND_OFFSET + N_HAND {
        k.points.insert(t, [coord(t, 0), coord(t, 1), coord(t, 2)]);
        k.weights.insert(t, LHAND_W);
    }
    k
}

/// `x y z c` records (cm) of TC-133 indices `idx`; missing → zeros with c = 0.
fn xyzc(k: &KeypointsFile, idx: impl Iterator<Item = usize>) -> Vec<f64> {
    idx.flat_map(|t| match k.points.get(&t) {
        Some(p) => vec![p[0] * 100.0, p[1] * 100.0, p[2] * 100.0, k.weight(t)],
        None => vec![0.0; 4],
    })
    .collect()
}

fn xyz_cm(k: &KeypointsFile, idx: impl Iterator<Item = usize>) -> Vec<f64> {
    idx.flat_map(|t| {
        let p = k.points[&t];
        [p[0] * 100.0, p[1] * 100.0, p[2] * 100.0]
    })
    .collect()
}

fn openpose_doc(k: &KeypointsFile) -> Value {
    // BODY_25: the mapped 15 and the six foot points from the targets, the other 4 (eyes,
    // ears) arbitrary.
    let mut pose = vec![0.0; 100];
    for s in 0..25 {
        pose[4 * s..4 * s + 4].copy_from_slice(&[s as f64, -(s as f64), 7.0, 0.9]);
    }
    for (t, &s) in OPENPOSE_BODY25_TO_TC133.iter().enumerate() {
        pose[4 * s..4 * s + 4].copy_from_slice(&xyzc(k, t..t + 1));
    }
    for (k_, &s) in OPENPOSE_BODY25_FEET.iter().enumerate() {
        let t = FEET_OFFSET + k_;
        pose[4 * s..4 * s + 4].copy_from_slice(&xyzc(k, t..t + 1));
    }
    json!({
        "version": 1.3,
        "people": [{
            "person_id": [-1],
            "pose_keypoints_2d": vec![1.0; 75],
            "pose_keypoints_3d": pose,
            "face_keypoints_2d": vec![1.0; 210],
            "face_keypoints_3d": xyzc(k, FACE_OFFSET..FACE_OFFSET + N_FACE),
            "hand_left_keypoints_2d": [],
            "hand_left_keypoints_3d": xyzc(k, LHAND_OFFSET..LHAND_OFFSET + N_HAND),
            "hand_right_keypoints_2d": [],
            "hand_right_keypoints_3d": []
        }]
    })
}

fn panoptic_docs(k: &KeypointsFile) -> [Value; 3] {
    let mut j19 = xyzc(k, 0..N_BODY);
    j19.extend([10.0, 20.0, 30.0, 0.7].repeat(4)); // eyes and ears: no TC-133 counterpart
    [
        json!({"version": 0.7, "univTime": 1234.5, "fpsType": "hd_29_97",
               "bodies": [{"id": 0, "joints19": j19}]}),
        json!({"version": 0.1, "univTime": 1234.5, "people": [{"id": 0, "face70": {
            "landmarks": xyz_cm(k, FACE_OFFSET..FACE_OFFSET + N_FACE),
            "averageScore": FACE_W, "visibility": [[0, 1]]}}]}),
        json!({"version": 0.1, "univTime": 1234.5, "people": [{"id": 0, "left_hand": {
            "landmarks": xyz_cm(k, LHAND_OFFSET..LHAND_OFFSET + N_HAND),
            "averageScore": LHAND_W, "visibility": [[0]]}}]}),
    ]
}

fn write(dir: &Path, name: &str, v: &Value) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, serde_json::to_string_pretty(v).unwrap()).unwrap();
    p
}

fn assert_same(a: &KeypointsFile, b: &KeypointsFile, what: &str) {
    let ka: Vec<_> = a.points.keys().collect();
    let kb: Vec<_> = b.points.keys().collect();
    assert_eq!(ka, kb, "{what}: different keypoint sets");
    for (i, p) in &a.points {
        let q = b.points[i];
        for c in 0..3 {
            assert!(
                (p[c] - q[c]).abs() <= 1e-12,
                "{what}: keypoint {i}: {p:?} vs {q:?}"
            );
        }
    }
    assert_eq!(a.weights, b.weights, "{what}: weights differ");
}

#[test]
fn tc127_openpose_and_panoptic_give_the_same_targets() {
    let dir = common::scratch("keypoints_in_same");
    let want = targets();
    let tc = dir.join("frame.tc127.json");
    want.write(&tc).unwrap();
    let op = write(&dir, "frame_keypoints.json", &openpose_doc(&want));
    let [b, f, h] = panoptic_docs(&want);
    let pb = write(&dir, "body3DScene_00000001.json", &b);
    let pf = write(&dir, "faceRecon3D_hd00000001.json", &f);
    let ph = write(&dir, "handRecon3D_hd00000001.json", &h);
    let opts = ImportOptions::default();
    assert_eq!(opts.unit, Unit::Centimetre, "documented default unit");

    let from_tc = keypoints_in::read_keypoints(&tc, &opts).unwrap();
    let from_op = keypoints_in::read_keypoints(&op, &opts).unwrap();
    let from_pan = keypoints_in::read_keypoints_files(&[&pb, &pf, &ph], &opts).unwrap();
    assert_same(&want, &from_tc, "tc127");
    assert_same(&want, &from_op, "openpose");
    assert_same(&want, &from_pan, "panoptic");
    assert_eq!(from_op.points.len(), 15 - 2 + 70 + 21);
    for t in MISSING_BODY {
        assert!(!from_op.points.contains_key(&t) && !from_pan.points.contains_key(&t));
    }

    // The explicit format must agree with the file; metres are an option.
    let forced = ImportOptions {
        format: Some(KeypointFormat::OpenPose),
        ..opts
    };
    let e = keypoints_in::read_keypoints(&pb, &forced)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("body3DScene_00000001.json") && e.contains("OpenPose"),
        "{e}"
    );
    let metres = ImportOptions {
        unit: Unit::Metre,
        ..opts
    };
    let m = keypoints_in::read_keypoints(&op, &metres).unwrap();
    let p0 = m.points[&0];
    assert!((p0[0] - want.points[&0][0] * 100.0).abs() < 1e-9);
}

fn error_of(dir: &Path, name: &str, v: &Value) -> String {
    let p = write(dir, name, v);
    let e = keypoints_in::read_keypoints(&p, &ImportOptions::default())
        .expect_err(name)
        .to_string();
    assert!(e.contains(name), "error does not name the file: {e}");
    e
}

#[test]
fn bad_keypoint_files_give_clear_errors() {
    let dir = common::scratch("keypoints_in_bad");
    let k = targets();
    let e = error_of(&dir, "unknown.json", &json!({"frames": []}));
    assert!(e.contains("unknown keypoints layout"), "{e}");

    let mut doc = openpose_doc(&k);
    doc["people"][0]["pose_keypoints_3d"] = json!(vec![1.0; 99]);
    let e = error_of(&dir, "short_pose.json", &doc);
    assert!(
        e.contains("expected 100 numbers") && e.contains("got 99"),
        "{e}"
    );

    let mut doc = openpose_doc(&k);
    doc["people"][0]["hand_left_keypoints_3d"] = json!(vec![1.0; 63]);
    let e = error_of(&dir, "hand_xyz.json", &doc);
    assert!(
        e.contains("hand_left_keypoints_3d") && e.contains("got 63"),
        "{e}"
    );

    let only2d = json!({"version": 1.3, "people": [{"pose_keypoints_2d": vec![1.0; 75],
        "pose_keypoints_3d": [], "face_keypoints_3d": []}]});
    let e = error_of(&dir, "only2d.json", &only2d);
    assert!(
        e.contains("only 2D") && e.contains("pose_keypoints_2d"),
        "{e}"
    );

    let [mut b, mut f, _] = panoptic_docs(&k);
    b["bodies"][0]["joints19"] = json!(vec![1.0; 57]);
    let e = error_of(&dir, "body_xyz.json", &b);
    assert!(e.contains("joints19") && e.contains("expected 76"), "{e}");
    f["people"][0]["face70"]["landmarks"] = json!(vec![1.0; 208]);
    let e = error_of(&dir, "face_short.json", &f);
    assert!(
        e.contains("face70.landmarks") && e.contains("expected 210"),
        "{e}"
    );

    let mut doc = openpose_doc(&k);
    doc["people"][0]["pose_keypoints_3d"][3] = json!(-0.5);
    let e = error_of(&dir, "negative_c.json", &doc);
    assert!(e.contains("confidence"), "{e}");

    let both = json!({"keypoints": {}, "bodies": []});
    let e = error_of(&dir, "both.json", &both);
    assert!(e.contains("ambiguous"), "{e}");

    // Two files giving the same keypoint.
    let [b, _, _] = panoptic_docs(&k);
    let p1 = write(&dir, "b1.json", &b);
    let p2 = write(&dir, "b2.json", &b);
    let e = keypoints_in::read_keypoints_files(&[&p1, &p2], &ImportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("b2.json") && e.contains("also given by"), "{e}");
}

#[test]
fn nobody_in_the_frame_gives_no_targets() {
    let dir = common::scratch("keypoints_in_empty");
    let p = write(
        &dir,
        "empty_keypoints.json",
        &json!({"version": 1.3, "people": []}),
    );
    let k = keypoints_in::read_keypoints(&p, &ImportOptions::default()).unwrap();
    assert!(k.points.is_empty());
}

/// OpenPose BODY_25's six foot points (19–24) are the layout's foot keypoints, in metres
/// with their confidences as weights; confidence 0 is absent; a bad foot point is an error
/// naming the file; a TC-127 file (no feet) reads as it is.
#[test]
fn openpose_foot_points_are_foot_keypoints() {
    let dir = common::scratch("keypoints_in_feet");
    let mut want = targets();
    for k in 0..N_FEET {
        if k != 4 {
            let t = FEET_OFFSET + k;
            want.points
                .insert(t, [(10.0 + k as f64) / 100.0, -0.2, 0.025 * k as f64]);
            want.weights.insert(t, 0.25 + 0.125 * k as f64);
        }
    }
    let doc = openpose_doc(&want);
    let p = write(&dir, "feet_keypoints.json", &doc);
    let r = keypoints_in::read_keypoints(&p, &ImportOptions::default()).unwrap();
    assert_same(&want, &r, "openpose with feet");
    for k in 0..N_FEET {
        let t = FEET_OFFSET + k;
        if k == 4 {
            assert!(!r.points.contains_key(&t), "confidence 0 is absent");
        } else {
            assert_eq!(r.weight(t), 0.25 + 0.125 * k as f64);
        }
    }
    // A TC-127 file (the feet absent, names as before) reads as it is.
    let tc = dir.join("frame.tc127.json");
    let old = want.clone().without_group(KeypointGroup::Feet);
    old.write(&tc).unwrap();
    let t = keypoints_in::read_keypoints(&tc, &ImportOptions::default()).unwrap();
    assert_same(&old, &t, "tc127");
    // A non-finite heel or a negative confidence: one error naming the file and the point.
    let mut doc = openpose_doc(&want);
    pose_set(&mut doc, 4 * 21, json!(null));
    let e = error_of(&dir, "bad_heel.json", &doc);
    assert!(e.contains("pose_keypoints") && e.contains("[84]"), "{e}");
    let mut doc = openpose_doc(&want);
    pose_set(&mut doc, 4 * 24 + 3, json!(-1.0));
    let e = keypoints_in::read_keypoints(
        &write(&dir, "bad_conf.json", &doc),
        &ImportOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("bad_conf.json") && e.contains("[24]"), "{e}");
}

fn pose_set(doc: &mut Value, i: usize, v: Value) {
    doc["people"][0]["pose_keypoints_3d"]
        .as_array_mut()
        .unwrap()[i] = v;
}

/// OpenPose's 2D arrays (`x y c`, pixels) read as TC-133 2D keypoints with the 3D reader's
/// mapping (BODY_25's body and foot points, face, hands); confidence 0 is absent, eyes and
/// ears have no TC-133 counterpart; a wrong length, a negative confidence or a file of
/// another layout is one error naming the file.
#[test]
fn openpose_2d_keypoints_map_to_tc133() {
    use keypoints_in::{OPENPOSE_BODY25_FEET, parse_openpose_2d};
    let dir = common::scratch("keypoints_in_2d");
    // Pixel of TC-133 keypoint t: (10 t, 1000 − t), confidence 0.5 (0 for the right heel).
    let px = |t: usize| [10.0 * t as f64, 1000.0 - t as f64];
    let conf = |t: usize| if t == FEET_OFFSET + 5 { 0.0 } else { 0.5 };
    let mut pose = vec![0.0; 75];
    for s in 0..25 {
        pose[3 * s..3 * s + 3].copy_from_slice(&[-1.0, -1.0, 0.9]); // eyes, ears: unmapped
    }
    let mut put = |s: usize, t: usize| {
        pose[3 * s..3 * s + 3].copy_from_slice(&[px(t)[0], px(t)[1], conf(t)]);
    };
    for (t, &s) in OPENPOSE_BODY25_TO_TC133.iter().enumerate() {
        put(s, t);
    }
    for (k, &s) in OPENPOSE_BODY25_FEET.iter().enumerate() {
        put(s, FEET_OFFSET + k);
    }
    let part = |o: usize, n: usize| -> Vec<f64> {
        (o..o + n)
            .flat_map(|t| [px(t)[0], px(t)[1], conf(t)])
            .collect()
    };
    let doc = json!({"version": 1.3, "people": [{
        "pose_keypoints_2d": pose,
        "face_keypoints_2d": part(FACE_OFFSET, N_FACE),
        "hand_left_keypoints_2d": part(LHAND_OFFSET, N_HAND),
        "hand_right_keypoints_2d": []
    }]});
    let p = Path::new("cam1_000000000000_keypoints.json");
    let k = parse_openpose_2d(&doc.to_string(), p, 0).unwrap();
    // 15 body + 5 feet + 70 face + 21 left hand.
    assert_eq!(k.len(), N_BODY + N_FEET - 1 + N_FACE + N_HAND);
    for (&t, &(xy, c)) in &k {
        assert_eq!((xy, c), (px(t), 0.5), "keypoint {t}");
    }
    assert!(
        !k.contains_key(&(FEET_OFFSET + 5)),
        "confidence 0 is absent"
    );
    // Nobody there: an empty frame.
    assert!(
        parse_openpose_2d(&doc.to_string(), p, 1)
            .unwrap()
            .is_empty()
    );
    // Errors name the file.
    let mut bad = doc.clone();
    bad["people"][0]["pose_keypoints_2d"] = json!([1.0, 2.0]);
    let e = parse_openpose_2d(&bad.to_string(), p, 0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("cam1_000000000000") && e.contains("75"), "{e}");
    let mut bad = doc.clone();
    bad["people"][0]["face_keypoints_2d"][2] = json!(-0.5);
    let e = parse_openpose_2d(&bad.to_string(), p, 0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cam1_000000000000") && e.contains("confidence"),
        "{e}"
    );
    let tc = write(
        &dir,
        "frame.json",
        &json!({"keypoints": {"neck": [0, 0, 1]}}),
    );
    let e = keypoints_in::read_openpose_2d(&tc, 0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame.json") && e.contains("OpenPose"), "{e}");
}
