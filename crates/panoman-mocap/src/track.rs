//! Tracking of retargeted motion from the TC-133 keypoints of its own meshes (issue 13: "CMU
//! `01_01` retargeted … tracked from the keypoints of the generated meshes").
//!
//! Per selected frame: the rig generator (embedded in the model) poses the frame's
//! [`GeneratorParams`] — the ground truth, mapped onto the model's topology —, the model's
//! keypoints of that mesh ([`panoman::Model::keypoints`]) are the only targets, and two
//! [`panoman::Tracker`]s fit them in frame order: PanoMan (skeletal IK warm-started from the
//! previous frame, then the shell fit with temporal terms) and the LBS baseline (the IK
//! alone, warm-started). Both are the trackers of `panoman track`; the per-vertex errors are
//! those of `panoman eval`'s clip ([`panoman::eval::Groups`]: no alignment, world frame).
//!
//! The layout's six foot keypoints (big toe, little toe and heel of each foot, what OpenPose
//! BODY_25 and COCO-WholeBody detectors add to a body layout) observe the feet's flexion.
//! [`TrackOptions::without_feet`] drops them (the older TC-127 layout, whose body stops at the
//! ankles); with `contacts` ([`TrackOptions::contacts`]) the trackers then get the foot–floor
//! contact prior ([`panoman::feet::ContactPrior`]), detected from the frames' own ankle
//! keypoints: no observation beyond TC-127.
//!
//! Units: metres in the API (meshes, keypoints), millimetres and milliseconds in the report.

use std::time::Instant;

use panoman::eval::{Groups, MeshTriple, PartErrors};
use panoman::{FitRequest, IkStart, Method, Model, ShapeCalibrationOptions, Targets, Tracker, V3};
use panoman_fit::shape_calibration::spread_frames;
use panoman_human::params::GeneratorParams;
use panoman_mesh::stats::median;
use serde::Serialize;

use crate::bvh::Bvh;
use crate::error::{MocapError, Result};
use crate::retarget::CmuRetarget;

/// A frame selection `start:end:step` (`end` exclusive; `None` = to the last frame), as
/// parsed by [`crate::solve_run::parse_frames`].
pub type FrameRange = (usize, Option<usize>, usize);

/// The frames of `range` in a sequence of `n_frames` frames, ascending.
///
/// # Errors
/// [`MocapError::Invalid`] when the step is 0, `end ≤ start`, or no frame of the range lies
/// below `n_frames` (an empty selection).
pub fn select_frames(n_frames: usize, range: FrameRange) -> Result<Vec<usize>> {
    let (start, end, step) = range;
    let bad = |what: String| Err(MocapError::Invalid { what });
    if step == 0 {
        return bad("frame step must be ≥ 1".into());
    }
    if end.is_some_and(|e| e <= start) {
        return bad(format!("empty frame range {start}:{}", end.unwrap_or(0)));
    }
    let stop = end.unwrap_or(n_frames).min(n_frames);
    if start >= stop {
        return bad(format!(
            "frame range {start}:{}:{step} selects no frame of the {n_frames} frames",
            end.map(|e| e.to_string()).unwrap_or_default()
        ));
    }
    Ok((start..stop).step_by(step).collect())
}

/// One tracked frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TrackFrame {
    /// The frame's index in the source sequence (e.g. the BVH frame).
    pub frame: usize,
    /// PanoMan's per-vertex errors against the generated mesh (mm; all / body / face /
    /// hands, mean and max).
    pub panoman: PartErrors,
    /// The LBS baseline's per-vertex errors (mm).
    pub lbs: PartErrors,
    /// PanoMan's wall time for the frame (`Tracker::track`: IK + shell fit), ms.
    pub panoman_ms: f64,
    /// The LBS baseline's wall time for the frame, ms.
    pub lbs_ms: f64,
    /// Whether PanoMan's fit passed its quality check.
    pub panoman_converged: bool,
    /// Whether the LBS fit passed its quality check.
    pub lbs_converged: bool,
}

