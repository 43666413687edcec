//! `panoman keypoints`: the TC-133 keypoints of a mesh in template topology, from the
//! template definitions (`panoman_human::keypoints`; `--model` comes with the model files).

use anyhow::{Result, anyhow};
use clap::Args;
use panoman_human::keypoints::{KeypointsFile, N_KEYPOINTS, derived_dir, load_or_build};
use panoman_human::template::{TopologyKind, full_template, small_template};
use panoman_mesh::io;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman keypoints`.
///
/// Example: `panoman keypoints --mesh posed.obj --out K.json` writes the 133 keypoints
/// (`neck`, `nose`, …, `face_00`…`face_69`, `lhand_00`…, `rhand_00`…) of a 13,348-vertex
/// mesh as `{"units": "m", "keypoints": {name: [x, y, z]}, "weights": {name: 1.0}}`.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman keypoints --mesh posed.obj --out K.json\n  \
    panoman keypoints --mesh small.ply --topology small --out K.json\n  \
    panoman render posed.obj --keypoints K.json --out kp.png\n\n\
    The mesh must be in template topology (full: 13,348 vertices, small: 1,229; e.g. from\n\
    `panoman generate --topology full`). The definitions are built once from the assets\n\
    (a few seconds) and cached next to the asset directory (`<assets>-derived/`).")]
pub struct KeypointsArgs {
    /// Mesh in template topology (.obj or .ply).
    #[arg(long)]
    pub mesh: PathBuf,
    /// Output keypoints file (JSON, metres).
    #[arg(long)]
    pub out: PathBuf,
    /// Topology of the mesh: `full` (13,348 vertices) or `small` (1,229 vertices).
    #[arg(long, default_value = "full")]
    pub topology: TopologyKind,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman keypoints`.
pub fn run(a: KeypointsArgs) -> Result<()> {
    let t0 = Instant::now();
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let mesh = io::read_mesh(&a.mesh)?;
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    let expected = match a.topology {
        TopologyKind::Full => full.mesh.n_vertices(),
        TopologyKind::Small => small.mesh.n_vertices(),
    };
    if mesh.n_vertices() != expected {
        return Err(anyhow!(
            "{}: {} vertices, but the {} template has {expected}{}",
            a.mesh.display(),
            mesh.n_vertices(),
            a.topology,
            match (a.topology, mesh.n_vertices()) {
                (TopologyKind::Full, n) if n == small.mesh.n_vertices() =>
                    " (use --topology small)",
                (TopologyKind::Small, n) if n == full.mesh.n_vertices() => " (use --topology full)",
                _ => "",
            }
        ));
    }
    let defs = load_or_build(&assets, &full, &small)?;
    let points = defs
        .set(a.topology)
        .try_evaluate(&mesh.positions)
        .map_err(|e| anyhow!("{}: {e}", a.mesh.display()))?;
    if let Some(k) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(anyhow!(
            "{}: keypoint `{}` is not finite (non-finite vertices?)",
            a.mesh.display(),
            defs.full.names[k]
        ));
    }
    KeypointsFile::from_all(&points).write(&a.out)?;
    println!(
        "{}: {N_KEYPOINTS} keypoints of {} ({} topology) in {:.0} ms (definitions cached in {})",
        a.out.display(),
        a.mesh.display(),
        a.topology,
        t0.elapsed().as_secs_f64() * 1e3,
        derived_dir(&assets).display()
    );
    Ok(())
}
