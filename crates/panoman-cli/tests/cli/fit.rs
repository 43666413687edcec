//! Acceptance tests of the fitting stage on the small preset (CI configuration): a held-out
//! person fitted from exact TC-127 keypoints (PanoMan and the LBS baseline), keypoints + a
//! partial noisy point cloud (ICP), contradictory constraints, sequences, and bad input through
//! the binary.

use panoman_fit::fit::{FitOptions, keypoint_residuals};
use panoman_fit::{Constraints, FitError, FrameSolver, Init, LbsRig, PointCloud, Tracking};
use panoman_human::keypoints::{KeypointGroup, KeypointsFile, keypoint_index};
use panoman_mesh::geom::{V3, norm, sub};
use panoman_model::model::PanoManModel;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::common;
use common::{ok, one_line_error, panoman, small_model};

/// A small dataset and a model trained on it (shared by the tests of this file).
fn trained() -> &'static (common::TempDir, PathBuf, PathBuf) {
    static CELL: OnceLock<(common::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    CELL.get_or_init(|| small_model("fit-test", 5))
}

/// The model and its frame solver (the LBS rig read from the assets).
fn model_and_solver(model_path: &Path) -> (PanoManModel, FrameSolver) {
    let model = PanoManModel::load(model_path).unwrap();
    let assets = panoman_human::assets::ensure_default().unwrap();
    let rig = LbsRig::load(&assets, &model).unwrap();
    let solver = FrameSolver::new(std::sync::Arc::new(model.clone()), rig).unwrap();
    (model, solver)
}

/// Held-out body-pose rows: (posed, rest) vertices.
fn held_out(data: &Path, n: usize) -> Vec<(Vec<V3>, Vec<V3>)> {
    let ds = panoman_human::dataset::Dataset::open(data).unwrap();
    let rows: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == 1 && ds.held_out.contains(&ds.identity[r]))
        .take(n)
        .collect();
    assert!(!rows.is_empty());
    let v = |row: usize| -> Vec<V3> {
        ds.vertices(row)
            .unwrap()
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect()
    };
    rows.iter()
        .map(|&r| (v(r), v(ds.rest_of[r] as usize)))
        .collect()
}

/// One cold fit with the default IK and fit options.
fn cold_fit(
    solver: &mut FrameSolver,
    c: &Constraints,
) -> panoman_fit::Result<(panoman_fit::ik::IkResult, panoman_fit::FitResult)> {
    solver.fit(c, &Default::default(), &FitOptions::default(), None)
}

fn mean_error(a: &[V3], b: &[V3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| norm(sub(*p, *q))).sum::<f64>() / a.len() as f64
}

#[test]
fn held_out_people_from_exact_keypoints() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let cases = held_out(data, 3);
    let (mut e_pm, mut e_lbs) = (0.0, 0.0);
    for (truth, _) in &cases {
        let kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
        let c = Constraints::from_keypoints(kp.clone());
        let (ikr, fit) = cold_fit(&mut solver, &c).unwrap();
        let (ep, el) = (
            mean_error(&fit.vertices, truth),
            mean_error(&ikr.posed, truth),
        );
        let res = keypoint_residuals(&model, &kp, &fit.vertices);
        println!(
            "panoman {:.2} mm, lbs {:.2} mm, keypoint residuals {:?}",
            ep * 1e3,
            el * 1e3,
            res.iter()
                .map(|(k, g)| format!("{k} {:.2}", g.mean_mm))
                .collect::<Vec<_>>()
        );
        e_pm += ep / cases.len() as f64;
        e_lbs += el / cases.len() as f64;
        // Exact keypoints are met closely: the keypoint terms dominate the shell's pull.
        assert!(res[&KeypointGroup::Body].mean_mm < 10.0, "{res:?}");
        // The report covers the stages that ran.
        let names: Vec<&str> = fit.report.stages.iter().map(|s| s.name.as_str()).collect();
        assert!(names.contains(&"keypoints"), "{names:?}");
    }
    println!(
        "mean per-vertex error: panoman {:.2} mm, lbs {:.2} mm",
        e_pm * 1e3,
        e_lbs * 1e3
    );
    // The issue's 10 mm bound on the full template, scaled for the small topology, whose
    // keypoint regressors alone are off by ~4 mm (body) and whose 1,229 vertices carry a far
    // coarser model (25 body components): 25 mm.
    assert!(e_pm < 0.025, "panoman mean error {:.2} mm", e_pm * 1e3);
}

