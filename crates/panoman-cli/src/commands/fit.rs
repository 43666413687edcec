//! `panoman fit` and `panoman track`: PanoMan fitted to TC-127 keypoints (+ point cloud,
//! handles, parameter edits), one frame or a sequence; `--baseline lbs` fits the LBS rig alone.

use anyhow::{Context, Result, anyhow};
use clap::{Args, ValueEnum};
use panoman::{
    FitOutput, FitReport, FitRequest, Fitter, IkStart, Method, Model, Params, Targets, Tracker,
    read_handles, read_points,
};
use panoman_fit::fit::FitOptions;
use panoman_interchange::keypoints_in::{ImportOptions, KeypointFormat, Unit};
use panoman_mesh::{TriMesh, io};
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
    for --baseline lbs) and DIR/report.json (time per stage, LM steps tried/accepted and\n\
    energies per stage, keypoint residual per group in mm, `converged` and `reason`).\n\
    Exit status: 0 a converged fit; 3 the outputs were written but the fit failed its\n\
    quality check (keypoint residual above the thresholds of docs/design/shell-fit.md §7\n\
    after retrying the initializer, or an implausible shape; a one-line warning names why);\n\
    1 an error. Handles: {\"handles\": [{\"vertex\": 123, \"position\": [x, y, z],\n\
    \"weight\": 1}]}. --params fixes α and the β blocks it gives (parameter edits).\n\n\
    Keypoints (TC-127 JSON): {\"keypoints\": {\"l_wrist\": [x, y, z], ...}, \"weights\": {\"l_wrist\": 0.5}}\n\
    in metres, any subset of the 127 names (15 body, face_00..face_69 = iBUG-68 + 2 pupils, 2x21\n\
    hand joints; full list and order in docs/formats.md §3); weights optional (default 1).\n\
    params.json: alpha (shape), beta per block (body_l, face_l, hands_l, body_a, face_a,\n\
    hands_a), translation (metres), rotation (axis-angle vector, radians).")]
pub struct FitArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Target keypoints (any subset of TC-127, metres), or OpenPose / CMU Panoptic JSON.
    #[arg(long)]
    pub keypoints: PathBuf,
    /// Layout of the keypoint files: tc127, openpose or panoptic (default: detected).
    #[arg(long)]
    pub keypoints_format: Option<KeypointFormat>,
    /// Unit of OpenPose / Panoptic coordinates: m, cm or mm.
    #[arg(long, default_value = "cm")]
    pub keypoints_unit: Unit,
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
    on β and the vertices. Writes DIR/<frame>.obj, DIR/<frame>.params.json and DIR/summary.json\n\
    (per frame: time, LM steps tried/accepted and energies per stage, keypoint residuals,\n\
    `converged`/`reason`; totals over the clip). Frames that fail the quality check are\n\
    flagged there and counted in a warning; the exit status is 0, or 3 with --strict.")]
pub struct TrackArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Directory of keypoint files (*.json), one per frame; or a directory of such sequence
    /// directories. Repeat for several sequences (each tracked in order into `--out/<name>/`).
    #[arg(long, required = true)]
    pub frames: Vec<PathBuf>,
    /// Sequences tracked in parallel (each sequence in order on one worker with its own
    /// fitter; the results are those of tracking them one by one).
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// Layout of the keypoint files: tc127, openpose or panoptic (default: detected).
    #[arg(long)]
    pub keypoints_format: Option<KeypointFormat>,
    /// Unit of OpenPose / Panoptic coordinates: m, cm or mm.
    #[arg(long, default_value = "cm")]
    pub keypoints_unit: Unit,
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
    /// Exit with status 3 when any frame fails the quality check (default: warn, exit 0).
    #[arg(long)]
    pub strict: bool,
    /// Asset directory.
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Keypoints of any supported layout (TC-127, OpenPose, CMU Panoptic; `panoman-interchange`).
fn read_keypoints(path: &Path, format: Option<KeypointFormat>, unit: Unit) -> Result<Targets> {
    let options = ImportOptions {
        unit,
        format,
        person: 0,
    };
    Ok(Targets {
        keypoints: panoman_interchange::keypoints_in::read_keypoints(path, &options)?,
        ..Default::default()
    })
}

