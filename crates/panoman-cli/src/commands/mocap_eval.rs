//! `panoman mocap eval`: the real-capture evaluation of issue 13, PanoMan beside the LBS rig
//! on real data where no model is the ground truth.
//!
//! * **Marker captures** (`nick_freeform_001.c3d` + `Nick01.vsk`, `ThomasFechten.csm`):
//!   [`solve_capture`] with each method — held-out marker error (5 folds, MoSh's protocol),
//!   fitted residual, warm time per frame, calibration time — and the jitter (the report's
//!   `jitter_m_per_s2`: mean acceleration of the solved mesh's vertices and of the model's
//!   markers beside the observed markers' own).
//! * **CMU `01_01`**: retargeted to the rig (shape fitted on 24 frames), its generated meshes
//!   tracked from their keypoints (TC-127, and TC-133 with the feet) by both methods ([`track_retarget`]), with the limb
//!   lengths calibrated from 8 frames: from the keypoints alone, with the foot–floor contact
//!   prior ([`ContactOptions`]), and with six foot points.
//! * **Pictures**: per marker capture the PanoMan frame with the largest fitted residual and
//!   the LBS solve of it, observed markers drawn (red) with the model's markers (blue); the
//!   CMU worst frame (truth, PanoMan, LBS); per-frame residual and tracking-error plots.
//!
//! Everything goes to `--out`: `summary.json` (every figure, per capture and method),
//! `*.png`; stdout gets one table.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use panoman::Method;
use panoman_mesh::TriMesh;
use panoman_mesh::geom::V3;
use panoman_mesh::io::write_bytes_atomically;
use panoman_mocap::marker_map::{model_markers, outward_sign};
use panoman_mocap::solve::SolveOptions;
use panoman_mocap::solve_run::{SolveOutput, SolveRequest, load_capture, solve_capture};
use panoman_mocap::track::{ContactOptions, TrackOptions, TrackReport, track_retarget};
use serde_json::json;

use crate::plot::{Series, line_panels};
use crate::render::{PALETTE, Scene, View};

/// How much of each capture `mocap eval` solves.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum MocapEvalPreset {
    /// Every nick frame, every 2nd Thomas frame, every 4th CMU frame (the README's figures;
    /// about 20 minutes on 2 cores).
    Full,
    /// nick frames 0–299, Thomas 0–599 every 2nd, CMU 0–399 every 8th (a few minutes).
    Quick,
}

