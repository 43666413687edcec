//! Triangulation: exact recovery, noise within the derived bound, outlier and left/right
//! swap rejection, too few agreeing views, points behind a camera, input errors.

mod common;

use common::{Normal, cloud, rig};
use panoman_capture::triangulate::{
    Observation, TriangulateOptions, triangulate, triangulate_many,
};
use panoman_mesh::geom::{V3, norm, sub};

fn observe(p: V3) -> Vec<Observation> {
    rig()
        .iter()
        .enumerate()
        .map(|(i, c)| Observation {
            camera: i,
            pixel: c.project(p).unwrap(),
            confidence: 0.5 + 0.1 * i as f64,
        })
        .collect()
}

#[test]
fn exact_views_recover_the_point_to_1e9_m() {
    let cams = rig();
    let opts = TriangulateOptions::default();
    let kps: Vec<Vec<Observation>> = cloud().into_iter().map(observe).collect();
    let out = triangulate_many(&cams, &kps, &opts).unwrap();
    for (p, t) in cloud().into_iter().zip(out) {
        let t = t.expect("triangulated");
        assert!(norm(sub(t.position, p)) <= 1e-9, "{p:?} → {:?}", t.position);
        assert_eq!(t.views, [0, 1, 2, 3]);
        assert!(t.reprojection_px < 1e-6);
        assert!((t.confidence - 0.65).abs() < 1e-12);
    }
    // Without refinement the DLT alone is exact on exact data too.
    let plain = TriangulateOptions {
        refine_iterations: 0,
        ..opts
    };
    let t = triangulate(&cams, &observe([0.1, 0.2, 1.3]), &plain)
        .unwrap()
        .unwrap();
    assert!(norm(sub(t.position, [0.1, 0.2, 1.3])) <= 1e-9);
}

/// σ = 0.5 px on every coordinate. A camera at depth z with focal f sees a lateral error
/// σ·z/f ≈ 0.5·3.5/1100 ≈ 1.6 mm; four views at ~90° constrain each horizontal axis by two
/// views and the vertical by four, so the 3-D RMS is ≈ 1.6·√(1/2 + 1/2 + 1/4) ≈ 1.8 mm.
/// The test allows twice that over 270 points (the sample RMS is within a few % of its
/// expectation at that count) and the worst point 5 × 1.8 mm.
#[test]
fn noise_of_half_a_pixel_stays_within_the_derived_bound() {
    let cams = rig();
    let mut g = Normal::new(7);
    let mut sum2 = 0.0;
    let mut worst = 0.0f64;
    let mut n = 0;
    for rep in 0..10 {
        for p in cloud() {
            let p = [p[0] + 0.01 * rep as f64, p[1], p[2]];
            let mut obs = observe(p);
            for o in &mut obs {
                o.pixel[0] += 0.5 * g.sample();
                o.pixel[1] += 0.5 * g.sample();
            }
            let t = triangulate(&cams, &obs, &TriangulateOptions::default())
                .unwrap()
                .unwrap();
            assert_eq!(t.views.len(), 4);
            let e = norm(sub(t.position, p));
            sum2 += e * e;
            worst = worst.max(e);
            n += 1;
        }
    }
    let rms = (sum2 / n as f64).sqrt();
    eprintln!(
        "σ = 0.5 px: rms {:.3} mm, worst {:.3} mm over {n} points",
        rms * 1e3,
        worst * 1e3
    );
    assert!(rms < 2.0 * 1.8e-3, "rms {rms} m");
    assert!(rms > 0.2e-3, "noise had no effect? rms {rms} m");
    assert!(worst < 5.0 * 1.8e-3, "worst {worst} m");
}

#[test]
fn a_300_px_outlier_view_is_rejected() {
    let cams = rig();
    for (k, p) in cloud().into_iter().enumerate() {
        let bad = k % 4;
        let mut obs = observe(p);
        obs[bad].pixel[0] += 300.0;
        let t = triangulate(&cams, &obs, &TriangulateOptions::default())
            .unwrap()
            .unwrap();
        assert!(!t.views.contains(&bad), "view {bad} kept: {:?}", t.views);
        assert_eq!(t.views.len(), 3);
        assert!(norm(sub(t.position, p)) <= 1e-3);
    }
}

