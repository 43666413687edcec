//! Interchange with a trained model: a 72-frame clip tracked by `panoman track` exports as one
//! animated .glb that passes the Khronos glTF-Validator; the same targets given as TC-133,
//! OpenPose and CMU Panoptic JSON give the same `panoman fit` (to 1e-9 m), and so do a TC-127
//! file and OpenPose without the feet.

use crate::common;

use common::{clip_keypoints, ok, small_model};
use panoman::{Generator, KeypointsFile, Model};
use panoman_human::keypoints::{
    FACE_OFFSET, FEET_OFFSET, KeypointGroup, LHAND_OFFSET, N_BODY, N_FACE, N_FEET, N_HAND,
    RHAND_OFFSET,
};
use panoman_interchange::keypoints_in::{
    OPENPOSE_BODY25_FEET, OPENPOSE_BODY25_TO_TC133, PANOPTIC_COCO19_TO_TC133,
};
use serde_json::json;
use std::path::Path;

fn read_obj(p: &Path) -> Vec<[f64; 3]> {
    panoman_mesh::io::read_mesh(p).unwrap().positions
}

/// Validates with `tools/node/validate.mjs` (0 errors and 0 warnings), when node is available
/// (required with PANOMAN_NODE_TESTS=1, as in CI).
fn validate(glb: &Path) {
    let required = std::env::var("PANOMAN_NODE_TESTS").is_ok_and(|v| v == "1");
    let tools = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/node");
    let ready = tools.join("node_modules/gltf-validator").exists();
    if !ready {
        assert!(
            !required,
            "PANOMAN_NODE_TESTS=1 but tools/node is not installed (npm ci)"
        );
        eprintln!("SKIPPED: glTF validation (npm ci --prefix tools/node to enable)");
        return;
    }
    let out = std::process::Command::new("node")
        .arg(tools.join("validate.mjs"))
        .arg(glb)
        .output()
        .expect("node");
    let line = String::from_utf8_lossy(&out.stdout);
    let report: serde_json::Value = serde_json::from_str(line.trim()).expect("validator JSON");
    assert_eq!(report["errors"], 0, "{line}");
    assert_eq!(report["warnings"], 0, "{line}");
    assert!(out.status.success(), "{line}");
}

#[test]
fn tracked_clip_exports_to_a_valid_glb() {
    let (dir, _data, model_path) = small_model("interchange-fit-clip", 7);
    let model = Model::load(&model_path).unwrap();
    let g = Generator::from_model(&model).unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let n = 72;
    for f in 0..n {
        let kp = KeypointsFile::from_all(&clip_keypoints(&model, &g, f, n));
        kp.write(&frames.join(format!("frame_{f:03}.json")))
            .unwrap();
    }
    let track = dir.join("track");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    ok(common::panoman(&[
        "track",
        "--model",
        &s(&model_path),
        "--frames",
        &s(&frames),
        "--out",
        &s(&track),
    ]));
    let glb = dir.join("clip.glb");
    let out = ok(common::panoman(&[
        "export",
        "--sequence",
        &s(&track),
        "--fps",
        "30",
        "--out",
        &s(&glb),
    ]));
    assert!(out.contains("72 frame"), "{out}");
    validate(&glb);
}

/// Coordinates on a 1/1024 m grid, so that their centimetre values (what OpenPose and
/// Panoptic files hold) are exact binary numbers and the unit conversion is exact.
fn snapped(points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    points
        .iter()
        .map(|p| p.map(|c| (c * 1024.0).round() / 1024.0))
        .collect()
}

fn xyzc_cm(points: &[[f64; 3]], idx: impl Iterator<Item = usize>) -> Vec<f64> {
    idx.flat_map(|t| {
        let p = points[t];
        [p[0] * 100.0, p[1] * 100.0, p[2] * 100.0, 1.0]
    })
    .collect()
}

