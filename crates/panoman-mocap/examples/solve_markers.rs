//! Solves a marker capture and prints the report's figures.
//!
//! `cargo run --release -p panoman-mocap --example solve_markers -- MODEL CAPTURE [lbs|panoman] [A:B:step] [OUT]`
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
    let req = SolveRequest {
        markers: PathBuf::from(&a[2]),
        vsk: std::env::var_os("VSK").map(PathBuf::from),
        marker_map: None,
        frames: parse_frames(a.get(4).map_or("0:", String::as_str))?,
        up: None,
        options: SolveOptions {
            method,
            calibration_rounds: env("ROUNDS", 4.0) as usize,
            marker_prior_m: env("PRIOR", 0.06),
            held_out_folds: env("FOLDS", 5.0) as usize,
            pose_prior: env("POSE_PRIOR", 1e-6),
            track_iterations: env("ITERS", 8.0) as usize,
            held_out_step: env("STEP", 10.0) as usize,
            ..SolveOptions::default()
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
            "held-out mean {:.2} mm (inliers {:.2}) over {} frames/fold in {:.1}s; worst {:?}",
            h.mean,
            h.mean_inliers,
            h.frames,
            h.seconds,
            &w[..5.min(w.len())]
        );
    }
    if let Ok(p) = std::env::var("REPORT") {
        std::fs::write(p, serde_json::to_vec_pretty(&out.report)?)?;
    }
    if let Some(o) = a.get(5) {
        write_solve(std::path::Path::new(o), &out, model.faces())?;
    }
    Ok(())
}
