//! The capture path with a model (the cached small model of the examples,
//! `panoman::training::small_model`): a synthetic four-camera scene of a generated person seen
//! through exact 2D keypoints, and the committed excerpt of real detections (Pose2Sim's
//! Demo_SinglePerson, `fixtures/pose2sim-excerpt`).

use std::path::PathBuf;

use panoman::{Generator, Method, Model};
use panoman_capture::camera::look_at;
use panoman_capture::capture::{CaptureConfig, Mask, track, view_errors};
use panoman_capture::sequence::{
    Detections, common_frames, estimate_offsets, read_detections_dir, triangulate_sequence,
};
use panoman_capture::triangulate::TriangulateOptions;
use panoman_capture::{Camera, read_calibration};
use panoman_interchange::keypoints_in::Keypoints2d;
use panoman_mesh::geom::{V3, matvec, norm, sub};

/// The small model, built once per test process (its first build is not safe to run twice
/// at once in one process).
fn model() -> Model {
    static PATH: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    let p = PATH.get_or_init(|| panoman::training::small_model(None).expect("small model"));
    Model::load(p).expect("load")
}

fn excerpt() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/pose2sim-excerpt")
}

/// Four cameras 3.5 m around the origin at 0.5 m height, looking at the origin (z up: the
/// generator's frame, the body centred on the origin).
fn cameras() -> Vec<Camera> {
    (0..4)
        .map(|i| {
            let a = 0.3 + i as f64 * std::f64::consts::FRAC_PI_2;
            let c = [3.5 * a.cos(), 3.5 * a.sin(), 0.5];
            let r = look_at(c, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
            let t = matvec(&r, c);
            Camera::pinhole(
                format!("cam{i}"),
                1400.0,
                1400.0,
                540.0,
                960.0,
                r,
                [-t[0], -t[1], -t[2]],
                Some([1080, 1920]),
            )
        })
        .collect()
}

#[test]
fn a_generated_person_is_recovered_from_exact_2d_keypoints_in_four_views() {
    let model = model();
    let g = Generator::from_model(&model).unwrap();
    let cams = cameras();
    let n = 4;
    let mut truth = Vec::new();
    let mut det = Detections {
        views: vec![Vec::new(); cams.len()],
        ..Default::default()
    };
    for f in 0..n {
        let u = f as f64 / (n - 1) as f64;
        let params = g
            .parse_params(&format!(
                r#"{{"pose_euler_xyz_deg": {{"upperarm01.R": [0, 0, {:.3}], "lowerarm01.R": [{:.3}, 0, 0],
                     "upperleg01.L": [{:.3}, 0, 0], "lowerleg01.L": [{:.3}, 0, 0]}}}}"#,
                50.0 * u,
                40.0 * u,
                -30.0 * u,
                35.0 * u
            ))
            .unwrap();
        let mesh: Vec<V3> = g
            .generate(&params, model.output_topology().unwrap())
            .unwrap();
        let kp = model.keypoints(&mesh).unwrap();
        for (c, cam) in cams.iter().enumerate() {
            let mut v = Keypoints2d::new();
            for (k, &p) in kp.iter().enumerate() {
                v.insert(k, (cam.project(p).expect("in front"), 1.0));
            }
            det.views[c].push(v);
        }
        truth.push(mesh);
    }
    let est = estimate_offsets(&cams, &det, 2).unwrap();
    assert!(est.iter().all(|e| e.offset == 0), "{est:?}");
    let offsets = vec![0; cams.len()];
    let tri =
        triangulate_sequence(&cams, &det, &offsets, &[], &TriangulateOptions::default()).unwrap();
    assert_eq!(tri.len(), n);
    // Exact views: every keypoint triangulates to the truth (to the solver's precision).
    let kp0 = model.keypoints(&truth[0]).unwrap();
    for (k, p) in &tri[0].keypoints.points {
        assert!(norm(sub(*p, kp0[*k])) < 1e-6, "keypoint {k}");
    }
    let cfg = CaptureConfig {
        calibrate_shape: 2,
        keypoint_sigma: 0.0,
        ..Default::default()
    };
    let tracked = track(&model, &tri, Method::PanoMan, &cfg, &|_| {}).unwrap();
    for (f, (v, t)) in tracked.vertices.iter().zip(&truth).enumerate() {
        let mean = v.iter().zip(t).map(|(a, b)| norm(sub(*a, *b))).sum::<f64>() / v.len() as f64;
        eprintln!("frame {f}: mean vertex error {:.2} mm", 1e3 * mean);
        assert!(
            mean < 5e-3,
            "frame {f}: mean vertex error {:.2} mm",
            1e3 * mean
        );
    }
    // The fitted mesh's silhouette covers the truth's (IoU of the two rasterized meshes).
    let grid = Mask {
        width: 270,
        height: 480,
        scale: 0.25,
        data: vec![false; 270 * 480],
    };
    let s_fit = grid.silhouette(&cams[1], &tracked.vertices[2], model.faces());
    let s_true = grid.silhouette(&cams[1], &truth[2], model.faces());
    assert!(s_fit.iou(&s_true) > 0.9, "IoU {}", s_fit.iou(&s_true));
}