/// Statistics of one method over the tracked frames.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MethodStats {
    /// Mean over frames of the per-frame mean per-vertex error, mm.
    pub mean_mm: f64,
    /// Median over frames of the per-frame mean per-vertex error, mm.
    pub median_mm: f64,
    /// Largest per-frame mean per-vertex error, mm.
    pub max_mm: f64,
    /// The source frame index of `max_mm`.
    pub worst_frame: usize,
    /// Largest single-vertex error over all frames, mm.
    pub max_vertex_mm: f64,
    /// Means over frames of the per-part means (body, face, hands), mm.
    pub body_mean_mm: f64,
    /// See `body_mean_mm`.
    pub face_mean_mm: f64,
    /// See `body_mean_mm`.
    pub hands_mean_mm: f64,
    /// Mean wall time per frame, ms (every frame, the cold first one included).
    pub ms_per_frame: f64,
    /// Median wall time per frame, ms.
    pub median_ms_per_frame: f64,
    /// Mean wall time of the warm frames (all but the first), ms; the first frame's if there
    /// is only one.
    pub warm_ms_per_frame: f64,
    /// Frames whose fit failed its quality check.
    pub not_converged: usize,
}

/// What [`track_generated`] measures.
#[derive(Clone, Debug, Serialize)]
pub struct TrackReport {
    /// Per tracked frame, in order.
    pub frames: Vec<TrackFrame>,
    /// PanoMan over the frames.
    pub panoman: MethodStats,
    /// The LBS baseline over the frames.
    pub lbs: MethodStats,
    /// Mean time to generate a ground-truth mesh and its keypoints, ms.
    pub generate_ms_per_frame: f64,
    /// Setup of both trackers (rig, solvers), s.
    pub setup_seconds: f64,
    /// The model's vertex count (the topology errors are measured on).
    pub n_vertices: usize,
    /// The keypoint layout the trackers were given: `TC-133`, or `TC-127` with
    /// [`TrackOptions::without_feet`].
    pub layout: String,
    /// The shape calibration, with [`TrackOptions::shape_frames`] > 0.
    pub calibration: Option<TrackCalibration>,
    /// The contact prior, with [`TrackOptions::contacts`].
    pub contacts: Option<TrackContacts>,
    /// Ground truth and both fits of PanoMan's worst frame (`panoman.worst_frame`; metres,
    /// the model's topology).
    #[serde(skip)]
    pub worst: Option<MeshTriple>,
}

pub use panoman::feet::{ContactOptions, ContactPrior};

/// What the trackers of [`track_generated`] are given besides the keypoints.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackOptions {
    /// Drop the six foot keypoints from the targets: the older TC-127 layout (module docs).
    pub without_feet: bool,
    /// Calibrate the identity's lengths from this many frames spread over the selection
    /// before tracking ([`panoman::Fitter::calibrate_shape`] on their keypoints; both
    /// trackers then hold the calibrated lengths,
    /// [`Tracker::set_shape`]); 0: none, the IK's six phenotype values only.
    pub shape_frames: usize,
    /// The foot–floor contact prior ([`panoman::feet::FootContacts`]): contacts detected
    /// from the frames' own ankle keypoints, each planted foot's sole held level by the IK.
    /// No observation beyond TC-127.
    pub contacts: Option<ContactOptions>,
    /// Source frame rate, Hz (the times of the contact detector's ankle speeds; set by
    /// [`track_retarget`] from the BVH). Needed with `contacts`.
    pub frame_rate: f64,
}

/// The contact prior of a [`track_generated`] run.
#[derive(Clone, Debug, Serialize)]
pub struct TrackContacts {
    /// Per foot (left, right) the floor level of the ankle, metres along up.
    pub floor: [f64; 2],
    /// Per foot the number of frames with contact weight ≥ ½.
    pub frames_down: [usize; 2],
    /// Per foot the mean contact weight over the frames.
    pub mean_weight: [f64; 2],
}

