//! `panoman bench`: timings of the kernels on the real templates.

use crate::util::{SplitMix, add_rla_noise, median_min_max, time_runs, twist_bend_pose};
use anyhow::Result;
use clap::Args;
use panoman_human::assets::AssetDir;
use panoman_human::generator::{Generator, GeneratorOptions, Posed};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_human::template::{SmallTopology, Template, full_template, small_template};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, TriMesh, io};
use rayon::prelude::*;
use serde_json::json;
use std::path::PathBuf;

/// Arguments of `panoman bench`.
///
/// Example: `panoman bench --json` prints lines like
/// `{"name":"g_full","median_ms":…,"min_ms":…,"max_ms":…,"runs":20}`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman bench --json\n  # {\"name\":\"g_full\",\"median_ms\":9.8,\"min_ms\":8.9,\"max_ms\":12.0,\"runs\":20}"
)]
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
    /// A model file (`panoman train`): adds the model and fitting entries (`model_load`,
    /// `pose`, `encode`, `fit_cold`, `track_warm`, `fit_process`, `fit_scan`); without it they
    /// are skipped.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The model's dataset: `fit_cold`, `fit_process` and `fit_scan` fit its held-out body
    /// rows (the people `panoman eval` fits); without it, people drawn by the clip sampler.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Only these entries (comma-separated names, e.g. `pose,fit_cold`).
    #[arg(long, value_delimiter = ',')]
    pub only: Option<Vec<String>>,
    /// People of `fit_cold`, `fit_process` and `fit_scan` (each fitted once; ≥ 1).
    #[arg(long, default_value_t = 10)]
    pub people: usize,
    /// Frames of the `track_warm` clip (≥ 2; `panoman eval` tracks 72).
    #[arg(long, default_value_t = 72)]
    pub clip_frames: usize,
    /// Seed of the clip, the scan and the drawn people (`panoman eval`'s default is 0).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the files the fitting entries write (people's keypoints `personNN.json`, the
    /// clip's `clip/NNNNN.json`, the scans `scanNN.ply`, the `panoman fit` outputs) here,
    /// e.g. to run another build's `panoman fit` / `panoman track` on them.
    #[arg(long)]
    pub keep: Option<PathBuf>,
    /// Parameters for the `pose` entry (PanoMan params JSON) instead of the three seeded
    /// random sets, e.g. to time the same call from another binding.
    #[arg(long)]
    pub pose_params: Option<PathBuf>,
}

pub(crate) struct Reporter {
    pub(crate) json: bool,
    pub(crate) only: Option<Vec<String>>,
}

impl Reporter {
    /// Whether entry `name` is wanted (`--only`).
    pub(crate) fn wants(&self, name: &str) -> bool {
        self.only
            .as_ref()
            .is_none_or(|o| o.iter().any(|n| n == name))
    }

    /// Whether any entry whose name starts with one of `prefixes` is wanted.
    pub(crate) fn wants_prefix(&self, prefixes: &[&str]) -> bool {
        self.only
            .as_ref()
            .is_none_or(|o| o.iter().any(|n| prefixes.iter().any(|p| n.starts_with(p))))
    }

    pub(crate) fn report(&self, name: &str, times: &[f64], note: &str) {
        self.report_with(name, times, note, serde_json::Map::new());
    }

