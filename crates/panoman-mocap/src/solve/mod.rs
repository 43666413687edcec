//! MoSh-style solving of optical markers with PanoMan or the LBS rig (issue 13, part 2).
//!
//! * **Calibration** ([`MarkerSolver::calibrate`]): on `calibration_frames` frames spread
//!   over the capture, alternating (a) a pose per frame — skeletal IK of the rig to the
//!   markers as surface points (`solve_with_points`), the six phenotype values fitted per
//!   frame in the first round and then held at their mean — and (b) a marker step: each
//!   marker's surface point is moved to the mean, over the frames, of the closest surface
//!   point to `observed − offset·n̂`, taken back to the rest mesh, shrunk toward its initial
//!   location (one pseudo-observation) and kept within `marker_prior_m` of it; its offset
//!   is the mean signed normal distance, shrunk toward the initial offset. From the second
//!   half of the rounds on, each marker's surface point also moves with the pose
//!   ([`PosePlacement`]: linear in the angles of the bones around it, fitted by ridge
//!   regression on the calibration frames; `pose_placement_ridge`). PanoMan's α is the
//!   shape-PCA projection of the calibrated rest mesh. In calibration and tracking the IK
//!   bounds the forearm's roll by ±`forearm_roll_deg` (90°, the sampler's ±30° elsewhere).
//! * **Tracking** ([`MarkerSolver::track`]): every frame the markers are surface-point
//!   targets `observed − offset·n̂` (n̂ the current normal at the marker's surface point,
//!   the surface point placed for the IK round's starting pose),
//!   missing ones skipped, down-weighted by Geman–McClure IRLS
//!   (`w = (σ²/(σ² + r²))²`, σ = `robust_sigma_m`; a marker whose residual exceeds
//!   `outlier_m` counts as an outlier). LBS: the IK, warm-started from the previous frame.
//!   PanoMan: that IK as initializer, then the shell fit toward PanoMan's guidance pose with
//!   the markers as handles (each marker pulls its triangle's three vertices, weighted by
//!   the barycentric coordinates, so that the triangle's marker point lands on its target),
//!   α fixed, the previous frame's fit as temporal term ([`panoman_fit::Previous`]).
//! * **Held-out marker error** ([`MarkerSolver::held_out`]): k folds over the markers; each
//!   fold is tracked without its markers on every `held_out_step`-th frame (the calibration
//!   frames left out), with the full calibration (MoSh: shape and placement are calibrated
//!   once with every marker) or, with `held_out_recalibrate`, a calibration of its own
//!   without them; a left-out marker's error is the distance of its observation from its
//!   surface point + offset **of the full calibration** on the solved mesh (placed for the
//!   solved pose, [`SolvedFrame::map`]). `mean` counts
//!   the markers that stay observable in their fold ([`MarkerSolver::observable`]),
//!   `mean_all` every one; capture glitches ([`crate::glitch`]) are missing observations.
use std::collections::BTreeMap;
use std::time::Instant;

use faer::linalg::solvers::Solve;
use panoman::Method;
use panoman_fit::ik::{IkConfig, IkResult, IkState, IkTargets, PointTarget, TemporalPrior};
use panoman_fit::{Constraints, FitOptions, FrameSolver, Previous, VertexHandle};
use panoman_human::params::{GeneratorParams, ShapeParams};
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{V3, add, dot, matvec, norm, scale, sub};
use panoman_model::model::Params;
use serde::Serialize;

use crate::error::{MocapError, Result};
use crate::marker_map::{
    MarkerMap, RestTemplate, closest_point, closest_point_among, surface_normal, surface_point,
    vertex_normals,
};
use crate::markers::MarkerSequence;

mod calibrate;
mod held_out;
mod placement;
mod tracking;

pub use placement::{PosePlacement, marker_patches, ridge_fit};
pub use tracking::mean_max_mm;

