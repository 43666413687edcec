//! Inverse kinematics of the LBS rig to TC-133 keypoints: the generator's parameters
//! (global rigid motion, local bone Euler angles, phenotype, face units) that best explain
//! a set of target keypoints.
//!
//! # Model
//! For parameters `p = (R, u, θ, β, f)` — global rotation `R ∈ SO(3)`, root translation `u`,
//! per-bone Euler angles `θ_c = (x, y, z)` (radians, `E_c = Rz(z)·Ry(y)·Rx(x)`), the six
//! phenotype values `β` (gender, age, muscle, weight, height, proportions) and the 52 face
//! units `f` — the generator ([`panoman_human::generator`]) gives the posed vertices
//!
//! `x_v(p) = Σ_b w_vb T_b(p) x̄_v(β, f)`, `T_b = W_b P_b⁻¹`,
//! `W_0 = [R | h_0 + u]`, `W_c = W_parent · P_parent⁻¹ P_c · [E_c | 0]`,
//!
//! (rest vertices `x̄`, rest frames `P_c` with heads `h_c`, both functions of `β, f`) and every
//! keypoint is a fixed sparse linear combination `K_k = Σ_v a_kv x_v` of template vertices,
//! composed here with the topology map so that `v` runs over Anny's output vertices. Because
//! `T_b` is affine, a keypoint collapses to a sum over the bones that skin its vertices:
//!
//! `K_k = Σ_b (M_b X_kb + σ_kb t_b)`, `X_kb = Σ_v a_kv w_vb x̄_v`, `σ_kb = Σ_v a_kv w_vb`,
//!
//! with `T_b = [M_b | t_b]`. `X_kb` depends on the shape only and `σ_kb` on nothing, so one
//! evaluation costs a forward-kinematics pass over the 163 bones and a few hundred 3×3
//! products (533 `(k, b)` pairs on the full template), independent of the mesh size.
//!
//! **Shape.** The rest mesh is linear in the face units and, inside each cell of the
//! phenotype anchor grid (gender, height, proportions `{0, 1}`; age `{0, ⅓, ⅔, 1}`; muscle,
//! weight `{0, ½, 1}`), multilinear in `β`: every phenotype blendshape coefficient is a
//! product of hat weights of distinct features. So are `X_kb` and the joints (means of rest
//! vertices). The solver therefore stores `X_kb`, heads and tails at the 288 grid points
//! (288 rest meshes of the generator, once per set of non-fitted shape values) and evaluates
//! them — and their `β` derivatives — exactly by multilinear interpolation, adding
//! `Σ_j f_j X^{(j)}_kb`, `Σ_j f_j Δh_j`, `Σ_j f_j Δt_j` for the face units (`X^{(j)}_kb =
//! Σ_v a_kv w_vb B_jv`, `B_j` the unit's displacement). The rest frames follow from the
//! joints (docs/design/rig-and-ik.md §2.3, [`panoman_human::rig::rest_frames`]).
//!
//! # Objective
//! `E(p) = Σ_k w_k |K_k(p) − k̂_k|² + λ_θ Σ_c Σ_a (θ_ca / s_ca)² + λ_β Σ_i (β_i − ½)²
//! + λ_f Σ_j f_j²` over the given targets `k̂_k` with weights `w_k ≥ 0` (metres), where
//! `s_ca = max(|lo|, |hi|)` of the sampler's range of that axis, subject to those ranges
//! ([`panoman_human::sampling::bone_range`]; axes with an empty range stay 0), `β ∈ [0, 1]⁶` (age is
//! kept in `[0, 1]` too) and `f ∈ [0, 1]⁵²`.
//!
//! # Jacobian
//! * **Bone angles** (analytic): a rotation `a` of bone `c` turns everything downstream about
//!   the world axis `ω = G_c n_a` through the posed head `o_c`, where `G_c` is the rotation of
//!   `W_parent P_parent⁻¹ P_c` (the frame before the bone's own delta) and
//!   `n_x = Rz Ry e_x`, `n_y = Rz e_y`, `n_z = e_z` (derivatives of `Rz Ry Rx`). Hence
//!   `∂x_v/∂a = ω × Σ_{b ⪰ c} w_vb (T_b x̄_v − o_c)` and, summing the keypoint's bones,
//!   `∂K_k/∂a = ω × (Y_kc − S_kc o_c)`, `Y_kc = Σ_{b ⪰ c} (M_b X_kb + σ_kb t_b)`,
//!   `S_kc = Σ_{b ⪰ c} σ_kb` (`b ⪰ c`: `b` is `c` or one of its descendants).
//! * **Global motion**: `R ← exp([φ]ₓ) R` gives `∂K_k/∂φ_i = e_i × (K_k − h_0 − u)`
//!   (`S_k0 = 1`: keypoint rows and skin rows sum to 1) and `∂K_k/∂u = I`.
//! * **Face units**: `∂K_k/∂f_j = Σ_b M_b X^{(j)}_kb`, plus, for the units that move the
//!   joints of a posable bone or the root (e.g. the jaw's), the change of the rest frames by a
//!   forward difference (step 1e-6) of the frames alone.
//! * **Phenotype**: `Σ_b M_b ∂X_kb/∂β_i` from the grid's exact multilinear derivative, plus
//!   the frames' part as for the face units. On a kink (an interior anchor) the derivative is
//!   one-sided: the solver takes the side the gradient points to (forward if it says
//!   "increase", backward if "decrease"), or holds the value for the iteration when both
//!   sides go uphill (a kink minimum).
//!
//! # Solver
//! Projected Levenberg–Marquardt: `(H + μ diag(H)) δ = −g` with `H = JᵀWJ + Λ`,
//! `g = JᵀW r + Λ(p − p̄)` over the free variables (a variable on a bound whose gradient
//! points outward is held for the iteration). A variable the step would take out of its
//! bounds is set onto the bound and the system re-solved for the others (active-set
//! refinement, ≤ 6 rounds); a phenotype value's step bounds are the kinks around it, so steps
//! stop on kinks and the one-sided rule above decides whether to cross. A step is accepted
//! if `E` decreases (`μ ← μ/4`), else `μ ← 10μ` and retried. A stage stops when the relative
//! decrease of `E` falls below [`IkConfig::tolerance`], when the RMS keypoint residual is
//! below 1e-8 m, when `μ` exceeds 1e10, or at its iteration cap. The solve is deterministic.
//! Stages (Total Capture's order; the priors are scaled by [`IkConfig::early_prior_scale`] in
//! the first three):
//!
//! 1. `torso`: global motion, spine, clavicles, shoulders — on neck, shoulders, hips, body centre;
//! 2. `body`: global motion, the 33 body bones, phenotype — on the body keypoints plus the
//!    wrists and knuckles of the hands and the rigid face points (nose, eye corners, pupils);
//! 3. `hands_face`: the finger bones, jaw, eyes and face units — on all targets, body fixed;
//! 4. `all`: every variable on all targets; with [`IkConfig::phenotype_restart`] run from two
//!    starts in parallel (rayon) and the lower `E` kept.
//!
//! Variables that no stage target depends on (structurally: no skinned vertex of the
//! keypoint rows below the bone) are left out of the stage.
//!
//! # Point targets
//! [`IkSolver::solve_with_points`] adds surface points `P_p = Σ_m b_pm x_m` (any sparse
//! combination of template vertices, e.g. barycentric points of an ICP match) with targets
//! `p̂_p` and weights `w_p` to the final stage: `E += Σ_p w_p |Π_p (P_p − p̂_p)|²`, `Π_p = n̂n̂ᵀ`
//! (point-to-plane) or `I`. A point is modelled exactly like a keypoint (`Σ_b M_b X_pb +
//! σ_pb t_b`, same analytic Jacobian), but its rest positions come from a per-vertex copy of
//! the phenotype grid (every vertex the topology reaches, built once per set of non-fitted
//! shape values) because the points change from call to call; building the model of a few
//! thousand points is a few milliseconds. Bones only points depend on (toes, e.g.) join the
//! stage. Point-to-plane rows enter the normal equations as scalars `n̂ᵀ∂P`.
//!
//! Initialisation: rest pose with the initial shape, the global motion from weighted Kabsch
//! ([`panoman_mesh::align::rigid_align`]) of the model's torso keypoints onto the targets
//! (all body keypoints, then all targets, if fewer than three torso targets are given; a pure
//! translation of centroids below three points).

