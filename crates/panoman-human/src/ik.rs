//! Inverse kinematics of the LBS rig to TC-127 keypoints: the generator's parameters
//! (global rigid motion, local bone Euler angles, phenotype, face units) that best explain
//! a set of target keypoints.
//!
//! # Model
//! For parameters `p = (R, u, θ, β, f)` — global rotation `R ∈ SO(3)`, root translation `u`,
//! per-bone Euler angles `θ_c = (x, y, z)` (radians, `E_c = Rz(z)·Ry(y)·Rx(x)`), the six
//! phenotype values `β` (gender, age, muscle, weight, height, proportions) and the 52 face
//! units `f` — the generator ([`crate::generator`]) gives the posed vertices
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
//! joints (§6.3 of the asset notes, [`crate::rig::rest_frames`]).
//!
//! # Objective
//! `E(p) = Σ_k w_k |K_k(p) − k̂_k|² + λ_θ Σ_c Σ_a (θ_ca / s_ca)² + λ_β Σ_i (β_i − ½)²
//! + λ_f Σ_j f_j²` over the given targets `k̂_k` with weights `w_k ≥ 0` (metres), where
//! `s_ca = max(|lo|, |hi|)` of the sampler's range of that axis, subject to those ranges
//! ([`crate::sampling::bone_range`]; axes with an empty range stay 0), `β ∈ [0, 1]⁶` (age is
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

use std::sync::{Arc, Mutex};
use std::time::Instant;

use panoman_mesh::align::{axis_angle, rigid_align};
use panoman_mesh::geom::{IDENTITY, M3, V3, add, cross, dot, matmul, matvec, norm, scale, sub};
use rayon::prelude::*;

use crate::error::{HumanError, Result};
use crate::generator::Generator;
use crate::keypoints::{
    FACE_OFFSET, KeypointGroup, KeypointSet, KeypointsFile, LHAND_OFFSET, N_KEYPOINTS,
    RHAND_OFFSET, keypoint_index, keypoint_names,
};
use crate::outputs::{OutputTopology, TopologyMap};
use crate::params::{GeneratorParams, PoseParams, ShapeParams};
use crate::phenotype::FACE_UNITS;
use crate::rig::{self, Affine};
use crate::sampling::{LEFT_HAND_SLOT, N_POSABLE, bone_range, posable_bones};
use crate::skinning::SkinWeights;

/// The phenotype values the IK fits, in the order of [`IkState::phenotype`].
pub const IK_PHENOTYPE: [&str; 6] = ["gender", "age", "muscle", "weight", "height", "proportions"];

/// Number of face units (52, [`FACE_UNITS`]).
const N_UNITS: usize = FACE_UNITS.len();

/// Step of the finite differences through the rest frames.
const FRAME_STEP: f64 = 1e-6;

/// TC-127 indices of the torso keypoints: neck, body_center, shoulders, hips.
const TORSO_KEYPOINTS: [usize; 6] = [0, 2, 3, 6, 9, 12];

/// Bones of the `torso` stage.
const TORSO_BONES: [&str; 9] = [
    "spine05",
    "spine04",
    "spine03",
    "spine02",
    "spine01",
    "clavicle.L",
    "clavicle.R",
    "shoulder01.L",
    "shoulder01.R",
];

/// Hand keypoints used by the `body` stage (wrist, thumb CMC, the four MCPs).
const HAND_ROOTS: [usize; 6] = [0, 1, 5, 9, 13, 17];

/// Face keypoints used by the `body` stage (nose bridge, tip and base, eye corners, pupils).
const FACE_RIGID: [usize; 9] = [27, 30, 33, 36, 39, 42, 45, 68, 69];

// ---------------------------------------------------------------------------------------------
// Targets.

/// One target keypoint: TC-127 index, position `k̂` (metres) and weight `w ≥ 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkTarget {
    /// TC-127 index ([`keypoint_names`]).
    pub index: usize,
    /// Target position in metres (world frame).
    pub position: V3,
    /// Weight `w_k ≥ 0` of the squared residual.
    pub weight: f64,
}

/// A set of target keypoints (any subset of the TC-127 names, each at most once).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IkTargets {
    /// The targets (validated by [`IkTargets::validate`] before every solve).
    pub targets: Vec<IkTarget>,
}

fn check_target(t: &IkTarget) -> Result<()> {
    let name = keypoint_names()
        .get(t.index)
        .ok_or_else(|| {
            HumanError::Invalid(format!(
                "target keypoint index {} is out of range (0..{N_KEYPOINTS})",
                t.index
            ))
        })?
        .as_str();
    if !t.position.iter().all(|x| x.is_finite()) {
        return Err(HumanError::Invalid(format!(
            "target keypoint `{name}` has a non-finite position {:?}",
            t.position
        )));
    }
    if !t.weight.is_finite() || t.weight < 0.0 {
        return Err(HumanError::Invalid(format!(
            "target keypoint `{name}` has an invalid weight {} (must be finite and ≥ 0)",
            t.weight
        )));
    }
    Ok(())
}

impl IkTargets {
    /// No targets.
    pub fn new() -> IkTargets {
        IkTargets::default()
    }

    /// Sets (or replaces) the target of TC-127 keypoint `index`.
    ///
    /// # Errors
    /// [`HumanError::Invalid`]: index out of range, non-finite position, weight negative or
    /// non-finite.
    pub fn set(&mut self, index: usize, position: V3, weight: f64) -> Result<()> {
        let t = IkTarget {
            index,
            position,
            weight,
        };
        check_target(&t)?;
        match self.targets.iter_mut().find(|x| x.index == index) {
            Some(x) => *x = t,
            None => self.targets.push(t),
        }
        Ok(())
    }

    /// [`IkTargets::set`] by keypoint name.
    ///
    /// # Errors
    /// An unknown name, or the errors of [`IkTargets::set`].
    pub fn set_named(&mut self, name: &str, position: V3, weight: f64) -> Result<()> {
        let i = keypoint_index(name)
            .ok_or_else(|| HumanError::Invalid(format!("unknown keypoint `{name}`")))?;
        self.set(i, position, weight)
    }

    /// All 127 keypoints of `points` (TC-127 order), weight 1 each.
    ///
    /// # Errors
    /// Not 127 points, or a non-finite point.
    pub fn all(points: &[V3]) -> Result<IkTargets> {
        if points.len() != N_KEYPOINTS {
            return Err(HumanError::Invalid(format!(
                "expected {N_KEYPOINTS} keypoints, got {}",
                points.len()
            )));
        }
        let mut t = IkTargets::new();
        for (i, &p) in points.iter().enumerate() {
            t.set(i, p, 1.0)?;
        }
        Ok(t)
    }

    /// The targets of a keypoints file ([`KeypointsFile`]: positions and weights).
    ///
    /// # Errors
    /// As [`IkTargets::set`].
    pub fn from_file(file: &KeypointsFile) -> Result<IkTargets> {
        let mut t = IkTargets::new();
        for (&i, &p) in &file.points {
            t.set(i, p, file.weight(i))?;
        }
        Ok(t)
    }

    /// The targets of the given groups only.
    pub fn only(&self, groups: &[KeypointGroup]) -> IkTargets {
        IkTargets {
            targets: self
                .targets
                .iter()
                .filter(|t| t.index < N_KEYPOINTS && groups.contains(&KeypointGroup::of(t.index)))
                .copied()
                .collect(),
        }
    }

    /// Number of targets.
    pub fn len(&self) -> usize {
        self.targets.len()
    }

    /// True when there are no targets.
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// Checks the set: not empty, every target valid (see [`IkTargets::set`]), no index twice,
    /// positive total weight.
    ///
    /// # Errors
    /// [`HumanError::Invalid`] with one line.
    pub fn validate(&self) -> Result<()> {
        if self.targets.is_empty() {
            return Err(HumanError::Invalid("no target keypoints given".into()));
        }
        let mut seen = [false; N_KEYPOINTS];
        let mut total = 0.0;
        for t in &self.targets {
            check_target(t)?;
            if std::mem::replace(&mut seen[t.index], true) {
                return Err(HumanError::Invalid(format!(
                    "target keypoint `{}` is given twice",
                    keypoint_names()[t.index]
                )));
            }
            total += t.weight;
        }
        if total <= 0.0 {
            return Err(HumanError::Invalid(
                "every target keypoint has weight 0".into(),
            ));
        }
        Ok(())
    }
}

/// An extra surface point target of [`IkSolver::solve_with_points`]: a fixed linear
/// combination `P(p) = Σ_m b_m x_m(p)` of vertices `m` of the solver's topology (e.g. the
/// barycentric weights of a triangle, or one vertex with coefficient 1), a target position
/// `p̂` (metres) and a weight `w ≥ 0` in the units of the keypoint weights.
///
/// Residual: point-to-point `√w (P − p̂)`, or, with a `normal` `n̂` (any non-zero length;
/// normalised), point-to-plane `√w n̂ᵀ(P − p̂)`, which lets the point slide along the
/// target's tangent plane (the usual ICP linearisation of a distance to a surface).
#[derive(Clone, Debug, PartialEq)]
pub struct PointTarget {
    /// `(vertex of the solver's topology, b_m)` pairs.
    pub rows: Vec<(u32, f64)>,
    /// Target position `p̂` in metres (world frame).
    pub position: V3,
    /// Weight `w ≥ 0` of the squared residual (same units as [`IkTarget::weight`]).
    pub weight: f64,
    /// Normal `n̂` of a point-to-plane residual; `None`: point-to-point.
    pub normal: Option<V3>,
}

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
}

impl Default for IkConfig {
    /// The defaults listed on the fields.
    fn default() -> Self {
        IkConfig {
            fit_phenotype: true,
            fit_face_units: None,
            pose_prior: 1e-6,
            phenotype_prior: 1e-5,
            face_unit_prior: 1e-7,
            early_prior_scale: 3.0,
            phenotype_restart: true,
            stage_iterations: 12,
            max_iterations: 40,
            tolerance: 1e-9,
            initial_shape: None,
            initial_state: None,
        }
    }
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
            &rig::rot_z(p.root_rotation_z_deg.to_radians()),
            &rig::euler_xyz_deg(root),
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
    /// `torso`, `body`, `hands_face` or `all`.
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
    /// TC-127 index.
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
    /// Mean residual per group in mm (`KeypointGroup::ALL` order: body, face, left hand,
    /// right hand), `None` for a group without targets.
    pub group_mean_mm: [Option<f64>; 4],
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
        let i = KeypointGroup::ALL.iter().position(|g| *g == group)?;
        self.group_mean_mm[i]
    }

    /// Mean residual over all targets in mm.
    pub fn mean_residual_mm(&self) -> f64 {
        let n = self.residuals.len().max(1) as f64;
        1e3 * self.residuals.iter().map(|r| r.distance).sum::<f64>() / n
    }
}

// ---------------------------------------------------------------------------------------------
// The solver's precomputed model.

/// A (keypoint, bone) term `M_b X_kb + σ_kb t_b`.
#[derive(Clone, Debug)]
struct Pair {
    bone: usize,
    sigma: f64,
    /// `(relevant vertex, a_kv w_vb)` entries in `coef`.
    coef: std::ops::Range<usize>,
    /// Positions in the keypoint's ancestor list of `b` and its ancestors, in `anc_pos`.
    anc: std::ops::Range<usize>,
    /// `(unit, X^{(j)}_kb)` entries in `unit_x`.
    units: std::ops::Range<usize>,
}

/// One row of a [`Skinned`] model (a keypoint of the set, or a point target).
#[derive(Clone, Debug)]
struct KpModel {
    /// TC-127 index of the name, if it is one.
    tc: Option<usize>,
    pairs: std::ops::Range<usize>,
    /// `A_k`: every bone skinning a vertex of the keypoint and its ancestors, ascending.
    anc: Vec<usize>,
    /// `S_kc` for `c ∈ A_k`.
    anc_sigma: Vec<f64>,
}

/// Skinned linear rows `Σ_a c_a x_a` over Anny output vertices (the keypoints of the set, or
/// the point targets of one [`IkSolver::solve_with_points`] call), collapsed per skinning
/// bone into pairs (module docs). `coef` indexes a list of relevant vertices owned by whoever
/// supplies the rest positions.
#[derive(Clone, Debug, Default)]
struct Skinned {
    rows: Vec<KpModel>,
    pairs: Vec<Pair>,
    coef: Vec<(u32, f64)>,
    anc_pos: Vec<u32>,
    unit_x: Vec<(u8, V3)>,
}

/// One row of a [`Skinned`] model before concatenation (ranges relative to its own lists).
struct RowPart {
    pairs: Vec<Pair>,
    coef: Vec<(u32, f64)>,
    anc_pos: Vec<u32>,
    unit_x: Vec<(u8, V3)>,
    anc: Vec<usize>,
    anc_sigma: Vec<f64>,
}

impl Skinned {
    /// Appends a row, shifting its ranges.
    fn push(&mut self, tc: Option<usize>, part: RowPart) {
        let first = self.pairs.len();
        let (c0, a0, u0) = (self.coef.len(), self.anc_pos.len(), self.unit_x.len());
        let shift = |r: &std::ops::Range<usize>, o: usize| r.start + o..r.end + o;
        self.pairs.extend(part.pairs.into_iter().map(|p| Pair {
            bone: p.bone,
            sigma: p.sigma,
            coef: shift(&p.coef, c0),
            anc: shift(&p.anc, a0),
            units: shift(&p.units, u0),
        }));
        self.coef.extend(part.coef);
        self.anc_pos.extend(part.anc_pos);
        self.unit_x.extend(part.unit_x);
        self.rows.push(KpModel {
            tc,
            pairs: first..self.pairs.len(),
            anc: part.anc,
            anc_sigma: part.anc_sigma,
        });
    }
}