/// The shape calibration of a [`track_generated`] run.
#[derive(Clone, Debug, Serialize)]
pub struct TrackCalibration {
    /// The source frames it used.
    pub frames: Vec<usize>,
    /// The fitted length knobs (`(first local change, value)`, [`panoman::LENGTH_KNOBS`]).
    pub knobs: Vec<(String, f64)>,
    /// Mean keypoint distance over its frames before and after, mm.
    pub before_mm: f64,
    /// See `before_mm`.
    pub after_mm: f64,
    /// Wall time, s.
    pub seconds: f64,
}

/// Progress of [`track_generated`]: `(frames done, frames in all, the last frame's row)`.
pub type TrackProgress<'a> = &'a mut dyn FnMut(usize, usize, &TrackFrame);

fn stats(
    rows: &[TrackFrame],
    pick: impl Fn(&TrackFrame) -> (PartErrors, f64, bool),
) -> MethodStats {
    let n = rows.len().max(1) as f64;
    let errs: Vec<f64> = rows.iter().map(|r| pick(r).0.all_mean).collect();
    let ms: Vec<f64> = rows.iter().map(|r| pick(r).1).collect();
    let (worst, max) =
        errs.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |(k, m), (i, &e)| {
                if e > m { (i, e) } else { (k, m) }
            },
        );
    let part = |f: fn(&PartErrors) -> f64| rows.iter().map(|r| f(&pick(r).0)).sum::<f64>() / n;
    let warm = if ms.len() > 1 { &ms[1..] } else { &ms[..] };
    MethodStats {
        mean_mm: errs.iter().sum::<f64>() / n,
        median_mm: median(&mut errs.clone()),
        max_mm: max,
        worst_frame: rows.get(worst).map_or(0, |r| r.frame),
        max_vertex_mm: rows.iter().map(|r| pick(r).0.all_max).fold(0.0, f64::max),
        body_mean_mm: part(|p| p.body_mean),
        face_mean_mm: part(|p| p.face_mean),
        hands_mean_mm: part(|p| p.hands_mean),
        ms_per_frame: ms.iter().sum::<f64>() / n,
        median_ms_per_frame: median(&mut ms.clone()),
        warm_ms_per_frame: warm.iter().sum::<f64>() / warm.len().max(1) as f64,
        not_converged: rows.iter().filter(|r| !pick(r).2).count(),
    }
}

fn inv(what: impl Into<String>) -> MocapError {
    MocapError::Invalid { what: what.into() }
}

