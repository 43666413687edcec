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
use panoman_fit::ik::{
    IkConfig, IkResult, IkSolver, IkState, IkTargets, PointTarget, TemporalPrior,
};
use panoman_fit::{Constraints, FitOptions, Previous, VertexHandle};
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

/// A marker's pose-dependent placement: where on the rest mesh it sits as a linear function
/// of the angles of the bones around it,
///
/// `r(θ) = a + Σ_k b_k (φ_k(θ) − μ_k)`,
///
/// `φ` the three Euler angles (radians) of the marker's bone, its parent and its children
/// (the root's unused angles left out), `μ` their mean over the calibration frames that
/// observed the marker (weighted by the frames' IRLS weights), `a` the marker's fixed
/// calibrated surface point on the rest mesh (metres; the marker step's weighted mean with
/// its prior and bound, not the regression's own centre) and `b_k` metres per radian. The
/// surface point of a frame is the point of the rest mesh closest to `r(θ)` among the
/// triangles `candidates` near `a` (which bounds how far a pose outside the calibration
/// frames' range carries it). Skin and the suit slide over the joints: an elbow marker's
/// distance to the wrist bar changes by 60 mm between a bent and a straight arm on Thomas,
/// which no fixed point of the rig's skin follows (docs/design/mocap.md, "Markers slide with
/// the pose"). PanoMan's surface patch of a marker stays around its fixed point `a`; it
/// moves by the marker's displacement like the marker's triangle.
#[derive(Clone, Debug)]
pub struct PosePlacement {
    /// `(bone, axis)` of each feature `φ_k`.
    pub features: Vec<(usize, usize)>,
    /// Mean `μ_k` of each feature over the calibration frames (IRLS-weighted; radians).
    pub mean: Vec<f64>,
    /// Rest-mesh point `a` at the mean pose (metres).
    pub at_mean: V3,
    /// `b_k` (metres per radian).
    pub slopes: Vec<V3>,
    /// Triangles searched for the closest point: the marker's fixed triangle and those with
    /// a vertex within 3 cm beyond the farthest calibration-frame placement from `a` (at most
    /// 15 cm) on the rest mesh.
    pub candidates: Vec<u32>,
}

impl PosePlacement {
    /// `r(θ)` for the bone angles `angles` (rig order, radians).
    pub fn rest_point(&self, angles: &[[f64; 3]]) -> V3 {
        let phi: Vec<f64> = self.features.iter().map(|&(b, a)| angles[b][a]).collect();
        self.at_features(&phi)
    }

    /// `a + Σ_k b_k (φ_k − μ_k)` for the feature values `phi`.
    fn at_features(&self, phi: &[f64]) -> V3 {
        self.mean
            .iter()
            .zip(&self.slopes)
            .zip(phi)
            .fold(self.at_mean, |r, ((m, s), x)| add(r, scale(*s, x - m)))
    }
}

/// Weighted ridge regression of 3-vectors on features: the `B` (`k` rows of 3) minimising
/// `Σ_f w_f |y_f − ȳ − Bᵀ(x_f − x̄)|² + λ Σ_f w_f |B|²`, with `x̄`, `ȳ` the weighted means.
/// Returns `(x̄, B)`; `None` when the samples carry no weight or the system is singular
/// (`λ = 0` with features that do not vary).
pub fn ridge_fit(samples: &[(Vec<f64>, V3, f64)], lambda: f64) -> Option<(Vec<f64>, Vec<V3>)> {
    let k = samples.first()?.0.len();
    let wsum: f64 = samples.iter().map(|s| s.2).sum();
    if wsum.is_nan() || wsum <= 0.0 {
        return None;
    }
    let mut xbar = vec![0.0; k];
    let mut ybar = [0.0; 3];
    for (x, y, w) in samples {
        for (m, v) in xbar.iter_mut().zip(x) {
            *m += w * v / wsum;
        }
        ybar = add(ybar, scale(*y, w / wsum));
    }
    let mut a = faer::Mat::<f64>::zeros(k, k);
    let mut rhs = faer::Mat::<f64>::zeros(k, 3);
    for (x, y, w) in samples {
        let d = sub(*y, ybar);
        for p in 0..k {
            let xp = x[p] - xbar[p];
            for q in 0..k {
                a[(p, q)] += w * xp * (x[q] - xbar[q]);
            }
            for c in 0..3 {
                rhs[(p, c)] += w * xp * d[c];
            }
        }
    }
    for p in 0..k {
        a[(p, p)] += lambda * wsum;
    }
    let llt = a.llt(faer::Side::Lower).ok()?;
    let b = llt.solve(&rhs);
    let slopes: Vec<V3> = (0..k).map(|p| [b[(p, 0)], b[(p, 1)], b[(p, 2)]]).collect();
    slopes
        .iter()
        .all(|s| s.iter().all(|v| v.is_finite()))
        .then_some((xbar, slopes))
}