/// The face-unit terms `(j, X^{(j)}_b)` of a pair from its coefficient list.
type UnitTerms<'f> = &'f dyn Fn(&[(u32, f64)]) -> Vec<(u8, V3)>;

/// The skinned model of one row `Σ_a c_a x_a` over Anny output vertices `a`: per skinning
/// bone `b` the pair `σ_b = Σ_a c_a w_ab` with coefficients `(rel(a), c_a w_ab)`, the
/// ancestor set `A` (every skinning bone and its ancestors) with `S_c`, and per pair the
/// face-unit terms `X^{(j)}_b` given by `units` from the pair's coefficient list.
fn skinned_row(
    row: &[(u32, f64)],
    rel_of_anny: &dyn Fn(u32) -> u32,
    skin: &SkinWeights,
    parents: &[Option<usize>],
    units: UnitTerms<'_>,
) -> RowPart {
    let n_bones = parents.len();
    let mut per_bone: std::collections::BTreeMap<usize, Vec<(u32, f64)>> =
        std::collections::BTreeMap::new();
    for &(a, w) in row {
        let r = rel_of_anny(a);
        let (s, e) = (
            skin.offsets[a as usize] as usize,
            skin.offsets[a as usize + 1] as usize,
        );
        for i in s..e {
            per_bone
                .entry(skin.bones[i] as usize)
                .or_default()
                .push((r, w * skin.weights[i]));
        }
    }
    let mut in_anc = vec![false; n_bones];
    for &b in per_bone.keys() {
        let mut c = Some(b);
        while let Some(x) = c {
            if in_anc[x] {
                break;
            }
            in_anc[x] = true;
            c = parents[x];
        }
    }
    let anc: Vec<usize> = (0..n_bones).filter(|&c| in_anc[c]).collect();
    let mut part = RowPart {
        pairs: Vec::with_capacity(per_bone.len()),
        coef: Vec::new(),
        anc_pos: Vec::new(),
        unit_x: Vec::new(),
        anc_sigma: vec![0.0; anc.len()],
        anc,
    };
    for (&b, list) in &per_bone {
        let sigma: f64 = list.iter().map(|e| e.1).sum();
        let c0 = part.coef.len();
        part.coef.extend_from_slice(list);
        let a0 = part.anc_pos.len();
        let mut c = Some(b);
        while let Some(x) = c {
            let p = part.anc.binary_search(&x).expect("ancestor");
            part.anc_pos.push(p as u32);
            part.anc_sigma[p] += sigma;
            c = parents[x];
        }
        let u0 = part.unit_x.len();
        part.unit_x.extend(units(list));
        part.pairs.push(Pair {
            bone: b,
            sigma,
            coef: c0..part.coef.len(),
            anc: a0..part.anc_pos.len(),
            units: u0..part.unit_x.len(),
        });
    }
    part
}

/// A row over vertices of `topology` composed with the topology map onto Anny output
/// vertices (duplicates merged, ascending).
fn anny_row(map: &TopologyMap, topology: OutputTopology, row: &[(u32, f64)]) -> Vec<(u32, f64)> {
    let mut r: Vec<(u32, f64)> = Vec::new();
    for &(v, w) in row {
        match topology {
            OutputTopology::Anny => r.push((v, w)),
            OutputTopology::Full => r.push((map.full_from_anny()[v as usize], w)),
            OutputTopology::Small => {
                let b = &map.small_binding()[v as usize];
                for i in 0..3 {
                    r.push((b.tri[i], w * b.bary[i]));
                }
            }
        }
    }
    r.sort_by_key(|e| e.0);
    let mut merged: Vec<(u32, f64)> = Vec::with_capacity(r.len());
    for (v, w) in r {
        match merged.last_mut() {
            Some(last) if last.0 == v => last.1 += w,
            _ => merged.push((v, w)),
        }
    }
    merged
}

/// A posable bone: rig index and range in radians.
#[derive(Clone, Debug)]
struct Posable {
    rig: usize,
    slot: usize,
    range: [[f64; 2]; 3],
    /// Per axis `1/s²` with `s = max(|lo|, |hi|)` of the range (0 for an empty range): the
    /// prior measures each angle against the largest angle its range allows.
    prior: [f64; 3],
}

/// Rest-shape quantities of one `(β, f)`.
#[derive(Clone, Debug)]
struct ShapeEval {
    heads: Vec<V3>,
    local: Vec<Affine>,
    inv_rest: Vec<Affine>,
    /// `X_kb` per pair.
    x: Vec<V3>,
    tails: Vec<V3>,
}

/// Forward kinematics of one state.
#[derive(Clone, Debug, Default)]
struct Kin {
    world: Vec<Affine>,
    /// Rotation of `W_parent P_parent⁻¹ P_c` (the frame before the bone's delta).
    pre: Vec<M3>,
    skin: Vec<Affine>,
}

/// Everything evaluated at one state.
#[derive(Clone, Debug)]
struct Current {
    state: IkState,
    shape: Arc<ShapeEval>,
    kin: Kin,
    /// Keypoints per set row.
    k: Vec<V3>,
    /// The point targets' part, when the evaluation had a point model.
    pts: Option<PtEval>,
}

/// Point targets evaluated at one state.
#[derive(Clone, Debug)]
struct PtEval {
    /// `X_pb` per pair of the point model at the state's `(β, f)`.
    x: Arc<Vec<V3>>,
    /// `Σ_m b_m x_m` per point target.
    p: Vec<V3>,
}

/// What an evaluation needs besides the state: the phenotype grid of the keypoints and,
/// when point targets are fitted, their model.
#[derive(Clone, Copy)]
struct Ctx<'c> {
    grid: &'c PhenGrid,
    pts: Option<&'c PointModel>,
}

impl<'c> Ctx<'c> {
    fn new(grid: &'c PhenGrid, pts: Option<&'c PointModel>) -> Ctx<'c> {
        Ctx { grid, pts }
    }
}

/// `Z_b = M_b X_b + σ_b t_b` of pair `i` of `sk`, `X_b = x[i]`.
#[inline]
fn pair_term(sk: &Skinned, i: usize, x: &[V3], kin: &Kin) -> V3 {
    let p = &sk.pairs[i];
    let t = &kin.skin[p.bone];
    add(matvec(&t.m, x[i]), scale(t.t, p.sigma))
}

/// The rows of `sk`, `Σ_b Z_b`, for pair rest quantities `x`.
fn rows_into(sk: &Skinned, x: &[V3], kin: &Kin, out: &mut Vec<V3>) {
    out.clear();
    out.extend(sk.rows.iter().map(|k| {
        let mut s = [0.0; 3];
        for i in k.pairs.clone() {
            s = add(s, pair_term(sk, i, x, kin));
        }
        s
    }));
}

/// `X_b = Σ_v c_v x̄_v` of every pair of `sk` for rest positions `rest` (its relevant
/// vertices).
fn pair_sums(sk: &Skinned, rest: &[V3]) -> Vec<V3> {
    sk.pairs
        .iter()
        .map(|p| {
            let mut x = [0.0; 3];
            for &(r, w) in &sk.coef[p.coef.clone()] {
                let q = rest[r as usize];
                x = [x[0] + w * q[0], x[1] + w * q[1], x[2] + w * q[2]];
            }
            x
        })
        .collect()
}

/// Adds the face units' terms `Σ_j f_j X^{(j)}_b` to the pair quantities `x`.
fn add_unit_terms(sk: &Skinned, units: &[f64; 52], x: &mut [V3]) {
    for (p, xp) in sk.pairs.iter().zip(x.iter_mut()) {
        for &(j, d) in &sk.unit_x[p.units.clone()] {
            let f = units[j as usize];
            if f != 0.0 {
                *xp = add(*xp, scale(d, f));
            }
        }
    }
}

/// Adds one residual row `w (J r)`, `w JᵀJ` (lower triangle) to `g`, `h` (`n × n`).
fn accumulate_row(jr: &[(usize, V3)], res: V3, w: f64, n: usize, h: &mut [f64], g: &mut [f64]) {
    for (a, &(i, di)) in jr.iter().enumerate() {
        let wdi = scale(di, w);
        g[i] += dot(wdi, res);
        for &(j, dj) in &jr[..=a] {
            let (hi, lo) = if i >= j { (i, j) } else { (j, i) };
            h[hi * n + lo] += dot(wdi, dj);
        }
    }
}

/// Adds one scalar residual row (`jr` in the first components) to `g`, `h`.
fn accumulate_scalar_row(
    jr: &[(usize, V3)],
    res: f64,
    w: f64,
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
) {
    for (a, &(i, di)) in jr.iter().enumerate() {
        let wdi = w * di[0];
        g[i] += wdi * res;
        for &(j, dj) in &jr[..=a] {
            let (hi, lo) = if i >= j { (i, j) } else { (j, i) };
            h[hi * n + lo] += wdi * dj[0];
        }
    }
}

/// Adds the point rows to `h`, `g` (point-to-plane rows hold the scalars `n̂ᵀ∂` in the first
/// components, see [`IkSolver::jacobian`]): in four fixed chunks in parallel, summed in chunk
/// order (deterministic), for more than 512 points.
fn accumulate_points(
    m: &PointModel,
    pe: &PtEval,
    jac: &[Vec<(usize, V3)>],
    n: usize,
    h: &mut [f64],
    g: &mut [f64],
) {
    let run = |range: std::ops::Range<usize>, h: &mut [f64], g: &mut [f64]| {
        for p in range {
            let r = &m.rows[p];
            if r.weight > 0.0 {
                let d = sub(pe.p[p], r.target);
                match r.normal {
                    Some(nn) => accumulate_scalar_row(&jac[p], dot(nn, d), r.weight, n, h, g),
                    None => accumulate_row(&jac[p], d, r.weight, n, h, g),
                }
            }
        }
    };
    let np = jac.len();
    if np <= 512 {
        run(0..np, h, g);
        return;
    }
    const CHUNKS: usize = 4;
    let parts: Vec<(Vec<f64>, Vec<f64>)> = (0..CHUNKS)
        .into_par_iter()
        .map(|c| {
            let mut hc = vec![0.0; n * n];
            let mut gc = vec![0.0; n];
            run(c * np / CHUNKS..(c + 1) * np / CHUNKS, &mut hc, &mut gc);
            (hc, gc)
        })
        .collect();
    for (hc, gc) in parts {
        h.iter_mut().zip(&hc).for_each(|(a, b)| *a += b);
        g.iter_mut().zip(&gc).for_each(|(a, b)| *a += b);
    }
}

/// Phenotype derivative of the rest quantities (one column).
#[derive(Clone, Debug)]
struct PhenColumn {
    /// `∂X_kb/∂β_i` per pair.
    x: Vec<V3>,
    heads: Vec<V3>,
    tails: Vec<V3>,
}

/// Anchors of the phenotype hat functions within `[0, 1]` ([`crate::phenotype`]): gender,
/// height, proportions `{0, 1}`; age `{0, 1/3, 2/3, 1}`; muscle, weight `{0, ½, 1}`. Every
/// phenotype coefficient is a product of hat weights of distinct features, so the rest mesh
/// is multilinear in `β` inside each cell of this grid (2 × 4 × 3 × 3 × 2 × 2 = 288 points)
/// and has kinks on the interior anchors.
const PHEN_AXES: [&[f64]; 6] = [
    &[0.0, 1.0],
    &[0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0],
    &[0.0, 0.5, 1.0],
    &[0.0, 0.5, 1.0],
    &[0.0, 1.0],
    &[0.0, 1.0],
];

/// The rest quantities `[X_kb (pairs) | heads | tails]` at every phenotype grid point
/// ([`PHEN_AXES`], row-major, last axis fastest), for one set of non-fitted shape values.
#[derive(Debug)]
struct PhenGrid {
    points: Vec<Vec<V3>>,
}

impl PhenGrid {
    /// Row-major strides of the grid axes.
    fn strides() -> [usize; 6] {
        let mut st = [1usize; 6];
        for d in (0..5).rev() {
            st[d] = st[d + 1] * PHEN_AXES[d + 1].len();
        }
        st
    }

    /// Multilinear interpolation of the grid at `beta` (its derivative along axis `deriv`
    /// when given). On an interior anchor, `side[d] < 0` takes the cell below, else the cell
    /// above (the value is the same; the derivative along `d` is one-sided).
    ///
    /// In the cell `[a_k, a_{k+1}]` of axis `d` with `t_d = (β_d − a_k)/(a_{k+1} − a_k)`:
    /// `f(β) = Σ_{corners c} Π_d ℓ_d(c_d) f(c)`, `ℓ_d = t_d` (upper) or `1 − t_d` (lower); the
    /// derivative replaces the factor of `deriv` by `±1/(a_{k+1} − a_k)`.
    fn interp(&self, beta: &[f64; 6], side: &[i8; 6], deriv: Option<usize>) -> Vec<V3> {
        let len = self.points[0].len();
        let mut out = vec![[0.0; 3]; len];
        for (idx, w) in corner_weights(beta, side, deriv) {
            for (o, p) in out.iter_mut().zip(&self.points[idx]) {
                o[0] += w * p[0];
                o[1] += w * p[1];
                o[2] += w * p[2];
            }
        }
        out
    }
}

/// Number of phenotype grid points (2 × 4 × 3 × 3 × 2 × 2).
const N_GRID: usize = 288;