#![allow(clippy::needless_range_loop)]
mod grid;
mod jacobian;
mod keypoint_model;
mod lm;
mod solver;
mod stages;
mod targets;

pub use keypoint_model::{
    ELBOW_EXTENSION_DEG, KNEE_EXTENSION_DEG, ik_extension_limit, ik_wide_range,
};
pub use solver::IkSolver;
pub use targets::{IkTarget, IkTargets, PointTarget};

use panoman_human::keypoints::KeypointGroup;
use panoman_human::outputs::OutputTopology;
use panoman_human::params::{GeneratorParams, ShapeParams};
use panoman_human::phenotype::FACE_UNITS;
use panoman_mesh::geom::{IDENTITY, M3, V3, matmul};
use panoman_mesh::rotation::axis_angle;

/// The phenotype values the IK fits, in the order of [`IkState::phenotype`].
pub const IK_PHENOTYPE: [&str; 6] = ["gender", "age", "muscle", "weight", "height", "proportions"];

/// Number of face units (52, [`FACE_UNITS`]).
const N_UNITS: usize = FACE_UNITS.len();

/// Step of the finite differences through the rest frames.
const FRAME_STEP: f64 = 1e-6;

// ---------------------------------------------------------------------------------------------
// Configuration, state and results.

/// Settings of [`IkSolver::solve`].
#[derive(Clone, Debug, PartialEq)]
pub struct IkConfig {
    /// Fit the six phenotype values ([`IK_PHENOTYPE`]) in `[0, 1]` (default true).
    pub fit_phenotype: bool,
    /// Fit the 52 face units in `[0, 1]`; `None` (default): when a face target with positive
    /// weight is given.
    pub fit_face_units: Option<bool>,
    /// `λ_θ`: pose prior `λ_θ Σ_c Σ_a (θ_ca / s_ca)²` in m², where `s_ca` is the largest
    /// |angle| the range of axis `a` of bone `c` allows (default 1e-6).
    pub pose_prior: f64,
    /// Temporal prior of a tracked sequence: `Σ_c λ_T,c Σ_a ((θ_ca − θ⁰_ca) / s_ca)²` in m²
    /// toward the previous frame's angles `θ⁰` (`s_ca` as in `pose_prior`, `λ_T,c` per
    /// bone). An angle the
    /// targets leave free — a finger that no marker sees — then stays where it was instead
    /// of wandering from frame to frame (jitter). `None` (default): none.
    pub temporal: Option<TemporalPrior>,
    /// `λ_β`: phenotype prior `λ_β Σ (β_i − ½)²` in m² (default 1e-5).
    pub phenotype_prior: f64,
    /// `λ_f`: face-unit prior `λ_f Σ f_j²` in m² (default 1e-7).
    pub face_unit_prior: f64,
    /// Factor on the three priors in the first three stages (default 3): they pull harder
    /// while the pose is still far off; the final stage uses the priors as given.
    pub early_prior_scale: f64,
    /// Run the final stage from two starts in parallel — the staged result and the same pose
    /// with every fitted phenotype value at ½ — and keep the lower objective (default true).
    /// Weight, muscle and proportions are only weakly observable from keypoints (a change
    /// over their whole range moves the keypoints by ~1–3 mm beyond what the pose can
    /// absorb), so the staged path can end in a basin with the wrong body shape.
    pub phenotype_restart: bool,
    /// Polish a cold keypoint solve of [`crate::pipeline::ik_fit`] from 12 other phenotype
    /// starts (age ±0.2 × muscle × weight ∈ {0.2, 0.8}², the solved pose) and keep the lowest
    /// objective (default true; `IkSolver::solve` itself does not polish). Measured on 10
    /// held-out people from exact keypoints: mean vertex error 7.35 → 4.50 mm, worst person
    /// 18.9 → 6.3 mm; the cold fit 1.56× the time (151 → 236 ms median) (docs/design/rig-and-ik.md §4.4.2).
    pub phenotype_polish: bool,
    /// Levenberg–Marquardt iterations of each polish start before the best one is continued
    /// to convergence (default 6; the same accuracy as 10 or 40 on the held-out people).
    pub polish_screen_iterations: usize,
    /// Iteration cap of each of the first three stages (default 12).
    pub stage_iterations: usize,
    /// Iteration cap of the final stage (default 40, per start).
    pub max_iterations: usize,
    /// Stop a stage when an accepted step decreases `E` by less than `tolerance · E`
    /// (default 1e-9).
    pub tolerance: f64,
    /// Starting shape: its six fitted phenotype values and face units are the initial values;
    /// its other phenotype values (breasts, races) and local changes are kept fixed. `None`:
    /// the default shape (all phenotype values 0.5, no face units).
    pub initial_shape: Option<ShapeParams>,
    /// Warm start (sequences): start from this state (e.g. the previous frame's
    /// [`IkResult::state`]) and run only the final `all` stage, without the Kabsch
    /// initialisation, the early stages or the phenotype restart. `None` (default): cold.
    pub initial_state: Option<IkState>,
    /// Use the wide joint ranges of [`ik_wide_range`] (arm twists ±180°, shoulders, elbows,
    /// hips, knees and ankles beyond the sampler's ranges) instead of the sampler's (default
    /// false). A cold solve with wide ranges finds wrong minima more often (measured with the
    /// twists alone: held-out fits from exact keypoints 7.3 → 10.2 mm), so the pipeline uses
    /// them only as a continuation from a bounded solve that misses its keypoints
    /// ([`crate::pipeline::ik_fit`]).
    pub wide_ranges: bool,
    /// Let elbows and knees reach full extension (a straight limb and a few degrees beyond:
    /// [`ik_extension_limit`]) where the sampler's ranges stop 8° (elbow) and 10° (knee)
    /// short of straight (default false; it also lowers those bounds of the wide ranges).
    /// Warm-started frames of a sequence use it ([`crate::frame::Tracking::ik_config`]): a
    /// cold solve that needs a straight limb reaches it through the range continuation of
    /// [`crate::pipeline::ik_fit`], and the frames after it must not be held inside the
    /// sampler's range.
    pub full_extension: bool,
    /// The forearm's roll range (`lowerarm02.L/R` about its own axis): `±L` degrees with the
    /// prior scale `L`, instead of the sampler's ±30°
    /// ([`panoman_human::sampling::TWIST_LIMIT_DEG`], chosen for the training data, where the
    /// skinned forearm starts to collapse beyond it). A forearm rolls about ±90° (pronation
    /// and supination); marker solving uses `Some(90.0)`, where the wrist markers observe
    /// the roll (`panoman_mocap::solve::SolveOptions::forearm_roll_deg`). The wide ranges
    /// take precedence. `None` (default): the sampler's.
    pub forearm_roll_deg: Option<f64>,
}

