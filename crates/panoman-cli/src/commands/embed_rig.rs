//! `panoman embed-rig`: store the LBS rig in a model file trained before rigs were embedded,
//! so that the file alone can fit and track (no asset tree needed afterwards).

use anyhow::Result;
use clap::Args;
use panoman_model::model::PanoManModel;
use std::path::PathBuf;

/// Arguments of `panoman embed-rig`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman embed-rig --model old.safetensors --out M.safetensors\n\n\
    Models written by `panoman train` already carry the rig; this upgrades older files."
)]
pub struct EmbedRigArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Output model file (default: overwrite --model, atomically).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Asset directory (default: $PANOMAN_ASSETS or the user cache).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman embed-rig`.
pub fn run(a: EmbedRigArgs) -> Result<()> {
    let mut model = PanoManModel::load(&a.model)?;
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    panoman::training::embed_rig(&mut model, &assets)?;
    let out = a.out.unwrap_or(a.model);
    model.save(&out)?;
    println!(
        "{}: {} model with its LBS rig ({:.1} MB)",
        out.display(),
        model.topology_name,
        std::fs::metadata(&out).map_or(0.0, |m| m.len() as f64 / 1e6)
    );
    Ok(())
}
