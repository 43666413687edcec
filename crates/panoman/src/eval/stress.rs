//! The stress set (issue 15): people and poses made by our own generator *outside* what the
//! model was trained on — composites (body pose, both hands' gestures and a facial
//! expression at once), whole-body composites (every body joint uniform over the generator's
//! full ranges, so the legs and feet move as much as the arms), phenotypes at the edges of the sampler, forearm twists of 120–180°
//! (the sampler stops at ±30°), a hand on the head and a hand at the chin (found by a search
//! of the arm's angles, beyond the sampler's ranges), a deep sit, a crouch, a kneel, a raised
//! foot and crossed legs. Every case reports its error per region (feet, legs, torso, arms,
//! hands, face; [`super::metrics::BodyRegions`]). Each case is
//! fitted from its exact TC-133 keypoints by the LBS rig (the IK) and by PanoMan (the shell
//! fit from that IK), and reported side by side with the per-vertex error, the keypoint
//! residual, what the shell stage did (steps tried/accepted) and the failure detector's
//! verdict ([`panoman_fit::quality::Verdict`]: converged or the reason, and whether the
//! initializer was retried). Twist cases add the forearm's cross-section radius over the person's true rest and
//! the errors over the shoulder region and the hand, where the ground truth is not collapsed.
//!
//! The cases are drawn from their own random streams ([`STRESS_DOMAIN`]), so they are new
//! draws for every model; the same seed gives the same cases.
use panoman_fit::Constraints;
use panoman_fit::fit::{FitResult, keypoint_residuals};
use panoman_fit::twist::LimbSegment;
use panoman_human::keypoints::{KeypointGroup, KeypointsFile};
use panoman_human::params::ShapeParams;
use panoman_human::phenotype::Phenotype;
use panoman_human::regions::Part;
use panoman_human::sampling::{
    BODY_BONES, BodyPoseSampler, BoneMap, ExpressionSampler, HandSampler, IdentitySampler, Theta,
    anny_age_of_years, bone_range, posable_bones, stream_rng, uniform_in,
};
use panoman_mesh::geom::{V3, add, dot, norm, scale, sub};
use rand_chacha::rand_core::RngCore;

use super::metrics::{PartErrors, part_errors};
use super::summary::{PerMethod, StressCase, StressSummary, StressTwist};
use super::{Bench, EvalPreset, EvalProgress, MeshTriple};
use crate::error::{Error, Result};

/// Random-stream domain of the stress cases (distinct from the synthesis and clip domains).
pub const STRESS_DOMAIN: u64 = 0x5743_5353;

/// What the stress set gives the summary and the renders.
pub(crate) struct StressRun {
    pub(crate) summary: StressSummary,
    /// Every case's meshes, by name.
    pub(crate) meshes: Vec<(String, MeshTriple)>,
}

/// One case before it is fitted.
struct Spec {
    name: String,
    kind: &'static str,
    shape: ShapeParams,
    theta: Theta,
    /// Forearm twist (degrees) of a twist case.
    twist_deg: Option<f64>,
    /// Upper-arm roll (degrees) of a twist case (0 for a forearm twist alone).
    upper_arm_deg: f64,
}

/// Slot of a posable bone in [`Theta`].
fn slot(bone: &str) -> Result<usize> {
    posable_bones()
        .iter()
        .position(|b| b == bone)
        .ok_or_else(|| Error::Invalid(format!("`{bone}` is not a posable bone")))
}

/// A composite: a sampled body pose, gestures on both hands and a facial expression.
fn composite_theta(rng: &mut impl RngCore, shape: &mut ShapeParams) -> Theta {
    let mut th = BodyPoseSampler.sample(rng);
    HandSampler.sample_into(rng, &mut th);
    let e = ExpressionSampler.sample(rng);
    e.write_theta(&mut th);
    shape.facial_actions = e.units;
    th
}