/// Controls of a solve.
#[derive(Clone, Debug)]
pub struct SolveOptions {
    /// PanoMan or the LBS rig.
    pub method: Method,
    /// Frames of the calibration (spread over the capture). Default 64: each marker's
    /// placement and the shape are means over these frames, and more poses pin them down
    /// better (LBS, full captures, 8 rounds, held-out `mean` at 24 / 64 / 128 frames: nick
    /// 11.25 / 10.54 / 10.43 mm, Thomas every 2nd frame 13.73 / 13.25 / 13.22 mm;
    /// docs/design/mocap.md).
    pub calibration_frames: usize,
    /// Pose / marker-placement alternations. Default 12. The alternation converges slowly
    /// (a marker's placement and the pose share its residual): nick's calibration residual
    /// 6.15 / 5.79 / 5.62 / 5.48 mm after 8 / 12 / 16 / 24 rounds, held-out (LBS) 10.54 /
    /// 10.19 / 10.00 / 9.80 mm. On Thomas a few markers' placements start to hop between
    /// rounds after about 10 (the mean move stalls near 0.8 mm, the largest 6–19 mm) and at
    /// 16 rounds one held-out fold's wrist flips (`LWRB` 34 → 75 mm; held-out 13.12 → 14.17
    /// mm): 12 improves both captures. Calibration time grows linearly (≈ 1.7 s per round
    /// with 64 frames on a 2-core machine).
    pub calibration_rounds: usize,
    /// Largest move of a marker's surface point from its initial place (m). Default 0.12 (the
    /// shipped rules place some markers, e.g. `cmu53`'s back-head ones, 5–10 cm off).
    pub marker_prior_m: f64,
    /// σ of the Geman–McClure weights (m). Default 0.03.
    pub robust_sigma_m: f64,
    /// Residual above which a marker counts as an outlier (m). Default 0.05.
    pub outlier_m: f64,
    /// IK iterations of a warm-started tracking frame. Default 8.
    pub track_iterations: usize,
    /// IRLS rounds (normals and weights updated) per tracking frame. Default 2.
    pub track_rounds: usize,
    /// λ_θ of the rig's pose prior (m², see `IkConfig::pose_prior`). Default 1e-6.
    pub pose_prior: f64,
    /// λ_T of the tracking's temporal prior toward the previous solved frame's bone angles
    /// (m², `IkConfig::temporal`, every bone), divided by the square of the frame gap (a
    /// velocity prior: held-out folds tracked on every `k`-th frame get `1/k²` of it).
    /// Default 3e-4: on nick frames 0–399 (LBS) the mesh's mean vertex acceleration
    /// 64.5 → 30.4 m/s² (the observed markers' 16.9), held-out 9.91 → 9.87 mm, fitted
    /// residual 5.80 → 6.08 mm; on Thomas (0–799, every 2nd) 12.9 → 7.0 m/s² (markers 6.6),
    /// held-out 13.98 → 13.75 mm, fitted 8.01 → 7.49 mm (docs/design/mocap.md). 0: none.
    pub temporal_prior: f64,
    /// PanoMan: σ (m) of each marker's surface patch ([`marker_patches`] on the calibrated
    /// rest mesh): the shell fit pulls the vertices within 2σ of an observed marker by the
    /// marker's displacement, Gaussian-weighted, so that the surface between markers follows
    /// them (a soft-tissue field; the LBS solve has no surface stage). Default 0.08; 0: the
    /// marker's triangle only.
    pub patch_sigma_m: f64,
    /// PanoMan: weight of a patch's handles relative to the marker's own (its triangle).
    /// Default 10.
    pub patch_weight: f64,
    /// Folds of the held-out marker error (0: none). Default 5.
    pub held_out_folds: usize,
    /// Every this many frames of the solved range are tracked per fold. Default 1: each fold
    /// is tracked as the solve tracks, frame after frame with the temporal prior at its
    /// strength, and every solved frame is measured (2026-12-06: 10 before, which measured a
    /// tenth of the frames with a hundredth of the temporal prior; Thomas' held-out mean
    /// 10.33 → 10.10 mm with PanoMan, 10.69 → 10.47 with LBS, the same solve). A step `k`
    /// divides the held-out time by about `k`.
    pub held_out_step: usize,
    /// Each held-out fold is calibrated anew without its markers (true: the stricter
    /// protocol, which also measures how consistently the calibration converges) or tracked
    /// with the full calibration (false: MoSh's protocol — shape and marker placement are
    /// calibrated once with every marker, the markers are held out of the per-frame solve).
    /// Default false.
    pub held_out_recalibrate: bool,
    /// Weight of a marker's initial place in the calibration's marker step, in
    /// pseudo-observations (frames). Default 1.
    pub placement_prior_weight: f64,
    /// Threshold of [`crate::glitch::find_glitches`] (m): [`crate::solve_run::solve_capture`]
    /// treats the glitches as missing (0: keeps every observation). Default 0.04.
    pub glitch_m: f64,
    /// Lower threshold of [`crate::glitch::find_glitches`] (m): a glitch run goes on through
    /// the frames whose score stays above it (hysteresis; `≥ glitch_m`: off). Default 0.02,
    /// half of `glitch_m`.
    pub glitch_low_m: f64,
    /// Ridge `λ` (rad², per frame) of the pose-dependent marker placements
    /// ([`PosePlacement`], fitted after calibration round ⌈R/2⌉ and after each later one);
    /// 0: each marker keeps one fixed surface point. Default 0.05. Held-out `mean`, full
    /// captures (`panoman mocap eval`), fixed → pose-dependent, PanoMan / LBS: nick 9.92 /
    /// 10.21 → 8.57 / 9.01 mm, Thomas (every 2nd frame) 11.47 / 11.89 → 10.33 / 10.69 mm;
    /// calibrated on the first half and evaluated on the second (LBS): nick 11.43 → 11.00,
    /// Thomas 13.44 → 12.30 mm (docs/design/mocap.md "Markers slide with the pose").
    pub pose_placement_ridge: f64,
    /// The forearm's roll range of the rig's IK, ±degrees ([`IkConfig::forearm_roll_deg`]);
    /// 0: the sampler's ±30°. Default 90, the forearm's own range (pronation and
    /// supination): with ±30° Thomas' fencing arm sits on the bound while its wrist bar
    /// rolls further (docs/design/mocap.md "The forearm rolls ±90°").
    pub forearm_roll_deg: f64,
    /// PanoMan's shell-fit options of a warm-started tracking frame (the first frame uses
    /// `FitOptions::default()`). Default [`panoman_fit::fit::warm_fit_options`].
    pub warm_fit: FitOptions,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            method: Method::PanoMan,
            calibration_frames: 64,
            calibration_rounds: 12,
            marker_prior_m: 0.12,
            robust_sigma_m: 0.03,
            outlier_m: 0.05,
            track_iterations: 8,
            track_rounds: 2,
            pose_prior: 1e-6,
            temporal_prior: 3e-4,
            patch_sigma_m: 0.08,
            patch_weight: 10.0,
            held_out_folds: 5,
            held_out_step: 1,
            held_out_recalibrate: false,
            placement_prior_weight: 1.0,
            glitch_m: 0.04,
            glitch_low_m: 0.02,
            pose_placement_ridge: 0.05,
            forearm_roll_deg: 90.0,
            warm_fit: panoman_fit::fit::warm_fit_options(),
        }
    }
}