/// The cold keypoint stage's first step ([`FitOptions::one_step_tolerance`]): with a loose
/// tolerance the stage stops after one LM step; with a tight one, or none, it takes its
/// factored steps; the default stops exactly when every group's residual after that one step
/// is within 1 mm, and otherwise gives the tight tolerance's fit.
#[test]
fn cold_keypoint_stage_stops_after_one_step_only_within_its_tolerance() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, _) = &held_out(data, 1)[0];
    let kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
    let c = Constraints::from_keypoints(kp.clone());
    let mut run = |tol: Option<f64>| {
        let opts = FitOptions {
            one_step_tolerance: tol,
            ..FitOptions::default()
        };
        let (_, fit) = solver.fit(&c, &Default::default(), &opts, None).unwrap();
        let stage = fit
            .report
            .stages
            .iter()
            .find(|s| s.name == "keypoints")
            .expect("keypoint stage")
            .clone();
        (stage, fit)
    };
    let (loose, fit_loose) = run(Some(1.0));
    let (tight, fit_tight) = run(Some(1e-9));
    let (factored, _) = run(None);
    let (default, fit_default) = run(FitOptions::default().one_step_tolerance);
    let steps = FitOptions::default().step_iterations;
    assert_eq!(loose.iterations, 1, "{loose:?}");
    assert!(loose.energy_end <= loose.energy_start, "{loose:?}");
    // One PCG step, then the remaining factored ones (rejected ones counted too).
    assert!(tight.iterations >= steps.min(2), "{tight:?}");
    assert!(factored.iterations >= steps.min(2), "{factored:?}");
    assert!(tight.energy_end <= tight.energy_start, "{tight:?}");
    let after_one = keypoint_residuals(&model, &kp, &fit_loose.vertices);
    let within = after_one.values().all(|g| g.mean_mm <= 1.0);
    let same = |a: &[V3], b: &[V3]| a.iter().zip(b).all(|(p, q)| norm(sub(*p, *q)) < 1e-9);
    if within {
        assert_eq!(default.iterations, 1);
        assert!(same(&fit_default.vertices, &fit_loose.vertices));
    } else {
        assert_eq!(default.iterations, tight.iterations);
        assert!(same(&fit_default.vertices, &fit_tight.vertices));
    }
    println!(
        "after one step {:?}; stage iterations loose {} tight {} factored {} default {}",
        after_one
            .iter()
            .map(|(k, g)| format!("{k} {:.2}", g.mean_mm))
            .collect::<Vec<_>>(),
        loose.iterations,
        tight.iterations,
        factored.iterations,
        default.iterations
    );
}

