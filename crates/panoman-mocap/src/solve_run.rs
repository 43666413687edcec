//! A whole marker solve from files: read the capture (C3D or CSM, to the project frame),
//! choose and place the marker map, calibrate, track, measure the held-out error, and write
//! the outputs (what `panoman mocap solve` does).
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use panoman_mesh::geom::V3;
use panoman_mesh::io::write_bytes_atomically;

use crate::error::{MocapError, Result};
use crate::jitter::mean_acceleration;
use crate::marker_map::{MarkerMap, MarkerMapFile, default_set_for, read_marker_map};
use crate::markers::{MarkerSequence, UpAxis};
use crate::solve::{
    Calibration, CalibrationSummary, FrameReport, Jitter, MarkerSolver, SolveOptions, SolveReport,
    SolvedFrame, mean_max_mm,
};

/// What to solve.
#[derive(Clone, Debug)]
pub struct SolveRequest {
    /// The marker file (`.c3d` or `.csm`).
    pub markers: PathBuf,
    /// A VSK of the subject (its marker radius sets the default offsets).
    pub vsk: Option<PathBuf>,
    /// A marker set or placed map (JSON); `None`: the shipped set that covers the capture.
    pub marker_map: Option<PathBuf>,
    /// Frames `start..end` (end exclusive, `None` = all) every `step`.
    pub frames: (usize, Option<usize>, usize),
    /// Up axis of the file when it does not say (C3D without `POINT:Y_SCREEN`); `None`:
    /// detected from the head and foot markers.
    pub up: Option<UpAxis>,
    /// Solver options.
    pub options: SolveOptions,
}

/// Everything a solve produced.
#[derive(Clone, Debug)]
pub struct SolveOutput {
    /// The report.
    pub report: SolveReport,
    /// The calibration.
    pub calibration: Calibration,
    /// The solved frames.
    pub frames: Vec<SolvedFrame>,
    /// The rig's bone names (for the parameter files).
    pub bone_names: Vec<String>,
}

/// Parses `A:B[:step]` (`B` may be empty for the end; `A` alone is one frame).
///
/// # Errors
/// [`MocapError::Invalid`] naming the text.
pub fn parse_frames(s: &str) -> Result<(usize, Option<usize>, usize)> {
    let bad = || MocapError::Invalid {
        what: format!("--frames `{s}`: expected A:B[:step] (e.g. 0:400:2)"),
    };
    let parts: Vec<&str> = s.split(':').collect();
    let num = |p: &str| p.trim().parse::<usize>().map_err(|_| bad());
    let opt = |p: &str| {
        if p.trim().is_empty() {
            Ok(None)
        } else {
            num(p).map(Some)
        }
    };
    let out = match parts.as_slice() {
        [a] => (num(a)?, Some(num(a)? + 1), 1),
        [a, b] => (opt(a)?.unwrap_or(0), opt(b)?, 1),
        [a, b, c] => (opt(a)?.unwrap_or(0), opt(b)?, num(c)?),
        _ => return Err(bad()),
    };
    if out.2 == 0 || out.1.is_some_and(|e| e <= out.0) {
        return Err(bad());
    }
    Ok(out)
}

/// Reads a C3D or CSM capture into the project frame (Z up, metres), subject prefixes
/// removed. The up axis: `up`, else the file's, else detected (the axis along which the
/// head markers are furthest from the foot markers).
///
/// # Errors
/// Reader errors (naming the file); an unknown extension; an undetectable up axis.
pub fn load_capture(path: &Path, up: Option<UpAxis>) -> Result<MarkerSequence> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let mut seq = match ext.as_deref() {
        Some("c3d") => crate::c3d::read_c3d(path)?.markers,
        Some("csm") => crate::csm::read_csm(path)?.0,
        _ => {
            return Err(MocapError::Format {
                path: path.to_path_buf(),
                what: "unknown marker file type (expected .c3d or .csm)".into(),
            });
        }
    };
    seq.strip_subject_prefix()?;
    if seq.n_frames() == 0 || seq.n_markers() == 0 {
        return Err(MocapError::Format {
            path: path.to_path_buf(),
            what: "the capture has no frames or no markers".into(),
        });
    }
    let up = match up.or(seq.up_axis) {
        Some(u) => u,
        None => detect_up(&seq).ok_or_else(|| MocapError::Format {
            path: path.to_path_buf(),
            what: "the up axis is not recorded and head/foot markers do not show it; pass --up"
                .into(),
        })?,
    };
    seq.to_project_frame(Some(up))
}