/// The non-zero corner weights `(grid index, weight)` of the multilinear interpolation at
/// `beta` (of its derivative along `deriv`), see [`PhenGrid::interp`].
fn corner_weights(beta: &[f64; 6], side: &[i8; 6], deriv: Option<usize>) -> Vec<(usize, f64)> {
    let strides = PhenGrid::strides();
    let mut lo = [0usize; 6];
    let mut f = [[0.0f64; 2]; 6];
    for d in 0..6 {
        let a = PHEN_AXES[d];
        let b = beta[d].clamp(a[0], a[a.len() - 1]);
        let mut k = (0..a.len() - 1).rfind(|&k| a[k] <= b).unwrap_or(0);
        if k > 0 && b == a[k] && side[d] < 0 {
            k -= 1;
        }
        let w = a[k + 1] - a[k];
        let t = (b - a[k]) / w;
        lo[d] = k;
        f[d] = if deriv == Some(d) {
            [-1.0 / w, 1.0 / w]
        } else {
            [1.0 - t, t]
        };
    }
    let mut out = Vec::with_capacity(64);
    for corner in 0..64usize {
        let mut w = 1.0;
        let mut idx = 0;
        for d in 0..6 {
            let bit = (corner >> (5 - d)) & 1;
            w *= f[d][bit];
            idx += (lo[d] + bit) * strides[d];
        }
        if w != 0.0 {
            out.push((idx, w));
        }
    }
    out
}

/// Surface data of the point targets, per solver (built on first use): the Anny output
/// vertices a row of the solver's topology can reach ("slots"), their kept indices, and the
/// face units' displacements `B_j` at them (CSR per slot, units ascending).
#[derive(Debug)]
struct Surface {
    slot_of_anny: Vec<u32>,
    kept_of_slot: Vec<u32>,
    unit_off: Vec<u32>,
    unit_val: Vec<(u8, V3)>,
}

/// Rest positions of every slot at every phenotype grid point ([`PHEN_AXES`]), laid out
/// `[slot][grid point]`, for one set of non-fitted shape values (face units 0).
#[derive(Debug)]
struct VertexGrid {
    data: Vec<V3>,
}

impl VertexGrid {
    /// [`VertexGrid::interp`] for several weight sets in one pass over the vertices (the
    /// grid reads dominate): one list per set.
    fn interp_many(&self, verts: &[u32], sets: &[Vec<(usize, f64)>]) -> Vec<Vec<V3>> {
        let k = sets.len();
        let one = |v: &u32, out: &mut [V3]| {
            let block = &self.data[*v as usize * N_GRID..(*v as usize + 1) * N_GRID];
            for (o, w) in out.iter_mut().zip(sets) {
                let mut acc = [0.0; 3];
                for &(g, c) in w {
                    let p = block[g];
                    acc[0] += c * p[0];
                    acc[1] += c * p[1];
                    acc[2] += c * p[2];
                }
                *o = acc;
            }
        };
        let mut flat = vec![[0.0; 3]; verts.len() * k];
        if k > 0 {
            if verts.len() >= 1024 {
                flat.par_chunks_mut(k * 256)
                    .zip(verts.par_chunks(256))
                    .for_each(|(out, vs)| {
                        for (o, v) in out.chunks_mut(k).zip(vs) {
                            one(v, o);
                        }
                    });
            } else {
                for (o, v) in flat.chunks_mut(k).zip(verts) {
                    one(v, o);
                }
            }
        }
        (0..k)
            .map(|j| flat.iter().skip(j).step_by(k).copied().collect())
            .collect()
    }

    /// `Σ_c w_c x̄_v(c)` for the slots `verts` and corner weights `w` (see
    /// [`corner_weights`]).
    fn interp(&self, verts: &[u32], w: &[(usize, f64)]) -> Vec<V3> {
        let one = |v: &u32| -> V3 {
            let block = &self.data[*v as usize * N_GRID..(*v as usize + 1) * N_GRID];
            let mut o = [0.0; 3];
            for &(g, c) in w {
                let p = block[g];
                o[0] += c * p[0];
                o[1] += c * p[1];
                o[2] += c * p[2];
            }
            o
        };
        if verts.len() >= 2048 {
            verts.par_iter().with_min_len(512).map(one).collect()
        } else {
            verts.iter().map(one).collect()
        }
    }
}

/// One point target in solver terms.
#[derive(Clone, Copy, Debug)]
struct PtRow {
    target: V3,
    weight: f64,
    /// Unit normal (point-to-plane), or `None` (point-to-point).
    normal: Option<V3>,
}

impl PtRow {
    /// `P v`: the projection `n̂ n̂ᵀ v` on the normal, or `v`.
    #[inline]
    fn proj(&self, v: V3) -> V3 {
        match self.normal {
            Some(n) => scale(n, dot(n, v)),
            None => v,
        }
    }
}

/// The skinned model of a list of point targets (see [`IkSolver::solve_with_points`]).
#[derive(Debug)]
struct PointModel {
    /// Rows in target order; `coef` indexes `verts`.
    sk: Skinned,
    /// Slots of the relevant vertices.
    verts: Vec<u32>,
    rows: Vec<PtRow>,
    grid: Arc<VertexGrid>,
}

impl PointModel {
    /// `X_pb` of every pair at `(β, f)`: the vertex grid interpolated at `β`, summed per
    /// pair, plus `Σ_j f_j X^{(j)}_pb`.
    fn shape_x(&self, beta: &[f64; 6], units: &[f64; 52]) -> Vec<V3> {
        let w = corner_weights(beta, &[1; 6], None);
        let mut x = pair_sums(&self.sk, &self.grid.interp(&self.verts, &w));
        add_unit_terms(&self.sk, units, &mut x);
        x
    }

    /// `∂X_pb/∂β_i` of every pair for each request `(i, side)` (one-sided on a kink,
    /// `side < 0` the cell below), in one pass over the grid.
    fn dx(&self, beta: &[f64; 6], requests: &[(usize, i8)]) -> Vec<Vec<V3>> {
        let sets: Vec<Vec<(usize, f64)>> = requests
            .iter()
            .map(|&(i, side)| {
                let mut sides = [1i8; 6];
                sides[i] = side;
                corner_weights(beta, &sides, Some(i))
            })
            .collect();
        self.grid
            .interp_many(&self.verts, &sets)
            .iter()
            .map(|xv| pair_sums(&self.sk, xv))
            .collect()
    }

    /// The point positions for pair quantities `x` and kinematics `kin`.
    fn eval(&self, x: Arc<Vec<V3>>, kin: &Kin) -> PtEval {
        let mut p = Vec::with_capacity(self.rows.len());
        rows_into(&self.sk, &x, kin, &mut p);
        PtEval { x, p }
    }
}

/// `template` with its face units zeroed and the six fitted phenotype values at grid point
/// `idx` ([`PHEN_AXES`], row-major).
fn grid_shape(template: &ShapeParams, idx: usize) -> ShapeParams {
    let strides = PhenGrid::strides();
    let mut s = template.clone();
    s.facial_actions = [0.0; 52];
    for d in 0..6 {
        let k = (idx / strides[d]) % PHEN_AXES[d].len();
        if let Some(slot) = s.phenotype.get_mut(IK_PHENOTYPE[d]) {
            *slot = PHEN_AXES[d][k];
        }
    }
    s
}

/// The grid cell `[a_k, a_{k+1}]` of phenotype value `i` at `b`; on an interior anchor the
/// cell below for `side < 0`, else the cell above.
fn phen_cell(i: usize, b: f64, side: i8) -> (f64, f64) {
    let a = PHEN_AXES[i];
    let mut k = (0..a.len() - 1).rfind(|&k| a[k] <= b).unwrap_or(0);
    if k > 0 && b == a[k] && side < 0 {
        k -= 1;
    }
    (a[k], a[k + 1])
}

/// True if phenotype value `i` sits on an interior anchor of its axis (a kink).
fn on_kink(i: usize, b: f64) -> bool {
    let a = PHEN_AXES[i];
    a[1..a.len() - 1].contains(&b)
}

/// The Jacobian of one iteration (see [`IkSolver::jacobian`]).
struct Jacobian {
    /// Per target row, `(column, ∂K/∂var)`.
    rows: Vec<Vec<(usize, V3)>>,
    /// Per point target, `(column, ∂(Σ b x)/∂var)`, for point-to-plane targets `n̂ᵀ∂` in the
    /// first component (empty without points).
    pts: Vec<Vec<(usize, V3)>>,
    /// Columns held this iteration (phenotype values at a kink minimum).
    held: Vec<usize>,
    /// Per phenotype value, the side of its kink the derivative was taken on.
    sides: [i8; 6],
}

/// A target in solver terms.
#[derive(Clone, Copy, Debug)]
struct Row {
    row: usize,
    target: V3,
    weight: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Var {
    Trans(usize),
    Rot(usize),
    Angle {
        bone: usize,
        axis: usize,
        lo: f64,
        hi: f64,
        /// Prior factor `1/s²` (see [`Posable::prior`]).
        prior: f64,
    },
    Phen(usize),
    Unit(usize),
}

/// The free variables of a stage with their column indices.
#[derive(Clone, Debug)]
struct VarSet {
    vars: Vec<Var>,
    trans: [Option<usize>; 3],
    rot: [Option<usize>; 3],
    bone: Vec<[Option<usize>; 3]>,
    phen: [Option<usize>; 6],
    unit: [Option<usize>; 52],
}

impl VarSet {
    fn new(n_bones: usize) -> VarSet {
        VarSet {
            vars: Vec::new(),
            trans: [None; 3],
            rot: [None; 3],
            bone: vec![[None; 3]; n_bones],
            phen: [None; 6],
            unit: [None; 52],
        }
    }

