//! `panoman capture`: markerless capture from calibrated multi-view video — detection (the
//! shipped MediaPipe detector, run with Python), synchronization, triangulation, tracking,
//! outputs and overlays, and the leave-one-camera-out evaluation; see `panoman_capture`.

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use panoman::{Method, Model};
use panoman_capture::capture::{
    CaptureConfig, HeldOutCamera, Mask, Tracked, keypoint_tracks, mean_acceleration, track,
    track_2d, vertex_tracks, view_errors,
};
use panoman_capture::frame::TriangulatedFrame;
use panoman_capture::reproject::ReprojectionOptions;
use panoman_capture::sequence::{
    Detections, camera_agreement, common_frames, estimate_offsets, gaussian_sigma_frames,
    person_boxes, read_detections_dir, smooth_keypoints, triangulate_sequence, triangulation_stats,
    views_at,
};
use panoman_capture::triangulate::TriangulateOptions;
use panoman_capture::{Camera, read_calibration};
use panoman_mesh::TriMesh;
use panoman_mesh::geom::V3;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::render::RgbImage;

/// The detector, embedded so that the binary can run it with any Python that has mediapipe.
const DETECT_PY: &str = include_str!("../../../panoman-py/python/panoman/detect.py");

/// Arguments of `panoman capture`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman data fetch video\n  bash scripts/detect-setup.sh     # a venv with mediapipe==0.10.14 (target/detect)\n  D=~/.cache/panoman/pose2sim-demo/Demo_SinglePerson\n  panoman capture --calibration $D/calibration/Calib.qca.txt --videos $D/videos \\\n      --python target/detect/bin/python --model M.safetensors --out cap --all-held-out\n  panoman capture --calibration calib.toml --detections dets/ --model M.safetensors --out cap\n\nOutputs: summary.json (offsets, timings per stage, triangulation, tracking, held_out[]),\nmeshes/frame_NNNN.obj, triangulated/frame_NNNN.json (TC-133 keypoints), overlays/<camera>/\nframe_NNNN.png (person mask grey, mesh silhouette blue, detections green, model keypoints red)."
)]
pub struct CaptureArgs {
    /// Camera calibration: *.qca.txt (Qualisys), *.toml (Pose2Sim / anipose), *.json (CMU
    /// Panoptic) or a folder with intri.yml + extri.yml (OpenCV / EasyMocap).
    #[arg(long)]
    pub calibration: PathBuf,
    /// One video per camera (file stem = camera name) or one image folder per camera: the
    /// detector runs on them first (into OUT/detections).
    #[arg(long, conflicts_with = "detections")]
    pub videos: Option<PathBuf>,
    /// Detections already made: DIR/<camera>/<camera>_<frame>_keypoints.json (OpenPose JSON),
    /// optional <camera>_<frame>_mask.png person masks and DIR/detections.json.
    #[arg(long)]
    pub detections: Option<PathBuf>,
    /// Model file (.safetensors).
    #[arg(long)]
    pub model: PathBuf,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Python with mediapipe==0.10.14 for --videos (default: $PANOMAN_DETECT_PYTHON, else
    /// target/detect/bin/python if present, else python3).
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Frame offsets per camera, in calibration order (camera frame = common frame + offset),
    /// e.g. 0,-3,5,-1; default: estimated.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub offsets: Option<Vec<i64>>,
    /// Largest offset searched (frames).
    #[arg(long, default_value_t = 10)]
    pub max_offset: usize,
    /// Inlier threshold of the triangulation (pixels).
    #[arg(long, default_value_t = 40.0)]
    pub threshold_px: f64,
    /// Shape calibration frames (0: none).
    #[arg(long, default_value_t = 8)]
    pub calibrate_shape: usize,
    /// Expected noise of the triangulated keypoints (metres per coordinate): the fit's priors
    /// and quality thresholds.
    #[arg(long, default_value_t = 0.015)]
    pub keypoint_sigma: f64,
    /// Temporal smoothing of the triangulated keypoints before the fit: the −3 dB cutoff (Hz)
    /// of a zero-phase Gaussian (0: none).
    #[arg(long, default_value_t = 6.0)]
    pub smooth_hz: f64,
    /// TC-133 keypoints left out of the fit (names, e.g. `neck`: MediaPipe has no neck, its
    /// OpenPose neck is the shoulders' midpoint); still triangulated and scored.
    #[arg(long, value_delimiter = ',')]
    pub ignore: Vec<String>,
    /// Frames per second (default: detections.json's, else 60).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Evaluate with this camera held out (fit from the others, score in it).
    #[arg(long, conflicts_with = "all_held_out")]
    pub held_out_camera: Option<String>,
    /// Evaluate with every camera held out in turn.
    #[arg(long)]
    pub all_held_out: bool,
    /// Fit the triangulated keypoints only. By default the 2D detections are fitted too:
    /// after tracking the triangulated keypoints, each keypoint's target is re-solved from
    /// every view's detection by a robust reprojection term anchored at the tracked model
    /// (Cauchy scale `--reprojection-scale-px`), and the sequence tracked again.
    #[arg(long)]
    pub no_refine_2d: bool,
    /// Cauchy scale of the reprojection term (pixels).
    #[arg(long, default_value_t = 15.0)]
    pub reprojection_scale_px: f64,
    /// Skip the LBS baseline in the evaluation.
    #[arg(long)]
    pub no_lbs: bool,
    /// Overlay pictures on the mask grid every N-th frame (0: no overlays at all; with
    /// --videos every frame is also composited over the video, and one .mp4 per camera).
    #[arg(long, default_value_t = 10)]
    pub overlay_every: usize,
}

fn write_json<T: serde::Serialize>(path: &Path, v: &T) -> Result<()> {
    let s = serde_json::to_string_pretty(v)?;
    crate::util::write_atomic(path, s.as_bytes())
}

/// The Python that runs the detector.
fn detector_python(a: &CaptureArgs) -> PathBuf {
    if let Some(p) = &a.python {
        return p.clone();
    }
    if let Some(p) = std::env::var_os("PANOMAN_DETECT_PYTHON").filter(|v| !v.is_empty()) {
        return PathBuf::from(p);
    }
    let local = PathBuf::from("target/detect/bin/python");
    if local.is_file() {
        return local;
    }
    PathBuf::from("python3")
}

/// Checks that the videos (or image folders) and the cameras match one to one.
fn check_videos(videos: &Path, cameras: &[Camera]) -> Result<()> {
    let mut stems = Vec::new();
    for e in std::fs::read_dir(videos).with_context(|| videos.display().to_string())? {
        let p = e?.path();
        let is_video = p.extension().and_then(|x| x.to_str()).is_some_and(|x| {
            ["mp4", "avi", "mov", "mkv"].contains(&x.to_ascii_lowercase().as_str())
        });
        if let Some(s) = p
            .file_stem()
            .and_then(|s| s.to_str())
            .filter(|_| is_video || p.is_dir())
        {
            stems.push((s.to_string(), p.clone()));
        }
    }
    for (s, p) in &stems {
        if !cameras.iter().any(|c| &c.name == s) {
            bail!(
                "{}: a video of camera {s:?}, which the calibration does not have (cameras: {})",
                p.display(),
                names(cameras)
            );
        }
    }
    for c in cameras {
        if !stems.iter().any(|(s, _)| s == &c.name) {
            bail!(
                "{}: no video of camera {:?} (expected {}.mp4 or a folder {})",
                videos.display(),
                c.name,
                c.name,
                c.name
            );
        }
    }
    Ok(())
}

fn names(cameras: &[Camera]) -> String {
    cameras
        .iter()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Runs the embedded detector script with `args` in the detector's Python (the script is
/// written to a temporary folder for the run). Its progress is passed to stderr as it comes;
/// its error line (`detect: error: <file>: …`) becomes this function's one-line error (FFmpeg's
/// own messages are silenced).
fn run_script(a: &CaptureArgs, args: &[&std::ffi::OsStr], what: &str) -> Result<()> {
    use std::io::{Read, Write};
    let py = detector_python(a);
    let dir = std::env::temp_dir().join(format!("panoman-detect-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
    let script = dir.join("detect.py");
    crate::util::write_atomic(&script, DETECT_PY.as_bytes())?;
    let child = std::process::Command::new(&py)
        .arg(&script)
        .args(args)
        .env("OPENCV_FFMPEG_LOGLEVEL", "-8")
        .env("OPENCV_LOG_LEVEL", "ERROR")
        .stderr(std::process::Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(c) => c,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&dir);
            bail!(
                "cannot run {} ({e}): the detector needs Python with mediapipe==0.10.14 \
                 (scripts/detect-setup.sh, then --python target/detect/bin/python)",
                py.display()
            );
        }
    };
    // Pass the progress through segment by segment (tqdm ends its updates with '\r'), keep
    // the error lines.
    let mut errors = Vec::new();
    if let Some(mut err) = child.stderr.take() {
        let mut seg = Vec::new();
        let mut byte = [0u8; 1];
        let mut out = std::io::stderr();
        while let Ok(1) = err.read(&mut byte) {
            seg.push(byte[0]);
            if byte[0] == b'\n' || byte[0] == b'\r' {
                let text = String::from_utf8_lossy(&seg).trim().to_string();
                if text.starts_with("detect: error:") || text.contains(".py: error:") {
                    errors.push(text);
                } else {
                    let _ = out.write_all(&seg);
                }
                seg.clear();
            }
        }
        let text = String::from_utf8_lossy(&seg).trim().to_string();
        if !text.is_empty() {
            errors.push(text);
        }
    }
    let status = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
    let status = status.with_context(|| format!("{what}: waiting for {}", py.display()))?;
    if !status.success() {
        match errors.last() {
            Some(e) => bail!("{what}: {}", e.trim_start_matches("detect: error: ")),
            None => bail!("{what}: {} exited with {status}", py.display()),
        }
    }
    Ok(())
}

/// Runs the embedded detector on `videos` into `out` (the detector writes atomically).
fn run_detector(a: &CaptureArgs, videos: &Path, out: &Path) -> Result<()> {
    run_script(
        a,
        &[
            "--videos".as_ref(),
            videos.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--masks".as_ref(),
        ],
        "detection",
    )
}

/// `detections.json` of a detection folder, if present.
fn detection_info(dir: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("detections.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// The person masks of camera `c` at camera frames `frames` (None where absent).
fn read_masks(
    dets: &Detections,
    c: usize,
    frames: &[usize],
    scale: f64,
) -> Result<Vec<Option<Mask>>> {
    frames
        .iter()
        .map(|&f| match dets.mask_path(c, f) {
            Some(p) => Ok(Some(Mask::read_png(&p, scale)?)),
            None => Ok(None),
        })
        .collect()
}

/// Least fraction of frames in which a camera must agree with the others
/// ([`camera_agreement`]) to be taken as seeing the same person.
const MIN_AGREEMENT: f64 = 0.5;

/// The frame offsets: given (`--offsets`) or estimated; with the JSON of `summary.json`.
fn synchronize(
    a: &CaptureArgs,
    cameras: &[Camera],
    dets: &Detections,
) -> Result<(Vec<i64>, serde_json::Value)> {
    Ok(match &a.offsets {
        Some(o) => (o.clone(), json!({"given": o})),
        None => {
            let est = estimate_offsets(cameras, dets, a.max_offset)?;
            let o: Vec<i64> = est.iter().map(|e| e.offset).collect();
            let rows: Vec<_> = est
                .iter()
                .map(|e| {
                    json!({"camera": e.camera, "offset": e.offset, "median_px": e.median_px,
                           "median_px_at_zero": e.median_px_at_zero, "pairs": e.pairs})
                })
                .collect();
            (o, json!({"estimated": rows}))
        }
    })
}

/// Detects camera `c` again inside the boxes where the other cameras' triangulated person
/// projects (every frame of the camera gets the nearest box: its own offset is unknown), and
/// replaces its detection folder.
#[allow(clippy::too_many_arguments)]
fn redetect_camera(
    a: &CaptureArgs,
    videos: &Path,
    det_dir: &Path,
    cameras: &[Camera],
    dets: &Detections,
    offsets: &[i64],
    c: usize,
    topts: &TriangulateOptions,
) -> Result<()> {
    let others = triangulate_sequence(cameras, dets, offsets, &[c], topts)?;
    let first = common_frames(dets, offsets).start;
    let boxes = person_boxes(&cameras[c], &others, first, 0);
    if boxes.is_empty() {
        bail!(
            "camera {}: the other cameras' person does not project into it",
            cameras[c].name
        );
    }
    let n = dets.frames(c);
    let all: BTreeMap<String, [f64; 4]> = (0..n)
        .filter_map(|f| {
            let near = boxes
                .range(..=f)
                .next_back()
                .map(|(&k, b)| (f - k, *b))
                .into_iter()
                .chain(boxes.range(f..).next().map(|(&k, b)| (k - f, *b)))
                .min_by_key(|(d, _)| *d)?;
            Some((f.to_string(), near.1))
        })
        .collect();
    let name = &cameras[c].name;
    let roi = a.out.join(format!(".roi-{name}.json"));
    write_json(&roi, &json!({"cameras": {name.as_str(): {"boxes": all}}}))?;
    let tmp = a.out.join(format!(".detections-{name}"));
    let _ = std::fs::remove_dir_all(&tmp);
    let status = run_script(
        a,
        &[
            "--videos".as_ref(),
            videos.as_os_str(),
            "--out".as_ref(),
            tmp.as_os_str(),
            "--masks".as_ref(),
            "--roi".as_ref(),
            roi.as_os_str(),
            "--cameras".as_ref(),
            name.as_ref(),
        ],
        &format!("detecting camera {name} again inside the person's boxes"),
    );
    let _ = std::fs::remove_file(&roi);
    if let Err(e) = status {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    let old = det_dir.join(name);
    let aside = a.out.join(format!(".detections-{name}-first"));
    let _ = std::fs::remove_dir_all(&aside);
    std::fs::rename(&old, &aside).with_context(|| old.display().to_string())?;
    std::fs::rename(tmp.join(name), &old).with_context(|| old.display().to_string())?;
    let _ = std::fs::remove_dir_all(&tmp);
    let _ = std::fs::remove_dir_all(&aside);
    Ok(())
}

/// Runs `panoman capture`; on an error, an output folder this run created is removed (nothing
/// half-written).
pub fn run(a: CaptureArgs) -> Result<()> {
    let created = !a.out.exists();
    let out = a.out.clone();
    let r = run_capture(a);
    if r.is_err() && created {
        let _ = std::fs::remove_dir_all(&out);
    }
    r
}

fn run_capture(a: CaptureArgs) -> Result<()> {
    let t_all = Instant::now();
    let cameras = read_calibration(&a.calibration)?;
    if cameras.len() < 2 {
        bail!(
            "{}: {} camera(s); triangulation needs at least 2",
            a.calibration.display(),
            cameras.len()
        );
    }
    if let Some(o) = a.offsets.as_ref().filter(|o| o.len() != cameras.len()) {
        bail!(
            "--offsets: {} values for {} cameras ({})",
            o.len(),
            cameras.len(),
            names(&cameras)
        );
    }
    let held: Vec<usize> = match (&a.held_out_camera, a.all_held_out) {
        (Some(n), _) => vec![cameras.iter().position(|c| &c.name == n).ok_or_else(|| {
            anyhow!(
                "{}: no camera {n:?} to hold out (cameras: {})",
                a.calibration.display(),
                names(&cameras)
            )
        })?],
        (None, true) => (0..cameras.len()).collect(),
        (None, false) => Vec::new(),
    };
    if !held.is_empty() && cameras.len() < 3 {
        bail!("holding a camera out needs at least 3 cameras (2 left to triangulate)");
    }
    let (videos, det_dir) = match (&a.videos, &a.detections) {
        (Some(v), None) => (Some(v.clone()), a.out.join("detections")),
        (None, Some(d)) => (None, d.clone()),
        _ => bail!("give --videos (detect first) or --detections"),
    };
    if let Some(v) = &videos {
        check_videos(v, &cameras)?;
    }
    if !a.model.is_file() {
        bail!("{}: no such model file", a.model.display());
    }
    let t_detect = Instant::now();
    if let Some(v) = &videos {
        std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
        if det_dir.join("detections.json").is_file() {
            eprintln!("detections: reusing {}", det_dir.display());
        } else {
            run_detector(&a, v, &det_dir)?;
        }
    }
    let detect_wall_s = t_detect.elapsed().as_secs_f64();
    let info = detection_info(&det_dir);
    let dets = read_detections_dir(&det_dir, &cameras, 0)?;
    let fps = a
        .fps
        .or_else(|| info.as_ref()?["cameras"][0]["fps"].as_f64())
        .unwrap_or(60.0);
    let mask_scale = info
        .as_ref()
        .and_then(|i| i["mask_scale"].as_f64())
        .unwrap_or(0.25);
    let model = Model::load(&a.model)?;

    // Synchronization, triangulation, and the person check (cameras that follow another
    // person are re-detected around the person the other cameras agree on).
    let t_sync = Instant::now();
    let mut dets = dets;
    let (mut offsets, mut sync) = synchronize(&a, &cameras, &dets)?;
    let topts = TriangulateOptions {
        threshold_px: a.threshold_px,
        ..Default::default()
    };
    let mut raw = triangulate_sequence(&cameras, &dets, &offsets, &[], &topts)?;
    let mut agreement: Vec<f64> = (0..cameras.len())
        .map(|c| camera_agreement(&raw, &dets, &offsets, c))
        .collect();
    let mut redetected = Vec::new();
    if let Some(v) = &videos {
        for c in 0..cameras.len() {
            if agreement[c] < MIN_AGREEMENT {
                eprintln!(
                    "capture: camera {} agrees with the others in {:.0} % of the frames: \
                     detecting again around the person the others see",
                    cameras[c].name,
                    100.0 * agreement[c]
                );
                redetect_camera(&a, v, &det_dir, &cameras, &dets, &offsets, c, &topts)?;
                redetected.push(cameras[c].name.clone());
            }
        }
        if !redetected.is_empty() {
            dets = read_detections_dir(&det_dir, &cameras, 0)?;
            (offsets, sync) = synchronize(&a, &cameras, &dets)?;
            raw = triangulate_sequence(&cameras, &dets, &offsets, &[], &topts)?;
            agreement = (0..cameras.len())
                .map(|c| camera_agreement(&raw, &dets, &offsets, c))
                .collect();
        }
    }
    for (c, &g) in agreement.iter().enumerate() {
        if g < MIN_AGREEMENT {
            eprintln!(
                "warning: camera {} agrees with the others in {:.0} % of the frames (another \
                 person?); its held-out scores compare different people",
                cameras[c].name,
                100.0 * g
            );
        }
    }
    let sync_s = t_sync.elapsed().as_secs_f64();
    let range = common_frames(&dets, &offsets);
    if range.is_empty() {
        bail!(
            "{}: no frame common to every camera under offsets {offsets:?}",
            det_dir.display()
        );
    }
    eprintln!(
        "capture: {} cameras, offsets {offsets:?}, {} common frames",
        cameras.len(),
        range.len()
    );
    let cfg = CaptureConfig {
        calibrate_shape: a.calibrate_shape,
        keypoint_sigma: a.keypoint_sigma,
        midpoints: if info
            .as_ref()
            .and_then(|i| i["detector"].as_str())
            .is_some_and(|d| d.starts_with("mediapipe"))
        {
            panoman_capture::capture::MEDIAPIPE_MIDPOINTS.to_vec()
        } else {
            Vec::new()
        },
        ignore: a
            .ignore
            .iter()
            .map(|n| {
                panoman_human::keypoints::keypoint_index(n)
                    .ok_or_else(|| anyhow!("--ignore: unknown keypoint {n:?}"))
            })
            .collect::<Result<_>>()?,
        fps,
        ..Default::default()
    };

    // All cameras: triangulate and track (PanoMan).
    let t_tri = Instant::now();
    let sigma = if a.smooth_hz > 0.0 {
        gaussian_sigma_frames(a.smooth_hz, fps)
    } else {
        0.0
    };
    let tri = smooth_keypoints(&raw, sigma);
    let tri_s = t_tri.elapsed().as_secs_f64();
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let passes = if a.no_refine_2d { 1 } else { 2 };
    let bar = crate::util::progress_bar((passes * tri.len()) as u64, "track");
    let t_fit = Instant::now();
    let tracked = track_with(
        &a,
        &model,
        &cameras,
        &dets,
        &offsets,
        &[],
        &tri,
        Method::PanoMan,
        &cfg,
        &|_| bar.inc(1),
    )?;
    bar.finish_and_clear();
    let fit_s = t_fit.elapsed().as_secs_f64();
    write_outputs(&a.out, &model, &raw, &tracked, fps)?;
    let camera_frames: Vec<Vec<usize>> = (0..cameras.len())
        .map(|c| {
            range
                .clone()
                .map(|t| (t as i64 + offsets[c]) as usize)
                .collect()
        })
        .collect();
    if a.overlay_every > 0 {
        let dir = a.out.join("overlays");
        write_overlays(
            &dir,
            &cameras,
            &dets,
            &camera_frames,
            &model,
            &tracked,
            mask_scale,
            a.overlay_every,
            fps,
        )?;
        if let Some(v) = &videos {
            composite_overlays(&a, v, &dir)?;
        }
    }

    // Leave-one-camera-out.
    let mut held_out = Vec::new();
    for &h in &held {
        eprintln!("held out: {}", cameras[h].name);
        held_out.push(evaluate_held_out(
            &a,
            &model,
            &cameras,
            &dets,
            &offsets,
            &camera_frames,
            h,
            &topts,
            &cfg,
            mask_scale,
            sigma,
        )?);
    }
    if !held_out.is_empty() {
        plot_held_out(&a.out.join("held_out.png"), &held_out)?;
    }
    let n = tri.len() as f64;
    let stats: BTreeMap<String, serde_json::Value> = triangulation_stats(&raw)
        .into_iter()
        .map(|(k, (frames, px))| {
            let name = model
                .keypoint_names()
                .get(k)
                .cloned()
                .unwrap_or(k.to_string());
            (
                name,
                json!({"frames": frames, "median_reprojection_px": px}),
            )
        })
        .collect();
    let detect_s_per_frame = info.as_ref().and_then(|i| i["seconds_per_frame"].as_f64());
    let summary = json!({
        "calibration": a.calibration.display().to_string(),
        "detections": det_dir.display().to_string(),
        "detector": info.as_ref().map(|i| i["detector"].clone()),
        "cameras": cameras.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
        "fps": fps,
        "synchronization": sync,
        "offsets": offsets,
        "person_agreement": cameras.iter().zip(&agreement).map(|(c, g)| (c.name.clone(), *g)).collect::<BTreeMap<_, _>>(),
        "redetected": redetected,
        "common_frames": [range.start, range.end],
        "frames": tri.len(),
        "seconds_per_frame": {
            "detection_per_view": detect_s_per_frame,
            "detection_wall": if videos.is_some() { Some(detect_wall_s / (n * cameras.len() as f64)) } else { None },
            "synchronization": sync_s / n,
            "triangulation": tri_s / n,
            "fit": fit_s / n,
        },
        "triangulation": stats,
        "smoothing": {"cutoff_hz": a.smooth_hz, "sigma_frames": sigma},
        "tracking": {
            "method": "panoman",
            "shape_calibration_seconds": tracked.calibration_seconds,
            "held_frames": tracked.held,
            "not_converged_frames": tracked.not_converged,
            "body_residual_mm_median": median_of(&tracked.residual_mm),
            "keypoint_residual_mm_median": keypoint_residuals(&model, &tri, &tracked),
        },
        "jitter_m_per_s2": {
            "panoman_vertices": mean_acceleration(&vertex_tracks(&tracked), fps),
            "panoman_keypoints": mean_acceleration(&keypoint_tracks(&tri, Some(&tracked)), fps),
            "triangulation_keypoints": mean_acceleration(&keypoint_tracks(&raw, None), fps),
            "triangulation_smoothed_keypoints": mean_acceleration(&keypoint_tracks(&tri, None), fps),
        },
        "held_out": held_out,
        "wall_seconds": t_all.elapsed().as_secs_f64(),
    });
    write_json(&a.out.join("summary.json"), &summary)?;
    print_summary(&summary);
    Ok(())
}

/// Per body and foot keypoint, the median distance (mm) between the tracked mesh's keypoint
/// and its target (the smoothed triangulation), over the frames where it was a target.
fn keypoint_residuals(
    model: &Model,
    tri: &[TriangulatedFrame],
    tracked: &Tracked,
) -> BTreeMap<String, f64> {
    let mut per: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for (f, t) in tri.iter().enumerate() {
        for (&k, &p) in t.keypoints.points.range(..21) {
            if let Some(q) = tracked.keypoints.get(f).and_then(|v| v.get(k)) {
                let d = panoman_mesh::geom::norm(panoman_mesh::geom::sub(p, *q));
                per.entry(k).or_default().push(1e3 * d);
            }
        }
    }
    per.into_iter()
        .map(|(k, v)| {
            let name = model
                .keypoint_names()
                .get(k)
                .cloned()
                .unwrap_or(k.to_string());
            (name, median_of(&v))
        })
        .collect()
}

/// Median of the finite values of `v` (NaN when none).
fn median_of(v: &[f64]) -> f64 {
    let mut f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    panoman_mesh::stats::median(&mut f)
}

fn print_summary(s: &serde_json::Value) {
    println!(
        "capture: {} frames, offsets {}, fit {:.3} s/frame, jitter (m/s²) mesh {:.2} keypoints {:.2} triangulation {:.2}",
        s["frames"],
        s["offsets"],
        s["seconds_per_frame"]["fit"].as_f64().unwrap_or(f64::NAN),
        s["jitter_m_per_s2"]["panoman_vertices"]
            .as_f64()
            .unwrap_or(f64::NAN),
        s["jitter_m_per_s2"]["panoman_keypoints"]
            .as_f64()
            .unwrap_or(f64::NAN),
        s["jitter_m_per_s2"]["triangulation_keypoints"]
            .as_f64()
            .unwrap_or(f64::NAN),
    );
    if let Some(rows) = s["held_out"].as_array() {
        if !rows.is_empty() {
            println!("held-out camera | body px P / L / tri | % bbox P / L / tri | IoU P / L");
        }
        for r in rows {
            let e = &r["keypoint_error"];
            let g = |m: &str, k: &str| e[m][k].as_f64().unwrap_or(f64::NAN);
            let iou = |m: &str| r["silhouette_iou"][m].as_f64().unwrap_or(f64::NAN);
            println!(
                "{} | {:.1} / {:.1} / {:.1} | {:.2} / {:.2} / {:.2} | {:.3} / {:.3}",
                r["camera"].as_str().unwrap_or("?"),
                g("panoman", "body_px"),
                g("lbs", "body_px"),
                g("triangulation", "body_px"),
                g("panoman", "body_pct_bbox"),
                g("lbs", "body_pct_bbox"),
                g("triangulation", "body_pct_bbox"),
                iou("panoman"),
                iou("lbs"),
            );
        }
    }
}

/// Meshes (OBJ) and the triangulated keypoints (before smoothing) per frame, and the sequence
/// as `capture.glb` (morph-target animation at `fps`, the keypoints as markers).
fn write_outputs(
    out: &Path,
    model: &Model,
    tri: &[TriangulatedFrame],
    tracked: &Tracked,
    fps: f64,
) -> Result<()> {
    let meshes = out.join("meshes");
    let kp = out.join("triangulated");
    std::fs::create_dir_all(&meshes).with_context(|| meshes.display().to_string())?;
    std::fs::create_dir_all(&kp).with_context(|| kp.display().to_string())?;
    for (f, (v, t)) in tracked.vertices.iter().zip(tri).enumerate() {
        panoman_mesh::io::write_mesh(
            &meshes.join(format!("frame_{f:04}.obj")),
            &TriMesh::new(v.clone(), model.faces().to_vec()),
        )?;
        t.keypoints.write(&kp.join(format!("frame_{f:04}.json")))?;
    }
    // The tracked sequence as one animated glTF with the triangulated keypoints as markers.
    let markers: Vec<_> = tri.iter().map(|t| t.keypoints.clone()).collect();
    let options = panoman_interchange::glb::GlbOptions {
        fps,
        ..Default::default()
    };
    let glb = panoman_interchange::glb::export_glb(
        model.faces(),
        &tracked.vertices,
        Some(&panoman_interchange::glb::Markers::from_keypoints(&markers)),
        &options,
    )?;
    panoman_mesh::io::write_bytes_atomically(&out.join("capture.glb"), &glb)?;
    Ok(())
}

/// Overlays. Every frame and camera: the mesh's silhouette on the mask grid
/// (`<camera>/silhouette_NNNN.png`) and an entry of `overlays.json` (the camera's frame, the
/// detections and the mesh's projected keypoints, full-resolution pixels), which the detector
/// script composites over the video (`--overlay`). Every `every`-th frame also a picture on the
/// mask grid (`<camera>/frame_NNNN.png`): person mask grey, mesh blue (purple where both),
/// detections green, the mesh's keypoints red.
#[allow(clippy::too_many_arguments)]
fn write_overlays(
    dir: &Path,
    cameras: &[Camera],
    dets: &Detections,
    camera_frames: &[Vec<usize>],
    model: &Model,
    tracked: &Tracked,
    scale: f64,
    every: usize,
    fps: f64,
) -> Result<()> {
    let mut cams_json = Vec::new();
    for (c, cam) in cameras.iter().enumerate() {
        let d = dir.join(&cam.name);
        std::fs::create_dir_all(&d).with_context(|| d.display().to_string())?;
        let [w, h] = cam
            .image_size
            .map(|[w, h]| {
                [
                    (w as f64 * scale).round() as usize,
                    (h as f64 * scale).round() as usize,
                ]
            })
            .unwrap_or([270, 480]);
        let mut frames_json = Vec::new();
        for (t, &f) in camera_frames[c].iter().enumerate() {
            let mask = match dets.mask_path(c, f) {
                Some(p) => Some(Mask::read_png(&p, scale)?),
                None => None,
            };
            let grid = mask.unwrap_or(Mask {
                width: w,
                height: h,
                scale,
                data: vec![false; w * h],
            });
            let sil = grid.silhouette(cam, &tracked.vertices[t], model.faces());
            let sil_name = format!("{}/silhouette_{t:04}.png", cam.name);
            crate::util::write_atomic(&dir.join(&sil_name), sil.encode_png())?;
            let detected: Vec<[f64; 2]> = dets.views[c][f]
                .values()
                .filter(|(_, conf)| *conf > 0.3)
                .map(|(u, _)| *u)
                .collect();
            let projected: Vec<[f64; 2]> = tracked.keypoints[t]
                .iter()
                .filter_map(|&k| cam.project(k))
                .collect();
            frames_json.push(json!({
                "index": t, "frame": f, "silhouette": sil_name,
                "detections": detected, "model": projected,
            }));
            if every == 0 || t % every != 0 {
                continue;
            }
            let dots: Vec<([f64; 2], [u8; 3])> = detected
                .iter()
                .map(|&u| (u, [40, 220, 60]))
                .chain(projected.iter().take(21).map(|&p| (p, [230, 40, 40])))
                .collect();
            let img = draw_overlay(&grid, &sil, &dots);
            img.save_png(&d.join(format!("frame_{t:04}.png")))?;
        }
        cams_json.push(json!({"name": cam.name, "frames": frames_json}));
    }
    write_json(
        &dir.join("overlays.json"),
        &json!({"scale": scale, "fps": fps, "cameras": cams_json}),
    )
}

/// Per held-out camera, the per-frame median body-keypoint error (pixels) of PanoMan, LBS and
/// the other cameras' triangulation.
fn plot_held_out(path: &Path, rows: &[HeldOutCamera]) -> Result<()> {
    let panels: Vec<(String, String, Vec<crate::plot::Series>)> = rows
        .iter()
        .map(|r| {
            let series = ["panoman", "lbs", "triangulation"]
                .iter()
                .filter_map(|m| {
                    let e = r.keypoint_error.get(*m)?;
                    Some(crate::plot::Series {
                        name: (*m).to_string(),
                        points: e
                            .per_frame_px
                            .iter()
                            .enumerate()
                            .filter(|(_, v)| v.is_finite())
                            .map(|(f, &v)| (f as f64, v))
                            .collect(),
                    })
                })
                .collect();
            (
                format!("held out: {}", r.camera),
                "body keypoint error (px)".to_string(),
                series,
            )
        })
        .collect();
    crate::plot::line_panels(path, &panels, "frame", false)
}

/// A picture on the mask grid: person mask grey, mesh silhouette blue (purple where both),
/// `dots` (full-resolution pixels, colour) as 5×5 squares.
fn draw_overlay(grid: &Mask, sil: &Mask, dots: &[([f64; 2], [u8; 3])]) -> RgbImage {
    let mut img = RgbImage::new(grid.width as u32, grid.height as u32, [20, 20, 20]);
    for i in 0..grid.data.len() {
        let col = match (grid.data[i], sil.data[i]) {
            (true, true) => [150, 110, 200],
            (true, false) => [130, 130, 130],
            (false, true) => [60, 90, 220],
            _ => continue,
        };
        img.data[3 * i..3 * i + 3].copy_from_slice(&col);
    }
    for &(p, col) in dots {
        let (x, y) = (p[0] * grid.scale, p[1] * grid.scale);
        for dy in -2i64..=2 {
            for dx in -2i64..=2 {
                let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                if xx >= 0 && yy >= 0 && (xx as usize) < grid.width && (yy as usize) < grid.height {
                    let i = 3 * (yy as usize * grid.width + xx as usize);
                    img.data[i..i + 3].copy_from_slice(&col);
                }
            }
        }
    }
    img
}

/// Composites the overlays over the videos with the detector script's `--overlay` mode
/// (`<camera>/video_NNNN.png` and `<camera>.mp4`).
fn composite_overlays(a: &CaptureArgs, videos: &Path, dir: &Path) -> Result<()> {
    run_script(
        a,
        &[
            "--overlay".as_ref(),
            dir.as_os_str(),
            "--videos".as_ref(),
            videos.as_os_str(),
        ],
        "overlays over the videos",
    )
}

/// Tracks `tri` (the common frames, cameras `skip` left out) by `method`: from the
/// triangulated keypoints, or with `--refine-2d` from the 2D detections too.
#[allow(clippy::too_many_arguments)]
fn track_with(
    a: &CaptureArgs,
    model: &Model,
    cameras: &[Camera],
    dets: &Detections,
    offsets: &[i64],
    skip: &[usize],
    tri: &[TriangulatedFrame],
    method: Method,
    cfg: &CaptureConfig,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Tracked> {
    if a.no_refine_2d {
        return Ok(track(model, tri, method, cfg, progress)?);
    }
    let views: Vec<_> = common_frames(dets, offsets)
        .map(|t| views_at(dets, offsets, t, skip))
        .collect();
    let o = ReprojectionOptions {
        scale_px: a.reprojection_scale_px,
        ..Default::default()
    };
    let sigma = if a.smooth_hz > 0.0 {
        gaussian_sigma_frames(a.smooth_hz, cfg.fps)
    } else {
        0.0
    };
    Ok(track_2d(
        model, cameras, &views, tri, method, cfg, &o, sigma, progress,
    )?)
}

/// Fits from every camera but `h` (PanoMan and LBS) and scores in `h`.
#[allow(clippy::too_many_arguments)]
fn evaluate_held_out(
    a: &CaptureArgs,
    model: &Model,
    cameras: &[Camera],
    dets: &Detections,
    offsets: &[i64],
    camera_frames: &[Vec<usize>],
    h: usize,
    topts: &TriangulateOptions,
    cfg: &CaptureConfig,
    mask_scale: f64,
    sigma: f64,
) -> Result<HeldOutCamera> {
    let raw = triangulate_sequence(cameras, dets, offsets, &[h], topts)?;
    let tri = smooth_keypoints(&raw, sigma);
    let passes = if a.no_refine_2d { 1 } else { 2 };
    let bar = crate::util::progress_bar(
        (passes * tri.len() * if a.no_lbs { 1 } else { 2 }) as u64,
        &format!("held out {}", cameras[h].name),
    );
    let methods: Vec<Method> = if a.no_lbs {
        vec![Method::PanoMan]
    } else {
        vec![Method::PanoMan, Method::Lbs]
    };
    let runs: Vec<Result<Tracked>> = std::thread::scope(|s| {
        let handles: Vec<_> = methods
            .iter()
            .map(|&m| {
                let (tri, bar) = (&tri, &bar);
                s.spawn(move || {
                    track_with(a, model, cameras, dets, offsets, &[h], tri, m, cfg, &|_| {
                        bar.inc(1)
                    })
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(anyhow!("a tracking thread panicked")))
            })
            .collect()
    });
    bar.finish_and_clear();
    let tracked: Vec<Tracked> = runs.into_iter().collect::<Result<_>>()?;
    let cam = &cameras[h];
    let det_h: Vec<_> = camera_frames[h]
        .iter()
        .map(|&f| dets.views[h][f].clone())
        .collect();
    let mut keypoint_error = BTreeMap::new();
    let name = |m: Method| {
        if m == Method::PanoMan {
            "panoman"
        } else {
            "lbs"
        }
    };
    for t in &tracked {
        let pred = |f: usize, k: usize| t.keypoints.get(f)?.get(k).copied();
        keypoint_error.insert(
            name(t.method).to_string(),
            view_errors(cam, &det_h, &tri, &pred, cfg.eval_min_confidence),
        );
    }
    for t in &tracked {
        let pred = |f: usize, k: usize| t.targets.get(f)?.points.get(&k).copied();
        keypoint_error.insert(
            format!("{}_targets", name(t.method)),
            view_errors(cam, &det_h, &tri, &pred, cfg.eval_min_confidence),
        );
    }
    let raw_pred = |f: usize, k: usize| -> Option<V3> { raw[f].keypoints.points.get(&k).copied() };
    keypoint_error.insert(
        "triangulation".into(),
        view_errors(cam, &det_h, &raw, &raw_pred, cfg.eval_min_confidence),
    );
    if sigma > 0.0 {
        let tri_pred =
            |f: usize, k: usize| -> Option<V3> { tri[f].keypoints.points.get(&k).copied() };
        keypoint_error.insert(
            "triangulation_smoothed".into(),
            view_errors(cam, &det_h, &tri, &tri_pred, cfg.eval_min_confidence),
        );
    }
    let masks = read_masks(dets, h, &camera_frames[h], mask_scale)?;
    // The worst frame (PanoMan's per-frame median body error) drawn on the mask grid: the
    // held-out view's mask and detections (green), PanoMan's silhouette and keypoints (red),
    // the other cameras' triangulation (yellow).
    if let (Some(p), Some(e)) = (tracked.first(), keypoint_error.get("panoman")) {
        let worst = e
            .per_frame_px
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(f, _)| f);
        if let (Some(f), Some(Some(m))) = (worst, worst.map(|f| masks.get(f).cloned().flatten())) {
            let sil = m.silhouette(cam, &p.vertices[f], model.faces());
            let dots: Vec<([f64; 2], [u8; 3])> = det_h[f]
                .iter()
                .filter(|(_, (_, c))| *c >= cfg.eval_min_confidence)
                .map(|(_, (u, _))| (*u, [40, 220, 60]))
                .chain(
                    tri[f]
                        .keypoints
                        .points
                        .range(..21)
                        .filter_map(|(_, &x)| cam.project(x))
                        .map(|u| (u, [240, 220, 40])),
                )
                .chain(
                    p.keypoints[f]
                        .iter()
                        .take(21)
                        .filter_map(|&x| cam.project(x))
                        .map(|u| (u, [230, 40, 40])),
                )
                .collect();
            let dir = a.out.join("held_out");
            std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
            draw_overlay(&m, &sil, &dots)
                .save_png(&dir.join(format!("{}_worst_frame_{f:04}.png", cam.name)))?;
        }
    }
    let mut silhouette_iou = BTreeMap::new();
    for t in &tracked {
        let ious: Vec<f64> = masks
            .iter()
            .enumerate()
            .filter_map(|(f, m)| {
                let m = m.as_ref()?;
                Some(m.silhouette(cam, &t.vertices[f], model.faces()).iou(m))
            })
            .collect();
        if !ious.is_empty() {
            silhouette_iou.insert(t.method, median_of(&ious));
        }
    }
    let mut jitter = BTreeMap::new();
    for t in &tracked {
        jitter.insert(
            format!("{}_vertices", name(t.method)),
            mean_acceleration(&vertex_tracks(t), cfg.fps),
        );
        jitter.insert(
            format!("{}_keypoints", name(t.method)),
            mean_acceleration(&keypoint_tracks(&tri, Some(t)), cfg.fps),
        );
    }
    jitter.insert(
        "triangulation_keypoints".into(),
        mean_acceleration(&keypoint_tracks(&raw, None), cfg.fps),
    );
    if sigma > 0.0 {
        jitter.insert(
            "triangulation_smoothed_keypoints".into(),
            mean_acceleration(&keypoint_tracks(&tri, None), cfg.fps),
        );
    }
    let fit_residual_mm = tracked
        .iter()
        .map(|t| (t.method, keypoint_residuals(model, &tri, t)))
        .collect();
    Ok(HeldOutCamera {
        fit_residual_mm,
        camera: cam.name.clone(),
        frames: tri.len(),
        keypoint_error,
        silhouette_iou,
        jitter,
    })
}
