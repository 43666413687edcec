//! One frame of 133 keypoints seen by four cameras: exact recovery as TC-133 targets with the
//! views' mean confidence as weight; a keypoint seen once is left out, one whose views
//! disagree is rejected, a corrupted view is dropped; count mismatches are errors.

mod common;

use common::rig;
use panoman_capture::frame::triangulate_frame;
use panoman_capture::triangulate::TriangulateOptions;
use panoman_human::keypoints::{N_KEYPOINTS, keypoint_index};
use panoman_interchange::keypoints_in::Keypoints2d;
use panoman_mesh::geom::{V3, norm, sub};

/// A deterministic "person" of 133 points within a 1 m box around (0, 0, 1).
fn points() -> Vec<V3> {
    (0..N_KEYPOINTS)
        .map(|k| {
            let f = |a: f64| ((k as f64 + 1.0) * a).sin() * 0.5;
            [f(0.7548), f(0.5698), 1.0 + f(0.3313)]
        })
        .collect()
}

fn views(pts: &[V3]) -> Vec<Keypoints2d> {
    rig()
        .iter()
        .enumerate()
        .map(|(i, c)| {
            pts.iter()
                .enumerate()
                .map(|(k, &p)| (k, (c.project(p).unwrap(), 0.4 + 0.1 * i as f64)))
                .collect()
        })
        .collect()
}

#[test]
fn a_frame_triangulates_to_tc133_targets() {
    let cams = rig();
    let pts = points();
    let mut v = views(&pts);
    let heel = keypoint_index("l_heel").unwrap();
    let nose = keypoint_index("nose").unwrap();
    let wrist = keypoint_index("r_wrist").unwrap();
    // The heel seen by camera 0 only; the nose's views moved apart vertically, across the
    // epipolar lines of this ring of cameras at about one height (a shift along them is a
    // consistent pair), so that no two agree; camera 3's right wrist 300 px off.
    for view in v.iter_mut().skip(1) {
        view.remove(&heel);
    }
    for (i, view) in v.iter_mut().enumerate() {
        view.get_mut(&nose).unwrap().0[1] += 200.0 * i as f64;
    }
    v[3].get_mut(&wrist).unwrap().0[1] += 300.0;
    let f = triangulate_frame(&cams, &v, &TriangulateOptions::default()).unwrap();
    assert_eq!(f.keypoints.points.len(), N_KEYPOINTS - 2);
    assert!(!f.keypoints.points.contains_key(&heel));
    assert_eq!(f.rejected, vec![nose]);
    for (&k, p) in &f.keypoints.points {
        assert!(norm(sub(*p, pts[k])) <= 1e-9, "keypoint {k}");
    }
    assert_eq!(f.details[&wrist].views, vec![0, 1, 2]);
    // The weight is the mean confidence of the views used: 0.4, 0.5, 0.6 (and 0.7).
    assert!((f.keypoints.weight(wrist) - 0.5).abs() < 1e-12);
    assert!((f.keypoints.weight(0) - 0.55).abs() < 1e-12);
    f.keypoints.validate().unwrap();
}

#[test]
fn mismatched_inputs_are_errors() {
    let cams = rig();
    let v = views(&points());
    let e = triangulate_frame(&cams, &v[..3], &TriangulateOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("3 detection sets for 4 cameras"),
        "{e}"
    );
    let mut bad = v.clone();
    bad[1].insert(N_KEYPOINTS, ([1.0, 1.0], 1.0));
    let e = triangulate_frame(&cams, &bad, &TriangulateOptions::default()).unwrap_err();
    assert!(e.to_string().contains("133"), "{e}");
    let mut nan = v;
    nan[2].get_mut(&5).unwrap().0[0] = f64::NAN;
    let e = triangulate_frame(&cams, &nan, &TriangulateOptions::default()).unwrap_err();
    assert!(e.to_string().contains("TC-133 keypoint"), "{e}");
}