fn detect_up(seq: &MarkerSequence) -> Option<UpAxis> {
    let is = |n: &str, keys: &[&str]| keys.iter().any(|k| n.contains(k));
    let mut d = [0.0; 3];
    let mut n = 0;
    for f in (0..seq.n_frames()).step_by(10) {
        let mean = |keys: &[&str]| {
            let v: Vec<[f64; 3]> = (0..seq.n_markers())
                .filter(|&i| is(&seq.names[i], keys))
                .filter_map(|i| seq.get(f, i))
                .collect();
            (!v.is_empty())
                .then(|| [0, 1, 2].map(|k| v.iter().map(|p| p[k]).sum::<f64>() / v.len() as f64))
        };
        if let (Some(h), Some(t)) = (mean(&["HD", "HEAD"]), mean(&["TOE", "HEE", "HEL", "ANK"])) {
            for k in 0..3 {
                d[k] += h[k] - t[k];
            }
            n += 1;
        }
    }
    if n == 0 {
        return None;
    }
    let k = (0..3).max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))?;
    Some(match (k, d[k] > 0.0) {
        (0, true) => UpAxis::X,
        (0, false) => UpAxis::NegX,
        (1, true) => UpAxis::Y,
        (1, false) => UpAxis::NegY,
        (_, true) => UpAxis::Z,
        _ => UpAxis::NegZ,
    })
}

/// The marker map of a capture's names on the solver's template.
///
/// # Errors
/// Names no map knows (listed); a map file that does not fit.
pub fn initial_map(
    solver: &MarkerSolver,
    names: &[String],
    map_file: Option<&Path>,
    vsk: Option<&Path>,
) -> Result<MarkerMap> {
    let radius = match vsk {
        Some(p) => {
            let v = crate::vsk::read_vsk(p)?;
            let r: Vec<f64> = v
                .markers
                .iter()
                .map(|m| m.radius)
                .filter(|r| *r > 0.0)
                .collect();
            (!r.is_empty()).then(|| r.iter().sum::<f64>() / r.len() as f64)
        }
        None => None,
    };
    let t = solver.template();
    match map_file {
        None => default_set_for(names)?.place(t, Some(names), radius),
        Some(p) => {
            let with_file = |e: MocapError| MocapError::Format {
                path: p.to_path_buf(),
                what: e.to_string(),
            };
            match read_marker_map(p)? {
                MarkerMapFile::Set(s) => s.place(t, Some(names), radius).map_err(with_file),
                MarkerMapFile::Placed(m) => m
                    .select(&t.topology, t.faces.len(), names)
                    .map_err(with_file),
            }
        }
    }
}