#[test]
fn a_left_right_swap_in_one_view_is_rejected() {
    // Left and right wrists 0.4 m apart; camera 2 reports them swapped.
    let cams = rig();
    let left = [0.2, 0.1, 1.1];
    let right = [-0.2, 0.1, 1.1];
    let mut obs_l = observe(left);
    let mut obs_r = observe(right);
    std::mem::swap(&mut obs_l[2].pixel, &mut obs_r[2].pixel);
    let out = triangulate_many(&cams, &[obs_l, obs_r], &TriangulateOptions::default()).unwrap();
    for (t, want) in out.into_iter().zip([left, right]) {
        let t = t.unwrap();
        assert_eq!(t.views, [0, 1, 3]);
        assert!(norm(sub(t.position, want)) <= 1e-3);
    }
}

#[test]
fn fewer_than_two_agreeing_views_give_none() {
    let cams = rig();
    let p = [0.0, 0.0, 1.0];
    let opts = TriangulateOptions::default();
    // One view.
    assert!(
        triangulate(&cams, &observe(p)[..1], &opts)
            .unwrap()
            .is_none()
    );
    // Two views that disagree by 300 px.
    let mut two = observe(p)[..2].to_vec();
    two[1].pixel[1] += 300.0;
    assert!(triangulate(&cams, &two, &opts).unwrap().is_none());
    // Zero confidence means "not seen".
    let mut obs = observe(p);
    for o in &mut obs[1..] {
        o.confidence = 0.0;
    }
    assert!(triangulate(&cams, &obs, &opts).unwrap().is_none());
    // Three views, each shifted vertically (across the near-horizontal epipolar lines of
    // this rig) by a different 200 px: no pair agrees. (Shifts *along* an epipolar line
    // cannot be detected by two views.)
    let mut obs = observe(p)[..3].to_vec();
    obs[1].pixel[1] += 200.0;
    obs[2].pixel[1] -= 200.0;
    assert!(triangulate(&cams, &obs, &opts).unwrap().is_none());
    // min_views = 3 with only two good views.
    let mut obs = observe(p);
    obs[0].pixel[0] += 300.0;
    obs[1].pixel[1] += 300.0;
    let three = TriangulateOptions {
        min_views: 3,
        ..opts
    };
    assert!(triangulate(&cams, &obs, &three).unwrap().is_none());
    assert!(triangulate(&cams, &obs, &opts).unwrap().is_some());
}

#[test]
fn a_point_behind_a_camera_is_rejected() {
    // Camera 0 and its mirror image through the world origin face each other; camera 1 "sees"
    // the point behind itself through the reflected pixel (projectively consistent).
    let cams = rig();
    let c1 = &cams[1];
    let behind: V3 = {
        let c = c1.centre();
        let a = c1.r[2];
        [c[0] - 0.8 * a[0], c[1] - 0.8 * a[1], c[2] - 0.8 * a[2]]
    };
    assert!(c1.project(behind).is_none());
    // Pixel of the reflection of `behind` through camera 1's centre: same ray line, other side.
    let c = c1.centre();
    let mirrored = [
        2.0 * c[0] - behind[0],
        2.0 * c[1] - behind[1],
        2.0 * c[2] - behind[2],
    ];
    let obs = vec![
        Observation {
            camera: 0,
            pixel: cams[0].project(behind).unwrap(),
            confidence: 1.0,
        },
        Observation {
            camera: 1,
            pixel: c1.project(mirrored).unwrap(),
            confidence: 1.0,
        },
    ];
    assert!(
        triangulate(&cams, &obs, &TriangulateOptions::default())
            .unwrap()
            .is_none()
    );
}

#[test]
fn invalid_input_is_an_error_not_a_panic() {
    let cams = rig();
    let opts = TriangulateOptions::default();
    let mut obs = observe([0.0, 0.0, 1.0]);
    obs[0].camera = 9;
    assert!(
        triangulate(&cams, &obs, &opts)
            .unwrap_err()
            .to_string()
            .contains("camera 9")
    );
    let mut obs = observe([0.0, 0.0, 1.0]);
    obs[1].camera = 0;
    assert!(
        triangulate(&cams, &obs, &opts)
            .unwrap_err()
            .to_string()
            .contains("twice")
    );
    let mut obs = observe([0.0, 0.0, 1.0]);
    obs[2].pixel[0] = f64::NAN;
    assert!(triangulate(&cams, &obs, &opts).is_err());
    let mut obs = observe([0.0, 0.0, 1.0]);
    obs[2].confidence = -1.0;
    assert!(triangulate(&cams, &obs, &opts).is_err());
    let e = triangulate_many(&cams, &[observe([0.0, 0.0, 1.0]), obs], &opts).unwrap_err();
    assert!(e.to_string().starts_with("keypoint 1: "), "{e}");
    let zero = TriangulateOptions {
        threshold_px: 0.0,
        ..opts
    };
    assert!(triangulate(&cams, &observe([0.0, 0.0, 1.0]), &zero).is_err());
}