/// The result of a calibration.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The calibrated markers (the capture's order).
    pub map: MarkerMap,
    /// The six fitted phenotype values (IK order).
    pub phenotype: [f64; 6],
    /// Rest mesh of the calibrated shape (template topology).
    pub rest: Vec<V3>,
    /// PanoMan shape α (projection of `rest`).
    pub alpha: Vec<f64>,
    /// The calibration frames (indices into the sequence).
    pub frames: Vec<usize>,
    /// Mean marker residual over the calibration frames after the last round (mm).
    pub mean_residual_mm: f64,
    /// Mean move of the surface points from the initial map (mm).
    pub mean_marker_shift_mm: f64,
    /// Per marker: its surface patch on `rest` ([`marker_patches`] with
    /// [`SolveOptions::patch_sigma_m`]), computed once.
    pub patches: Vec<Vec<(u32, f64)>>,
    /// Wall time (s).
    pub seconds: f64,
    /// Per marker: its pose-dependent placement (`None`: fixed at `map`'s; all `None` or
    /// empty when [`SolveOptions::pose_placement_ridge`] is 0).
    pub pose_placement: Vec<Option<PosePlacement>>,
}

impl Calibration {
    /// The pose-dependent placements and the rest mesh they live on; `None` when every
    /// marker keeps a fixed surface point (`pose_placement_ridge` 0, or too few frames).
    pub fn placement(&self) -> Option<(&[Option<PosePlacement>], &[V3])> {
        self.pose_placement
            .iter()
            .any(Option::is_some)
            .then_some((self.pose_placement.as_slice(), self.rest.as_slice()))
    }
}

