//! `panoman bench`: timings of the kernels on the real templates.

use crate::util::{add_rla_noise, median_min_max, time_runs, twist_bend_pose};
use anyhow::Result;
use clap::Args;
use panoman_human::template::{full_template, small_template};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, TriMesh, io};
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `panoman bench`.
///
/// Example: `panoman bench --json` prints lines like
/// `{"name":"g_full","median_ms":…,"min_ms":…,"max_ms":…,"runs":20}`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// One JSON object per line: name, median_ms, min_ms, max_ms, runs.
    #[arg(long)]
    pub json: bool,
    /// Timed runs per benchmark (after one warm-up run).
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

struct Reporter {
    json: bool,
}

impl Reporter {
    fn report(&self, name: &str, times: &[f64], note: &str) {
        let (med, min, max) = median_min_max(times);
        if self.json {
            println!(
                "{}",
                json!({"name": name, "median_ms": med, "min_ms": min, "max_ms": max, "runs": times.len()})
            );
        } else {
            println!(
                "{name:<16} median {med:>9.3} ms   min {min:>9.3}   max {max:>9.3}   ({} runs) {note}",
                times.len()
            );
        }
    }
}

/// Runs `panoman bench`.
pub fn run(a: BenchArgs) -> Result<()> {
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    let rep = Reporter { json: a.json };
    let runs = a.runs.max(1);
    for (tag, mesh) in [("full", &full.mesh), ("small", &small.mesh)] {
        bench_topology(&rep, tag, mesh, runs)?;
    }
    // Mesh I/O at full resolution.
    let dir = std::env::temp_dir().join(format!("panoman-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let obj = dir.join("t.obj");
    let ply = dir.join("t.ply");
    let posed = TriMesh::new(
        twist_bend_pose(&full.mesh.positions),
        full.mesh.faces.clone(),
    );
    let t = time_runs(1, runs.min(10), || {
        io::write_mesh(&obj, &posed).expect("write obj")
    });
    rep.report("obj_write_full", &t, "");
    let t = time_runs(1, runs.min(10), || {
        io::read_mesh(&obj).expect("read obj");
    });
    rep.report("obj_read_full", &t, "");
    let t = time_runs(1, runs.min(10), || {
        io::write_mesh(&ply, &posed).expect("write ply")
    });
    rep.report("ply_write_full", &t, "(binary)");
    let t = time_runs(1, runs.min(10), || {
        io::read_mesh(&ply).expect("read ply");
    });
    rep.report("ply_read_full", &t, "(binary)");
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

fn bench_topology(rep: &Reporter, tag: &str, rest: &TriMesh, runs: usize) -> Result<()> {
    let posed = twist_bend_pose(&rest.positions);
    let setup_runs = if tag == "full" { runs.min(5) } else { runs };
    let t = time_runs(0, setup_runs, || {
        let topo = Topology::build(rest.n_vertices(), &rest.faces).expect("topology");
        Reconstructor::new(&topo).expect("setup");
    });
    rep.report(
        &format!("setup_{tag}"),
        &t,
        "(topology tables + both factorizations)",
    );
    let topo = Topology::build(rest.n_vertices(), &rest.faces)?;
    let rec = Reconstructor::new(&topo)?;
    let rg = RestGeometry::new(&topo, &rest.positions)?;
    let mut rla = Rla::zeros(topo.n_edges());
    let t = time_runs(1, runs, || {
        rla.compute_into(&topo, &rg, &posed).expect("rla");
    });
    rep.report(&format!("rla_{tag}"), &t, "(RL and RA of all edges)");
    let gauge = rec.gauge_from(&rest.positions)?;
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; topo.n_vertices];
    let t = time_runs(1, runs, || {
        rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)
            .expect("g");
    });
    let it = ws.stats.pcg_iterations;
    rep.report(
        &format!("g_{tag}"),
        &t,
        &format!("(integrable RLA, {it} PCG iterations)"),
    );
    let mut noisy = rla.clone();
    add_rla_noise(&mut noisy, 0.002, 0.01, 7);
    let t = time_runs(1, runs, || {
        rec.reconstruct_rla(&mut ws, &rg, &noisy, &gauge, &mut out)
            .expect("g");
    });
    let it = ws.stats.pcg_iterations;
    rep.report(
        &format!("g_{tag}_noisy"),
        &t,
        &format!("(0.2 % length + 0.01 rad angle noise, {it} PCG iterations)"),
    );
    Ok(())
}
