//! A held-out motion clip: PanoMan tracked with warm starts versus the LBS rig fitted per
//! frame (warm-started from its own previous frame).
use panoman_fit::fit::warm_fit_options;
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Constraints, Tracking, ik_fit};
use panoman_human::clip::{Clip, ClipConfig};
use panoman_human::keypoints::KeypointsFile;
use serde::{Deserialize, Serialize};

use super::fitting::StageTimes;
use super::metrics::{PartErrors, mean_of, part_errors};
use super::summary::{ClipSummary, FitStats, MedianMinMax};
use super::{Bench, EvalPreset, EvalProgress, MeshTriple};
use crate::error::Result;

/// One clip frame (a row of `clip.csv`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClipRow {
    /// PanoMan's per-vertex errors (mm).
    pub panoman: PartErrors,
    /// The LBS rig's per-vertex errors (mm).
    pub lbs: PartErrors,
    /// PanoMan's time (IK + shell fit, s).
    pub panoman_s: f64,
    /// The LBS rig's time (s).
    pub lbs_s: f64,
}

/// What the clip gives the summary and the renders.
pub(crate) struct ClipRun {
    pub(crate) summary: ClipSummary,
    pub(crate) frames: Vec<ClipRow>,
    /// Stage times of the warm frames (all but the first).
    pub(crate) warm_stage_times: StageTimes,
    /// PanoMan time of the warm frames.
    pub(crate) warm_s: MedianMinMax,
    /// The middle frame.
    pub(crate) map_frame: Option<MeshTriple>,
}

/// Generates the clip of `seed` and fits every frame by both methods.
pub(crate) fn run(
    b: &mut Bench,
    preset: &EvalPreset,
    seed: u64,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<ClipRun> {
    let clip = Clip::generate(&ClipConfig {
        seed,
        n_frames: preset.clip_frames,
        n_keyframes: preset.clip_keyframes,
    })?;
    let (_, truths) = clip.meshes(&b.rig().generator, &b.rig().map, b.rig().topology)?;
    let mut seq = Tracking::new(b.opts.clone(), warm_fit_options(), b.ikc.clone(), false);
    let mut prev_lbs: Option<IkState> = None;
    let mut frames: Vec<ClipRow> = Vec::new();
    let mut warm_times = Vec::new();
    let mut warm_stage_times = StageTimes::new();
    let mut map_frame = None;
    let mut stats = FitStats::default();
    for (f, truth) in truths.iter().enumerate() {
        let c = Constraints::from_keypoints(KeypointsFile::from_all(
            &b.model.inner().keypoints.evaluate(truth),
        ));
        let (ikr, fit) = seq.fit_next(&mut b.solver, &c)?;
        // The LBS baseline's frames use the PanoMan sequence's IK settings.
        let lbs = ik_fit(
            b.solver.ik(),
            &c,
            &IkConfig {
                initial_state: prev_lbs.clone(),
                ..seq.ik_config(&b.ikc, prev_lbs.is_some())
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
        let (pe, le) = (
            part_errors(&fit.vertices, truth, &b.groups),
            part_errors(&lbs.posed, truth, &b.groups),
        );
        stats.add(&fit, &ikr.posed, pe.all_mean, le.all_mean);
        frames.push(ClipRow {
            panoman: pe,
            lbs: le,
            panoman_s: secs,
            lbs_s: lbs.seconds,
        });
        if f == truths.len() / 2 {
            map_frame = Some(MeshTriple {
                truth: truth.clone(),
                panoman: fit.vertices,
                lbs: lbs.posed.clone(),
            });
        }
        prev_lbs = Some(lbs.state);
        progress(EvalProgress::Step {
            done: f + 1,
            total: truths.len(),
        });
    }
    let warm_s = MedianMinMax::of(&warm_times);
    let pm: Vec<PartErrors> = frames.iter().map(|r| r.panoman).collect();
    let lbs: Vec<PartErrors> = frames.iter().map(|r| r.lbs).collect();
    Ok(ClipRun {
        summary: ClipSummary {
            first_frame_s: frames.first().map(|r| r.panoman_s),
            frames: frames.len(),
            lbs: mean_of(&lbs),
            panoman: mean_of(&pm),
            warm_s,
            stats,
        },
        frames,
        warm_stage_times,
        warm_s,
        map_frame,
    })
}
