//! Fit quality (docs/design/shell-fit.md §7): keypoint-residual thresholds, shape
//! plausibility and the verdict a fit carries (`converged`, `reason`, the IK attempts).
//!
//! **Thresholds.** With exact keypoints a fit that found the right basin leaves a residual of
//! a fraction of a millimetre (default model, 10 held-out people: IK body mean 0.47 mm, worst
//! keypoint 5.9 mm; PanoMan 0.05 / 0.5 mm). A wrong basin (a limb through the body, a crossed
//! arm, the wrong body shape) leaves centimetres. With Gaussian noise of σ per coordinate the
//! distance of a keypoint to its noise-free position has the χ₃ distribution: rms `√3·σ`, mean
//! `1.6σ`, and the largest of 127 about `3.9σ`; the fit absorbs part of it, so these bound the
//! expected residual from above. A group fails when
//!
//! ```text
//! mean > mean_mm + noise_mean_factor · √3 σ     (defaults 10 mm, 2)
//! max  > max_mm  + noise_max_factor  · √3 σ     (defaults 50 mm, 4)
//! ```
//!
//! i.e. 10 / 50 mm for exact keypoints (20× the measured good mean, 8× the good max) and
//! 27 / 85 mm at σ = 5 mm. The IK initializer is checked against twice these
//! ([`QualityOptions::initializer_factor`]). **Plausibility**: the shape coefficients α (PCA projection of the
//! initializer's rest shape) fail when some `|α_i|/σ_i` of a *leading* component (one that
//! explains at least [`LEADING_VARIANCE`] = 1 % of the training variance; σ_i the PCA's
//! standard deviation) exceeds [`QualityOptions::alpha_sigma`] (default 5: a Gaussian prior
//! puts 6e−7 of its mass beyond). The trailing components are left out: on the default model
//! the first component explains 99.4 %, the others are estimated from few identities, and a
//! held-out person fitted to 0.06 mm scores |α_i|/σ_i ≈ 5 on them (rms 4.8), so a test over
//! all components flagged every clip frame. A fitted phenotype value on its bound 0 or 1 is
//! noted in the reason of a failed check (not a failure on its own: real people reach them).
use crate::fit::GroupResidual;
use crate::ik::{IK_PHENOTYPE, IkResult};
use panoman_human::keypoints::KeypointGroup;
use panoman_model::model::PanoManModel;
use serde::Serialize;
use std::collections::BTreeMap;

/// Thresholds of the quality check (module docs). Lengths in mm except `keypoint_sigma`.
#[derive(Clone, Debug, PartialEq)]
pub struct QualityOptions {
    /// Expected keypoint noise σ (metres per coordinate; 0 for exact keypoints). Default 0.
    pub keypoint_sigma: f64,
    /// Mean residual of a group allowed with exact keypoints (mm). Default 10.
    pub mean_mm: f64,
    /// Largest residual of one keypoint allowed with exact keypoints (mm). Default 50.
    pub max_mm: f64,
    /// Multiple of `√3 σ` added to `mean_mm`. Default 2.
    pub noise_mean_factor: f64,
    /// Multiple of `√3 σ` added to `max_mm`. Default 4.
    pub noise_max_factor: f64,
    /// Largest `|α_i|/σ_i` of a plausible shape over the leading components (module docs).
    /// Default 5.
    pub alpha_sigma: f64,
    /// Retry a failed initializer from other starts ([`crate::pipeline::robust_ik`]). Default
    /// true.
    pub retry: bool,
    /// Factor on all thresholds for the IK initializer (its check triggers the retries and,
    /// if still failing, `converged: false`). Default 2: a person the rig cannot reproduce
    /// exactly (the template mesh itself: IK body mean 10.1 mm on the full template, 11.2 mm
    /// on the small one) is met by the final fit to 0.1–1.6 mm, while a wrong basin leaves
    /// ≥ 30 mm.
    pub initializer_factor: f64,
}

impl Default for QualityOptions {
    fn default() -> Self {
        QualityOptions {
            keypoint_sigma: 0.0,
            mean_mm: 10.0,
            max_mm: 50.0,
            noise_mean_factor: 2.0,
            noise_max_factor: 4.0,
            alpha_sigma: 5.0,
            retry: true,
            initializer_factor: 2.0,
        }
    }
}

