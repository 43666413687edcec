//! Fitting PanoMan to sparse 3D constraints (paper §5, Eq. 6–11; docs/design/shell-fit.md §1).
//!
//! The unknowns are the vertices V and the parameters p = (α, β). The energy is the discrete
//! shell toward the guidance pose `B_P(α, β)` plus constraints:
//!
//! ```text
//! E(V, β) = Σ_e (ℓ_e(V)/ℓ*_e − 1)²  +  c_B² Σ_e ω_e² wrap(φ_e(V) − φ*_e)²            (Eq. 7–8)
//!         + λ_K/ℓ̄² Σ_k w_k |Γ_k V − k̂_k|²                                          (keypoints)
//!         + λ_H/ℓ̄² Σ_h |x_h − x̂_h|²                                                (handles)
//!         + λ_I/ℓ̄² Σ_c (n̂_cᵀ(Σ_m b_cm x_m − p_c))²                                 (ICP)
//! ℓ* = ℓ^r(α) ⊙ (1 + X̄_L + M_L β_L + R_L),  φ* = φ^r(α) + X̄_A + M_A β_A + R_A        (Eq. 3–5)
//! ```
//!
//! It is minimised by alternation (docs/design/shell-fit.md §3.1): a V-step is a
//! Levenberg–Marquardt solve of the shell energy with the constraints
//! ([`panoman_mesh::shell::ShellSolver`], fixed sparsity pattern and symbolic factorization
//! built once per model load, including the couplings of the keypoint regressors); a β-step is
//! the least-squares projection of V's RL/RA onto the components with α fixed (the encoder's
//! normal equations are factored once per model). Each sweep lowers the shell energy of the
//! V-step for the new guidance; the V of the last V-step is the fit.
//!
//! Stages (PanoMan §5.3 with Total Capture's staging): the guidance pose from the initializer
//! is rigidly placed on the keypoints; then torso keypoints only; then all keypoints with
//! alternating sweeps; then, if a point cloud is given, ICP passes with re-matching (the
//! damping is reset whenever correspondences change, since E is not monotone across
//! re-matching).
use crate::error::{FitError, Result};
use crate::icp::{IcpOptions, MatchStats, VertexFaces, correspondences_on};
use crate::quality::{QualityOptions, Verdict};
use crate::targets::Targets;
use panoman_human::keypoints::{KeypointGroup, KeypointsFile};
use panoman_mesh::align::{Rigid, rigid_align};
use panoman_mesh::geom::{V3, add, dot, matmul, matvec, norm, scale, sub};
use panoman_mesh::rotation::{from_rotation_vector, rotation_vector};
use panoman_mesh::shell::{
    Handle, PcgOptions, PointConstraint, ShellOptions, ShellReport, ShellSolver, ShellTargets,
};
use panoman_mesh::{RestGeometry, Rla, Topology};
use panoman_model::model::{BlockName, Evaluator, PanoManModel, Params};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// Names of the torso keypoints used by the first stage.
pub const TORSO_KEYPOINTS: [&str; 6] = [
    "neck",
    "body_center",
    "l_shoulder",
    "r_shoulder",
    "l_hip",
    "r_hip",
];

/// Keypoint regressor rows with more vertices than this are kept out of the shell solver's
/// JᵀJ pattern ([`ShellSolver::with_dense_supports`]).
pub const DENSE_SUPPORT: usize = 64;