/// A whole-body composite: every body bone's angles uniform over the generator's full
/// ranges ([`bone_range`]: spine, neck, head, clavicles, shoulders, arms, the hips' flexion,
/// abduction and roll about the leg, knees, the ankles' flexion, inversion and turn, the limbs'
/// twists to their limits), so that the legs and feet move as much as the arms; both hands'
/// gestures and a facial expression on top.
fn whole_body_theta(rng: &mut impl RngCore, shape: &mut ShapeParams) -> Result<Theta> {
    let mut th = composite_theta(rng, shape);
    for bone in BODY_BONES {
        let Some(range) = bone_range(bone) else {
            continue;
        };
        let s = slot(bone)?;
        for (a, [lo, hi]) in range.into_iter().enumerate() {
            th.deg[s][a] = uniform_in(rng, lo, hi);
        }
    }
    Ok(th)
}

/// The phenotypes at the sampler's edges (name, phenotype).
fn extreme_phenotypes() -> Vec<(&'static str, Phenotype)> {
    let p = |gender, years: f64, muscle, weight, height| Phenotype {
        gender,
        age: anny_age_of_years(years).clamp(-1.0 / 3.0, 1.0),
        muscle,
        weight,
        height,
        ..Phenotype::default()
    };
    vec![
        ("old_slim_woman", p(1.0, 85.0, 0.0, 0.0, 0.4)),
        ("heavy_muscular_man", p(0.0, 35.0, 1.0, 1.0, 0.6)),
        ("tall_thin_man", p(0.0, 25.0, 0.3, 0.0, 1.0)),
        ("short_heavy_woman", p(1.0, 50.0, 0.2, 1.0, 0.0)),
        ("child_8y", p(0.5, 8.0, 0.5, 0.5, 0.5)),
    ]
}

