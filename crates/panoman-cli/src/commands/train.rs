//! `panoman train`: dataset H → PanoMan model file, training report and the Fig. 7 curves.

use crate::plot::component_curves_files;
use crate::util::write_atomic;
use anyhow::{Context, Result, bail};
use clap::Args;
use panoman_model::train::{TrainConfig, TrainReport, evaluate};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `panoman train`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman synth --preset small --out H && panoman train --data H --preset small --out M.safetensors\n  panoman train --data H --out M.safetensors   # default preset: 10 shape, 250/100/50 components\n\nBlock sizes: K components per part (--components BODY,FACE,HANDS, default 250,100,50) give\nK + 1 β coefficients per block (251/101/51): coefficient 0 scales the part's mean.\n\nAlso writes <out>.report.json and the Fig. 7 curves <out>.fig7.csv / <out>.fig7.png."
)]
pub struct TrainArgs {
    /// Dataset directory written by `panoman synth` (or a user's own, same layout).
    #[arg(long)]
    pub data: PathBuf,
    /// `small` (CI-sized) or `default` (the paper's sizes).
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Output model file (.safetensors).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of every random choice (same data + seed → byte-identical model).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Override the components per part as `BODY,FACE,HANDS` (e.g. `400,100,50`).
    #[arg(long)]
    pub components: Option<String>,
    /// Override the number of shape (α) components (preset: 10 default, 6 small); at most the
    /// number of training identities − 1.
    #[arg(long)]
    pub shape_components: Option<usize>,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Do not train: evaluate the existing model --out on --data (held-out representation
    /// error with the least-squares and Gauss–Newton encoders, Fig. 7 curves) and update the
    /// `representation_error` and evaluation timings of <out>.report.json (created if missing).
    #[arg(long)]
    pub evaluate_only: bool,
    /// Override the preset's held-out rows per kind of the evaluation (0 = all).
    #[arg(long)]
    pub eval_rows: Option<usize>,
    /// With --evaluate-only: skip the Fig. 7 curves (the representation error only).
    #[arg(long, requires = "evaluate_only")]
    pub skip_curves: bool,
}

/// Runs `panoman train`.
pub fn run(a: TrainArgs) -> Result<()> {
    let t0 = Instant::now();
    // The model, its report and figures go next to --out: check the location before training
    // (minutes), not after.
    panoman_mesh::io::check_output_path(&a.out)?;
    let mut cfg = TrainConfig::preset(&a.preset)?;
    cfg.seed = a.seed;
    if let Some(c) = &a.components {
        let v: Vec<usize> = c
            .split(',')
            .map(|x| x.trim().parse::<usize>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                anyhow::anyhow!("--components: expected BODY,FACE,HANDS counts, got '{c}'")
            })?;
        if v.len() != 3 || v.contains(&0) {
            bail!("--components: expected three positive counts BODY,FACE,HANDS, got '{c}'");
        }
        cfg.components = [v[0], v[1], v[2]];
    }
    if let Some(n) = a.shape_components {
        if n == 0 {
            bail!("--shape-components: expected a positive count");
        }
        cfg.n_shape = n;
    }
    if let Some(n) = a.eval_rows {
        cfg.eval_rows_per_kind = n;
    }
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let pb = indicatif::ProgressBar::new_spinner();
    pb.enable_steady_tick(Duration::from_millis(150));
    // One progress reporter for training and evaluation: prints each finished stage's time;
    // a message `"{stage} ({detail})"` of the current stage only updates the spinner.
    let mut stage_start = Instant::now();
    let mut last = String::new();
    let mut stage = |name: &str| {
        let detail = !last.is_empty()
            && name
                .strip_prefix(last.as_str())
                .is_some_and(|rest| rest.starts_with(" ("));
        if detail {
            pb.set_message(name.to_string());
            return;
        }
        if !last.is_empty() {
            pb.suspend(|| eprintln!("  {last}: {:.1} s", stage_start.elapsed().as_secs_f64()));
        }
        last = name.to_string();
        stage_start = Instant::now();
        pb.set_message(name.to_string());
    };
    let stem = a.out.with_extension("");
    let report_path = PathBuf::from(format!("{}.report.json", stem.display()));
    let (model, base_report, ds, regions) = if a.evaluate_only {
        let model = panoman_model::model::PanoManModel::load(&a.out)?;
        let (ds, regions) = panoman::training::dataset_and_regions(&assets, &a.data)?;
        // The training's report when it reads, else one from the model file's own report.
        let report = std::fs::read_to_string(&report_path)
            .ok()
            .and_then(|t| serde_json::from_str::<TrainReport>(&t).ok())
            .unwrap_or_else(|| TrainReport {
                preset: cfg.preset.clone(),
                model: model.report.clone().unwrap_or_default(),
                ..TrainReport::default()
            });
        (model, report, ds, regions)
    } else {
        let trained = panoman::training::train(&assets, &a.data, &cfg, &mut stage)?;
        let (out, ds, regions) = (trained.output, trained.dataset, trained.regions);
        out.model.save(&a.out)?;
        // The training report, until the evaluation below completes it: its
        // `representation_error` is null ("not evaluated yet"), so that a run stopped during
        // the evaluation does not leave a report that reads as complete.
        let report = out.report;
        write_atomic(&report_path, report_json(&report)?)?;
        (out.model, report, ds, regions)
    };
    let topo_name = model.topology_name.clone();
    let model = std::sync::Arc::new(model);
    let eval = if a.skip_curves {
        let t = Instant::now();
        let gn = panoman_model::model::GnOptions::default();
        let repr = panoman_model::train::evaluate_representation(
            &model,
            &ds,
            &regions,
            cfg.eval_rows_per_kind,
            Some(&gn),
            &mut stage,
        )?;
        panoman_model::train::Evaluation {
            representation_error: repr,
            timings: panoman_model::train::EvaluationTimings {
                evaluation_s: t.elapsed().as_secs_f64(),
                curves_s: 0.0,
            },
            curves: Vec::new(),
        }
    } else {
        evaluate(&model, &ds, &regions, &cfg, &mut stage)
            .with_context(|| a.data.display().to_string())?
    };
    stage("");
    pb.finish_and_clear();
    let mut report = base_report;
    report.representation_error = Some(eval.representation_error.clone());
    report
        .timings
        .insert("evaluation_s".into(), eval.timings.evaluation_s);
    report
        .timings
        .insert("curves_s".into(), eval.timings.curves_s);
    write_atomic(&report_path, report_json(&report)?)?;
    // Fig. 7: CSV + PNG.
    let csv_path = PathBuf::from(format!("{}.fig7.csv", stem.display()));
    let png_path = PathBuf::from(format!("{}.fig7.png", stem.display()));
    if !a.skip_curves {
        component_curves_files(&csv_path, &png_path, &eval.curves)?;
    }
    let ev = &eval.representation_error;
    println!(
        "{}: {} model ({} shape, β {}), trained in {:.1} s",
        a.out.display(),
        topo_name,
        model.shape.n_components(),
        model
            .blocks
            .iter()
            .map(|b| format!("{} {}", b.name, b.n_components()))
            .collect::<Vec<_>>()
            .join(", "),
        t0.elapsed().as_secs_f64()
    );
    for (part, e) in [("body", &ev.body), ("face", &ev.face), ("hands", &ev.hands)] {
        println!(
            "  held-out {part:<5}: mean {:.2} mm (max {:.1}) | with correction {:.2} mm (max {:.1}) | exact rest shape {:.2} mm | whole-mesh alignment {:.2} mm  [{} rows]",
            e.mean_mm,
            e.max_mm,
            e.mean_mm_corrected,
            e.max_mm_corrected,
            e.mean_mm_exact_rest,
            e.mean_mm_whole_alignment,
            e.rows
        );
        if e.mean_mm_gn > 0.0 {
            println!(
                "      Gauss–Newton β: mean {:.2} mm (max {:.1}) | with correction {:.2} mm (max {:.1}); worst least-squares row {} (vertex {})",
                e.mean_mm_gn,
                e.max_mm_gn,
                e.mean_mm_gn_corrected,
                e.max_mm_gn_corrected,
                e.worst_row,
                e.worst_vertex
            );
        }
    }
    println!(
        "  report {}, curves {} / {}",
        report_path.display(),
        csv_path.display(),
        png_path.display()
    );
    Ok(())
}

/// The report as pretty JSON with every object's keys sorted (through `serde_json::Value`),
/// as the report files have always been written.
fn report_json(report: &TrainReport) -> Result<String> {
    Ok(serde_json::to_string_pretty(&serde_json::to_value(
        report,
    )?)?)
}
