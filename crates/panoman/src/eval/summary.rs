//! [`EvalSummary`]: every number of `panoman eval`, the layout of its `summary.json`.
use std::collections::BTreeMap;

use panoman_model::train::RepresentationError;
use serde::{Deserialize, Deserializer, Serialize};

use super::metrics::{PartErrors, RegionErrors};

/// Reads a number that may have been written as `null` (serde_json writes NaN and ±∞ as
/// `null`) back as NaN.
fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The summary of `panoman eval` (`summary.json`). Every error is in mm, every time in
/// seconds, on the held-out identities of the model's own dataset. Layout (top-level keys):
///
/// - `representation`: held-out representation error per part (`body`, `face`, `hands`:
///   [`panoman_model::train::PartError`]), paper Fig. 7 / 18;
/// - `fit_held_out`: fits from TC-133 keypoints ([`HeldOutFits`]), Fig. 19–20;
/// - `clip`: a held-out motion clip, PanoMan tracked vs the LBS rig per frame ([`ClipSummary`]);
/// - `twist`: the twist study ([`TwistSummary`]), Fig. 1 / 13;
/// - `composite`: which rows the composite motion was built from, or `null` ([`CompositeRows`]);
/// - `stress`: the stress set ([`StressSummary`]): composites, extreme shapes, large twists,
///   contacts and postures made by our generator beyond the training sampler, per case;
/// - `timing`: stage timings ([`TimingSummary`]), Table 1;
/// - `meta`: the run ([`EvalMeta`]);
/// - `headline`: the headline figures in one place ([`Headline`]).
///
/// Numbers that are NaN or infinite (e.g. a median of no samples) are written as `null` and
/// read back as NaN. `panoman eval` writes the keys of every object sorted.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EvalSummary {
    /// The held-out motion clip.
    pub clip: ClipSummary,
    /// Which rows the composite motion was built from (`null` when the dataset has no
    /// held-out face or hand rows).
    pub composite: Option<CompositeRows>,
    /// Fits of held-out people from exact and noisy keypoints.
    pub fit_held_out: HeldOutFits,
    /// The headline figures.
    pub headline: Headline,
    /// The run.
    pub meta: EvalMeta,
    /// Held-out representation error per part.
    pub representation: RepresentationError,
    /// The stress set.
    pub stress: StressSummary,
    /// Stage timings.
    pub timing: TimingSummary,
    /// The twist study.
    pub twist: TwistSummary,
}

/// `stress`: every case of the stress set, their means and the worst case.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct StressSummary {
    /// Per case, in the order they were run.
    pub cases: Vec<StressCase>,
    /// Means of the per-case means, max of the maxima.
    pub mean: PerMethod<PartErrors>,
    /// The case with the largest PanoMan mean error (rendered as `stress_worst.png`).
    pub worst_case: String,
    /// Cases whose mean error over all vertices exceeds 20 mm.
    pub cases_over_20mm: PerMethod<usize>,
    /// Cases where PanoMan's mean error is more than 3 % above the LBS baseline's.
    pub panoman_over_lbs_3pct: usize,
    /// Cases the failure detector flagged (`converged: false`).
    pub flagged: usize,
    /// Cases whose shell stage accepted at least one step.
    pub cases_with_accepted_steps: usize,
    /// Cases whose initializer was retried.
    pub retried: usize,
}

impl StressSummary {
    /// The summary of `cases`.
    pub fn of(cases: Vec<StressCase>) -> StressSummary {
        let (l, p): (Vec<PartErrors>, Vec<PartErrors>) = cases
            .iter()
            .map(|c| (c.errors.lbs, c.errors.panoman))
            .unzip();
        let worst_case = cases
            .iter()
            .max_by(|a, b| {
                a.errors
                    .panoman
                    .all_mean
                    .total_cmp(&b.errors.panoman.all_mean)
            })
            .map(|c| c.name.clone())
            .unwrap_or_default();
        let count = |f: &dyn Fn(&StressCase) -> bool| cases.iter().filter(|c| f(c)).count();
        StressSummary {
            mean: PerMethod {
                lbs: super::metrics::mean_of(&l),
                panoman: super::metrics::mean_of(&p),
            },
            worst_case,
            cases_over_20mm: PerMethod {
                lbs: count(&|c| c.errors.lbs.all_mean > 20.0),
                panoman: count(&|c| c.errors.panoman.all_mean > 20.0),
            },
            panoman_over_lbs_3pct: count(&|c| {
                c.errors.panoman.all_mean > 1.03 * c.errors.lbs.all_mean
            }),
            flagged: count(&|c| !c.converged),
            cases_with_accepted_steps: count(&|c| c.shell_steps_accepted > 0),
            retried: count(&|c| c.retried),
            cases,
        }
    }
}