/// Controls of a fit.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// Bending weight c_B of Eq. 8 (dimensionless Fröhlich–Botsch ω_e). Default 1.
    pub c_b: f64,
    /// λ_K: keypoint weight (dimensionless; residuals are scaled by 1/ℓ̄). Default 10.
    pub keypoint_weight: f64,
    /// λ_H: handle weight. Default 10.
    pub handle_weight: f64,
    /// λ_I: ICP weight per matched point. Default 1.
    pub icp_weight: f64,
    /// LM iterations of the torso stage (Total Capture's first stage; the IK initializer
    /// already stages torso → body → hands, so the default skips it). Default 0.
    pub torso_iterations: usize,
    /// LM iterations of each V-step in the keypoint and ICP stages (the budget of accepted
    /// steps, see `step_retries`). Default 4.
    pub step_iterations: usize,
    /// Rejected LM steps of a V-step retried with a larger damping before they use up a unit
    /// of `step_iterations` ([`ShellOptions::retry_rejected`]): a one-iteration warm V-step
    /// then ends with an accepted step instead of silently doing nothing. Default 8 (μ grows
    /// by up to 2⁴⁵ over a run of 9 rejections).
    pub step_retries: usize,
    /// Alternating V-/β-sweeps of the keypoint stage. Default 1.
    pub sweeps: usize,
    /// ICP passes (re-matching each time; Total Capture does 2). Default 2.
    pub icp_passes: usize,
    /// ICP passes when the fit starts from the skeletal ICP of the rig on the same scan
    /// ([`crate::FrameSolver::fit`] runs [`crate::ik_icp`] first), whose mesh is already matched.
    /// Default 1: measured on 6 held-out people (keypoints + 3,501 of 5,000 scan points,
    /// `examples/scan_bench`), one pass gives 1.69 mm against 1.78 mm with two (every person
    /// equal or better), the scan fit in about 0.6× the time.
    pub icp_passes_after_skeletal: usize,
    /// Correspondence rejection.
    pub icp: IcpOptions,
    /// Numeric Cholesky factorizations on the rayon pool (faer's parallel supernodal
    /// factorization); sequential otherwise. Default false: measured faster on 2 cores.
    pub parallel_factor: bool,
    /// Initial LM damping μ of each V-step of the torso and keypoint stages (relative to diag
    /// JᵀJ, docs/design/shell-fit.md §3.4). Default 1: a short, trust-region-like first step
    /// (measured on the eval's 10 held-out people, exact keypoints, with rejected steps
    /// retried: μ₀ = 1e−2 / 0.3 / 1 / 3 / 10 → PanoMan +3.75 / +1.34 / +0.81 / +0.42 / +0.18 %
    /// mean vertex error over the LBS initializer, 40 of 40 steps accepted each time; the
    /// guidance pose's representation error makes long steps toward it cost accuracy).
    pub mu_init: f64,
    /// Initial LM damping μ of the ICP stages' V-steps, where the scan is evidence the
    /// guidance pose lacks. Default 1e−2.
    pub icp_mu_init: f64,
    /// Initial β_B from the motion MLP applied to the initializer's skeleton pose (PanoMan
    /// §5.3: `β_B = β_MLP(θ)`) instead of the projection of the initializer's mesh; face and
    /// hand blocks are still projected. With it the guidance pose follows the components'
    /// linear blending rather than the rig's skinning (which collapses under large twists).
    /// Default false.
    pub motion_init: bool,
    /// Use the correction MLP in the guidance pose. Default true.
    pub correction: bool,
    /// Start the V-steps from the initializer's mesh (e.g. the IK rig mesh, or the previous
    /// frame) instead of the guidance pose `g(B_P(α, β))`. Default true.
    pub start_from_init_mesh: bool,
    /// λ_T: temporal term `λ_T/ℓ̄² Σ_v |x_v − x̂_v|²` toward the previous frame's fit carried by
    /// the skeletal motion (see [`Previous::init`]; sequences only). Default 0.01.
    pub temporal_vertex_weight: f64,
    /// τ: temporal smoothing of β, `β ← (β_LS + τ β_prev)/(1 + τ)` after each β-step (the
    /// minimiser of `|β − β_LS|² + τ|β − β_prev|²` in the encoder's metric up to its
    /// conditioning; sequences only). Default 0.5.
    pub temporal_beta: f64,
    /// How the parameters are placed. Default [`Placement::Aligned`].
    pub placement: Placement,
    /// τ_θ: weight of the motion constraint, `β_B ← (β_LS + τ_θ β_θ)/(1 + τ_θ)` after each
    /// β-step, the minimiser of `|β_B − β_LS|² + τ_θ|β_B − β_θ|²` (see
    /// [`Constraints::motion`]). Default 1.
    pub motion_weight: f64,
    /// Thresholds of the quality check of the initializer and of the fit
    /// ([`crate::quality`]).
    pub quality: QualityOptions,
    /// V-steps solved inexactly by preconditioned conjugate gradients instead of a sparse
    /// factorization ([`panoman_mesh::shell::PcgOptions`]; falls back to the factorization
    /// when PCG misses its tolerance). Default `None`; [`warm_fit_options`] sets it.
    pub pcg: Option<PcgOptions>,
    /// Fixed-point iterations `β ← LS(RLA − R(β))` of each β-step with the correction MLP
    /// (each one MLP evaluation and one projection). Default 2.
    pub correction_iterations: usize,
    /// Start those iterations from the β at hand (the frame's earlier β-step, else the
    /// previous frame's) instead of the uncorrected projection. Default false;
    /// [`warm_fit_options`] sets it with one iteration.
    pub correction_warm_start: bool,
    /// Tolerance (m) of the cold keypoint stage's first step. A fit without a previous
    /// frame, motion data or [`FitOptions::pcg`], whose keypoint stage takes more than one LM
    /// iteration in one sweep, first takes one LM step solved by PCG
    /// ([`PcgOptions::default`], μ = [`FitOptions::mu_init`]) and stops there when every
    /// keypoint group's mean residual (body, face, each hand; [`group_residuals`]) is within
    /// this tolerance; otherwise it goes on with `step_iterations − 1` factored steps. From
    /// exact keypoints one step reaches them to a few tenths of a millimetre on the default
    /// model, and each further step moves the fit toward the guidance pose and its
    /// representation error (docs/design/shell-fit.md §3.6); from noisy keypoints, or with a
    /// model whose guidance pose is far from them, the residual stays above the tolerance and
    /// the stage takes all its steps. `None`: always the factored steps. Default
    /// `Some(1e-3)` (1 mm).
    pub one_step_tolerance: Option<f64>,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            c_b: 1.0,
            keypoint_weight: 10.0,
            handle_weight: 10.0,
            icp_weight: 1.0,
            torso_iterations: 0,
            step_iterations: 4,
            step_retries: 8,
            sweeps: 1,
            icp_passes: 2,
            icp_passes_after_skeletal: 1,
            icp: IcpOptions::default(),
            mu_init: 1.0,
            icp_mu_init: 1e-2,
            parallel_factor: false,
            motion_init: false,
            correction: true,
            start_from_init_mesh: true,
            temporal_vertex_weight: 0.01,
            temporal_beta: 0.5,
            placement: Placement::Aligned,
            motion_weight: 1.0,
            quality: QualityOptions::default(),
            pcg: None,
            correction_iterations: 2,
            correction_warm_start: false,
            one_step_tolerance: Some(1e-3),
        }
    }
}

/// Options for warm-started frames of a sequence. The IK mesh of a warm-started IK is
/// already close, so the V-step takes one accepted LM step (rejected ones are retried with a
/// larger damping, [`FitOptions::step_retries`]; before they were not, and every warm step of
/// the eval's clip was rejected: PanoMan's warm frames were the LBS initializer's), starting
/// from the default damping μ₀ = 1 (on the eval's held-out clip, first 24 frames, default
/// model: μ₀ = 1e−2 / 0.3 / 1 / 10 gave 3.49 / 3.37 / 3.35 / 3.34 mm against the
/// initializer's 3.34 mm). The placement is propagated from the previous frame instead of
/// re-solving `g`. The step is solved by PCG ([`PcgOptions::default`]): with μ = 1 the damped
/// system is well conditioned, and 6–14 conjugate-gradient products replace the numeric
/// factorization (docs/design/shell-fit.md §3.5). Each β-step makes one fixed-point iteration
/// of the correction from the β at hand instead of two from the uncorrected projection (on
/// the eval's clip: the same tracking error to 10⁻⁵ mm, the warm frame 137 → 114 ms).
pub fn warm_fit_options() -> FitOptions {
    FitOptions {
        step_iterations: 1,
        placement: Placement::Propagated,
        pcg: Some(PcgOptions::default()),
        correction_iterations: 1,
        correction_warm_start: true,
        ..FitOptions::default()
    }
}

