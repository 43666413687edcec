//! `panoman bench --model M`: the model and fitting entries, on data generated the way
//! `panoman eval` generates it (its held-out people, its clip, the scan of `scan_bench`).

use super::bench::{BenchArgs, Reporter};
use crate::util::{SplitMix, time_runs};
use anyhow::Result;
use panoman::{Correction, Model, Params};
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// The entries of this module, in the order they run.
pub(crate) const NAMES: &[&str] = &[
    "model_load",
    "pose",
    "encode",
    "fit_cold",
    "track_warm",
    "fit_process",
    "fit_scan",
];

/// Three seeded random parameter sets: α ~ N(0, 1) (unit variance on the training
/// identities), each β coefficient uniform in the middle half of its training range.
fn random_params(model: &Model, seed: u64) -> Vec<Params> {
    let mut rng = SplitMix(seed);
    let mut u = move || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    (0..3)
        .map(|_| Params {
            alpha: (0..model.n_shape())
                .map(|_| {
                    let (a, b) = (u().max(1e-300), u());
                    (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
                })
                .collect(),
            beta: model
                .inner()
                .blocks
                .iter()
                .map(|b| {
                    let beta = b
                        .beta_range
                        .iter()
                        .map(|r| {
                            let (lo, hi) = (f64::from(r[0]), f64::from(r[1]));
                            0.5 * (lo + hi) + 0.25 * (hi - lo) * (2.0 * u() - 1.0)
                        })
                        .collect();
                    (b.name.clone(), beta)
                })
                .collect(),
            ..Default::default()
        })
        .collect()
}

/// Runs the model and fitting entries `rep` wants on the model file `path`.
pub(crate) fn run(rep: &Reporter, a: &BenchArgs, path: &Path, runs: usize) -> Result<()> {
    if rep.wants("model_load") {
        let t = time_runs(0, runs, || {
            std::hint::black_box(Model::load(path).expect("model load"));
        });
        rep.report(
            "model_load",
            &t,
            "(read + validate + topology tables and factorizations)",
        );
    }
    let t0 = Instant::now();
    let model = Model::load(path)?;
    let load_s = t0.elapsed().as_secs_f64();
    if !rep.json {
        println!(
            "model {} ({} topology, {} vertices, loaded in {load_s:.2} s)",
            path.display(),
            model.topology_name(),
            model.n_vertices()
        );
    }
    let params = random_params(&model, a.seed ^ 0x5eed);
    if rep.wants("pose") {
        let mut k = 0;
        let t = time_runs(1, runs, || {
            let v = model
                .pose(&params[k % params.len()], Correction::Apply)
                .expect("pose");
            std::hint::black_box(v.len());
            k += 1;
        });
        let extra = json!({"vertices": model.n_vertices(), "batch": 1});
        rep.report_with(
            "pose",
            &t,
            "(Model::pose, B = 1, correction on, random α/β)",
            extra.as_object().cloned().unwrap_or_default(),
        );
    }
    Ok(())
}
