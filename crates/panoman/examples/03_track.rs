//! 03: track a short generated motion (a person turning and raising an arm) from its
//! keypoints, frame after frame, with PanoMan and with the LBS baseline.
//!
//! `cargo run --release -p panoman --example 03_track [MODEL.safetensors] [FRAMES]`
use panoman::{FitRequest, Generator, IkStart, Method, Model, Targets, Tracker};

fn main() -> panoman::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = match args.get(1) {
        Some(p) => p.into(),
        None => panoman::training::small_model(None)?,
    };
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let model = Model::load(&path)?;
    let generator = Generator::from_model(&model)?;
    let frames: Vec<Vec<[f64; 3]>> = (0..n)
        .map(|f| {
            let u = f as f64 / n.max(2).saturating_sub(1) as f64;
            let json = format!(
                r#"{{"pose_euler_xyz_deg": {{"upperarm01.R": [0, 0, {:.3}], "lowerarm01.R": [{:.3}, 0, 0]}},
                    "root_rotation_z_deg": {:.3}, "root_translation_m": [{:.3}, 0, 0]}}"#,
                50.0 * u,
                40.0 * u,
                30.0 * u,
                0.2 * u
            );
            generator.generate(&generator.parse_params(&json)?, model.output_topology()?)
        })
        .collect::<panoman::Result<_>>()?;
    for method in [Method::PanoMan, Method::Lbs] {
        let mut tracker = Tracker::new(
            &model,
            FitRequest {
                method,
                ..Default::default()
            },
            IkStart::Warm,
        )?;
        let mut errs = Vec::new();
        let mut times = Vec::new();
        for truth in &frames {
            let out = tracker.track(&Targets::from_keypoints(&model.keypoints(truth)?))?;
            let e: f64 = out
                .vertices
                .iter()
                .zip(truth)
                .map(|(a, b)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*a, *b)))
                .sum::<f64>();
            errs.push(1e3 * e / truth.len() as f64);
            times.push(out.report.total_seconds);
        }
        let warm: Vec<f64> = times.iter().skip(1).copied().collect();
        println!(
            "{method:?}: {n} frames, mean vertex error {:.2} mm (worst frame {:.2}), first frame {:.2} s, warm frames {:.0} ms on average",
            errs.iter().sum::<f64>() / n as f64,
            errs.iter().fold(0.0f64, |a, &b| a.max(b)),
            times[0],
            1e3 * warm.iter().sum::<f64>() / warm.len().max(1) as f64
        );
    }
    Ok(())
}