/// One case of the stress set, fitted from its exact TC-133 keypoints.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct StressCase {
    /// Its name (`composite_0`, `old_slim_woman`, `twist_forearm_150`, `hand_on_head`, …).
    pub name: String,
    /// `composite`, `whole-body`, `extreme shape`, `twist`, `contact` or `posture`.
    pub kind: String,
    /// Per-vertex errors against the ground truth (mm).
    pub errors: PerMethod<PartErrors>,
    /// Mean per-vertex error per region: feet, legs, torso, arms, hands, face (mm).
    #[serde(default)]
    pub regions: PerMethod<RegionErrors>,
    /// Mean keypoint residual over the 133 keypoints (mm).
    pub keypoint_residual_mm: PerMethod<f64>,
    /// Shell LM steps tried over the fit's stages.
    pub shell_steps_tried: usize,
    /// Of those, accepted.
    pub shell_steps_accepted: usize,
    /// Largest distance between PanoMan's and the LBS fit's vertices (mm): 0 when the shell
    /// stage left the initializer's mesh as it was.
    pub differs_from_lbs_mm: f64,
    /// The failure detector's verdict.
    pub converged: bool,
    /// Why the detector flagged it (`null` when converged).
    pub reason: Option<String>,
    /// Whether the initializer was retried from other starts (its first result failed the
    /// quality check).
    pub retried: bool,
    /// IK + shell fit (s).
    pub seconds: f64,
    /// Twist measures of a twist case.
    pub twist: Option<StressTwist>,
    /// The ground truth encoded and posed again (`encode` with the true rest, correction
    /// applied): mean and max per-vertex error, mm; composites only, with
    /// [`super::EvalConfig::stress_representation`].
    #[serde(default)]
    pub representation_mm: Option<MeanMax>,
}

/// The twist measures of a stress case: the forearm's smallest cross-section radius over the
/// person's true rest, and the errors where the twist must be reproduced without collapse.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StressTwist {
    /// The forearm twist (degrees).
    pub angle_deg: f64,
    /// The upper arm's roll beside it (degrees; 0 for a forearm twist alone).
    #[serde(default)]
    pub upper_arm_deg: f64,
    /// The ground truth's (skinned, collapsing) ratio.
    #[serde(deserialize_with = "nan_if_null")]
    pub truth_min_radius_ratio: f64,
    /// Smallest slice radius ratio of the fit over the person's true rest.
    pub min_radius_ratio: PerMethod<f64>,
    /// The upper arm's (shoulder to elbow, 15–85 %) smallest slice radius ratio over the
    /// true rest: the ground truth's (skinned: an upper-arm roll collapses it too).
    #[serde(default, deserialize_with = "nan_if_null")]
    pub truth_upper_arm_min_radius_ratio: f64,
    /// The same for the fits.
    #[serde(default)]
    pub upper_arm_min_radius_ratio: PerMethod<f64>,
    /// Mean error over the shoulder region (vertices within 12 cm of the shoulder joint at
    /// rest, hand excluded; mm).
    pub shoulder_mean_mm: PerMethod<f64>,
    /// Mean error over the left hand (mm).
    pub hand_mean_mm: PerMethod<f64>,
}

/// One value per method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PerMethod<T> {
    /// The LBS rig (skeletal IK) baseline.
    pub lbs: T,
    /// PanoMan (IK initializer, then the shell fit).
    pub panoman: T,
}

/// `{"mean", "max"}` (mm).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MeanMax {
    /// Max over the people of the per-person max.
    pub max: f64,
    /// Mean over the people of the per-person mean.
    pub mean: f64,
}