/// The case list of `preset` (deterministic in `seed`).
fn specs(preset: &EvalPreset, seed: u64) -> Result<Vec<Spec>> {
    let mut out = Vec::new();
    let mut k = 0u64;
    let mut next_rng = || {
        k += 1;
        stream_rng(seed, STRESS_DOMAIN, k)
    };
    for i in 0..preset.stress_composites {
        let mut rng = next_rng();
        let mut shape = IdentitySampler::default().sample(&mut rng).shape;
        let theta = composite_theta(&mut rng, &mut shape);
        out.push(Spec {
            name: format!("composite_{i}"),
            kind: "composite",
            shape,
            theta,
            twist_deg: None,
            upper_arm_deg: 0.0,
        });
    }
    for i in 0..preset.stress_whole_body {
        let mut rng = stream_rng(seed, STRESS_DOMAIN, 2000 + i as u64);
        let mut shape = IdentitySampler::default().sample(&mut rng).shape;
        let theta = whole_body_theta(&mut rng, &mut shape)?;
        out.push(Spec {
            name: format!("whole_body_{i}"),
            kind: "whole-body",
            shape,
            theta,
            twist_deg: None,
            upper_arm_deg: 0.0,
        });
    }
    for (name, ph) in extreme_phenotypes()
        .into_iter()
        .take(preset.stress_extremes)
    {
        let mut rng = next_rng();
        let mut shape = ShapeParams {
            phenotype: ph,
            ..ShapeParams::default()
        };
        let theta = composite_theta(&mut rng, &mut shape);
        out.push(Spec {
            name: name.into(),
            kind: "extreme shape",
            shape,
            theta,
            twist_deg: None,
            upper_arm_deg: 0.0,
        });
    }
    let twist = slot("lowerarm02.L")?;
    let upper_twist = slot("upperarm02.L")?;
    let elbow = slot("lowerarm01.L")?;
    let shoulder = slot("upperarm01.L")?;
    let arm_cases = preset
        .stress_twists_deg
        .iter()
        .map(|&f| [0.0, f])
        .chain(preset.stress_arm_rolls_deg.iter().copied());
    for [upper, ang] in arm_cases {
        let mut rng = next_rng();
        let shape = IdentitySampler::default().sample(&mut rng).shape;
        let mut theta = BodyPoseSampler.sample(&mut rng);
        // The left arm lowered 30° and raised 20° forward, away from the body, with a bent
        // elbow, so that the hand's keypoints show the forearm's roll.
        theta.deg[shoulder] = [20.0, 0.0, -30.0];
        theta.deg[elbow] = [35.0, 0.0, 0.0];
        theta.deg[twist][1] = ang;
        if upper != 0.0 {
            theta.deg[upper_twist][1] = upper;
        }
        out.push(Spec {
            name: if upper == 0.0 {
                format!("twist_forearm_{ang:.0}")
            } else {
                format!("twist_arm_{upper:.0}_{ang:.0}")
            },
            kind: "twist",
            shape,
            theta,
            twist_deg: Some(ang),
            upper_arm_deg: upper,
        });
    }
    for name in ["sit_deep", "crouch", "kneel", "foot_raised", "legs_crossed"]
        .into_iter()
        .take(preset.stress_postures)
    {
        let mut rng = next_rng();
        let shape = IdentitySampler::default().sample(&mut rng).shape;
        let mut theta = BodyPoseSampler.sample(&mut rng);
        // Hip flexion is −x, abduction +z on the left; knee flexion +x; the foot's flexion
        // (toes down) +x, its inversion y (the sampler's conventions, right side mirrored as
        // (x, −y, −z)). Per side: [hip (x, y, z)], knee x, [foot (x, y, z)].
        type Leg = ([f64; 3], f64, [f64; 3]);
        let legs: [Leg; 2] = match name {
            "crouch" => [([-125.0, 0.0, 0.0], 140.0, [30.0, 0.0, 0.0]); 2],
            "sit_deep" => [([-100.0, 0.0, 0.0], 100.0, [0.0, 0.0, 0.0]); 2],
            // On the right knee, the left foot forward and flat, the right toes bent under.
            "kneel" => [
                ([-95.0, 0.0, 5.0], 95.0, [-10.0, 0.0, 0.0]),
                ([10.0, 0.0, 0.0], 110.0, [35.0, 0.0, 0.0]),
            ],
            // The left foot raised in front, rolled out and pointed and turned in.
            "foot_raised" => [
                ([-60.0, 25.0, 10.0], 80.0, [40.0, 10.0, 15.0]),
                ([0.0, 0.0, 0.0], 0.0, [0.0, 0.0, 0.0]),
            ],
            // The left leg crossed over the right: flexed, adducted and rolled in.
            _ => [
                ([-35.0, -25.0, -30.0], 20.0, [15.0, -10.0, 0.0]),
                ([-5.0, 10.0, 0.0], 5.0, [0.0, 0.0, 0.0]),
            ],
        };
        for (side, (hip, knee, foot)) in ["L", "R"].into_iter().zip(legs) {
            let m = if side == "L" { 1.0 } else { -1.0 };
            let mirror = |v: [f64; 3]| [v[0], m * v[1], m * v[2]];
            theta.deg[slot(&format!("upperleg01.{side}"))?] = mirror(hip);
            theta.deg[slot(&format!("lowerleg01.{side}"))?][0] = knee;
            theta.deg[slot(&format!("foot.{side}"))?] = mirror(foot);
        }
        out.push(Spec {
            name: name.into(),
            kind: "posture",
            shape,
            theta,
            twist_deg: None,
            upper_arm_deg: 0.0,
        });
    }
    Ok(out)
}

/// The keypoints of the rig posed by `theta` on the model's topology, and the mesh.
fn posed_keypoints(
    b: &Bench,
    id: &panoman_human::generator::Identity,
    bones: &BoneMap,
    theta: &Theta,
) -> (Vec<V3>, Vec<V3>) {
    let posed = id.pose(&bones.pose_params(theta));
    let x = b.rig().map.map(b.rig().topology, &posed.vertices);
    (b.model.inner().keypoints.evaluate(&x), x)
}