    /// [`Reporter::report`] with extra JSON fields (accuracy, throughput).
    pub(crate) fn report_with(
        &self,
        name: &str,
        times: &[f64],
        note: &str,
        extra: serde_json::Map<String, serde_json::Value>,
    ) {
        if !self.wants(name) {
            return;
        }
        let (med, min, max) = median_min_max(times);
        if self.json {
            let mut o = json!({"name": name, "median_ms": med, "min_ms": min, "max_ms": max, "runs": times.len()});
            if let Some(m) = o.as_object_mut() {
                m.extend(extra);
            }
            println!("{o}");
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
    let rep = Reporter {
        json: a.json,
        only: a.only.clone(),
    };
    let runs = a.runs.max(1);
    if rep.wants_prefix(&["setup_", "rla_", "g_", "obj_", "ply_", "gen_"]) {
        bench_kernels(&rep, &a, runs)?;
    }
    match &a.model {
        Some(m) => super::bench_fit::run(&rep, &a, m, runs)?,
        None => {
            if rep.wants_prefix(super::bench_fit::NAMES) {
                eprintln!(
                    "note: the model and fitting entries ({}) need --model M.safetensors; skipped",
                    super::bench_fit::NAMES.join(", ")
                );
            }
        }
    }
    Ok(())
}

/// The kernel entries: topology setup, RLA, `g`, mesh I/O, the generator.
fn bench_kernels(rep: &Reporter, a: &BenchArgs, runs: usize) -> Result<()> {
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    for (tag, mesh) in [("full", &full.mesh), ("small", &small.mesh)] {
        if rep.wants_prefix(&[
            &format!("setup_{tag}"),
            &format!("rla_{tag}"),
            &format!("g_{tag}"),
        ]) {
            bench_topology(rep, tag, mesh, runs)?;
        }
    }
    if rep.wants_prefix(&["obj_", "ply_"]) {
        bench_io(rep, &full, runs)?;
    }
    if rep.wants_prefix(&["gen_"]) {
        bench_generator(rep, &assets, &full, &small, runs)?;
    }
    Ok(())
}

/// Mesh I/O at full resolution.
fn bench_io(rep: &Reporter, full: &Template, runs: usize) -> Result<()> {
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
    let it = ws.stats.frame_iterations;
    rep.report(
        &format!("g_{tag}"),
        &t,
        &format!("(integrable RLA, {it} frame iterations)"),
    );
    let mut noisy = rla.clone();
    add_rla_noise(&mut noisy, 0.002, 0.01, 7);
    let t = time_runs(1, runs, || {
        rec.reconstruct_rla(&mut ws, &rg, &noisy, &gauge, &mut out)
            .expect("g");
    });
    let it = ws.stats.frame_iterations;
    rep.report(
        &format!("g_{tag}_noisy"),
        &t,
        &format!("(0.2 % length + 0.01 rad angle noise, {it} frame iterations)"),
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Generator throughput: a new identity, posing one identity onto the full template, and a
// batch of poses across all cores.

/// Uniform ranges (degrees, local Euler XYZ, left side) of docs/design/rig-and-ik.md §3.3 for the bones
/// a body-pose sampler moves; right-side bones mirror them as (x, −y, −z). A stand-in for
/// the proper pose samplers.
#[rustfmt::skip]
const POSE_RANGES: &[(&str, [(f64, f64); 3])] = &[
    ("spine05", [(-8.0, 12.0), (-8.0, 8.0), (-6.0, 6.0)]),
    ("spine04", [(-8.0, 12.0), (-8.0, 8.0), (-6.0, 6.0)]),
    ("spine03", [(-8.0, 12.0), (-8.0, 8.0), (-6.0, 6.0)]),
    ("spine02", [(-6.0, 10.0), (-8.0, 8.0), (-6.0, 6.0)]),
    ("spine01", [(-6.0, 10.0), (-8.0, 8.0), (-6.0, 6.0)]),
    ("neck01", [(-10.0, 15.0), (-15.0, 15.0), (-10.0, 10.0)]),
    ("neck02", [(-10.0, 15.0), (-15.0, 15.0), (-10.0, 10.0)]),
    ("neck03", [(-10.0, 15.0), (-15.0, 15.0), (-10.0, 10.0)]),
    ("head", [(-15.0, 20.0), (-20.0, 20.0), (-12.0, 12.0)]),
    ("jaw", [(0.0, 22.0), (-3.0, 3.0), (-4.0, 4.0)]),
    ("clavicle.L", [(-8.0, 12.0), (-5.0, 5.0), (-8.0, 15.0)]),
    ("shoulder01.L", [(-8.0, 8.0), (-5.0, 5.0), (-8.0, 12.0)]),
    ("upperarm01.L", [(-40.0, 90.0), (-45.0, 45.0), (-40.0, 90.0)]),
    ("upperarm02.L", [(0.0, 0.0), (-30.0, 30.0), (0.0, 0.0)]),
    ("lowerarm01.L", [(-35.0, 95.0), (-20.0, 20.0), (0.0, 0.0)]),
    ("lowerarm02.L", [(0.0, 0.0), (-45.0, 45.0), (0.0, 0.0)]),
    ("wrist.L", [(-20.0, 20.0), (-10.0, 10.0), (-60.0, 50.0)]),
    ("upperleg01.L", [(-90.0, 25.0), (-30.0, 30.0), (-35.0, 15.0)]),
    ("upperleg02.L", [(0.0, 0.0), (-15.0, 15.0), (0.0, 0.0)]),
    ("lowerleg01.L", [(0.0, 120.0), (-8.0, 8.0), (0.0, 0.0)]),
    ("lowerleg02.L", [(0.0, 0.0), (-10.0, 10.0), (0.0, 0.0)]),
    ("foot.L", [(-20.0, 40.0), (-10.0, 10.0), (-15.0, 15.0)]),
    ("finger1-1.L", [(-15.0, 35.0), (-15.0, 15.0), (-25.0, 25.0)]),
    ("finger1-2.L", [(0.0, 55.0), (0.0, 0.0), (-5.0, 5.0)]),
    ("finger1-3.L", [(-5.0, 75.0), (0.0, 0.0), (0.0, 0.0)]),
    ("metacarpal1.L", [(0.0, 6.0), (0.0, 0.0), (-3.0, 3.0)]),
    ("metacarpal2.L", [(0.0, 6.0), (0.0, 0.0), (-3.0, 3.0)]),
    ("metacarpal3.L", [(0.0, 8.0), (0.0, 0.0), (-3.0, 3.0)]),
    ("metacarpal4.L", [(0.0, 10.0), (0.0, 0.0), (-3.0, 3.0)]),
    ("finger2-1.L", [(-15.0, 85.0), (0.0, 0.0), (-12.0, 12.0)]),
    ("finger2-2.L", [(0.0, 100.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger2-3.L", [(0.0, 70.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger3-1.L", [(-15.0, 85.0), (0.0, 0.0), (-12.0, 12.0)]),
    ("finger3-2.L", [(0.0, 100.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger3-3.L", [(0.0, 70.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger4-1.L", [(-15.0, 85.0), (0.0, 0.0), (-12.0, 12.0)]),
    ("finger4-2.L", [(0.0, 100.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger4-3.L", [(0.0, 70.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger5-1.L", [(-15.0, 85.0), (0.0, 0.0), (-12.0, 12.0)]),
    ("finger5-2.L", [(0.0, 100.0), (0.0, 0.0), (0.0, 0.0)]),
    ("finger5-3.L", [(0.0, 70.0), (0.0, 0.0), (0.0, 0.0)]),
];

fn uniform(rng: &mut SplitMix, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
}

/// A random pose: every bone of [`POSE_RANGES`] (and its `.R` mirror) uniform in its range,
/// eyes with one shared gaze, a random turn about the vertical.
fn random_pose(bones: &[String], rng: &mut SplitMix) -> PoseParams {
    let mut euler = vec![[0.0; 3]; bones.len()];
    let index = |name: &str| bones.iter().position(|b| b == name);
    for (name, r) in POSE_RANGES {
        let mut sides = vec![(name.to_string(), [1.0, 1.0, 1.0])];
        if let Some(stem) = name.strip_suffix(".L") {
            sides.push((format!("{stem}.R"), [1.0, -1.0, -1.0]));
        }
        for (bone, sign) in sides {
            if let Some(c) = index(&bone) {
                euler[c] = std::array::from_fn(|k| sign[k] * uniform(rng, r[k].0, r[k].1));
            }
        }
    }
    let gaze = [uniform(rng, -20.0, 20.0), 0.0, uniform(rng, -30.0, 30.0)];
    for eye in ["eye.L", "eye.R"] {
        if let Some(c) = index(eye) {
            euler[c] = gaze;
        }
    }
    PoseParams {
        euler_deg: euler,
        root_rotation_z_deg: uniform(rng, -180.0, 180.0),
        root_translation: [0.0; 3],
    }
}

/// A random identity: the six default phenotype values uniform in [0, 1], 8 face units.
fn random_shape(rng: &mut SplitMix) -> ShapeParams {
    let mut shape = ShapeParams::default();
    let p = &mut shape.phenotype;
    for v in [
        &mut p.gender,
        &mut p.age,
        &mut p.muscle,
        &mut p.weight,
        &mut p.height,
        &mut p.proportions,
    ] {
        *v = uniform(rng, 0.0, 1.0);
    }
    for _ in 0..8 {
        let k = (rng.next_u64() % shape.facial_actions.len() as u64) as usize;
        shape.facial_actions[k] = uniform(rng, 0.0, 1.0);
    }
    shape
}

fn bench_generator(
    rep: &Reporter,
    assets: &AssetDir,
    full: &Template,
    small: &SmallTopology,
    runs: usize,
) -> Result<()> {
    let generator = Generator::load(assets, GeneratorOptions::default())?;
    let map = TopologyMap::new(&generator, full, small)?;
    let mut rng = SplitMix(2024);
    let shapes: Vec<ShapeParams> = (0..3).map(|_| random_shape(&mut rng)).collect();
    let poses: Vec<PoseParams> = (0..3)
        .map(|_| random_pose(generator.bone_names(), &mut rng))
        .collect();

    // A new identity: rest mesh (blendshapes), joints, rest frames.
    let mut k = 0;
    let t = time_runs(1, runs, || {
        let id = generator.identity(&shapes[k % 3]).expect("identity");
        std::hint::black_box(id.rest_vertices().len());
        k += 1;
    });
    rep.report("gen_identity", &t, "(rest mesh + joints + rest frames)");

    // Posing one identity (FK + LBS) and mapping it to the full template.
    let id = generator.identity(&shapes[0])?;
    let mut posed = Posed::default();
    let mut out = Vec::new();
    let mut k = 0;
    let t = time_runs(1, runs, || {
        id.pose_into(&poses[k % 3], &mut posed);
        map.map_into(OutputTopology::Full, &posed.vertices, &mut out);
        std::hint::black_box(out.len());
        k += 1;
    });
    rep.report("gen_pose_full", &t, "(FK + LBS + gather, one mesh)");

    // A batch of poses across all cores (time per mesh).
    const BATCH: usize = 200;
    let batch: Vec<PoseParams> = (0..BATCH)
        .map(|_| random_pose(generator.bone_names(), &mut rng))
        .collect();
    let t: Vec<f64> = time_runs(1, runs.min(10), || {
        batch.par_iter().for_each_init(
            || (Posed::default(), Vec::new()),
            |(posed, out), pose| {
                id.pose_into(pose, posed);
                map.map_into(OutputTopology::Full, &posed.vertices, out);
                std::hint::black_box(out.len());
            },
        );
    })
    .into_iter()
    .map(|ms| ms / BATCH as f64)
    .collect();
    let (med, _, _) = median_min_max(&t);
    rep.report(
        "gen_pose_full_batch",
        &t,
        &format!(
            "(per mesh; {:.0} meshes/s on {} threads, batches of {BATCH})",
            1e3 / med,
            rayon::current_num_threads()
        ),
    );
    Ok(())
}