impl QualityOptions {
    /// The quality options for keypoints with noise σ (metres per coordinate).
    pub fn for_noise(sigma: f64) -> Self {
        QualityOptions {
            keypoint_sigma: sigma.max(0.0),
            ..Self::default()
        }
    }

    /// The options of the initializer's check: the residual thresholds scaled by
    /// [`QualityOptions::initializer_factor`].
    pub fn for_initializer(&self) -> Self {
        let f = self.initializer_factor.max(1.0);
        QualityOptions {
            mean_mm: f * self.mean_mm,
            max_mm: f * self.max_mm,
            noise_mean_factor: f * self.noise_mean_factor,
            noise_max_factor: f * self.noise_max_factor,
            ..self.clone()
        }
    }

    /// `(mean, max)` thresholds in mm for this noise level (module docs).
    pub fn thresholds_mm(&self) -> Thresholds {
        let s = 1e3 * 3f64.sqrt() * self.keypoint_sigma.max(0.0);
        Thresholds {
            mean_mm: self.mean_mm + self.noise_mean_factor * s,
            max_mm: self.max_mm + self.noise_max_factor * s,
        }
    }

    /// The problems of a set of group residuals (empty when every group passes), e.g.
    /// `body keypoint mean 31.2 mm > 10.0 mm`.
    pub fn keypoint_problems(&self, res: &BTreeMap<KeypointGroup, GroupResidual>) -> Vec<Problem> {
        let t = self.thresholds_mm();
        let mut out = Vec::new();
        for (g, r) in res {
            if r.n == 0 {
                continue;
            }
            if r.mean_mm.is_nan() || r.mean_mm > t.mean_mm {
                out.push(Problem::KeypointMean {
                    group: *g,
                    mean_mm: r.mean_mm,
                    threshold_mm: t.mean_mm,
                });
            } else if r.max_mm.is_nan() || r.max_mm > t.max_mm {
                out.push(Problem::KeypointMax {
                    group: *g,
                    max_mm: r.max_mm,
                    threshold_mm: t.max_mm,
                });
            }
        }
        out
    }

    /// The problems of shape coefficients α: a leading component's `|α_i|/σ_i` above
    /// [`QualityOptions::alpha_sigma`].
    pub fn shape_problems(&self, model: &PanoManModel, alpha: &[f64]) -> Vec<Problem> {
        let z = alpha_leading_sigma(model, alpha);
        if z.is_nan() || z > self.alpha_sigma {
            vec![Problem::Shape {
                sigmas: z,
                threshold: self.alpha_sigma,
            }]
        } else {
            Vec::new()
        }
    }
}

/// One failed quality check. Written (reports, JSON) as one line, e.g. `body keypoint mean
/// 31.2 mm > 10.0 mm`; a verdict's `reason` joins its problems with `; `.
#[derive(Clone, Debug, PartialEq)]
pub enum Problem {
    /// A group's mean keypoint residual is above the threshold (mm).
    KeypointMean {
        /// The group.
        group: KeypointGroup,
        /// Its mean residual (mm; NaN fails).
        mean_mm: f64,
        /// The threshold (mm).
        threshold_mm: f64,
    },
    /// A group's largest keypoint residual is above the threshold (mm).
    KeypointMax {
        /// The group.
        group: KeypointGroup,
        /// Its largest residual (mm; NaN fails).
        max_mm: f64,
        /// The threshold (mm).
        threshold_mm: f64,
    },
    /// The shape is outside the PCA prior: a leading component's `|α_i|/σ_i` is above
    /// [`QualityOptions::alpha_sigma`].
    Shape {
        /// The largest `|α_i|/σ_i` over the leading components.
        sigmas: f64,
        /// The bound.
        threshold: f64,
    },
    /// Fitted phenotype values sit on their bounds (noted with another failure), e.g.
    /// `muscle = 1`.
    PhenotypeAtBounds(Vec<String>),
    /// A problem of the initializer's chosen start.
    Initializer(Box<Problem>),
    /// The initializer was retried from this many starts.
    StartsTried(usize),
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Problem::KeypointMean {
                group,
                mean_mm,
                threshold_mm,
            } => write!(
                f,
                "{group} keypoint mean {mean_mm:.1} mm > {threshold_mm:.1} mm"
            ),
            Problem::KeypointMax {
                group,
                max_mm,
                threshold_mm,
            } => write!(
                f,
                "{group} keypoint max {max_mm:.1} mm > {threshold_mm:.1} mm"
            ),
            Problem::Shape { sigmas, threshold } => write!(
                f,
                "shape outside the PCA prior (|α|/σ {sigmas:.1} > {threshold:.1} on a leading component)"
            ),
            Problem::PhenotypeAtBounds(v) => {
                write!(f, "phenotype on its bounds: {}", v.join(", "))
            }
            Problem::Initializer(p) => write!(f, "initializer: {p}"),
            Problem::StartsTried(n) => write!(f, "{n} initializer starts tried"),
        }
    }
}