/// `{"median", "min", "max"}` of a sample (s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MedianMinMax {
    /// Max.
    #[serde(deserialize_with = "nan_if_null")]
    pub max: f64,
    /// Median.
    #[serde(deserialize_with = "nan_if_null")]
    pub median: f64,
    /// Min.
    #[serde(deserialize_with = "nan_if_null")]
    pub min: f64,
}

impl MedianMinMax {
    /// The median, min and max of a sample (the median of an even count is the mean of the
    /// middle two); NaN for an empty sample.
    pub fn of(xs: &[f64]) -> MedianMinMax {
        let (median, min, max) = panoman_mesh::stats::median_min_max(xs);
        MedianMinMax { max, median, min }
    }
}

/// `fit_held_out`: held-out people fitted from their TC-133 keypoints (cold fits).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct HeldOutFits {
    /// Exact keypoints: mean over the people of the per-vertex errors, per part.
    pub exact: PerMethod<PartErrors>,
    /// Keypoint residuals of the exact-keypoint fits by `method/group` (`panoman/body`,
    /// `lbs/left_hand`, …).
    pub keypoint_residual_exact_mm: BTreeMap<String, MeanMax>,
    /// Keypoints with Gaussian noise σ = 5 mm per coordinate (the IK's priors set for it).
    pub noise_5mm: PerMethod<PartErrors>,
    /// People fitted.
    pub people: usize,
    /// Exact keypoints, per person.
    pub per_person_exact: Vec<PerMethod<PartErrors>>,
    /// What the PanoMan fits did, exact keypoints.
    #[serde(default)]
    pub stats_exact: FitStats,
    /// What the PanoMan fits did, 5 mm noise.
    #[serde(default)]
    pub stats_noise_5mm: FitStats,
}

/// What a set of PanoMan fits did: shell LM steps, the quality check, and how the fits
/// compare with their LBS initializer.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FitStats {
    /// Fits (frames).
    pub fits: usize,
    /// Shell LM steps tried over all fits and stages.
    pub steps_tried: usize,
    /// Shell LM steps accepted.
    pub steps_accepted: usize,
    /// Fits with at least one accepted step.
    pub fits_with_accepted_steps: usize,
    /// Fits whose vertices differ from their IK initializer's (by more than 1 µm somewhere).
    pub differs_from_lbs: usize,
    /// Fits whose mean vertex error is below the LBS baseline's.
    pub lower_error_than_lbs: usize,
    /// Fits flagged `converged: false`.
    pub not_converged: usize,
    /// Fits whose initializer was retried from other starts.
    pub ik_retried: usize,
    /// The distinct reasons of the fits flagged (at most 10).
    #[serde(default)]
    pub reasons: Vec<String>,
}

impl FitStats {
    /// Counts one fit: its report, its initializer's vertices, and the mean vertex errors
    /// (mm) of PanoMan and of the LBS baseline.
    pub(crate) fn add(
        &mut self,
        fit: &panoman_fit::FitResult,
        init: &[[f64; 3]],
        panoman_mm: f64,
        lbs_mm: f64,
    ) {
        let (t, a) = fit
            .report
            .stages
            .iter()
            .fold((0, 0), |(t, a), s| (t + s.iterations, a + s.accepted));
        self.fits += 1;
        self.steps_tried += t;
        self.steps_accepted += a;
        self.fits_with_accepted_steps += usize::from(a > 0);
        let differs = fit
            .vertices
            .iter()
            .zip(init)
            .any(|(x, y)| (0..3).any(|c| (x[c] - y[c]).abs() > 1e-6));
        self.differs_from_lbs += usize::from(differs);
        self.lower_error_than_lbs += usize::from(panoman_mm < lbs_mm);
        self.not_converged += usize::from(!fit.report.verdict.converged);
        self.ik_retried += usize::from(fit.report.verdict.retried);
        if let Some(r) = &fit.report.verdict.reason()
            && self.reasons.len() < 10
            && !self.reasons.contains(r)
        {
            self.reasons.push(r.clone());
        }
    }
}

