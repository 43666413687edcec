//! `panoman eval`: the paper's experiments on open data (Fig. 7, 18, 19–21, 1/13, 16 and
//! Table 1), measured, as CSV + PNG + renders, `summary.json` and an offline `index.html`.

use crate::plot::{Series, line_panels};
use crate::render::{Rgb, Scene, View, error_color};
use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use panoman_fit::fit::{FitOptions, FitResult, keypoint_residuals, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkSolver, IkState};
use panoman_fit::twist::LimbSegment;
use panoman_fit::{
    Constraints, Fitter, Rig, Sequence, fit_frame, ik_config_for_noise, ik_fit, init_of,
};
use panoman_human::clip::{Clip, ClipConfig};
use panoman_human::dataset::Dataset;
use panoman_human::keypoints::{KeypointsFile, keypoint_index};
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_human::regions::{Part, Regions};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::TriMesh;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_mesh::measure::enclosed_volume;
use panoman_model::model::{Evaluator, PanoManModel, Params};
use panoman_model::train::{component_curves, evaluate_representation};
use serde_json::{Value, json};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `panoman eval`.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman eval --model M.safetensors --data H --out report/\n  \
    panoman eval --model Ms.safetensors --data Hs --preset small --out report-small/\n\n\
    Writes REPORT_DIR/index.html (open it in a browser, no network needed), summary.json\n\
    with every number, CSV files and PNG plots/renders. The data directory must be the\n\
    dataset the model was trained on (its held-out identities are used).")]