/// A sequence whose second frame is the first one moved rigidly: the warm-started fit follows
/// the motion (fit₁ ≈ M fit₀), and the propagated placement is the first frame's placement
/// composed with M (a composition in the wrong order or a transposed rotation fails here); a
/// third frame, back at the first pose, returns to it.
#[test]
fn sequence_follows_a_rigid_motion_and_propagates_the_placement() {
    use panoman_mesh::geom::{add, matmul, matvec};
    use panoman_mesh::rotation::axis_angle;
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, _) = held_out(data, 1).remove(0);
    let r = axis_angle([0.2, 0.1, 1.0], 0.3);
    let t = [0.05, -0.02, 0.01];
    let moved: Vec<V3> = truth.iter().map(|&p| add(matvec(&r, p), t)).collect();
    let mut seq = Tracking::default();
    let mut fits = Vec::new();
    for x in [&truth, &moved, &truth] {
        let c = Constraints::from_keypoints(KeypointsFile::from_all(&model.keypoints.evaluate(x)));
        fits.push(seq.fit_next(&mut solver, &c).unwrap().1);
    }
    let (f0, f1, f2) = (&fits[0], &fits[1], &fits[2]);
    let ml = solver.shell().mean_edge();
    // The warm fit follows the motion to a fraction of an edge.
    let e1 = mean_error(
        &f1.vertices,
        &f0.vertices
            .iter()
            .map(|&p| add(matvec(&r, p), t))
            .collect::<Vec<_>>(),
    );
    assert!(e1 < 0.5 * ml, "moved fit off by {:.2} mm", e1 * 1e3);
    assert!(
        mean_error(&f2.vertices, &f0.vertices) < 0.5 * ml,
        "the third frame did not return"
    );
    // Shape kept along the sequence; placement composed with the motion.
    assert_eq!(f1.params.alpha, f0.params.alpha);
    let rot = |v: V3| {
        let a = norm(v);
        if a == 0.0 {
            panoman_mesh::geom::IDENTITY
        } else {
            axis_angle(v, a)
        }
    };
    let r0 = rot(f0.params.rotation);
    let r1 = rot(f1.params.rotation);
    let expect = matmul(&r, &r0);
    let dr = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (r1[i][j] - expect[i][j]).abs())
        .fold(0.0, f64::max);
    println!("rotation off by {dr:e}");
    assert!(dr < 0.01, "rotation off by {dr:e}");
    let t1 = add(matvec(&r, f0.params.translation), t);
    assert!(
        norm(sub(f1.params.translation, t1)) < 0.5 * ml,
        "translation {:?} vs {t1:?}",
        f1.params.translation
    );
}

/// Motion data θ constrains β_B through the motion MLP: with a large τ_θ the fitted body
/// coefficients are β_MLP(θ) (to 1/(1+τ_θ) of their least-squares distance), without motion
/// data they are not; non-finite angles are an error.
#[test]
fn motion_data_constrains_the_body_coefficients() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, _) = held_out(data, 1).remove(0);
    let c = Constraints::from_keypoints(KeypointsFile::from_all(&model.keypoints.evaluate(&truth)));
    let ikr = solver.ik_fit(&c, &Default::default()).unwrap();
    let init = solver.init_of(&ikr);
    let theta = init.theta.clone().unwrap();
    let (bl, ba) = model
        .beta_from_theta(&|b: &str| theta.get(b).copied())
        .expect("the small model has a motion MLP");
    let body = |p: &panoman_model::model::Params| {
        let mut v = p.beta[&model.blocks[0].name].clone();
        v.extend(&p.beta[&model.blocks[3].name]);
        v
    };
    let mut target = bl.clone();
    target.extend(&ba);
    let dist = |v: &[f64]| {
        v.iter()
            .zip(&target)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let free = solver
        .shell_mut()
        .fit(&c, &init, &FitOptions::default())
        .unwrap();
    let d_free = dist(&body(&free.params));
    let with = Constraints {
        motion: Some(theta.clone()),
        ..c.clone()
    };
    let opts = FitOptions {
        motion_weight: 1e6,
        ..FitOptions::default()
    };
    let held = solver.shell_mut().fit(&with, &init, &opts).unwrap();
    let d_held = dist(&body(&held.params));
    println!("|β_B − β_θ|: free {d_free:.3e}, τ_θ = 1e6 {d_held:.3e}");
    assert!(d_free > 1e-3, "{d_free}");
    assert!(d_held < 1e-5 * d_free.max(1.0), "{d_held} vs {d_free}");
    // The fit still meets the keypoints (the shell's V is free).
    let res = keypoint_residuals(&model, &c.targets.keypoints, &held.vertices);
    assert!(res[&KeypointGroup::Body].mean_mm < 10.0, "{res:?}");
    let mut bad = theta;
    bad.insert("upperarm01.L".into(), [f64::NAN, 0.0, 0.0]);
    let e = solver
        .shell_mut()
        .fit(
            &Constraints {
                motion: Some(bad),
                ..c
            },
            &init,
            &opts,
        )
        .unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
}