/// A vertex handle as given by the user: dimensionless weight (multiplied by λ_H/ℓ̄²).
#[derive(Clone, Debug, PartialEq, serde::Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct VertexHandle {
    /// Vertex index in the model's template.
    pub vertex: u32,
    /// Target position (metres).
    pub position: V3,
    /// Relative weight (default 1).
    #[serde(default = "one")]
    pub weight: f64,
}

fn one() -> f64 {
    1.0
}

/// A level constraint between two vertices: `n̂ᵀ(x_a − x_b) = d` — the height of vertex `a`
/// above vertex `b` along the unit direction `n̂` (e.g. world up) is `d` metres. A sole held
/// level on the floor is two of them per foot (heel against big toe and against small toe,
/// [`crate::fit::LevelPair`]s built by `panoman::feet`): a foot-contact prior that needs no
/// observation of the foot. The skeletal IK fits each as a point-to-plane target of the
/// combination `x_a − x_b` ([`crate::ik::PointTarget`] with rows `[(a, 1), (b, −1)]` and
/// normal `n̂`), with the handles' final stage ([`crate::pipeline::ik_fit`]); the shell fit
/// starts from that IK and follows its guidance pose there.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LevelPair {
    /// The upper vertex `a` (model template index).
    pub a: u32,
    /// The lower vertex `b`.
    pub b: u32,
    /// Direction `n` along which heights are measured (any length > 0; normalised).
    pub up: V3,
    /// Target height `d` of `a` above `b` along `n̂`, metres.
    pub offset: f64,
    /// Relative weight, in keypoint units (1 = one keypoint's squared distance).
    #[serde(default = "one")]
    pub weight: f64,
}

/// The constraint set of one fit: its [`Targets`] and what the fit holds fixed, is pulled
/// toward, or carries from the previous frame.
#[derive(Clone, Debug, Default)]
pub struct Constraints {
    /// What the fit matches: keypoints, vertex handles, level pairs, a point cloud.
    pub targets: Targets,
    /// Parameter edits: α (when non-empty) and the β blocks present here are held fixed.
    pub fixed: Option<Params>,
    /// Motion data θ: local Euler angles (radians, `R = Rz·Ry·Rx`) by rig bone name, e.g. from
    /// motion capture. Through the model's motion MLP it gives `β_θ = β_MLP(θ)` for the body
    /// blocks, which starts β_B and pulls every β-step toward it with
    /// [`FitOptions::motion_weight`] (PanoMan §5: motion data as a parameter constraint).
    pub motion: Option<std::collections::BTreeMap<String, [f64; 3]>>,
    /// The previous frame of a sequence: warm start, temporal terms
    /// ([`FitOptions::temporal_vertex_weight`], [`FitOptions::temporal_beta`]), its shape α
    /// (kept for the whole sequence) and its placement ([`Placement::Propagated`]).
    pub previous: Option<Previous>,
}

impl Constraints {
    /// The constraints of `targets` alone (nothing fixed, no motion data, no previous frame).
    pub fn of(targets: Targets) -> Constraints {
        Constraints {
            targets,
            ..Default::default()
        }
    }

    /// The constraints of keypoints alone.
    pub fn from_keypoints(keypoints: KeypointsFile) -> Constraints {
        Constraints::of(Targets {
            keypoints,
            ..Default::default()
        })
    }
}

/// The previous frame of a sequence.
#[derive(Clone, Debug)]
pub struct Previous {
    /// Its fit.
    pub vertices: Vec<V3>,
    /// Its parameters, with their placement.
    pub params: Params,
    /// Its initializer's mesh (the IK mesh). With it the temporal vertex target is the previous
    /// fit carried along by the skeletal motion, `x_prev + (x_init − x_init,prev)`, so that the
    /// term smooths the non-skeletal detail without lagging behind the motion; without it the
    /// target is `x_prev`.
    pub init: Option<Vec<V3>>,
}

/// How a fit's parameters get their rigid placement (`rotation`, `translation`: the motion
/// that puts `B_P(α, β)`, built in the gauge of `B_S(α)`, onto the fitted vertices).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// Least-squares rigid alignment of `B_P(α, β)` (one `g` solve, about 0.4 s on the full
    /// template) to the fit.
    Aligned,
    /// In a sequence: the previous frame's placement followed by the rigid motion of the
    /// fit's torso (vertices within 0.12 m of the neck–pelvis axis of the mean shape) since
    /// the previous frame; no `g` solve. `Aligned` when there is no previous frame.
    Propagated,
}

/// Where the fit starts: a mesh in template topology and its rest shape (from skeletal IK, or
/// the previous frame of a sequence).
#[derive(Clone, Debug)]
pub struct Init {
    /// Posed vertices.
    pub posed: Vec<V3>,
    /// Rest shape of the same person (α is its PCA projection).
    pub rest: Vec<V3>,
    /// The skeleton pose that produced `posed` (local Euler angles in radians by bone name),
    /// for the motion MLP's β_B (see [`FitOptions::motion_init`]).
    pub theta: Option<std::collections::BTreeMap<String, [f64; 3]>>,
    /// A mesh of the same person whose *local* shape the first guidance pose is projected
    /// from instead of `posed` (RL/RA are invariant to rigid motion, so a limb rotated as a
    /// whole keeps them): the IK's pose with large arm twists clamped to where linear-blend
    /// skinning does not collapse the limb. The V-steps still start from `posed` (whose
    /// keypoints are right), and the shell energy toward this guidance restores the limb's
    /// lengths and cross-sections while the keypoints keep the twist (PanoMan Fig. 1, 13).
    pub guide: Option<Vec<V3>>,
}

/// Time, iterations and energies of one stage.
#[derive(Clone, Debug, Serialize)]
pub struct StageReport {
    /// Stage name.
    pub name: String,
    /// Wall time (s).
    pub seconds: f64,
    /// LM iterations (linear solves) tried in the stage, rejected ones included.
    pub iterations: usize,
    /// Accepted LM iterations (steps that lowered the energy).
    pub accepted: usize,
    /// Shell+constraint energy (dimensionless) at the start of the stage's first V-step; the
    /// end is that of its last V-step (a β-step between sweeps changes the guidance, so with
    /// several sweeps the two are energies of different targets).
    pub energy_start: f64,
    /// See `energy_start`.
    pub energy_end: f64,
    /// ICP matching statistics (ICP stages).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub matches: Option<MatchStats>,
}

