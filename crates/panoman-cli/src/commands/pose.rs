//! `panoman pose`: parameters → mesh through the model (B_P(α, β), Eq. 5).

use anyhow::Result;
use clap::Args;
use panoman::{Correction, Model};
use panoman_mesh::{TriMesh, io};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman pose`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman pose --model M.safetensors --params P.json --out X.obj\n  # P.json: {\"alpha\": [...], \"beta\": {\"body_l\": [...], \"body_a\": [...]}, \"translation\": [0,0,0]}"
)]
pub struct PoseArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Parameter file (missing keys are zeros; unknown keys and wrong lengths are errors).
    #[arg(long)]
    pub params: PathBuf,
    /// Output mesh (.obj or .ply).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip the correction MLP.
    #[arg(long)]
    pub no_correction: bool,
}

/// Runs `panoman pose`.
pub fn run(a: PoseArgs) -> Result<()> {
    let model = Model::load(&a.model)?;
    let params = model.read_params(&a.params)?;
    let corr = if a.no_correction {
        Correction::Skip
    } else {
        Correction::Apply
    };
    let t = Instant::now();
    let v = model
        .pose(&params, corr)
        .map_err(|e| anyhow::anyhow!("{}", e.in_file(&a.params)))?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    io::write_mesh(&a.out, &TriMesh::new(v, model.faces().to_vec()))?;
    println!(
        "{}: {} vertices, posed in {ms:.1} ms ({} correction)",
        a.out.display(),
        model.n_vertices(),
        if a.no_correction || !model.has_correction() {
            "without"
        } else {
            "with"
        }
    );
    Ok(())
}