/// The shell fit's ICP (`Fitter::fit` with a point cloud) moves a fit toward a noisy scan with
/// a missing part. The initializer is the keypoint IK *without* the phenotype polish
/// (`IkConfig::phenotype_polish = false`), which leaves this person in a wrong phenotype cell
/// (body shape centimetres off, 9.6 mm mean): that is what the scan has to correct. (With the
/// polish the IK is within 2.4 mm here, and on CI's small model the shell stage moves such a
/// near-exact initializer *away* from the LBS-made truth — 3.7 mm with keypoints only, 5.6 mm
/// with the scan — because its 24-component guidance is far off; on the default model the
/// scan fit is 1.6 mm against 4.5 mm from keypoints, `panoman bench --only fit_scan`.)
#[test]
fn point_cloud_with_missing_part_and_noise_helps() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, _) = &held_out(data, 1)[0];
    // A scan: every vertex of the front-facing 70 % (by height order of a plane cut),
    // displaced by 2 mm Gaussian noise (deterministic generator).
    let mut s = 0x9e3779b97f4a7c15u64;
    let mut gauss = || {
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b) = (u().max(1e-300), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    };
    let mut ys: Vec<f64> = truth.iter().map(|p| p[1]).collect();
    ys.sort_by(f64::total_cmp);
    let cut = ys[(0.7 * ys.len() as f64) as usize];
    let points: Vec<V3> = truth
        .iter()
        .filter(|p| p[1] <= cut)
        .map(|p| {
            [
                p[0] + 0.002 * gauss(),
                p[1] + 0.002 * gauss(),
                p[2] + 0.002 * gauss(),
            ]
        })
        .collect();
    // TC-127 keypoints (the feet left out): with the foot keypoints the unpolished IK lands
    // this person within 4.4 mm, the near-exact case described above.
    let kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth))
        .without_group(panoman_human::keypoints::KeypointGroup::Feet);
    let c = Constraints::from_keypoints(kp);
    let unpolished = panoman_fit::ik::IkConfig {
        phenotype_polish: false,
        ..Default::default()
    };
    let ikr = solver.ik_fit(&c, &unpolished).unwrap();
    let init = Init {
        posed: ikr.posed.clone(),
        rest: ikr.rest.clone(),
        theta: None,
        guide: None,
    };
    let base = solver
        .shell_mut()
        .fit(&c, &init, &FitOptions::default())
        .unwrap();
    let mut with_points = c.clone();
    with_points.targets.points = Some(PointCloud {
        positions: points,
        normals: None,
    });
    let fit = solver
        .shell_mut()
        .fit(&with_points, &init, &FitOptions::default())
        .unwrap();
    let (e0, e1) = (
        mean_error(&base.vertices, truth),
        mean_error(&fit.vertices, truth),
    );
    println!(
        "keypoints only {:.2} mm, with points {:.2} mm",
        e0 * 1e3,
        e1 * 1e3
    );
    let icp: Vec<_> = fit
        .report
        .stages
        .iter()
        .filter(|s| s.name.starts_with("icp"))
        .collect();
    assert_eq!(icp.len(), 2, "two ICP passes");
    assert!(icp[0].matches.as_ref().unwrap().matched > 0);
    assert!(e1 < e0, "the scan must help: {e0} → {e1}");
}

#[test]
fn contradictory_constraints_return_the_best_fit_and_bad_input_is_an_error() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, rest) = &held_out(data, 1)[0];
    let mut kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
    // The left wrist 1 m away from the elbow: unreachable.
    let w = keypoint_index("l_wrist").unwrap();
    kp.points.get_mut(&w).unwrap()[0] += 1.0;
    let c = Constraints::from_keypoints(kp);
    let (_, fit) = cold_fit(&mut solver, &c).expect("an unreachable target is not an error");
    assert!(fit.vertices.iter().flatten().all(|x| x.is_finite()));
    assert!(fit.report.keypoint_residuals[&KeypointGroup::Body].max_mm > 100.0);

    let init = Init {
        posed: truth.clone(),
        rest: rest.clone(),
        theta: None,
        guide: None,
    };
    let mut empty = c.clone();
    empty.targets.points = Some(PointCloud::default());
    let e = solver
        .shell_mut()
        .fit(&empty, &init, &FitOptions::default())
        .unwrap_err();
    assert!(matches!(e, FitError::Invalid(_)) && e.to_string().contains("empty"));
    let nothing = Constraints::default();
    assert!(
        solver
            .shell_mut()
            .fit(&nothing, &init, &FitOptions::default())
            .is_err()
    );
    let wrong = Init {
        posed: truth[..10].to_vec(),
        rest: rest.clone(),
        theta: None,
        guide: None,
    };
    let e = solver
        .shell_mut()
        .fit(&c, &wrong, &FitOptions::default())
        .unwrap_err();
    assert!(e.to_string().contains("vertices"), "{e}");
}