impl StageReport {
    /// A stage without LM iterations (projection, placement) that started at `t`.
    fn timed(name: &str, t: Instant) -> Self {
        StageReport {
            name: name.into(),
            seconds: t.elapsed().as_secs_f64(),
            iterations: 0,
            accepted: 0,
            energy_start: 0.0,
            energy_end: 0.0,
            matches: None,
        }
    }

    /// A stage that started at `t` and ended with the V-step `rep`.
    fn of_solve(
        name: impl Into<String>,
        t: Instant,
        rep: &ShellReport,
        matches: Option<MatchStats>,
    ) -> Self {
        StageReport {
            name: name.into(),
            seconds: t.elapsed().as_secs_f64(),
            iterations: rep.iterations,
            accepted: rep.accepted,
            energy_start: rep.energies[0],
            energy_end: *rep.energies.last().unwrap_or(&0.0),
            matches,
        }
    }
}

/// Residual of one keypoint group (mm).
#[derive(Clone, Debug, Default, Serialize)]
pub struct GroupResidual {
    /// Keypoints of the group that were given.
    pub n: usize,
    /// Mean distance (mm).
    pub mean_mm: f64,
    /// Max distance (mm).
    pub max_mm: f64,
}

/// Everything a fit reports.
#[derive(Clone, Debug, Serialize)]
pub struct ShellFitReport {
    /// Per stage.
    pub stages: Vec<StageReport>,
    /// Keypoint residuals per group (body, face, left_hand, right_hand), after the fit.
    pub keypoint_residuals: std::collections::BTreeMap<KeypointGroup, GroupResidual>,
    /// Total time (s) of [`ShellFitter::fit`] (initializer excluded).
    pub seconds: f64,
    /// The quality check of the fit's final keypoint residuals and shape ([`crate::quality`];
    /// [`crate::FrameSolver::fit`] adds the initializer's attempts).
    pub verdict: Verdict,
}

/// A fitted mesh with its parameters.
#[derive(Clone, Debug)]
pub struct FitResult {
    /// Fitted vertices (template topology, metres).
    pub vertices: Vec<V3>,
    /// α, β of the last β-step and the rigid motion placing `B_P(α, β)` on the fit.
    pub params: Params,
    /// Report.
    pub report: ShellFitReport,
}

/// Per-model fitting state: the evaluator (g, encoder), the shell solver whose pattern
/// includes the keypoint regressors' couplings, and the ICP incidence lists. Build once, fit
/// many frames.
pub struct ShellFitter {
    model: Arc<PanoManModel>,
    ev: Evaluator,
    solver: ShellSolver,
    vf: VertexFaces,
    mean_edge: f64,
    /// 1 on the torso vertices of [`Placement::Propagated`], 0 elsewhere.
    torso_weights: Vec<f64>,
    /// The rest geometry of the last fit's α (a sequence keeps α).
    rest_cache: Option<(Vec<f64>, RestGeometry)>,
    /// β_θ = (β_LB, β_AB) of the current fit's motion data, if any.
    motion_beta: Option<(Vec<f64>, Vec<f64>)>,
    /// The last correction residual `R(β_B)` with its input (the body β as f32): a warm
    /// frame's final β-step asks for the residual of the β its guidance was made of.
    correction_memo: Option<(Vec<f32>, Vec<f32>)>,
}

impl ShellFitter {
    /// Builds the per-model state (topology, g, encoder, shell pattern + symbolic factor).
    pub fn new(model: Arc<PanoManModel>) -> Result<Self> {
        let ev = Evaluator::new(model.clone())?;
        Self::with_evaluator(ev)
    }

    /// Builds the fitting state around an existing evaluator of the model (its topology
    /// tables and `g`'s factorizations are reused, not rebuilt).
    pub fn with_evaluator(ev: Evaluator) -> Result<Self> {
        let model = ev.model.clone();
        let model = &model;
        let topo = ev.topology().clone();
        // Narrow regressors (face landmarks, hand joints) couple their vertices in JᵀJ; wide
        // ones (body joints, 200 vertices) are dense supports, solved through the
        // quasi-definite system instead of a 200-vertex clique each (full template: JᵀJ
        // 3.24M → 0.91M entries, one LM iteration 125 → 90 ms).
        let mut extra = Vec::new();
        let mut dense = Vec::new();
        for row in &model.keypoints.rows {
            if row.len() > DENSE_SUPPORT {
                dense.push(row.clone());
                continue;
            }
            for (p, &(a, _)) in row.iter().enumerate() {
                for &(b, _) in &row[..p] {
                    if a != b {
                        extra.push((a.min(b), a.max(b)));
                    }
                }
            }
        }
        extra.sort_unstable();
        extra.dedup();
        let solver = ShellSolver::with_dense_supports(&topo, &extra, &dense)?;
        let vf = VertexFaces::new(&topo);
        let rest = model.rest_shape(&[]);
        let rg = RestGeometry::new(&topo, &rest)?;
        let mean_edge = rg.lengths.iter().sum::<f64>() / rg.lengths.len().max(1) as f64;
        let torso_weights = torso_weights(model, &rest);
        Ok(ShellFitter {
            model: model.clone(),
            ev,
            solver,
            vf,
            mean_edge,
            torso_weights,
            rest_cache: None,
            motion_beta: None,
            correction_memo: None,
        })
    }

    /// The model.
    pub fn model(&self) -> &Arc<PanoManModel> {
        &self.model
    }

    /// The template topology.
    pub fn topology(&self) -> &Topology {
        self.ev.topology()
    }

    /// Mean rest edge length ℓ̄ of the mean shape (m), the scale of the constraint weights.
    pub fn mean_edge(&self) -> f64 {
        self.mean_edge
    }

