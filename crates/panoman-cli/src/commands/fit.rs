//! `panoman fit` and `panoman track`: PanoMan fitted to TC-127 keypoints (+ point cloud,
//! handles, parameter edits), one frame or a sequence; `--baseline lbs` fits the LBS rig alone.

use anyhow::{Context, Result, anyhow};
use clap::{Args, ValueEnum};
use panoman_fit::fit::{FitOptions, FitResult, VertexHandle, keypoint_residuals, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkResult, IkState};
use panoman_fit::{
    Constraints, Fitter, IkIcpOptions, Rig, Sequence, fit_frame, ik_config_for_noise, ik_fit,
    ik_icp,
};
use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::{TriMesh, io};
use panoman_model::model::{PanoManModel, Params};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What is fitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Baseline {
    /// The LBS rig alone (skeletal IK with pose, phenotype and face units).
    Lbs,
}

/// Arguments of `panoman fit`.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman keypoints --mesh person.obj --out K.json\n  \
    panoman fit --model M.safetensors --keypoints K.json --out fit/\n  \
    panoman fit --model M.safetensors --keypoints K.json --points scan.ply --out fit/\n  \
    panoman fit --model M.safetensors --keypoints K.json --baseline lbs --out lbs/\n\n\
    Writes DIR/mesh.obj, DIR/params.json (α, β and the rigid motion; the rig's parameters\n\
    for --baseline lbs) and DIR/report.json (time per stage, iterations, keypoint residual\n\
    per group in mm). Handles: {\"handles\": [{\"vertex\": 123, \"position\": [x, y, z],\n\
    \"weight\": 1}]}. --params fixes α and the β blocks it gives (parameter edits).")]
pub struct FitArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Target keypoints (any subset of TC-127, metres).
    #[arg(long)]
    pub keypoints: PathBuf,
    /// A point cloud (PLY or OBJ vertices, metres) fitted by ICP after the keypoints.
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// Vertex handles (JSON).
    #[arg(long)]
    pub handles: Option<PathBuf>,
    /// Parameter edits: α and the β blocks given here are held fixed.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Fit a baseline instead of PanoMan.
    #[arg(long)]
    pub baseline: Option<Baseline>,
    /// Expected keypoint noise σ (metres, per coordinate, e.g. 0.005 for a detector): the
    /// initializer's pose, shape and expression priors grow with σ².
    #[arg(long, default_value_t = 0.0)]
    pub keypoint_sigma: f64,
    /// Keypoint weight λ_K (dimensionless).
    #[arg(long, default_value_t = FitOptions::default().keypoint_weight)]
    pub keypoint_weight: f64,
    /// Motion data θ: a generator parameter file (e.g. the params.json of `--baseline lbs`, or
    /// a mocap pose in the same layout) whose bone angles give β_B through the model's motion
    /// MLP, as a constraint on the body coefficients.
    #[arg(long)]
    pub motion: Option<PathBuf>,
    /// Weight τ_θ of the motion data (β_B ← (β_LS + τ_θ β_θ)/(1 + τ_θ) after each β-step).
    #[arg(long, default_value_t = FitOptions::default().motion_weight)]
    pub motion_weight: f64,
    /// Asset directory (default: $PANOMAN_ASSETS or the user cache).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Arguments of `panoman track`.
#[derive(Args, Debug)]
#[command(after_help = "Example:\n  \
    panoman track --model M.safetensors --frames kp_frames/ --out track/\n\n\
    Fits every *.json keypoint file of --frames in name order: the first frame cold (IK +\n\
    fit), the next ones with the IK warm-started from the previous frame and temporal terms\n\
    on β and the vertices. Writes DIR/<frame>.obj, DIR/<frame>.params.json and DIR/summary.json.")]
pub struct TrackArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Directory of keypoint files (*.json), one per frame.
    #[arg(long)]
    pub frames: PathBuf,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Fit the LBS baseline instead (IK per frame, warm-started).
    #[arg(long)]
    pub baseline: Option<Baseline>,
    /// Run the IK initializer cold on every frame instead of warm-starting it from the
    /// previous frame (slower, robust to large motion between frames).
    #[arg(long)]
    pub cold: bool,
    /// Asset directory.
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

fn read_keypoints(path: &Path) -> Result<KeypointsFile> {
    Ok(KeypointsFile::read(path)?)
}

fn read_handles(path: &Path, model: &PanoManModel) -> Result<Vec<VertexHandle>> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        handles: Vec<VertexHandle>,
    }
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let f: File = serde_json::from_str(&text)
        .map_err(|e| anyhow!("{}: not a valid handle file: {e}", path.display()))?;
    for (i, h) in f.handles.iter().enumerate() {
        if h.vertex as usize >= model.n_vertices {
            return Err(anyhow!(
                "{}: handle {i}: vertex {} out of range (the model has {} vertices)",
                path.display(),
                h.vertex,
                model.n_vertices
            ));
        }
        if !h.position.iter().all(|x| x.is_finite()) || h.weight.is_nan() || h.weight < 0.0 {
            return Err(anyhow!(
                "{}: handle {i}: non-finite position or negative weight",
                path.display()
            ));
        }
    }
    Ok(f.handles)
}