/// A hand placed on a target: the arm's angles (`upperarm01` x, y, z and `lowerarm01` x of
/// `side`) searched by coordinate descent with step halving from a few starts, so that the
/// hand's middle knuckle (`hand_09`) and its wrist (`hand_00`) reach `targets(rest keypoints)`.
/// The angles may leave the sampler's ranges (that is the point of the case).
fn place_hand(
    b: &Bench,
    id: &panoman_human::generator::Identity,
    bones: &BoneMap,
    theta: &mut Theta,
    side: char,
    targets: (V3, V3),
) -> Result<f64> {
    let vars = [
        (slot(&format!("upperarm01.{side}"))?, 0usize),
        (slot(&format!("upperarm01.{side}"))?, 1),
        (slot(&format!("upperarm01.{side}"))?, 2),
        (slot(&format!("lowerarm01.{side}"))?, 0),
    ];
    let hand = if side == 'L' { "lhand" } else { "rhand" };
    let names = &b.model.inner().keypoints.names;
    let row = |k: &str| names.iter().position(|n| n == k);
    let (Some(knuckle), Some(wrist)) = (row(&format!("{hand}_09")), row(&format!("{hand}_00")))
    else {
        return Err(Error::Invalid(
            "the model has no hand keypoints for the contact cases".into(),
        ));
    };
    let cost = |th: &Theta| {
        let (k, _) = posed_keypoints(b, id, bones, th);
        let d = |a: V3, t: V3| dot(sub(a, t), sub(a, t));
        d(k[knuckle], targets.0) + d(k[wrist], targets.1)
    };
    let mut best = (f64::INFINITY, *theta);
    for start in [
        [0.0, 0.0, 90.0, 90.0],
        [90.0, 0.0, 90.0, 120.0],
        [60.0, 0.0, 0.0, 140.0],
    ] {
        let mut th = *theta;
        for (&(s, a), &v) in vars.iter().zip(&start) {
            th.deg[s][a] = v;
        }
        let mut c = cost(&th);
        let mut step = 40.0;
        while step >= 1.0 {
            let mut moved = false;
            for &(s, a) in &vars {
                for dir in [-1.0, 1.0] {
                    let mut t2 = th;
                    t2.deg[s][a] += dir * step;
                    let c2 = cost(&t2);
                    if c2 < c {
                        (th, c, moved) = (t2, c2, true);
                    }
                }
            }
            if !moved {
                step *= 0.5;
            }
        }
        if c < best.0 {
            best = (c, th);
        }
    }
    *theta = best.1;
    Ok(best.0.sqrt())
}

/// The contact cases: the left hand on the head and the right hand under the chin.
fn contact_specs(b: &Bench, preset: &EvalPreset, seed: u64) -> Result<Vec<Spec>> {
    let g = b.rig().generator.clone();
    let bones = BoneMap::new(g.bone_names())?;
    let mut out = Vec::new();
    for (i, name) in ["hand_on_head", "hand_at_chin"]
        .into_iter()
        .enumerate()
        .take(preset.stress_contacts)
    {
        let mut rng = stream_rng(seed, STRESS_DOMAIN, 1000 + i as u64);
        let mut shape = IdentitySampler::default().sample(&mut rng).shape;
        let mut theta = composite_theta(&mut rng, &mut shape);
        let id = g.identity(&shape)?;
        let (k, x) = posed_keypoints(b, &id, &bones, &theta);
        let names = &b.model.inner().keypoints.names;
        let at = |n: &str| names.iter().position(|m| m == n).map(|r| k[r]);
        let (Some(neck), Some(center), Some(nose), Some(ls), Some(rs), Some(chin)) = (
            at("neck"),
            at("body_center"),
            at("nose"),
            at("l_shoulder"),
            at("r_shoulder"),
            at("face_08"),
        ) else {
            continue;
        };
        let unit = |v: V3| scale(v, 1.0 / norm(v).max(1e-12));
        let up = unit(sub(neck, center));
        let left = unit(sub(ls, rs));
        let fwd0 = sub(nose, neck);
        let fwd = unit(sub(fwd0, scale(up, dot(fwd0, up))));
        let (side, targets) = if name == "hand_on_head" {
            let top = x
                .iter()
                .copied()
                .max_by(|p, q| dot(*p, up).total_cmp(&dot(*q, up)))
                .unwrap_or(neck);
            let t = add(top, scale(up, 0.03));
            ('L', (t, add(add(top, scale(left, 0.08)), scale(up, 0.01))))
        } else {
            let t = add(chin, scale(fwd, 0.05));
            ('R', (t, add(t, scale(up, -0.09))))
        };
        place_hand(b, &id, &bones, &mut theta, side, targets)?;
        out.push(Spec {
            name: name.into(),
            kind: "contact",
            shape,
            theta,
            twist_deg: None,
            upper_arm_deg: 0.0,
        });
    }
    Ok(out)
}