    fn push(&mut self, v: Var) {
        let i = self.vars.len();
        match v {
            Var::Trans(a) => self.trans[a] = Some(i),
            Var::Rot(a) => self.rot[a] = Some(i),
            Var::Angle { bone, axis, .. } => self.bone[bone][axis] = Some(i),
            Var::Phen(a) => self.phen[a] = Some(i),
            Var::Unit(a) => self.unit[a] = Some(i),
        }
        self.vars.push(v);
    }
}

/// Inverse kinematics of the generator's LBS rig to the keypoints of one topology (module
/// docs). Built once per generator, topology and keypoint set; [`IkSolver::solve`] can then be
/// called any number of times (also from several threads).
pub struct IkSolver {
    generator: Arc<Generator>,
    map: Arc<TopologyMap>,
    topology: OutputTopology,
    set: KeypointSet,
    row_of_tc: Vec<Option<usize>>,
    parents: Vec<Option<usize>>,
    /// Relevant vertices: rest positions needed (keypoint vertices and joint regressors), as
    /// kept-vertex indices of the generator.
    rel_kept: Vec<u32>,
    head_rel: Vec<Vec<u32>>,
    tail_rel: Vec<Vec<u32>>,
    /// The keypoint rows (`coef` indexes `rel_kept`).
    kp: Skinned,
    /// Per unit: `(bone, Δhead, Δtail)` per unit value.
    unit_joints: Vec<Vec<(usize, V3, V3)>>,
    /// Units whose joint motion changes the frame of a posable bone or the root.
    frame_units: Vec<usize>,
    posable: Vec<Posable>,
    /// Phenotype grids per set of non-fitted shape values (see [`IkSolver::grid`]).
    grids: Mutex<Vec<(String, Arc<PhenGrid>)>>,
    /// Surface data of point targets (see [`IkSolver::surface`]), built on first use.
    surface: Mutex<Option<Arc<Surface>>>,
    /// Per-vertex phenotype grids of point targets (see [`IkSolver::vertex_grid`]).
    vertex_grids: Mutex<Vec<(String, Arc<VertexGrid>)>>,
    setup_seconds: f64,
}

fn rel_mean(idx: &[u32], pos: &[V3]) -> V3 {
    let mut s = [0.0; 3];
    for &k in idx {
        let p = pos[k as usize];
        s = [s[0] + p[0], s[1] + p[1], s[2] + p[2]];
    }
    let n = idx.len() as f64;
    [s[0] / n, s[1] / n, s[2] / n]
}

/// `Rz(z)·Ry(y)·Rx(x)` of radians (identity for zero angles).
fn euler_rad(e: [f64; 3]) -> M3 {
    if e == [0.0; 3] {
        IDENTITY
    } else {
        matmul(
            &rig::rot_z(e[2]),
            &matmul(&rig::rot_y(e[1]), &rig::rot_x(e[0])),
        )
    }
}

impl IkSolver {
    /// Precomputes the keypoint model of `keypoints` (a set on `topology`, e.g.
    /// [`crate::keypoints::KeypointDefinitions::set`]): the keypoint rows composed with the
    /// topology map onto Anny's output vertices, their skinning bones `σ_kb` and coefficient
    /// lists, the ancestor sets `A_k` with `S_kc`, the face units' `X^{(j)}_kb` and joint
    /// displacements (53 rest meshes of the generator), and the phenotype grid of the default
    /// shape (288 rest meshes), all in parallel. About 40–80 ms on 2 cores.
    ///
    /// # Errors
    /// [`HumanError::Invalid`]: the set is invalid or not on `topology`; generator errors.
    pub fn new(
        generator: Arc<Generator>,
        map: Arc<TopologyMap>,
        topology: OutputTopology,
        keypoints: &KeypointSet,
    ) -> Result<IkSolver> {
        let t0 = Instant::now();
        keypoints
            .validate()
            .map_err(|e| HumanError::Invalid(format!("keypoint set: {e}")))?;
        if keypoints.n_vertices != map.n_vertices(topology) {
            return Err(HumanError::Invalid(format!(
                "the keypoint set has {} vertices, topology `{topology}` has {}",
                keypoints.n_vertices,
                map.n_vertices(topology)
            )));
        }
        let rig = generator.rig();
        let n_bones = rig.len();
        let parents: Vec<Option<usize>> = generator.bone_parents().to_vec();
        if parents.first() != Some(&None) || parents.iter().skip(1).any(Option::is_none) {
            return Err(HumanError::Invalid(
                "the rig must have bone 0 as its only root".into(),
            ));
        }

        // Keypoint rows on anny (output) vertices.
        let anny_rows: Vec<Vec<(u32, f64)>> = keypoints
            .rows
            .iter()
            .map(|row| anny_row(&map, topology, row))
            .collect();

        // Relevant kept vertices.
        let kob = generator.kept_of_base();
        let out_base = generator.output_vertices();
        let n_kept = generator.kept_vertices().len();
        let mut rel_of_kept = vec![u32::MAX; n_kept];
        let mut rel_kept: Vec<u32> = Vec::new();
        let mut rel = |kept: u32| -> u32 {
            let slot = &mut rel_of_kept[kept as usize];
            if *slot == u32::MAX {
                *slot = rel_kept.len() as u32;
                rel_kept.push(kept);
            }
            *slot
        };
        let mut anny_rel: Vec<(u32, u32)> = Vec::new();
        for row in &anny_rows {
            for &(a, _) in row {
                let k = kob[out_base[a as usize] as usize];
                anny_rel.push((a, rel(k)));
            }
        }
        let to_rel = |vs: &[u32], rel: &mut dyn FnMut(u32) -> u32| -> Vec<u32> {
            vs.iter().map(|&b| rel(kob[b as usize])).collect()
        };
        let head_rel: Vec<Vec<u32>> = rig
            .bones
            .iter()
            .map(|b| to_rel(&b.head_vertices, &mut rel))
            .collect();
        let tail_rel: Vec<Vec<u32>> = rig
            .bones
            .iter()
            .map(|b| to_rel(&b.tail_vertices, &mut rel))
            .collect();
        anny_rel.sort_unstable();
        anny_rel.dedup();
        let rel_of_anny = |a: u32| -> u32 {
            let i = anny_rel
                .binary_search_by_key(&a, |e| e.0)
                .expect("touched vertex");
            anny_rel[i].1
        };

        // Face-unit bases at the relevant vertices: B_j = rest(f = e_j) − rest(0).
        let default = ShapeParams::default();
        let rest0 = generator.rest_mesh(&default)?;
        let unit_dense: Vec<Vec<V3>> = (0..N_UNITS)
            .into_par_iter()
            .map(|j| -> Result<Vec<V3>> {
                let mut s = default.clone();
                s.facial_actions[j] = 1.0;
                let r = generator.rest_mesh(&s)?;
                Ok(rel_kept
                    .iter()
                    .map(|&k| sub(r[k as usize], rest0[k as usize]))
                    .collect())
            })
            .collect::<Result<Vec<_>>>()?;
        let unit_joints: Vec<Vec<(usize, V3, V3)>> = unit_dense
            .iter()
            .map(|d| {
                (0..n_bones)
                    .filter_map(|c| {
                        let dh = rel_mean(&head_rel[c], d);
                        let dt = rel_mean(&tail_rel[c], d);
                        (dh != [0.0; 3] || dt != [0.0; 3]).then_some((c, dh, dt))
                    })
                    .collect()
            })
            .collect();

        // Posable bones.
        let posable: Vec<Posable> = posable_bones()
            .iter()
            .enumerate()
            .map(|(slot, name)| {
                let c = rig.index(name).ok_or_else(|| {
                    HumanError::Invalid(format!("the rig has no posable bone `{name}`"))
                })?;
                let r = bone_range(name).expect("posable bones have ranges");
                let range = r.map(|a| a.map(f64::to_radians));
                let prior = range.map(|[lo, hi]| {
                    let s = lo.abs().max(hi.abs());
                    if lo < hi { 1.0 / (s * s) } else { 0.0 }
                });
                Ok(Posable {
                    rig: c,
                    slot,
                    range,
                    prior,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut frame_bone = vec![false; n_bones];
        frame_bone[0] = true;
        for p in &posable {
            frame_bone[p.rig] = true;
        }
        let frame_units: Vec<usize> = (0..N_UNITS)
            .filter(|&j| unit_joints[j].iter().any(|(c, _, _)| frame_bone[*c]))
            .collect();

        // Pairs, ancestors.
        let skin = generator.skin_weights();
        let unit_terms = |list: &[(u32, f64)]| -> Vec<(u8, V3)> {
            let mut out = Vec::new();
            for (j, d) in unit_dense.iter().enumerate() {
                let mut x = [0.0; 3];
                for &(r, w) in list {
                    x = add(x, scale(d[r as usize], w));
                }
                if x != [0.0; 3] {
                    out.push((j as u8, x));
                }
            }
            out
        };
        let mut kp = Skinned::default();
        for (row, name) in anny_rows.iter().zip(&keypoints.names) {
            let part = skinned_row(row, &rel_of_anny, skin, &parents, &unit_terms);
            kp.push(keypoint_index(name), part);
        }
        let mut row_of_tc = vec![None; N_KEYPOINTS];
        for (r, k) in kp.rows.iter().enumerate() {
            if let Some(t) = k.tc {
                row_of_tc[t] = Some(r);
            }
        }
        IkSolver {
            generator,
            map,
            topology,
            set: keypoints.clone(),
            row_of_tc,
            parents,
            rel_kept,
            head_rel,
            tail_rel,
            kp,
            unit_joints,
            frame_units,
            posable,
            grids: Mutex::new(Vec::new()),
            surface: Mutex::new(None),
            vertex_grids: Mutex::new(Vec::new()),
            setup_seconds: 0.0,
        }
        .with_default_grid(t0)
    }

    /// Seconds spent in [`IkSolver::new`].
    pub fn setup_seconds(&self) -> f64 {
        self.setup_seconds
    }

    /// Topology of the keypoint set and of the result meshes.
    pub fn topology(&self) -> OutputTopology {
        self.topology
    }

    /// Number of Anny output vertices the keypoints depend on (after composing with the
    /// topology map) plus the joint-regressor vertices: the rest positions the solver needs.
    pub fn n_relevant_vertices(&self) -> usize {
        self.rel_kept.len()
    }

    /// The generator shape of a state: `template` with the six phenotype values and the face
    /// units of `state`.
    pub fn shape_params(&self, state: &IkState, template: &ShapeParams) -> ShapeParams {
        let mut s = template.clone();
        for (name, &v) in IK_PHENOTYPE.iter().zip(&state.phenotype) {
            if let Some(slot) = s.phenotype.get_mut(name) {
                *slot = v;
            }
        }
        s.facial_actions = state.face_units;
        s
    }

    /// The generator pose of a state: bone angles in degrees, `R = Rz(z) Ry(y) Rx(x)` written
    /// as `root_rotation_z_deg = z` and root Euler `(x, y, 0)` (at `|R₂₀| = 1`, `x = 0`),
    /// root translation `u`.
    pub fn pose_params(&self, state: &IkState) -> PoseParams {
        let mut euler_deg: Vec<[f64; 3]> = state
            .angles
            .iter()
            .map(|a| a.map(f64::to_degrees))
            .collect();
        let r = &state.rotation;
        let sy = (-r[2][0]).clamp(-1.0, 1.0);
        let y = sy.asin();
        let (x, z) = if sy.abs() < 1.0 - 1e-12 {
            (r[2][1].atan2(r[2][2]), r[1][0].atan2(r[0][0]))
        } else {
            (0.0, (-r[0][1]).atan2(r[1][1]))
        };
        euler_deg[0] = [x.to_degrees(), y.to_degrees(), 0.0];
        PoseParams {
            euler_deg,
            root_rotation_z_deg: z.to_degrees(),
            root_translation: state.translation,
        }
    }

    /// [`IkSolver::shape_params`] and [`IkSolver::pose_params`] together.
    pub fn params(&self, state: &IkState, template: &ShapeParams) -> GeneratorParams {
        GeneratorParams {
            shape: self.shape_params(state, template),
            pose: self.pose_params(state),
        }
    }

    // -----------------------------------------------------------------------------------------
    // Evaluation.

    /// The non-fitted part of a shape, as the key of its phenotype grid.
    fn grid_key(template: &ShapeParams) -> String {
        let p = &template.phenotype;
        format!(
            "{:?}|{:?}",
            [p.cupsize, p.firmness, p.african, p.asian, p.caucasian],
            template.local_changes
        )
    }

    /// [`IkSolver::new`]'s last step: the phenotype grid of the default shape.
    fn with_default_grid(mut self, t0: Instant) -> Result<Self> {
        self.grid(&ShapeParams::default())?;
        self.setup_seconds = t0.elapsed().as_secs_f64();
        Ok(self)
    }

    /// The phenotype grid of `template`'s non-fitted values (other phenotype values, local
    /// changes), built on first use (288 rest meshes of the generator, in parallel) and
    /// cached.
    fn grid(&self, template: &ShapeParams) -> Result<Arc<PhenGrid>> {
        let key = IkSolver::grid_key(template);
        let mut grids = self.grids.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, g)) = grids.iter().find(|(k, _)| *k == key) {
            return Ok(g.clone());
        }
        let points = (0..N_GRID)
            .into_par_iter()
            .map(|idx| -> Result<Vec<V3>> {
                let r = self.generator.rest_mesh(&grid_shape(template, idx))?;
                let rest: Vec<V3> = self.rel_kept.iter().map(|&k| r[k as usize]).collect();
                let mut v = self.pair_x(&rest);
                v.extend(self.head_rel.iter().map(|h| rel_mean(h, &rest)));
                v.extend(self.tail_rel.iter().map(|t| rel_mean(t, &rest)));
                Ok(v)
            })
            .collect::<Result<Vec<_>>>()?;
        let g = Arc::new(PhenGrid { points });
        grids.push((key, g.clone()));
        Ok(g)
    }

    /// The surface data of point targets (built on first use, ~53 rest meshes): the Anny
    /// output vertices that rows of the solver's topology reach, their kept indices and the
    /// face units' displacements `B_j = rest(f = e_j) − rest(0)` there.
    fn surface(&self) -> Result<Arc<Surface>> {
        let mut guard = self.surface.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = &*guard {
            return Ok(s.clone());
        }
        let n_anny = self.map.n_anny_vertices();
        let mut reach = vec![false; n_anny];
        match self.topology {
            OutputTopology::Anny => reach.iter_mut().for_each(|r| *r = true),
            OutputTopology::Full => {
                for &a in self.map.full_from_anny() {
                    reach[a as usize] = true;
                }
            }
            OutputTopology::Small => {
                for b in self.map.small_binding() {
                    for &a in &b.tri {
                        reach[a as usize] = true;
                    }
                }
            }
        }
        let kob = self.generator.kept_of_base();
        let out_base = self.generator.output_vertices();
        let mut slot_of_anny = vec![u32::MAX; n_anny];
        let mut kept_of_slot = Vec::new();
        for a in 0..n_anny {
            if reach[a] {
                slot_of_anny[a] = kept_of_slot.len() as u32;
                kept_of_slot.push(kob[out_base[a] as usize]);
            }
        }
        let default = ShapeParams::default();
        let rest0 = self.generator.rest_mesh(&default)?;
        let per_unit: Vec<Vec<(u32, V3)>> = (0..N_UNITS)
            .into_par_iter()
            .map(|j| -> Result<Vec<(u32, V3)>> {
                let mut s = default.clone();
                s.facial_actions[j] = 1.0;
                let r = self.generator.rest_mesh(&s)?;
                Ok(kept_of_slot
                    .iter()
                    .enumerate()
                    .filter_map(|(slot, &k)| {
                        let d = sub(r[k as usize], rest0[k as usize]);
                        (d != [0.0; 3]).then_some((slot as u32, d))
                    })
                    .collect())
            })
            .collect::<Result<Vec<_>>>()?;
        let n_slots = kept_of_slot.len();
        let mut unit_off = vec![0u32; n_slots + 1];
        for list in &per_unit {
            for &(slot, _) in list {
                unit_off[slot as usize + 1] += 1;
            }
        }
        for i in 0..n_slots {
            unit_off[i + 1] += unit_off[i];
        }
        let mut fill = unit_off.clone();
        let mut unit_val = vec![(0u8, [0.0; 3]); unit_off[n_slots] as usize];
        for (j, list) in per_unit.iter().enumerate() {
            for &(slot, d) in list {
                unit_val[fill[slot as usize] as usize] = (j as u8, d);
                fill[slot as usize] += 1;
            }
        }
        let s = Arc::new(Surface {
            slot_of_anny,
            kept_of_slot,
            unit_off,
            unit_val,
        });
        *guard = Some(s.clone());
        Ok(s)
    }

    /// The per-vertex phenotype grid of `template`'s non-fitted values: the rest positions
    /// of every slot of `surface` at the 288 grid points (288 rest meshes in parallel, about
    /// 24 bytes × 288 per slot: 92 MB on the full template), built on first use and cached.
    fn vertex_grid(&self, template: &ShapeParams, surface: &Surface) -> Result<Arc<VertexGrid>> {
        let key = IkSolver::grid_key(template);
        let mut grids = self.vertex_grids.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, g)) = grids.iter().find(|(k, _)| *k == key) {
            return Ok(g.clone());
        }
        let n_slots = surface.kept_of_slot.len();
        let mut data = vec![[0.0; 3]; n_slots * N_GRID];
        let all: Vec<usize> = (0..N_GRID).collect();
        for chunk in all.chunks(16) {
            let meshes = chunk
                .par_iter()
                .map(|&idx| -> Result<Vec<V3>> {
                    let r = self.generator.rest_mesh(&grid_shape(template, idx))?;
                    Ok(surface
                        .kept_of_slot
                        .iter()
                        .map(|&k| r[k as usize])
                        .collect())
                })
                .collect::<Result<Vec<_>>>()?;
            for (&idx, m) in chunk.iter().zip(&meshes) {
                for (slot, p) in m.iter().enumerate() {
                    data[slot * N_GRID + idx] = *p;
                }
            }
        }
        let g = Arc::new(VertexGrid { data });
        grids.push((key, g.clone()));
        Ok(g)
    }