/// Solves a capture end to end (see the module docs).
///
/// # Errors
/// Reading, map, calibration or tracking errors.
pub fn solve_capture(model: &panoman::Model, req: &SolveRequest) -> Result<SolveOutput> {
    let t_setup = Instant::now();
    let mut seq = load_capture(&req.markers, req.up)?;
    // Options are checked (by the solver) before any of them is used.
    let mut solver = MarkerSolver::new(model, req.options.clone())?;
    let glitches: BTreeMap<String, usize> = if req.options.glitch_m > 0.0 {
        let n =
            crate::glitch::drop_glitches(&mut seq, req.options.glitch_m, req.options.glitch_low_m);
        seq.names
            .iter()
            .zip(n)
            .filter(|(_, c)| *c > 0)
            .map(|(m, c)| (m.clone(), c))
            .collect()
    } else {
        BTreeMap::new()
    };
    let map = initial_map(
        &solver,
        &seq.names,
        req.marker_map.as_deref(),
        req.vsk.as_deref(),
    )?;
    let (a, b, step) = req.frames;
    let end = b.unwrap_or(seq.n_frames()).min(seq.n_frames());
    let frames: Vec<usize> = (a..end).step_by(step).collect();
    if frames.is_empty() {
        return Err(MocapError::Invalid {
            what: format!(
                "--frames selects no frame (the capture has {})",
                seq.n_frames()
            ),
        });
    }
    let setup_s = t_setup.elapsed().as_secs_f64();
    let all = vec![true; seq.n_markers()];
    let cal = solver.calibrate(&seq, &frames, &map, &all)?;
    let t = Instant::now();
    let cpu0 = process_cpu_seconds();
    let solved = solver.track(&seq, &frames, &cal, &all)?;
    let tracking_s = t.elapsed().as_secs_f64();
    let tracking_cpu_s = process_cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    let held = if req.options.held_out_folds > 0 {
        Some(solver.held_out(&seq, &frames, &cal, Some(&solved))?)
    } else {
        None
    };
    let frame_reports: Vec<FrameReport> = solved.iter().map(FrameReport::of).collect();
    let (mean_all, max_all, _) =
        mean_max_mm(solved.iter().flat_map(|s| s.residuals.iter().copied()));
    let warm: Vec<f64> = solved.iter().skip(1).map(|s| s.seconds).collect();
    let mut times = BTreeMap::new();
    times.insert("setup_s".to_string(), setup_s);
    times.insert("calibration_s".to_string(), cal.seconds);
    times.insert("tracking_s".to_string(), tracking_s);
    times.insert("first_frame_s".to_string(), solved[0].seconds);
    times.insert(
        "tracking_warm_ms_per_frame".to_string(),
        1e3 * warm.iter().sum::<f64>() / warm.len().max(1) as f64,
    );
    for s in solved.iter().skip(1) {
        for (name, sec) in &s.stage_seconds {
            *times
                .entry(format!("tracking_warm_{name}_ms_per_frame"))
                .or_insert(0.0) += 1e3 * sec / warm.len().max(1) as f64;
        }
    }
    if let Some(c) = tracking_cpu_s {
        times.insert(
            "tracking_cpu_ms_per_frame".to_string(),
            1e3 * c / solved.len().max(1) as f64,
        );
    }
    if let Some(h) = &held {
        times.insert("held_out_s".to_string(), h.seconds);
    }
    let jitter = jitter_of(
        &solver,
        &seq,
        &solved,
        &cal,
        step.max(1) as f64 / seq.rate_hz,
    );
    let report = SolveReport {
        method: req.options.method,
        capture: req.markers.display().to_string(),
        marker_set: map.set.clone(),
        n_markers: seq.n_markers(),
        n_frames: solved.len(),
        frames: frame_reports,
        mean_residual_mm: mean_all,
        max_residual_mm: max_all,
        outliers: solved.iter().map(|s| s.outliers).sum(),
        per_marker_residual_mm: map
            .markers
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let (mean, _, _) = mean_max_mm(solved.iter().map(|s| s.residuals[i]));
                (m.name.clone(), mean)
            })
            .collect(),
        calibration: CalibrationSummary {
            frames: cal.frames.clone(),
            mean_marker_shift_mm: cal.mean_marker_shift_mm,
            mean_residual_mm: cal.mean_residual_mm,
            phenotype: cal.phenotype,
            rounds: req.options.calibration_rounds,
            seconds: cal.seconds,
        },
        times,
        glitches,
        held_out_marker_error_mm: held,
        jitter_m_per_s2: jitter,
    };
    Ok(SolveOutput {
        report,
        calibration: cal,
        frames: solved,
        bone_names: solver.bone_names().to_vec(),
    })
}

impl FrameReport {
    /// The report of a solved frame.
    fn of(s: &SolvedFrame) -> FrameReport {
        let (mean_mm, max_mm, n) = mean_max_mm(s.residuals.iter().copied());
        FrameReport {
            frame: s.frame,
            markers: n,
            mean_mm,
            max_mm,
            outliers: s.outliers,
            ms: 1e3 * s.seconds,
        }
    }
}

/// The mean accelerations of the solved frames `dt` seconds apart: of the mesh vertices, of
/// the model markers (where observed) and of the observed markers.
fn jitter_of(
    solver: &MarkerSolver,
    seq: &MarkerSequence,
    solved: &[SolvedFrame],
    cal: &Calibration,
    dt: f64,
) -> Jitter {
    let meshes: Vec<&[V3]> = solved.iter().map(|f| f.vertices.as_slice()).collect();
    let observed: Vec<&[V3]> = solved.iter().map(|f| seq.frame(f.frame)).collect();
    let placed: Vec<Vec<V3>> = solved
        .iter()
        .zip(&observed)
        .map(|(f, obs)| {
            solver
                .model_markers(f.map(cal), &f.vertices)
                .into_iter()
                .zip(obs.iter())
                .map(|(m, o)| {
                    if o.iter().all(|c| c.is_finite()) {
                        m
                    } else {
                        [f64::NAN; 3]
                    }
                })
                .collect()
        })
        .collect();
    let placed: Vec<&[V3]> = placed.iter().map(Vec::as_slice).collect();
    Jitter {
        mesh_vertices: mean_acceleration(&meshes, dt),
        model_markers: mean_acceleration(&placed, dt),
        observed_markers: mean_acceleration(&observed, dt),
    }
}

