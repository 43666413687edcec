//! 01: load a model, pose it from parameters, encode a mesh back, and write meshes.
//!
//! `cargo run --release -p panoman --example 01_pose [MODEL.safetensors] [OUT_DIR]`
//! (default: the small example model, built on first use; output in the system temp dir).
use panoman::{BlockName, Correction, Model, Params};

fn main() -> panoman::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = match args.get(1) {
        Some(p) => p.into(),
        None => panoman::training::small_model(None)?,
    };
    let out = args
        .get(2)
        .map_or_else(|| std::env::temp_dir().join("panoman-01"), Into::into);
    std::fs::create_dir_all(&out).map_err(|source| panoman::Error::Io {
        path: out.clone(),
        source,
    })?;
    let model = Model::load(&path)?;
    println!(
        "{}: {} vertices, {} shape coefficients",
        path.display(),
        model.n_vertices(),
        model.n_shape()
    );
    for b in model.blocks() {
        println!(
            "  block {:<8} {:>4} coefficients on {:>6} edges",
            b.name.as_str(),
            b.size,
            b.n_edges
        );
    }
    // The mean shape in the mean motion, then a second person: α₀ = +2σ along shape component 0,
    // and the first body-angle component switched on.
    let mean = model.pose(&Params::default(), Correction::Apply)?;
    let mut p = Params {
        alpha: vec![0.0; model.n_shape()],
        ..Default::default()
    };
    p.alpha[0] = 2.0;
    let body_a = model
        .blocks()
        .into_iter()
        .find(|b| b.name == BlockName::BodyAngle)
        .map_or(0, |b| b.size);
    let mut beta = vec![0.0; body_a];
    if body_a > 1 {
        beta[1] = 1.0;
    }
    p.beta.insert(BlockName::BodyAngle, beta);
    let other = model.pose(&p, Correction::Apply)?;
    let height = |v: &[[f64; 3]]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), x| (l.min(x[2]), h.max(x[2])));
        hi - lo
    };
    println!(
        "mean shape {:.3} m tall, the other person {:.3} m",
        height(&mean),
        height(&other)
    );
    // Encode the second mesh (given its rest shape B_S(α)) and pose it again: the model's own
    // output comes back, up to g's least-squares rebuild.
    let q = model.encode(&other, Some(&model.rest_shape(&p.alpha)), Correction::Apply)?;
    let back = model.pose(&q, Correction::Apply)?;
    let err = back
        .iter()
        .zip(&other)
        .map(|(a, b)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*a, *b)))
        .sum::<f64>()
        / back.len() as f64;
    println!(
        "encode → pose: mean vertex distance {:.2} mm (world frame)",
        err * 1e3
    );
    for (name, v) in [
        ("mean.obj", mean),
        ("other.obj", other),
        ("reencoded.obj", back),
    ] {
        let mesh = panoman_mesh::TriMesh::new(v, model.faces().to_vec());
        panoman_mesh::io::write_mesh(&out.join(name), &mesh)?;
    }
    println!("meshes in {}", out.display());
    Ok(())
}