impl Default for IkConfig {
    /// The defaults listed on the fields.
    fn default() -> Self {
        IkConfig {
            fit_phenotype: true,
            fit_face_units: None,
            pose_prior: 1e-6,
            temporal: None,
            phenotype_prior: 1e-5,
            face_unit_prior: 1e-7,
            early_prior_scale: 3.0,
            phenotype_restart: true,
            phenotype_polish: true,
            polish_screen_iterations: 6,
            stage_iterations: 12,
            max_iterations: 40,
            tolerance: 1e-9,
            initial_shape: None,
            initial_state: None,
            wide_ranges: false,
            full_extension: false,
            forearm_roll_deg: None,
        }
    }
}

/// [`IkConfig::temporal`]: the weights `λ_T,c` (m²) and the reference angles `θ⁰` (radians),
/// both per rig bone in the order of [`IkState::angles`] (e.g. the previous frame's angles).
#[derive(Clone, Debug, PartialEq)]
pub struct TemporalPrior {
    /// `λ_T,c` in m² (≥ 0) per rig bone.
    pub weights: Vec<f64>,
    /// `θ⁰` per rig bone.
    pub angles: Vec<[f64; 3]>,
}

/// The rig parameters the IK optimises.
///
/// Posed root: `W_0 = [R | h_0 + u]` (rotation about the root head `h_0`, then translation),
/// which [`IkSolver::params`] writes as `root_rotation_z_deg = z` and root Euler angles
/// `(x, y, 0)` for `R = Rz(z) Ry(y) Rx(x)`.
#[derive(Clone, Debug, PartialEq)]
pub struct IkState {
    /// Global rotation `R` (row-major).
    pub rotation: M3,
    /// Root translation `u` (metres).
    pub translation: V3,
    /// Euler angles `[x, y, z]` in **radians** per rig bone (rig order); entry 0 (root) is
    /// unused (the root's rotation is `rotation`).
    pub angles: Vec<[f64; 3]>,
    /// Phenotype values in [`IK_PHENOTYPE`] order.
    pub phenotype: [f64; 6],
    /// Face-unit values in [`FACE_UNITS`] order.
    pub face_units: [f64; 52],
}