    /// Checks the constraint set against the model: keypoints the model defines, finite
    /// values, handle vertices in range, a non-empty point cloud.
    pub fn validate(&self, c: &Constraints) -> Result<()> {
        c.targets
            .keypoints
            .validate()
            .map_err(|e| FitError::Invalid(format!("keypoints: {e}")))?;
        if c.targets.keypoints.points.is_empty()
            && c.targets.handles.is_empty()
            && c.targets.points.is_none()
        {
            return Err(FitError::Invalid(
                "nothing to fit: no keypoints, handles or points".into(),
            ));
        }
        let names = &self.model.keypoints.names;
        for &k in c.targets.keypoints.points.keys() {
            let name = &panoman_human::keypoints::keypoint_names()[k];
            if !names.iter().any(|n| n == name) {
                return Err(FitError::Invalid(format!(
                    "keypoint '{name}' is not defined by the model"
                )));
            }
        }
        let nv = self.model.n_vertices;
        for (i, h) in c.targets.handles.iter().enumerate() {
            if h.vertex as usize >= nv {
                return Err(FitError::Invalid(format!(
                    "handle {i}: vertex {} out of range (the model has {nv} vertices)",
                    h.vertex
                )));
            }
            if !h.position.iter().all(|x| x.is_finite()) || h.weight.is_nan() || h.weight < 0.0 {
                return Err(FitError::Invalid(format!(
                    "handle {i}: non-finite position or negative weight"
                )));
            }
        }
        for (i, l) in c.targets.levels.iter().enumerate() {
            if l.a as usize >= nv || l.b as usize >= nv || l.a == l.b {
                return Err(FitError::Invalid(format!(
                    "level {i}: vertices {} and {} out of range or equal (the model has {nv} vertices)",
                    l.a, l.b
                )));
            }
            let ok = l.up.iter().all(|x| x.is_finite())
                && norm(l.up) > 1e-12
                && l.offset.is_finite()
                && l.weight.is_finite()
                && l.weight >= 0.0;
            if !ok {
                return Err(FitError::Invalid(format!(
                    "level {i}: zero or non-finite direction, non-finite offset or negative weight"
                )));
            }
        }
        if let Some(crate::targets::PointCloud {
            positions: p,
            normals: n,
        }) = &c.targets.points
        {
            if p.is_empty() {
                return Err(FitError::Invalid("the point cloud is empty".into()));
            }
            if let Some(i) = p.iter().position(|x| !x.iter().all(|c| c.is_finite())) {
                return Err(FitError::Invalid(format!("point {i} is not finite")));
            }
            if let Some(n) = n
                && n.len() != p.len()
            {
                return Err(FitError::Invalid(format!(
                    "{} normals for {} points",
                    n.len(),
                    p.len()
                )));
            }
        }
        if let Some(f) = &c.fixed {
            f.validate(&self.model)?;
        }
        if let Some(m) = &c.motion {
            if self.model.motion.is_none() {
                return Err(FitError::Invalid(
                    "motion data given, but the model has no motion MLP".into(),
                ));
            }
            if let Some((b, _)) = m.iter().find(|(_, e)| !e.iter().all(|x| x.is_finite())) {
                return Err(FitError::Invalid(format!(
                    "motion data: bone '{b}' has a non-finite angle"
                )));
            }
        }
        if let Some(prev) = &c.previous {
            for (what, len) in [
                ("vertices", Some(prev.vertices.len())),
                ("initializer vertices", prev.init.as_ref().map(Vec::len)),
            ] {
                if let Some(len) = len
                    && len != nv
                {
                    return Err(FitError::Invalid(format!(
                        "previous frame has {len} {what}, the model has {nv}"
                    )));
                }
            }
            prev.params.validate(&self.model)?;
        }
        Ok(())
    }

    /// Model row index of each given keypoint, with target and weight.
    fn keypoint_terms(&self, c: &Constraints, only: Option<&[&str]>) -> Vec<(usize, V3, f64)> {
        let all = panoman_human::keypoints::keypoint_names();
        let mut out = Vec::new();
        for (&k, &p) in &c.targets.keypoints.points {
            let name = &all[k];
            if let Some(only) = only
                && !only.contains(&name.as_str())
            {
                continue;
            }
            if let Some(r) = self.model.keypoints.names.iter().position(|n| n == name) {
                out.push((r, p, c.targets.keypoints.weight(k)));
            }
        }
        out
    }

    /// Keypoint, handle and temporal terms (`init`: this frame's initializer mesh, which
    /// carries the previous fit along the skeletal motion, see [`Previous::init`]).
    fn constraint_targets(
        &self,
        targets: &mut ShellTargets,
        kp: &[(usize, V3, f64)],
        c: &Constraints,
        init: &[V3],
        opts: &FitOptions,
    ) {
        let l2 = self.mean_edge * self.mean_edge;
        targets.points = kp
            .iter()
            .map(|&(r, p, w)| PointConstraint {
                rows: self.model.keypoints.rows[r].clone(),
                target: p,
                weight: opts.keypoint_weight * w / l2,
                normal: None,
            })
            .collect();
        targets.handles = c
            .targets
            .handles
            .iter()
            .map(|h| Handle {
                vertex: h.vertex,
                position: h.position,
                weight: opts.handle_weight * h.weight / l2,
            })
            .collect();
        if let Some(prev) = &c.previous
            && opts.temporal_vertex_weight > 0.0
        {
            let carried = |v: usize| match &prev.init {
                Some(a) => add(prev.vertices[v], sub(init[v], a[v])),
                None => prev.vertices[v],
            };
            targets
                .handles
                .extend((0..prev.vertices.len()).map(|v| Handle {
                    vertex: v as u32,
                    position: carried(v),
                    weight: opts.temporal_vertex_weight / l2,
                }));
        }
    }

    /// The correction residual `R(β_B)` of `params` ([`PanoManModel::correction_residual`]),
    /// reused when the body β is the last call's.
    fn correction(&mut self, params: &Params) -> Option<Vec<f32>> {
        self.model.correction.as_ref()?;
        let x = self.model.body_beta_f32(params);
        if let Some((input, r)) = &self.correction_memo
            && *input == x
        {
            return Some(r.clone());
        }
        let r = self.model.correction_residual(params)?;
        self.correction_memo = Some((x, r.clone()));
        Some(r)
    }