#[test]
fn cli_fit_baseline_track_and_bad_input() {
    let (dir, data, model_path) = trained();
    let model = PanoManModel::load(model_path).unwrap();
    let m = model_path.to_str().unwrap();
    let cases = held_out(data, 3);
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for (k, (truth, _)) in cases.iter().enumerate() {
        KeypointsFile::from_all(&model.keypoints.evaluate(truth))
            .write(&frames.join(format!("f{k:03}.json")))
            .unwrap();
    }
    let k0 = frames.join("f000.json");
    let k0s = k0.to_str().unwrap();
    let out = dir.join("fit");
    ok(panoman(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        k0s,
        "--out",
        out.to_str().unwrap(),
    ]));
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(rep["method"], "panoman");
    assert!(
        rep["keypoint_residuals"]["body"]["mean_mm"]
            .as_f64()
            .unwrap()
            < 10.0
    );
    assert!(rep["stages"].as_array().unwrap().len() >= 3);
    let fitted = panoman_mesh::io::read_mesh(&out.join("mesh.obj")).unwrap();
    assert!(mean_error(&fitted.positions, &cases[0].0) < 0.03);
    assert!(out.join("params.json").exists());
    // The fitted parameters pose through the model.
    ok(panoman(&[
        "pose",
        "--model",
        m,
        "--params",
        out.join("params.json").to_str().unwrap(),
        "--out",
        dir.join("posed.obj").to_str().unwrap(),
    ]));

    let lbs = dir.join("lbs");
    ok(panoman(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        k0s,
        "--baseline",
        "lbs",
        "--out",
        lbs.to_str().unwrap(),
    ]));
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(lbs.join("report.json")).unwrap()).unwrap();
    assert_eq!(rep["method"], "lbs");
    // The baseline's rig parameters as motion data for PanoMan (β_B pulled to β_MLP(θ)).
    let motion = dir.join("motion");
    ok(panoman(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        k0s,
        "--motion",
        lbs.join("params.json").to_str().unwrap(),
        "--out",
        motion.to_str().unwrap(),
    ]));
    assert!(motion.join("params.json").exists());
    let missing = dir.join("no-such-motion.json");
    one_line_error(
        &panoman(&[
            "fit",
            "--model",
            m,
            "--keypoints",
            k0s,
            "--motion",
            missing.to_str().unwrap(),
            "--out",
            motion.to_str().unwrap(),
        ]),
        "no-such-motion.json",
    );

    let track = dir.join("track");
    ok(panoman(&[
        "track",
        "--model",
        m,
        "--frames",
        frames.to_str().unwrap(),
        "--out",
        track.to_str().unwrap(),
    ]));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(track.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(s["frames"], 3);
    for k in 0..3 {
        assert!(track.join(format!("f{k:03}.obj")).exists());
    }
    assert!(s["shape_calibration"].is_null());
    // With a shape calibration from two of the frames (the LBS baseline: the same IK).
    let cal = dir.join("track-cal");
    ok(panoman(&[
        "track",
        "--model",
        m,
        "--frames",
        frames.to_str().unwrap(),
        "--baseline",
        "lbs",
        "--calibrate-shape",
        "2",
        "--out",
        cal.to_str().unwrap(),
    ]));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cal.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["frames"], 3);
    let c = &s["shape_calibration"];
    let used: Vec<&str> = c["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(used.len() == 2 && used[0].ends_with("f000.json") && used[1].ends_with("f001.json"));
    let knobs = c["knobs"].as_object().unwrap();
    assert_eq!(knobs.len(), 9);
    assert!(knobs.values().all(|v| v.as_f64().unwrap().abs() <= 1.0));
    assert!(knobs.contains_key("measure-lowerarm-length-incr"));
    for k in ["keypoint_error_before_mm", "keypoint_error_after_mm"] {
        assert!(c[k].as_f64().unwrap().is_finite(), "{k}");
    }

    // Bad input: one line, non-zero exit, nothing written.
    let bad = dir.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    let unknown = bad.join("unknown.json");
    std::fs::write(&unknown, r#"{"keypoints": {"l_elbw": [0, 0, 1]}}"#).unwrap();
    let nan = bad.join("nan.json");
    std::fs::write(&nan, r#"{"keypoints": {"l_elbow": [0, 1e999, 1]}}"#).unwrap();
    let empty_ply = bad.join("empty.ply");
    std::fs::write(
        &empty_ply,
        "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    )
    .unwrap();
    let wrong_params = bad.join("p.json");
    std::fs::write(&wrong_params, r#"{"beta": {"body_l": [1, 2]}}"#).unwrap();
    let o = bad.join("out");
    let os = o.to_str().unwrap();
    for (args, needle) in [
        (vec!["--keypoints", unknown.to_str().unwrap()], "l_elbw"),
        (vec!["--keypoints", nan.to_str().unwrap()], "nan.json"),
        (
            vec!["--keypoints", k0s, "--points", empty_ply.to_str().unwrap()],
            "empty",
        ),
        (
            vec![
                "--keypoints",
                k0s,
                "--params",
                wrong_params.to_str().unwrap(),
            ],
            "body_l",
        ),
    ] {
        let mut a = vec!["fit", "--model", m, "--out", os];
        a.extend(args);
        one_line_error(&panoman(&a), needle);
        assert!(!o.join("mesh.obj").exists());
    }
}

#[test]
fn eval_small_configuration_writes_every_figure() {
    let (dir, data, model_path) = trained();
    let out = dir.join("report");
    ok(panoman(&[
        "eval",
        "--model",
        model_path.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--preset",
        "small",
        "--out",
        out.to_str().unwrap(),
    ]));
    for f in [
        "index.html",
        "summary.json",
        "components.csv",
        "components.png",
        "correction_ablation.png",
        "clip.csv",
        "clip.png",
        "twist_radius.png",
        "twist_volume.png",
        "twist_forearm_90.png",
        "twist_forearm_150.png",
        "twist_forearm_180.png",
        "error_map.png",
        "fit_example.png",
        "composite.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    for key in [
        "representation",
        "fit_held_out",
        "clip",
        "twist",
        "composite",
        "timing",
        "headline",
    ] {
        assert!(!s[key].is_null(), "summary.json lacks {key}");
    }
    // Numbers, not placeholders: errors are finite and positive, timings measured.
    let h = &s["headline"];
    for m in ["panoman", "lbs"] {
        let e = h["fit_exact_mean_mm"][m].as_f64().unwrap();
        assert!(e.is_finite() && e > 0.0 && e < 100.0, "{m}: {e}");
    }
    assert!(h["cold_fit_median_s"].as_f64().unwrap() > 0.0);
    assert_eq!(s["clip"]["frames"], 6);
    // The typed summary reads every key back and writes the same document.
    let typed: panoman::eval::EvalSummary = serde_json::from_value(s.clone()).unwrap();
    assert_eq!(serde_json::to_value(&typed).unwrap(), s);
    assert_eq!(typed.fit_held_out.people, 2);
    assert_eq!(typed.twist.limbs.len(), 4);
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("twist_radius.png") && html.contains("error_map.png"));
}

/// The quality check (docs/design/shell-fit.md §7): a held-out person from exact keypoints
/// passes on the first IK start; the same keypoints with the left wrist 0.5 m off cannot be
/// met, so the initializer is retried from the other starts, and the fit, still returned, is
/// flagged `converged: false` with a reason naming the body keypoints.
#[test]
fn quality_check_retries_and_flags_an_impossible_keypoint() {
    let (_, data, model_path) = trained();
    let (model, mut solver) = model_and_solver(model_path);
    let (truth, _) = &held_out(data, 1)[0];
    let mut kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
    let good = Constraints::from_keypoints(kp.clone());
    let (_, fit) = cold_fit(&mut solver, &good).unwrap();
    let v = &fit.report.verdict;
    assert!(v.converged, "{:?}", v.reason());
    assert!(v.problems.is_empty() && !v.retried && v.ik_attempts.len() == 1);
    assert!(v.ik_attempts[0].chosen && v.ik_attempts[0].problems.is_empty());
    // The shell stage did something: its LM steps were accepted.
    let accepted: usize = fit.report.stages.iter().map(|s| s.accepted).sum();
    assert!(accepted > 0, "{:?}", fit.report.stages);

    let w = keypoint_index("l_wrist").unwrap();
    kp.points.get_mut(&w).unwrap()[1] += 0.5;
    let bad = Constraints::from_keypoints(kp);
    let (_, fit) = cold_fit(&mut solver, &bad).unwrap();
    let v = &fit.report.verdict;
    assert!(!v.converged);
    let reason = v.reason().unwrap();
    assert!(reason.contains("body keypoint"), "{reason}");
    // The problems are typed: the body group's residual is named with its threshold.
    assert!(
        v.problems.iter().any(|p| matches!(
            p,
            panoman_fit::quality::Problem::KeypointMean {
                group: KeypointGroup::Body,
                ..
            } | panoman_fit::quality::Problem::KeypointMax {
                group: KeypointGroup::Body,
                ..
            }
        )),
        "{:?}",
        v.problems
    );
    assert!(v.retried && v.ik_attempts.len() >= 6, "{:?}", v.ik_attempts);
    assert_eq!(v.ik_attempts.iter().filter(|a| a.chosen).count(), 1);
    assert!(v.ik_attempts.iter().all(|a| !a.problems.is_empty()));
    assert!(fit.vertices.iter().flatten().all(|x| x.is_finite()));
}

/// The CLI side of the quality check: `panoman fit` writes its outputs for an impossible
/// keypoint set but warns on one line and exits 3 (report.json: `converged: false`, a
/// reason); `panoman track` flags the frame in summary.json, exits 0 with a warning, and 3
/// with `--strict`; summary.json has the per-frame stages and the clip's step totals.
#[test]
fn cli_not_converged_fit_exits_3_and_track_flags_the_frame() {
    let (dir, data, model_path) = trained();
    let model = PanoManModel::load(model_path).unwrap();
    let m = model_path.to_str().unwrap();
    let (truth, _) = &held_out(data, 1)[0];
    let frames = dir.join("frames-bad");
    std::fs::create_dir_all(&frames).unwrap();
    let mut kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
    kp.write(&frames.join("f000.json")).unwrap();
    let w = keypoint_index("l_wrist").unwrap();
    kp.points.get_mut(&w).unwrap()[1] += 0.5;
    let bad = frames.join("f001.json");
    kp.write(&bad).unwrap();
    let out = dir.join("fit-bad");
    let o = panoman(&[
        "fit",
        "--model",
        m,
        "--keypoints",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("warning:") && stderr.contains("did not converge"));
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(rep["converged"], false);
    assert!(rep["reason"].as_str().unwrap().contains("keypoint"));
    assert!(rep["ik_attempts"].as_array().unwrap().len() > 1);
    assert!(out.join("mesh.obj").exists());

    let track = dir.join("track-bad");
    let args = |strict: bool| {
        let mut a = vec![
            "track",
            "--model",
            m,
            "--frames",
            frames.to_str().unwrap(),
            "--out",
            track.to_str().unwrap(),
        ];
        if strict {
            a.push("--strict");
        }
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let a: Vec<String> = args(false);
    let o = panoman(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(o.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 of 2 frames did not converge"));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(track.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(s["not_converged"], 1);
    assert_eq!(s["not_converged_frames"][0], "f001");
    let pf = s["per_frame"].as_array().unwrap();
    assert_eq!(pf[0]["converged"], true);
    assert_eq!(pf[1]["converged"], false);
    assert!(pf[0]["shell_stages"].as_array().unwrap().len() >= 2);
    assert!(s["steps_accepted"].as_u64().unwrap() > 0);
    assert!(s["steps_tried"].as_u64() >= s["steps_accepted"].as_u64());
    let a: Vec<String> = args(true);
    let o = panoman(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(o.status.code(), Some(3));
}
