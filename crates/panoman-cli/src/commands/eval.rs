//! `panoman eval`: the paper's experiments on open data (Fig. 7, 18, 19–21, 1/13, 16 and
//! Table 1), measured by [`panoman::eval::run_all`], written here as CSV + PNG + renders,
//! `summary.json` and an offline `index.html`.

use crate::plot::{Series, line_panels};
use crate::render::{Rgb, Scene, View, error_color};
use anyhow::{Context, Result};
use clap::Args;
use panoman::eval::{
    ClipRow, EvalConfig, EvalOutput, EvalPreset, EvalProgress, EvalSummary, MeshTriple, PartErrors,
    StressSummary, TwistSummary,
};
use panoman_mesh::TriMesh;
use panoman_mesh::geom::{V3, norm, sub};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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
    /// Run one experiment only: `stress` (the stress set: writes stress.json, a per-case and
    /// per-region table on stdout, stress/NAME.png and stress_worst.png).
    #[arg(long, value_parser = ["stress"])]
    pub only: Option<String>,
    /// Fit the stress set from TC-127 keypoints: the six foot keypoints left out.
    #[arg(long)]
    pub without_feet: bool,
    /// Also encode the ground truth of every composite of the stress set (both kinds) and
    /// pose it again (representation error; about a minute per case on the default model).
    #[arg(long)]
    pub representation: bool,
    /// Asset directory.
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman eval`.
pub fn run(a: EvalArgs) -> Result<()> {
    let t_all = Instant::now();
    let cfg = EvalConfig {
        stress_without_feet: a.without_feet,
        stress_representation: a.representation,
        model: a.model.clone(),
        data: a.data.clone(),
        preset: EvalPreset::named(&a.preset)?,
        seed: a.seed,
    };
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    std::fs::create_dir_all(&a.out).with_context(|| a.out.display().to_string())?;
    if a.only.is_some() {
        return stress_only(&a, &cfg, &assets, t_all);
    }
    let output = {
        let pb = indicatif::ProgressBar::new_spinner();
        pb.enable_steady_tick(Duration::from_millis(150));
        let mut experiment = String::new();
        let mut on_progress = |p: EvalProgress| match p {
            EvalProgress::Experiment(name) => {
                let secs = t_all.elapsed().as_secs_f64();
                pb.suspend(|| eprintln!("  eval: {name} ({secs:.0} s)"));
                experiment = name.to_string();
                pb.set_message(format!("eval: {name}"));
            }
            EvalProgress::Step { done, total } => {
                pb.set_message(format!("eval: {experiment} ({done}/{total} done)"));
            }
            EvalProgress::Detail(what) => pb.set_message(format!("eval: {what}")),
        };
        let out = panoman::eval::run_all(&cfg, &assets, &mut on_progress);
        pb.finish_and_clear();
        out?
    };
    eprintln!(
        "  eval: plots and renders ({:.0} s)",
        t_all.elapsed().as_secs_f64()
    );
    write_report(&a.out, &output)?;
    let s = &output.summary;
    println!(
        "{}: report in {:.0} s; body fit error PanoMan {:.1} mm vs LBS {:.1} mm (exact keypoints, {} people)",
        a.out.join("index.html").display(),
        t_all.elapsed().as_secs_f64(),
        s.fit_held_out.exact.panoman.body_mean,
        s.fit_held_out.exact.lbs.body_mean,
        s.fit_held_out.people
    );
    Ok(())
}

/// `panoman eval --only stress`: the stress set alone, `stress.json`, the renders and a table
/// per case and region (PanoMan / LBS, mm).
fn stress_only(
    a: &EvalArgs,
    cfg: &EvalConfig,
    assets: &panoman_human::assets::AssetDir,
    t_all: Instant,
) -> Result<()> {
    let mut on_progress = |p: EvalProgress| {
        if let EvalProgress::Detail(what) = p {
            eprintln!("  eval: {what} ({:.0} s)", t_all.elapsed().as_secs_f64());
        }
    };
    let out = panoman::eval::run_stress(cfg, assets, &mut on_progress)?;
    let s = &out.summary;
    let faces = panoman::Model::load(&a.model)?.faces().to_vec();
    stress_renders(&a.out, &faces, &out.meshes, &s.worst_case)?;
    write_text(
        &a.out.join("stress.json"),
        &(serde_json::to_string_pretty(&serde_json::to_value(s)?)? + "\n"),
    )?;
    let names = panoman::eval::REGION_NAMES;
    println!(
        "{:<18} {:<13} {:>15}  {}",
        "case",
        "kind",
        "all (P / L)",
        names.map(|n| format!("{n:>15}")).join(" ")
    );
    for c in &s.cases {
        let (p, l) = (c.regions.panoman.values(), c.regions.lbs.values());
        let cells: Vec<String> = p
            .iter()
            .zip(&l)
            .map(|(p, l)| format!("{:>15}", format!("{p:.2} / {l:.2}")))
            .collect();
        println!(
            "{:<18} {:<13} {:>15}  {}{}",
            c.name,
            c.kind,
            format!(
                "{:.2} / {:.2}",
                c.errors.panoman.all_mean, c.errors.lbs.all_mean
            ),
            cells.join(" "),
            if c.converged { "" } else { "  (flagged)" }
        );
        if let Some(r) = &c.representation_mm {
            println!(
                "{:<18} representation (encode → pose): mean {:.2} mm, max {:.1} mm",
                "", r.mean, r.max
            );
        }
    }
    println!(
        "mean {:.2} / {:.2} mm; worst {}; {}: {:.0} s",
        s.mean.panoman.all_mean,
        s.mean.lbs.all_mean,
        s.worst_case,
        a.out.join("stress.json").display(),
        t_all.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Every file of the report directory from the evaluation's output.
fn write_report(dir: &Path, o: &EvalOutput) -> Result<()> {
    let out = |name: &str| dir.join(name);
    let s = &o.summary;
    crate::plot::component_curves_files(&out("components.csv"), &out("components.png"), &o.curves)?;
    correction_ablation(&out("correction_ablation.png"), s)?;
    clip_files(dir, &o.clip_frames)?;
    twist_plots(dir, &s.twist)?;
    renders(dir, o)?;
    // Through a `Value` so that keys come out sorted, as `summary.json` always had them.
    let sorted = serde_json::to_value(s)?;
    write_text(
        &out("summary.json"),
        &(serde_json::to_string_pretty(&sorted)? + "\n"),
    )?;
    write_text(&out("index.html"), &html(s))?;
    Ok(())
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

/// Fig. 18: mean representation error without (0) and with (1) the correction MLP.
fn correction_ablation(path: &Path, s: &EvalSummary) -> Result<()> {
    let r = &s.representation;
    let ablation: Vec<Series> = [("body", &r.body), ("face", &r.face), ("hands", &r.hands)]
        .iter()
        .map(|(part, e)| Series {
            name: part.to_string(),
            points: vec![(0.0, e.mean_mm), (1.0, e.mean_mm_corrected)],
        })
        .collect();
    line_panels(
        path,
        &[(
            "Correction MLP ablation (0 = without, 1 = with)".into(),
            "mean per-vertex error (mm)".into(),
            ablation,
        )],
        "correction MLP",
        false,
    )
}

/// `clip.csv` and `clip.png`: per-frame errors of both methods.
fn clip_files(dir: &Path, frames: &[ClipRow]) -> Result<()> {
    let mut csv = String::from(
        "frame,panoman_body_mean_mm,panoman_face_mean_mm,panoman_hands_mean_mm,panoman_all_mean_mm,panoman_all_max_mm,lbs_body_mean_mm,lbs_face_mean_mm,lbs_hands_mean_mm,lbs_all_mean_mm,lbs_all_max_mm,panoman_s,lbs_s\n",
    );
    for (f, r) in frames.iter().enumerate() {
        let (p, l) = (&r.panoman, &r.lbs);
        let _ = writeln!(
            csv,
            "{f},{},{},{},{},{},{},{},{},{},{},{},{}",
            p.body_mean,
            p.face_mean,
            p.hands_mean,
            p.all_mean,
            p.all_max,
            l.body_mean,
            l.face_mean,
            l.hands_mean,
            l.all_mean,
            l.all_max,
            r.panoman_s,
            r.lbs_s
        );
    }
    write_text(&dir.join("clip.csv"), &csv)?;
    let panel = |title: &str, y: &str, f: &dyn Fn(&PartErrors) -> f64| {
        let curve = |name: &str, g: &dyn Fn(&ClipRow) -> &PartErrors| Series {
            name: name.into(),
            points: frames
                .iter()
                .enumerate()
                .map(|(i, r)| (i as f64, f(g(r))))
                .collect(),
        };
        (
            title.to_string(),
            y.to_string(),
            vec![curve("PanoMan", &|r| &r.panoman), curve("LBS", &|r| &r.lbs)],
        )
    };
    let mean = "mean per-vertex error (mm)";
    line_panels(
        &dir.join("clip.png"),
        &[
            panel("Body", mean, &|e| e.body_mean),
            panel("Face", mean, &|e| e.face_mean),
            panel("Hands", mean, &|e| e.hands_mean),
            panel("Whole mesh, max", "max per-vertex error (mm)", &|e| {
                e.all_max
            }),
        ],
        "frame",
        false,
    )
}

type Panel = (String, String, Vec<Series>);

/// `twist_radius.png` and `twist_volume.png` from the twist study's rows.
fn twist_plots(dir: &Path, twist: &TwistSummary) -> Result<()> {
    let mut radius: Vec<Panel> = Vec::new();
    let mut volume: Vec<Panel> = Vec::new();
    for l in &twist.limbs {
        let series = |name: &str, f: &dyn Fn(&panoman::eval::TwistRow) -> f64| Series {
            name: name.into(),
            points: l.rows.iter().map(|r| (r.angle_deg, f(r))).collect(),
        };
        radius.push((
            format!("{}: min radius ratio", l.limb),
            "posed / rest".to_string(),
            vec![
                series("LBS rig (truth)", &|r| r.rig_min_radius_ratio),
                series("LBS fit", &|r| r.lbs_fit_min_radius_ratio),
                series("PanoMan fit", &|r| r.panoman_min_radius_ratio),
            ],
        ));
        // Volume changes can be negative: the plotted zero is shifted to keep plotters' range.
        let shifted = |name: &str, f: &dyn Fn(&panoman::eval::TwistRow) -> f64| {
            series(name, &|r| f(r) + 10.0)
        };
        volume.push((
            format!("{}: volume change", l.limb),
            "% of rest volume + 10".to_string(),
            vec![
                shifted("LBS rig (truth)", &|r| r.rig_volume_change_pct),
                shifted("LBS fit", &|r| r.lbs_fit_volume_change_pct),
                shifted("PanoMan fit", &|r| r.panoman_volume_change_pct),
            ],
        ));
    }
    line_panels(
        &dir.join("twist_radius.png"),
        &radius,
        "twist (degrees)",
        false,
    )?;
    line_panels(
        &dir.join("twist_volume.png"),
        &volume,
        "twist (degrees)",
        false,
    )
}

/// The renders: fit example, spatial error map (Fig. 21), forearm twists, composite motion.
fn renders(dir: &Path, o: &EvalOutput) -> Result<()> {
    let faces = o.model.faces();
    let mesh = |x: &[V3]| TriMesh::new(x.to_vec(), faces.to_vec());
    let plain =
        |t: &MeshTriple| [&t.truth, &t.panoman, &t.lbs].map(|x| (mesh(x), None::<Vec<Rgb>>));
    if let Some(t) = &o.meshes.error_map {
        let scale = 30.0;
        let colors = |x: &[V3]| -> Vec<Rgb> {
            x.iter()
                .zip(&t.truth)
                .map(|(p, q)| error_color(1e3 * norm(sub(*p, *q)) / scale))
                .collect()
        };
        save_render(
            &dir.join("error_map.png"),
            &[
                (mesh(&t.truth), None),
                (mesh(&t.panoman), Some(colors(&t.panoman))),
                (mesh(&t.lbs), Some(colors(&t.lbs))),
            ],
            View::Front,
        )?;
    }
    if let Some(t) = &o.meshes.fit_example {
        save_render(&dir.join("fit_example.png"), &plain(t), View::Front)?;
    }
    for r in &o.meshes.twist_forearm {
        // Order: the twisted target, the LBS fit, the PanoMan fit.
        let t = &r.meshes;
        let m = [&t.truth, &t.lbs, &t.panoman].map(|x| (mesh(x), None));
        save_render(
            &dir.join(format!("twist_forearm_{:.0}.png", r.angle_deg)),
            &m,
            View::Front,
        )?;
    }
    stress_renders(
        dir,
        o.model.faces(),
        &o.meshes.stress,
        &o.summary.stress.worst_case,
    )?;
    if let Some(c) = &o.meshes.composite {
        c.params.write(&dir.join("composite.params.json"))?;
        let parts: Vec<_> = c.posed.iter().map(|x| (mesh(x), None)).collect();
        save_render(&dir.join("composite.png"), &parts, View::Front)?;
    }
    Ok(())
}

/// The stress set: `stress/NAME.png` per case and `stress_worst.png` (ground truth, PanoMan,
/// LBS, coloured by per-vertex error, 0–30 mm).
fn stress_renders(
    dir: &Path,
    faces: &[[u32; 3]],
    meshes: &[(String, panoman::eval::MeshTriple)],
    worst_case: &str,
) -> Result<()> {
    let mesh = |x: &[V3]| TriMesh::new(x.to_vec(), faces.to_vec());
    if !meshes.is_empty() {
        std::fs::create_dir_all(dir.join("stress"))
            .with_context(|| format!("{}: cannot create", dir.join("stress").display()))?;
    }
    for (name, t) in meshes {
        let colors = |x: &[V3]| -> Vec<Rgb> {
            x.iter()
                .zip(&t.truth)
                .map(|(p, q)| error_color(1e3 * norm(sub(*p, *q)) / 30.0))
                .collect()
        };
        let parts = [
            (mesh(&t.truth), None),
            (mesh(&t.panoman), Some(colors(&t.panoman))),
            (mesh(&t.lbs), Some(colors(&t.lbs))),
        ];
        save_render(
            &dir.join("stress").join(format!("{name}.png")),
            &parts,
            View::Front,
        )?;
        if name == worst_case {
            save_render(&dir.join("stress_worst.png"), &parts, View::Front)?;
        }
    }
    Ok(())
}

/// `index.html` from the typed summary (every number also in `summary.json`).
fn html(s: &EvalSummary) -> String {
    let f = |x: f64| {
        if x.is_finite() {
            format!("{x:.2}")
        } else {
            "–".into()
        }
    };
    let fit = &s.fit_held_out;
    let row = |name: &str, v: &PartErrors| {
        format!(
            "<tr><td>{name}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            f(v.all_mean),
            f(v.body_mean),
            f(v.face_mean),
            f(v.hands_mean),
            f(v.all_max)
        )
    };
    let r = &s.representation;
    let repr_rows: String = [("body", &r.body), ("face", &r.face), ("hands", &r.hands)]
        .iter()
        .map(|(p, e)| {
            format!(
                "<tr><td>{p}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                f(e.mean_mm),
                f(e.mean_mm_corrected),
                f(e.max_mm)
            )
        })
        .collect();
    let mut twist_rows = String::new();
    for l in &s.twist.limbs {
        if let Some(last) = l.rows.last() {
            let _ = write!(
                twist_rows,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                l.limb,
                f(last.angle_deg),
                f(last.rig_min_radius_ratio),
                f(last.lbs_fit_min_radius_ratio),
                f(last.panoman_min_radius_ratio),
                f(last.rig_volume_change_pct),
                f(last.lbs_fit_volume_change_pct),
                f(last.panoman_volume_change_pct),
            );
        }
    }
    let stress_rows = stress_table(&s.stress, &f);
    let mut timing_rows = String::new();
    for (name, t) in &s.timing.stages {
        let _ = writeln!(
            timing_rows,
            "<tr><td>{name}</td><td>{:.3}</td><td>{:.3}</td><td>{:.3}</td><td>{}</td></tr>",
            t.min_s, t.median_s, t.max_s, t.runs
        );
    }
    let m = &s.meta;
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

<h2>2. Fitting from TC-133 keypoints (Fig. 19–20)</h2>
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

<h2>6. Stress set: beyond the training sampler</h2>
<p>Cases our generator makes outside the sampler the model was trained on (composites of body pose,
gestures and expression; phenotypes at the edges; forearm twists up to 180°; a hand on the head and at
the chin; a deep sit and a crouch), fitted from exact TC-133 keypoints. Errors in mm (PanoMan / LBS);
steps: shell LM steps accepted/tried; Δ: largest distance between the PanoMan and LBS meshes (mm).
Worst case: <b>{worst}</b>; cases above 20 mm: {o20p} PanoMan / {o20l} LBS; PanoMan more than 3 % above LBS:
{o3}; flagged by the failure detector: {flagged}.</p>
<table><tr><th>case</th><th>kind</th><th>all mean</th><th>body</th><th>hands</th><th>face</th><th>kp residual</th>
<th>steps</th><th>Δ</th><th>verdict</th></tr>{stress_rows}</table>
<figure><img src="stress_worst.png"><figcaption>The worst case: ground truth, PanoMan, LBS, coloured by
per-vertex error from 0 (blue) to 30 mm (red); every case is rendered in <code>stress/</code>.</figcaption></figure>

<h2>7. Timing (Table 1)</h2>
<p>Cold fits from TC-133 keypoints, seconds on this machine; the paper reports 274.5 s per frame in total.
Warm-started clip frames: median {wmed} s.</p>
<table><tr><th>stage</th><th>min</th><th>median</th><th>max</th><th>runs</th></tr>{timing_rows}</table>
</body></html>
"#,
        model = m.model,
        topo = m.topology,
        data = m.data,
        preset = m.preset,
        seed = m.seed,
        secs = m.seconds,
        people = fit.people,
        pe = row("PanoMan, exact keypoints", &fit.exact.panoman),
        le = row("LBS, exact keypoints", &fit.exact.lbs),
        pn = row("PanoMan, 5 mm noise", &fit.noise_5mm.panoman),
        ln = row("LBS, 5 mm noise", &fit.noise_5mm.lbs),
        frames = s.clip.frames,
        wmed = f(s.clip.warm_s.median),
        worst = s.stress.worst_case,
        o20p = s.stress.cases_over_20mm.panoman,
        o20l = s.stress.cases_over_20mm.lbs,
        o3 = s.stress.panoman_over_lbs_3pct,
        flagged = s.stress.flagged,
    )
}

/// The stress set's rows: per case PanoMan / LBS errors, residual, steps, verdict; twist
/// cases add a row with the forearm radius ratio and the shoulder / hand errors.
fn stress_table(st: &StressSummary, f: &dyn Fn(f64) -> String) -> String {
    let mut rows = String::new();
    let pair = |p: f64, l: f64| format!("{} / {}", f(p), f(l));
    for c in &st.cases {
        let (p, l) = (&c.errors.panoman, &c.errors.lbs);
        let _ = write!(
            rows,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}/{}</td><td>{}</td><td>{}</td></tr>",
            c.name,
            c.kind,
            pair(p.all_mean, l.all_mean),
            pair(p.body_mean, l.body_mean),
            pair(p.hands_mean, l.hands_mean),
            pair(p.face_mean, l.face_mean),
            pair(c.keypoint_residual_mm.panoman, c.keypoint_residual_mm.lbs),
            c.shell_steps_accepted,
            c.shell_steps_tried,
            f(c.differs_from_lbs_mm),
            c.reason.as_deref().unwrap_or("converged"),
        );
        let (rp, rl) = (c.regions.panoman.values(), c.regions.lbs.values());
        let by_region: Vec<String> = panoman::eval::REGION_NAMES
            .iter()
            .zip(rp.iter().zip(&rl))
            .map(|(n, (p, l))| format!("{n} {}", pair(*p, *l)))
            .collect();
        let _ = write!(
            rows,
            "<tr><td></td><td colspan=\"9\">by region, mm (PanoMan / LBS): {}</td></tr>",
            by_region.join(", ")
        );
        if let Some(t) = &c.twist {
            let _ = write!(
                rows,
                "<tr><td></td><td colspan=\"9\">forearm radius ratio {} (truth {}), upper arm {} (truth {}), shoulder {} mm, hand {} mm (PanoMan / LBS)</td></tr>",
                pair(t.min_radius_ratio.panoman, t.min_radius_ratio.lbs),
                f(t.truth_min_radius_ratio),
                pair(
                    t.upper_arm_min_radius_ratio.panoman,
                    t.upper_arm_min_radius_ratio.lbs
                ),
                f(t.truth_upper_arm_min_radius_ratio),
                pair(t.shoulder_mean_mm.panoman, t.shoulder_mean_mm.lbs),
                pair(t.hand_mean_mm.panoman, t.hand_mean_mm.lbs),
            );
        }
    }
    rows
}