    /// Computes (and keeps) the correction residual that the first β-step of [`ShellFitter::fit`]
    /// with `c` and `opts` will ask for when it starts from the previous frame's β
    /// ([`FitOptions::correction_warm_start`]): `R(β_prev)` depends only on the previous frame,
    /// so a tracker can compute it while the skeletal IK of the new frame runs
    /// ([`crate::FrameSolver::fit`]). The fit's result is the same (the fit finds it
    /// in the memo); nothing happens when that β-step would not ask for it.
    pub fn prefetch_correction(&mut self, c: &Constraints, opts: &FitOptions) {
        let body = &self.model.blocks[0].name;
        if let Some(prev) = &c.previous
            && opts.correction
            && opts.correction_warm_start
            && opts.correction_iterations > 0
            && self.model.correction.is_some()
            && prev.params.beta.contains_key(body)
        {
            let params = Params {
                beta: prev.params.beta.clone(),
                ..Default::default()
            };
            self.correction(&params);
        }
    }

    /// Shell targets of the guidance pose `B_P(α, β)` on the rest shape `B_S(α)`.
    fn guidance(
        &mut self,
        params: &Params,
        rg: &RestGeometry,
        x: &[V3],
        opts: &FitOptions,
    ) -> Result<ShellTargets> {
        let r = if opts.correction {
            self.correction(params)
        } else {
            None
        };
        let rla = self.model.rla_with_residual(params, r.as_deref());
        Ok(ShellTargets::from_rla(
            self.ev.topology(),
            rg,
            &rla,
            x,
            opts.c_b,
        )?)
    }

    /// V-step: `iterations` LM iterations of the shell energy with `targets` from `x`, starting
    /// from the damping `mu`.
    fn v_step(
        &mut self,
        targets: &ShellTargets,
        x: &mut [V3],
        iterations: usize,
        mu: f64,
        opts: &FitOptions,
    ) -> Result<ShellReport> {
        let r = self.solver.solve(
            targets,
            x,
            &ShellOptions {
                max_iterations: iterations,
                retry_rejected: opts.step_retries,
                mu_init: mu,
                parallel_factor: opts.parallel_factor,
                pcg: opts.pcg,
                ..Default::default()
            },
        )?;
        Ok(r)
    }

    /// β-step: least-squares β of V's RL/RA w.r.t. `B_S(α)`; fixed blocks keep their values.
    fn beta_step(
        &mut self,
        x: &[V3],
        rg: &RestGeometry,
        params: &mut Params,
        c: &Constraints,
        opts: &FitOptions,
    ) -> Result<()> {
        let rla = Rla::compute(self.ev.topology(), rg, x)?;
        // Fixed point β ← LS(RLA − R(β)) of the correction (docs/design/shell-fit.md §4):
        // from the uncorrected projection, or (`correction_warm_start`) from the β at hand —
        // this frame's earlier β-step, else the previous frame's.
        let body = &self.model.blocks[0].name;
        let warm = opts.correction_warm_start
            && self.model.correction.is_some()
            && opts.correction
            && (params.beta.contains_key(body)
                || c.previous
                    .as_ref()
                    .is_some_and(|p| p.params.beta.contains_key(body)));
        if warm {
            if !params.beta.contains_key(body)
                && let Some(prev) = &c.previous
            {
                params.beta = prev.params.beta.clone();
            }
        } else {
            self.ev.encode_beta(&rla, params, None)?;
        }
        if opts.correction && self.model.correction.is_some() {
            for _ in 0..opts.correction_iterations {
                let r = self.correction(params).expect("has correction");
                self.ev.encode_beta(&rla, params, Some(&r))?;
            }
        }
        if let Some((bl, ba)) = &self.motion_beta
            && opts.motion_weight > 0.0
        {
            let tau = opts.motion_weight;
            for (b, target) in [(0usize, bl), (3, ba)] {
                if let Some(v) = params.beta.get_mut(&self.model.blocks[b].name)
                    && v.len() == target.len()
                {
                    for (x, t) in v.iter_mut().zip(target) {
                        *x = (*x + tau * t) / (1.0 + tau);
                    }
                }
            }
        }
        if let Some(prev) = &c.previous
            && opts.temporal_beta > 0.0
        {
            let tau = opts.temporal_beta;
            for (name, b) in params.beta.iter_mut() {
                if let Some(pb) = prev.params.beta.get(name)
                    && pb.len() == b.len()
                {
                    for (x, p) in b.iter_mut().zip(pb) {
                        *x = (*x + tau * p) / (1.0 + tau);
                    }
                }
            }
        }
        if let Some(f) = &c.fixed {
            for (name, b) in &f.beta {
                if !b.is_empty() {
                    params.beta.insert(*name, b.clone());
                }
            }
        }
        Ok(())
    }