/// Per marker of `map`: the vertices of `rest` (`faces`) within `2σ` of its surface point,
/// with the Gaussian factor `exp(−d²/2σ²)` of their distance `d` (metres); empty lists for
/// `σ ≤ 0`. PanoMan's shell fit pulls each observed marker's patch by the marker's
/// displacement ([`SolveOptions::patch_weight`]).
pub fn marker_patches(
    faces: &[[u32; 3]],
    map: &MarkerMap,
    rest: &[V3],
    sigma: f64,
) -> Vec<Vec<(u32, f64)>> {
    map.markers
        .iter()
        .map(|m| {
            if sigma.is_nan() || sigma <= 0.0 {
                return Vec::new();
            }
            let p = surface_point(faces, rest, m.triangle, m.barycentric);
            rest.iter()
                .enumerate()
                .filter_map(|(v, q)| {
                    let d = sub(*q, p);
                    let d2 = dot(d, d);
                    (d2 < 4.0 * sigma * sigma)
                        .then(|| (v as u32, (-0.5 * d2 / (sigma * sigma)).exp()))
                })
                .collect()
        })
        .collect()
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
    /// Calibration: frames, time (s), residual and marker shift (mm), phenotype.
    pub calibration: serde_json::Value,
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
    rig: panoman_fit::Rig,
    ik: IkSolver,
    shell: panoman_fit::Fitter,
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
        let rig = panoman_fit::Rig::for_model(model.inner(), || {
            Err(panoman_fit::FitError::Invalid(
                "the model file has no embedded LBS rig (run `panoman embed-rig`)".into(),
            ))
        })
        .map_err(|e| inv(e.to_string()))?;
        let ik = rig.ik_solver().map_err(|e| inv(e.to_string()))?;
        let shell = panoman_fit::Fitter::with_evaluator(model.evaluator())
            .map_err(|e| inv(e.to_string()))?;
        let template = RestTemplate::new(
            &rig,
            model.faces(),
            model.topology_name(),
            &ShapeParams::default(),
        )?;
        Ok(MarkerSolver {
            model: model.clone(),
            rig,
            ik,
            shell,
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
        self.rig.generator.bone_names()
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
            let r = self.ik.solve_with_points(&kp, &points, &cfg).map_err(inv)?;
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
        let shape = self.ik.shape_params(&st, &ShapeParams::default());
        let t = RestTemplate::new(&self.rig, self.faces(), &self.template.topology, &shape)?;
        Ok(t.vertices)
    }

    /// Calibrates shape and marker placement on frames of `seq` (see the module docs);
    /// markers with `active[i] == false` are left out (their placement is kept).
    ///
    /// # Errors
    /// Too few frames with markers; IK failures.
    pub fn calibrate(
        &self,
        seq: &MarkerSequence,
        frames: &[usize],
        initial: &MarkerMap,
        active: &[bool],
    ) -> Result<Calibration> {
        let t0 = Instant::now();
        let o = &self.options;
        let nm = initial.markers.len();
        let calib = pick_frames(seq, frames, active, o.calibration_frames);
        if calib.is_empty() {
            return Err(MocapError::Invalid {
                what: "no frame has 3 or more of the markers observed".into(),
            });
        }
        let mut map = initial.clone();
        let mut phen = [0.5; 6];
        let mut states: Vec<(IkState, Vec<V3>)> = Vec::new();
        for &f in &calib {
            let st = self.cold_state(&map, seq.frame(f), active, phen);
            let r = self.ik_frame(
                &map,
                seq.frame(f),
                active,
                st,
                &self.template.vertices,
                true,
                3,
                40,
                0.15,
                None,
                None,
            )?;
            states.push((r.result.state.clone(), r.result.posed.clone()));
        }
        for (i, p) in phen.iter_mut().enumerate() {
            *p = states.iter().map(|s| s.0.phenotype[i]).sum::<f64>() / states.len() as f64;
        }
        let rest = self.rest_mesh(phen)?;
        let init_rest: Vec<V3> = initial
            .markers
            .iter()
            .map(|m| surface_point(self.faces(), &rest, m.triangle, m.barycentric))
            .collect();
        let mut mean_res = f64::NAN;
        // The pose-dependent placements: fitted after round ⌈R/2⌉, once the fixed
        // placements have settled, and used from the next round on.
        let mut placements: Vec<Option<PosePlacement>> = Vec::new();
        let first_fit = o.calibration_rounds.max(1).div_ceil(2);
        for round in 0..o.calibration_rounds.max(1) {
            // Wide weights first (the initial placement may be centimetres off), then the
            // tracking σ.
            let sigma = (0.1 / (1 << round) as f64).max(o.robust_sigma_m);
            let mut outs = Vec::with_capacity(calib.len());
            for (k, &f) in calib.iter().enumerate() {
                let (mut st, mesh) = states[k].clone();
                st.phenotype = phen;
                let r = self.ik_frame(
                    &map,
                    seq.frame(f),
                    active,
                    st,
                    &mesh,
                    false,
                    2,
                    20,
                    sigma,
                    None,
                    placements
                        .iter()
                        .any(Option::is_some)
                        .then_some((placements.as_slice(), rest.as_slice())),
                )?;
                states[k] = (r.result.state.clone(), r.result.posed.clone());
                outs.push(r);
            }
            let obs: Vec<Obs> = calib.iter().map(|&f| seq.frame(f)).collect();
            let samples =
                self.marker_step(&mut map, initial, &init_rest, &rest, &outs, &obs, active);
            if o.pose_placement_ridge > 0.0 && round + 1 >= first_fit {
                placements = self.fit_pose_placement(&map, &rest, &outs, &samples);
            }
            let all: Vec<f64> = outs
                .iter()
                .flat_map(|r| r.residuals.iter().copied().filter(|x| x.is_finite()))
                .collect();
            mean_res = 1e3 * all.iter().sum::<f64>() / all.len().max(1) as f64;
        }
        let shift: f64 = (0..nm)
            .map(|i| {
                let m = &map.markers[i];
                norm(sub(
                    surface_point(self.faces(), &rest, m.triangle, m.barycentric),
                    init_rest[i],
                ))
            })
            .sum::<f64>()
            / nm.max(1) as f64;
        let flat: Vec<f64> = rest.iter().flatten().copied().collect();
        let alpha = self.model.inner().shape.project(&flat);
        let patches = marker_patches(self.faces(), &map, &rest, o.patch_sigma_m);
        Ok(Calibration {
            map,
            phenotype: phen,
            rest,
            alpha,
            frames: calib,
            mean_residual_mm: mean_res,
            mean_marker_shift_mm: 1e3 * shift,
            patches,
            seconds: t0.elapsed().as_secs_f64(),
            pose_placement: placements,
        })
    }

    /// `map` with each marker that has a pose-dependent placement moved to its surface point
    /// for the bone angles of `state` ([`PosePlacement`]; `rest` is the calibrated rest mesh).
    pub fn posed_map(
        &self,
        map: &MarkerMap,
        placement: &[Option<PosePlacement>],
        rest: &[V3],
        state: &IkState,
    ) -> MarkerMap {
        let faces = self.faces();
        let mut m = map.clone();
        for (mk, p) in m.markers.iter_mut().zip(placement) {
            let Some(p) = p else { continue };
            let r = p.rest_point(&state.angles);
            if let Some((t, bc)) = closest_point_among(faces, rest, r, p.candidates.iter().copied())
            {
                mk.triangle = t;
                mk.barycentric = bc;
            }
        }
        m
    }

    /// Fits each marker's [`PosePlacement`] from the calibration frames' solves `outs`: the
    /// marker step's per-frame rest-mesh points under the observation (`samples`) regressed
    /// on the angles of the marker's bone, its parent and its children ([`ridge_fit`] with
    /// [`SolveOptions::pose_placement_ridge`], the frames' IRLS weights). `None` for a
    /// marker with fewer than [`MIN_PLACEMENT_FRAMES`] frames (or no bone in the rig): it
    /// keeps its fixed place.
    fn fit_pose_placement(
        &self,
        map: &MarkerMap,
        rest: &[V3],
        outs: &[IkOut],
        samples: &[Vec<PlacementSample>],
    ) -> Vec<Option<PosePlacement>> {
        let faces = self.faces();
        let names = self.bone_names();
        let parents = self.rig.generator.bone_parents();
        let lambda = self.options.pose_placement_ridge;
        map.markers
            .iter()
            .zip(samples)
            .map(|(m, marker_samples)| {
                if marker_samples.len() < MIN_PLACEMENT_FRAMES {
                    return None;
                }
                let bone = names.iter().position(|n| *n == m.bone)?;
                let mut bones = vec![bone];
                bones.extend(parents[bone]);
                bones.extend((0..names.len()).filter(|&c| parents[c] == Some(bone)));
                // Bone 0's angles are unused (the root's rotation is the state's own).
                let features: Vec<(usize, usize)> = bones
                    .iter()
                    .filter(|&&b| b != 0)
                    .flat_map(|&b| (0..3).map(move |axis| (b, axis)))
                    .collect();
                let phi = |k: usize| -> Vec<f64> {
                    let angles = &outs[k].result.state.angles;
                    features.iter().map(|&(b, axis)| angles[b][axis]).collect()
                };
                let rows: Vec<(Vec<f64>, V3, f64)> = marker_samples
                    .iter()
                    .map(|s| (phi(s.frame), s.on_rest, s.weight))
                    .collect();
                let (mean, slopes) = ridge_fit(&rows, lambda)?;
                let mut pp = PosePlacement {
                    features,
                    mean,
                    at_mean: surface_point(faces, rest, m.triangle, m.barycentric),
                    slopes,
                    candidates: Vec::new(),
                };
                // The search reaches 3 cm beyond the calibration frames' farthest placement
                // (at most 15 cm): a pose outside their range does not carry the marker
                // further than that.
                let reach = rows
                    .iter()
                    .map(|(x, _, _)| norm(sub(pp.at_features(x), pp.at_mean)))
                    .fold(0.0, f64::max);
                let radius = (reach + 0.03).min(0.15);
                pp.candidates = (0..faces.len() as u32)
                    .filter(|&t| {
                        t == m.triangle
                            || faces[t as usize].iter().any(|&k| {
                                let d = sub(rest[k as usize], pp.at_mean);
                                dot(d, d) < radius * radius
                            })
                    })
                    .collect();
                Some(pp)
            })
            .collect()
    }

    /// The marker-placement step of the calibration (see the module docs); returns each
    /// marker's per-frame samples (for [`PosePlacement`]).
    #[allow(clippy::too_many_arguments)]
    fn marker_step(
        &self,
        map: &mut MarkerMap,
        initial: &MarkerMap,
        init_rest: &[V3],
        rest: &[V3],
        outs: &[IkOut],
        obs: &[Obs],
        active: &[bool],
    ) -> Vec<Vec<PlacementSample>> {
        let o = &self.options;
        let faces = self.faces();
        let normals: Vec<Vec<V3>> = outs
            .iter()
            .map(|r| vertex_normals(faces, &r.result.posed, self.template.normal_sign))
            .collect();
        let mut samples = vec![Vec::new(); map.markers.len()];
        for (i, m) in map.markers.iter_mut().enumerate() {
            if !active[i] {
                continue;
            }
            let (mut acc, mut wsum, mut dsum) = ([0.0; 3], 0.0, 0.0);
            for (k, (r, ob)) in outs.iter().zip(obs).enumerate() {
                let w = r.weights[i];
                if !(w > 0.0 && finite(&ob[i])) {
                    continue;
                }
                let x = &r.result.posed;
                // The frame's own placement (pose-dependent) gives the normal.
                let pm = &r.map.markers[i];
                let n = surface_normal(faces, &normals[k], pm.triangle, pm.barycentric);
                let s = sub(ob[i], scale(n, m.offset_m));
                let (t, b) = closest_point(faces, x, s, 0.08);
                let q = surface_point(faces, x, t, b);
                let nq = surface_normal(faces, &normals[k], t, b);
                let on_rest = surface_point(faces, rest, t, b);
                acc = add(acc, scale(on_rest, w));
                dsum += w * dot(sub(ob[i], q), nq);
                wsum += w;
                samples[i].push(PlacementSample {
                    frame: k,
                    on_rest,
                    weight: w,
                });
            }
            if wsum <= 0.0 {
                continue;
            }
            let lambda = o.placement_prior_weight.max(1e-9);
            let q0 = init_rest[i];
            let mut q = scale(add(acc, scale(q0, lambda)), 1.0 / (wsum + lambda));
            let d = sub(q, q0);
            if norm(d) > o.marker_prior_m {
                q = add(q0, scale(d, o.marker_prior_m / norm(d)));
            }
            let (t, b) = closest_point(faces, rest, q, 0.06);
            m.triangle = t;
            m.barycentric = b;
            let off0 = initial.markers[i].offset_m;
            m.offset_m = ((dsum + lambda * off0) / (wsum + lambda)).clamp(0.003, 0.06);
        }
        samples
    }
}

/// Frames a marker needs in the calibration for a pose-dependent placement (with fewer it
/// keeps its fixed surface point; the ridge keeps the slopes of a small sample small).
const MIN_PLACEMENT_FRAMES: usize = 8;

/// One calibration frame's evidence for a marker's placement: the rest-mesh point under its
/// observation and the frame's IRLS weight.
#[derive(Clone, Debug)]
struct PlacementSample {
    /// Index into the calibration frames.
    frame: usize,
    on_rest: V3,
    weight: f64,
}

/// Up to `n` frames of `frames`, evenly spread, each with ≥ 3 active markers observed
/// (preferring frames with ≥ 80 % of them).
fn pick_frames(seq: &MarkerSequence, frames: &[usize], active: &[bool], n: usize) -> Vec<usize> {
    let count = |f: usize| {
        seq.frame(f)
            .iter()
            .zip(active)
            .filter(|(p, a)| **a && finite(p))
            .count()
    };
    let n_active = active.iter().filter(|a| **a).count();
    for frac in [0.8, 0.0] {
        let good: Vec<usize> = frames
            .iter()
            .copied()
            .filter(|&f| {
                let c = count(f);
                c >= 3 && c as f64 >= frac * n_active as f64
            })
            .collect();
        if good.len() >= n.min(frames.len()).max(1) || frac == 0.0 {
            let k = n.min(good.len());
            return (0..k)
                .map(|j| good[(j * good.len() + good.len() / (2 * k.max(1))) / k.max(1)])
                .collect();
        }
    }
    Vec::new()
}

/// Handles of the markers for the shell fit: each marker pulls its triangle's vertices
/// (weighted by the barycentric coordinates) so that the triangle, translated, puts its
/// marker point on `target`.
#[allow(clippy::too_many_arguments)]
fn marker_handles(
    faces: &[[u32; 3]],
    map: &MarkerMap,
    x: &[V3],
    targets: &[Option<V3>],
    weights: &[f64],
    patches: &[Vec<(u32, f64)>],
    patch_weight: f64,
) -> Vec<VertexHandle> {
    let mut h = Vec::new();
    for (i, m) in map.markers.iter().enumerate() {
        let Some(t) = targets[i] else { continue };
        let f = faces[m.triangle as usize];
        let p = surface_point(faces, x, m.triangle, m.barycentric);
        let shift = sub(t, p);
        for k in 0..3 {
            let w = weights[i] * m.barycentric[k];
            if w > 1e-9 {
                h.push(VertexHandle {
                    vertex: f[k],
                    position: add(x[f[k] as usize], shift),
                    weight: w,
                });
            }
        }
        // The marker's surface patch follows it by the same displacement (a soft-tissue
        // field that the shell blends between markers).
        for &(v, g) in patches.get(i).map_or(&[][..], Vec::as_slice) {
            let w = patch_weight * weights[i] * g;
            if w > 1e-9 {
                h.push(VertexHandle {
                    vertex: v,
                    position: add(x[v as usize], shift),
                    weight: w,
                });
            }
        }
    }
    h
}

/// State carried from frame to frame.
#[derive(Clone)]
struct Carry {
    state: IkState,
    mesh: Vec<V3>,
    previous: Option<Previous>,
}

impl MarkerSolver {
    /// Tracks `frames` of `seq` in order with calibration `cal`; markers with
    /// `active[i] == false` are not used.
    ///
    /// # Errors
    /// IK or shell-fit failures (a frame with fewer than 3 markers keeps the previous
    /// frame's solution).
    pub fn track(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        cal: &Calibration,
        active: &[bool],
    ) -> Result<Vec<SolvedFrame>> {
        // On a worker of rayon's pool, as `panoman_fit::fit_frame` runs a frame: the frames'
        // many small fork-joins start from a worker.
        let mut res = None;
        rayon::scope(|_| res = Some(self.track_here(seq, frames, cal, active)));
        res.expect("the scope ran its closure")
    }

    /// [`MarkerSolver::track`] on the calling thread.
    fn track_here(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        cal: &Calibration,
        active: &[bool],
    ) -> Result<Vec<SolvedFrame>> {
        let mut out: Vec<SolvedFrame> = Vec::with_capacity(frames.len());
        let mut carry: Option<Carry> = None;
        let mut last_solved: Option<usize> = None;
        for &f in frames {
            let t = Instant::now();
            let obs = seq.frame(f);
            let n_obs = (0..obs.len())
                .filter(|&i| active[i] && finite(&obs[i]))
                .count();
            if n_obs < 3
                && let Some(prev) = out.last()
            {
                let mut s = prev.clone();
                s.frame = f;
                s.residuals = vec![f64::NAN; obs.len()];
                s.outliers = 0;
                s.seconds = t.elapsed().as_secs_f64();
                s.stage_seconds = Vec::new();
                out.push(s);
                continue;
            }
            let gap = last_solved.map_or(1, |p| f.saturating_sub(p));
            let (frame, next) = self.track_frame(obs, cal, active, carry.as_ref(), gap)?;
            carry = Some(next);
            last_solved = Some(f);
            out.push(SolvedFrame {
                frame: f,
                seconds: t.elapsed().as_secs_f64(),
                ..frame
            });
        }
        Ok(out)
    }

    fn track_frame(
        &mut self,
        obs: Obs,
        cal: &Calibration,
        active: &[bool],
        carry: Option<&Carry>,
        gap: usize,
    ) -> Result<(SolvedFrame, Carry)> {
        let o = self.options.clone();
        let map = &cal.map;
        let t_ik = Instant::now();
        let ik = match carry {
            Some(c) => {
                // The prior is on velocity: over a gap of several frames the pose may move
                // that many times further.
                let temporal = (o.temporal_prior > 0.0).then(|| TemporalPrior {
                    weights: vec![
                        o.temporal_prior / (gap.max(1) as f64).powi(2);
                        c.state.angles.len()
                    ],
                    angles: c.state.angles.clone(),
                });
                self.ik_frame(
                    map,
                    obs,
                    active,
                    c.state.clone(),
                    &c.mesh,
                    false,
                    o.track_rounds,
                    o.track_iterations,
                    o.robust_sigma_m,
                    temporal,
                    cal.placement(),
                )?
            }
            None => {
                let st = self.cold_state(map, obs, active, cal.phenotype);
                self.ik_frame(
                    map,
                    obs,
                    active,
                    st,
                    &self.template.vertices,
                    false,
                    4,
                    40,
                    o.robust_sigma_m,
                    None,
                    cal.placement(),
                )?
            }
        };
        let mut stage_seconds = vec![("ik".to_string(), t_ik.elapsed().as_secs_f64())];
        let rig_params = ik.result.params.clone();
        let state = ik.result.state.clone();
        if o.method == Method::Lbs {
            let residuals = ik.residuals.clone();
            let outliers = count_outliers(&residuals, o.outlier_m);
            let mesh = ik.result.posed.clone();
            let frame = SolvedFrame {
                frame: 0,
                vertices: mesh.clone(),
                rig_params,
                params: None,
                residuals,
                outliers,
                seconds: 0.0,
                stage_seconds,
                placement: cal.placement().map(|_| ik.map.clone()),
            };
            let next = Carry {
                state,
                mesh,
                previous: None,
            };
            return Ok((frame, next));
        }
        let (vertices, params, stages) = self.shell_frame(&ik, obs, cal, active, carry)?;
        stage_seconds.extend(stages);
        let residuals = self.residuals(&ik.map, obs, active, &vertices);
        let outliers = count_outliers(&residuals, o.outlier_m);
        let next = Carry {
            state,
            mesh: ik.result.posed.clone(),
            previous: Some(Previous {
                vertices: vertices.clone(),
                params: params.clone(),
                init: Some(ik.result.posed.clone()),
            }),
        };
        let frame = SolvedFrame {
            frame: 0,
            vertices,
            rig_params,
            params: Some(params),
            residuals,
            outliers,
            seconds: 0.0,
            stage_seconds,
            placement: cal.placement().map(|_| ik.map.clone()),
        };
        Ok((frame, next))
    }

    /// PanoMan's shell fit of one frame from its IK.
    fn shell_frame(
        &mut self,
        ik: &IkOut,
        obs: Obs,
        cal: &Calibration,
        active: &[bool],
        carry: Option<&Carry>,
    ) -> Result<(Vec<V3>, Params, StageTimes)> {
        let faces = self.template.faces.clone();
        let x = &ik.result.posed;
        let normals = vertex_normals(&faces, x, self.template.normal_sign);
        let targets: Vec<Option<V3>> = ik
            .map
            .markers
            .iter()
            .enumerate()
            .map(|(i, m)| {
                (active[i] && finite(&obs[i]) && ik.weights[i] > 0.0).then(|| {
                    let n = surface_normal(&faces, &normals, m.triangle, m.barycentric);
                    sub(obs[i], scale(n, m.offset_m))
                })
            })
            .collect();
        let handles = marker_handles(
            &faces,
            &ik.map,
            x,
            &targets,
            &ik.weights,
            &cal.patches,
            self.options.patch_weight,
        );
        let previous = carry.and_then(|c| c.previous.clone());
        let opts = if previous.is_some() {
            self.options.warm_fit.clone()
        } else {
            FitOptions::default()
        };
        let c = Constraints {
            handles,
            fixed: Some(Params {
                alpha: cal.alpha.clone(),
                ..Default::default()
            }),
            previous,
            ..Default::default()
        };
        let init = panoman_fit::init_of(&ik.result, &self.ik, self.rig.generator.bone_names());
        let fit = self
            .shell
            .fit(&c, &init, &opts)
            .map_err(|e| MocapError::Invalid {
                what: format!("shell fit: {e}"),
            })?;
        let stages = fit
            .report
            .stages
            .iter()
            .map(|s| (format!("shell_{}", s.name), s.seconds))
            .collect();
        Ok((fit.vertices, fit.params, stages))
    }
}

fn count_outliers(r: &[f64], limit: f64) -> usize {
    r.iter().filter(|x| x.is_finite() && **x > limit).count()
}

/// Mean and max (mm) of the finite entries.
pub fn mean_max_mm(r: impl IntoIterator<Item = f64>) -> (f64, f64, usize) {
    let (mut s, mut m, mut n) = (0.0, 0.0f64, 0usize);
    for x in r.into_iter().filter(|x| x.is_finite()) {
        s += x;
        m = m.max(x);
        n += 1;
    }
    if n == 0 {
        (f64::NAN, f64::NAN, 0)
    } else {
        (1e3 * s / n as f64, 1e3 * m, n)
    }
}

impl MarkerSolver {
    /// Per marker: whether it is observable by the `active` markers — it is active, or
    /// another active marker is on its rig bone or on a bone below it.
    pub fn observable(&self, map: &MarkerMap, active: &[bool]) -> Vec<bool> {
        let names = self.bone_names();
        let parents = self.rig.generator.bone_parents();
        let bone = |i: usize| names.iter().position(|n| *n == map.markers[i].bone);
        let below = |b: usize, mut c: usize| loop {
            if c == b {
                return true;
            }
            match parents[c] {
                Some(p) => c = p,
                None => return false,
            }
        };
        (0..map.markers.len())
            .map(|i| {
                active[i]
                    || bone(i).is_none_or(|b| {
                        (0..map.markers.len())
                            .filter(|&j| j != i && active[j])
                            .any(|j| bone(j).is_some_and(|c| below(b, c)))
                    })
            })
            .collect()
    }

    /// The held-out marker error (see the module docs) on `frames` (every
    /// `held_out_step`-th is used) with the full calibration `full`; `full_solve` (the
    /// tracking with every marker) marks glitch observations for
    /// [`HeldOut::mean_inliers`].
    ///
    /// # Errors
    /// Calibration or tracking failures of a fold.
    pub fn held_out(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        full: &Calibration,
        full_solve: Option<&[SolvedFrame]>,
    ) -> Result<HeldOut> {
        let full_res: BTreeMap<usize, &[f64]> = full_solve
            .unwrap_or(&[])
            .iter()
            .map(|s| (s.frame, s.residuals.as_slice()))
            .collect();
        let mut inliers: Vec<f64> = Vec::new();
        let t0 = Instant::now();
        let k = self.options.held_out_folds.max(2);
        let nm = full.map.markers.len();
        // The calibration frames (where the full calibration saw every marker) are not
        // evaluated, unless they are all there is (a clip of a few frames).
        let stepped: Vec<usize> = frames
            .iter()
            .copied()
            .step_by(self.options.held_out_step.max(1))
            .collect();
        let mut sub_frames: Vec<usize> = stepped
            .iter()
            .copied()
            .filter(|f| !full.frames.contains(f))
            .collect();
        if sub_frames.is_empty() {
            sub_frames = stepped;
        }
        let mut per: Vec<Vec<f64>> = vec![Vec::new(); nm];
        let mut unobservable = vec![false; nm];
        for fold in 0..k {
            let active: Vec<bool> = (0..nm).map(|i| i % k != fold).collect();
            for (u, o) in unobservable
                .iter_mut()
                .zip(self.observable(&full.map, &active))
            {
                *u |= !o;
            }
            let cal = if self.options.held_out_recalibrate {
                self.calibrate(seq, frames, &full.map, &active)?
            } else {
                full.clone()
            };
            let solved = self.track(seq, &sub_frames, &cal, &active)?;
            for s in &solved {
                let mm = self.model_markers(s.map(full), &s.vertices);
                let obs = seq.frame(s.frame);
                for i in (0..nm).filter(|&i| !active[i] && finite(&obs[i])) {
                    let e = norm(sub(mm[i], obs[i]));
                    per[i].push(e);
                    if !unobservable[i]
                        && full_res
                            .get(&s.frame)
                            .is_some_and(|r| r[i] <= self.options.outlier_m)
                    {
                        inliers.push(e);
                    }
                }
            }
        }
        let all: Vec<f64> = per.iter().flatten().copied().collect();
        let kept: Vec<f64> = per
            .iter()
            .zip(&unobservable)
            .filter(|(_, u)| !**u)
            .flat_map(|(v, _)| v.iter().copied())
            .collect();
        let mean_mm = |v: &[f64]| {
            if v.is_empty() {
                f64::NAN
            } else {
                1e3 * v.iter().sum::<f64>() / v.len() as f64
            }
        };
        let per_marker = full
            .map
            .markers
            .iter()
            .zip(&per)
            .filter(|(_, v)| !v.is_empty())
            .map(|(m, v)| (m.name.clone(), 1e3 * v.iter().sum::<f64>() / v.len() as f64))
            .collect();
        Ok(HeldOut {
            mean: mean_mm(&kept),
            mean_all: mean_mm(&all),
            unobservable: (0..nm)
                .filter(|&i| unobservable[i] && !per[i].is_empty())
                .map(|i| full.map.markers[i].name.clone())
                .collect(),
            per_marker,
            mean_inliers: if full_solve.is_some() {
                mean_mm(&inliers)
            } else {
                f64::NAN
            },
            observations: [kept.len(), inliers.len(), all.len()],
            method: format!(
                "{k}-fold over markers (marker i in fold i mod {k}); {}; each fold tracked without its markers on {} (calibration frames left out); error = |observed − (surface point + offset·n̂)| on the solved mesh, with the held-out marker's placement from the full calibration (MoSh), moved to the solved pose when the placement is pose-dependent (pose_placement_ridge > 0); capture glitches (markers that leave their rigid neighbours) are missing; `mean` leaves out the markers that no other marker of their fold observes (`unobservable`), `mean_all` keeps them",
                if self.options.held_out_recalibrate {
                    "each fold calibrated anew without its markers"
                } else {
                    "shape and placement calibrated once with every marker (MoSh)"
                },
                match self.options.held_out_step.max(1) {
                    1 => "every solved frame, as the solve tracks".to_string(),
                    k => format!(
                        "every {k}-th solved frame, with 1/{} of the temporal prior",
                        k * k
                    ),
                }
            ),
            folds: k,
            frames: sub_frames.len(),
            seconds: t0.elapsed().as_secs_f64(),
        })
    }
}