/// `clip`: a held-out synthetic clip; PanoMan tracked with warm starts, the LBS rig fitted per
/// frame (warm-started from its previous frame).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ClipSummary {
    /// First frame's PanoMan time (IK + shell fit, s); `null` for an empty clip.
    pub first_frame_s: Option<f64>,
    /// Frames.
    pub frames: usize,
    /// LBS errors over the frames (mean of means, max of maxima).
    pub lbs: PartErrors,
    /// PanoMan errors over the frames.
    pub panoman: PartErrors,
    /// PanoMan time of the warm-started frames (all but the first).
    pub warm_s: MedianMinMax,
    /// What the PanoMan frames did (LM steps, quality check, comparison with LBS).
    #[serde(default)]
    pub stats: FitStats,
}

/// `twist`: limbs twisted about their bone by the LBS rig, fitted from their keypoints.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TwistSummary {
    /// The twist angles (degrees).
    pub angles_deg: Vec<f64>,
    /// Per limb.
    pub limbs: Vec<TwistLimb>,
}

/// One limb of the twist study.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TwistLimb {
    /// The rig bone twisted.
    pub bone: String,
    /// `forearm`, `upper arm`, `wrist` or `neck`.
    pub limb: String,
    /// One row per angle.
    pub rows: Vec<TwistRow>,
}

/// One twist angle of one limb. Radius ratios: minimum over the limb segment's slices of the
/// posed over the rest cross-section radius; volume changes: enclosed volume over the rest
/// volume − 1, in %.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistRow {
    /// Twist (degrees).
    #[serde(deserialize_with = "nan_if_null")]
    pub angle_deg: f64,
    /// The LBS fit's mean keypoint residual (mm).
    #[serde(deserialize_with = "nan_if_null")]
    pub lbs_fit_keypoint_mean_mm: f64,
    /// The LBS fit's radius ratio.
    #[serde(deserialize_with = "nan_if_null")]
    pub lbs_fit_min_radius_ratio: f64,
    /// The LBS fit's volume change (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub lbs_fit_volume_change_pct: f64,
    /// PanoMan's mean keypoint residual (mm).
    #[serde(deserialize_with = "nan_if_null")]
    pub panoman_keypoint_mean_mm: f64,
    /// PanoMan's radius ratio.
    #[serde(deserialize_with = "nan_if_null")]
    pub panoman_min_radius_ratio: f64,
    /// PanoMan's radius ratio over its own rest shape `B_S(α)`.
    #[serde(deserialize_with = "nan_if_null")]
    pub panoman_own_rest_min_radius_ratio: f64,
    /// PanoMan's volume change (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub panoman_volume_change_pct: f64,
    /// The target's (LBS rig, true pose) radius ratio.
    #[serde(deserialize_with = "nan_if_null")]
    pub rig_min_radius_ratio: f64,
    /// The target's volume change (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub rig_volume_change_pct: f64,
}

/// `composite`: the dataset rows whose fits gave the body, expression and gesture blocks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CompositeRows {
    /// Body (β_B, α and placement) from this row's fit.
    pub body_from_row: usize,
    /// Face blocks from this row's fit.
    pub expression_from_row: usize,
    /// Hand blocks from this row's fit.
    pub gesture_from_row: usize,
}

/// Timing of one stage over several runs (s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    /// Max.
    #[serde(deserialize_with = "nan_if_null")]
    pub max_s: f64,
    /// Median.
    #[serde(deserialize_with = "nan_if_null")]
    pub median_s: f64,
    /// Min.
    #[serde(deserialize_with = "nan_if_null")]
    pub min_s: f64,
    /// Runs.
    pub runs: usize,
}

/// `timing`: stage times of the cold held-out fits and of the warm clip frames.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct TimingSummary {
    /// The paper's total per frame (274.5 s).
    pub paper_total_s: f64,
    /// Cold fits (exact keypoints) by stage: `ik`, the shell fit's stages, `total`.
    pub stages: BTreeMap<String, StageTiming>,
    /// Warm clip frames, whole frame.
    pub warm_clip_frame_s: MedianMinMax,
    /// Warm clip frames by stage: `ik` and the shell fit's stages.
    pub warm_stages: BTreeMap<String, StageTiming>,
}

/// `meta`: what was evaluated.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct EvalMeta {
    /// The dataset directory, as given.
    pub data: String,
    /// The model file, as given.
    pub model: String,
    /// The preset's name.
    pub preset: String,
    /// Wall time of the whole evaluation (s).
    pub seconds: f64,
    /// The seed of the clip and the keypoint noise.
    pub seed: u64,
    /// The model's topology (`full` or `small`).
    pub topology: String,
}

