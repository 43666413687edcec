//! 02: fit PanoMan and the LBS baseline to the 133 keypoints of a generated person, and
//! compare both fits with the ground-truth mesh.
//!
//! `cargo run --release -p panoman --example 02_fit_keypoints [MODEL.safetensors]`
use panoman::{FitRequest, Fitter, Generator, Method, Model, Targets};

/// A person the model was not trained on (phenotype and pose chosen here).
pub const PERSON: &str = r#"{
  "phenotype": {"gender": 0.8, "age": 0.6, "muscle": 0.7, "weight": 0.4},
  "facial_actions": {"jawOpen": 0.3},
  "pose_euler_xyz_deg": {"upperarm01.L": [0, 0, -35], "lowerarm01.L": [45, 0, 0],
                         "upperleg01.R": [-25, 0, 0], "lowerleg01.R": [30, 0, 0]},
  "root_rotation_z_deg": 20
}"#;

fn mean_mm(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*x, *y)))
        .sum();
    1e3 * s / a.len() as f64
}

fn main() -> panoman::Result<()> {
    let path = match std::env::args().nth(1) {
        Some(p) => p.into(),
        None => panoman::training::small_model(None)?,
    };
    let model = Model::load(&path)?;
    let generator = Generator::from_model(&model)?;
    let truth = generator.generate(&generator.parse_params(PERSON)?, model.output_topology()?)?;
    let targets = Targets::from_keypoints(&model.keypoints(&truth)?);
    let mut fitter = Fitter::new(&model)?;
    println!("setup {:.2} s", fitter.setup_seconds());
    for method in [Method::PanoMan, Method::Lbs] {
        let out = fitter.fit(
            &targets,
            &FitRequest {
                method,
                ..Default::default()
            },
        )?;
        let r = &out.report;
        println!(
            "{method:?}: mean vertex error {:.2} mm; keypoint residual body {:.2} / face {:.2} mm; {:.2} s",
            mean_mm(&out.vertices, &truth),
            r.keypoint_residuals[&panoman::KeypointGroup::Body].mean_mm,
            r.keypoint_residuals[&panoman::KeypointGroup::Face].mean_mm,
            r.total_seconds
        );
        for s in &r.stages {
            println!(
                "  stage {:<10} {:>2} of {:>2} LM steps accepted, energy {:.3e} → {:.3e}",
                s.name, s.accepted, s.iterations, s.energy_start, s.energy_end
            );
        }
    }
    Ok(())
}