/// Arguments of `panoman mocap eval`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  panoman data fetch --dir mocap-data\n  panoman mocap eval --model M.safetensors --data mocap-data --out mocap-eval/\n\nReads nick_freeform_001.c3d, Nick01.vsk, ThomasFechten.csm and 01_01.bvh from --data (the names `panoman data fetch` writes). Writes summary.json (held-out marker error, fitted residual, jitter, times per capture and method; the CMU tracking errors), markers_<capture>.png (the worst-residual frame, PanoMan and LBS, observed markers red, model markers blue), residuals.png, cmu_track.png and cmu_worst.png."
)]
pub struct MocapEvalArgs {
    /// Model file with an embedded rig.
    #[arg(long)]
    pub model: PathBuf,
    /// Folder of the real captures (`panoman data fetch --dir`).
    #[arg(long)]
    pub data: PathBuf,
    /// How much of each capture is solved.
    #[arg(long, value_enum, default_value = "full")]
    pub preset: MocapEvalPreset,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// One marker capture of the evaluation.
struct Capture {
    name: &'static str,
    file: &'static str,
    vsk: Option<&'static str>,
    full: (usize, Option<usize>, usize),
    quick: (usize, Option<usize>, usize),
}

const CAPTURES: [Capture; 2] = [
    Capture {
        name: "nick",
        file: "nick_freeform_001.c3d",
        vsk: Some("Nick01.vsk"),
        full: (0, None, 1),
        quick: (0, Some(300), 1),
    },
    Capture {
        name: "thomas",
        file: "ThomasFechten.csm",
        vsk: None,
        full: (0, None, 2),
        quick: (0, Some(600), 2),
    },
];

/// Runs `panoman mocap eval`.
pub fn run(a: MocapEvalArgs) -> Result<()> {
    let need = |f: &str| -> Result<PathBuf> {
        let p = a.data.join(f);
        if !p.is_file() {
            bail!(
                "{}: missing (the captures come from `panoman data fetch --dir {}`)",
                p.display(),
                a.data.display()
            );
        }
        Ok(p)
    };
    // Every input checked before the long runs.
    let bvh_path = need("01_01.bvh")?;
    let mut files = Vec::new();
    for c in &CAPTURES {
        files.push((need(c.file)?, c.vsk.map(need).transpose()?));
    }
    let model = panoman::Model::load(&a.model)?;
    if !model.has_rig() {
        bail!(
            "{}: the model has no embedded rig (see `panoman embed-rig`)",
            a.model.display()
        );
    }
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let mut summary = serde_json::Map::new();
    let mut residual_panels = Vec::new();
    let mut table = Vec::new();
    for (c, (file, vsk)) in CAPTURES.iter().zip(&files) {
        let frames = match a.preset {
            MocapEvalPreset::Full => c.full,
            MocapEvalPreset::Quick => c.quick,
        };
        let mut per_method = serde_json::Map::new();
        let mut series = Vec::new();
        let mut outs = Vec::new();
        for method in [Method::PanoMan, Method::Lbs] {
            eprintln!("{}: solving with {method:?} …", c.name);
            let req = SolveRequest {
                markers: file.clone(),
                vsk: vsk.clone(),
                marker_map: None,
                frames,
                up: None,
                options: SolveOptions {
                    method,
                    ..SolveOptions::default()
                },
            };
            let out = solve_capture(&model, &req)?;
            let r = &out.report;
            let j = r.jitter_m_per_s2;
            let h = r.held_out_marker_error_mm.as_ref();
            let label = method_name(method);
            table.push(format!(
                "{:<8} {:<8} held-out {:>6.2} mm (all {:>6.2})  fitted {:>5.2} mm  jitter mesh {:>6.2} / model markers {:>6.2} / markers {:>6.2} m/s²  warm {:>6.1} ms/frame",
                c.name,
                label,
                h.map_or(f64::NAN, |h| h.mean),
                h.map_or(f64::NAN, |h| h.mean_all),
                r.mean_residual_mm,
                j.mesh_vertices.unwrap_or(f64::NAN),
                j.model_markers.unwrap_or(f64::NAN),
                j.observed_markers.unwrap_or(f64::NAN),
                r.times
                    .get("tracking_warm_ms_per_frame")
                    .copied()
                    .unwrap_or(f64::NAN),
            ));
            per_method.insert(
                label.into(),
                json!({
                    "held_out_marker_error_mm": h.map(|h| json!({
                        "mean": h.mean, "mean_all": h.mean_all, "per_marker": h.per_marker,
                        "unobservable": h.unobservable, "method": h.method,
                    })),
                    "fitted_residual_mm": {"mean": r.mean_residual_mm, "max": r.max_residual_mm,
                        "per_marker": r.per_marker_residual_mm},
                    "jitter_m_per_s2": j,
                    "times": r.times,
                    "glitches": r.glitches,
                    "n_frames": r.n_frames,
                }),
            );
            series.push(Series {
                name: label.into(),
                points: r
                    .frames
                    .iter()
                    .map(|f| (f.frame as f64, f.mean_mm))
                    .collect(),
            });
            outs.push(out);
        }
        render_markers(&a.out, c.name, file, &outs, &model)?;
        residual_panels.push((
            format!("{}: fitted residual per frame", c.name),
            "mean marker residual (mm)".to_string(),
            series,
        ));
        summary.insert(
            c.name.into(),
            json!({"file": file.display().to_string(), "frames": range_spec(frames),
                "methods": per_method}),
        );
    }
    line_panels(
        &a.out.join("residuals.png"),
        &residual_panels,
        "frame",
        false,
    )?;
    let cmu = cmu_tracking(&a, &bvh_path, &model, &mut table)?;
    summary.insert("cmu_01_01".into(), cmu);
    write_bytes_atomically(
        &a.out.join("summary.json"),
        &serde_json::to_vec_pretty(&serde_json::Value::Object(summary))?,
    )?;
    for line in &table {
        println!("{line}");
    }
    println!("wrote {}", a.out.display());
    Ok(())
}

/// A frame range as `A:B:step` (`B` empty: to the end), the syntax of `--frames`.
fn range_spec((a, b, step): (usize, Option<usize>, usize)) -> String {
    format!(
        "{a}:{}:{step}",
        b.map(|e| e.to_string()).unwrap_or_default()
    )
}

fn method_name(m: Method) -> &'static str {
    match m {
        Method::PanoMan => "panoman",
        Method::Lbs => "lbs",
    }
}

