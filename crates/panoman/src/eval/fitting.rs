//! Held-out people fitted from exact and noisy TC-133 keypoints (Fig. 19–20).
use std::collections::BTreeMap;
use std::path::Path;

use panoman_fit::fit::{FitResult, keypoint_residuals};
use panoman_fit::{Constraints, ik_config_for_noise};
use panoman_human::keypoints::{KeypointGroup, KeypointsFile};
use panoman_mesh::geom::V3;

use super::metrics::{Noise, PartErrors, mean_of, part_errors, to_v3};
use super::summary::{FitStats, HeldOutFits, MeanMax, PerMethod};
use super::{Bench, EvalPreset, EvalProgress, MeshTriple};
use crate::error::{Error, Result};

/// Stage times by stage name (s), one entry per run.
pub(crate) type StageTimes = BTreeMap<String, Vec<f64>>;

/// What the held-out fits give the later experiments.
pub(crate) struct HeldOut {
    pub(crate) summary: HeldOutFits,
    /// The body rows fitted, in order.
    pub(crate) pick: Vec<usize>,
    /// Cold-fit stage times (exact keypoints).
    pub(crate) stage_times: StageTimes,
    /// The first person's exact fit.
    pub(crate) first_fit: Option<MeshTriple>,
    /// The exact fits, in order.
    pub(crate) fits: Vec<FitResult>,
}

/// Keypoint residuals accumulated per (method, keypoint group): Σ mean (mm), max (mm), people.
type ResidualSums = BTreeMap<(&'static str, KeypointGroup), (f64, f64, usize)>;

/// Evenly spaced held-out body rows, `preset.people` of them at most.
fn pick_people(b: &Bench, preset: &EvalPreset, data: &Path) -> Result<Vec<usize>> {
    let body_rows = b.held_out_rows(1);
    if body_rows.is_empty() {
        return Err(Error::Format {
            path: data.to_path_buf(),
            what: "no held-out body rows".into(),
        });
    }
    let n = preset.people.min(body_rows.len());
    Ok((0..n).map(|i| body_rows[i * body_rows.len() / n]).collect())
}

fn noisy(kp: &[V3], noise: &mut Noise) -> Vec<V3> {
    kp.iter()
        .map(|p| {
            [
                p[0] + 0.005 * noise.next(),
                p[1] + 0.005 * noise.next(),
                p[2] + 0.005 * noise.next(),
            ]
        })
        .collect()
}

fn record_times(times: &mut StageTimes, ik_s: f64, fit: &FitResult) {
    times.entry("ik".into()).or_default().push(ik_s);
    for s in &fit.report.stages {
        times.entry(s.name.clone()).or_default().push(s.seconds);
    }
    times
        .entry("total".into())
        .or_default()
        .push(ik_s + fit.report.seconds);
}

/// Fits each picked person from exact keypoints, then from keypoints with 5 mm noise (the
/// IK's priors set for σ = 5 mm), PanoMan and the LBS rig from one IK each.
pub(crate) fn run(
    b: &mut Bench,
    preset: &EvalPreset,
    seed: u64,
    data: &Path,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<HeldOut> {
    let pick = pick_people(b, preset, data)?;
    let mut noise = Noise::for_seed(seed);
    let (mut exact, mut noise_5mm) = (Vec::new(), Vec::new());
    let mut out = HeldOut {
        summary: HeldOutFits::default(),
        pick: pick.clone(),
        stage_times: StageTimes::new(),
        first_fit: None,
        fits: Vec::new(),
    };
    let mut kp_res = ResidualSums::new();
    let (mut stats_exact, mut stats_noisy) = (FitStats::default(), FitStats::default());
    let noisy_opts = panoman_fit::FitOptions {
        quality: panoman_fit::quality::QualityOptions::for_noise(0.005),
        ..b.opts.clone()
    };
    let total = 2 * pick.len();
    for (i, &r) in pick.iter().enumerate() {
        let truth = to_v3(b.ds.vertices(r)?);
        let kp = b.model.inner().keypoints.evaluate(&truth);
        for is_noisy in [false, true] {
            let pts = if is_noisy {
                noisy(&kp, &mut noise)
            } else {
                kp.clone()
            };
            let c = Constraints::from_keypoints(KeypointsFile::from_all(&pts));
            let ikc = if is_noisy {
                ik_config_for_noise(0.005)
            } else {
                b.ikc.clone()
            };
            let opts = if is_noisy { &noisy_opts } else { &b.opts };
            let (ikr, fit) = b.solver.fit(&c, &ikc, opts, None)?;
            let errors = PerMethod {
                lbs: part_errors(&ikr.posed, &truth, &b.groups),
                panoman: part_errors(&fit.vertices, &truth, &b.groups),
            };
            let st = if is_noisy {
                &mut stats_noisy
            } else {
                &mut stats_exact
            };
            st.add(
                &fit,
                &ikr.posed,
                errors.panoman.all_mean,
                errors.lbs.all_mean,
            );
            progress(EvalProgress::Step {
                done: 2 * i + 1 + usize::from(is_noisy),
                total,
            });
            if is_noisy {
                noise_5mm.push(errors);
                continue;
            }
            exact.push(errors);
            for (m, x) in [("panoman", &fit.vertices), ("lbs", &ikr.posed)] {
                for (g, r) in keypoint_residuals(b.model.inner(), &c.targets.keypoints, x) {
                    let e = kp_res.entry((m, g)).or_insert((0.0, 0.0f64, 0usize));
                    e.0 += r.mean_mm;
                    e.1 = e.1.max(r.max_mm);
                    e.2 += 1;
                }
            }
            record_times(&mut out.stage_times, ikr.seconds, &fit);
            if out.first_fit.is_none() {
                out.first_fit = Some(MeshTriple {
                    truth: truth.clone(),
                    panoman: fit.vertices.clone(),
                    lbs: ikr.posed.clone(),
                });
            }
            out.fits.push(fit);
        }
    }
    out.summary = HeldOutFits {
        exact: per_method_mean(&exact),
        keypoint_residual_exact_mm: kp_res
            .iter()
            .map(|((m, g), (s, mx, n))| {
                (
                    format!("{m}/{g}"),
                    MeanMax {
                        max: *mx,
                        mean: s / *n as f64,
                    },
                )
            })
            .collect(),
        noise_5mm: per_method_mean(&noise_5mm),
        people: pick.len(),
        per_person_exact: exact,
        stats_exact,
        stats_noise_5mm: stats_noisy,
    };
    Ok(out)
}

/// [`mean_of`] per method.
pub(crate) fn per_method_mean(xs: &[PerMethod<PartErrors>]) -> PerMethod<PartErrors> {
    let (l, p): (Vec<PartErrors>, Vec<PartErrors>) = xs.iter().map(|e| (e.lbs, e.panoman)).unzip();
    PerMethod {
        lbs: mean_of(&l),
        panoman: mean_of(&p),
    }
}