#[test]
fn the_real_excerpt_synchronizes_triangulates_and_scores_a_held_out_view() {
    let dir = excerpt();
    let cams = read_calibration(&dir.join("Calib.qca.txt")).unwrap();
    assert_eq!(cams.len(), 4);
    let det = read_detections_dir(&dir.join("detections"), &cams, 0).unwrap();
    assert_eq!(det.frames(0), 12);
    let est = estimate_offsets(&cams, &det, 3).unwrap();
    let offsets: Vec<i64> = est.iter().map(|e| e.offset).collect();
    for e in &est[1..] {
        // The chosen offset is the minimum over the searched ones, 0 included.
        assert!(e.median_px <= e.median_px_at_zero, "{e:?}");
        assert!(e.offset.abs() <= 3);
    }
    let range = common_frames(&det, &offsets);
    assert!(!range.is_empty());
    let held = 1;
    let opts = TriangulateOptions {
        threshold_px: 40.0,
        ..Default::default()
    };
    let tri = triangulate_sequence(&cams, &det, &offsets, &[held], &opts).unwrap();
    for f in &tri {
        for t in f.details.values() {
            assert!(!t.views.contains(&held));
            assert!(t.reprojection_px <= opts.threshold_px);
        }
    }
    let model = model();
    let cfg = CaptureConfig {
        calibrate_shape: 2,
        midpoints: panoman_capture::capture::MEDIAPIPE_MIDPOINTS.to_vec(),
        ..Default::default()
    };
    let tracked = track(&model, &tri, Method::PanoMan, &cfg, &|_| {}).unwrap();
    assert_eq!(tracked.vertices.len(), tri.len());
    // The targets recorded are the frames the fit followed.
    assert_eq!(tracked.targets.len(), tri.len());
    for (t, f) in tracked.targets.iter().zip(&tri) {
        assert_eq!(t, &f.keypoints);
    }
    // MediaPipe's neck is its shoulders' midpoint: so is the tracked one.
    for k in &tracked.keypoints {
        let mid = [0, 1, 2].map(|j| 0.5 * (k[3][j] + k[9][j]));
        assert!(norm(sub(k[0], mid)) < 1e-12);
    }
    let det_h: Vec<_> = range
        .clone()
        .map(|t| det.views[held][(t as i64 + offsets[held]) as usize].clone())
        .collect();
    let pred = |f: usize, k: usize| tracked.keypoints.get(f)?.get(k).copied();
    let e = view_errors(&cams[held], &det_h, &tri, &pred, 0.5);
    assert!(e.scored > 0 && e.body_px.is_finite(), "{e:?}");
    // The masks read and the mesh overlaps the person in the held-out view.
    let cam = &cams[held];
    let f0 = (range.start as i64 + offsets[held]) as usize;
    let mask = Mask::read_png(&det.mask_path(held, f0).expect("a mask"), 0.25).unwrap();
    assert_eq!((mask.width, mask.height), (270, 480));
    let iou = mask
        .silhouette(cam, &tracked.vertices[0], model.faces())
        .iou(&mask);
    assert!(iou > 0.0 && iou <= 1.0, "IoU {iou}");
}