/// `markers_<name>.png`: the frame with PanoMan's largest mean residual, PanoMan and LBS side
/// by side (front view), the observed markers in red and the calibrated model markers in
/// blue.
fn render_markers(
    dir: &Path,
    name: &str,
    file: &Path,
    outs: &[SolveOutput],
    model: &panoman::Model,
) -> Result<()> {
    let Some(worst) = outs[0]
        .report
        .frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.mean_mm.is_finite())
        .max_by(|a, b| a.1.mean_mm.total_cmp(&b.1.mean_mm))
        .map(|(i, _)| i)
    else {
        return Ok(());
    };
    let seq = load_capture(file, None)?;
    let faces = model.faces().to_vec();
    let mut scene = Scene::new(560 * outs.len() as u32, 800);
    for (k, out) in outs.iter().enumerate() {
        let f = &out.frames[worst];
        let obs: Vec<V3> = seq
            .frame(f.frame)
            .iter()
            .copied()
            .filter(|p| p.iter().all(|c| c.is_finite()))
            .collect();
        let sign = outward_sign(&faces, &out.calibration.rest);
        // The placement the frame was solved with (pose-dependent since 2026-12-06).
        let placed = model_markers(f.map(&out.calibration), &faces, &f.vertices, sign);
        scene
            .add_mesh(
                &TriMesh::new(f.vertices.clone(), faces.clone()),
                PALETTE[1 + k % 3],
            )
            .add_points(&placed, [40, 80, 220], 3.0)
            .add_points(&obs, [220, 40, 40], 3.0);
    }
    scene
        .render(View::Front)
        .save_png(&dir.join(format!("markers_{name}.png")))
}

/// The CMU clip: retargeted (shape fitted on 24 frames), tracked from TC-127 and TC-133 keypoints with
/// the limb lengths calibrated from 8 frames: alone, with the foot–floor contact prior, and
/// with the six foot points.
fn cmu_tracking(
    a: &MocapEvalArgs,
    bvh_path: &Path,
    model: &panoman::Model,
    table: &mut Vec<String>,
) -> Result<serde_json::Value> {
    use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
    let bvh = read_bvh(bvh_path)?.scaled(CMU_UNIT_M);
    let Some(rig) = model.rig() else {
        bail!("the model has no embedded rig");
    };
    eprintln!("CMU 01_01: retargeting …");
    let (_, rt) = super::mocap::cmu_retarget(&rig.generator, &bvh, 24)?;
    let range = match a.preset {
        MocapEvalPreset::Full => (0, None, 4),
        MocapEvalPreset::Quick => (0, Some(400), 8),
    };
    let mut out = serde_json::Map::new();
    let mut panels = Vec::new();
    let mut worst: Option<TrackReport> = None;
    // (key, without the feet, contact prior, panel title); the last one's worst frame is
    // rendered.
    let variants = [
        ("tc127", true, false, "CMU 01_01 from TC-127"),
        (
            "tc127_contacts",
            true,
            true,
            "CMU 01_01 from TC-127 + contact prior",
        ),
        ("tc133", false, false, "CMU 01_01 from TC-133 (feet)"),
    ];
    for (key, without_feet, contacts, title) in variants {
        eprintln!("CMU 01_01: tracking, {key} …");
        let opts = TrackOptions {
            without_feet,
            shape_frames: 8,
            contacts: contacts.then(ContactOptions::default),
            ..TrackOptions::default()
        };
        let rep = track_retarget(model, &rt, &bvh, range, opts, &mut |_, _, _| {})?;
        table.push(format!(
            "cmu      {key:<10} tracked: PanoMan {:>6.2} mm (median {:.2}, worst {:.2} at frame {}), LBS {:>6.2} mm; warm {:.0} / {:.0} ms/frame",
            rep.panoman.mean_mm,
            rep.panoman.median_mm,
            rep.panoman.max_mm,
            rep.panoman.worst_frame,
            rep.lbs.mean_mm,
            rep.panoman.warm_ms_per_frame,
            rep.lbs.warm_ms_per_frame
        ));
        out.insert(
            key.into(),
            json!({"panoman": rep.panoman, "lbs": rep.lbs, "shape_calibration": rep.calibration,
                "layout": rep.layout, "contacts": rep.contacts, "per_frame": rep.frames}),
        );
        let s = |f: fn(&panoman_mocap::track::TrackFrame) -> f64, name: &str| Series {
            name: name.into(),
            points: rep.frames.iter().map(|r| (r.frame as f64, f(r))).collect(),
        };
        panels.push((
            title.to_string(),
            "mean vertex error (mm)".to_string(),
            vec![
                s(|r| r.panoman.all_mean, "panoman"),
                s(|r| r.lbs.all_mean, "lbs"),
            ],
        ));
        worst = Some(rep);
    }
    line_panels(&a.out.join("cmu_track.png"), &panels, "BVH frame", false)?;
    if let Some(w) = worst.and_then(|r| r.worst) {
        let faces = model.faces().to_vec();
        let mut scene = Scene::new(1680, 800);
        for (k, v) in [&w.truth, &w.panoman, &w.lbs].into_iter().enumerate() {
            scene.add_mesh(&TriMesh::new(v.clone(), faces.clone()), PALETTE[k]);
        }
        scene
            .render(View::Side)
            .save_png(&a.out.join("cmu_worst.png"))?;
    }
    out.insert("frames".into(), json!(range_spec(range)));
    Ok(serde_json::Value::Object(out))
}