pub struct EvalArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset directory (the model's training set; held-out identities are evaluated).
    #[arg(long)]
    pub data: PathBuf,
    /// Report directory.
    #[arg(long)]
    pub out: PathBuf,
    /// `default` (10 held-out people, 72-frame clip, twists every 30°) or `small` (CI).
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Seed of the held-out clip and keypoint noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Asset directory.
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

struct Preset {
    people: usize,
    clip_frames: usize,
    clip_keyframes: usize,
    twist_angles: Vec<f64>,
    repr_rows: usize,
    curve_rows: usize,
}

impl Preset {
    fn of(name: &str) -> Result<Preset> {
        Ok(match name {
            "default" => Preset {
                people: 10,
                clip_frames: 72,
                clip_keyframes: 5,
                twist_angles: vec![0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 170.0, 180.0],
                repr_rows: 20,
                curve_rows: 8,
            },
            "small" => Preset {
                people: 2,
                clip_frames: 6,
                clip_keyframes: 2,
                twist_angles: vec![0.0, 90.0, 150.0, 170.0, 180.0],
                repr_rows: 4,
                curve_rows: 2,
            },
            other => bail!("unknown preset `{other}` (expected `default` or `small`)"),
        })
    }
}

/// Mean and max per-vertex error (mm) per part (body, face, hands) and over all vertices.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
struct PartErrors {
    all_mean: f64,
    all_max: f64,
    body_mean: f64,
    body_max: f64,
    face_mean: f64,
    face_max: f64,
    hands_mean: f64,
    hands_max: f64,
}

/// Per clip frame: PanoMan errors, LBS errors, PanoMan seconds, LBS seconds.
type ClipRow = (PartErrors, PartErrors, f64, f64);

struct Groups {
    body: Vec<u32>,
    face: Vec<u32>,
    hands: Vec<u32>,
}

fn part_errors(x: &[V3], truth: &[V3], g: &Groups) -> PartErrors {
    let d: Vec<f64> = x
        .iter()
        .zip(truth)
        .map(|(a, b)| 1e3 * norm(sub(*a, *b)))
        .collect();
    let stat = |vs: &[u32]| {
        let (mut s, mut m) = (0.0, 0.0f64);
        for &v in vs {
            s += d[v as usize];
            m = m.max(d[v as usize]);
        }
        (s / vs.len().max(1) as f64, m)
    };
    let all: f64 = d.iter().sum::<f64>() / d.len().max(1) as f64;
    let (bm, bx) = stat(&g.body);
    let (fm, fx) = stat(&g.face);
    let (hm, hx) = stat(&g.hands);
    PartErrors {
        all_mean: all,
        all_max: d.iter().cloned().fold(0.0, f64::max),
        body_mean: bm,
        body_max: bx,
        face_mean: fm,
        face_max: fx,
        hands_mean: hm,
        hands_max: hx,
    }
}

fn mean_of(xs: &[PartErrors]) -> PartErrors {
    let n = xs.len().max(1) as f64;
    let mut m = PartErrors::default();
    for x in xs {
        m.all_mean += x.all_mean / n;
        m.body_mean += x.body_mean / n;
        m.face_mean += x.face_mean / n;
        m.hands_mean += x.hands_mean / n;
        m.all_max = m.all_max.max(x.all_max);
        m.body_max = m.body_max.max(x.body_max);
        m.face_max = m.face_max.max(x.face_max);
        m.hands_max = m.hands_max.max(x.hands_max);
    }
    m
}

fn to_v3(x: Vec<[f32; 3]>) -> Vec<V3> {
    x.iter()
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect()
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::util::write_atomic(path, text)
}

fn save_render(path: &Path, meshes: &[(TriMesh, Option<Vec<Rgb>>)], view: View) -> Result<()> {
    let mut scene = Scene::new(300 * meshes.len().max(1) as u32, 520);
    scene.supersample(2);
    for (m, c) in meshes {
        match c {
            Some(c) => scene.add_mesh_colored(m, c),
            None => scene.add_mesh(m, [190, 190, 200]),
        };
    }
    scene.render(view).save_png(path)?;
    Ok(())
}

/// Deterministic Gaussian noise (xorshift + Box–Muller), for keypoint noise.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> f64 {
        let mut u = || {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b) = (u().max(1e-300), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

/// Runs `panoman eval`.
pub fn run(a: EvalArgs) -> Result<()> {
    let t_all = Instant::now();
    let preset = Preset::of(&a.preset)?;
    let model = std::sync::Arc::new(PanoManModel::load(&a.model)?);
    let ds = Dataset::open(&a.data)?;
    if ds.topology_hash != model.topology_hash {
        bail!(
            "{}: the dataset's topology ({}) is not the model's ({})",
            a.data.display(),
            ds.meta["topology"]["name"].as_str().unwrap_or("?"),
            model.topology_name
        );
    }
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let full = full_template(&assets)?;
    let full_regions = Regions::full(&assets, &full)?;
    let regions = match model.topology_name.as_str() {
        "small" => {
            let small = small_template(&assets, &full)?;
            Regions::small(&full_regions, &small).map_err(|e| anyhow!("small regions: {e}"))?
        }
        _ => full_regions,
    };
    let groups = Groups {
        body: regions.vertices_of(Part::Body),
        face: regions.vertices_of(Part::Face),
        hands: {
            let mut h = regions.vertices_of(Part::LeftHand);
            h.extend(regions.vertices_of(Part::RightHand));
            h
        },
    };
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    let out = |name: &str| a.out.join(name);
    let mut summary = serde_json::Map::new();
    let say = |what: &str| eprintln!("  eval: {what} ({:.0} s)", t_all.elapsed().as_secs_f64());

    // 1. Representation error versus number of components, and the correction ablation.
    say("representation error and component curves");
    let repr = evaluate_representation(&model, &ds, &regions, preset.repr_rows)?;
    let curves = component_curves(&model, &ds, &regions, preset.curve_rows)?;
    crate::plot::component_curves_files(&out("components.csv"), &out("components.png"), &curves)?;
    let ablation: Vec<Series> = ["body", "face", "hands"]
        .iter()
        .map(|part| Series {
            name: part.to_string(),
            points: vec![
                (0.0, repr[part]["mean_mm"].as_f64().unwrap_or(0.0)),
                (1.0, repr[part]["mean_mm_corrected"].as_f64().unwrap_or(0.0)),
            ],
        })
        .collect();
    line_panels(
        &out("correction_ablation.png"),
        &[(
            "Correction MLP ablation (0 = without, 1 = with)".into(),
            "mean per-vertex error (mm)".into(),
            ablation,
        )],
        "correction MLP",
        false,
    )?;
    summary.insert("representation".into(), repr.clone());

    // The fitting machinery.
    let rig = Rig::load(&assets, &model)?;
    let ik = rig.ik_solver()?;
    let mut fitter = Fitter::new(model.clone())?;
    let opts = FitOptions::default();
    let ikc = IkConfig::default();

    // 2a. Held-out people from exact and noisy keypoints.
    say("fitting held-out people");
    let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
    let rows_of = |kind: u8| -> Vec<usize> {
        (0..ds.n_rows)
            .filter(|&r| ds.kind[r] == kind && held.contains(&ds.identity[r]))
            .collect()
    };
    let body_rows = rows_of(1);
    if body_rows.is_empty() {
        bail!("{}: no held-out body rows", a.data.display());
    }
    let pick: Vec<usize> = (0..preset.people.min(body_rows.len()))
        .map(|i| body_rows[i * body_rows.len() / preset.people.min(body_rows.len())])
        .collect();
    let mut noise = Noise(0x5eed ^ a.seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    let (mut pm_exact, mut lbs_exact, mut pm_noisy, mut lbs_noisy) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut stage_times: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    let mut warm_stage_times: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    let mut first_fit: Option<(Vec<V3>, Vec<V3>, Vec<V3>)> = None;
    // (method, keypoint group) → (Σ mean residual mm, max mm, people).
    let mut kp_res: std::collections::BTreeMap<(&str, String), (f64, f64, usize)> =
        Default::default();
    let mut fits_a: Vec<FitResult> = Vec::new();
    for &r in &pick {
        let truth = to_v3(ds.vertices(r)?);
        let kp = model.keypoints.evaluate(&truth);
        for noisy in [false, true] {
            let pts: Vec<V3> = if noisy {
                kp.iter()
                    .map(|p| {
                        [
                            p[0] + 0.005 * noise.next(),
                            p[1] + 0.005 * noise.next(),
                            p[2] + 0.005 * noise.next(),
                        ]
                    })
                    .collect()
            } else {
                kp.clone()
            };
            let c = Constraints {
                keypoints: KeypointsFile::from_all(&pts),
                ..Default::default()
            };
            // Noisy keypoints: the IK's priors for σ = 5 mm (the noise level is known here).
            let ikc_k = if noisy {
                ik_config_for_noise(0.005)
            } else {
                ikc.clone()
            };
            let (ikr, fit) = fit_frame(&rig, &ik, &mut fitter, &c, &ikc_k, &opts, None)?;
            let (ep, el) = (
                part_errors(&fit.vertices, &truth, &groups),
                part_errors(&ikr.posed, &truth, &groups),
            );
            if noisy {
                pm_noisy.push(ep);
                lbs_noisy.push(el);
            } else {
                pm_exact.push(ep);
                lbs_exact.push(el);
                for (m, x) in [("panoman", &fit.vertices), ("lbs", &ikr.posed)] {
                    for (g, r) in keypoint_residuals(&model, &c.keypoints, x) {
                        let e = kp_res.entry((m, g)).or_insert((0.0, 0.0f64, 0usize));
                        e.0 += r.mean_mm;
                        e.1 = e.1.max(r.max_mm);
                        e.2 += 1;
                    }
                }
                stage_times
                    .entry("ik".into())
                    .or_default()
                    .push(ikr.seconds);
                for s in &fit.report.stages {
                    stage_times
                        .entry(s.name.clone())
                        .or_default()
                        .push(s.seconds);
                }
                stage_times
                    .entry("total".into())
                    .or_default()
                    .push(ikr.seconds + fit.report.seconds);
                if first_fit.is_none() {
                    first_fit = Some((truth.clone(), fit.vertices.clone(), ikr.posed.clone()));
                }
                fits_a.push(fit);
            }
        }
    }
    summary.insert(
        "fit_held_out".into(),
        json!({
            "people": pick.len(),
            "exact": {"panoman": mean_of(&pm_exact), "lbs": mean_of(&lbs_exact)},
            "noise_5mm": {"panoman": mean_of(&pm_noisy), "lbs": mean_of(&lbs_noisy)},
            "keypoint_residual_exact_mm": kp_res.iter().map(|((m, g), (s, mx, n))| {
                (format!("{m}/{g}"), json!({"mean": s / *n as f64, "max": mx}))
            }).collect::<serde_json::Map<String, Value>>(),
            "per_person_exact": pm_exact.iter().zip(&lbs_exact)
                .map(|(p, l)| json!({"panoman": p, "lbs": l})).collect::<Vec<_>>(),
        }),
    );

    // 2b. A held-out motion clip: PanoMan tracked (warm starts) vs the LBS rig per frame.
    say("held-out motion clip");
    let clip = Clip::generate(&ClipConfig {
        seed: a.seed,
        n_frames: preset.clip_frames,
        n_keyframes: preset.clip_keyframes,
    })?;
    let (_, frames) = clip.meshes(&rig.generator, &rig.map, rig.topology)?;
    let mut seq = Sequence::new(opts.clone(), warm_fit_options(), ikc.clone(), false);
    let mut prev_lbs: Option<IkState> = None;
    let mut clip_rows: Vec<ClipRow> = Vec::new();
    let mut warm_times = Vec::new();
    let mut map_frame: Option<(Vec<V3>, Vec<V3>, Vec<V3>)> = None;
    let bar = crate::util::progress_bar(frames.len() as u64, "clip");
    for (f, truth) in frames.iter().enumerate() {
        let kp = KeypointsFile::from_all(&model.keypoints.evaluate(truth));
        let c = Constraints {
            keypoints: kp,
            ..Default::default()
        };
        let (ikr, fit) = seq.fit_next(&rig, &ik, &mut fitter, &c)?;
        let lbs = ik_fit(
            &ik,
            &c,
            &IkConfig {
                initial_state: prev_lbs.clone(),
                ..ikc.clone()
            },
        )?;
        let secs = ikr.seconds + fit.report.seconds;
        if f > 0 {
            warm_times.push(secs);
            for s in &fit.report.stages {
                warm_stage_times
                    .entry(s.name.clone())
                    .or_default()
                    .push(s.seconds);
            }
            warm_stage_times
                .entry("ik".into())
                .or_default()
                .push(ikr.seconds);
        }
        let (ep, el) = (
            part_errors(&fit.vertices, truth, &groups),
            part_errors(&lbs.posed, truth, &groups),
        );
        if f == frames.len() / 2 {
            map_frame = Some((truth.clone(), fit.vertices.clone(), lbs.posed.clone()));
        }
        clip_rows.push((ep, el, secs, lbs.seconds));
        prev_lbs = Some(lbs.state.clone());
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut csv = String::from(
        "frame,panoman_body_mean_mm,panoman_face_mean_mm,panoman_hands_mean_mm,panoman_all_mean_mm,panoman_all_max_mm,lbs_body_mean_mm,lbs_face_mean_mm,lbs_hands_mean_mm,lbs_all_mean_mm,lbs_all_max_mm,panoman_s,lbs_s\n",
    );
    for (f, (p, l, s, ls)) in clip_rows.iter().enumerate() {
        let _ = writeln!(
            csv,
            "{f},{},{},{},{},{},{},{},{},{},{},{s},{ls}",
            p.body_mean,
            p.face_mean,
            p.hands_mean,
            p.all_mean,
            p.all_max,
            l.body_mean,
            l.face_mean,
            l.hands_mean,
            l.all_mean,
            l.all_max
        );
    }
    write_text(&out("clip.csv"), &csv)?;
    let curve = |name: &str, f: &dyn Fn(&ClipRow) -> f64| Series {
        name: name.into(),
        points: clip_rows
            .iter()
            .enumerate()
            .map(|(i, r)| (i as f64, f(r)))
            .collect(),
    };
    line_panels(
        &out("clip.png"),
        &[
            (
                "Body".into(),
                "mean per-vertex error (mm)".into(),
                vec![
                    curve("PanoMan", &|r| r.0.body_mean),
                    curve("LBS", &|r| r.1.body_mean),
                ],
            ),
            (
                "Face".into(),
                "mean per-vertex error (mm)".into(),
                vec![
                    curve("PanoMan", &|r| r.0.face_mean),
                    curve("LBS", &|r| r.1.face_mean),
                ],
            ),
            (
                "Hands".into(),
                "mean per-vertex error (mm)".into(),
                vec![
                    curve("PanoMan", &|r| r.0.hands_mean),
                    curve("LBS", &|r| r.1.hands_mean),
                ],
            ),
            (
                "Whole mesh, max".into(),
                "max per-vertex error (mm)".into(),
                vec![
                    curve("PanoMan", &|r| r.0.all_max),
                    curve("LBS", &|r| r.1.all_max),
                ],
            ),
        ],
        "frame",
        false,
    )?;
    let pm_clip: Vec<PartErrors> = clip_rows.iter().map(|r| r.0).collect();
    let lbs_clip: Vec<PartErrors> = clip_rows.iter().map(|r| r.1).collect();
    let (wmed, wmin, wmax) = crate::util::median_min_max(&warm_times);
    summary.insert(
        "clip".into(),
        json!({
            "frames": frames.len(),
            "panoman": mean_of(&pm_clip), "lbs": mean_of(&lbs_clip),
            "first_frame_s": clip_rows.first().map(|r| r.2),
            "warm_s": {"median": wmed, "min": wmin, "max": wmax},
        }),
    );

    // 3. Twist study.
    say("twist study");
    let twist = twist_study(&model, &rig, &ik, &mut fitter, &ikc, &opts, &preset, &a.out)?;
    summary.insert("twist".into(), twist);

    // 4. Spatial error map (one clip frame).
    say("renders");
    if let Some((truth, pm, lbs)) = &map_frame {
        let scale = 30.0;
        let colors = |x: &[V3]| -> Vec<Rgb> {
            x.iter()
                .zip(truth)
                .map(|(p, q)| error_color(1e3 * norm(sub(*p, *q)) / scale))
                .collect()
        };
        let mesh = |x: &[V3]| TriMesh::new(x.to_vec(), model.faces.clone());
        save_render(
            &out("error_map.png"),
            &[
                (mesh(truth), None),
                (mesh(pm), Some(colors(pm))),
                (mesh(lbs), Some(colors(lbs))),
            ],
            View::Front,
        )?;
    }
    if let Some((truth, pm, lbs)) = &first_fit {
        let mesh = |x: &[V3]| TriMesh::new(x.to_vec(), model.faces.clone());
        save_render(
            &out("fit_example.png"),
            &[(mesh(truth), None), (mesh(pm), None), (mesh(lbs), None)],
            View::Front,
        )?;
    }

    // 5. Composite motion: body of one fit, expression of a second, gesture of a third.
    let face_rows = rows_of(2);
    let hand_rows = rows_of(3);
    let mut composite = json!(null);
    if let (Some(fa), Some(&rf), Some(&rh)) = (fits_a.first(), face_rows.first(), hand_rows.first())
    {
        let fit_row = |fitter: &mut Fitter, r: usize| -> Result<FitResult> {
            let truth = to_v3(ds.vertices(r)?);
            let c = Constraints {
                keypoints: KeypointsFile::from_all(&model.keypoints.evaluate(&truth)),
                ..Default::default()
            };
            Ok(fit_frame(&rig, &ik, fitter, &c, &ikc, &opts, None)?.1)
        };
        let fb = fit_row(&mut fitter, rf)?;
        let fc = fit_row(&mut fitter, rh)?;
        let mut p = fa.params.clone();
        for (src, blocks) in [
            (&fb.params, ["face_l", "face_a"]),
            (&fc.params, ["hands_l", "hands_a"]),
        ] {
            for b in blocks {
                if let Some(v) = src.beta.get(b) {
                    p.beta.insert(b.to_string(), v.clone());
                }
            }
        }
        p.write(&out("composite.params.json"))?;
        let mut ev = Evaluator::new(model.clone())?;
        let mesh = |x: Vec<V3>| TriMesh::new(x, model.faces.clone());
        let posed = |ev: &mut Evaluator, p: &Params| -> Result<Vec<V3>> { Ok(ev.pose(p, true)?) };
        let parts = [
            mesh(posed(&mut ev, &fa.params)?),
            mesh(posed(&mut ev, &fb.params)?),
            mesh(posed(&mut ev, &fc.params)?),
            mesh(posed(&mut ev, &p)?),
        ];
        save_render(
            &out("composite.png"),
            &parts.iter().map(|m| (m.clone(), None)).collect::<Vec<_>>(),
            View::Front,
        )?;
        composite =
            json!({"body_from_row": pick[0], "expression_from_row": rf, "gesture_from_row": rh});
    }
    summary.insert("composite".into(), composite);

    // 6. Timing table.
    let mut timing = serde_json::Map::new();
    let mut rows_md = String::new();
    for (name, xs) in &stage_times {
        let (med, min, max) = crate::util::median_min_max(xs);
        timing.insert(
            name.clone(),
            json!({"median_s": med, "min_s": min, "max_s": max, "runs": xs.len()}),
        );
        let _ = writeln!(
            rows_md,
            "<tr><td>{name}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{}</td></tr>",
            min,
            med,
            max,
            xs.len()
        );
    }
    let mut warm_timing = serde_json::Map::new();
    for (name, xs) in &warm_stage_times {
        let (med, min, max) = crate::util::median_min_max(xs);
        warm_timing.insert(
            name.clone(),
            json!({"median_s": med, "min_s": min, "max_s": max, "runs": xs.len()}),
        );
    }
    summary.insert(
        "timing".into(),
        json!({"stages": timing, "warm_stages": warm_timing, "paper_total_s": 274.5,
               "warm_clip_frame_s": {"median": wmed, "min": wmin, "max": wmax}}),
    );
    summary.insert(
        "meta".into(),
        json!({"model": a.model.display().to_string(), "data": a.data.display().to_string(),
               "preset": a.preset, "seed": a.seed, "seconds": t_all.elapsed().as_secs_f64(),
               "topology": model.topology_name}),
    );
    // Headline figures (the issue's questions in one place).
    let twist_v = summary["twist"].clone();
    let mut at180 = serde_json::Map::new();
    let mut forearm_min = f64::INFINITY;
    let mut forearm_own_min = f64::INFINITY;
    if let Some(limbs) = twist_v["limbs"].as_array() {
        for l in limbs {
            let rows = l["rows"].as_array().cloned().unwrap_or_default();
            if let Some(last) = rows.last() {
                at180.insert(
                    l["limb"].as_str().unwrap_or("?").to_string(),
                    json!({"angle_deg": last["angle_deg"],
                           "rig_volume_change_pct": last["rig_volume_change_pct"],
                           "lbs_fit_volume_change_pct": last["lbs_fit_volume_change_pct"],
                           "panoman_volume_change_pct": last["panoman_volume_change_pct"]}),
                );
            }
            if l["limb"] == "forearm" {
                for r in &rows {
                    let ang = r["angle_deg"].as_f64().unwrap_or(0.0);
                    if (120.0..=170.0).contains(&ang) {
                        forearm_min =
                            forearm_min.min(r["panoman_min_radius_ratio"].as_f64().unwrap_or(0.0));
                        forearm_own_min = forearm_own_min.min(
                            r["panoman_own_rest_min_radius_ratio"]
                                .as_f64()
                                .unwrap_or(0.0),
                        );
                    }
                }
            }
        }
    }
    let stages_v = summary["timing"]["stages"].clone();
    summary.insert(
        "headline".into(),
        json!({
            "fit_exact_mean_mm": {"panoman": mean_of(&pm_exact).all_mean, "lbs": mean_of(&lbs_exact).all_mean},
            "fit_noise_5mm_mean_mm": {"panoman": mean_of(&pm_noisy).all_mean, "lbs": mean_of(&lbs_noisy).all_mean},
            "clip_mean_mm": {"panoman": mean_of(&pm_clip).all_mean, "lbs": mean_of(&lbs_clip).all_mean},
            "forearm_twist_120_170_min_radius_ratio_panoman": if forearm_min.is_finite() { json!(forearm_min) } else { json!(null) },
            "forearm_twist_120_170_min_radius_ratio_panoman_own_rest": if forearm_own_min.is_finite() { json!(forearm_own_min) } else { json!(null) },
            "twist_largest_angle": at180,
            "cold_fit_median_s": stages_v["total"]["median_s"],
            "warm_frame_median_s": wmed,
        }),
    );
    let summary = Value::Object(summary);
    write_text(
        &out("summary.json"),
        &(serde_json::to_string_pretty(&summary)? + "\n"),
    )?;
    write_text(&out("index.html"), &html(&summary, &rows_md))?;
    println!(
        "{}: report in {:.0} s; body fit error PanoMan {:.1} mm vs LBS {:.1} mm (exact keypoints, {} people)",
        a.out.join("index.html").display(),
        t_all.elapsed().as_secs_f64(),
        mean_of(&pm_exact).body_mean,
        mean_of(&lbs_exact).body_mean,
        pick.len()
    );
    Ok(())
}

/// One limb of the twist study: the bone twisted (about its own y axis, the bone direction)
/// and the keypoints spanning the measured segment with the `t` range near the joint.
struct Limb {
    name: &'static str,
    bone: &'static str,
    a: &'static str,
    b: &'static str,
    t: (f64, f64),
    r_max: f64,
}

const LIMBS: [Limb; 4] = [
    Limb {
        name: "forearm",
        bone: "lowerarm02.L",
        a: "l_elbow",
        b: "l_wrist",
        t: (0.15, 0.85),
        r_max: 0.06,
    },
    Limb {
        name: "upper arm",
        bone: "upperarm02.L",
        a: "l_shoulder",
        b: "l_elbow",
        t: (0.15, 0.85),
        r_max: 0.08,
    },
    Limb {
        name: "wrist",
        bone: "wrist.L",
        a: "l_elbow",
        b: "l_wrist",
        t: (0.6, 1.0),
        r_max: 0.06,
    },
    Limb {
        name: "neck",
        bone: "neck02",
        a: "neck",
        b: "nose",
        t: (0.0, 0.45),
        r_max: 0.09,
    },
];

#[allow(clippy::too_many_arguments)]
fn twist_study(
    model: &PanoManModel,
    rig: &Rig,
    ik: &IkSolver,
    fitter: &mut Fitter,
    ikc: &IkConfig,
    opts: &FitOptions,
    preset: &Preset,
    out: &Path,
) -> Result<Value> {
    let g = &rig.generator;
    let names = g.bone_names();
    let id = g.identity(&ShapeParams::default())?;
    let rest = rig.map.map(rig.topology, id.rest_vertices());
    let kr = model.keypoints.evaluate(&rest);
    let rest_vol = enclosed_volume(&TriMesh::new(rest.clone(), model.faces.clone()));
    let angles = preset.twist_angles.clone();
    let twist_opts = opts.clone();
    let mut limbs_out = Vec::new();
    let mut panels = Vec::new();
    let mut vol_panels = Vec::new();
    for limb in &LIMBS {
        let kb = names
            .iter()
            .position(|n| n == limb.bone)
            .ok_or_else(|| anyhow!("the rig has no bone `{}`", limb.bone))?;
        let (ia, ib) = (
            keypoint_index(limb.a).expect("TC-127 name"),
            keypoint_index(limb.b).expect("TC-127 name"),
        );
        let rows_a = model.keypoints.names.iter().position(|n| n == limb.a);
        let rows_b = model.keypoints.names.iter().position(|n| n == limb.b);
        let (Some(ra), Some(rb)) = (rows_a, rows_b) else {
            continue;
        };
        let seg = LimbSegment::new(&rest, kr[ra], kr[rb], limb.t.0, limb.t.1, limb.r_max, 7);
        let min_ratio = |x: &[V3]| -> f64 {
            let k = model.keypoints.evaluate(x);
            seg.radius_ratios(&rest, (kr[ra], kr[rb]), x, (k[ra], k[rb]))
                .into_iter()
                .filter(|r| r.is_finite())
                .fold(f64::INFINITY, f64::min)
        };
        let vol = |x: &[V3]| {
            100.0
                * (enclosed_volume(&TriMesh::new(x.to_vec(), model.faces.clone())) / rest_vol - 1.0)
        };
        let mut rows = Vec::new();
        for &ang in &angles {
            let mut pose = PoseParams {
                euler_deg: vec![[0.0; 3]; names.len()],
                ..Default::default()
            };
            pose.euler_deg[kb][1] = ang;
            let posed = id.pose(&pose);
            let truth = rig.map.map(rig.topology, &posed.vertices);
            let kt = model.keypoints.evaluate(&truth);
            let c = Constraints {
                keypoints: KeypointsFile::from_all(&kt),
                ..Default::default()
            };
            // The identity is known here (the study is about the twist): the IK keeps the
            // true phenotype and fits the pose only, for both the baseline and the initializer.
            let ik_known = IkConfig {
                fit_phenotype: false,
                initial_shape: Some(ShapeParams::default()),
                ..ikc.clone()
            };
            let ikr = ik_fit(ik, &c, &ik_known)?;
            let init = init_of(&ikr, ik, names);
            let fit = fitter.fit(&c, &init, &twist_opts)?;
            let _ = (ia, ib);
            let kres = |x: &[V3]| {
                let r = keypoint_residuals(model, &c.keypoints, x);
                let all: f64 = r.values().map(|g| g.mean_mm * g.n as f64).sum::<f64>()
                    / r.values().map(|g| g.n).sum::<usize>().max(1) as f64;
                all
            };
            // Over PanoMan's own rest shape B_S(α) (the 10-component shape PCA makes the limb a
            // few % thinner than the person's true rest even untwisted).
            let own_rest_ratio = {
                let own = model.rest_shape(&fit.params.alpha);
                let ko = model.keypoints.evaluate(&own);
                let k = model.keypoints.evaluate(&fit.vertices);
                seg.radius_ratios(&own, (ko[ra], ko[rb]), &fit.vertices, (k[ra], k[rb]))
                    .into_iter()
                    .filter(|r| r.is_finite())
                    .fold(f64::INFINITY, f64::min)
            };
            rows.push(json!({
                "lbs_fit_keypoint_mean_mm": kres(&ikr.posed),
                "panoman_keypoint_mean_mm": kres(&fit.vertices),
                "angle_deg": ang,
                "rig_min_radius_ratio": min_ratio(&truth),
                "lbs_fit_min_radius_ratio": min_ratio(&ikr.posed),
                "panoman_min_radius_ratio": min_ratio(&fit.vertices),
                "panoman_own_rest_min_radius_ratio": own_rest_ratio,
                "rig_volume_change_pct": vol(&truth),
                "lbs_fit_volume_change_pct": vol(&ikr.posed),
                "panoman_volume_change_pct": vol(&fit.vertices),
            }));
            if limb.name == "forearm" && [90.0, 150.0, 180.0].contains(&ang) {
                let m = |x: &[V3]| (TriMesh::new(x.to_vec(), model.faces.clone()), None);
                save_render(
                    &out.join(format!("twist_forearm_{ang:.0}.png")),
                    &[m(&truth), m(&ikr.posed), m(&fit.vertices)],
                    View::Front,
                )?;
            }
        }
        let series = |key: &str| -> Vec<(f64, f64)> {
            rows.iter()
                .map(|r| {
                    (
                        r["angle_deg"].as_f64().unwrap_or(0.0),
                        r[key].as_f64().unwrap_or(f64::NAN),
                    )
                })
                .collect()
        };
        panels.push((
            format!("{}: min radius ratio", limb.name),
            "posed / rest".to_string(),
            vec![
                Series {
                    name: "LBS rig (truth)".into(),
                    points: series("rig_min_radius_ratio"),
                },
                Series {
                    name: "LBS fit".into(),
                    points: series("lbs_fit_min_radius_ratio"),
                },
                Series {
                    name: "PanoMan fit".into(),
                    points: series("panoman_min_radius_ratio"),
                },
            ],
        ));
        vol_panels.push((
            format!("{}: volume change", limb.name),
            "% of rest volume".to_string(),
            vec![
                Series {
                    name: "LBS rig (truth)".into(),
                    points: series("rig_volume_change_pct"),
                },
                Series {
                    name: "LBS fit".into(),
                    points: series("lbs_fit_volume_change_pct"),
                },
                Series {
                    name: "PanoMan fit".into(),
                    points: series("panoman_volume_change_pct"),
                },
            ],
        ));
        limbs_out.push(json!({"limb": limb.name, "bone": limb.bone, "rows": rows}));
    }
    // Volume changes can be negative: shift the plotted panels' zero to keep plotters' range.
    line_panels(
        &out.join("twist_radius.png"),
        &panels,
        "twist (degrees)",
        false,
    )?;
    let shifted: Vec<(String, String, Vec<Series>)> = vol_panels
        .into_iter()
        .map(|(t, y, s)| {
            (
                t,
                format!("{y} + 10"),
                s.into_iter()
                    .map(|s| Series {
                        name: s.name,
                        points: s.points.into_iter().map(|(x, y)| (x, y + 10.0)).collect(),
                    })
                    .collect(),
            )
        })
        .collect();
    line_panels(
        &out.join("twist_volume.png"),
        &shifted,
        "twist (degrees)",
        false,
    )?;
    Ok(json!({"angles_deg": angles, "limbs": limbs_out}))
}

fn html(s: &Value, timing_rows: &str) -> String {
    let f = |v: &Value| v.as_f64().map_or("–".into(), |x| format!("{x:.2}"));
    let fit = &s["fit_held_out"];
    let row = |name: &str, v: &Value| {
        format!(
            "<tr><td>{name}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            f(&v["all_mean"]),
            f(&v["body_mean"]),
            f(&v["face_mean"]),
            f(&v["hands_mean"]),
            f(&v["all_max"])
        )
    };
    let repr = &s["representation"];
    let repr_rows: String = ["body", "face", "hands"]
        .iter()
        .map(|p| {
            format!(
                "<tr><td>{p}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                f(&repr[p]["mean_mm"]),
                f(&repr[p]["mean_mm_corrected"]),
                f(&repr[p]["max_mm"])
            )
        })
        .collect();
    let mut twist_rows = String::new();
    if let Some(limbs) = s["twist"]["limbs"].as_array() {
        for l in limbs {
            if let Some(last) = l["rows"].as_array().and_then(|r| r.last()) {
                let _ = write!(
                    twist_rows,
                    "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                    l["limb"].as_str().unwrap_or("?"),
                    f(&last["angle_deg"]),
                    f(&last["rig_min_radius_ratio"]),
                    f(&last["lbs_fit_min_radius_ratio"]),
                    f(&last["panoman_min_radius_ratio"]),
                    f(&last["rig_volume_change_pct"]),
                    f(&last["lbs_fit_volume_change_pct"]),
                    f(&last["panoman_volume_change_pct"]),
                );
            }
        }
    }
    format!(
        r#"<!doctype html>
<html><head><meta charset="utf-8"><title>panoman evaluation</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:4px 10px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}img{{max-width:100%;border:1px solid #eee}}
figcaption{{color:#555;font-size:90%;margin-bottom:1.5em}}</style></head><body>
<h1>panoman evaluation</h1>
<p>Model <code>{model}</code> ({topo} topology), data <code>{data}</code>, preset {preset}, seed {seed};
generated in {secs:.0} s. All numbers are in <code>summary.json</code>.</p>

<h2>1. Representation error versus number of components (Fig. 7) and the correction MLP (Fig. 18)</h2>
<figure><img src="components.png"><figcaption>Held-out rows encoded (α from the rest shape, β by least
squares on RL/RA), rebuilt with g; body on the whole mesh, face and each hand aligned on themselves.
CSV: components.csv.</figcaption></figure>
<table><tr><th>part</th><th>mean (mm)</th><th>with correction (mm)</th><th>max (mm)</th></tr>{repr_rows}</table>
<figure><img src="correction_ablation.png"><figcaption>Mean representation error without (0) and with (1)
the correction MLP.</figcaption></figure>

<h2>2. Fitting from TC-127 keypoints (Fig. 19–20)</h2>
<p>{people} held-out people (identities and poses the model never saw), per-vertex error against the
ground truth (mm).</p>
<table><tr><th>method</th><th>all mean</th><th>body mean</th><th>face mean</th><th>hands mean</th><th>max</th></tr>
{pe}{le}{pn}{ln}</table>
<figure><img src="fit_example.png"><figcaption>Ground truth, PanoMan fit, LBS fit (first held-out person).</figcaption></figure>
<figure><img src="clip.png"><figcaption>A held-out synthetic clip ({frames} frames: body motion, expressions,
gestures): per-frame mean error per part and max error, PanoMan tracked with warm starts vs the LBS rig
fitted per frame. CSV: clip.csv.</figcaption></figure>

<h2>3. Twists (Fig. 1, 13)</h2>
<figure><img src="twist_radius.png"><figcaption>Minimum limb cross-section radius (median per slice, posed
over rest) near the joint versus twist angle: the LBS rig that generated the target, the LBS rig fitted
to the target's keypoints, and PanoMan fitted to the same keypoints.</figcaption></figure>
<figure><img src="twist_volume.png"><figcaption>Enclosed volume change versus twist angle (plotted +10 %
so that the axis starts at 0).</figcaption></figure>
<table><tr><th>limb</th><th>angle</th><th>rig radius</th><th>LBS fit radius</th><th>PanoMan radius</th>
<th>rig vol %</th><th>LBS fit vol %</th><th>PanoMan vol %</th></tr>{twist_rows}</table>
<figure><img src="twist_forearm_90.png"><img src="twist_forearm_150.png"><img src="twist_forearm_180.png">
<figcaption>Forearm twisted 90°, 150°, 180°: LBS rig (target), LBS fit, PanoMan fit.</figcaption></figure>

<h2>4. Spatial error map (Fig. 21)</h2>
<figure><img src="error_map.png"><figcaption>Middle frame of the clip: ground truth, PanoMan, LBS, coloured by
per-vertex error from 0 (blue) to 30 mm (red).</figcaption></figure>

<h2>5. Composite motion (Fig. 16)</h2>
<figure><img src="composite.png"><figcaption>Body of one fit, expression of a second, gesture of a third, and
the composite posed from mixed β blocks (composite.params.json).</figcaption></figure>

<h2>6. Timing (Table 1)</h2>
<p>Cold fits from TC-127 keypoints, seconds on this machine; the paper reports 274.5 s per frame in total.
Warm-started clip frames: median {wmed} s.</p>
<table><tr><th>stage</th><th>min</th><th>median</th><th>max</th><th>runs</th></tr>{timing_rows}</table>
</body></html>
"#,
        model = s["meta"]["model"].as_str().unwrap_or(""),
        topo = s["meta"]["topology"].as_str().unwrap_or(""),
        data = s["meta"]["data"].as_str().unwrap_or(""),
        preset = s["meta"]["preset"].as_str().unwrap_or(""),
        seed = s["meta"]["seed"],
        secs = s["meta"]["seconds"].as_f64().unwrap_or(0.0),
        people = fit["people"],
        pe = row("PanoMan, exact keypoints", &fit["exact"]["panoman"]),
        le = row("LBS, exact keypoints", &fit["exact"]["lbs"]),
        pn = row("PanoMan, 5 mm noise", &fit["noise_5mm"]["panoman"]),
        ln = row("LBS, 5 mm noise", &fit["noise_5mm"]["lbs"]),
        frames = s["clip"]["frames"],
        wmed = f(&s["clip"]["warm_s"]["median"]),
    )
}
