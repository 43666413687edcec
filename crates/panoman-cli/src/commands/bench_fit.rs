//! `panoman bench --model M`: the model and fitting entries, on data generated the way
//! `panoman eval` generates it (its held-out people, its clip, the scan of `scan_bench`).

use super::bench::{BenchArgs, Reporter};
use crate::util::{SplitMix, median_min_max, time_runs};
use anyhow::{Context, Result, anyhow};
use panoman::{
    Correction, FitRequest, Fitter, IkStart, Model, Params, PointCloud, Targets, Tracker,
};
use panoman_human::clip::{Clip, ClipConfig};
use panoman_human::dataset::Dataset;
use panoman_mesh::geom::{V3, norm, sub};
use serde_json::{Map, Value, json};
use std::path::Path;
use std::time::Instant;

/// The entries of this module, in the order they run.
pub(crate) const NAMES: &[&str] = &[
    "model_load",
    "pose",
    "encode",
    "fit_cold",
    "track_warm",
    "fit_process",
    "fit_scan",
];

/// Three seeded random parameter sets: α ~ N(0, 1) (unit variance on the training
/// identities), each β coefficient uniform in the middle half of its training range.
fn random_params(model: &Model, seed: u64) -> Vec<Params> {
    let mut rng = SplitMix(seed);
    let mut u = move || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    (0..3)
        .map(|_| Params {
            alpha: (0..model.n_shape())
                .map(|_| {
                    let (a, b) = (u().max(1e-300), u());
                    (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
                })
                .collect(),
            beta: panoman::BlockName::ALL
                .into_iter()
                .map(|b| {
                    let beta = model
                        .beta_range(b)
                        .iter()
                        .map(|r| {
                            let (lo, hi) = (f64::from(r[0]), f64::from(r[1]));
                            0.5 * (lo + hi) + 0.25 * (hi - lo) * (2.0 * u() - 1.0)
                        })
                        .collect();
                    (b, beta)
                })
                .collect(),
            ..Default::default()
        })
        .collect()
}

/// Runs the model and fitting entries `rep` wants on the model file `path`.
pub(crate) fn run(rep: &Reporter, a: &BenchArgs, path: &Path, runs: usize) -> Result<()> {
    if rep.wants("model_load") {
        let t = time_runs(0, runs, || {
            std::hint::black_box(Model::load(path).expect("model load"));
        });
        rep.report(
            "model_load",
            &t,
            "(read + validate + topology tables and factorizations)",
        );
    }
    let t0 = Instant::now();
    let model = Model::load(path)?;
    let load_s = t0.elapsed().as_secs_f64();
    if !rep.json {
        println!(
            "model {} ({} topology, {} vertices, loaded in {load_s:.2} s)",
            path.display(),
            model.topology_name(),
            model.n_vertices()
        );
    }
    let params = match &a.pose_params {
        Some(p) => vec![model.read_params(p)?],
        None => random_params(&model, a.seed ^ 0x5eed),
    };
    if rep.wants("pose") {
        let mut k = 0;
        let t = time_runs(1, runs, || {
            let v = model
                .pose(&params[k % params.len()], Correction::Apply)
                .expect("pose");
            std::hint::black_box(v.len());
            k += 1;
        });
        let extra = json!({"vertices": model.n_vertices(), "batch": 1});
        rep.report_with(
            "pose",
            &t,
            "(Model::pose, B = 1, correction on, random α/β: far from fitted poses, g runs long; bench.py times fitted ones)",
            obj(extra),
        );
    }
    if !rep.wants_prefix(&["encode", "fit_", "track_"]) {
        return Ok(());
    }
    let (people, rests): (Vec<Vec<V3>>, Vec<Vec<V3>>) = people(&model, a)?.into_iter().unzip();
    let dir = match &a.keep {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("panoman-bench-fit-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    let result = run_fits(rep, a, path, &model, (&people, &rests), &dir, runs);
    if a.keep.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    result
}

fn obj(v: Value) -> Map<String, Value> {
    v.as_object().cloned().unwrap_or_default()
}

/// Mean per-vertex distance (mm).
fn mean_error_mm(x: &[V3], truth: &[V3]) -> f64 {
    1e3 * x
        .iter()
        .zip(truth)
        .map(|(p, q)| norm(sub(*p, *q)))
        .sum::<f64>()
        / truth.len().max(1) as f64
}

fn mean(xs: &[f64]) -> f64 {
    xs.iter().sum::<f64>() / xs.len().max(1) as f64
}

/// The people fitted (ground-truth meshes in the model's topology): with `--data`, its
/// held-out body rows evenly spread (as `panoman eval` and `examples/scan_bench` pick them);
/// without, the first frame of the clips of seeds `seed + 1 …` (the eval clip's sampler).
/// Each with its rest shape (the identity's rest row, or the clip identity's rest mesh).
fn people(model: &Model, a: &BenchArgs) -> Result<Vec<(Vec<V3>, Vec<V3>)>> {
    let n = a.people.max(1);
    if let Some(data) = &a.data {
        let ds = Dataset::open(data)?;
        if ds.topology_hash != model.topology_hash() {
            return Err(anyhow!(
                "{}: the dataset's topology is not the model's",
                data.display()
            ));
        }
        let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
        let rows: Vec<usize> = (0..ds.n_rows)
            .filter(|&r| ds.kind[r] == 1 && held.contains(&ds.identity[r]))
            .collect();
        if rows.is_empty() {
            return Err(anyhow!("{}: no held-out body rows", data.display()));
        }
        let n = n.min(rows.len());
        let f64s = |v: Vec<[f32; 3]>| -> Vec<V3> { v.iter().map(|c| c.map(f64::from)).collect() };
        (0..n)
            .map(|i| {
                let r = rows[i * rows.len() / n];
                let rest_row = (0..ds.n_rows)
                    .find(|&q| ds.kind[q] == 0 && ds.identity[q] == ds.identity[r])
                    .ok_or_else(|| {
                        anyhow!(
                            "{}: identity {} has no rest row",
                            data.display(),
                            ds.identity[r]
                        )
                    })?;
                Ok((f64s(ds.vertices(r)?), f64s(ds.vertices(rest_row)?)))
            })
            .collect()
    } else {
        let (rig, topology) = rig_of(model)?;
        (0..n as u64)
            .map(|i| {
                let clip = Clip::generate(&ClipConfig {
                    seed: a.seed + 1 + i,
                    n_frames: 2,
                    n_keyframes: 2,
                })?;
                let (rest, mut m) = clip.meshes(&rig.generator, &rig.map, topology)?;
                Ok((m.swap_remove(0), rest))
            })
            .collect()
    }
}

/// The model's LBS rig (embedded, else from the assets) and its topology.
fn rig_of(
    model: &Model,
) -> Result<(
    std::sync::Arc<panoman_human::rigfile::RigData>,
    panoman::OutputTopology,
)> {
    let rig = match model.rig() {
        Some(r) => r.clone(),
        None => std::sync::Arc::new(panoman_human::rigfile::RigData::from_assets(
            &panoman_human::assets::ensure_default()?,
        )?),
    };
    Ok((rig, model.output_topology()?))
}

/// Writes points as an ASCII PLY point cloud (readable by `panoman fit --points`).
fn write_points(path: &Path, pts: &[V3]) -> Result<()> {
    use std::fmt::Write as _;
    let mut s = String::with_capacity(40 * pts.len() + 128);
    let _ = write!(
        s,
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
        pts.len()
    );
    for p in pts {
        let _ = writeln!(s, "{:.6} {:.6} {:.6}", p[0], p[1], p[2]);
    }
    crate::util::write_atomic(path, s)
}

fn run_fits(
    rep: &Reporter,
    a: &BenchArgs,
    path: &Path,
    model: &Model,
    (people, rests): (&[Vec<V3>], &[Vec<V3>]),
    dir: &Path,
    runs: usize,
) -> Result<()> {
    let targets: Vec<Targets> = people
        .iter()
        .map(|t| Ok(Targets::from_keypoints(&model.keypoints(t)?)))
        .collect::<Result<_>>()?;
    let source = if a.data.is_some() {
        "held-out rows"
    } else {
        "clip-sampler people"
    };
    if rep.wants("encode") {
        let mut k = 0;
        let mut errs = Vec::new();
        let t: Vec<f64> = (0..runs)
            .map(|_| {
                let (x, rest) = (&people[k % people.len()], &rests[k % people.len()]);
                let t = Instant::now();
                let p = model
                    .encode(x, Some(rest), Correction::Apply)
                    .expect("encode");
                let ms = 1e3 * t.elapsed().as_secs_f64();
                if k < people.len().min(3) {
                    let back = model.pose(&p, Correction::Apply).expect("pose");
                    errs.push(mean_error_mm(&back, x));
                }
                k += 1;
                ms
            })
            .collect();
        let e = mean(&errs);
        rep.report_with(
            "encode",
            &t,
            &format!(
                "(Model::encode with the person's rest shape, Gauss–Newton, {source}; pose(encode) error {e:.2} mm over {})",
                errs.len()
            ),
            obj(json!({"error_mm": e, "error_people": errs.len()})),
        );
    }
    let mut fitter = if rep.wants_prefix(&["fit_cold", "track_warm", "fit_scan"]) {
        Some(Fitter::new(model)?)
    } else {
        None
    };
    if rep.wants("fit_cold")
        && let Some(f) = fitter.as_mut()
    {
        // One untimed fit first (allocations, pools).
        f.fit(&targets[0], &FitRequest::default())?;
        let (mut t, mut errs, mut solve) = (Vec::new(), Vec::new(), Vec::new());
        for (x, tg) in people.iter().zip(&targets) {
            let t0 = Instant::now();
            let out = f.fit(tg, &FitRequest::default())?;
            t.push(1e3 * t0.elapsed().as_secs_f64());
            solve.push(1e3 * out.report.total_seconds);
            errs.push(mean_error_mm(&out.vertices, x));
        }
        let e = mean(&errs);
        let (sm, _, _) = median_min_max(&solve);
        rep.report_with(
            "fit_cold",
            &t,
            &format!(
                "(Fitter::fit, exact keypoints, {} {source}; mean vertex error {e:.2} mm; IK + shell median {sm:.0} ms)",
                people.len()
            ),
            obj(json!({"error_mm": e, "errors_mm": errs, "people": people.len(), "solve_median_ms": sm})),
        );
    }
    if rep.wants("track_warm")
        && let Some(f) = fitter.take()
    {
        let (rig, topology) = rig_of(model)?;
        let clip = Clip::generate(&ClipConfig {
            seed: a.seed,
            n_frames: a.clip_frames.max(2),
            n_keyframes: 5.min(a.clip_frames.max(2)),
        })?;
        let (_, truths) = clip.meshes(&rig.generator, &rig.map, topology)?;
        let frames_dir = dir.join("clip");
        std::fs::create_dir_all(&frames_dir)?;
        let mut tracker = Tracker::with_fitter(f, FitRequest::default(), IkStart::Warm);
        let (mut t, mut errs) = (Vec::new(), Vec::new());
        let mut first_ms = f64::NAN;
        // Per warm frame: the IK, each shell stage and the rest (output assembly), in ms.
        let mut stage_ms: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
        for (i, x) in truths.iter().enumerate() {
            let tg = Targets::from_keypoints(&model.keypoints(x)?);
            tg.keypoints
                .write(&frames_dir.join(format!("{i:05}.json")))?;
            let t0 = Instant::now();
            let out = tracker.track(&tg)?;
            let ms = 1e3 * t0.elapsed().as_secs_f64();
            if i == 0 {
                first_ms = ms;
            } else {
                t.push(ms);
                let r = &out.report;
                let mut add = |k: &str, v: f64| stage_ms.entry(k.into()).or_default().push(v);
                add("ik", 1e3 * r.ik.seconds);
                for st in &r.stages {
                    add(&st.name, 1e3 * st.seconds);
                }
                add("other", ms - 1e3 * (r.ik.seconds + r.fit_seconds));
            }
            errs.push(mean_error_mm(&out.vertices, x));
        }
        let e = mean(&errs);
        let stages: serde_json::Map<String, Value> = stage_ms
            .into_iter()
            .map(|(k, v)| (k, json!(crate::util::median_min_max(&v).0)))
            .collect();
        rep.report_with(
            "track_warm",
            &t,
            &format!(
                "(Tracker::track per frame after the first, {}-frame eval clip of seed {}; mean error {e:.2} mm; first frame {first_ms:.0} ms)",
                truths.len(),
                a.seed
            ),
            obj(json!({"error_mm": e, "frames": truths.len(), "first_frame_ms": first_ms,
                "seed": a.seed, "stages_median_ms": stages})),
        );
        fitter = Some(Fitter::new(model)?);
    }
    if rep.wants("fit_process") {
        let exe = std::env::current_exe()?;
        let (mut t, mut errs, mut setup) = (Vec::new(), Vec::new(), Vec::new());
        for (i, (x, tg)) in people.iter().zip(&targets).enumerate() {
            let kp = dir.join(format!("person{i:02}.json"));
            tg.keypoints.write(&kp)?;
            let out = dir.join(format!("fit{i:02}"));
            let t0 = Instant::now();
            let st = std::process::Command::new(&exe)
                .arg("fit")
                .arg("--model")
                .arg(path)
                .arg("--keypoints")
                .arg(&kp)
                .arg("--out")
                .arg(&out)
                .stdout(std::process::Stdio::null())
                .status()?;
            t.push(1e3 * t0.elapsed().as_secs_f64());
            if !(st.success() || st.code() == Some(i32::from(crate::util::EXIT_NOT_CONVERGED))) {
                return Err(anyhow!("panoman fit on {} failed: {st}", kp.display()));
            }
            let mesh = panoman_mesh::io::read_mesh(&out.join("mesh.obj"))?;
            errs.push(mean_error_mm(&mesh.positions, x));
            let r: Value =
                serde_json::from_str(&std::fs::read_to_string(out.join("report.json"))?)?;
            setup.push(1e3 * r["setup_seconds"].as_f64().unwrap_or(f64::NAN));
        }
        let e = mean(&errs);
        let (sm, _, _) = median_min_max(&setup);
        rep.report_with(
            "fit_process",
            &t,
            &format!(
                "(whole `panoman fit` process, {} {source}; mean vertex error {e:.2} mm; setup median {sm:.0} ms)",
                people.len()
            ),
            obj(json!({"error_mm": e, "people": people.len(), "setup_median_ms": sm})),
        );
    }
    if rep.wants("fit_scan")
        && let Some(f) = fitter.as_mut()
    {
        let mut rng = 12345u64;
        let (mut t, mut errs, mut kp_errs, mut npts) = (Vec::new(), Vec::new(), Vec::new(), 0);
        let mut cases = Vec::new();
        for (i, (x, tg)) in people.iter().zip(&targets).enumerate() {
            let pts = panoman_fit::icp::simulated_scan(x, model.faces(), 5000, 0.002, &mut rng);
            let x_kp_len = model.keypoint_names().len();
            // scan_bench draws (unused, zero-σ) keypoint noise here, two xorshift64 steps per
            // normal: keep its stream.
            for _ in 0..6 * x_kp_len {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
            }
            if a.keep.is_some() {
                tg.keypoints
                    .write(&dir.join(format!("person{i:02}.json")))?;
                write_points(&dir.join(format!("scan{i:02}.ply")), &pts)?;
            }
            npts = pts.len();
            let with = Targets {
                points: Some(PointCloud {
                    positions: pts,
                    normals: None,
                }),
                ..tg.clone()
            };
            let t0 = Instant::now();
            let out = f.fit(&with, &FitRequest::default())?;
            let ms = 1e3 * t0.elapsed().as_secs_f64();
            t.push(ms);
            let e = mean_error_mm(&out.vertices, x);
            errs.push(e);
            let kp = f.fit(tg, &FitRequest::default())?;
            let ke = mean_error_mm(&kp.vertices, x);
            kp_errs.push(ke);
            let ik_stages: Vec<Value> = out
                .report
                .ik
                .stages
                .iter()
                .map(|s| json!([s.name, 1e3 * s.seconds, s.iterations]))
                .collect();
            let shell_stages: Vec<Value> = out
                .report
                .stages
                .iter()
                .map(|s| json!([s.name, 1e3 * s.seconds]))
                .collect();
            cases.push(json!({"error_mm": e, "keypoints_only_mm": ke, "ms": ms,
                "ik_ms": 1e3 * out.report.ik.seconds, "ik_iterations": out.report.ik.iterations,
                "ik_stages": ik_stages, "shell_ms": 1e3 * out.report.fit_seconds,
                "shell_stages": shell_stages}));
        }
        let (e, ke) = (mean(&errs), mean(&kp_errs));
        rep.report_with(
            "fit_scan",
            &t,
            &format!(
                "(Fitter::fit, keypoints + {npts} of 5,000 scan points (2 mm noise, back 30 % cut), {} {source}; error {e:.2} mm, keypoints alone {ke:.2} mm)",
                people.len()
            ),
            obj(json!({"error_mm": e, "keypoints_only_mm": ke, "people": people.len(), "cases": cases})),
        );
    }
    Ok(())
}