fn write_json<T: serde::Serialize>(path: &Path, v: &T) -> Result<()> {
    crate::util::write_atomic(path, serde_json::to_string_pretty(v)? + "\n")
}

fn request(a: &FitArgs, fitter: &Fitter, model: &Model) -> Result<FitRequest> {
    let mut req = FitRequest {
        method: if a.baseline.is_some() {
            Method::Lbs
        } else {
            Method::PanoMan
        },
        keypoint_sigma: a.keypoint_sigma,
        keypoint_weight: a.keypoint_weight,
        motion_weight: a.motion_weight,
        ..Default::default()
    };
    if let Some(p) = &a.params {
        req.fixed = Some(Params::read(p, model.inner())?);
    }
    if let Some(p) = &a.motion {
        if a.baseline.is_some() {
            return Err(anyhow!(
                "--motion constrains PanoMan's β_B; it does not apply to --baseline lbs"
            ));
        }
        if model.inner().motion.is_none() {
            return Err(anyhow!(
                "{}: motion data given, but the model {} has no motion MLP",
                p.display(),
                a.model.display()
            ));
        }
        req.motion = Some(fitter.read_motion(p)?);
    }
    if !(a.motion_weight >= 0.0 && a.motion_weight.is_finite()) {
        return Err(anyhow!("--motion-weight must be a finite value ≥ 0"));
    }
    if !(a.keypoint_sigma >= 0.0 && a.keypoint_sigma.is_finite()) {
        return Err(anyhow!(
            "--keypoint-sigma must be a finite value ≥ 0 (metres)"
        ));
    }
    Ok(req)
}

fn write_params(path: &Path, out: &FitOutput, fitter: &Fitter) -> Result<()> {
    match &out.params {
        Some(p) => p.write(path)?,
        None => write_json(path, &out.rig_params.to_json(fitter.bone_names()))?,
    }
    Ok(())
}

/// Runs `panoman fit`.
pub fn run(a: FitArgs) -> Result<()> {
    let t_setup = Instant::now();
    let model = Model::load(&a.model)?;
    let mut targets = read_keypoints(&a.keypoints, a.keypoints_format, a.keypoints_unit)?;
    if let Some(h) = &a.handles {
        targets.handles = read_handles(h, model.n_vertices())?;
    }
    if let Some(p) = &a.points {
        let cloud = read_points(p)?;
        cloud
            .check_against(&targets.keypoints)
            .map_err(|e| e.in_file(p))?;
        targets.points = Some(cloud);
    }
    let mut fitter = Fitter::with_assets(&model, a.assets.as_deref())?;
    let req = request(&a, &fitter, &model)?;
    let setup_s = t_setup.elapsed().as_secs_f64();
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let mut out = fitter
        .fit(&targets, &req)
        .map_err(|e| anyhow!("{}", e.in_file(&a.keypoints)))?;
    out.report.setup_seconds = Some(setup_s);
    io::write_mesh(
        &a.out.join("mesh.obj"),
        &TriMesh::new(out.vertices.clone(), model.faces().to_vec()),
    )?;
    write_params(&a.out.join("params.json"), &out, &fitter)?;
    write_json(&a.out.join("report.json"), &out.report)?;
    print_summary(&out.report, setup_s, &a.out);
    if !out.report.converged() {
        return Err(crate::util::WarnExit {
            code: crate::util::EXIT_NOT_CONVERGED,
            message: format!(
                "{}: the fit did not converge ({}); outputs written, see report.json",
                a.out.display(),
                out.report
                    .verdict
                    .reason
                    .as_deref()
                    .unwrap_or("unknown reason")
            ),
        }
        .into());
    }
    Ok(())
}