/// One solved frame.
#[derive(Clone, Debug)]
pub struct SolvedFrame {
    /// Frame index in the sequence.
    pub frame: usize,
    /// Solved vertices (template topology, metres).
    pub vertices: Vec<V3>,
    /// The rig's parameters of the IK.
    pub rig_params: GeneratorParams,
    /// PanoMan parameters (PanoMan only).
    pub params: Option<Params>,
    /// Per marker: distance of the observation from the model marker (m); NaN when missing
    /// or not used.
    pub residuals: Vec<f64>,
    /// Markers counted as outliers.
    pub outliers: usize,
    /// Wall time (s).
    pub seconds: f64,
    /// Wall time per stage (s): `ik`, and for PanoMan the shell fit's stages (`shell_init`
    /// with the first β-step, `shell_keypoints` with the guidance and the V-step,
    /// `shell_params` with the last β-step and the placement).
    pub stage_seconds: Vec<(String, f64)>,
    /// The markers' placement of this frame when it is pose-dependent
    /// ([`PosePlacement`]; `None`: the calibration's fixed map, see [`SolvedFrame::map`]).
    pub placement: Option<MarkerMap>,
}

impl SolvedFrame {
    /// The marker map this frame was solved with: its pose-dependent placement, else the
    /// calibration's map.
    pub fn map<'a>(&'a self, cal: &'a Calibration) -> &'a MarkerMap {
        self.placement.as_ref().unwrap_or(&cal.map)
    }
}

/// Per-frame line of the report.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    /// Frame index in the file (first frame 0).
    pub frame: usize,
    /// Markers observed and used.
    pub markers: usize,
    /// Mean residual (mm).
    pub mean_mm: f64,
    /// Largest residual (mm).
    pub max_mm: f64,
    /// Outlier markers.
    pub outliers: usize,
    /// Wall time (ms).
    pub ms: f64,
}

/// Held-out marker error.
#[derive(Clone, Debug, Serialize)]
pub struct HeldOut {
    /// Mean over the held-out observations of the markers that stay observable in their
    /// fold (mm; see [`HeldOut::unobservable`]): the protocol's figure.
    pub mean: f64,
    /// Mean over every held-out observation, unobservable markers included (mm).
    pub mean_all: f64,
    /// Markers that are unobservable once held out: no other marker of the fold is on their
    /// rig bone or a bone below it, so the joint that places them is seen by no marker and
    /// their error measures the pose prior, not the solve (a hand's or toe's only marker).
    /// Their errors are in `per_marker` and `mean_all`, not in `mean`.
    pub unobservable: Vec<String>,
    /// Mean per marker (mm).
    pub per_marker: BTreeMap<String, f64>,
    /// Like `mean`, over the observations that the solve with every marker also fits within
    /// `outlier_m` (mm). `NaN` when no full solve was given.
    pub mean_inliers: f64,
    /// Held-out observations (of `mean` / of `mean_inliers` / of `mean_all`).
    pub observations: [usize; 3],
    /// How it was measured.
    pub method: String,
    /// Folds.
    pub folds: usize,
    /// Frames tracked per fold.
    pub frames: usize,
    /// Wall time (s).
    pub seconds: f64,
}