    /// Checks point targets and builds their skinned model (rows composed with the topology
    /// map, pairs, ancestors, face-unit terms; in parallel over the points).
    fn point_model(&self, points: &[PointTarget], template: &ShapeParams) -> Result<PointModel> {
        let nv = self.map.n_vertices(self.topology);
        for (i, p) in points.iter().enumerate() {
            let bad = |what: String| Err(HumanError::Invalid(format!("point target {i}: {what}")));
            if p.rows.is_empty() {
                return bad("no vertices".into());
            }
            if let Some(&(v, w)) = p
                .rows
                .iter()
                .find(|(v, w)| *v as usize >= nv || !w.is_finite())
            {
                return bad(format!(
                    "vertex {v} (coefficient {w}) out of range or not finite \
                     (topology `{}` has {nv} vertices)",
                    self.topology
                ));
            }
            if !p.position.iter().all(|x| x.is_finite()) {
                return bad(format!("non-finite position {:?}", p.position));
            }
            if !p.weight.is_finite() || p.weight < 0.0 {
                return bad(format!(
                    "invalid weight {} (must be finite and ≥ 0)",
                    p.weight
                ));
            }
            if let Some(n) = p.normal
                && !(n.iter().all(|x| x.is_finite()) && norm(n) > 1e-12)
            {
                return bad(format!("invalid normal {n:?}"));
            }
        }
        let surface = self.surface()?;
        let grid = self.vertex_grid(template, &surface)?;
        let rows: Vec<Vec<(u32, f64)>> = points
            .par_iter()
            .with_min_len(256)
            .map(|p| anny_row(&self.map, self.topology, &p.rows))
            .collect();
        let mut local_of_slot = vec![u32::MAX; surface.kept_of_slot.len()];
        let mut verts: Vec<u32> = Vec::new();
        for r in &rows {
            for &(a, _) in r {
                let slot = surface.slot_of_anny[a as usize];
                debug_assert!(slot != u32::MAX, "reachable vertex");
                let l = &mut local_of_slot[slot as usize];
                if *l == u32::MAX {
                    *l = verts.len() as u32;
                    verts.push(slot);
                }
            }
        }
        let rel = |a: u32| local_of_slot[surface.slot_of_anny[a as usize] as usize];
        let units = |list: &[(u32, f64)]| -> Vec<(u8, V3)> {
            let mut acc = [[0.0; 3]; N_UNITS];
            let mut any = false;
            for &(r, w) in list {
                let slot = verts[r as usize] as usize;
                let (a, b) = (
                    surface.unit_off[slot] as usize,
                    surface.unit_off[slot + 1] as usize,
                );
                for &(j, d) in &surface.unit_val[a..b] {
                    acc[j as usize] = add(acc[j as usize], scale(d, w));
                    any = true;
                }
            }
            if !any {
                return Vec::new();
            }
            (0..N_UNITS)
                .filter(|&j| acc[j] != [0.0; 3])
                .map(|j| (j as u8, acc[j]))
                .collect()
        };
        let skin = self.generator.skin_weights();
        let parts: Vec<RowPart> = rows
            .par_iter()
            .with_min_len(128)
            .map(|r| skinned_row(r, &rel, skin, &self.parents, &units))
            .collect();
        let mut sk = Skinned::default();
        for part in parts {
            sk.push(None, part);
        }
        let rows = points
            .iter()
            .map(|p| PtRow {
                target: p.position,
                weight: p.weight,
                normal: p.normal.map(|n| scale(n, 1.0 / norm(n))),
            })
            .collect();
        Ok(PointModel {
            sk,
            verts,
            rows,
            grid,
        })
    }

    /// Frames from heads and tails: `(local, inv_rest)`.
    fn frames(&self, heads: &[V3], tails: &[V3]) -> (Vec<Affine>, Vec<Affine>) {
        let frames = rig::rest_frames(self.generator.rig(), heads, tails);
        let inv: Vec<Affine> = frames.iter().map(Affine::inverse_rigid).collect();
        let local = self
            .parents
            .iter()
            .enumerate()
            .map(|(c, p)| match p {
                None => Affine::IDENTITY,
                Some(p) => inv[*p].compose(&frames[c]),
            })
            .collect();
        (local, inv)
    }

    /// Shape quantities at `(β, f)`: the grid interpolation at `β` plus the face units'
    /// linear terms `Σ_j f_j X^{(j)}_kb`, `Σ_j f_j Δh_j`, `Σ_j f_j Δt_j`; then the frames.
    fn shape_eval(&self, grid: &PhenGrid, beta: &[f64; 6], units: &[f64; 52]) -> ShapeEval {
        let mut v = grid.interp(beta, &[1; 6], None);
        let np = self.kp.pairs.len();
        let nb = self.parents.len();
        let mut tails = v.split_off(np + nb);
        let mut heads = v.split_off(np);
        let mut x = v;
        add_unit_terms(&self.kp, units, &mut x);
        for (j, &f) in units.iter().enumerate() {
            if f != 0.0 {
                for &(c, dh, dt) in &self.unit_joints[j] {
                    heads[c] = add(heads[c], scale(dh, f));
                    tails[c] = add(tails[c], scale(dt, f));
                }
            }
        }
        let (local, inv_rest) = self.frames(&heads, &tails);
        ShapeEval {
            heads,
            local,
            inv_rest,
            x,
            tails,
        }
    }

    /// Forward kinematics (module docs).
    fn kinematics(&self, shape: &ShapeEval, st: &IkState, kin: &mut Kin) {
        let n = self.parents.len();
        kin.world.resize(n, Affine::IDENTITY);
        kin.pre.resize(n, IDENTITY);
        kin.skin.resize(n, Affine::IDENTITY);
        for c in 0..n {
            match self.parents[c] {
                None => {
                    kin.world[c] = Affine::new(st.rotation, add(shape.heads[c], st.translation));
                    kin.pre[c] = IDENTITY;
                }
                Some(p) => {
                    let g = kin.world[p].compose(&shape.local[c]);
                    kin.pre[c] = g.m;
                    kin.world[c] = Affine::new(matmul(&g.m, &euler_rad(st.angles[c])), g.t);
                }
            }
            kin.skin[c] = kin.world[c].compose(&shape.inv_rest[c]);
        }
    }

    fn keypoints_into(&self, shape: &ShapeEval, kin: &Kin, out: &mut Vec<V3>) {
        rows_into(&self.kp, &shape.x, kin, out);
    }

    fn current(&self, state: IkState, ctx: Ctx<'_>) -> Current {
        let shape = Arc::new(self.shape_eval(ctx.grid, &state.phenotype, &state.face_units));
        let mut kin = Kin::default();
        self.kinematics(&shape, &state, &mut kin);
        let mut k = Vec::new();
        self.keypoints_into(&shape, &kin, &mut k);
        let pts = ctx.pts.map(|m| {
            let x = Arc::new(m.shape_x(&state.phenotype, &state.face_units));
            m.eval(x, &kin)
        });
        Current {
            state,
            shape,
            kin,
            k,
            pts,
        }
    }

    /// Evaluates a new state, reusing the shape of `prev` when `β` and `f` are unchanged.
    fn reevaluate(&self, state: IkState, prev: &Current, ctx: Ctx<'_>) -> Current {
        if state.phenotype == prev.state.phenotype && state.face_units == prev.state.face_units {
            let shape = prev.shape.clone();
            let mut kin = prev.kin.clone();
            self.kinematics(&shape, &state, &mut kin);
            let mut k = Vec::with_capacity(prev.k.len());
            self.keypoints_into(&shape, &kin, &mut k);
            let pts = ctx.pts.map(|m| {
                let x = match &prev.pts {
                    Some(p) => p.x.clone(),
                    None => Arc::new(m.shape_x(&state.phenotype, &state.face_units)),
                };
                m.eval(x, &kin)
            });
            return Current {
                state,
                shape,
                kin,
                k,
                pts,
            };
        }
        self.current(state, ctx)
    }

    /// The model's keypoints (set order) at `state`, with `template` supplying the shape
    /// values the IK does not fit. Equal (to rounding) to evaluating the keypoint set on the
    /// generator's posed mesh of [`IkSolver::params`].
    ///
    /// # Errors
    /// Generator errors while building the template's phenotype grid.
    pub fn model_keypoints(&self, state: &IkState, template: &ShapeParams) -> Result<Vec<V3>> {
        let grid = self.grid(template)?;
        Ok(self.current(state.clone(), Ctx::new(&grid, None)).k)
    }

    /// The model positions `Σ_m b_m x_m(p)` of point targets (their order) at `state`, by the
    /// solver's fast point model (per-vertex phenotype grid, skinning collapsed per bone);
    /// equal to rounding to evaluating the rows on the generator's posed mesh of
    /// [`IkSolver::params`]. Targets, weights and normals are not used.
    ///
    /// # Errors
    /// Invalid point rows (see [`IkSolver::solve_with_points`]); generator errors.
    pub fn model_points(
        &self,
        state: &IkState,
        template: &ShapeParams,
        points: &[PointTarget],
    ) -> Result<Vec<V3>> {
        let grid = self.grid(template)?;
        let pm = self.point_model(points, template)?;
        let cur = self.current(state.clone(), Ctx::new(&grid, Some(&pm)));
        Ok(cur.pts.map(|p| p.p).unwrap_or_default())
    }

    /// A variable of the public API as a solver variable (no bounds or prior).
    fn var_of(&self, var: IkVariable) -> Result<Var> {
        let n_bones = self.parents.len();
        let bad = |what: &str| Err(HumanError::Invalid(format!("invalid IK variable: {what}")));
        match var {
            IkVariable::Translation(i) if i < 3 => Ok(Var::Trans(i)),
            IkVariable::Rotation(i) if i < 3 => Ok(Var::Rot(i)),
            IkVariable::Angle { bone, axis } if bone >= 1 && bone < n_bones && axis < 3 => {
                Ok(Var::Angle {
                    bone,
                    axis,
                    lo: f64::NEG_INFINITY,
                    hi: f64::INFINITY,
                    prior: 0.0,
                })
            }
            IkVariable::Phenotype(i) if i < 6 => Ok(Var::Phen(i)),
            IkVariable::FaceUnit(j) if j < N_UNITS => Ok(Var::Unit(j)),
            _ => bad(&format!("{var:?}")),
        }
    }

    /// One Jacobian column for every keypoint of the set and every point of `pm`.
    fn column(
        &self,
        state: &IkState,
        grid: &PhenGrid,
        pm: Option<&PointModel>,
        var: IkVariable,
    ) -> Result<(Vec<V3>, Vec<V3>)> {
        let mut vs = VarSet::new(self.parents.len());
        vs.push(self.var_of(var)?);
        let ctx = Ctx::new(grid, pm);
        let cur = self.current(state.clone(), ctx);
        let rows: Vec<Row> = (0..self.kp.rows.len())
            .map(|row| Row {
                row,
                target: [0.0; 3],
                weight: 1.0,
            })
            .collect();
        let jac = self.jacobian(&vs, &cur, &rows, ctx, [0.0; 6]);
        let sum = |rows: &[Vec<(usize, V3)>]| -> Vec<V3> {
            rows.iter()
                .map(|r| r.iter().fold([0.0; 3], |s, e| add(s, e.1)))
                .collect()
        };
        Ok((sum(&jac.rows), sum(&jac.pts)))
    }

    /// `∂K_k/∂var` for every keypoint of the set (set order), as the solver computes it
    /// (analytic for the global motion, the bone angles and the face units' rest-mesh part;
    /// finite differences for the phenotype and the face units' frame part).
    ///
    /// # Errors
    /// Generator errors; [`HumanError::Invalid`] for an index out of range or the root as
    /// an `Angle` bone.
    pub fn jacobian_column(
        &self,
        state: &IkState,
        template: &ShapeParams,
        var: IkVariable,
    ) -> Result<Vec<V3>> {
        self.var_of(var)?;
        let grid = self.grid(template)?;
        Ok(self.column(state, &grid, None, var)?.0)
    }

    /// `∂(Σ_m b_m x_m)/∂var` for every point target (their order; normals ignored), as the
    /// solver computes it (see [`IkSolver::jacobian_column`]; the phenotype part of the rest
    /// positions is the exact derivative of the per-vertex phenotype grid).
    ///
    /// # Errors
    /// As [`IkSolver::jacobian_column`] and [`IkSolver::model_points`].
    pub fn point_jacobian_column(
        &self,
        state: &IkState,
        template: &ShapeParams,
        points: &[PointTarget],
        var: IkVariable,
    ) -> Result<Vec<V3>> {
        self.var_of(var)?;
        let grid = self.grid(template)?;
        let plain: Vec<PointTarget> = points
            .iter()
            .map(|p| PointTarget {
                normal: None,
                ..p.clone()
            })
            .collect();
        let pm = self.point_model(&plain, template)?;
        Ok(self.column(state, &grid, Some(&pm), var)?.1)
    }

