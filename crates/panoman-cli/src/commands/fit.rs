//! `panoman fit` and `panoman track`: PanoMan fitted to TC-133 keypoints (+ point cloud,
//! handles, parameter edits), one frame or a sequence; `--baseline lbs` fits the LBS rig alone.

use anyhow::{Context, Result, anyhow};
use clap::{Args, ValueEnum};
use panoman::feet::{ContactOptions, ContactPrior, FootAnchors};
use panoman::{
    FitOutput, FitReport, FitRequest, Fitter, IkStart, Method, Model, Targets, Tracker,
    read_handles, read_points,
};
use panoman_fit::fit::FitOptions;
use panoman_fit::shape_calibration::{ShapeCalibrationOptions, spread_frames};
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

/// World up axis of a keypoint sequence (`panoman track --up`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum UpAxis {
    /// +X.
    X,
    /// +Y (Y-up worlds, e.g. glTF scenes).
    Y,
    /// +Z (panoman's own frame, Vicon lab frames).
    Z,
    /// −X.
    NegX,
    /// −Y (CMU Panoptic's world, whose y points down).
    NegY,
    /// −Z.
    NegZ,
}

impl UpAxis {
    /// The unit vector.
    pub fn vector(self) -> [f64; 3] {
        match self {
            UpAxis::X => [1.0, 0.0, 0.0],
            UpAxis::Y => [0.0, 1.0, 0.0],
            UpAxis::Z => [0.0, 0.0, 1.0],
            UpAxis::NegX => [-1.0, 0.0, 0.0],
            UpAxis::NegY => [0.0, -1.0, 0.0],
            UpAxis::NegZ => [0.0, 0.0, -1.0],
        }
    }
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
    Keypoints (TC-133 JSON): {\"keypoints\": {\"l_wrist\": [x, y, z], ...}, \"weights\": {\"l_wrist\": 0.5}}\n\
    in metres, any subset of the 133 names (15 body, 6 feet: l_big_toe l_small_toe l_heel r_..., \n\
    face_00..face_69 = iBUG-68 + 2 pupils, 2x21 hand joints; full list and order in\n\
    docs/formats.md §3; TC-127 files are the same without the feet); weights optional (default 1).\n\
    params.json: alpha (shape), beta per block (body_l, face_l, hands_l, body_a, face_a,\n\
    hands_a), translation (metres), rotation (axis-angle vector, radians).")]