/// The calibration's part of [`SolveReport`] (`report.json`'s `calibration`; fields in
/// alphabetical order, the file's key order).
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationSummary {
    /// The calibration frames (indices into the sequence).
    pub frames: Vec<usize>,
    /// Mean move of the surface points from the initial map (mm).
    pub mean_marker_shift_mm: f64,
    /// Mean marker residual over the calibration frames after the last round (mm).
    pub mean_residual_mm: f64,
    /// The six fitted phenotype values (IK order).
    pub phenotype: [f64; 6],
    /// Calibration rounds ([`SolveOptions::calibration_rounds`]).
    pub rounds: usize,
    /// Wall time (s).
    pub seconds: f64,
}

/// `report.json`.
#[derive(Clone, Debug, Serialize)]
pub struct SolveReport {
    /// The method.
    pub method: Method,
    /// The marker file.
    pub capture: String,
    /// The marker set of the map.
    pub marker_set: String,
    /// Markers of the capture.
    pub n_markers: usize,
    /// Frames solved.
    pub n_frames: usize,
    /// Per frame.
    pub frames: Vec<FrameReport>,
    /// Mean of all residuals (mm).
    pub mean_residual_mm: f64,
    /// Largest residual (mm).
    pub max_residual_mm: f64,
    /// Outlier marker-frames.
    pub outliers: usize,
    /// Mean residual per marker over the solved frames (mm).
    pub per_marker_residual_mm: BTreeMap<String, f64>,
    /// The calibration's summary.
    pub calibration: CalibrationSummary,
    /// Times per stage (s; `tracking_warm_ms_per_frame` in ms).
    pub times: BTreeMap<String, f64>,
    /// Observations treated as missing as capture glitches, per marker (see
    /// [`crate::glitch`]; only markers with one or more).
    pub glitches: BTreeMap<String, usize>,
    /// Held-out marker error (when folds > 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out_marker_error_mm: Option<HeldOut>,
    /// Jitter: mean accelerations over consecutive solved frames (m/s²,
    /// [`crate::jitter::mean_acceleration`]; `None` with fewer than three frames).
    pub jitter_m_per_s2: Jitter,
}

/// Mean accelerations (m/s²) of a solve over its consecutive solved frames (a frame step `s`
/// makes `dt = s / rate`): of the mesh's vertices, of the model's markers where they are
/// observed, and of the observed markers themselves (capture glitches missing) — the same
/// points as the model markers, so the last two compare like for like.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Jitter {
    /// The solved mesh's vertices.
    pub mesh_vertices: Option<f64>,
    /// The model markers (surface point + offset) where the marker is observed.
    pub model_markers: Option<f64>,
    /// The observed markers.
    pub observed_markers: Option<f64>,
}

/// Observed positions of one frame in the map's marker order (NaN = missing).
type Obs<'a> = &'a [V3];

/// Wall time per named stage (s).
type StageTimes = Vec<(String, f64)>;

fn finite(p: &V3) -> bool {
    p.iter().all(|c| c.is_finite())
}

/// The solver of one model: the rig, its IK, PanoMan's shell fitter and the rest template.
pub struct MarkerSolver {
    model: panoman::Model,
    solver: FrameSolver,
    template: RestTemplate,
    /// Options.
    pub options: SolveOptions,
}

struct IkOut {
    result: IkResult,
    residuals: Vec<f64>,
    weights: Vec<f64>,
    /// The marker map of the solved pose (the pose-dependent placements moved).
    map: MarkerMap,
}