/// The twist study's volume changes at the largest angle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistVolumes {
    /// The angle (degrees).
    #[serde(deserialize_with = "nan_if_null")]
    pub angle_deg: f64,
    /// LBS fit (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub lbs_fit_volume_change_pct: f64,
    /// PanoMan (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub panoman_volume_change_pct: f64,
    /// The target (%).
    #[serde(deserialize_with = "nan_if_null")]
    pub rig_volume_change_pct: f64,
}

/// `headline`: the headline figures.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Headline {
    /// Clip, mean over all vertices (mm).
    pub clip_mean_mm: PerMethod<f64>,
    /// Median total time of a cold fit (`timing.stages.total.median_s`).
    pub cold_fit_median_s: Option<f64>,
    /// Held-out fits from exact keypoints, mean over all vertices (mm).
    pub fit_exact_mean_mm: PerMethod<f64>,
    /// Held-out fits from 5 mm-noise keypoints, mean over all vertices (mm).
    pub fit_noise_5mm_mean_mm: PerMethod<f64>,
    /// PanoMan's smallest forearm radius ratio for twists in 120–170°.
    pub forearm_twist_120_170_min_radius_ratio_panoman: Option<f64>,
    /// As above, over PanoMan's own rest shape.
    pub forearm_twist_120_170_min_radius_ratio_panoman_own_rest: Option<f64>,
    /// Per limb, the volume changes at the largest angle.
    pub twist_largest_angle: BTreeMap<String, TwistVolumes>,
    /// Median PanoMan time of a warm clip frame (s).
    #[serde(deserialize_with = "nan_if_null")]
    pub warm_frame_median_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> EvalSummary {
        EvalSummary {
            composite: None,
            clip: ClipSummary::default(),
            fit_held_out: HeldOutFits::default(),
            headline: Headline {
                warm_frame_median_s: f64::NAN,
                ..Default::default()
            },
            meta: EvalMeta::default(),
            representation: RepresentationError::default(),
            stress: StressSummary::of(vec![StressCase {
                name: "twist_forearm_150".into(),
                twist: Some(StressTwist {
                    truth_min_radius_ratio: f64::NAN,
                    ..Default::default()
                }),
                ..Default::default()
            }]),
            timing: TimingSummary::default(),
            twist: TwistSummary {
                angles_deg: vec![0.0, 180.0],
                limbs: vec![TwistLimb {
                    bone: "neck02".into(),
                    limb: "neck".into(),
                    rows: vec![TwistRow {
                        rig_min_radius_ratio: f64::INFINITY,
                        ..Default::default()
                    }],
                }],
            },
        }
    }

    #[test]
    fn layout_keeps_the_summary_json_keys() {
        let v = serde_json::to_value(sample()).unwrap();
        let keys: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
        assert_eq!(
            keys,
            [
                "clip",
                "composite",
                "fit_held_out",
                "headline",
                "meta",
                "representation",
                "stress",
                "timing",
                "twist"
            ]
        );
        assert!(v["stress"]["cases"][0]["twist"]["truth_min_radius_ratio"].is_null());
        assert_eq!(v["stress"]["worst_case"], "twist_forearm_150");
        assert!(v["composite"].is_null());
        assert!(v["headline"]["warm_frame_median_s"].is_null());
        assert!(v["twist"]["limbs"][0]["rows"][0]["rig_min_radius_ratio"].is_null());
        assert!(v["representation"]["body"]["mean_mm_corrected"].is_number());
    }

    #[test]
    fn non_finite_numbers_round_trip_as_nan_and_missing_keys_fail() {
        let v = serde_json::to_value(sample()).unwrap();
        let back: EvalSummary = serde_json::from_value(v.clone()).unwrap();
        assert!(back.headline.warm_frame_median_s.is_nan());
        assert!(back.twist.limbs[0].rows[0].rig_min_radius_ratio.is_nan());
        assert_eq!(serde_json::to_value(&back).unwrap(), v);
        let mut renamed = v;
        let clip = renamed.as_object_mut().unwrap().remove("clip").unwrap();
        renamed["clip_renamed"] = clip;
        assert!(serde_json::from_value::<EvalSummary>(renamed).is_err());
    }
}