fn print_summary(rep: &FitReport, setup_s: f64, out: &Path) {
    let groups: Vec<String> = rep
        .keypoint_residuals
        .iter()
        .map(|(k, v)| format!("{k} {:.2}", v.mean_mm))
        .collect();
    let method = match rep.method {
        Method::PanoMan => "panoman",
        Method::Lbs => "lbs",
    };
    let (tried, accepted) = rep.steps();
    let steps = if rep.method == Method::PanoMan {
        format!("; shell LM steps {accepted}/{tried} accepted")
    } else {
        String::new()
    };
    println!(
        "{}: {method} fit in {:.2} s (setup {:.2} s); keypoint residual (mm): {}{steps}",
        out.display(),
        rep.total_seconds,
        setup_s,
        groups.join(", ")
    );
}

/// Runs `panoman track`.
pub fn run_track(a: TrackArgs) -> Result<()> {
    let t_setup = Instant::now();
    let model = Model::load(&a.model)?;
    let seqs = sequences(&a.frames)?;
    if seqs.len() == 1 && a.jobs <= 1 {
        let summary = track_sequence(&a, &model, &seqs[0].1, &a.out, t_setup, None)?;
        return summary.finish(&a);
    }
    track_sequences(&a, &model, &seqs, t_setup)
}

/// The sequences of `--frames`: each directory with keypoint files (*.json) is one; a
/// directory without any is a directory of sequences (its subdirectories with keypoint
/// files, in name order). Returns (name, frame files in name order).
fn sequences(dirs: &[PathBuf]) -> Result<Vec<(String, Vec<PathBuf>)>> {
    let json_files = |d: &Path| -> Result<Vec<PathBuf>> {
        let mut f: Vec<PathBuf> = std::fs::read_dir(d)
            .with_context(|| d.display().to_string())?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "json"))
            .collect();
        f.sort();
        Ok(f)
    };
    let name_of = |d: &Path| {
        d.file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sequence".into())
    };
    let mut out = Vec::new();
    for d in dirs {
        let files = json_files(d)?;
        if !files.is_empty() {
            out.push((name_of(d), files));
            continue;
        }
        let mut subs: Vec<PathBuf> = std::fs::read_dir(d)
            .with_context(|| d.display().to_string())?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        subs.sort();
        let before = out.len();
        for s in subs {
            let files = json_files(&s)?;
            if !files.is_empty() {
                out.push((name_of(&s), files));
            }
        }
        if out.len() == before {
            return Err(anyhow!(
                "{}: no keypoint files (*.json) in the directory or its subdirectories",
                d.display()
            ));
        }
    }
    // Output directories are named after the sequences: make the names unique.
    let mut seen = std::collections::BTreeMap::<String, usize>::new();
    for (name, _) in out.iter_mut() {
        let n = seen.entry(name.clone()).or_default();
        *n += 1;
        if *n > 1 {
            *name = format!("{name}-{n}");
        }
    }
    Ok(out)
}

/// What one tracked sequence reports (its summary.json is written).
struct SequenceSummary {
    out: PathBuf,
    frames: usize,
    first_s: f64,
    warm: (f64, f64, f64),
    wall_s: f64,
    not_converged: Vec<String>,
}

impl SequenceSummary {
    /// Prints the one-line summary and the not-converged warning (an error with --strict).
    fn finish(&self, a: &TrackArgs) -> Result<()> {
        println!(
            "{}: {} frames; first {:.2} s, then median {:.0} ms per frame (min {:.0}, max {:.0}); {:.2} frames/s",
            self.out.display(),
            self.frames,
            self.first_s,
            self.warm.0 * 1e3,
            self.warm.1 * 1e3,
            self.warm.2 * 1e3,
            self.frames as f64 / self.wall_s
        );
        if !self.not_converged.is_empty() {
            let message = format!(
                "{}: {} of {} frames did not converge ({}); see not_converged_frames in summary.json",
                self.out.display(),
                self.not_converged.len(),
                self.frames,
                self.not_converged.join(", ")
            );
            if a.strict {
                return Err(crate::util::WarnExit {
                    code: crate::util::EXIT_NOT_CONVERGED,
                    message,
                }
                .into());
            }
            eprintln!("warning: {message}");
        }
        Ok(())
    }
}

