//! Stage timings (Table 1) and the headline figures.
use std::collections::BTreeMap;

use super::fitting::StageTimes;
use super::summary::{
    ClipSummary, Headline, HeldOutFits, MedianMinMax, PerMethod, StageTiming, TimingSummary,
    TwistSummary, TwistVolumes,
};
use panoman_mesh::stats::median_min_max;

/// Paper Table 1: total seconds per frame.
const PAPER_TOTAL_S: f64 = 274.5;

fn stats(times: &StageTimes) -> BTreeMap<String, StageTiming> {
    times
        .iter()
        .map(|(name, xs)| {
            let (median_s, min_s, max_s) = median_min_max(xs);
            let t = StageTiming {
                max_s,
                median_s,
                min_s,
                runs: xs.len(),
            };
            (name.clone(), t)
        })
        .collect()
}

/// The `timing` section from the cold fits' and the warm clip frames' stage times.
pub(crate) fn summary(
    cold: &StageTimes,
    warm: &StageTimes,
    warm_frame: &MedianMinMax,
) -> TimingSummary {
    TimingSummary {
        paper_total_s: PAPER_TOTAL_S,
        stages: stats(cold),
        warm_clip_frame_s: *warm_frame,
        warm_stages: stats(warm),
    }
}

/// The `headline` section.
pub(crate) fn headline(
    fit: &HeldOutFits,
    clip: &ClipSummary,
    twist: &TwistSummary,
    timing: &TimingSummary,
) -> Headline {
    let mut twist_largest_angle = BTreeMap::new();
    let (mut forearm_min, mut forearm_own_min) = (f64::INFINITY, f64::INFINITY);
    for l in &twist.limbs {
        if let Some(last) = l.rows.last() {
            let v = TwistVolumes {
                angle_deg: last.angle_deg,
                lbs_fit_volume_change_pct: last.lbs_fit_volume_change_pct,
                panoman_volume_change_pct: last.panoman_volume_change_pct,
                rig_volume_change_pct: last.rig_volume_change_pct,
            };
            twist_largest_angle.insert(l.limb.clone(), v);
        }
        if l.limb == "forearm" {
            for r in l
                .rows
                .iter()
                .filter(|r| (120.0..=170.0).contains(&r.angle_deg))
            {
                forearm_min = forearm_min.min(r.panoman_min_radius_ratio);
                forearm_own_min = forearm_own_min.min(r.panoman_own_rest_min_radius_ratio);
            }
        }
    }
    let finite = |x: f64| x.is_finite().then_some(x);
    Headline {
        clip_mean_mm: PerMethod {
            lbs: clip.lbs.all_mean,
            panoman: clip.panoman.all_mean,
        },
        cold_fit_median_s: timing.stages.get("total").map(|t| t.median_s),
        fit_exact_mean_mm: PerMethod {
            lbs: fit.exact.lbs.all_mean,
            panoman: fit.exact.panoman.all_mean,
        },
        fit_noise_5mm_mean_mm: PerMethod {
            lbs: fit.noise_5mm.lbs.all_mean,
            panoman: fit.noise_5mm.panoman.all_mean,
        },
        forearm_twist_120_170_min_radius_ratio_panoman: finite(forearm_min),
        forearm_twist_120_170_min_radius_ratio_panoman_own_rest: finite(forearm_own_min),
        twist_largest_angle,
        warm_frame_median_s: timing.warm_clip_frame_s.median,
    }
}