impl MarkerSolver {
    /// Builds the solver (the model must carry its LBS rig).
    ///
    /// # Errors
    /// [`MocapError::Invalid`]: a temporal prior, patch σ, patch weight or glitch threshold
    /// that is negative or not finite (naming the option and its flag), no embedded rig,
    /// solver setup failures.
    pub fn new(model: &panoman::Model, options: SolveOptions) -> Result<MarkerSolver> {
        let inv = |what: String| MocapError::Invalid { what };
        for (name, v) in [
            ("temporal_prior (--temporal-prior)", options.temporal_prior),
            ("patch_sigma_m (--patch-sigma)", options.patch_sigma_m),
            ("patch_weight", options.patch_weight),
            ("glitch_m (--glitch-m)", options.glitch_m),
            ("glitch_low_m (--glitch-low-m)", options.glitch_low_m),
            (
                "pose_placement_ridge (--pose-placement-ridge)",
                options.pose_placement_ridge,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(inv(format!("{name} = {v} must be finite and ≥ 0")));
            }
        }
        let roll = options.forearm_roll_deg;
        if !(roll.is_finite() && (0.0..=180.0).contains(&roll)) {
            return Err(inv(format!(
                "forearm_roll_deg (--forearm-roll-deg) = {roll} must be in [0, 180]"
            )));
        }
        let solver = FrameSolver::for_model(model.evaluator(), || {
            Err(panoman_fit::FitError::Invalid(
                "the model file has no embedded LBS rig (run `panoman embed-rig`)".into(),
            ))
        })
        .map_err(|e| inv(e.to_string()))?;
        let template = RestTemplate::new(
            solver.rig(),
            model.faces(),
            model.topology_name(),
            &ShapeParams::default(),
        )?;
        Ok(MarkerSolver {
            model: model.clone(),
            solver,
            template,
            options,
        })
    }

    /// The rest template (default identity) the default maps are placed on.
    pub fn template(&self) -> &RestTemplate {
        &self.template
    }

    /// The rig's bone names.
    pub fn bone_names(&self) -> &[String] {
        self.solver.bone_names()
    }

    fn faces(&self) -> &[[u32; 3]] {
        &self.template.faces
    }

    /// Model marker positions (surface point + offset · normal) on a mesh.
    pub fn model_markers(&self, map: &MarkerMap, x: &[V3]) -> Vec<V3> {
        crate::marker_map::model_markers(map, self.faces(), x, self.template.normal_sign)
    }

    /// A start for a frame without a previous one: the rest pose of `phenotype`, placed by
    /// the rigid motion of the torso markers of `map` on the rest mesh onto the observed.
    fn cold_state(&self, map: &MarkerMap, obs: Obs, active: &[bool], phen: [f64; 6]) -> IkState {
        let mut st = IkState::rest(self.bone_names().len(), &ShapeParams::default());
        st.phenotype = phen;
        let rest_m = self.model_markers(map, &self.template.vertices);
        let torso = |b: &str| {
            [
                "spine", "neck", "head", "shoulder", "clavicle", "pelvis", "root",
            ]
            .iter()
            .any(|p| b.starts_with(p))
        };
        let pick = |torso_only: bool| -> (Vec<V3>, Vec<V3>) {
            (0..map.markers.len())
                .filter(|&i| active[i] && finite(&obs[i]))
                .filter(|&i| !torso_only || torso(&map.markers[i].bone))
                .map(|i| (rest_m[i], obs[i]))
                .unzip()
        };
        let (mut a, mut b) = pick(true);
        if a.len() < 3 {
            (a, b) = pick(false);
        }
        if a.len() >= 3 {
            let r = rigid_align(&a, &b, None);
            let h0 = self.template.heads[0];
            st.rotation = r.r;
            st.translation = sub(add(r.t, matvec(&r.r, h0)), h0);
        }
        st
    }

