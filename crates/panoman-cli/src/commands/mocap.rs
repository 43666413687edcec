//! `panoman mocap`: optical markers solved with PanoMan or the LBS rig, and CMU BVH motion
//! retargeted to the rig; the logic lives in `panoman-mocap` (`solve`, `solve_run`,
//! `retarget`).

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use panoman_mesh::io::write_bytes_atomically;
use panoman_mocap::markers::UpAxis;
use panoman_mocap::solve::SolveOptions;
use panoman_mocap::solve_run::{SolveRequest, parse_frames, solve_capture, write_solve};
use std::path::PathBuf;

/// `panoman mocap …`.
#[derive(Subcommand, Debug)]
pub enum MocapCommand {
    /// Solve optical markers (C3D or CSM), MoSh-style: calibration, tracking, held-out error.
    Solve(SolveArgs),
    /// Retarget a CMU BVH to the rig: generator parameters per frame + joint error.
    Retarget(RetargetArgs),
    /// Write a folder of per-frame generator parameters (solve / retarget output) as BVH.
    Export(ExportArgs),
    /// The real-capture evaluation: both marker captures and the CMU clip, PanoMan beside
    /// LBS (held-out marker error, jitter, tracking error, pictures).
    Eval(super::mocap_eval::MocapEvalArgs),
}

/// Arguments of `panoman mocap export`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman mocap export --params solve/ --model M.safetensors --fps 120 --bvh solve.bvh\n\nOne joint per rig bone (rest heads, metres), channels Zrotation Yrotation Xrotation (root also positions); the identity is the first frame's shape."
)]
pub struct ExportArgs {
    /// Output BVH.
    #[arg(long)]
    pub bvh: PathBuf,
    /// Folder of `params_*.json` generator-parameter files (name order = frame order).
    #[arg(long)]
    pub params: PathBuf,
    /// Model whose embedded rig is used (default: the rig of the assets).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Frame rate (Hz).
    #[arg(long, default_value_t = 120.0)]
    pub fps: f64,
}

/// Which model solves the markers.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum MethodArg {
    /// The LBS rig's IK as initializer, then PanoMan's shell fit.
    Panoman,
    /// The LBS rig alone.
    Lbs,
}

/// Up axis of a marker file.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum UpArg {
    /// +Y up (Vicon C3D).
    Y,
    /// +Z up (Vicon lab frame, CSM).
    Z,
}