/// Mean error (mm) of `x` against `truth` over `vs`.
fn mean_over(x: &[V3], truth: &[V3], vs: &[u32]) -> f64 {
    let s: f64 = vs
        .iter()
        .map(|&v| norm(sub(x[v as usize], truth[v as usize])))
        .sum();
    1e3 * s / vs.len().max(1) as f64
}

/// The twist measures of a twist case (see the module docs).
fn twist_measures(
    b: &Bench,
    angle: f64,
    upper_arm_deg: f64,
    rest: &[V3],
    meshes: &MeshTriple,
) -> Result<StressTwist> {
    let kp = &b.model.inner().keypoints;
    let names = &kp.names;
    let row = |n: &str| {
        names
            .iter()
            .position(|m| m == n)
            .ok_or_else(|| Error::Invalid(format!("the model has no keypoint `{n}`")))
    };
    let (re, rw, rs) = (row("l_elbow")?, row("l_wrist")?, row("l_shoulder")?);
    let kr = kp.evaluate(rest);
    let seg = LimbSegment::new(rest, kr[re], kr[rw], 0.15, 0.85, 0.06, 7);
    let ratio = |x: &[V3]| {
        let k = kp.evaluate(x);
        seg.radius_ratios(rest, (kr[re], kr[rw]), x, (k[re], k[rw]))
            .into_iter()
            .filter(|r| r.is_finite())
            .fold(f64::INFINITY, f64::min)
    };
    let upper = LimbSegment::new(rest, kr[rs], kr[re], 0.15, 0.85, 0.06, 7);
    let upper_ratio = |x: &[V3]| {
        let k = kp.evaluate(x);
        upper
            .radius_ratios(rest, (kr[rs], kr[re]), x, (k[rs], k[re]))
            .into_iter()
            .filter(|r| r.is_finite())
            .fold(f64::INFINITY, f64::min)
    };
    let hand = b.regions.vertices_of(Part::LeftHand);
    let shoulder: Vec<u32> = (0..rest.len() as u32)
        .filter(|&v| norm(sub(rest[v as usize], kr[rs])) < 0.12 && !hand.contains(&v))
        .collect();
    let t = &meshes.truth;
    Ok(StressTwist {
        angle_deg: angle,
        upper_arm_deg,
        truth_min_radius_ratio: ratio(t),
        min_radius_ratio: PerMethod {
            lbs: ratio(&meshes.lbs),
            panoman: ratio(&meshes.panoman),
        },
        truth_upper_arm_min_radius_ratio: upper_ratio(t),
        upper_arm_min_radius_ratio: PerMethod {
            lbs: upper_ratio(&meshes.lbs),
            panoman: upper_ratio(&meshes.panoman),
        },
        shoulder_mean_mm: PerMethod {
            lbs: mean_over(&meshes.lbs, t, &shoulder),
            panoman: mean_over(&meshes.panoman, t, &shoulder),
        },
        hand_mean_mm: PerMethod {
            lbs: mean_over(&meshes.lbs, t, &hand),
            panoman: mean_over(&meshes.panoman, t, &hand),
        },
    })
}

/// Mean keypoint residual (mm) over all given keypoints of `x`.
fn residual_mm(b: &Bench, c: &Constraints, x: &[V3]) -> f64 {
    let r = keypoint_residuals(b.model.inner(), &c.targets.keypoints, x);
    r.values().map(|g| g.mean_mm * g.n as f64).sum::<f64>()
        / r.values().map(|g| g.n).sum::<usize>().max(1) as f64
}

/// Shell LM steps (tried, accepted) over the fit's stages.
fn shell_steps(fit: &FitResult) -> (usize, usize) {
    fit.report
        .stages
        .iter()
        .fold((0, 0), |(t, a), s| (t + s.iterations, a + s.accepted))
}