    /// IK of one frame: `rounds` IRLS rounds from `warm` (whose mesh is `mesh`); with
    /// `placement` (pose-dependent placements and the rest mesh) the markers are placed for
    /// the pose each round starts from, and once more for the solved pose.
    #[allow(clippy::too_many_arguments)]
    fn ik_frame(
        &self,
        map: &MarkerMap,
        obs: Obs,
        active: &[bool],
        warm: IkState,
        mesh: &[V3],
        fit_phenotype: bool,
        rounds: usize,
        iterations: usize,
        sigma: f64,
        temporal: Option<TemporalPrior>,
        placement: Option<(&[Option<PosePlacement>], &[V3])>,
    ) -> Result<IkOut> {
        let inv = |e: panoman_fit::FitError| MocapError::Invalid {
            what: format!("marker IK: {e}"),
        };
        let nm = map.markers.len();
        let mut weights: Vec<f64> = (0..nm)
            .map(|i| f64::from(u8::from(active[i] && finite(&obs[i]))))
            .collect();
        let used = weights.iter().filter(|w| **w > 0.0).count();
        if used < 3 {
            return Err(MocapError::Invalid {
                what: format!("only {used} markers observed (need 3)"),
            });
        }
        let centroid = (0..nm)
            .filter(|&i| weights[i] > 0.0)
            .fold([0.0; 3], |a, i| add(a, scale(obs[i], 1.0 / used as f64)));
        let mut kp = IkTargets::new();
        // The solver needs one keypoint; this one has a negligible weight.
        kp.set_named("body_center", centroid, 1e-12).map_err(inv)?;
        let mut state = warm;
        let mut cur = mesh.to_vec();
        let mut last = None;
        let mut residuals = vec![f64::NAN; nm];
        // `map` placed for a pose (pose-dependent placements; `None`: `map` as it is). Each
        // round starts from the placement of the pose it starts from.
        let place = |st: &IkState| placement.map(|(pp, rest)| self.posed_map(map, pp, rest, st));
        let mut placed = place(&state);
        for _ in 0..rounds.max(1) {
            let round_map = placed.as_ref().unwrap_or(map);
            let normals = vertex_normals(self.faces(), &cur, self.template.normal_sign);
            let points: Vec<PointTarget> = round_map
                .markers
                .iter()
                .enumerate()
                .filter(|(i, _)| weights[*i] > 0.0)
                .map(|(i, m)| {
                    let f = self.faces()[m.triangle as usize];
                    let n = surface_normal(self.faces(), &normals, m.triangle, m.barycentric);
                    PointTarget {
                        rows: (0..3).map(|k| (f[k], m.barycentric[k])).collect(),
                        position: sub(obs[i], scale(n, m.offset_m)),
                        weight: weights[i],
                        normal: None,
                    }
                })
                .collect();
            let cfg = IkConfig {
                fit_phenotype,
                fit_face_units: Some(false),
                max_iterations: iterations,
                pose_prior: self.options.pose_prior,
                temporal: temporal.clone(),
                initial_state: Some(state.clone()),
                forearm_roll_deg: (self.options.forearm_roll_deg > 0.0)
                    .then_some(self.options.forearm_roll_deg),
                ..IkConfig::default()
            };
            let r = self
                .solver
                .ik()
                .solve_with_points(&kp, &points, &cfg)
                .map_err(inv)?;
            state = r.state.clone();
            cur.clone_from(&r.posed);
            placed = place(&state);
            residuals = self.residuals(placed.as_ref().unwrap_or(map), obs, active, &cur);
            for i in 0..nm {
                if residuals[i].is_finite() {
                    let s2 = sigma * sigma;
                    let q = s2 / (s2 + residuals[i] * residuals[i]);
                    weights[i] = q * q;
                }
            }
            last = Some(r);
        }
        Ok(IkOut {
            result: last.expect("one round"),
            residuals,
            weights,
            map: placed.unwrap_or_else(|| map.clone()),
        })
    }

    /// Distances of the observations from the model markers on `x` (NaN: missing / unused).
    fn residuals(&self, map: &MarkerMap, obs: Obs, active: &[bool], x: &[V3]) -> Vec<f64> {
        let mm = self.model_markers(map, x);
        (0..map.markers.len())
            .map(|i| {
                if active[i] && finite(&obs[i]) {
                    norm(sub(mm[i], obs[i]))
                } else {
                    f64::NAN
                }
            })
            .collect()
    }

    fn rest_mesh(&self, phen: [f64; 6]) -> Result<Vec<V3>> {
        let mut st = IkState::rest(self.bone_names().len(), &ShapeParams::default());
        st.phenotype = phen;
        let shape = self.solver.ik().shape_params(&st, &ShapeParams::default());
        let t = RestTemplate::new(
            self.solver.rig(),
            self.faces(),
            &self.template.topology,
            &shape,
        )?;
        Ok(t.vertices)
    }
}