/// OpenPose BODY_25 (cm) of TC-133 keypoints `k`, the foot points with confidence `feet`.
fn openpose_doc(k: &[[f64; 3]], feet: f64) -> serde_json::Value {
    let mut pose = vec![0.0; 100];
    for (t, &src) in OPENPOSE_BODY25_TO_TC133.iter().enumerate() {
        pose[4 * src..4 * src + 4].copy_from_slice(&xyzc_cm(k, t..t + 1));
    }
    for (i, &src) in OPENPOSE_BODY25_FEET.iter().enumerate() {
        let t = FEET_OFFSET + i;
        pose[4 * src..4 * src + 4].copy_from_slice(&xyzc_cm(k, t..t + 1));
        pose[4 * src + 3] = feet;
    }
    json!({"version": 1.3, "people": [{
        "pose_keypoints_3d": pose,
        "face_keypoints_3d": xyzc_cm(k, FACE_OFFSET..FACE_OFFSET + N_FACE),
        "hand_left_keypoints_3d": xyzc_cm(k, LHAND_OFFSET..LHAND_OFFSET + N_HAND),
        "hand_right_keypoints_3d": xyzc_cm(k, RHAND_OFFSET..RHAND_OFFSET + N_HAND),
    }]})
}

#[test]
fn tc133_tc127_openpose_and_panoptic_targets_give_the_same_fit() {
    let (dir, _data, model_path) = small_model("interchange-fit-formats", 8);
    let model = Model::load(&model_path).unwrap();
    let g = Generator::from_model(&model).unwrap();
    let k = snapped(&clip_keypoints(&model, &g, 30, 72));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let write = |name: &str, v: &serde_json::Value| {
        let p = dir.join(name);
        std::fs::write(&p, v.to_string()).unwrap();
        p
    };
    // TC-133: all 133, and the body alone.
    let all = dir.join("tc133.json");
    KeypointsFile::from_all(&k).write(&all).unwrap();
    let mut body = KeypointsFile::default();
    for (t, p) in k.iter().enumerate().take(N_BODY) {
        body.points.insert(t, *p);
    }
    let body_path = dir.join("tc133_body.json");
    body.write(&body_path).unwrap();
    // An old TC-127 file: every keypoint but the feet, as files of that layout were written.
    let old = KeypointsFile::from_all(&k).without_group(KeypointGroup::Feet);
    let old_text = old.to_json().unwrap();
    assert!(!old_text.contains("heel") && old_text.contains("r_ankle"));
    let old_path = dir.join("tc127.json");
    std::fs::write(&old_path, old_text).unwrap();
    // OpenPose BODY_25 + face + hands (cm), with and without the foot points; the 4 BODY_25
    // points without a TC-133 counterpart (eyes, ears) get confidence 0.
    let openpose = write("openpose.json", &openpose_doc(&k, 1.0));
    let openpose_no_feet = write("openpose_no_feet.json", &openpose_doc(&k, 0.0));
    // Panoptic hdPose3d_stage1_coco19 (cm): the body (a fit reads one file per frame).
    let mut j19 = vec![0.0; 19 * 4];
    for (t, &src) in PANOPTIC_COCO19_TO_TC133.iter().enumerate() {
        j19[4 * src..4 * src + 4].copy_from_slice(&xyzc_cm(&k, t..t + 1));
    }
    let panoptic = write(
        "panoptic_body.json",
        &json!({"version": 0.7, "univTime": 1.0, "fpsType": "hd_29_97",
                "bodies": [{"id": 0, "joints19": j19}]}),
    );
    let fit = |kp: &Path, format: &str, out: &str| {
        ok(common::panoman(&[
            "fit",
            "--model",
            &s(&model_path),
            "--keypoints",
            &s(kp),
            "--keypoints-format",
            format,
            "--out",
            &s(&dir.join(out)),
        ]));
        read_obj(&dir.join(out).join("mesh.obj"))
    };
    let max_diff = |a: &[[f64; 3]], b: &[[f64; 3]]| {
        a.iter()
            .zip(b)
            .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs()))
            .fold(0.0f64, f64::max)
    };
    let tc = fit(&all, "panoman", "fit_tc133");
    let op = fit(&openpose, "openpose", "fit_openpose");
    assert!(
        max_diff(&tc, &op) <= 1e-9,
        "OpenPose fit differs by {}",
        max_diff(&tc, &op)
    );
    // TC-127 files still fit, as OpenPose files without the feet do.
    let old = fit(&old_path, "tc127", "fit_tc127");
    let op_old = fit(&openpose_no_feet, "openpose", "fit_openpose_no_feet");
    assert!(
        max_diff(&old, &op_old) <= 1e-9,
        "OpenPose without feet differs from TC-127 by {}",
        max_diff(&old, &op_old)
    );
    // The foot keypoints are targets: the TC-127 fit is another fit.
    assert!(max_diff(&tc, &old) > 1e-6);
    let tcb = fit(&body_path, "panoman", "fit_tc133_body");
    let pb = fit(&panoptic, "panoptic", "fit_panoptic_body");
    assert!(
        max_diff(&tcb, &pb) <= 1e-9,
        "Panoptic fit differs by {}",
        max_diff(&tcb, &pb)
    );
    // The fits are not trivially equal: the body-only fit is another fit.
    assert!(max_diff(&tc, &tcb) > 1e-6);
    // A fit's parameters export as the posed model (`export --params --model`).
    let glb = dir.join("fit.glb");
    ok(common::panoman(&[
        "export",
        "--params",
        &s(&dir.join("fit_tc133/params.json")),
        "--model",
        &s(&model_path),
        "--out",
        &s(&glb),
    ]));
    validate(&glb);
}