fn read_points(path: &Path) -> Result<Vec<[f64; 3]>> {
    let pts = match io::MeshFormat::from_path(path)? {
        io::MeshFormat::Ply => io::ply::read_ply_points(path)?,
        _ => io::read_mesh(path)?.positions,
    };
    if pts.is_empty() {
        return Err(anyhow!("{}: the point cloud is empty", path.display()));
    }
    if let Some(i) = pts.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(anyhow!("{}: point {i} is not finite", path.display()));
    }
    Ok(pts)
}

/// Report of the LBS baseline.
fn lbs_report(r: &IkResult, model: &PanoManModel, kp: &KeypointsFile) -> serde_json::Value {
    json!({
        "method": "lbs",
        "seconds": r.seconds,
        "stages": r.stages.iter().map(|s| json!({
            "name": s.name, "seconds": s.seconds, "iterations": s.iterations,
            "variables": s.n_variables, "cost_before": s.cost_before, "cost_after": s.cost_after,
        })).collect::<Vec<_>>(),
        "iterations": r.iterations,
        "keypoint_residuals": keypoint_residuals(model, kp, &r.posed),
    })
}

fn fit_report(ik: Option<&IkResult>, fit: &FitResult, setup_s: f64) -> serde_json::Value {
    let ik_s = ik.map_or(0.0, |r| r.seconds);
    json!({
        "method": "panoman",
        "setup_seconds": setup_s,
        "ik": ik.map(|r| json!({
            "seconds": r.seconds, "iterations": r.iterations,
            "keypoint_mean_mm": r.mean_residual_mm(),
        })),
        "stages": fit.report.stages,
        "fit_seconds": fit.report.seconds,
        "total_seconds": ik_s + fit.report.seconds,
        "keypoint_residuals": fit.report.keypoint_residuals,
    })
}

fn write_json(path: &Path, v: &serde_json::Value) -> Result<()> {
    crate::util::write_atomic(path, serde_json::to_string_pretty(v)? + "\n")
}