impl Serialize for Problem {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

/// The thresholds of one fit (mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Thresholds {
    /// Mean residual allowed per group (mm).
    pub mean_mm: f64,
    /// Largest residual allowed per keypoint (mm).
    pub max_mm: f64,
}

/// Share of the training variance a shape component must explain to be checked.
pub const LEADING_VARIANCE: f64 = 0.01;

/// The largest `|α_i|/σ_i` over the shape PCA's leading components (explained variance ratio
/// ≥ [`LEADING_VARIANCE`], σ_i > 0); 0 for an empty α.
pub fn alpha_leading_sigma(model: &PanoManModel, alpha: &[f64]) -> f64 {
    let sh = &model.shape;
    alpha
        .iter()
        .zip(&sh.std_devs)
        .zip(&sh.explained_variance_ratio)
        .filter(|((_, s), r)| **s > 0.0 && **r >= LEADING_VARIANCE)
        .map(|((a, s), _)| (a / s).abs())
        .fold(0.0, f64::max)
}

/// Keypoint residuals per group (mm) of an IK result, from its per-target residuals with
/// weight > 0.
pub fn ik_group_residuals(r: &IkResult) -> BTreeMap<KeypointGroup, GroupResidual> {
    crate::fit::group_residuals(
        r.residuals
            .iter()
            .filter(|e| e.weight > 0.0)
            .map(|e| (e.index, 1e3 * e.distance)),
    )
}

/// The fitted phenotype values of `r` that sit on a bound (0 or 1), e.g. `muscle = 1`.
pub fn phenotype_at_bounds(r: &IkResult) -> Vec<String> {
    IK_PHENOTYPE
        .iter()
        .zip(r.state.phenotype)
        .filter(|(_, v)| *v <= 1e-9 || *v >= 1.0 - 1e-9)
        .map(|(n, v)| format!("{n} = {}", v.round()))
        .collect()
}

/// One start of the initializer, as reported.
#[derive(Clone, Debug, Serialize)]
pub struct IkAttempt {
    /// The start: `first`, `cold`, `strong_priors`, `mean_shape`, `phenotype m<muscle>
    /// w<weight>`.
    pub name: String,
    /// Mean keypoint residual over all targets (mm).
    pub mean_mm: f64,
    /// Largest keypoint residual (mm).
    pub max_mm: f64,
    /// The IK objective (priors included; m²).
    pub cost: f64,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// What failed the quality check (empty: passed).
    pub problems: Vec<Problem>,
    /// Whether this start was kept.
    pub chosen: bool,
}

impl IkAttempt {
    /// The attempt `name` of result `r` with its problems.
    pub fn of(name: &str, r: &IkResult, problems: Vec<Problem>) -> Self {
        let max = r
            .residuals
            .iter()
            .filter(|e| e.weight > 0.0)
            .map(|e| 1e3 * e.distance)
            .fold(0.0, f64::max);
        IkAttempt {
            name: name.to_string(),
            mean_mm: r.mean_residual_mm(),
            max_mm: max,
            cost: r.cost,
            iterations: r.iterations,
            problems,
            chosen: false,
        }
    }
}