impl IkState {
    /// Rest pose of `n_bones` bones, identity rotation, zero translation, the six phenotype
    /// values and face units of `shape`.
    pub fn rest(n_bones: usize, shape: &ShapeParams) -> IkState {
        IkState {
            rotation: IDENTITY,
            translation: [0.0; 3],
            angles: vec![[0.0; 3]; n_bones],
            phenotype: IK_PHENOTYPE.map(|n| shape.phenotype.get(n).unwrap_or(0.5)),
            face_units: shape.facial_actions,
        }
    }

    /// The state of generator parameters: `R = Rz(root_rotation_z)·E_root`, `u =
    /// root_translation`, bone angles in radians, phenotype and face units of the shape.
    pub fn from_params(params: &GeneratorParams, n_bones: usize) -> IkState {
        let mut s = IkState::rest(n_bones, &params.shape);
        let p = &params.pose;
        let root = p.euler_deg.first().copied().unwrap_or([0.0; 3]);
        s.rotation = matmul(
            &panoman_mesh::rotation::rot_z(p.root_rotation_z_deg.to_radians()),
            &panoman_mesh::rotation::euler_xyz_deg(root),
        );
        s.translation = p.root_translation;
        for (c, e) in p.euler_deg.iter().enumerate().skip(1).take(n_bones - 1) {
            s.angles[c] = e.map(f64::to_radians);
        }
        s
    }

