//! Property tests of the whole fit (issue 17, numeric edge cases): the skeletal IK (the LBS
//! baseline) and the PanoMan fit driven with degenerate or adversarial targets on the small
//! example model. Each case either returns an error or a finite result whose keypoint
//! residuals are finite; never a panic (proptest reports one as a failure) and never an
//! unbounded loop (every solver stage has an iteration cap; the suite finishing is the check).
//!
//! Case counts (per method, PanoMan and LBS): 6 for each of keypoints at one point,
//! collinear, a person up to 1 km away, scaled by 1e−9…1e6, one to five keypoints and a
//! non-finite coordinate; 4 each for duplicated handles and point clouds of 0–3 points — 44
//! cases, 88 fits (a degenerate fit runs its stages to their caps, ≈ 1–2 s each here).
use std::sync::{Mutex, OnceLock};

use panoman::targets::PointCloud;
use panoman::{
    FitOutput, FitRequest, Fitter, KeypointsFile, Method, Model, Targets, V3, VertexHandle,
};
use proptest::prelude::*;

struct Fixture {
    model: Model,
    fitter: Mutex<Fitter>,
    /// The keypoints of the mean person (133, metres).
    mean_kp: Vec<V3>,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let path = panoman::training::small_model(None).expect("small model");
        let model = Model::load(&path).expect("load");
        let fitter = Mutex::new(Fitter::new(&model).expect("fitter"));
        let mean_kp = model.keypoints(&model.rest_shape(&[])).expect("keypoints");
        Fixture {
            model,
            fitter,
            mean_kp,
        }
    })
}

/// Runs both methods on `t` and checks the contract; `must_fail` for inputs that are invalid.
fn check(t: &Targets, must_fail: bool) -> Result<(), TestCaseError> {
    let f = fixture();
    for method in [Method::PanoMan, Method::Lbs] {
        let req = FitRequest {
            method,
            ..Default::default()
        };
        let out = f.fitter.lock().unwrap().fit(t, &req);
        match out {
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(
                    !msg.is_empty() && !msg.contains('\n'),
                    "one-line error: {msg:?}"
                );
            }
            Ok(o) => {
                prop_assert!(!must_fail, "{method:?}: invalid targets were accepted");
                finite(&o, f.model.n_vertices())?;
            }
        }
    }
    Ok(())
}

fn finite(o: &FitOutput, nv: usize) -> Result<(), TestCaseError> {
    prop_assert_eq!(o.vertices.len(), nv);
    prop_assert!(
        o.vertices.iter().flatten().all(|c| c.is_finite()),
        "non-finite vertex"
    );
    for (g, r) in &o.report.keypoint_residuals {
        prop_assert!(
            r.mean_mm.is_finite() && r.max_mm.is_finite(),
            "group {g}: {r:?}"
        );
    }
    Ok(())
}

fn kp(points: impl IntoIterator<Item = (usize, V3)>) -> Targets {
    let mut k = KeypointsFile::default();
    for (i, p) in points {
        k.points.insert(i, p);
        k.weights.insert(i, 1.0);
    }
    Targets {
        keypoints: k,
        ..Default::default()
    }
}

fn point() -> impl Strategy<Value = V3> {
    [-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(6))]

    #[test]
    fn all_keypoints_at_one_point(p in point()) {
        check(&kp((0..133).map(|i| (i, p))), false)?;
    }

    #[test]
    fn collinear_keypoints(p in point(), d in point()) {
        check(&kp((0..133).map(|i| {
            let t = i as f64 / 126.0;
            (i, [p[0] + t * d[0], p[1] + t * d[1], p[2] + t * d[2]])
        })), false)?;
    }

    #[test]
    fn a_person_up_to_a_kilometre_away(dir in point(), dist in 1.0..1000.0f64) {
        let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt().max(1e-9);
        let off = dir.map(|c| c / n * dist);
        let f = fixture();
        check(&kp(f.mean_kp.iter().enumerate().map(|(i, q)| {
            (i, [q[0] + off[0], q[1] + off[1], q[2] + off[2]])
        })), false)?;
    }

    #[test]
    fn a_person_scaled_from_1e_minus_9_to_1e6(e in -9.0..6.0f64) {
        let s = 10f64.powf(e);
        let f = fixture();
        check(&kp(f.mean_kp.iter().enumerate().map(|(i, q)| (i, q.map(|c| c * s)))), false)?;
    }

    #[test]
    fn one_to_five_keypoints(ids in proptest::collection::btree_set(0usize..133, 1..=5)) {
        let f = fixture();
        check(&kp(ids.into_iter().map(|i| (i, f.mean_kp[i]))), false)?;
    }

    #[test]
    fn a_non_finite_coordinate(i in 0usize..133, c in 0usize..3, which in 0usize..3) {
        let f = fixture();
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][which];
        let mut pts = f.mean_kp.clone();
        pts[i][c] = bad;
        check(&kp(pts.into_iter().enumerate()), true)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4))]

    #[test]
    fn duplicated_handles(v in 0u32..1229, p in point(), copies in 2usize..6) {
        let f = fixture();
        let mut t = kp(f.mean_kp.iter().copied().enumerate());
        t.handles = (0..copies).map(|_| VertexHandle { vertex: v, position: p, weight: 1.0 }).collect();
        check(&t, false)?;
    }

    #[test]
    fn point_clouds_of_zero_to_three_points(n in 0usize..4, p in point()) {
        let f = fixture();
        let mut t = kp(f.mean_kp.iter().copied().enumerate());
        t.points = Some(PointCloud { positions: vec![p; n], normals: None });
        // Fewer than 3 points is an error; 3 identical points may be rejected or fitted.
        check(&t, n < 3)?;
    }
}