pub struct FitArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Target keypoints (any subset of TC-133, metres), or OpenPose / CMU Panoptic JSON.
    #[arg(long)]
    pub keypoints: PathBuf,
    /// Layout of the keypoint files: panoman (TC-133 or TC-133 names), openpose or panoptic
    /// (default: detected).
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
    flagged there and counted in a warning; the exit status is 0, or 3 with --strict.\n\n\
    After each frame the tracker state is checkpointed in DIR/track-resume/ (state.bin,\n\
    rows.jsonl); a killed run restarted with --resume goes on after the last complete frame\n\
    and gives the same files (summary.json covers every frame). One `panoman track` at a time\n\
    may write DIR (a second one fails at once).")]
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
    /// Layout of the keypoint files: panoman (TC-133 or TC-133 names), openpose or panoptic
    /// (default: detected).
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
    /// First calibrate the identity's limb and trunk lengths (MoSh's shape stage) from N
    /// frames spread over each sequence: their segment lengths (upper arm, forearm, thigh,
    /// shank, shoulder and hip width, torso) fix the rig's length controls, and the frames' mean
    /// phenotype is held, for every frame; summary.json gets `shape_calibration`. 0: the IK's
    /// six phenotype values fitted per frame.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub calibrate_shape: usize,
    /// Foot–floor contact prior (for keypoints without the foot points, e.g. TC-127): a foot
    /// whose ankle keypoint is within 2–5 cm of its lowest height in the sequence and slower
    /// than 0.25–0.6 m/s counts as planted; its sole is then held level (heel and toes at
    /// their rest heights) and its heel and toes stay where they landed. Needs --fps;
    /// summary.json gets `contacts` (docs/design/rig-and-ik.md §4.9).
    #[arg(long, requires = "fps")]
    pub contacts: bool,
    /// Frame rate of the keypoint files, Hz (the ankle speeds of --contacts).
    #[arg(long, value_name = "HZ")]
    pub fps: Option<f64>,
    /// World up axis of the keypoints (for --contacts).
    #[arg(long, value_enum, default_value = "z")]
    pub up: UpAxis,
    /// Continue an interrupted run into the same --out: skip the frames whose outputs the
    /// checkpoint in DIR/track-resume/ records as complete and go on from its tracker state
    /// (same outputs as an uninterrupted run, bit for bit); without a checkpoint, start at
    /// the first frame.
    #[arg(long)]
    pub resume: bool,
    /// Asset directory.
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Keypoints of any supported layout (panoman TC-133 or TC-127 JSON, OpenPose, CMU Panoptic;
/// `panoman-interchange`). An OpenPose BODY_25 file's foot points (big toe, small toe, heel)
/// are the layout's foot keypoints.
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
        req.fixed = Some(model.read_params(p)?);
    }
    if let Some(p) = &a.motion {
        if a.baseline.is_some() {
            return Err(anyhow!(
                "--motion constrains PanoMan's β_B; it does not apply to --baseline lbs"
            ));
        }
        if !model.has_motion() {
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
        targets.handles.extend(read_handles(h, model.n_vertices())?);
    }
    if let Some(p) = &a.points {
        let cloud = read_points(p)?;
        cloud
            .check_against(&targets.keypoints)
            .map_err(|e| panoman::Error::from(e).in_file(p))?;
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
                    .reason()
                    .unwrap_or_else(|| "unknown reason".into())
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
    /// Frames fitted by this run (all but those restored by `--resume`).
    fitted: usize,
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
            self.fitted as f64 / self.wall_s
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
    let contacts = if a.contacts {
        Some(contact_prior(a, model, frames, &targets)?)
    } else {
        None
    };
    let start = if a.cold { IkStart::Cold } else { IkStart::Warm };
    let fitter = Fitter::with_assets(model, a.assets.as_deref())?;
    let mut tracker = Tracker::with_fitter(fitter, req, start);
    tracker.set_contacts(contacts);
    let calibration = if a.calibrate_shape > 0 {
        let picked = spread_frames(targets.len(), a.calibrate_shape);
        let sel: Vec<Targets> = picked.iter().map(|&i| targets[i].clone()).collect();
        let opts = ShapeCalibrationOptions::default();
        let cal = tracker
            .calibrate_shape(&sel, &opts)
            .map_err(|e| anyhow!("shape calibration: {e}"))?;
        Some(json!({
            "frames": picked.iter().map(|&i| frames[i].display().to_string()).collect::<Vec<_>>(),
            "knobs": cal
                .knobs
                .iter()
                .map(|(k, v)| (k.name(), *v))
                .collect::<std::collections::BTreeMap<_, _>>(),
            "keypoint_error_before_mm": cal.before_mm,
            "keypoint_error_after_mm": cal.after_mm,
            "seconds": cal.seconds,
        }))
    } else {
        None
    };
    let setup_s = t_setup.elapsed().as_secs_f64();
    std::fs::create_dir_all(out_dir).with_context(|| out_dir.display().to_string())?;
    let mut resume = ResumeState::open(a, out_dir)?;
    let done = if a.resume {
        resume.restore(&mut tracker, frames)?
    } else {
        resume.reset()?;
        0
    };
    let own_bar = bar
        .is_none()
        .then(|| crate::util::progress_bar(frames.len() as u64, "track"));
    let Some(bar) = bar.or(own_bar.as_ref()) else {
        return Err(anyhow!("no progress bar"));
    };
    bar.inc(done as u64);
    let mut rows: Vec<serde_json::Value> = resume.rows.clone();
    for (f, (path, t)) in frames.iter().zip(&targets).enumerate().skip(done) {
        let stem = frame_stem(path, f);
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
        let row = frame_row(&stem, &out.report);
        resume.record(&tracker, path, &row)?;
        rows.push(row);
        bar.inc(1);
    }
    let mut totals = TrackTotals::default();
    for r in &rows {
        totals.add(r);
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
        "frames_per_second": (rows.len() - done) as f64 / wall_s,
        "resumed_after_frames": done,
        "steps_tried": totals.tried,
        "steps_accepted": totals.accepted,
        "frames_with_accepted_steps": totals.frames_accepting,
        "not_converged": totals.not_converged.len(),
        "not_converged_frames": totals.not_converged,
        "ik_retried": totals.retried,
        "shape_calibration": calibration,
        "contacts": tracker.contacts().map(|p| json!({
            "floor_ankle_height_m": p.contacts.floor,
            "frames_down": p.frames_down(),
            "weights": p.contacts.weights,
        })),
        "per_frame": rows,
    });
    write_json(&out_dir.join("summary.json"), &summary)?;
    Ok(SequenceSummary {
        out: out_dir.to_path_buf(),
        frames: times.len(),
        fitted: rows.len() - done,
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
    /// Adds one row of [`frame_row`].
    fn add(&mut self, row: &serde_json::Value) {
        let n = |k: &str| row[k].as_u64().unwrap_or(0) as usize;
        let (t, a) = (n("steps_tried"), n("steps_accepted"));
        self.tried += t;
        self.accepted += a;
        self.frames_accepting += usize::from(a > 0);
        self.retried += usize::from(row["ik_retried"].as_bool().unwrap_or(false));
        if row["converged"].as_bool() != Some(true) {
            self.not_converged
                .push(row["frame"].as_str().unwrap_or_default().to_string());
        }
    }
}

/// The output name of frame `f` read from `path`.
fn frame_stem(path: &Path, f: usize) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| format!("{f:05}"))
}

