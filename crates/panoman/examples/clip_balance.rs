//! Measurement tool (not a test): the eval's held-out clip (seed 0, 5 keyframes) tracked by
//! PanoMan with warm-frame options from the environment, against the LBS rig, printing the
//! mean per-vertex error (mm) and the shell LM steps tried/accepted.
//!
//! `cargo run --release -p panoman --example clip_balance -- MODEL [FRAMES]` with optional
//! `TB` (temporal β τ), `TV` (temporal vertex λ_T), `KW` (λ_K), `RET` (step retries), `IT`
//! (warm step iterations), `CB` (c_B), `MU` (initial μ), `CORR` (0: no correction MLP).
use panoman_fit::fit::{FitOptions, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Constraints, FrameSolver, LbsRig, Tracking};
use panoman_human::clip::{Clip, ClipConfig};
use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_model::model::PanoManModel;
use std::sync::Arc;

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn mean_mm(a: &[V3], b: &[V3]) -> f64 {
    1e3 * a.iter().zip(b).map(|(p, q)| norm(sub(*p, *q))).sum::<f64>() / a.len() as f64
}

/// With `HELD=DATA_DIR`: the eval's 10 held-out people from exact keypoints, cold fits with
/// `CMU` (μ₀) and `CIT` (iterations) of the cold options.
fn held_out(
    data: &str,
    model: &Arc<PanoManModel>,
    solver: &mut FrameSolver,
) -> Result<(), Box<dyn std::error::Error>> {
    let ds = panoman_human::dataset::Dataset::open(std::path::Path::new(data))?;
    let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
    let rows: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == 1 && held.contains(&ds.identity[r]))
        .collect();
    let n = rows.len().min(10);
    let d = FitOptions::default();
    let opts = FitOptions {
        mu_init: env("CMU", d.mu_init),
        step_iterations: env("CIT", d.step_iterations as f64) as usize,
        step_retries: env("RET", d.step_retries as f64) as usize,
        ..d
    };
    let (mut pm, mut lbs, mut better, mut acc) = (0.0, 0.0, 0, 0);
    for i in 0..n {
        let r = rows[i * rows.len() / n];
        let truth: Vec<V3> = ds
            .vertices(r)?
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect();
        let c =
            Constraints::from_keypoints(KeypointsFile::from_all(&model.keypoints.evaluate(&truth)));
        let (ikr, fit) = solver.fit(&c, &IkConfig::default(), &opts, None)?;
        let (p, l) = (mean_mm(&fit.vertices, &truth), mean_mm(&ikr.posed, &truth));
        pm += p / n as f64;
        lbs += l / n as f64;
        better += usize::from(p < l);
        acc += fit.report.stages.iter().map(|s| s.accepted).sum::<usize>();
    }
    println!(
        "held-out {n}: panoman {pm:.3} mm, lbs {lbs:.3} mm ({:+.2} %), lower {better}, accepted {acc}",
        100.0 * (pm / lbs - 1.0)
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let model = Arc::new(PanoManModel::load(std::path::Path::new(&args[1]))?);
    let n_frames = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(72);
    let assets = panoman_human::assets::ensure_default()?;
    let mut solver = FrameSolver::new(model.clone(), LbsRig::load(&assets, &model)?)?;
    if let Ok(data) = std::env::var("HELD") {
        return held_out(&data, &model, &mut solver);
    }
    let d = warm_fit_options();
    let warm = FitOptions {
        temporal_beta: env("TB", d.temporal_beta),
        temporal_vertex_weight: env("TV", d.temporal_vertex_weight),
        keypoint_weight: env("KW", d.keypoint_weight),
        step_retries: env("RET", d.step_retries as f64) as usize,
        step_iterations: env("IT", d.step_iterations as f64) as usize,
        c_b: env("CB", d.c_b),
        mu_init: env("MU", d.mu_init),
        correction: env("CORR", 1.0) > 0.0,
        ..d
    };
    let clip = Clip::generate(&ClipConfig {
        seed: 0,
        n_frames,
        n_keyframes: 5,
    })?;
    let rig = solver.rig();
    let (_, truths) = clip.meshes(&rig.generator, &rig.map, rig.topology)?;
    let mut seq = Tracking::new(FitOptions::default(), warm, IkConfig::default(), false);
    let mut prev: Option<IkState> = None;
    let (mut pm, mut lbs, mut init_e) = (0.0, 0.0, 0.0);
    let (mut tried, mut acc, mut retried) = (0, 0, 0);
    let mut reasons: Vec<String> = Vec::new();
    for truth in &truths {
        let c =
            Constraints::from_keypoints(KeypointsFile::from_all(&model.keypoints.evaluate(truth)));
        let (ikr, fit) = seq.fit_next(&mut solver, &c)?;
        let l = solver.ik_fit(
            &c,
            &IkConfig {
                initial_state: prev.clone(),
                ..IkConfig::default()
            },
        )?;
        if pm == 0.0 {
            println!(
                "frame 0: panoman {:.3} mm, its IK {:.3} mm",
                mean_mm(&fit.vertices, truth),
                mean_mm(&ikr.posed, truth)
            );
        }
        pm += mean_mm(&fit.vertices, truth);
        lbs += mean_mm(&l.posed, truth);
        init_e += mean_mm(&ikr.posed, truth);
        for s in &fit.report.stages {
            tried += s.iterations;
            acc += s.accepted;
        }
        prev = Some(l.state);
        retried += usize::from(fit.report.verdict.retried);
        if let Some(r) = &fit.report.verdict.reason()
            && reasons.len() < 3
        {
            reasons.push(r.clone());
        }
    }
    let n = truths.len() as f64;
    println!("{retried} retried; reasons {reasons:#?}");
    println!(
        "frames {n}: panoman {:.3} mm, its IK {:.3} mm, lbs {:.3} mm; steps {acc}/{tried} accepted",
        pm / n,
        init_e / n,
        lbs / n
    );
    Ok(())
}