    /// The state moved by `h` along one variable, with the solver's update rules: `u_i += h`;
    /// `R ← exp(h [e_i]ₓ) R`; `θ_c,a += h`; `β_i += h`; `f_j += h` (no clamping).
    pub fn perturbed(&self, var: IkVariable, h: f64) -> IkState {
        let mut s = self.clone();
        match var {
            IkVariable::Translation(i) => s.translation[i] += h,
            IkVariable::Rotation(i) => {
                let mut axis = [0.0; 3];
                axis[i] = 1.0;
                s.rotation = matmul(&axis_angle(axis, h), &s.rotation);
            }
            IkVariable::Angle { bone, axis } => s.angles[bone][axis] += h,
            IkVariable::Phenotype(i) => s.phenotype[i] += h,
            IkVariable::FaceUnit(j) => s.face_units[j] += h,
        }
        s
    }
}

/// One scalar parameter of [`IkState`] (for [`IkSolver::jacobian_column`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IkVariable {
    /// Component `i` of the root translation `u`.
    Translation(usize),
    /// World-axis increment `φ_i` of the global rotation (`R ← exp([φ]ₓ) R`).
    Rotation(usize),
    /// Euler angle `axis` (0 x, 1 y, 2 z; radians) of rig bone `bone` (≥ 1).
    Angle {
        /// Rig index of the bone.
        bone: usize,
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
    },
    /// Phenotype value `i` ([`IK_PHENOTYPE`]).
    Phenotype(usize),
    /// Face unit `j` ([`FACE_UNITS`]).
    FaceUnit(usize),
}

