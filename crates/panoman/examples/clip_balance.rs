//! Measurement tool (not a test): the eval's held-out clip (seed 0, 5 keyframes) tracked by
//! PanoMan with warm-frame options from the environment, against the LBS rig, printing the
//! mean per-vertex error (mm) and the shell LM steps tried/accepted.
//!
//! `cargo run --release -p panoman --example clip_balance -- MODEL [FRAMES]` with optional
//! `TB` (temporal β τ), `TV` (temporal vertex λ_T), `KW` (λ_K), `RET` (step retries), `IT`
//! (warm step iterations), `CB` (c_B), `MU` (initial μ), `CORR` (0: no correction MLP).
use panoman_fit::fit::{FitOptions, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Constraints, Fitter, Rig, Sequence, ik_fit};
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let model = Arc::new(PanoManModel::load(std::path::Path::new(&args[1]))?);
    let n_frames = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(72);
    let assets = panoman_human::assets::ensure_default()?;
    let rig = Rig::load(&assets, &model)?;
    let ik = rig.ik_solver()?;
    let mut fitter = Fitter::new(model.clone())?;
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
    let (_, truths) = clip.meshes(&rig.generator, &rig.map, rig.topology)?;
    let mut seq = Sequence::new(FitOptions::default(), warm, IkConfig::default(), false);
    let mut prev: Option<IkState> = None;
    let (mut pm, mut lbs, mut init_e) = (0.0, 0.0, 0.0);
    let (mut tried, mut acc, mut retried) = (0, 0, 0);
    let mut reasons: Vec<String> = Vec::new();
    for truth in &truths {
        let c = Constraints {
            keypoints: KeypointsFile::from_all(&model.keypoints.evaluate(truth)),
            ..Default::default()
        };
        let (ikr, fit) = seq.fit_next(&rig, &ik, &mut fitter, &c)?;
        let l = ik_fit(
            &ik,
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
        if retried == 0 {
            let sh = &model.shape;
            let z: Vec<String> = fit
                .params
                .alpha
                .iter()
                .zip(&sh.std_devs)
                .zip(&sh.explained_variance_ratio)
                .map(|((a, s), r)| format!("{:.1}@{:.3}", a / s, r))
                .collect();
            println!("z@evr: {}", z.join(" "));
        }
        retried += usize::from(fit.report.verdict.retried);
        if fit.report.verdict.retried && retried == 1 {
            for a in &fit.report.verdict.ik_attempts {
                println!(
                    "  {}: mean {:.2} max {:.2} chosen {} {:?}",
                    a.name, a.mean_mm, a.max_mm, a.chosen, a.problems
                );
            }
        }
        if let Some(r) = &fit.report.verdict.reason {
            if reasons.len() < 3 {
                reasons.push(r.clone());
            }
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