/// OpenPose BODY_25's foot points are keypoint targets: a person with both feet flexed (30°
/// and 25° toes down, which TC-127 cannot see) fitted by `panoman fit --baseline lbs` (the
/// IK alone) from the same OpenPose keypoints with the six foot points given and at
/// confidence 0: with them the feet land.
#[test]
fn openpose_foot_points_place_the_feet() {
    let (dir, _data, model_path) = small_model("interchange-fit-feet", 9);
    let model = Model::load(&model_path).unwrap();
    let g = Generator::from_model(&model).unwrap();
    let params = g
        .parse_params(
            r#"{"pose_euler_xyz_deg": {"foot.L": [30, 0, 0], "foot.R": [25, 0, 0],
                "upperarm01.R": [0, 0, 40]}}"#,
        )
        .unwrap();
    let truth = g
        .generate(&params, model.output_topology().unwrap())
        .unwrap();
    let k = model.keypoints(&truth).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let fit = |c: f64, name: &str| {
        let kp = dir.join(format!("{name}.json"));
        std::fs::write(&kp, openpose_doc(&k, c).to_string()).unwrap();
        let out = dir.join(name);
        ok(common::panoman(&[
            "fit",
            "--model",
            &s(&model_path),
            "--keypoints",
            &s(&kp),
            "--baseline",
            "lbs",
            "--out",
            &s(&out),
        ]));
        let report = std::fs::read_to_string(out.join("report.json")).unwrap();
        (read_obj(&out.join("mesh.obj")), report)
    };
    // Mean distance of the fit's foot keypoints to the truth's, metres.
    let foot_err = |m: &[[f64; 3]]| {
        let f = model.keypoints(m).unwrap();
        (FEET_OFFSET..FEET_OFFSET + N_FEET)
            .map(|t| {
                let (a, b) = (f[t], k[t]);
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
            })
            .sum::<f64>()
            / N_FEET as f64
    };
    let (without, r0) = fit(0.0, "no_feet");
    let (with, r1) = fit(1.0, "feet");
    let (e0, e1) = (foot_err(&without), foot_err(&with));
    eprintln!(
        "foot keypoints {:.1} mm without, {:.1} mm with",
        1e3 * e0,
        1e3 * e1
    );
    assert!(!r0.contains("\"feet\"") && r1.contains("\"feet\""), "{r1}");
    assert!(e0 > 0.02, "TC-127 alone placed the flexed feet: {e0} m");
    assert!(e1 < 0.005 && e1 * 5.0 < e0, "{e0} → {e1} m");
}