/// What one stage of the solve did.
#[derive(Clone, Debug, PartialEq)]
pub struct IkStageReport {
    /// `torso`, `body`, `hands_face` or `all`; `phenotype_polish` for the polish of
    /// [`crate::pipeline::ik_fit`] (its iterations are those of all 12 screened starts and of
    /// the continued one; `cost_after` is the kept result's).
    pub name: &'static str,
    /// Number of free variables.
    pub n_variables: usize,
    /// Number of targets (weight > 0) the stage fits.
    pub n_targets: usize,
    /// Number of point targets the stage fits ([`IkSolver::solve_with_points`]; 0 without).
    pub n_points: usize,
    /// Levenberg–Marquardt iterations (Jacobian evaluations; both starts of a restarted
    /// final stage counted).
    pub iterations: usize,
    /// Objective `E` (all targets, priors included) before the stage.
    pub cost_before: f64,
    /// Objective `E` after the stage.
    pub cost_after: f64,
    /// Wall time in seconds.
    pub seconds: f64,
}

/// Distance of one fitted keypoint to its target.
#[derive(Clone, Debug, PartialEq)]
pub struct IkResidual {
    /// TC-133 index.
    pub index: usize,
    /// Keypoint name.
    pub name: String,
    /// `|K_k − k̂_k|` in metres, `K_k` evaluated on the fitted posed mesh.
    pub distance: f64,
    /// The target's weight.
    pub weight: f64,
}

/// The outcome of [`IkSolver::solve`].
#[derive(Clone, Debug)]
pub struct IkResult {
    /// The fitted generator parameters (shape + pose): `panoman generate` with
    /// [`IkResult::to_json`] reproduces [`IkResult::posed`].
    pub params: GeneratorParams,
    /// The fitted state.
    pub state: IkState,
    /// Topology of the meshes.
    pub topology: OutputTopology,
    /// The posed mesh in [`IkResult::topology`] (metres).
    pub posed: Vec<V3>,
    /// The fitted identity's rest mesh (face units included) in [`IkResult::topology`].
    pub rest: Vec<V3>,
    /// All keypoints of the keypoint set evaluated on [`IkResult::posed`] (set order).
    pub keypoints: Vec<V3>,
    /// One residual per target, in target order.
    pub residuals: Vec<IkResidual>,
    /// Mean residual per group in mm (`KeypointGroup::ALL` order: body, feet, face, left
    /// hand, right hand), `None` for a group without targets.
    pub group_mean_mm: [Option<f64>; 5],
    /// Total Levenberg–Marquardt iterations (both starts of the final stage counted).
    pub iterations: usize,
    /// The stages in order (skipped stages are left out).
    pub stages: Vec<IkStageReport>,
    /// Final objective `E` (point terms included when point targets were given).
    pub cost: f64,
    /// Mean distance of the point targets with weight > 0 to their model points on
    /// [`IkResult::posed`] in mm (along the normal for point-to-plane targets); `None`
    /// without point targets.
    pub point_residual_mm: Option<f64>,
    /// Wall time of the whole solve in seconds (meshes included).
    pub seconds: f64,
}

impl IkResult {
    /// The parameters as JSON in the layout of [`GeneratorParams::to_json`].
    pub fn to_json(&self, bone_names: &[String]) -> serde_json::Value {
        self.params.to_json(bone_names)
    }

    /// Mean residual of a group in mm (`None` without targets in the group).
    pub fn group_mean(&self, group: KeypointGroup) -> Option<f64> {
        self.group_mean_mm[group.position()]
    }

    /// Mean residual over all targets in mm.
    pub fn mean_residual_mm(&self) -> f64 {
        let n = self.residuals.len().max(1) as f64;
        1e3 * self.residuals.iter().map(|r| r.distance).sum::<f64>() / n
    }
}