/// The verdict of a fit: whether it converged to an acceptable fit, why not, and what the
/// initializer tried.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    /// True when the final keypoint residuals are within the thresholds and the shape is
    /// plausible.
    pub converged: bool,
    /// Why not (empty when converged): the failed checks. Written as `reason`, the problems
    /// joined with `; ` ([`Verdict::reason`]).
    #[serde(
        rename = "reason",
        serialize_with = "joined",
        skip_serializing_if = "Vec::is_empty"
    )]
    pub problems: Vec<Problem>,
    /// The thresholds applied (mm).
    pub thresholds: Thresholds,
    /// Whether the initializer was retried from other starts.
    pub retried: bool,
    /// The initializer's starts (one when the first passed).
    pub ik_attempts: Vec<IkAttempt>,
}

impl Verdict {
    /// A verdict from the final problems (empty: converged).
    pub fn from_problems(
        problems: Vec<Problem>,
        opts: &QualityOptions,
        ik_attempts: Vec<IkAttempt>,
    ) -> Self {
        Verdict {
            converged: problems.is_empty(),
            problems,
            thresholds: opts.thresholds_mm(),
            retried: ik_attempts.len() > 1,
            ik_attempts,
        }
    }

    /// Why the fit did not converge: its problems joined with `; ` (`None` when converged).
    pub fn reason(&self) -> Option<String> {
        (!self.problems.is_empty()).then(|| {
            self.problems
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("; ")
        })
    }
}

/// Serializes problems as one line, joined with `; `.
fn joined<S: serde::Serializer>(p: &[Problem], s: S) -> std::result::Result<S::Ok, S::Error> {
    let v: Vec<String> = p.iter().map(ToString::to_string).collect();
    s.serialize_str(&v.join("; "))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn res(mean: f64, max: f64) -> BTreeMap<KeypointGroup, GroupResidual> {
        [(
            KeypointGroup::Body,
            GroupResidual {
                n: 15,
                mean_mm: mean,
                max_mm: max,
            },
        )]
        .into()
    }

    /// Exact keypoints: 10 / 50 mm; σ = 5 mm adds 2·√3·5 and 4·√3·5 mm; NaN fails.
    #[test]
    fn thresholds_follow_the_noise() {
        let q = QualityOptions::default();
        assert_eq!(q.thresholds_mm().mean_mm, 10.0);
        assert!(q.keypoint_problems(&res(0.5, 6.0)).is_empty());
        assert_eq!(q.keypoint_problems(&res(30.0, 60.0)).len(), 1);
        assert!(matches!(
            q.keypoint_problems(&res(2.0, 60.0))[0],
            Problem::KeypointMax { max_mm: 60.0, .. }
        ));
        let nan = &q.keypoint_problems(&res(f64::NAN, 1.0))[0];
        assert!(matches!(nan, Problem::KeypointMean { mean_mm, .. } if mean_mm.is_nan()));
        // One line each, as reports have always written them.
        assert_eq!(
            q.keypoint_problems(&res(30.0, 60.0))[0].to_string(),
            "body keypoint mean 30.0 mm > 10.0 mm"
        );
        let v = Verdict::from_problems(
            vec![
                Problem::Initializer(Box::new(Problem::StartsTried(2))),
                Problem::PhenotypeAtBounds(vec!["muscle = 1".into()]),
            ],
            &q,
            Vec::new(),
        );
        assert_eq!(
            v.reason().as_deref(),
            Some("initializer: 2 initializer starts tried; phenotype on its bounds: muscle = 1")
        );
        assert_eq!(
            serde_json::to_value(&v).unwrap()["reason"],
            serde_json::json!(v.reason().unwrap())
        );
        let n = QualityOptions::for_noise(0.005).thresholds_mm();
        assert!((n.mean_mm - (10.0 + 2.0 * 3f64.sqrt() * 5.0)).abs() < 1e-9);
        assert!((n.max_mm - (50.0 + 4.0 * 3f64.sqrt() * 5.0)).abs() < 1e-9);
        assert!(
            QualityOptions::for_noise(0.005)
                .keypoint_problems(&res(20.0, 60.0))
                .is_empty()
        );
    }
}
