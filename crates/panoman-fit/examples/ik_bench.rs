//! IK benchmark: generates held-out-like people (seeded identity, body pose, hand gestures,
//! facial expression, global rotation and translation), computes their exact TC-133 keypoints,
//! fits the rig to them with [`panoman_fit::ik::IkSolver`] from a cold start and prints the
//! time per fit, the keypoint residuals and the per-vertex error of the fitted posed mesh
//! against the truth per part (body / face / left hand / right hand).
//!
//! ```sh
//! cargo run --release -p panoman-fit --example ik_bench [-- N [full|small] [known-shape]]
//! ```
//!
//! `known-shape` gives the solver the true shape (phenotype and face units as the start, the
//! phenotype not fitted), which separates the pose's share of the vertex error from the
//! phenotype's. `IK_BENCH_VERBOSE=1` prints the stages and the fitted phenotype per person.

use std::time::Instant;

use panoman_fit::ik::{IkConfig, IkSolver, IkTargets};
use panoman_human::generator::Generator;
use panoman_human::keypoints::{KeypointGroup, load_or_build};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::GeneratorParams;
use panoman_human::regions::{Part, Regions};
use panoman_human::sampling::{
    BodyPoseSampler, BoneMap, ExpressionSampler, HandSampler, IdentitySampler, stream_rng,
    uniform_in,
};
use panoman_human::template::{TopologyKind, full_template, small_template};

/// The keypoint groups of the report's columns (per-part vertex errors beside them).
const REPORTED: [KeypointGroup; 4] = [
    KeypointGroup::Body,
    KeypointGroup::Face,
    KeypointGroup::LeftHand,
    KeypointGroup::RightHand,
];

/// Stream domain of the benchmark's people (distinct from the dataset and keypoint domains).
const DOMAIN_IK_BENCH: u64 = 0x494b_0001;

/// Person `i`: identity, body pose with hand gestures, an expression (face units, jaw,
/// gaze), a global rotation (any heading, ±15° tilt) and translation.
fn person(bones: &BoneMap, i: u64) -> GeneratorParams {
    let mut rng = stream_rng(2024, DOMAIN_IK_BENCH, i);
    let mut shape = IdentitySampler::default().sample(&mut rng).shape;
    let mut theta = BodyPoseSampler.sample(&mut rng);
    HandSampler.sample_into(&mut rng, &mut theta);
    let expr = ExpressionSampler.sample(&mut rng);
    shape.facial_actions = expr.units;
    expr.write_theta(&mut theta);
    let mut pose = bones.pose_params(&theta);
    pose.root_rotation_z_deg = uniform_in(&mut rng, -180.0, 180.0);
    pose.euler_deg[0] = [
        uniform_in(&mut rng, -15.0, 15.0),
        uniform_in(&mut rng, -15.0, 15.0),
        0.0,
    ];
    pose.root_translation = [
        uniform_in(&mut rng, -1.0, 1.0),
        uniform_in(&mut rng, -1.0, 1.0),
        uniform_in(&mut rng, -0.2, 0.2),
    ];
    GeneratorParams { shape, pose }
}