/// Arguments of `panoman mocap solve`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman mocap solve --markers nick_freeform_001.c3d --vsk Nick01.vsk --model M.safetensors --frames 0:400:2 --out solve/\n\nWrites mesh_NNNNN.obj, params_NNNNN.json (rig), panoman_params_NNNNN.json (PanoMan), marker_map.json, pose_placement.json (how each marker's place moves with the pose) and report.json (residuals, times, held_out_marker_error_mm)."
)]
pub struct SolveArgs {
    /// Marker capture (.c3d or .csm).
    #[arg(long)]
    pub markers: PathBuf,
    /// The subject's Vicon VSK (its marker radius sets the default offsets).
    #[arg(long)]
    pub vsk: Option<PathBuf>,
    /// Marker set (anatomical rules) or placed marker map (JSON); default: the shipped set
    /// (cmu53 or plugin_gait43) that has every marker of the capture.
    #[arg(long)]
    pub marker_map: Option<PathBuf>,
    /// Model file with an embedded rig (`panoman train` output).
    #[arg(long)]
    pub model: PathBuf,
    /// PanoMan or the LBS rig.
    #[arg(long, value_enum, default_value = "panoman")]
    pub method: MethodArg,
    /// Frames A:B[:step] (B exclusive, empty = to the end).
    #[arg(long, default_value = "0:")]
    pub frames: String,
    /// Up axis when the file does not record it (default: detected from head/foot markers).
    #[arg(long, value_enum)]
    pub up: Option<UpArg>,
    /// Folds of the held-out marker error (0: skip it).
    #[arg(long, default_value_t = 5)]
    pub folds: usize,
    /// Every this many solved frames are tracked per held-out fold (1: every frame, as the
    /// solve tracks; 10 takes a tenth of the time and measures a tenth of the frames).
    #[arg(long, default_value_t = 1)]
    pub held_out_step: usize,
    /// Calibration frames (spread over the solved range; default: `SolveOptions`, 64).
    #[arg(long)]
    pub calibration_frames: Option<usize>,
    /// Pose / marker-placement rounds of the calibration (default: `SolveOptions`, 12).
    #[arg(long)]
    pub calibration_rounds: Option<usize>,
    /// Capture-glitch threshold in metres (markers that leave their rigid neighbours by
    /// more are treated as missing; 0 keeps every observation; default: `SolveOptions`).
    #[arg(long)]
    pub glitch_m: Option<f64>,
    /// Lower capture-glitch threshold in metres: a glitch run goes on while the marker stays
    /// this far from its rigid neighbours (hysteresis; default: `SolveOptions`, 0.02; a value
    /// at or above the threshold turns it off).
    #[arg(long)]
    pub glitch_low_m: Option<f64>,
    /// Ridge λ (rad²) of the pose-dependent marker placements: each marker's surface point
    /// moves linearly with the angles of the bones around it, fitted in the calibration
    /// (default: `SolveOptions`, 0.05; 0: one fixed surface point per marker).
    #[arg(long)]
    pub pose_placement_ridge: Option<f64>,
    /// The forearm's roll range of the IK, ±degrees (default: `SolveOptions`, 90, the
    /// forearm's pronation and supination; 0: the model sampler's ±30°).
    #[arg(long)]
    pub forearm_roll_deg: Option<f64>,
    /// Weight λ_T (m²) of the tracking's temporal prior on the rig's bone angles (toward the
    /// previous frame's; default: `SolveOptions`, 3e-4; 0: none): less jitter, a little lag.
    #[arg(long)]
    pub temporal_prior: Option<f64>,
    /// PanoMan: σ in metres of each marker's surface patch, which the shell fit pulls with
    /// the marker (default: `SolveOptions`, 0.08; 0: the marker's triangle only).
    #[arg(long)]
    pub patch_sigma: Option<f64>,
    /// Calibrate each held-out fold anew without its markers (stricter than MoSh's
    /// protocol, which calibrates once with every marker and holds markers out of the
    /// per-frame solve: the default).
    #[arg(long)]
    pub held_out_recalibrate: bool,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `panoman mocap retarget`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman mocap retarget --bvh 01_01.bvh --model M.safetensors --out retarget/\n  panoman mocap retarget --bvh 01_01.bvh --model M.safetensors --track 0::4 --out retarget/\n  panoman mocap retarget --bvh 01_01.bvh --model M.safetensors --track 0::4 --no-feet --contacts --out retarget-tc127/\n  panoman mocap retarget --bvh 01_01.bvh --model M.safetensors --track 0::4 --calibrate-shape 8 --out retarget-cal/\n\nWrites params_NNNNN.json (generator parameters, usable by `generate` and `fit --motion`) and summary.json (joint error vs the BVH's forward kinematics). With --track, the selected frames' meshes are generated by the model's rig, tracked from their TC-133 keypoints (with --no-feet the TC-127 ones, without the six foot points) with PanoMan and the LBS baseline, and track.json gets the per-vertex errors (mm) and times (ms) per frame and their statistics; worst_{truth,panoman,lbs}.obj are PanoMan's worst frame."
)]
pub struct RetargetArgs {
    /// CMU BVH (31 joints, frame 0 a T-pose).
    #[arg(long)]
    pub bvh: PathBuf,
    /// Model whose embedded rig is used (default: the rig of the assets).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Frames of the shape fit, spread over the clip (0: default identity).
    #[arg(long, default_value_t = 24)]
    pub shape_frames: usize,
    /// Also track frames A:B[:step] (B exclusive, empty = to the end) from the TC-133
    /// keypoints of their generated meshes, PanoMan and LBS (needs --model); writes track.json.
    #[arg(long, value_name = "A:B:STEP")]
    pub track: Option<String>,
    /// With --track: drop the six foot keypoints (big toe, little toe and heel of each foot)
    /// from the targets, i.e. track from the older TC-127 layout, which stops at the ankles.
    #[arg(long, requires = "track")]
    pub no_feet: bool,
    /// With --track: the foot–floor contact prior — feet detected as planted from their
    /// ankle keypoints (within 2–5 cm of the ankle's floor level and slower than
    /// 0.25–0.6 m/s) get their soles held level (heel and toes at their rest heights) by the
    /// IK. No observation beyond TC-127.
    #[arg(long, requires = "track")]
    pub contacts: bool,
    /// With --track: first calibrate the identity's limb and trunk lengths from the
    /// keypoints of N frames spread over the tracked ones; both trackers
    /// then hold them (0: none, the IK's six phenotype values only).
    #[arg(long, value_name = "N", default_value_t = 0, requires = "track")]
    pub calibrate_shape: usize,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `panoman mocap …`.
pub fn run(c: MocapCommand) -> Result<()> {
    match c {
        MocapCommand::Solve(a) => run_solve(a),
        MocapCommand::Retarget(a) => run_retarget(a),
        MocapCommand::Export(a) => run_export(a),
        MocapCommand::Eval(a) => super::mocap_eval::run(a),
    }
}

fn generator_of(
    model: Option<&std::path::Path>,
) -> Result<std::sync::Arc<panoman_human::generator::Generator>> {
    Ok(match model {
        Some(m) => {
            let model = panoman::Model::load(m)?;
            match model.rig() {
                Some(r) => r.generator.clone(),
                None => bail!("{}: the model has no embedded rig", m.display()),
            }
        }
        None => std::sync::Arc::new(panoman_human::generator::Generator::load_default()?),
    })
}

fn run_export(a: ExportArgs) -> Result<()> {
    if !(a.fps > 0.0 && a.fps.is_finite()) {
        bail!("--fps {} must be > 0", a.fps);
    }
    let generator = generator_of(a.model.as_deref())?;
    let mut files: Vec<PathBuf> = std::fs::read_dir(&a.params)
        .with_context(|| a.params.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("params_") && n.ends_with(".json"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{}: no params_*.json files", a.params.display());
    }
    let params = files
        .iter()
        .map(|p| generator.read_params(p))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    let identity = generator.identity(&params[0].shape)?;
    let poses: Vec<_> = params.into_iter().map(|p| p.pose).collect();
    let bvh = panoman_mocap::bvh_export::rig_motion_bvh(&identity, &poses, 1.0 / a.fps)?;
    bvh.write(&a.bvh)?;
    println!(
        "{} frames, {} joints → {}",
        poses.len(),
        bvh.joints.len(),
        a.bvh.display()
    );
    Ok(())
}

fn run_solve(a: SolveArgs) -> Result<()> {
    let model = panoman::Model::load(&a.model)?;
    let d = SolveOptions::default();
    let req = SolveRequest {
        markers: a.markers.clone(),
        vsk: a.vsk.clone(),
        marker_map: a.marker_map.clone(),
        frames: parse_frames(&a.frames)?,
        up: a.up.map(|u| match u {
            UpArg::Y => UpAxis::Y,
            UpArg::Z => UpAxis::Z,
        }),
        options: SolveOptions {
            method: match a.method {
                MethodArg::Panoman => panoman::Method::PanoMan,
                MethodArg::Lbs => panoman::Method::Lbs,
            },
            held_out_folds: a.folds,
            held_out_step: a.held_out_step.max(1),
            calibration_frames: a.calibration_frames.unwrap_or(d.calibration_frames).max(1),
            calibration_rounds: a.calibration_rounds.unwrap_or(d.calibration_rounds).max(1),
            glitch_m: a.glitch_m.unwrap_or(d.glitch_m),
            glitch_low_m: a.glitch_low_m.unwrap_or(d.glitch_low_m),
            pose_placement_ridge: a.pose_placement_ridge.unwrap_or(d.pose_placement_ridge),
            forearm_roll_deg: a.forearm_roll_deg.unwrap_or(d.forearm_roll_deg),
            temporal_prior: a.temporal_prior.unwrap_or(d.temporal_prior),
            patch_sigma_m: a.patch_sigma.unwrap_or(d.patch_sigma_m),
            held_out_recalibrate: a.held_out_recalibrate,
            ..d
        },
    };
    let out = solve_capture(&model, &req)?;
    write_solve(&a.out, &out, model.faces())?;
    let r = &out.report;
    println!(
        "{} frames: residual mean {:.2} mm (max {:.1}), {} outlier marker-frames; calibration {:.1} s, warm tracking {:.1} ms/frame",
        r.n_frames,
        r.mean_residual_mm,
        r.max_residual_mm,
        r.outliers,
        out.calibration.seconds,
        r.times["tracking_warm_ms_per_frame"]
    );
    if let Some(h) = &r.held_out_marker_error_mm {
        println!(
            "held-out marker error: mean {:.2} mm (all markers {:.2} mm; unobservable once held out: {})",
            h.mean,
            h.mean_all,
            h.unobservable.join(" ")
        );
    }
    let j = &r.jitter_m_per_s2;
    if let (Some(m), Some(o)) = (j.mesh_vertices, j.observed_markers) {
        println!(
            "jitter: mesh vertices {m:.1} m/s², observed markers {o:.1} m/s² (mean acceleration)"
        );
    }
    println!("wrote {}", a.out.display());
    Ok(())
}

fn run_retarget(a: RetargetArgs) -> Result<()> {
    use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
    use panoman_mocap::retarget::{CMU_EVAL_JOINTS, retarget_error};
    let bvh = read_bvh(&a.bvh)?.scaled(CMU_UNIT_M);
    let n = bvh.n_frames();
    // Check the tracking request before the (long) retarget.
    let track = match &a.track {
        None => None,
        Some(t) => {
            let range = panoman_mocap::solve_run::parse_frames(t)
                .map_err(|_| anyhow::anyhow!("--track `{t}`: expected A:B[:step] (e.g. 0::4)"))?;
            let frames = panoman_mocap::track::select_frames(n, range)
                .with_context(|| format!("--track `{t}` on {}", a.bvh.display()))?;
            let Some(m) = a.model.as_deref() else {
                bail!(
                    "--track needs --model (the model that tracks and whose rig generates the meshes)"
                );
            };
            Some((t.clone(), range, frames.len(), panoman::Model::load(m)?))
        }
    };
    let generator = match &track {
        Some((.., model)) => match model.rig() {
            Some(r) => r.generator.clone(),
            None => bail!("the model has no embedded rig (see `panoman embed-rig`)"),
        },
        None => generator_of(a.model.as_deref())?,
    };
    let (shape, rt) = cmu_retarget(&generator, &bvh, a.shape_frames)?;
    let identity = generator.identity(&shape)?;
    let names = generator.bone_names();
    let rig_idx: Vec<usize> = CMU_EVAL_JOINTS
        .iter()
        .map(|(_, b)| names.iter().position(|x| x == b))
        .collect::<Option<_>>()
        .context("rig bone of the evaluation joints")?;
    let bvh_idx: Vec<usize> = CMU_EVAL_JOINTS
        .iter()
        .map(|(j, _)| bvh.joint_index(j))
        .collect::<Option<_>>()
        .with_context(|| format!("{}: not a CMU 31-joint skeleton", a.bvh.display()))?;
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let (mut rig, mut truth) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for f in 0..n {
        let p = rt.params(&bvh, f);
        let posed = identity.pose(&p.pose);
        rig.push(rig_idx.iter().map(|&b| posed.bone_heads[b]).collect());
        let bp = bvh.joint_positions(f);
        truth.push(bvh_idx.iter().map(|&j| bp[j]).collect());
        let path = a.out.join(format!("params_{f:05}.json"));
        let text = serde_json::to_vec_pretty(&p.to_json(names))?;
        write_bytes_atomically(&path, &text)?;
    }
    let e = retarget_error(&rig, &truth);
    let summary = serde_json::json!({
        "bvh": a.bvh.display().to_string(),
        "frames": n,
        "rig_scale": rt.scale,
        "joint_error_mm": {
            "mean": e.global_mean_mm,
            "max": e.global_max_mm,
            "per_frame_similarity_mean": e.per_frame_mean_mm,
            "per_joint": CMU_EVAL_JOINTS.iter().zip(&e.per_joint_mm)
                .map(|((j, _), m)| (j.to_string(), *m)).collect::<std::collections::BTreeMap<_, _>>(),
            "method": "rig bone heads vs the BVH's forward kinematics, after one similarity for the clip",
        },
    });
    write_bytes_atomically(
        &a.out.join("summary.json"),
        &serde_json::to_vec_pretty(&summary)?,
    )?;
    println!(
        "{n} frames retargeted: joint error mean {:.1} mm (max {:.1}); wrote {}",
        e.global_mean_mm,
        e.global_max_mm,
        a.out.display()
    );
    if let Some((spec, range, count, model)) = track {
        run_track(&a, &bvh, &rt, &spec, range, count, &model)?;
    }
    Ok(())
}

/// The retarget of a CMU clip (metres) to the rig of `generator`: the shape fitted on
/// `shape_frames` frames spread over the clip (0: the default identity), the rest poses
/// aligned on frame 0 (the T-pose).
///
/// # Errors
/// Shape fit and calibration errors (e.g. not a CMU skeleton).
pub fn cmu_retarget(
    generator: &panoman_human::generator::Generator,
    bvh: &panoman_mocap::bvh::Bvh,
    shape_frames: usize,
) -> Result<(
    panoman_human::params::ShapeParams,
    panoman_mocap::retarget::CmuRetarget,
)> {
    use panoman_mocap::retarget::{CmuRetarget, fit_cmu_shape};
    let n = bvh.n_frames();
    let mut shape = panoman_human::params::ShapeParams::default();
    if shape_frames > 0 && n > 1 {
        let k = shape_frames.min(n);
        let frames: Vec<usize> = (0..k).map(|j| j * (n - 1) / (k - 1).max(1)).collect();
        shape = fit_cmu_shape(generator, &shape, bvh, &frames, 30)?.shape;
    }
    let identity = generator.identity(&shape)?;
    let rt = CmuRetarget::calibrate(&identity, &shape, bvh, 0)?;
    Ok((shape, rt))
}

/// The 1, 5 and 15 minute load averages (`/proc/loadavg`; `None` where there is none).
fn load_average() -> Option<[f64; 3]> {
    let s = std::fs::read_to_string("/proc/loadavg").ok()?;
    let v: Vec<f64> = s
        .split_whitespace()
        .take(3)
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    v.try_into().ok()
}

fn run_track(
    a: &RetargetArgs,
    bvh: &panoman_mocap::bvh::Bvh,
    rt: &panoman_mocap::retarget::CmuRetarget,
    spec: &str,
    range: panoman_mocap::track::FrameRange,
    count: usize,
    model: &panoman::Model,
) -> Result<()> {
    use std::io::Write;
    let load_before = load_average();
    let t = std::time::Instant::now();
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut progress = |done: usize, total: usize, r: &panoman_mocap::track::TrackFrame| {
        if tty || done.is_multiple_of(50) || done == total {
            eprint!(
                "\rtracking {done}/{total}: frame {} PanoMan {:.1} mm, LBS {:.1} mm{}",
                r.frame,
                r.panoman.all_mean,
                r.lbs.all_mean,
                if tty { "   " } else { "\n" }
            );
            let _ = std::io::stderr().flush();
        }
    };
    fn targets_text(a: &RetargetArgs) -> String {
        let mut t = String::from(if a.no_feet {
            "TC-127 keypoints"
        } else {
            "TC-133 keypoints"
        });
        if a.contacts {
            t += " + foot-floor contact prior";
        }
        t
    }
    let opts = panoman_mocap::track::TrackOptions {
        without_feet: a.no_feet,
        shape_frames: a.calibrate_shape,
        contacts: a
            .contacts
            .then(panoman_mocap::track::ContactOptions::default),
        ..Default::default()
    };
    if a.calibrate_shape > 0 {
        eprintln!(
            "calibrating the limb lengths from {} frames …",
            a.calibrate_shape
        );
    }
    let rep = panoman_mocap::track::track_retarget(model, rt, bvh, range, opts, &mut progress)?;
    if tty {
        eprintln!();
    }
    let seconds = t.elapsed().as_secs_f64();
    let load_after = load_average();
    debug_assert_eq!(rep.frames.len(), count);
    let json = serde_json::json!({
        "bvh": a.bvh.display().to_string(),
        "model": a.model.as_ref().map(|m| m.display().to_string()),
        "frames_spec": spec,
        "n_frames": rep.frames.len(),
        "n_vertices": rep.n_vertices,
        "targets": targets_text(a),
        "contacts": rep.contacts,
        "layout": rep.layout,
        "shape_calibration": rep.calibration,
        "method": "meshes generated by the model's rig from the retargeted parameters (ground truth, the model's topology); their keypoints are the targets (TC-133: body, big toe, little toe and heel per foot, face, hands; with --no-feet TC-127, without the feet); panoman = Tracker (IK warm-started + shell fit with temporal terms), lbs = Tracker of the LBS baseline (IK warm-started); error = mean per-vertex distance to the generated mesh, no alignment, mm; times = wall time of Tracker::track per frame, ms",
        "panoman": rep.panoman,
        "lbs": rep.lbs,
        "generate_ms_per_frame": rep.generate_ms_per_frame,
        "setup_seconds": rep.setup_seconds,
        "seconds": seconds,
        "machine": {
            "loadavg_before": load_before,
            "loadavg_after": load_after,
            "cpus": std::thread::available_parallelism().map(|n| n.get()).ok(),
        },
        "per_frame": rep.frames,
    });
    write_bytes_atomically(
        &a.out.join("track.json"),
        &serde_json::to_vec_pretty(&json)?,
    )?;
    if let Some(w) = &rep.worst {
        let faces = model.faces().to_vec();
        for (name, v) in [
            ("worst_truth.obj", &w.truth),
            ("worst_panoman.obj", &w.panoman),
            ("worst_lbs.obj", &w.lbs),
        ] {
            let mesh = panoman_mesh::TriMesh::new(v.clone(), faces.clone());
            panoman_mesh::io::write_mesh(&a.out.join(name), &mesh)?;
        }
    }
    let (p, l) = (&rep.panoman, &rep.lbs);
    println!(
        "{} frames tracked from {}: PanoMan mean {:.2} mm (median {:.2}, max {:.2} at frame {}), {:.0} ms/frame; LBS mean {:.2} mm (median {:.2}, max {:.2} at frame {}), {:.0} ms/frame; load {}; wrote {}",
        rep.frames.len(),
        targets_text(a),
        p.mean_mm,
        p.median_mm,
        p.max_mm,
        p.worst_frame,
        p.ms_per_frame,
        l.mean_mm,
        l.median_mm,
        l.max_mm,
        l.worst_frame,
        l.ms_per_frame,
        load_after.map_or("?".into(), |v| format!(
            "{:.2} {:.2} {:.2}",
            v[0], v[1], v[2]
        )),
        a.out.join("track.json").display()
    );
    Ok(())
}
