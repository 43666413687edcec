//! Solves a marker capture and prints the report's figures.
//!
//! `cargo run --release -p panoman-mocap --example solve_markers -- MODEL CAPTURE [lbs|panoman] [A:B:step] [OUT]`
//!
//! Environment overrides for experiments (unset: the library's defaults): `VSK`, `ROUNDS`,
//! `PRIOR`, `FOLDS`, `POSE_PRIOR`, `TEMPORAL_PRIOR`, `PATCH_SIGMA`, `PATCH_WEIGHT`, `ITERS`, `STEP`, `RECAL`, `LAMBDA`, `CAL_FRAMES`, `SIGMA`,
//! `TRACK_ROUNDS`, `GLITCH`, `GLITCH_LOW`, `POSE_RIDGE`, `ROLL`, and of the warm shell fit `CORRECTION`, `TEMPORAL`, `HANDLE`,
//! `MU` (μ₀), `STEPS` (LM iterations per V-step), `CB` (bending weight).
use std::path::PathBuf;

use panoman_mocap::solve::SolveOptions;
use panoman_mocap::solve_run::{SolveRequest, parse_frames, solve_capture, write_solve};

fn env(k: &str, d: f64) -> f64 {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let model = panoman::Model::load(&a[1])?;
    let method = match a.get(3).map(String::as_str) {
        Some("lbs") => panoman::Method::Lbs,
        _ => panoman::Method::PanoMan,
    };
    // Every knob defaults to the library's own default (no copies of the values here).
    let d = SolveOptions::default();
    let warm = d.warm_fit.clone();
    let req = SolveRequest {
        markers: PathBuf::from(&a[2]),
        vsk: std::env::var_os("VSK").map(PathBuf::from),
        marker_map: None,
        frames: parse_frames(a.get(4).map_or("0:", String::as_str))?,
        up: None,
        options: SolveOptions {
            method,
            calibration_rounds: env("ROUNDS", d.calibration_rounds as f64) as usize,
            marker_prior_m: env("PRIOR", d.marker_prior_m),
            held_out_folds: env("FOLDS", d.held_out_folds as f64) as usize,
            pose_prior: env("POSE_PRIOR", d.pose_prior),
            temporal_prior: env("TEMPORAL_PRIOR", d.temporal_prior),
            patch_sigma_m: env("PATCH_SIGMA", d.patch_sigma_m),
            patch_weight: env("PATCH_WEIGHT", d.patch_weight),
            track_iterations: env("ITERS", d.track_iterations as f64) as usize,
            held_out_step: env("STEP", d.held_out_step as f64) as usize,
            held_out_recalibrate: env("RECAL", f64::from(u8::from(d.held_out_recalibrate))) > 0.0,
            placement_prior_weight: env("LAMBDA", d.placement_prior_weight),
            calibration_frames: env("CAL_FRAMES", d.calibration_frames as f64) as usize,
            robust_sigma_m: env("SIGMA", d.robust_sigma_m),
            track_rounds: env("TRACK_ROUNDS", d.track_rounds as f64) as usize,
            glitch_m: env("GLITCH", d.glitch_m),
            glitch_low_m: env("GLITCH_LOW", d.glitch_low_m),
            pose_placement_ridge: env("POSE_RIDGE", d.pose_placement_ridge),
            forearm_roll_deg: env("ROLL", d.forearm_roll_deg),
            warm_fit: panoman_fit::FitOptions {
                correction: env("CORRECTION", f64::from(u8::from(warm.correction))) > 0.0,
                temporal_vertex_weight: env("TEMPORAL", warm.temporal_vertex_weight),
                handle_weight: env("HANDLE", warm.handle_weight),
                mu_init: env("MU", warm.mu_init),
                step_iterations: env("STEPS", warm.step_iterations as f64) as usize,
                c_b: env("CB", warm.c_b),
                ..warm
            },
            ..d
        },
    };
    let out = solve_capture(&model, &req)?;
    let r = &out.report;
    println!(
        "{:?} frames {} residual mean {:.2} max {:.2} mm outliers {} calib {:.2}s (res {:.2} mm shift {:.1} mm) warm {:.1} ms/frame",
        r.method,
        r.n_frames,
        r.mean_residual_mm,
        r.max_residual_mm,
        r.outliers,
        out.calibration.seconds,
        out.calibration.mean_residual_mm,
        out.calibration.mean_marker_shift_mm,
        r.times["tracking_warm_ms_per_frame"]
    );
    println!("times {:?}", r.times);
    println!("jitter (m/s²) {:?}", r.jitter_m_per_s2);
    let mut w: Vec<(&String, &f64)> = r
        .per_marker_residual_mm
        .iter()
        .filter(|(_, v)| v.is_finite())
        .collect();
    w.sort_by(|x, y| y.1.total_cmp(x.1));
    println!("worst residuals {:?}", &w[..8.min(w.len())]);
    if let Some(h) = &r.held_out_marker_error_mm {
        let mut w: Vec<(&String, &f64)> = h.per_marker.iter().collect();
        w.sort_by(|x, y| y.1.total_cmp(x.1));
        println!(
            "held-out mean {:.2} mm (all {:.2}, inliers {:.2}; unobservable {:?}) over {} frames/fold in {:.1}s; worst {:?}",
            h.mean,
            h.mean_all,
            h.mean_inliers,
            h.unobservable,
            h.frames,
            h.seconds,
            &w[..5.min(w.len())]
        );
    }
    limb_lengths(&model, out.calibration.phenotype)?;
    println!("glitches {:?}", r.glitches);
    if let Ok(p) = std::env::var("REPORT") {
        std::fs::write(p, serde_json::to_vec_pretty(&out.report)?)?;
    }
    if let Some(o) = a.get(5) {
        write_solve(std::path::Path::new(o), &out, model.faces())?;
    }
    Ok(())
}

/// Prints the calibrated rig's limb lengths (mm; compare with a VSK's segment lengths).
fn limb_lengths(model: &panoman::Model, phen: [f64; 6]) -> Result<(), Box<dyn std::error::Error>> {
    let fitter = panoman::Fitter::new(model)?;
    let (rig, ik) = (fitter.solver().rig(), fitter.solver().ik());
    let names = rig.generator.bone_names().to_vec();
    let template = panoman_human::params::ShapeParams::default();
    let mut st = panoman_fit::ik::IkState::rest(names.len(), &template);
    st.phenotype = phen;
    let identity = rig.generator.identity(&ik.shape_params(&st, &template))?;
    let heads = identity.bone_heads();
    let h = |n: &str| heads[names.iter().position(|x| x == n).expect("bone")];
    let d = |a: &str, b: &str| {
        let (p, q) = (h(a), h(b));
        1e3 * ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
    };
    println!(
        "limb lengths (mm): thigh {:.0} shank {:.0} upper arm {:.0} forearm {:.0} hip width {:.0}",
        d("upperleg01.L", "lowerleg01.L"),
        d("lowerleg01.L", "foot.L"),
        d("upperarm01.L", "lowerarm01.L"),
        d("lowerarm01.L", "wrist.L"),
        d("upperleg01.L", "upperleg01.R"),
    );
    Ok(())
}
