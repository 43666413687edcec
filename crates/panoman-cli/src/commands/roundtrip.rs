//! `panoman roundtrip`: RLA of a mesh w.r.t. a rest mesh, rebuilt by `g`.

use crate::util::{median_min_max, ms_since, time_runs};
use anyhow::{Result, bail};
use clap::Args;
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{norm, sub};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, io};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman roundtrip`.
///
/// Example: `panoman roundtrip --rest R.obj --mesh M.obj --json` prints
/// `{"max_error_m": 3e-14, "mean_error_m": …, "g_ms": …, …}`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman roundtrip --rest R.obj --mesh M.obj --json\n  # {\"max_error_m\": 6e-13, \"mean_error_m\": 3e-13, \"g_ms\": 9.1, ...}"
)]
pub struct RoundtripArgs {
    /// Rest mesh (defines the rest lengths and angles, and the gauge).
    #[arg(long)]
    pub rest: PathBuf,
    /// Mesh in the same topology as the rest mesh.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Timed repetitions of g (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Also write the reconstructed (rigidly aligned) mesh here.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `panoman roundtrip`.
pub fn run(a: RoundtripArgs) -> Result<()> {
    let rest = io::read_mesh(&a.rest)?;
    let mesh = io::read_mesh(&a.mesh)?;
    if rest.n_vertices() != mesh.n_vertices() {
        bail!(
            "{}: has {} vertices but the rest mesh {} has {}",
            a.mesh.display(),
            mesh.n_vertices(),
            a.rest.display(),
            rest.n_vertices()
        );
    }
    if rest.faces != mesh.faces {
        let f = rest.faces.iter().zip(&mesh.faces).position(|(x, y)| x != y);
        bail!(
            "{}: faces differ from the rest mesh {} ({})",
            a.mesh.display(),
            a.rest.display(),
            match f {
                Some(f) => format!("first difference at face {f}"),
                None => format!("{} vs {} faces", mesh.n_faces(), rest.n_faces()),
            }
        );
    }
    let t = Instant::now();
    let topo = Topology::build(rest.n_vertices(), &rest.faces).map_err(|e| e.in_file(&a.rest))?;
    let rec = Reconstructor::new(&topo).map_err(|e| e.in_file(&a.rest))?;
    let setup_ms = ms_since(t);
    let rg = RestGeometry::new(&topo, &rest.positions).map_err(|e| e.in_file(&a.rest))?;
    let t = Instant::now();
    let rla = Rla::compute(&topo, &rg, &mesh.positions).map_err(|e| e.in_file(&a.mesh))?;
    let rla_ms = ms_since(t);
    let gauge = rec.gauge_from(&rest.positions)?;
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; topo.n_vertices];
    let mut failure = None;
    let times = time_runs(1, a.repeat.max(1), || {
        if let Err(e) = rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out) {
            failure = Some(e);
        }
    });
    if let Some(e) = failure {
        return Err(e.into());
    }
    let (g_ms, g_min, _) = median_min_max(&times);
    let motion = rigid_align(&out, &mesh.positions, None);
    motion.apply_all(&mut out);
    let errs: Vec<f64> = out
        .iter()
        .zip(&mesh.positions)
        .map(|(x, y)| norm(sub(*x, *y)))
        .collect();
    let max = errs.iter().copied().fold(0.0, f64::max);
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    if let Some(path) = &a.out {
        io::write_mesh(
            path,
            &panoman_mesh::TriMesh::new(out.clone(), mesh.faces.clone()),
        )?;
    }
    let rl_max = rla.rl.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let ra_max = rla.ra.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if a.json {
        println!(
            "{}",
            json!({
                "rest": a.rest.display().to_string(),
                "mesh": a.mesh.display().to_string(),
                "vertices": topo.n_vertices,
                "faces": topo.n_faces(),
                "edges": topo.n_edges(),
                "max_error_m": max,
                "mean_error_m": mean,
                "g_ms": g_ms,
                "g_min_ms": g_min,
                "g_runs": times.len(),
                "setup_ms": setup_ms,
                "rla_ms": rla_ms,
                "frame_iterations": ws.stats.frame_iterations,
                "max_abs_rl": rl_max,
                "max_abs_ra": ra_max,
            })
        );
    } else {
        println!(
            "{} → g → aligned: max error {:.3e} mm, mean {:.3e} mm ({} vertices, |RL| ≤ {:.3}, |RA| ≤ {:.3} rad)",
            a.mesh.display(),
            max * 1e3,
            mean * 1e3,
            topo.n_vertices,
            rl_max,
            ra_max
        );
        println!(
            "time: g {:.1} ms (median of {}), RLA {:.1} ms, per-topology setup {:.1} ms, frame iterations {}",
            g_ms,
            times.len(),
            rla_ms,
            setup_ms,
            ws.stats.frame_iterations
        );
    }
    Ok(())
}
