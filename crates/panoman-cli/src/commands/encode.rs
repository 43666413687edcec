//! `panoman encode`: a registered mesh (template topology) → α, β (the inverse of `pose`).

use anyhow::{Result, bail};
use clap::Args;
use panoman::{Correction, Encoder, Model};
use panoman_mesh::align::aligned_error;
use panoman_mesh::geom::{norm, sub};
use panoman_mesh::io;
use std::path::PathBuf;

/// Arguments of `panoman encode`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman encode --model M.safetensors --mesh X.obj --rest R.obj --out P.json\n  panoman pose --model M.safetensors --params P.json --out X2.obj   # ≈ X.obj\n\nβ is the least-squares fit of the mesh's RL/RA refined by Gauss–Newton on the vertex error\nthrough g (the model's closest mesh); --least-squares stops after the first step."
)]
pub struct EncodeArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Mesh in the model's template topology.
    #[arg(long)]
    pub mesh: PathBuf,
    /// The identity's rest mesh (α is its PCA projection); without it α is projected from the
    /// mesh itself.
    #[arg(long)]
    pub rest: Option<PathBuf>,
    /// Output parameter file (.json).
    #[arg(long)]
    pub out: PathBuf,
    /// Ignore the correction MLP while fitting β.
    #[arg(long)]
    pub no_correction: bool,
    /// β by least squares on the mesh's RL/RA only (the best RL/RA), without the Gauss–Newton
    /// refinement on the vertex error through g (the best mesh; default).
    #[arg(long)]
    pub least_squares: bool,
}

/// Runs `panoman encode`.
pub fn run(a: EncodeArgs) -> Result<()> {
    let model = Model::load(&a.model)?;
    let check = |path: &PathBuf| -> Result<Vec<[f64; 3]>> {
        let m = io::read_mesh(path)?;
        if m.n_vertices() != model.n_vertices() || m.faces != model.faces() {
            bail!(
                "{}: not in the model's {} topology ({} vertices, {} faces; the model has {} and {})",
                path.display(),
                model.topology_name(),
                m.n_vertices(),
                m.n_faces(),
                model.n_vertices(),
                model.faces().len()
            );
        }
        Ok(m.positions)
    };
    let mesh = check(&a.mesh)?;
    let rest = a.rest.as_ref().map(check).transpose()?;
    let corr = if a.no_correction {
        Correction::Skip
    } else {
        Correction::Apply
    };
    let encoder = if a.least_squares {
        Encoder::LeastSquares
    } else {
        Encoder::VertexError
    };
    let t0 = std::time::Instant::now();
    let p = model
        .encode_with(&mesh, rest.as_deref(), corr, encoder)
        .map_err(|e| anyhow::anyhow!("{}", e.in_file(&a.mesh)))?;
    let secs = t0.elapsed().as_secs_f64();
    let back = model.pose(&p, corr)?;
    let world = back
        .iter()
        .zip(&mesh)
        .map(|(a, b)| norm(sub(*a, *b)))
        .fold((0.0f64, 0.0f64), |(mx, s), d| (mx.max(d), s + d));
    let (max, mean) = aligned_error(&back, &mesh);
    p.write(&a.out)?;
    println!(
        "{}: α {} values, β {} values ({}, {secs:.1} s; rigid placement kept); re-posed mesh \
         error mean {:.2} mm, max {:.2} mm (world frame: mean {:.2} mm, max {:.2} mm)",
        a.out.display(),
        p.alpha.len(),
        p.beta.values().map(Vec::len).sum::<usize>(),
        if a.least_squares {
            "least squares on RL/RA"
        } else {
            "Gauss–Newton on the vertex error"
        },
        mean * 1e3,
        max * 1e3,
        world.1 / mesh.len().max(1) as f64 * 1e3,
        world.0 * 1e3
    );
    Ok(())
}