    /// Fits the constraints from `init` (see the module docs for the stages).
    pub fn fit(&mut self, c: &Constraints, init: &Init, opts: &FitOptions) -> Result<FitResult> {
        self.validate(c)?;
        let nv = self.model.n_vertices;
        if init.posed.len() != nv || init.rest.len() != nv {
            return Err(FitError::Invalid(format!(
                "initial meshes have {} / {} vertices, the model has {nv}",
                init.posed.len(),
                init.rest.len()
            )));
        }
        let t0 = Instant::now();
        let mut stages = Vec::new();
        // Initial parameters: α fixed, kept from the previous frame of a sequence, or the
        // projection of the initializer's rest shape; β by projection of the initial mesh.
        let t = Instant::now();
        let alpha = match (&c.fixed, &c.previous) {
            (Some(f), _) if !f.alpha.is_empty() => f.alpha.clone(),
            (_, Some(prev)) => prev.params.alpha.clone(),
            _ => {
                let flat: Vec<f64> = init.rest.iter().flatten().copied().collect();
                self.model.shape.project(&flat)
            }
        };
        let rg = match self.rest_cache.take() {
            Some((a, rg)) if a == alpha => rg,
            _ => RestGeometry::new(self.ev.topology(), &self.model.rest_shape(&alpha))?,
        };
        let mut params = Params {
            alpha,
            ..Default::default()
        };
        // β_θ of the motion data (a constraint), else of the initializer's skeleton pose when
        // `motion_init` (a start only).
        self.motion_beta = c
            .motion
            .as_ref()
            .and_then(|m| self.model.beta_from_theta(&|b: &str| m.get(b).copied()));
        let start_theta = match (&self.motion_beta, &init.theta) {
            (Some(mb), _) => Some(mb.clone()),
            (None, Some(theta)) if opts.motion_init => {
                self.model.beta_from_theta(&|b: &str| theta.get(b).copied())
            }
            _ => None,
        };
        let guide = init.guide.as_ref().filter(|g| g.len() == nv);
        self.beta_step(guide.unwrap_or(&init.posed), &rg, &mut params, c, opts)?;
        if let Some((bl, ba)) = start_theta {
            let fixed = |name: BlockName| {
                c.fixed
                    .as_ref()
                    .is_some_and(|f| f.beta.get(&name).is_some_and(|b| !b.is_empty()))
            };
            for (name, v) in [(BlockName::BodyLength, bl), (BlockName::BodyAngle, ba)] {
                if !fixed(name) {
                    params.beta.insert(name, v);
                }
            }
        }
        let all_kp = self.keypoint_terms(c, None);
        let mut x = if opts.start_from_init_mesh {
            init.posed.clone()
        } else {
            let mut p0 = params.clone();
            p0.rotation = [0.0; 3];
            p0.translation = [0.0; 3];
            let mut g = self.ev.pose(&p0, opts.correction)?;
            // Rigid placement on the keypoints (all given; the initial mesh when none).
            let (a, b): (Vec<V3>, Vec<V3>) = if all_kp.len() >= 3 {
                let k = self.model.keypoints.evaluate(&g);
                all_kp.iter().map(|&(r, p, _)| (k[r], p)).unzip()
            } else {
                (g.clone(), init.posed.clone())
            };
            let m = rigid_align(&a, &b, None);
            m.apply_all(&mut g);
            g
        };
        stages.push(StageReport::timed("init", t));
        // Stage 1: torso keypoints.
        let torso = self.keypoint_terms(c, Some(&TORSO_KEYPOINTS));
        if !torso.is_empty() && opts.torso_iterations > 0 {
            let t = Instant::now();
            let mut targets = self.guidance(&params, &rg, &x, opts)?;
            self.constraint_targets(&mut targets, &torso, c, &init.posed, opts);
            let rep = self.v_step(&targets, &mut x, opts.torso_iterations, opts.mu_init, opts)?;
            stages.push(StageReport::of_solve("torso", t, &rep, None));
        }
        // Stage 2: all keypoints, alternating V- and β-steps.
        let pass = StagePass {
            rg: &rg,
            c,
            init,
            kp: &all_kp,
            opts,
        };
        stages.push(self.keypoint_stage(&pass, &mut x, &mut params)?);
        // Stage 3: ICP.
        stages.extend(self.icp_stages(&pass, &mut x, &mut params)?);
        // Final parameters and the rigid motion placing B_P(α, β) on the fit.
        let t = Instant::now();
        self.beta_step(&x, &rg, &mut params, c, opts)?;
        let placement = self.placement(c, &x, &mut params, opts)?;
        params.rotation = rotation_vector(&placement.r);
        params.translation = placement.t;
        self.rest_cache = Some((params.alpha.clone(), rg));
        stages.push(StageReport::timed("params", t));
        let keypoint_residuals = keypoint_residuals(&self.model, &c.targets.keypoints, &x);
        let mut problems = opts.quality.keypoint_problems(&keypoint_residuals);
        problems.extend(opts.quality.shape_problems(&self.model, &params.alpha));
        let report = ShellFitReport {
            stages,
            keypoint_residuals,
            seconds: t0.elapsed().as_secs_f64(),
            verdict: Verdict::from_problems(problems, &opts.quality, Vec::new()),
        };
        Ok(FitResult {
            vertices: x,
            params,
            report,
        })
    }

    /// Stage 2 of [`ShellFitter::fit`]: `opts.sweeps` sweeps of a V-step on all keypoints, each
    /// after the first preceded by a β-step; a cold fit may stop after one step
    /// ([`FitOptions::one_step_tolerance`]).
    fn keypoint_stage(
        &mut self,
        pass: &StagePass<'_>,
        x: &mut [V3],
        params: &mut Params,
    ) -> Result<StageReport> {
        let (rg, c, opts) = (pass.rg, pass.c, pass.opts);
        let t = Instant::now();
        let mut its = 0;
        let mut acc = 0;
        let (mut e0, mut e1) = (0.0, 0.0);
        let one_step = opts.one_step_tolerance.filter(|_| {
            c.previous.is_none()
                && c.motion.is_none()
                && opts.pcg.is_none()
                && opts.sweeps <= 1
                && opts.step_iterations > 1
                && !c.targets.keypoints.points.is_empty()
        });
        for sweep in 0..opts.sweeps.max(1) {
            if sweep > 0 {
                self.beta_step(x, rg, params, c, opts)?;
            }
            let mut targets = self.guidance(params, rg, x, opts)?;
            self.constraint_targets(&mut targets, pass.kp, c, &pass.init.posed, opts);
            let mut iterations = opts.step_iterations;
            let mut energies = Vec::new();
            if let Some(tol) = one_step {
                let quick = FitOptions {
                    pcg: Some(PcgOptions::default()),
                    ..opts.clone()
                };
                let rep = self.v_step(&targets, x, 1, opts.mu_init, &quick)?;
                its += rep.iterations;
                acc += rep.accepted;
                energies.extend_from_slice(&rep.energies);
                let within = keypoint_residuals(&self.model, &c.targets.keypoints, x)
                    .values()
                    .all(|g| g.mean_mm <= 1e3 * tol);
                iterations = if within { 0 } else { iterations - 1 };
            }
            if iterations > 0 {
                let rep = self.v_step(&targets, x, iterations, opts.mu_init, opts)?;
                its += rep.iterations;
                acc += rep.accepted;
                energies.extend_from_slice(&rep.energies);
            }
            if sweep == 0 {
                e0 = energies[0];
            }
            e1 = *energies.last().unwrap_or(&0.0);
        }
        Ok(StageReport {
            name: "keypoints".into(),
            seconds: t.elapsed().as_secs_f64(),
            iterations: its,
            accepted: acc,
            energy_start: e0,
            energy_end: e1,
            matches: None,
        })
    }