    /// `∂(X, heads, tails)/∂β_i` at `β` from the grid (one-sided on a kink: `side < 0` the
    /// cell below).
    fn phen_column(&self, grid: &PhenGrid, beta: &[f64; 6], i: usize, side: i8) -> PhenColumn {
        let mut sides = [1i8; 6];
        sides[i] = side;
        let mut v = grid.interp(beta, &sides, Some(i));
        let np = self.kp.pairs.len();
        let nb = self.parents.len();
        let tails = v.split_off(np + nb);
        let heads = v.split_off(np);
        PhenColumn { x: v, heads, tails }
    }

    /// `∂K/∂β_i` of every keypoint (set order) from a column of rest-quantity derivatives:
    /// `Σ_b M_b ∂X_kb/∂β_i` plus the frame part; with `pts` (the point model and its
    /// `∂X_pb/∂β_i`) the same for the points.
    fn phen_values(
        &self,
        cur: &Current,
        col: &PhenColumn,
        pts: Option<(&PointModel, Vec<V3>)>,
    ) -> (Vec<V3>, Option<Vec<V3>>) {
        let moves = (0..self.parents.len()).map(|b| (b, col.heads[b], col.tails[b]));
        let (mut vals, pvals) = self.frame_part(cur, moves, pts.as_ref().map(|p| p.0));
        for (kp, v) in self.kp.rows.iter().zip(vals.iter_mut()) {
            for p in kp.pairs.clone() {
                *v = add(*v, matvec(&cur.kin.skin[self.kp.pairs[p].bone].m, col.x[p]));
            }
        }
        let pvals = match (pts, pvals) {
            (Some((m, dx)), Some(mut pv)) => {
                for (row, v) in m.sk.rows.iter().zip(pv.iter_mut()) {
                    for p in row.pairs.clone() {
                        *v = add(*v, matvec(&cur.kin.skin[m.sk.pairs[p].bone].m, dx[p]));
                    }
                }
                Some(pv)
            }
            _ => None,
        };
        (vals, pvals)
    }

    /// `X_kb` of every pair for rest positions `rest` (relevant vertices).
    fn pair_x(&self, rest: &[V3]) -> Vec<V3> {
        pair_sums(&self.kp, rest)
    }

    /// `∂K/∂s` through the rest frames only, for joints moving as `heads + s·dh`,
    /// `tails + s·dt` (forward difference, step [`FRAME_STEP`]); `X_kb` held fixed. With a
    /// point model (and points evaluated in `cur`), the same for the points.
    fn frame_part(
        &self,
        cur: &Current,
        moves: impl Iterator<Item = (usize, V3, V3)>,
        pm: Option<&PointModel>,
    ) -> (Vec<V3>, Option<Vec<V3>>) {
        let mut shape = (*cur.shape).clone();
        for (c, dh, dt) in moves {
            shape.heads[c] = add(shape.heads[c], scale(dh, FRAME_STEP));
            shape.tails[c] = add(shape.tails[c], scale(dt, FRAME_STEP));
        }
        let (local, inv) = self.frames(&shape.heads, &shape.tails);
        shape.local = local;
        shape.inv_rest = inv;
        let mut kin = Kin::default();
        self.kinematics(&shape, &cur.state, &mut kin);
        let mut k = Vec::new();
        self.keypoints_into(&shape, &kin, &mut k);
        let diff = |a: &[V3], b: &[V3]| -> Vec<V3> {
            a.iter()
                .zip(b)
                .map(|(a, b)| scale(sub(*a, *b), 1.0 / FRAME_STEP))
                .collect()
        };
        let pts = match (pm, &cur.pts) {
            (Some(m), Some(pe)) => {
                // Only points skinned to a bone whose skinning transform changed move (the
                // rig order lists parents first).
                let mut dirty = vec![false; self.parents.len()];
                for c in 0..dirty.len() {
                    dirty[c] = shape.local[c] != cur.shape.local[c]
                        || shape.inv_rest[c] != cur.shape.inv_rest[c]
                        || shape.heads[c] != cur.shape.heads[c]
                        || self.parents[c].is_some_and(|p| dirty[p]);
                }
                let out =
                    m.sk.rows
                        .iter()
                        .zip(&pe.p)
                        .map(|(row, p0)| {
                            if row.pairs.clone().any(|i| dirty[m.sk.pairs[i].bone]) {
                                let mut q = [0.0; 3];
                                for i in row.pairs.clone() {
                                    q = add(q, pair_term(&m.sk, i, &pe.x, &kin));
                                }
                                scale(sub(q, *p0), 1.0 / FRAME_STEP)
                            } else {
                                [0.0; 3]
                            }
                        })
                        .collect();
                Some(out)
            }
            _ => None,
        };
        (diff(&k, &cur.k), pts)
    }

    /// Rows `(column, ∂K/∂var)` of the Jacobian for the given targets (and the point targets
    /// of `ctx`, projected on their normals), the columns held this iteration (phenotype
    /// values at a kink minimum) and, per phenotype value, the side of its kink the
    /// derivative was taken on (−1 below, 1 above; see [`PhenGrid::interp`]); `prior_grad[i]`
    /// is the prior's gradient along phenotype value `i`.
    fn jacobian(
        &self,
        vs: &VarSet,
        cur: &Current,
        rows: &[Row],
        ctx: Ctx<'_>,
        prior_grad: [f64; 6],
    ) -> Jacobian {
        let st = &cur.state;
        let grid = ctx.grid;
        let pts = match (ctx.pts, &cur.pts) {
            (Some(m), Some(pe)) => Some((m, pe)),
            _ => None,
        };
        let pm = pts.map(|p| p.0);
        // Phenotype columns. On a kink the side is chosen by the gradient: the forward
        // derivative if it says "increase", the backward one if it says "decrease", else the
        // value is held for this iteration (a kink minimum along it).
        type Col = (usize, Vec<V3>, Option<Vec<V3>>);
        let mut phen_cols: Vec<Col> = Vec::new();
        let mut held = Vec::new();
        let mut sides = [1i8; 6];
        {
            let beta = &st.phenotype;
            // The points' rest derivatives of every column (and kink side) at once.
            let mut requests = Vec::new();
            for i in 0..6 {
                if vs.phen[i].is_some() {
                    requests.push((i, 1i8));
                    if on_kink(i, beta[i]) {
                        requests.push((i, -1));
                    }
                }
            }
            let mut dxs: Vec<Option<Vec<V3>>> = match pm {
                Some(m) => m.dx(beta, &requests).into_iter().map(Some).collect(),
                None => Vec::new(),
            };
            for i in 0..6 {
                let Some(col) = vs.phen[i] else { continue };
                let mut values = |side: i8| {
                    let dx = pm.map(|m| {
                        let r = requests
                            .iter()
                            .position(|&q| q == (i, side))
                            .expect("requested");
                        (m, dxs[r].take().expect("used once"))
                    });
                    self.phen_values(cur, &self.phen_column(grid, beta, i, side), dx)
                };
                let fwd = values(1);
                if !on_kink(i, beta[i]) {
                    phen_cols.push((col, fwd.0, fwd.1));
                    continue;
                }
                let back = values(-1);
                let grad = |v: &(Vec<V3>, Option<Vec<V3>>)| -> f64 {
                    let data: f64 = rows
                        .iter()
                        .map(|r| r.weight * dot(v.0[r.row], sub(cur.k[r.row], r.target)))
                        .sum();
                    let pdata: f64 = match (pts, &v.1) {
                        (Some((m, pe)), Some(pv)) => m
                            .rows
                            .iter()
                            .enumerate()
                            .map(|(p, r)| {
                                r.weight * dot(r.proj(pv[p]), r.proj(sub(pe.p[p], r.target)))
                            })
                            .sum(),
                        _ => 0.0,
                    };
                    data + pdata + prior_grad[i]
                };
                if grad(&fwd) < 0.0 {
                    phen_cols.push((col, fwd.0, fwd.1));
                } else if grad(&back) > 0.0 {
                    sides[i] = -1;
                    phen_cols.push((col, back.0, back.1));
                } else {
                    held.push(col);
                }
            }
        }
        // Face units: frame part for the units that move the joints of a posable bone.
        let mut unit_frame_cols: Vec<Col> = Vec::new();
        for &j in &self.frame_units {
            let Some(col) = vs.unit[j] else { continue };
            let moves = self.unit_joints[j].iter().copied();
            let (k, p) = self.frame_part(cur, moves, pm);
            unit_frame_cols.push((col, k, p));
        }
        let any_unit = vs.unit.iter().any(Option::is_some);
        let axes = self.bone_axes(vs, cur);
        let kp_phen: Vec<(usize, &[V3])> = phen_cols.iter().map(|c| (c.0, &c.1[..])).collect();
        let kp_unit: Vec<(usize, &[V3])> =
            unit_frame_cols.iter().map(|c| (c.0, &c.1[..])).collect();
        let jac = rows
            .iter()
            .map(|r| {
                self.row_entries(
                    &self.kp,
                    r.row,
                    &cur.shape.x,
                    cur,
                    vs,
                    &axes,
                    any_unit,
                    &kp_phen,
                    &kp_unit,
                )
            })
            .collect();
        let pt_jac = match pts {
            Some((m, pe)) => {
                fn second(c: &(usize, Vec<V3>, Option<Vec<V3>>)) -> (usize, &[V3]) {
                    (c.0, c.2.as_deref().expect("point columns with points"))
                }
                let pt_phen: Vec<(usize, &[V3])> = phen_cols.iter().map(second).collect();
                let pt_unit: Vec<(usize, &[V3])> = unit_frame_cols.iter().map(second).collect();
                (0..m.rows.len())
                    .into_par_iter()
                    .with_min_len(64)
                    .map(|p| {
                        let mut e = self.row_entries(
                            &m.sk, p, &pe.x, cur, vs, &axes, any_unit, &pt_phen, &pt_unit,
                        );
                        if let Some(n) = m.rows[p].normal {
                            // Point-to-plane: the scalar n̂ᵀ∂ in the first component.
                            for x in &mut e {
                                x.1 = [dot(n, x.1), 0.0, 0.0];
                            }
                        }
                        e
                    })
                    .collect()
            }
            None => Vec::new(),
        };
        Jacobian {
            rows: jac,
            pts: pt_jac,
            held,
            sides,
        }
    }

    /// The world axes `ω_ca = G_c n_a` of the free bone angles (module docs), per bone (zero
    /// for bones without a free angle).
    fn bone_axes(&self, vs: &VarSet, cur: &Current) -> Vec<[V3; 3]> {
        let st = &cur.state;
        (0..self.parents.len())
            .map(|c| {
                let cols = vs.bone[c];
                if c == 0 || cols.iter().all(Option::is_none) {
                    return [[0.0; 3]; 3];
                }
                let [_, ay, az] = st.angles[c];
                let rz = rig::rot_z(az);
                let n = [
                    matvec(&matmul(&rz, &rig::rot_y(ay)), [1.0, 0.0, 0.0]),
                    [rz[0][1], rz[1][1], rz[2][1]],
                    [0.0, 0.0, 1.0],
                ];
                std::array::from_fn(|a| matvec(&cur.kin.pre[c], n[a]))
            })
            .collect()
    }

    /// The Jacobian entries `(column, ∂/∂var)` of row `row` of `sk` (pair rest quantities
    /// `x`): global motion and bone angles analytically from the subtree sums `Y_c` (bone
    /// axes `axes` from [`IkSolver::bone_axes`]), then the given phenotype columns and the
    /// face units (rest-mesh part plus the given frame part).
    #[allow(clippy::too_many_arguments)]
    fn row_entries(
        &self,
        sk: &Skinned,
        row: usize,
        x: &[V3],
        cur: &Current,
        vs: &VarSet,
        axes: &[[V3; 3]],
        any_unit: bool,
        phen_cols: &[(usize, &[V3])],
        unit_frame_cols: &[(usize, &[V3])],
    ) -> Vec<(usize, V3)> {
        let kin = &cur.kin;
        let kp = &sk.rows[row];
        let mut entries: Vec<(usize, V3)> = Vec::new();
        // Subtree sums Y_kc.
        let mut y = vec![[0.0; 3]; kp.anc.len()];
        let mut unit_acc = [[0.0; 3]; 52];
        for i in kp.pairs.clone() {
            let z = pair_term(sk, i, x, kin);
            for &p in &sk.anc_pos[sk.pairs[i].anc.clone()] {
                y[p as usize] = add(y[p as usize], z);
            }
            if any_unit {
                let m = &kin.skin[sk.pairs[i].bone].m;
                for &(j, x) in &sk.unit_x[sk.pairs[i].units.clone()] {
                    if vs.unit[j as usize].is_some() {
                        unit_acc[j as usize] = add(unit_acc[j as usize], matvec(m, x));
                    }
                }
            }
        }
        for (p, &c) in kp.anc.iter().enumerate() {
            let o = kin.world[c].t;
            let d = sub(y[p], scale(o, kp.anc_sigma[p]));
            if c == 0 {
                for a in 0..3 {
                    let mut e = [0.0; 3];
                    e[a] = 1.0;
                    if let Some(col) = vs.rot[a] {
                        entries.push((col, cross(e, d)));
                    }
                    if let Some(col) = vs.trans[a] {
                        entries.push((col, scale(e, kp.anc_sigma[p])));
                    }
                }
                continue;
            }
            let cols = vs.bone[c];
            if cols.iter().all(Option::is_none) {
                continue;
            }
            for a in 0..3 {
                if let Some(col) = cols[a] {
                    entries.push((col, cross(axes[c][a], d)));
                }
            }
        }
        for (col, vals) in phen_cols {
            entries.push((*col, vals[row]));
        }
        for (col, c) in unit_frame_cols {
            // Added to the rest-mesh part below via the accumulator.
            let j = match vs.vars[*col] {
                Var::Unit(j) => j,
                _ => unreachable!("unit column"),
            };
            unit_acc[j] = add(unit_acc[j], c[row]);
        }
        if any_unit {
            for (j, acc) in unit_acc.iter().enumerate() {
                if let Some(col) = vs.unit[j]
                    && *acc != [0.0; 3]
                {
                    entries.push((col, *acc));
                }
            }
        }
        entries
    }