/// Fits one case and measures it.
fn run_case(
    b: &mut Bench,
    spec: &Spec,
    cfg: &super::EvalConfig,
) -> Result<(StressCase, MeshTriple)> {
    let g = b.rig().generator.clone();
    let bones = BoneMap::new(g.bone_names())?;
    let id = g.identity(&spec.shape)?;
    let rest = b.rig().map.map(b.rig().topology, id.rest_vertices());
    let (kp, truth) = posed_keypoints(b, &id, &bones, &spec.theta);
    let mut keypoints = KeypointsFile::from_points(&kp)?;
    if cfg.stress_without_feet {
        keypoints = keypoints.without_group(KeypointGroup::Feet);
    }
    let c = Constraints::from_keypoints(keypoints);
    let t = std::time::Instant::now();
    let (ikr, fit) = b.solver.fit(&c, &b.ikc, &b.opts, None)?;
    let seconds = t.elapsed().as_secs_f64();
    let errors: PerMethod<PartErrors> = PerMethod {
        lbs: part_errors(&ikr.posed, &truth, &b.groups),
        panoman: part_errors(&fit.vertices, &truth, &b.groups),
    };
    let regions = PerMethod {
        lbs: b.body_regions.errors(&ikr.posed, &truth),
        panoman: b.body_regions.errors(&fit.vertices, &truth),
    };
    let residual = PerMethod {
        lbs: residual_mm(b, &c, &ikr.posed),
        panoman: residual_mm(b, &c, &fit.vertices),
    };
    let (tried, accepted) = shell_steps(&fit);
    let verdict = fit.report.verdict.clone();
    let meshes = MeshTriple {
        truth,
        panoman: fit.vertices,
        lbs: ikr.posed,
    };
    let representation =
        if cfg.stress_representation && matches!(spec.kind, "composite" | "whole-body") {
            let p = b
                .model
                .encode(&meshes.truth, Some(&rest), crate::Correction::Apply)?;
            let x = b.model.pose(&p, crate::Correction::Apply)?;
            let d: Vec<f64> = x
                .iter()
                .zip(&meshes.truth)
                .map(|(a, t)| 1e3 * norm(sub(*a, *t)))
                .collect();
            Some(super::summary::MeanMax {
                mean: d.iter().sum::<f64>() / d.len().max(1) as f64,
                max: d.iter().copied().fold(0.0, f64::max),
            })
        } else {
            None
        };
    let twist = match spec.twist_deg {
        Some(a) => Some(twist_measures(b, a, spec.upper_arm_deg, &rest, &meshes)?),
        None => None,
    };
    let case = StressCase {
        name: spec.name.clone(),
        kind: spec.kind.into(),
        errors,
        regions,
        keypoint_residual_mm: residual,
        shell_steps_tried: tried,
        shell_steps_accepted: accepted,
        differs_from_lbs_mm: 1e3
            * meshes
                .panoman
                .iter()
                .zip(&meshes.lbs)
                .map(|(p, q)| norm(sub(*p, *q)))
                .fold(0.0, f64::max),
        converged: verdict.converged,
        reason: verdict.reason(),
        retried: verdict.retried,
        seconds,
        twist,
        representation_mm: representation,
    };
    Ok((case, meshes))
}

/// Runs the stress set of `preset`.
pub(crate) fn run(
    b: &mut Bench,
    preset: &EvalPreset,
    seed: u64,
    cfg: &super::EvalConfig,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<StressRun> {
    let mut specs = specs(preset, seed)?;
    specs.extend(contact_specs(b, preset, seed)?);
    let mut cases = Vec::new();
    let mut all = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        progress(EvalProgress::Detail(&format!("stress case {}", s.name)));
        let (case, meshes) = run_case(b, s, cfg)?;
        all.push((case.name.clone(), meshes));
        cases.push(case);
        progress(EvalProgress::Step {
            done: i + 1,
            total: specs.len(),
        });
    }
    Ok(StressRun {
        summary: StressSummary::of(cases),
        meshes: all,
    })
}