fn dist_mm(a: [f64; 3], b: [f64; 3]) -> f64 {
    1e3 * ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: u64 = args.first().map(|s| s.parse()).transpose()?.unwrap_or(10);
    let small_topo = args.iter().any(|a| a == "small");
    let known_shape = args.iter().any(|a| a == "known-shape");
    let verbose = std::env::var_os("IK_BENCH_VERBOSE").is_some();
    let (topology, kind) = if small_topo {
        (OutputTopology::Small, TopologyKind::Small)
    } else {
        (OutputTopology::Full, TopologyKind::Full)
    };

    let dir = panoman_human::assets::ensure_default()?;
    let generator = Generator::load_default()?;
    let full = full_template(&dir)?;
    let small = small_template(&dir, &full)?;
    let map = TopologyMap::new(&generator, &full, &small)?;
    let defs = load_or_build(&dir, &full, &small)?;
    let set = defs.set(kind);
    let regions_full = Regions::full(&dir, &full)?;
    let regions = if small_topo {
        Regions::small(&regions_full, &small)?
    } else {
        regions_full
    };
    let bones = BoneMap::new(generator.bone_names())?;

    let t = Instant::now();
    let (generator, map) = (std::sync::Arc::new(generator), std::sync::Arc::new(map));
    let solver = IkSolver::new(generator.clone(), map.clone(), topology, set)?;
    println!(
        "topology {topology}: solver setup {:.1} ms ({} relevant vertices){}",
        1e3 * t.elapsed().as_secs_f64(),
        solver.n_relevant_vertices(),
        if known_shape { ", shape known" } else { "" }
    );

    let mut times = Vec::new();
    let mut kp_mean = Vec::new();
    let mut group_sum = [0.0; 4];
    let mut part_sum = [0.0; 4];
    let mut part_max = [0.0f64; 4];
    let mut all_sum = 0.0;
    let mut stage_time = std::collections::BTreeMap::<&str, f64>::new();
    println!(
        "{:>3} {:>7} {:>5} {:>7} | kp mm: {:>6} {:>6} {:>6} {:>6} | vertex mm: {:>6} {:>6} {:>6} {:>6} {:>6}",
        "#",
        "ms",
        "iters",
        "kp mm",
        "body",
        "face",
        "lhand",
        "rhand",
        "all",
        "body",
        "face",
        "lhand",
        "rhand"
    );
    for i in 0..n {
        let truth = person(&bones, i);
        let identity = generator.identity(&truth.shape)?;
        let posed = identity.pose(&truth.pose);
        let truth_mesh = map.map(topology, &posed.vertices);
        let targets = IkTargets::all(&set.evaluate(&truth_mesh))?;
        let mut config = IkConfig::default();
        if known_shape {
            config.initial_shape = Some(truth.shape.clone());
            config.fit_phenotype = false;
        }
        let result = solver.solve(&targets, &config)?;
        times.push(result.seconds);
        for s in &result.stages {
            *stage_time.entry(s.name).or_default() += s.seconds;
        }
        let mean_kp = result.mean_residual_mm();
        kp_mean.push(mean_kp);
        let mut sums = [0.0; 4];
        let mut counts = [0usize; 4];
        let mut total = 0.0;
        for (v, (a, b)) in result.posed.iter().zip(&truth_mesh).enumerate() {
            let d = dist_mm(*a, *b);
            let p = regions.vertex_part[v].index();
            sums[p] += d;
            counts[p] += 1;
            part_max[p] = part_max[p].max(d);
            total += d;
        }
        let part_mean: Vec<f64> = (0..4).map(|p| sums[p] / counts[p].max(1) as f64).collect();
        let all = total / truth_mesh.len() as f64;
        all_sum += all;
        for p in 0..4 {
            part_sum[p] += part_mean[p];
            group_sum[p] += result.group_mean(REPORTED[p]).unwrap_or(0.0);
        }
        let g = |k: KeypointGroup| result.group_mean(k).unwrap_or(f64::NAN);
        println!(
            "{i:>3} {:>7.1} {:>5} {:>7.3} | {:>13.3} {:>6.3} {:>6.3} {:>6.3} | {:>17.2} {:>6.2} {:>6.2} {:>6.2} {:>6.2}",
            1e3 * result.seconds,
            result.iterations,
            mean_kp,
            g(KeypointGroup::Body),
            g(KeypointGroup::Face),
            g(KeypointGroup::LeftHand),
            g(KeypointGroup::RightHand),
            all,
            part_mean[0],
            part_mean[1],
            part_mean[2],
            part_mean[3],
        );
        if verbose {
            for s in &result.stages {
                println!(
                    "      {:<10} vars {:>3} targets {:>3} iters {:>3} E {:.3e} -> {:.3e} {:.1} ms",
                    s.name,
                    s.n_variables,
                    s.n_targets,
                    s.iterations,
                    s.cost_before,
                    s.cost_after,
                    1e3 * s.seconds
                );
            }
            let tp = &truth.shape.phenotype;
            println!(
                "      phenotype fit {:.3?} truth {:.3?}",
                result.state.phenotype,
                [
                    tp.gender,
                    tp.age,
                    tp.muscle,
                    tp.weight,
                    tp.height,
                    tp.proportions
                ]
            );
        }
    }
    let nf = n as f64;
    println!(
        "median time per IK {:.1} ms (mean {:.1} ms, max {:.1} ms); mean keypoint residual \
         {:.3} mm (body {:.3}, face {:.3}, left hand {:.3}, right hand {:.3})",
        1e3 * panoman_mesh::stats::median(&mut times.clone()),
        1e3 * times.iter().sum::<f64>() / nf,
        1e3 * times.iter().copied().fold(0.0, f64::max),
        kp_mean.iter().sum::<f64>() / nf,
        group_sum[0] / nf,
        group_sum[1] / nf,
        group_sum[2] / nf,
        group_sum[3] / nf,
    );
    println!(
        "mean per-vertex error {:.2} mm: {}",
        all_sum / nf,
        Part::ALL
            .iter()
            .map(|p| format!(
                "{} {:.2} (max {:.1})",
                p.name(),
                part_sum[p.index()] / nf,
                part_max[p.index()]
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "mean time per stage: {}",
        stage_time
            .iter()
            .map(|(k, v)| format!("{k} {:.1} ms", 1e3 * v / nf))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}