    // -----------------------------------------------------------------------------------------
    // Objective.

    fn prior(&self, st: &IkState, cfg: &IkConfig) -> f64 {
        let mut e = 0.0;
        for p in &self.posable {
            let a = st.angles[p.rig];
            for k in 0..3 {
                e += cfg.pose_prior * p.prior[k] * a[k] * a[k];
            }
        }
        for &b in &st.phenotype {
            e += cfg.phenotype_prior * (b - 0.5) * (b - 0.5);
        }
        for &f in &st.face_units {
            e += cfg.face_unit_prior * f * f;
        }
        e
    }

    fn cost(&self, cur: &Current, rows: &[Row], pm: Option<&PointModel>, cfg: &IkConfig) -> f64 {
        self.data_cost(cur, rows, pm) + self.prior(&cur.state, cfg)
    }

    /// `Σ_k w_k |K_k − k̂_k|²` plus, with a point model evaluated in `cur`, the point terms
    /// `Σ_p w_p |P_p(Σ_m b_m x_m − p)|²` (`P_p` the projection on the normal, or identity).
    fn data_cost(&self, cur: &Current, rows: &[Row], pm: Option<&PointModel>) -> f64 {
        let k: f64 = rows
            .iter()
            .map(|r| {
                let d = sub(cur.k[r.row], r.target);
                r.weight * dot(d, d)
            })
            .sum();
        match (pm, &cur.pts) {
            (Some(m), Some(pe)) => {
                let p: f64 = m
                    .rows
                    .iter()
                    .zip(&pe.p)
                    .map(|(r, x)| {
                        let d = r.proj(sub(*x, r.target));
                        r.weight * dot(d, d)
                    })
                    .sum();
                k + p
            }
            _ => k,
        }
    }

    /// Value, bounds and prior `(x, lo, hi, λ, x̄)` of a variable.
    fn var_info(&self, v: Var, st: &IkState, cfg: &IkConfig) -> (f64, f64, f64, f64, f64) {
        let inf = f64::INFINITY;
        match v {
            Var::Trans(a) => (st.translation[a], -inf, inf, 0.0, 0.0),
            Var::Rot(_) => (0.0, -inf, inf, 0.0, 0.0),
            Var::Angle {
                bone,
                axis,
                lo,
                hi,
                prior,
            } => (st.angles[bone][axis], lo, hi, cfg.pose_prior * prior, 0.0),
            Var::Phen(i) => (st.phenotype[i], 0.0, 1.0, cfg.phenotype_prior, 0.5),
            Var::Unit(j) => (st.face_units[j], 0.0, 1.0, cfg.face_unit_prior, 0.0),
        }
    }

    /// The state moved by `delta`, each value clamped to its step bounds `info = (x, lo, hi)`
    /// and snapped onto a bound it comes within 1e-12 of.
    fn apply_step(
        &self,
        vs: &VarSet,
        st: &IkState,
        delta: &[f64],
        info: &[(f64, f64, f64)],
    ) -> IkState {
        let mut s = st.clone();
        let mut phi = [0.0; 3];
        for (i, &v) in vs.vars.iter().enumerate() {
            let d = delta[i];
            if d == 0.0 {
                continue;
            }
            let (x, lo, hi) = info[i];
            let mut nx = (x + d).clamp(lo, hi);
            if nx <= lo + 1e-12 {
                nx = lo;
            } else if nx >= hi - 1e-12 {
                nx = hi;
            }
            match v {
                Var::Trans(a) => s.translation[a] = nx,
                Var::Rot(a) => phi[a] = d,
                Var::Angle { bone, axis, .. } => s.angles[bone][axis] = nx,
                Var::Phen(i) => s.phenotype[i] = nx,
                Var::Unit(j) => s.face_units[j] = nx,
            }
        }
        let angle = norm(phi);
        if angle > 0.0 {
            s.rotation = matmul(&axis_angle(phi, angle), &s.rotation);
        }
        s
    }

    /// One Levenberg–Marquardt stage (keypoint `rows`, and the point targets of `ctx` when it
    /// has a point model). Returns the number of iterations.
    fn lm_stage(
        &self,
        cur: &mut Current,
        vs: &VarSet,
        rows: &[Row],
        cfg: &IkConfig,
        ctx: Ctx<'_>,
        max_iter: usize,
    ) -> usize {
        let n = vs.vars.len();
        if n == 0 || rows.is_empty() {
            return 0;
        }
        let pm = ctx.pts;
        if let Some(m) = pm
            && cur.pts.is_none()
        {
            let x = Arc::new(m.shape_x(&cur.state.phenotype, &cur.state.face_units));
            cur.pts = Some(m.eval(x, &cur.kin));
        }
        let wsum: f64 = rows.iter().map(|r| r.weight).sum::<f64>()
            + pm.map_or(0.0, |m| m.rows.iter().map(|r| r.weight).sum::<f64>());
        let floor = 1e-16 * wsum;
        let mut f = self.cost(cur, rows, pm, cfg);
        let mut mu = 1e-4;
        let mut iters = 0;
        let mut h = vec![0.0; n * n];
        let mut g = vec![0.0; n];
        while iters < max_iter {
            iters += 1;
            let prior_grad = cur.state.phenotype.map(|b| cfg.phenotype_prior * (b - 0.5));
            let Jacobian {
                rows: jac,
                pts: pt_jac,
                held,
                sides,
            } = self.jacobian(vs, cur, rows, ctx, prior_grad);
            h.iter_mut().for_each(|x| *x = 0.0);
            g.iter_mut().for_each(|x| *x = 0.0);
            for (r, jr) in rows.iter().zip(&jac) {
                let res = sub(cur.k[r.row], r.target);
                accumulate_row(jr, res, r.weight, n, &mut h, &mut g);
            }
            if let (Some(m), Some(pe)) = (pm, &cur.pts) {
                accumulate_points(m, pe, &pt_jac, n, &mut h, &mut g);
            }
            let mut free = Vec::with_capacity(n);
            for (i, &v) in vs.vars.iter().enumerate() {
                let (x, lo, hi, lam, x0) = self.var_info(v, &cur.state, cfg);
                h[i * n + i] += lam;
                g[i] += lam * (x - x0);
                let at_lo = x <= lo + 1e-12 && g[i] > 0.0;
                let at_hi = x >= hi - 1e-12 && g[i] < 0.0;
                if !(at_lo || at_hi || held.contains(&i)) {
                    free.push(i);
                }
            }
            if free.is_empty() {
                break;
            }
            let max_diag = free.iter().map(|&i| h[i * n + i]).fold(0.0, f64::max);
            let info: Vec<(f64, f64, f64)> = vs
                .vars
                .iter()
                .map(|&v| {
                    let (x, lo, hi, _, _) = self.var_info(v, &cur.state, cfg);
                    match v {
                        // A step stops on the kinks around the value (module docs).
                        Var::Phen(i) => {
                            let (a, b) = phen_cell(i, x, sides[i]);
                            (x, a, b)
                        }
                        _ => (x, lo, hi),
                    }
                })
                .collect();
            let mut accepted = None;
            while mu <= 1e10 {
                let Some(delta) = damped_step(&h, &g, n, &free, &info, mu, max_diag) else {
                    mu *= 10.0;
                    continue;
                };
                let trial = self.apply_step(vs, &cur.state, &delta, &info);
                let next = self.reevaluate(trial, cur, ctx);
                let ft = self.cost(&next, rows, pm, cfg);
                if ft < f {
                    accepted = Some((next, ft));
                    mu = (mu * 0.25).max(1e-12);
                    break;
                }
                mu *= 10.0;
            }
            let Some((next, ft)) = accepted else { break };
            let decrease = f - ft;
            *cur = next;
            f = ft;
            if decrease <= cfg.tolerance * (f + decrease) || self.data_cost(cur, rows, pm) < floor {
                break;
            }
        }
        iters
    }

    // -----------------------------------------------------------------------------------------
    // Solve.

    /// Fits the rig to `targets` (module docs: staged projected Levenberg–Marquardt).
    ///
    /// # Errors
    /// [`HumanError::Invalid`]: empty targets, a non-finite position or weight, a keypoint
    /// the set does not define, an invalid configuration or initial shape; generator errors.
    /// Unreachable targets are not an error: the best fit is returned.
    pub fn solve(&self, targets: &IkTargets, config: &IkConfig) -> Result<IkResult> {
        self.solve_with_points(targets, &[], config)
    }