/// CPU time of this process, all threads, user + system (s; Linux `/proc/self/stat`, in
/// its 10 ms ticks); `None` elsewhere. On a shared machine it is the load-independent
/// counterpart of the wall times.
pub fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may contain spaces).
    let rest = &s[s.rfind(')')? + 1..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn json_bytes(v: &impl serde::Serialize) -> Vec<u8> {
    // NaN is not JSON: serde_json writes null for it.
    let mut b = serde_json::to_vec_pretty(v).expect("serializable");
    b.push(b'\n');
    b
}

/// Writes `mesh_NNNNN.obj`, `params_NNNNN.json` (the rig's generator parameters, for
/// `generate`, `fit --motion`, `mocap export`), `panoman_params_NNNNN.json` (PanoMan's α, β
/// and placement; PanoMan only), `marker_map.json`, `pose_placement.json` (the markers'
/// pose-dependent placements, when the calibration fitted any; a stale one from an earlier
/// solve is removed otherwise) and `report.json` into `dir`, each file atomically.
///
/// # Errors
/// [`MocapError::Io`] naming the file.
pub fn write_solve(dir: &Path, out: &SolveOutput, faces: &[[u32; 3]]) -> Result<()> {
    let bone_names = &out.bone_names;
    // The writers' errors already start with the file (`<path>: <what>`).
    let io = |_path: PathBuf| {
        move |e: panoman_mesh::MeshError| MocapError::Invalid {
            what: e.to_string(),
        }
    };
    std::fs::create_dir_all(dir).map_err(|source| MocapError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    for s in &out.frames {
        let p = dir.join(format!("mesh_{:05}.obj", s.frame));
        let mesh = panoman_mesh::mesh::TriMesh {
            positions: s.vertices.clone(),
            faces: faces.to_vec(),
        };
        panoman_mesh::io::obj::write_obj(&p, &mesh).map_err(io(p.clone()))?;
        let v = s.rig_params.to_json(bone_names);
        let p = dir.join(format!("params_{:05}.json", s.frame));
        write_bytes_atomically(&p, &json_bytes(&v)).map_err(io(p.clone()))?;
        if let Some(pm) = &s.params {
            let p = dir.join(format!("panoman_params_{:05}.json", s.frame));
            write_bytes_atomically(&p, &json_bytes(pm)).map_err(io(p.clone()))?;
        }
    }
    let p = dir.join("marker_map.json");
    write_bytes_atomically(&p, &json_bytes(&out.calibration.map)).map_err(io(p.clone()))?;
    let cal = &out.calibration;
    if cal.pose_placement.iter().any(Option::is_some) {
        // The pose-dependent part of the placement (`PosePlacement`), per marker that has one.
        let v: Vec<serde_json::Value> = cal
            .map
            .markers
            .iter()
            .zip(&cal.pose_placement)
            .filter_map(|(m, pp)| {
                let pp = pp.as_ref()?;
                let features: Vec<String> = pp
                    .features
                    .iter()
                    .map(|&(b, a)| format!("{}.{}", bone_names[b], ["x", "y", "z"][a]))
                    .collect();
                Some(serde_json::json!({
                    "marker": m.name,
                    "rest_point_m": pp.at_mean,
                    "features": features,
                    "mean_rad": pp.mean,
                    "slopes_m_per_rad": pp.slopes,
                }))
            })
            .collect();
        let p = dir.join("pose_placement.json");
        write_bytes_atomically(&p, &json_bytes(&v)).map_err(io(p.clone()))?;
    } else {
        let p = dir.join("pose_placement.json");
        if p.exists() {
            std::fs::remove_file(&p).map_err(|source| MocapError::Io { path: p, source })?;
        }
    }
    let p = dir.join("report.json");
    write_bytes_atomically(&p, &json_bytes(&out.report)).map_err(io(p.clone()))?;
    Ok(())
}

/// Mean of the vertices (for quick checks).
pub fn centroid(x: &[V3]) -> V3 {
    let n = x.len().max(1) as f64;
    x.iter().fold([0.0; 3], |a, p| {
        [a[0] + p[0] / n, a[1] + p[1] / n, a[2] + p[2] / n]
    })
}