/// FNV-1a 64 of `bytes` (identifies the model and frame files of a checkpoint), hex.
fn fnv1a(bytes: &[u8]) -> String {
    format!("{:016x}", panoman_mesh::io::fnv1a(bytes))
}

/// The foot–floor contact prior of one sequence (`--contacts`), detected from its frames'
/// ankle keypoints (frame `i` at `i / fps` s); a frame without both ankles is named.
fn contact_prior(
    a: &TrackArgs,
    model: &Model,
    frames: &[PathBuf],
    targets: &[Targets],
) -> Result<ContactPrior> {
    let fps = a.fps.unwrap_or(0.0);
    for (t, p) in targets.iter().zip(frames) {
        panoman::feet::ankles(t).map_err(|name| {
            anyhow!(
                "{}: no {name} keypoint; --contacts needs both ankles in every frame",
                p.display()
            )
        })?;
    }
    let options = ContactOptions {
        up: a.up.vector(),
        ..ContactOptions::default()
    };
    ContactPrior::from_targets(model, targets, fps, &options).map_err(|e| {
        let dir = frames[0].parent().unwrap_or(Path::new("."));
        anyhow!("{}: {e}", dir.display())
    })
}

/// The foot anchors as checkpoint JSON: per foot `null` or the 9 coordinates' f64 bits (exact).
fn anchors_to_json(a: &FootAnchors) -> serde_json::Value {
    json!(a.anchors.map(|f| f.map(|p| {
        p.as_flattened()
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<u64>>()
    })))
}

/// Inverse of [`anchors_to_json`]; `None` for a malformed value. A header without anchors
/// (no --contacts) gives none.
fn anchors_from_json(v: &serde_json::Value) -> Option<FootAnchors> {
    let mut out = FootAnchors::default();
    let Some(feet) = v.as_array() else {
        return v.is_null().then_some(out);
    };
    if feet.len() != 2 {
        return None;
    }
    for (s, f) in feet.iter().enumerate() {
        if f.is_null() {
            continue;
        }
        let bits: Vec<u64> = f
            .as_array()?
            .iter()
            .map(serde_json::Value::as_u64)
            .collect::<Option<_>>()?;
        if bits.len() != 9 {
            return None;
        }
        out.anchors[s] = Some(std::array::from_fn(|k| {
            std::array::from_fn(|c| f64::from_bits(bits[3 * k + c]))
        }));
    }
    Some(out)
}