    /// Fits the rig to `targets` and to extra surface point targets `points` (see
    /// [`PointTarget`]): the objective of the module docs plus
    /// `Σ_p w_p |P_p(Σ_m b_m x_m(θ, β, f) − p̂_p)|²` (`P_p = n̂ n̂ᵀ` for point-to-plane targets,
    /// else the identity), in the final `all` stage (both starts of the phenotype restart;
    /// with [`IkConfig::initial_state`] that is the only stage). The keypoints keep their
    /// role: the early stages fit them alone, and they initialise the global motion.
    ///
    /// **Point model.** A point is a sparse linear combination of template vertices, so it is
    /// modelled like a keypoint (module docs): `Σ_b (M_b X_pb + σ_pb t_b)` with the pairs of
    /// its skinning bones. The rest positions `x̄_v(β)` of its vertices come from a
    /// per-vertex phenotype grid (the rest meshes at the 288 grid points, kept for every
    /// vertex the topology reaches; built on the first call per set of non-fitted shape
    /// values: 288 rest meshes, ~0.15–0.3 s on 2 cores, 92 MB on the full template), so
    /// `X_pb` and `∂X_pb/∂β_i` are exact multilinear interpolations; face units add
    /// `Σ_j f_j X^{(j)}_pb`. The Jacobian is analytic as for the keypoints (bone angles,
    /// global motion, face units' rest part; phenotype from the grid) plus the same
    /// finite-difference frame parts. Building the model of a few thousand points takes a
    /// few milliseconds, so the correspondences may change between calls (ICP); variables
    /// that only points depend on (e.g. toes) join the final stage.
    ///
    /// Without points this is exactly [`IkSolver::solve`].
    ///
    /// # Errors
    /// As [`IkSolver::solve`]; [`HumanError::Invalid`] for a point with no vertices, a vertex
    /// out of range of the topology, a non-finite coefficient, position, weight or normal, a
    /// negative weight or a zero normal.
    pub fn solve_with_points(
        &self,
        targets: &IkTargets,
        points: &[PointTarget],
        config: &IkConfig,
    ) -> Result<IkResult> {
        let t_start = Instant::now();
        targets.validate()?;
        for (name, v) in [
            ("pose_prior", config.pose_prior),
            ("phenotype_prior", config.phenotype_prior),
            ("face_unit_prior", config.face_unit_prior),
            ("tolerance", config.tolerance),
            ("early_prior_scale", config.early_prior_scale),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(HumanError::Invalid(format!(
                    "IK config: `{name}` = {v} must be finite and ≥ 0"
                )));
            }
        }
        let mut template = config.initial_shape.clone().unwrap_or_default();
        template.validate().map_err(HumanError::Invalid)?;
        for name in IK_PHENOTYPE {
            if let Some(v) = template.phenotype.get_mut(name) {
                *v = v.clamp(0.0, 1.0);
            }
        }
        let all_rows: Vec<Row> = targets
            .targets
            .iter()
            .map(|t| {
                let row = self.row_of_tc[t.index].ok_or_else(|| {
                    HumanError::Invalid(format!(
                        "keypoint `{}` is not defined by the keypoint set",
                        keypoint_names()[t.index]
                    ))
                })?;
                Ok(Row {
                    row,
                    target: t.position,
                    weight: t.weight,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let fit_units = config.fit_face_units.unwrap_or_else(|| {
            targets
                .targets
                .iter()
                .any(|t| t.weight > 0.0 && KeypointGroup::of(t.index) == KeypointGroup::Face)
        });
        let n_bones = self.parents.len();
        let warm = config.initial_state.is_some();
        let mut state = match &config.initial_state {
            Some(s) => {
                if s.angles.len() != n_bones
                    || !s
                        .translation
                        .iter()
                        .chain(s.rotation.iter().flatten())
                        .all(|x| x.is_finite())
                {
                    return Err(HumanError::Invalid(format!(
                        "IK warm start: {} bone angles (expected {n_bones}) or non-finite global motion",
                        s.angles.len()
                    )));
                }
                s.clone()
            }
            None => IkState::rest(n_bones, &template),
        };
        if !fit_units && !warm {
            state.face_units = template.facial_actions;
        }
        let grid = self.grid(&template)?;
        let pm = if points.is_empty() {
            None
        } else {
            Some(self.point_model(points, &template)?)
        };
        let ctx0 = Ctx::new(&grid, None);
        let ctx_points = Ctx::new(&grid, pm.as_ref());
        let n_points = pm
            .as_ref()
            .map_or(0, |m| m.rows.iter().filter(|r| r.weight > 0.0).count());
        let mut cur = self.current(state, ctx0);

        // Initial global motion: Kabsch on the torso keypoints.
        let weighted: Vec<&IkTarget> = targets.targets.iter().filter(|t| t.weight > 0.0).collect();
        let pick = |f: &dyn Fn(usize) -> bool| -> Vec<&IkTarget> {
            weighted.iter().copied().filter(|t| f(t.index)).collect()
        };
        let mut init = pick(&|i| TORSO_KEYPOINTS.contains(&i));
        if init.len() < 3 {
            init = pick(&|i| i < FACE_OFFSET);
        }
        if init.len() < 3 {
            init = weighted.clone();
        }
        let model: Vec<V3> = init
            .iter()
            .map(|t| cur.k[self.row_of_tc[t.index].expect("checked")])
            .collect();
        let goal: Vec<V3> = init.iter().map(|t| t.position).collect();
        let w: Vec<f64> = init.iter().map(|t| t.weight).collect();
        let h0 = cur.shape.heads[0];
        let mut st = cur.state.clone();
        if warm {
            // Keep the warm start's global motion.
        } else if init.len() >= 3 {
            let rigid = rigid_align(&model, &goal, Some(&w));
            st.rotation = rigid.r;
            // R k + t = R (k − h0) + h0 + u  ⇒  u = t + R h0 − h0.
            st.translation = sub(add(rigid.t, matvec(&rigid.r, h0)), h0);
        } else {
            let ws: f64 = w.iter().sum();
            let mut d = [0.0; 3];
            for ((m, q), wi) in model.iter().zip(&goal).zip(&w) {
                d = add(d, scale(sub(*q, *m), wi / ws));
            }
            st.translation = d;
        }
        cur = self.reevaluate(st, &cur, ctx0);

        // Stages.
        let in_group = |i: usize, lo: usize, hi: usize| (lo..hi).contains(&i);
        let body_rows: Vec<Row> = all_rows
            .iter()
            .zip(&targets.targets)
            .filter(|(_, t)| {
                let i = t.index;
                i < FACE_OFFSET
                    || (in_group(i, LHAND_OFFSET, RHAND_OFFSET)
                        && HAND_ROOTS.contains(&(i - LHAND_OFFSET)))
                    || (i >= RHAND_OFFSET && HAND_ROOTS.contains(&(i - RHAND_OFFSET)))
                    || (in_group(i, FACE_OFFSET, LHAND_OFFSET)
                        && FACE_RIGID.contains(&(i - FACE_OFFSET)))
            })
            .map(|(r, _)| *r)
            .filter(|r| r.weight > 0.0)
            .collect();
        let torso_rows: Vec<Row> = all_rows
            .iter()
            .zip(&targets.targets)
            .filter(|(r, t)| TORSO_KEYPOINTS.contains(&t.index) && r.weight > 0.0)
            .map(|(r, _)| *r)
            .collect();
        let every_rows: Vec<Row> = all_rows
            .iter()
            .copied()
            .filter(|r| r.weight > 0.0)
            .collect();
        let has_face_rows = |rows: &[Row]| {
            rows.iter().any(|r| {
                self.kp.rows[r.row]
                    .tc
                    .is_some_and(|t| KeypointGroup::of(t) == KeypointGroup::Face)
            })
        };

        struct Spec<'r> {
            name: &'static str,
            global: bool,
            bones: &'r dyn Fn(&Posable) -> bool,
            phen: bool,
            units: bool,
            rows: &'r [Row],
            iters: usize,
        }
        let torso_bone = |p: &Posable| {
            let name = &self.generator.bone_names()[p.rig];
            TORSO_BONES.contains(&name.as_str())
        };
        let body_bone = |p: &Posable| p.slot < LEFT_HAND_SLOT;
        let hand_face_bone = |p: &Posable| p.slot >= LEFT_HAND_SLOT && p.slot < N_POSABLE;
        let any_bone = |_: &Posable| true;
        let specs = [
            Spec {
                name: "torso",
                global: true,
                bones: &torso_bone,
                phen: false,
                units: false,
                rows: &torso_rows,
                iters: config.stage_iterations,
            },
            Spec {
                name: "body",
                global: true,
                bones: &body_bone,
                phen: config.fit_phenotype,
                units: false,
                rows: &body_rows,
                iters: config.stage_iterations,
            },
            Spec {
                name: "hands_face",
                global: false,
                bones: &hand_face_bone,
                phen: false,
                units: fit_units,
                rows: &every_rows,
                iters: config.stage_iterations,
            },
            Spec {
                name: "all",
                global: true,
                bones: &any_bone,
                phen: config.fit_phenotype,
                units: fit_units,
                rows: &every_rows,
                iters: config.max_iterations,
            },
        ];
        let mut stages = Vec::new();
        let mut iterations = 0;
        for spec in &specs {
            if spec.rows.is_empty() || spec.iters == 0 || (warm && spec.name != "all") {
                continue;
            }
            let t = Instant::now();
            // Point targets join the final stage.
            let ctx = if spec.name == "all" { ctx_points } else { ctx0 };
            // Bones that influence a stage keypoint (or point).
            let mut influences = vec![false; n_bones];
            for r in spec.rows {
                for &c in &self.kp.rows[r.row].anc {
                    influences[c] = true;
                }
            }
            if let Some(m) = ctx.pts {
                for (row, r) in m.sk.rows.iter().zip(&m.rows) {
                    if r.weight > 0.0 {
                        for &c in &row.anc {
                            influences[c] = true;
                        }
                    }
                }
            }
            let mut vs = VarSet::new(n_bones);
            if spec.global {
                for a in 0..3 {
                    vs.push(Var::Trans(a));
                    vs.push(Var::Rot(a));
                }
            }
            for p in &self.posable {
                if !(spec.bones)(p) || !influences[p.rig] {
                    continue;
                }
                for axis in 0..3 {
                    let [lo, hi] = p.range[axis];
                    if lo < hi {
                        vs.push(Var::Angle {
                            bone: p.rig,
                            axis,
                            lo,
                            hi,
                            prior: p.prior[axis],
                        });
                    }
                }
            }
            if spec.phen {
                for i in 0..6 {
                    vs.push(Var::Phen(i));
                }
            }
            if spec.units && has_face_rows(spec.rows) {
                for j in 0..N_UNITS {
                    vs.push(Var::Unit(j));
                }
            }
            if ctx.pts.is_some() && cur.pts.is_none() {
                cur = self.reevaluate(cur.state.clone(), &cur, ctx);
            }
            let cost_before = self.cost(&cur, &every_rows, ctx.pts, config);
            let scale = if spec.name == "all" {
                1.0
            } else {
                config.early_prior_scale
            };
            let stage_config = IkConfig {
                pose_prior: config.pose_prior * scale,
                phenotype_prior: config.phenotype_prior * scale,
                face_unit_prior: config.face_unit_prior * scale,
                ..config.clone()
            };
            let it = if spec.name == "all" && spec.phen && config.phenotype_restart && !warm {
                // Second start: the same pose from the default phenotype.
                let mut st = cur.state.clone();
                st.phenotype = [0.5; 6];
                let mut other = self.reevaluate(st, &cur, ctx);
                let (rows, iters) = (spec.rows, spec.iters);
                let (a, b) = rayon::join(
                    || self.lm_stage(&mut cur, &vs, rows, &stage_config, ctx, iters),
                    || self.lm_stage(&mut other, &vs, rows, &stage_config, ctx, iters),
                );
                if self.cost(&other, &every_rows, ctx.pts, config)
                    < self.cost(&cur, &every_rows, ctx.pts, config)
                {
                    cur = other;
                }
                a + b
            } else {
                self.lm_stage(&mut cur, &vs, spec.rows, &stage_config, ctx, spec.iters)
            };
            iterations += it;
            stages.push(IkStageReport {
                name: spec.name,
                n_variables: vs.vars.len(),
                n_targets: spec.rows.len(),
                n_points: if ctx.pts.is_some() { n_points } else { 0 },
                iterations: it,
                cost_before,
                cost_after: self.cost(&cur, &every_rows, ctx.pts, config),
                seconds: t.elapsed().as_secs_f64(),
            });
        }

        // Result meshes from the generator itself.
        let cost = self.cost(&cur, &every_rows, pm.as_ref(), config);
        let state = cur.state;
        let params = self.params(&state, &template);
        let identity = self.generator.identity(&params.shape)?;
        let posed_anny = identity.pose(&params.pose);
        let posed = self.map.map(self.topology, &posed_anny.vertices);
        let rest = self.map.map(self.topology, identity.rest_vertices());
        let keypoints = self.set.evaluate(&posed);
        let mut sums = [(0.0, 0usize); 4];
        let residuals: Vec<IkResidual> = targets
            .targets
            .iter()
            .zip(&all_rows)
            .map(|(t, r)| {
                let distance = norm(sub(keypoints[r.row], t.position));
                let g = KeypointGroup::of(t.index);
                let gi = KeypointGroup::ALL.iter().position(|x| *x == g).unwrap_or(0);
                sums[gi].0 += distance;
                sums[gi].1 += 1;
                IkResidual {
                    index: t.index,
                    name: keypoint_names()[t.index].clone(),
                    distance,
                    weight: t.weight,
                }
            })
            .collect();
        let group_mean_mm = sums.map(|(s, n)| (n > 0).then(|| 1e3 * s / n as f64));
        let point_residual_mm = pm.as_ref().map(|m| {
            let (mut sum, mut count) = (0.0, 0usize);
            for (p, r) in points.iter().zip(&m.rows) {
                if r.weight > 0.0 {
                    let mut q = [0.0; 3];
                    for &(v, b) in &p.rows {
                        q = add(q, scale(posed[v as usize], b));
                    }
                    sum += norm(r.proj(sub(q, r.target)));
                    count += 1;
                }
            }
            1e3 * sum / count.max(1) as f64
        });
        Ok(IkResult {
            params,
            state,
            topology: self.topology,
            posed,
            rest,
            keypoints,
            residuals,
            group_mean_mm,
            iterations,
            stages,
            cost,
            point_residual_mm,
            seconds: t_start.elapsed().as_secs_f64(),
        })
    }
}

/// The damped Gauss–Newton step `(H + μD) δ = −g` (`D = diag(H)`, floored) over the free
/// variables, with an active-set refinement: a variable the step would take out of its
/// bounds is set onto the bound and the system is solved again for the others (at most six
/// rounds), so the step minimises the damped quadratic model on the face of the box. `info`
/// holds `(x, lo, hi)` per variable. `None` if a system is not positive definite.
fn damped_step(
    h: &[f64],
    g: &[f64],
    n: usize,
    free: &[usize],
    info: &[(f64, f64, f64)],
    mu: f64,
    max_diag: f64,
) -> Option<Vec<f64>> {
    let hij = |i: usize, j: usize| if i >= j { h[i * n + j] } else { h[j * n + i] };
    let mut active: Vec<usize> = free.to_vec();
    let mut delta = vec![0.0; n];
    let mut clamped: Vec<usize> = Vec::new();
    for _round in 0..6 {
        let m = active.len();
        if m == 0 {
            break;
        }
        let mut a = vec![0.0; m * m];
        let mut b = vec![0.0; m];
        for (p, &i) in active.iter().enumerate() {
            for (q, &j) in active[..=p].iter().enumerate() {
                a[p * m + q] = hij(i, j);
            }
            let d = h[i * n + i].max(1e-12 * max_diag).max(1e-18);
            a[p * m + p] += mu * d;
            b[p] = -g[i] - clamped.iter().map(|&j| hij(i, j) * delta[j]).sum::<f64>();
        }
        if !cholesky_solve(&mut a, m, &mut b) {
            return None;
        }
        let mut out = Vec::new();
        for (p, &i) in active.iter().enumerate() {
            let (x, lo, hi) = info[i];
            delta[i] = b[p];
            if x + b[p] < lo {
                delta[i] = lo - x;
                out.push(i);
            } else if x + b[p] > hi {
                delta[i] = hi - x;
                out.push(i);
            }
        }
        if out.is_empty() {
            break;
        }
        active.retain(|i| !out.contains(i));
        clamped.extend(out);
    }
    Some(delta)
}

/// Solves `A x = b` in place for a symmetric positive definite `A` (`n × n`, row-major, lower
/// triangle read) by Cholesky `A = L Lᵀ`; `b` becomes `x`. False if `A` is not numerically
/// positive definite.
fn cholesky_solve(a: &mut [f64], n: usize, b: &mut [f64]) -> bool {
    for j in 0..n {
        let (upper, lower) = a.split_at_mut((j + 1) * n);
        let rj = &mut upper[j * n..];
        let d = rj[j] - rj[..j].iter().map(|x| x * x).sum::<f64>();
        if d.is_nan() || d <= 0.0 {
            return false;
        }
        let dj = d.sqrt();
        rj[j] = dj;
        let rj = &rj[..j];
        for ri in lower.chunks_exact_mut(n) {
            let s: f64 = ri[..j].iter().zip(rj).map(|(x, y)| x * y).sum();
            ri[j] = (ri[j] - s) / dj;
        }
    }
    for i in 0..n {
        let s: f64 = a[i * n..i * n + i]
            .iter()
            .zip(&b[..i])
            .map(|(x, y)| x * y)
            .sum();
        b[i] = (b[i] - s) / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= a[k * n + i] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    true
}