/// Runs `panoman fit`.
pub fn run(a: FitArgs) -> Result<()> {
    let t_setup = Instant::now();
    let model = std::sync::Arc::new(PanoManModel::load(&a.model)?);
    let kp = read_keypoints(&a.keypoints)?;
    let mut c = Constraints {
        keypoints: kp.clone(),
        ..Default::default()
    };
    if let Some(h) = &a.handles {
        c.handles = read_handles(h, &model)?;
    }
    if let Some(p) = &a.points {
        c.points = Some((read_points(p)?, None));
    }
    if let Some(p) = &a.params {
        c.fixed = Some(Params::read(p, &model)?);
    }
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let rig = Rig::load(&assets, &model)?;
    if let Some(p) = &a.motion {
        if a.baseline.is_some() {
            return Err(anyhow!(
                "--motion constrains PanoMan's β_B; it does not apply to --baseline lbs"
            ));
        }
        if model.motion.is_none() {
            return Err(anyhow!(
                "{}: motion data given, but the model {} has no motion MLP",
                p.display(),
                a.model.display()
            ));
        }
        let gp = rig.generator.read_params(p)?;
        c.motion = Some(
            rig.generator
                .bone_names()
                .iter()
                .zip(&gp.pose.euler_deg)
                .filter(|(_, e)| **e != [0.0; 3])
                .map(|(n, e)| (n.clone(), e.map(f64::to_radians)))
                .collect(),
        );
    }
    if !(a.motion_weight >= 0.0 && a.motion_weight.is_finite()) {
        return Err(anyhow!("--motion-weight must be a finite value ≥ 0"));
    }
    let ik = rig.ik_solver()?;
    let mut fitter = Fitter::new(model.clone())?;
    fitter
        .validate(&c)
        .map_err(|e| anyhow!("{}: {e}", a.keypoints.display()))?;
    if !(a.keypoint_sigma >= 0.0 && a.keypoint_sigma.is_finite()) {
        return Err(anyhow!(
            "--keypoint-sigma must be a finite value ≥ 0 (metres)"
        ));
    }
    let ikc = ik_config_for_noise(a.keypoint_sigma);
    let setup_s = t_setup.elapsed().as_secs_f64();
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let opts = FitOptions {
        keypoint_weight: a.keypoint_weight,
        motion_weight: a.motion_weight,
        ..Default::default()
    };
    match a.baseline {
        Some(Baseline::Lbs) => {
            let kerr = |e: panoman_fit::FitError| anyhow!("{}: {e}", a.keypoints.display());
            let mut r = ik_fit(&ik, &c, &ikc).map_err(kerr)?;
            if c.points.is_some() {
                // The rig fitted to the scan too (skeletal ICP), same as PanoMan's initializer.
                r = ik_icp(&rig, &ik, &c, &ikc, &r, &IkIcpOptions::default())
                    .map_err(kerr)?
                    .0;
            }
            io::write_mesh(
                &a.out.join("mesh.obj"),
                &TriMesh::new(r.posed.clone(), model.faces.clone()),
            )?;
            write_json(
                &a.out.join("params.json"),
                &r.to_json(rig.generator.bone_names()),
            )?;
            let rep = lbs_report(&r, &model, &kp);
            write_json(&a.out.join("report.json"), &rep)?;
            print_summary("lbs", r.seconds, &rep["keypoint_residuals"], &a.out);
        }
        None => {
            let (ikr, fit) = fit_frame(&rig, &ik, &mut fitter, &c, &ikc, &opts, None)
                .map_err(|e| anyhow!("{}: {e}", a.keypoints.display()))?;
            io::write_mesh(
                &a.out.join("mesh.obj"),
                &TriMesh::new(fit.vertices.clone(), model.faces.clone()),
            )?;
            fit.params.write(&a.out.join("params.json"))?;
            let rep = fit_report(Some(&ikr), &fit, setup_s);
            write_json(&a.out.join("report.json"), &rep)?;
            print_summary(
                "panoman",
                rep["total_seconds"].as_f64().unwrap_or(0.0),
                &rep["keypoint_residuals"],
                &a.out,
            );
        }
    }
    Ok(())
}

fn print_summary(method: &str, seconds: f64, res: &serde_json::Value, out: &Path) {
    let groups: Vec<String> = res
        .as_object()
        .map(|m| {
            m.iter()
                .map(|(k, v)| format!("{k} {:.2}", v["mean_mm"].as_f64().unwrap_or(f64::NAN)))
                .collect()
        })
        .unwrap_or_default();
    println!(
        "{}: {method} fit in {:.2} s; keypoint residual (mm): {}",
        out.display(),
        seconds,
        groups.join(", ")
    );
}