/// Tracks the meshes of `frames` — `(source frame index, generator parameters)` in order —
/// from their keypoints with PanoMan and the LBS baseline (see the module docs) and
/// measures the per-vertex error of both against the generated meshes.
///
/// The meshes are generated by the rig embedded in `model` on the model's topology
/// (`(V, 3)`, metres); an identity is built once per distinct shape. The targets are the
/// model's keypoints of each generated mesh, less the feet with
/// [`TrackOptions::without_feet`]. `progress` hears every finished frame.
///
/// # Errors
/// [`MocapError::Invalid`] for no frames, a model without an embedded rig or on a topology
/// the generator does not map to, parameters the generator rejects (naming the frame), and
/// tracker failures (naming the frame and the method).
pub fn track_generated(
    model: &Model,
    frames: &[(usize, GeneratorParams)],
    opts: TrackOptions,
    progress: TrackProgress,
) -> Result<TrackReport> {
    if frames.is_empty() {
        return Err(inv("no frames to track"));
    }
    let rig = model
        .rig()
        .cloned()
        .ok_or_else(|| inv("the model carries no rig (see `panoman embed-rig`)"))?;
    let topology = model
        .output_topology()
        .map_err(|e| inv(format!("model: {e}")))?;
    let groups = Groups::of_model(model);
    let feet = panoman_human::keypoints::KeypointGroup::Feet.range();
    let has_feet = feet.clone().all(|i| {
        model
            .keypoint_names()
            .contains(&panoman_human::keypoints::keypoint_names()[i])
    });
    if !opts.without_feet && !has_feet {
        return Err(inv(
            "the model's keypoints have no foot points (a model of the TC-127 layout: train \
             it anew, or track without the feet)",
        ));
    }
    let t_setup = Instant::now();
    let tracker = |method| {
        let req = FitRequest {
            method,
            ..FitRequest::default()
        };
        Tracker::new(model, req, IkStart::Warm).map_err(|e| inv(format!("tracker: {e}")))
    };
    let (mut pm, mut lbs) = (tracker(Method::PanoMan)?, tracker(Method::Lbs)?);
    let setup_seconds = t_setup.elapsed().as_secs_f64();
    let mut truth = GroundTruth {
        model,
        rig: &rig,
        topology,
        without_feet: opts.without_feet,
        identity: None,
    };
    let calibration = match opts.shape_frames {
        0 => None,
        n => Some(calibrate(&mut pm, &mut lbs, &mut truth, frames, n)?),
    };
    if let Some(co) = &opts.contacts {
        if !(opts.frame_rate.is_finite() && opts.frame_rate > 0.0) {
            return Err(inv(format!(
                "contacts need the frame rate (got {} Hz)",
                opts.frame_rate
            )));
        }
        // The frames' ankles (one more generation per frame, 0.4 ms; the meshes are not kept).
        let ankles = frames
            .iter()
            .map(|(f, p)| {
                let a = panoman::feet::ankles(&truth.frame(*f, p)?.1)
                    .map_err(|name| inv(format!("frame {f}: no {name} keypoint")))?;
                Ok((*f as f64 / opts.frame_rate, a))
            })
            .collect::<Result<Vec<_>>>()?;
        let prior = ContactPrior::new(model, &ankles, co).map_err(|e| inv(e.to_string()))?;
        pm.set_contacts(Some(prior.clone()));
        lbs.set_contacts(Some(prior));
    }
    let mut rows: Vec<TrackFrame> = Vec::with_capacity(frames.len());
    let mut worst: Option<MeshTriple> = None;
    let mut gen_s = 0.0;
    for (k, (f, p)) in frames.iter().enumerate() {
        let t = Instant::now();
        let (truth, targets) = truth.frame(*f, p)?;
        gen_s += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let a = pm
            .track(&targets)
            .map_err(|e| inv(format!("frame {f}: PanoMan: {e}")))?;
        let panoman_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let b = lbs
            .track(&targets)
            .map_err(|e| inv(format!("frame {f}: LBS: {e}")))?;
        let lbs_ms = t.elapsed().as_secs_f64() * 1e3;
        let row = TrackFrame {
            frame: *f,
            panoman: groups.errors(&a.vertices, &truth),
            lbs: groups.errors(&b.vertices, &truth),
            panoman_ms,
            lbs_ms,
            panoman_converged: a.report.converged(),
            lbs_converged: b.report.converged(),
        };
        if rows
            .iter()
            .all(|r| r.panoman.all_mean < row.panoman.all_mean)
        {
            worst = Some(MeshTriple {
                truth,
                panoman: a.vertices,
                lbs: b.vertices,
            });
        }
        rows.push(row);
        progress(k + 1, frames.len(), &row);
    }
    Ok(TrackReport {
        panoman: stats(&rows, |r| (r.panoman, r.panoman_ms, r.panoman_converged)),
        lbs: stats(&rows, |r| (r.lbs, r.lbs_ms, r.lbs_converged)),
        generate_ms_per_frame: gen_s * 1e3 / rows.len() as f64,
        setup_seconds,
        n_vertices: model.n_vertices(),
        layout: if opts.without_feet {
            panoman_human::keypoints::LAYOUT_NAME_TC127
        } else {
            panoman_human::keypoints::LAYOUT_NAME
        }
        .to_string(),
        calibration,
        contacts: pm.contacts().map(|p| {
            let w = &p.contacts.weights;
            let n = w.len().max(1) as f64;
            TrackContacts {
                floor: p.contacts.floor,
                frames_down: p.frames_down(),
                mean_weight: [0, 1].map(|s| w.iter().map(|x| x[s]).sum::<f64>() / n),
            }
        }),
        frames: rows,
        worst,
    })
}

