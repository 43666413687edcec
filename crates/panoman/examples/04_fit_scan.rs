//! 04: fit a generated person from its keypoints plus a partial, noisy point cloud (a scan
//! without its back), and compare with the keypoints-only fit.
//!
//! `cargo run --release -p panoman --example 04_fit_scan [MODEL.safetensors]`
use panoman::{FitRequest, Fitter, Generator, Model, PointCloud, Targets};

fn main() -> panoman::Result<()> {
    let path = match std::env::args().nth(1) {
        Some(p) => p.into(),
        None => panoman::training::small_model(None)?,
    };
    let model = Model::load(&path)?;
    let generator = Generator::from_model(&model)?;
    let person = r#"{"phenotype": {"gender": 0.3, "weight": 0.8, "height": 0.6},
                     "pose_euler_xyz_deg": {"upperarm01.L": [0, 0, -30], "upperleg01.L": [-20, 0, 0]}}"#;
    let truth = generator.generate(&generator.parse_params(person)?, model.output_topology()?)?;
    // The scan: every vertex on the front half (y < centre), with 2 mm of deterministic
    // pseudo-random noise (a fixed LCG, so the example prints the same numbers every run).
    let cy = truth.iter().map(|p| p[1]).sum::<f64>() / truth.len() as f64;
    let mut state = 12345u64;
    let mut noise = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.004
    };
    let scan: Vec<[f64; 3]> = truth
        .iter()
        .filter(|p| p[1] < cy)
        .map(|p| [p[0] + noise(), p[1] + noise(), p[2] + noise()])
        .collect();
    let keypoints = Targets::from_keypoints(&model.keypoints(&truth)?);
    let with_scan = Targets {
        points: Some(PointCloud {
            positions: scan.clone(),
            normals: None,
        }),
        ..keypoints.clone()
    };
    let mut fitter = Fitter::new(&model)?;
    for (what, t) in [("keypoints", &keypoints), ("keypoints + scan", &with_scan)] {
        let out = fitter.fit(t, &FitRequest::default())?;
        let e: f64 = out
            .vertices
            .iter()
            .zip(&truth)
            .map(|(a, b)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*a, *b)))
            .sum();
        println!(
            "{what:<17}: mean vertex error {:.2} mm in {:.2} s",
            1e3 * e / truth.len() as f64,
            out.report.total_seconds
        );
    }
    println!("({} scan points)", scan.len());
    Ok(())
}