/// Runs `panoman track`.
pub fn run_track(a: TrackArgs) -> Result<()> {
    let model = std::sync::Arc::new(PanoManModel::load(&a.model)?);
    let mut frames: Vec<PathBuf> = std::fs::read_dir(&a.frames)
        .with_context(|| a.frames.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    frames.sort();
    if frames.is_empty() {
        return Err(anyhow!(
            "{}: no keypoint files (*.json) in the directory",
            a.frames.display()
        ));
    }
    let kps: Vec<KeypointsFile> = frames
        .iter()
        .map(|p| read_keypoints(p))
        .collect::<Result<_>>()?;
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let rig = Rig::load(&assets, &model)?;
    let ik = rig.ik_solver()?;
    let mut fitter = Fitter::new(model.clone())?;
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let bar = crate::util::progress_bar(frames.len() as u64, "track");
    let mut seq = Sequence::new(
        FitOptions::default(),
        warm_fit_options(),
        IkConfig::default(),
        a.cold,
    );
    // The LBS baseline's previous IK state (warm start).
    let mut prev_lbs: Option<IkState> = None;
    let mut rows = Vec::new();
    for (f, (path, kp)) in frames.iter().zip(&kps).enumerate() {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("{f:05}"));
        let c = Constraints {
            keypoints: kp.clone(),
            ..Default::default()
        };
        let err = |e: panoman_fit::FitError| anyhow!("{}: {e}", path.display());
        let (vertices, seconds, res, stage_s) = match a.baseline {
            Some(Baseline::Lbs) => {
                let ikc = IkConfig {
                    initial_state: if a.cold { None } else { prev_lbs.take() },
                    ..Default::default()
                };
                let r = ik_fit(&ik, &c, &ikc).map_err(err)?;
                write_json(
                    &a.out.join(format!("{stem}.params.json")),
                    &r.to_json(rig.generator.bone_names()),
                )?;
                let res = keypoint_residuals(&model, kp, &r.posed);
                prev_lbs = Some(r.state.clone());
                (r.posed, r.seconds, res, json!({"ik": r.seconds}))
            }
            None => {
                let (ikr, fit) = seq.fit_next(&rig, &ik, &mut fitter, &c).map_err(err)?;
                fit.params
                    .write(&a.out.join(format!("{stem}.params.json")))?;
                let mut st = serde_json::Map::new();
                st.insert("ik".into(), ikr.seconds.into());
                for s in &fit.report.stages {
                    st.insert(s.name.clone(), s.seconds.into());
                }
                (
                    fit.vertices,
                    ikr.seconds + fit.report.seconds,
                    fit.report.keypoint_residuals,
                    serde_json::Value::Object(st),
                )
            }
        };
        io::write_mesh(
            &a.out.join(format!("{stem}.obj")),
            &TriMesh::new(vertices, model.faces.clone()),
        )?;
        rows.push(json!({"frame": stem, "seconds": seconds, "stages": stage_s,
                         "keypoint_residuals": res}));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let times: Vec<f64> = rows
        .iter()
        .map(|r| r["seconds"].as_f64().unwrap_or(0.0))
        .collect();
    let warm: Vec<f64> = times.iter().skip(1).copied().collect();
    let (med, min, max) = crate::util::median_min_max(&warm);
    let summary = json!({
        "method": if a.baseline.is_some() { "lbs" } else { "panoman" },
        "frames": rows.len(),
        "first_frame_seconds": times[0],
        "warm_seconds": {"median": med, "min": min, "max": max},
        "per_frame": rows,
    });
    write_json(&a.out.join("summary.json"), &summary)?;
    println!(
        "{}: {} frames; first {:.2} s, then median {:.0} ms per frame (min {:.0}, max {:.0})",
        a.out.display(),
        times.len(),
        times[0],
        med * 1e3,
        min * 1e3,
        max * 1e3
    );
    Ok(())
}