/// The ground truth of [`track_generated`]'s frames: the rig's meshes on the model's topology
/// and their keypoints as targets; an identity is built once per distinct shape.
struct GroundTruth<'a> {
    model: &'a Model,
    rig: &'a panoman_human::rigfile::RigData,
    topology: panoman_human::outputs::OutputTopology,
    without_feet: bool,
    identity: Option<(
        panoman_human::params::ShapeParams,
        panoman_human::generator::Identity<'a>,
    )>,
}

impl GroundTruth<'_> {
    /// Frame `f` of parameters `p`: its mesh and its targets.
    fn frame(&mut self, f: usize, p: &GeneratorParams) -> Result<(Vec<V3>, Targets)> {
        let at = |e: &dyn std::fmt::Display| inv(format!("frame {f}: {e}"));
        p.shape.validate().map_err(|e| at(&e))?;
        p.pose
            .validate(self.rig.generator.bone_names())
            .map_err(|e| at(&e))?;
        if self.identity.as_ref().is_none_or(|(s, _)| *s != p.shape) {
            let id = self.rig.generator.identity(&p.shape).map_err(|e| at(&e))?;
            self.identity = Some((p.shape.clone(), id));
        }
        let id = &self.identity.as_ref().expect("identity built above").1;
        let truth = self.rig.map.map(self.topology, &id.pose(&p.pose).vertices);
        let kp = self.model.keypoints(&truth).map_err(|e| at(&e))?;
        let mut targets = Targets::from_keypoints(&kp);
        if self.without_feet {
            targets.keypoints = std::mem::take(&mut targets.keypoints)
                .without_group(panoman_human::keypoints::KeypointGroup::Feet);
        }
        Ok((truth, targets))
    }
}

/// The identity's lengths calibrated on `n` frames spread over `frames`
/// ([`Tracker::calibrate_shape`]), given to both trackers.
fn calibrate(
    pm: &mut Tracker,
    lbs: &mut Tracker,
    truth: &mut GroundTruth<'_>,
    frames: &[(usize, GeneratorParams)],
    n: usize,
) -> Result<TrackCalibration> {
    let picked = spread_frames(frames.len(), n);
    let t = Instant::now();
    let targets = picked
        .iter()
        .map(|&i| truth.frame(frames[i].0, &frames[i].1).map(|(_, t)| t))
        .collect::<Result<Vec<_>>>()?;
    let cal = pm
        .calibrate_shape(&targets, &ShapeCalibrationOptions::default())
        .map_err(|e| inv(format!("shape calibration: {e}")))?;
    lbs.set_shape(Some(cal.shape.clone()));
    Ok(TrackCalibration {
        frames: picked.iter().map(|&i| frames[i].0).collect(),
        knobs: cal
            .knobs
            .iter()
            .map(|(k, v)| (k.name().to_string(), *v))
            .collect(),
        before_mm: cal.before_mm,
        after_mm: cal.after_mm,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// [`track_generated`] on the retarget `rt` of `bvh` (in metres, as calibrated): the
/// generator parameters of the frames `range` selects.
///
/// # Errors
/// [`select_frames`]'s for the range, then [`track_generated`]'s.
pub fn track_retarget(
    model: &Model,
    rt: &CmuRetarget,
    bvh: &Bvh,
    range: FrameRange,
    opts: TrackOptions,
    progress: TrackProgress,
) -> Result<TrackReport> {
    let frames = select_frames(bvh.n_frames(), range)?;
    let params: Vec<(usize, GeneratorParams)> =
        frames.iter().map(|&f| (f, rt.params(bvh, f))).collect();
    let opts = TrackOptions {
        frame_rate: bvh.rate_hz(),
        ..opts
    };
    track_generated(model, &params, opts, progress)
}
