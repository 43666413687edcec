//! `panoman generate`: one Anny-equivalent mesh (phenotype, face units, local changes, pose)
//! from a parameter file, in the anny, full or small topology.

use anyhow::{Result, anyhow};
use clap::Args;
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::{OutputTopology, TopologyMap, anny_triangles};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::{TriMesh, io};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman generate`.
///
/// Example: `panoman generate --params case.json --out posed.obj --rest rest.obj
/// --topology full` writes the posed mesh and the identity's rest mesh on the 13,348-vertex
/// template. The parameter file has the layout of the reference cases
/// (`{"phenotype": {"age": 0.7}, "facial_actions": {"jawOpen": 0.4}, "local_changes": {…},
/// "pose_euler_xyz_deg": {"lowerarm01.L": [60, 0, 0]}, "root_rotation_z_deg": 30,
/// "root_translation_m": [0, 0, 0]}`); missing keys mean defaults (`{}` is the default body in
/// its rest pose).
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman generate --params case.json --out posed.obj --rest rest.obj\n  \
    panoman generate --params case.json --out posed.ply --topology full\n\n\
    case.json (every key optional; `{}` is the default body in its rest pose):\n  \
    {\"phenotype\": {\"gender\": 0.2, \"age\": 0.7}, \"facial_actions\": {\"jawOpen\": 0.4},\n   \
    \"local_changes\": {\"stomach-pregnant-incr\": -0.3},\n   \
    \"pose_euler_xyz_deg\": {\"lowerarm01.L\": [60, 0, 0]}, \"root_rotation_z_deg\": 30,\n   \
    \"root_translation_m\": [0, 0, 0]}")]
pub struct GenerateArgs {
    /// Parameter file (JSON): phenotype, facial_actions, local_changes, pose_euler_xyz_deg,
    /// root_rotation_z_deg, root_translation_m; every key optional.
    #[arg(long)]
    pub params: PathBuf,
    /// Output mesh of the posed body (.obj or .ply).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the identity's rest mesh (same topology) here.
    #[arg(long)]
    pub rest: Option<PathBuf>,
    /// Output topology: `anny` (Anny's 13,718 vertices incl. eyes and tongue), `full`
    /// (panoman's template, 13,348 vertices) or `small` (1,229 vertices).
    #[arg(long, default_value = "anny")]
    pub topology: OutputTopology,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman generate`.
pub fn run(a: GenerateArgs) -> Result<()> {
    let t0 = Instant::now();
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let generator = Generator::load(&assets, GeneratorOptions::default())?;
    let params = generator.read_params(&a.params)?;
    let in_params = |e: panoman_human::HumanError| anyhow!("{}: {e}", a.params.display());
    let map = match a.topology {
        OutputTopology::Anny => None,
        _ => {
            let full = full_template(&assets)?;
            let small = small_template(&assets, &full)?;
            Some(TopologyMap::new(&generator, &full, &small)?)
        }
    };
    let t = Instant::now();
    let identity = generator.identity(&params.shape).map_err(in_params)?;
    let posed = identity.pose(&params.pose);
    let gen_ms = t.elapsed().as_secs_f64() * 1e3;
    let faces = match &map {
        Some(m) => m.faces(a.topology).to_vec(),
        None => anny_triangles(&generator)?,
    };
    let to_mesh = |vertices: &[[f64; 3]]| {
        let positions = match &map {
            Some(m) => m.map(a.topology, vertices),
            None => vertices.to_vec(),
        };
        TriMesh::new(positions, faces.clone())
    };
    let mesh = to_mesh(&posed.vertices);
    if let Some(rest) = &a.rest {
        io::write_mesh(rest, &to_mesh(identity.rest_vertices()))?;
    }
    io::write_mesh(&a.out, &mesh)?;
    println!(
        "{}: {} topology, {} vertices, {} triangles{} (generated in {:.1} ms, {:.2} s in all)",
        a.out.display(),
        a.topology,
        mesh.n_vertices(),
        mesh.n_faces(),
        match &a.rest {
            Some(r) => format!("; rest mesh {}", r.display()),
            None => String::new(),
        },
        gen_ms,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