    /// Stage 3 of [`ShellFitter::fit`]: `opts.icp_passes` passes of β-step, closest-point matching
    /// to the point cloud and V-step (none without a point cloud).
    fn icp_stages(
        &mut self,
        pass: &StagePass<'_>,
        x: &mut [V3],
        params: &mut Params,
    ) -> Result<Vec<StageReport>> {
        let (rg, c, opts) = (pass.rg, pass.c, pass.opts);
        let mut stages = Vec::new();
        let Some(crate::targets::PointCloud {
            positions: pts,
            normals: nrm,
        }) = &c.targets.points
        else {
            return Ok(stages);
        };
        let l2 = self.mean_edge * self.mean_edge;
        for i in 0..opts.icp_passes {
            let t = Instant::now();
            self.beta_step(x, rg, params, c, opts)?;
            let mut targets = self.guidance(params, rg, x, opts)?;
            self.constraint_targets(&mut targets, pass.kp, c, &pass.init.posed, opts);
            let (cons, stats) = correspondences_on(
                &self.ev.topology().faces,
                &self.vf,
                x,
                pts,
                nrm.as_deref(),
                opts.icp_weight / l2,
                &opts.icp,
            );
            targets.points.extend(cons);
            let rep = self.v_step(&targets, x, opts.step_iterations, opts.icp_mu_init, opts)?;
            stages.push(StageReport::of_solve(
                format!("icp{}", i + 1),
                t,
                &rep,
                Some(stats),
            ));
        }
        Ok(stages)
    }

    /// The rigid motion placing `B_P(α, β)` on the fit `x` ([`FitOptions::placement`]);
    /// `params`' rigid motion is zeroed where the guidance pose is evaluated.
    fn placement(
        &mut self,
        c: &Constraints,
        x: &[V3],
        params: &mut Params,
        opts: &FitOptions,
    ) -> Result<Rigid> {
        Ok(match (&c.previous, opts.placement) {
            (Some(prev), Placement::Propagated) => {
                // The torso patch's rigid motion since the previous frame, applied to the
                // previous placement.
                let k = rigid_align(&prev.vertices, x, Some(&self.torso_weights));
                let r0 = from_rotation_vector(prev.params.rotation);
                Rigid {
                    r: matmul(&k.r, &r0),
                    t: add(matvec(&k.r, prev.params.translation), k.t),
                }
            }
            _ => {
                params.rotation = [0.0; 3];
                params.translation = [0.0; 3];
                let guide = self.ev.pose(params, opts.correction)?;
                rigid_align(&guide, x, None)
            }
        })
    }
}

/// What the keypoint and ICP stages of [`ShellFitter::fit`] share: the rest geometry of `α`, the
/// constraints, the initializer and the keypoint terms of all given keypoints.
struct StagePass<'p> {
    rg: &'p RestGeometry,
    c: &'p Constraints,
    init: &'p Init,
    kp: &'p [(usize, V3, f64)],
    opts: &'p FitOptions,
}

/// Radius (m) around the neck–pelvis axis of the mean shape that selects the torso vertices of
/// [`Placement::Propagated`] (chest, belly and back; the arms hang further out).
const TORSO_RADIUS: f64 = 0.12;

/// 1 on the vertices of `rest` within [`TORSO_RADIUS`] of the segment between the model's
/// `neck` and `body_center` keypoints, 0 elsewhere (all 1 if the model lacks them or the
/// selection is too small for a rigid fit).
fn torso_weights(model: &PanoManModel, rest: &[V3]) -> Vec<f64> {
    let k = model.keypoints.evaluate(rest);
    let at = |name: &str| {
        model
            .keypoints
            .names
            .iter()
            .position(|n| n == name)
            .map(|i| k[i])
    };
    let (Some(a), Some(b)) = (at("neck"), at("body_center")) else {
        return vec![1.0; rest.len()];
    };
    let ab = sub(b, a);
    let l2 = dot(ab, ab).max(1e-12);
    let w: Vec<f64> = rest
        .iter()
        .map(|&p| {
            let s = (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0);
            let q = add(a, scale(ab, s));
            if norm(sub(p, q)) < TORSO_RADIUS {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    if w.iter().sum::<f64>() < 10.0 {
        vec![1.0; rest.len()]
    } else {
        w
    }
}

/// Residual per keypoint group (mm) of the model's keypoints on `x` against the targets.
pub fn keypoint_residuals(
    model: &PanoManModel,
    kp: &KeypointsFile,
    x: &[V3],
) -> std::collections::BTreeMap<KeypointGroup, GroupResidual> {
    let all = panoman_human::keypoints::keypoint_names();
    let values = model.keypoints.evaluate(x);
    group_residuals(kp.points.iter().filter_map(|(&k, &p)| {
        let r = model.keypoints.names.iter().position(|n| n == &all[k])?;
        Some((k, 1e3 * norm(sub(values[r], p))))
    }))
}

/// Mean and max per keypoint group of `(TC-133 index, distance in mm)` pairs.
pub fn group_residuals(
    distances: impl Iterator<Item = (usize, f64)>,
) -> std::collections::BTreeMap<KeypointGroup, GroupResidual> {
    let mut out: std::collections::BTreeMap<KeypointGroup, GroupResidual> = Default::default();
    for (k, d) in distances {
        let g = out.entry(KeypointGroup::of(k)).or_default();
        g.n += 1;
        g.mean_mm += d;
        g.max_mm = g.max_mm.max(d);
    }
    for g in out.values_mut() {
        g.mean_mm /= g.n.max(1) as f64;
    }
    out
}