/// Tracks one sequence (`frames` in order) into `out`; `t_setup` is when its setup began
/// (summary.json's `setup_seconds`). `bar`: a shared progress bar (else one of its own).
fn track_sequence(
    a: &TrackArgs,
    model: &Model,
    frames: &[PathBuf],
    out_dir: &Path,
    t_setup: Instant,
    bar: Option<&indicatif::ProgressBar>,
) -> Result<SequenceSummary> {
    let targets: Vec<Targets> = frames
        .iter()
        .map(|p| read_keypoints(p, a.keypoints_format, a.keypoints_unit))
        .collect::<Result<_>>()?;
    let req = FitRequest {
        method: if a.baseline.is_some() {
            Method::Lbs
        } else {
            Method::PanoMan
        },
        ..Default::default()
    };
    let start = if a.cold { IkStart::Cold } else { IkStart::Warm };
    let fitter = Fitter::with_assets(model, a.assets.as_deref())?;
    let mut tracker = Tracker::with_fitter(fitter, req, start);
    let setup_s = t_setup.elapsed().as_secs_f64();
    std::fs::create_dir_all(out_dir).with_context(|| out_dir.display().to_string())?;
    let own_bar = bar
        .is_none()
        .then(|| crate::util::progress_bar(frames.len() as u64, "track"));
    let Some(bar) = bar.or(own_bar.as_ref()) else {
        return Err(anyhow!("no progress bar"));
    };
    let mut rows = Vec::new();
    let mut totals = TrackTotals::default();
    for (f, (path, t)) in frames.iter().zip(&targets).enumerate() {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("{f:05}"));
        let out = tracker
            .track(t)
            .map_err(|e| anyhow!("{}", e.in_file(path)))?;
        write_params(
            &out_dir.join(format!("{stem}.params.json")),
            &out,
            tracker.fitter(),
        )?;
        io::write_mesh(
            &out_dir.join(format!("{stem}.obj")),
            &TriMesh::new(out.vertices.clone(), model.faces().to_vec()),
        )?;
        totals.add(&stem, &out.report);
        rows.push(frame_row(&stem, &out.report));
        bar.inc(1);
    }
    if let Some(b) = &own_bar {
        b.finish_and_clear();
    }
    let times: Vec<f64> = rows
        .iter()
        .map(|r| r["seconds"].as_f64().unwrap_or(0.0))
        .collect();
    let warm: Vec<f64> = times.iter().skip(1).copied().collect();
    let (med, min, max) = crate::util::median_min_max(&warm);
    let wall_s = t_setup.elapsed().as_secs_f64();
    let summary = json!({
        "method": if a.baseline.is_some() { "lbs" } else { "panoman" },
        "setup_seconds": setup_s,
        "frames": rows.len(),
        "first_frame_seconds": times[0],
        "warm_seconds": {"median": med, "min": min, "max": max},
        "wall_seconds": wall_s,
        "frames_per_second": rows.len() as f64 / wall_s,
        "steps_tried": totals.tried,
        "steps_accepted": totals.accepted,
        "frames_with_accepted_steps": totals.frames_accepting,
        "not_converged": totals.not_converged.len(),
        "not_converged_frames": totals.not_converged,
        "ik_retried": totals.retried,
        "per_frame": rows,
    });
    write_json(&out_dir.join("summary.json"), &summary)?;
    Ok(SequenceSummary {
        out: out_dir.to_path_buf(),
        frames: times.len(),
        first_s: times[0],
        warm: (med, min, max),
        wall_s,
        not_converged: totals.not_converged,
    })
}