/// First bytes of DIR/track-resume/state.bin.
const RESUME_MAGIC: &[u8; 8] = b"PMTRKRS1";

/// The checkpoint of `panoman track` in DIR/track-resume/: `state.bin` (written atomically
/// after each frame's outputs: magic, a JSON header with the number of complete frames and
/// what the run depends on, then [`Tracker::checkpoint`]), `rows.jsonl` (one line per frame,
/// appended and synced before `state.bin` counts it: frame, input hash, summary row) and
/// `lock` (an exclusive lock held while the run writes DIR).
struct ResumeState {
    dir: PathBuf,
    out: PathBuf,
    /// What the run depends on besides the frames (model file, options).
    key: serde_json::Value,
    /// Summary rows of the complete frames.
    rows: Vec<serde_json::Value>,
    _lock: std::fs::File,
}

impl ResumeState {
    /// Creates DIR/track-resume/ and takes its lock.
    fn open(a: &TrackArgs, out_dir: &Path) -> Result<ResumeState> {
        let dir = out_dir.join("track-resume");
        std::fs::create_dir_all(&dir).with_context(|| {
            format!("{}: cannot create the checkpoint directory", dir.display())
        })?;
        let lock_path = dir.join("lock");
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&lock_path)
            .with_context(|| lock_path.display().to_string())?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(anyhow!(
                    "{}: another `panoman track` is writing this directory (lock {} held); \
                     wait for it or use another --out",
                    out_dir.display(),
                    lock_path.display()
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(anyhow!("{}: cannot lock: {e}", lock_path.display()));
            }
        }
        let model = std::fs::read(&a.model).with_context(|| a.model.display().to_string())?;
        let key = json!({
            "model_bytes": model.len(),
            "model_fnv": fnv1a(&model),
            "baseline": a.baseline.is_some(),
            "cold": a.cold,
            "calibrate_shape": a.calibrate_shape,
            "keypoints_format": a.keypoints_format.map(|f| format!("{f:?}")),
            "keypoints_unit": format!("{:?}", a.keypoints_unit),
            "contacts": a.contacts.then(|| json!({"fps": a.fps, "up": format!("{:?}", a.up)})),
        });
        Ok(ResumeState {
            dir,
            out: out_dir.to_path_buf(),
            key,
            rows: Vec::new(),
            _lock: lock,
        })
    }

    fn state_path(&self) -> PathBuf {
        self.dir.join("state.bin")
    }

    fn rows_path(&self) -> PathBuf {
        self.dir.join("rows.jsonl")
    }

    /// A fresh run: no checkpoint, no rows.
    fn reset(&mut self) -> Result<()> {
        match std::fs::remove_file(self.state_path()) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(anyhow!("{}: {e}", self.state_path().display())),
        }
        crate::util::write_atomic(&self.rows_path(), b"")?;
        self.rows.clear();
        Ok(())
    }

    /// `--resume`: restores the tracker from the checkpoint; returns the number of frames
    /// already complete (0 without a checkpoint, after [`ResumeState::reset`]).
    fn restore(&mut self, tracker: &mut Tracker, frames: &[PathBuf]) -> Result<usize> {
        let sp = self.state_path();
        let bytes = match std::fs::read(&sp) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                eprintln!(
                    "{}: no checkpoint to resume from; tracking from the first frame",
                    self.out.display()
                );
                self.reset()?;
                return Ok(0);
            }
            Err(e) => return Err(anyhow!("{}: {e}", sp.display())),
        };
        let bad = |what: &str| {
            anyhow!(
                "{}: cannot resume: {what}; run without --resume to start again",
                sp.display()
            )
        };
        if bytes.len() < 16 || !bytes.starts_with(RESUME_MAGIC) {
            return Err(bad("not a track checkpoint"));
        }
        let hlen = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
        let hlen = usize::try_from(hlen)
            .ok()
            .filter(|&h| h <= bytes.len() - 16)
            .ok_or_else(|| bad("truncated checkpoint"))?;
        let header: serde_json::Value = serde_json::from_slice(&bytes[16..16 + hlen])
            .map_err(|_| bad("unreadable checkpoint header"))?;
        if header["key"] != self.key {
            return Err(bad(
                "it was written with another model file or other options (--baseline, --cold, \
                 --calibrate-shape, --keypoints-format, --keypoints-unit, --contacts, --fps, \
                 --up)",
            ));
        }
        let done = header["frames_done"]
            .as_u64()
            .ok_or_else(|| bad("unreadable checkpoint header"))? as usize;
        if done > frames.len() {
            return Err(bad(&format!(
                "it records {done} frames, --frames has {}",
                frames.len()
            )));
        }
        let text = std::fs::read_to_string(self.rows_path())
            .with_context(|| self.rows_path().display().to_string())?;
        let mut rows = Vec::with_capacity(done);
        let mut kept = String::new();
        for (f, line) in text.lines().take(done).enumerate() {
            let v: serde_json::Value = serde_json::from_str(line)
                .map_err(|_| bad(&format!("line {} of rows.jsonl is damaged", f + 1)))?;
            let p = &frames[f];
            let input = std::fs::read(p).with_context(|| p.display().to_string())?;
            let stem = frame_stem(p, f);
            if v["frame"] != stem.as_str() || v["input"] != fnv1a(&input).as_str() {
                return Err(bad(&format!(
                    "frame {} ({}) is not the frame tracked there (the frames changed)",
                    f + 1,
                    p.display()
                )));
            }
            for file in [format!("{stem}.obj"), format!("{stem}.params.json")] {
                if !self.out.join(&file).is_file() {
                    return Err(bad(&format!("{file} of a checkpointed frame is missing")));
                }
            }
            rows.push(v["row"].clone());
            kept.push_str(line);
            kept.push('\n');
        }
        if rows.len() != done {
            return Err(bad("rows.jsonl has fewer frames than the checkpoint"));
        }
        let anchors = anchors_from_json(&header["anchors"])
            .ok_or_else(|| bad("unreadable foot anchors in the checkpoint header"))?;
        tracker
            .restore(&bytes[16 + hlen..])
            .map_err(|e| bad(&e.to_string()))?;
        // The contact prior is not in the tracker's checkpoint: its anchors are in the header.
        if let Some(p) = tracker.contacts() {
            let mut p = p.clone();
            p.anchors = anchors;
            p.next = done;
            tracker.set_contacts(Some(p));
        }
        // Lines after the checkpoint (a frame killed before its checkpoint) are dropped.
        crate::util::write_atomic(&self.rows_path(), kept)?;
        self.rows = rows;
        if done > 0 {
            eprintln!(
                "{}: resuming after frame {} ({done} of {} frames complete)",
                self.out.display(),
                frame_stem(&frames[done - 1], done - 1),
                frames.len()
            );
        }
        Ok(done)
    }

    /// Records a frame whose outputs are written: appends its row, then checkpoints.
    fn record(&mut self, tracker: &Tracker, path: &Path, row: &serde_json::Value) -> Result<()> {
        use std::io::Write;
        let input = std::fs::read(path).with_context(|| path.display().to_string())?;
        let line = json!({"frame": row["frame"], "input": fnv1a(&input), "row": row});
        let rp = self.rows_path();
        (|| {
            let mut f = std::fs::OpenOptions::new().append(true).open(&rp)?;
            f.write_all((serde_json::to_string(&line)? + "\n").as_bytes())?;
            f.sync_data()?;
            anyhow::Ok(())
        })()
        .with_context(|| rp.display().to_string())?;
        self.rows.push(row.clone());
        let header = serde_json::to_vec(&json!({"frames_done": self.rows.len(), "key": self.key,
            "anchors": tracker.contacts().map(|p| anchors_to_json(&p.anchors))}))?;
        let mut bytes = RESUME_MAGIC.to_vec();
        bytes.extend_from_slice(&(header.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&header);
        bytes.extend_from_slice(&tracker.checkpoint());
        crate::util::write_atomic(&self.state_path(), bytes)
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
           "converged": rep.verdict.converged, "reason": rep.verdict.reason(),
           "ik_retried": rep.verdict.retried})
}