/// Several sequences (or one with `--jobs`): `--jobs` workers each take the next sequence and
/// track it in order into `--out/<name>/`; `--out/summary.json` has the totals and the
/// throughput (frames per second of wall time, model load included).
fn track_sequences(
    a: &TrackArgs,
    model: &Model,
    seqs: &[(String, Vec<PathBuf>)],
    t_start: Instant,
) -> Result<()> {
    let jobs = a.jobs.max(1).min(seqs.len());
    let n_frames: usize = seqs.iter().map(|s| s.1.len()).sum();
    let bar = crate::util::progress_bar(n_frames as u64, "track");
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut results: Vec<Option<Result<SequenceSummary>>> = (0..seqs.len()).map(|_| None).collect();
    let slots = std::sync::Mutex::new(&mut results);
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    if i >= seqs.len() {
                        break;
                    }
                    let (name, frames) = &seqs[i];
                    let r = track_sequence(
                        a,
                        model,
                        frames,
                        &a.out.join(name),
                        Instant::now(),
                        Some(&bar),
                    );
                    let failed = r.is_err();
                    if let Ok(mut s) = slots.lock() {
                        s[i] = Some(r);
                    }
                    if failed {
                        // Stop handing out sequences after an error.
                        next.store(seqs.len(), std::sync::atomic::Ordering::Relaxed);
                    }
                }
            });
        }
    });
    bar.finish_and_clear();
    let wall_s = t_start.elapsed().as_secs_f64();
    let mut done = Vec::new();
    for (r, (name, _)) in results.into_iter().zip(seqs) {
        match r {
            Some(Ok(s)) => done.push((name, s)),
            Some(Err(e)) => return Err(e.context(format!("sequence {name}"))),
            None => {}
        }
    }
    let not_converged: usize = done.iter().map(|(_, s)| s.not_converged.len()).sum();
    let summary = json!({
        "sequences": done.iter().map(|(name, s)| json!({
            "name": name,
            "out": s.out.display().to_string(),
            "frames": s.frames,
            "first_frame_seconds": s.first_s,
            "warm_seconds": {"median": s.warm.0, "min": s.warm.1, "max": s.warm.2},
            "wall_seconds": s.wall_s,
            "not_converged": s.not_converged.len(),
        })).collect::<Vec<_>>(),
        "jobs": jobs,
        "frames": n_frames,
        "wall_seconds": wall_s,
        "frames_per_second": n_frames as f64 / wall_s,
        "not_converged": not_converged,
    });
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    write_json(&a.out.join("summary.json"), &summary)?;
    for (_, s) in &done {
        s.finish(a)?;
    }
    println!(
        "{}: {} sequences, {n_frames} frames on {jobs} workers in {wall_s:.2} s: {:.2} frames/s",
        a.out.display(),
        done.len(),
        n_frames as f64 / wall_s
    );
    Ok(())
}

/// Totals of a tracked clip for summary.json.
#[derive(Default)]
struct TrackTotals {
    tried: usize,
    accepted: usize,
    frames_accepting: usize,
    retried: usize,
    not_converged: Vec<String>,
}

impl TrackTotals {
    fn add(&mut self, stem: &str, rep: &FitReport) {
        let (t, a) = rep.steps();
        self.tried += t;
        self.accepted += a;
        self.frames_accepting += usize::from(a > 0);
        self.retried += usize::from(rep.verdict.retried);
        if !rep.converged() {
            self.not_converged.push(stem.to_string());
        }
    }
}

/// One frame of summary.json: time, the IK and shell stages (time, iterations, steps
/// tried/accepted, energies or IK costs), keypoint residuals and the quality check.
fn frame_row(stem: &str, rep: &FitReport) -> serde_json::Value {
    let mut st = serde_json::Map::new();
    st.insert("ik".into(), rep.ik.seconds.into());
    for s in &rep.stages {
        st.insert(s.name.clone(), s.seconds.into());
    }
    let (tried, accepted) = rep.steps();
    json!({"frame": stem, "seconds": rep.total_seconds, "stages": st,
           "ik_stages": rep.ik.stages, "shell_stages": rep.stages,
           "steps_tried": tried, "steps_accepted": accepted,
           "keypoint_residuals": rep.keypoint_residuals,
           "converged": rep.verdict.converged, "reason": rep.verdict.reason,
           "ik_retried": rep.verdict.retried})
}
