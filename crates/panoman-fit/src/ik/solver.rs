//! [`IkSolver`]: construction, the generator parameters of a state, evaluation of a state,
//! and the staged solve.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use panoman_human::generator::Generator;
use panoman_human::keypoints::{FACE_OFFSET, KeypointGroup, KeypointSet, keypoint_names};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::{GeneratorParams, PoseParams, ShapeParams};
use panoman_human::rig::{self, Affine};
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{IDENTITY, M3, V3, add, matmul, matvec, norm, scale, sub};

use super::grid::{PhenGrid, Surface, VertexGrid};
use super::keypoint_model::{
    Ctx, Current, Kin, PointModel, Posable, Relevant, ShapeEval, Skinned, add_unit_terms, anny_row,
    frame_units, posable_of, rows_into, skinned_keypoints, unit_bases, unit_joint_moves,
};
use super::lm::Row;
use super::stages::{StagePlan, StageRows, TORSO_KEYPOINTS};
use super::targets::{IkTarget, IkTargets, PointTarget};
use super::{IK_PHENOTYPE, IkConfig, IkResidual, IkResult, IkState};
use crate::error::{FitError, Result};

/// Inverse kinematics of the generator's LBS rig to the keypoints of one topology (module
/// docs). Built once per generator, topology and keypoint set; [`IkSolver::solve`] can then be
/// called any number of times (also from several threads).
pub struct IkSolver {
    pub(super) generator: Arc<Generator>,
    pub(super) map: Arc<TopologyMap>,
    pub(super) topology: OutputTopology,
    pub(super) set: KeypointSet,
    pub(super) row_of_tc: Vec<Option<usize>>,
    pub(super) parents: Vec<Option<usize>>,
    /// Relevant vertices: rest positions needed (keypoint vertices and joint regressors), as
    /// kept-vertex indices of the generator.
    pub(super) rel_kept: Vec<u32>,
    pub(super) head_rel: Vec<Vec<u32>>,
    pub(super) tail_rel: Vec<Vec<u32>>,
    /// The keypoint rows (`coef` indexes `rel_kept`).
    pub(super) kp: Skinned,
    /// Per unit: `(bone, Δhead, Δtail)` per unit value.
    pub(super) unit_joints: Vec<Vec<(usize, V3, V3)>>,
    /// Units whose joint motion changes the frame of a posable bone or the root.
    pub(super) frame_units: Vec<usize>,
    pub(super) posable: Vec<Posable>,
    /// Phenotype grids per set of non-fitted shape values (see [`IkSolver::grid`]).
    pub(super) grids: Mutex<Vec<(String, Arc<PhenGrid>)>>,
    /// Surface data of point targets (see [`IkSolver::surface`]), built on first use.
    pub(super) surface: Mutex<Option<Arc<Surface>>>,
    /// Per-vertex phenotype grids of point targets (see [`IkSolver::vertex_grid`]).
    pub(super) vertex_grids: Mutex<Vec<(String, Arc<VertexGrid>)>>,
    pub(super) setup_seconds: f64,
}

pub(super) fn rel_mean(idx: &[u32], pos: &[V3]) -> V3 {
    let mut s = [0.0; 3];
    for &k in idx {
        let p = pos[k as usize];
        s = [s[0] + p[0], s[1] + p[1], s[2] + p[2]];
    }
    let n = idx.len() as f64;
    [s[0] / n, s[1] / n, s[2] / n]
}

/// `Rz(z)·Ry(y)·Rx(x)` of radians (identity for zero angles).
pub(super) fn euler_rad(e: [f64; 3]) -> M3 {
    if e == [0.0; 3] {
        IDENTITY
    } else {
        panoman_mesh::rotation::euler_xyz(e)
    }
}

impl IkSolver {
    /// Precomputes the keypoint model of `keypoints` (a set on `topology`, e.g.
    /// [`panoman_human::keypoints::KeypointDefinitions::set`]): the keypoint rows composed with the
    /// topology map onto Anny's output vertices, their skinning bones `σ_kb` and coefficient
    /// lists, the ancestor sets `A_k` with `S_kc`, the face units' `X^{(j)}_kb` and joint
    /// displacements (53 rest meshes of the generator), and the phenotype grid of the default
    /// shape (288 rest meshes), all in parallel. About 40–80 ms on 2 cores.
    ///
    /// # Errors
    /// [`FitError::Invalid`]: the set is invalid or not on `topology`; generator errors.
    pub fn new(
        generator: Arc<Generator>,
        map: Arc<TopologyMap>,
        topology: OutputTopology,
        keypoints: &KeypointSet,
    ) -> Result<IkSolver> {
        let t0 = Instant::now();
        keypoints
            .validate()
            .map_err(|e| FitError::Invalid(format!("keypoint set: {e}")))?;
        if keypoints.n_vertices != map.n_vertices(topology) {
            return Err(FitError::Invalid(format!(
                "the keypoint set has {} vertices, topology `{topology}` has {}",
                keypoints.n_vertices,
                map.n_vertices(topology)
            )));
        }
        let rig = generator.rig();
        let n_bones = rig.len();
        let parents: Vec<Option<usize>> = generator.bone_parents().to_vec();
        if parents.first() != Some(&None) || parents.iter().skip(1).any(Option::is_none) {
            return Err(FitError::Invalid(
                "the rig must have bone 0 as its only root".into(),
            ));
        }

        // Keypoint rows on anny (output) vertices.
        let anny_rows: Vec<Vec<(u32, f64)>> = keypoints
            .rows
            .iter()
            .map(|row| anny_row(&map, topology, row))
            .collect();
        let rel = Relevant::new(&generator, &anny_rows);
        // Face-unit bases at the relevant vertices: B_j = rest(f = e_j) − rest(0).
        let unit_dense = unit_bases(&generator, &rel.kept)?;
        let unit_joints = unit_joint_moves(&unit_dense, &rel, n_bones);
        let posable = posable_of(rig)?;
        let frame_units = frame_units(&posable, &unit_joints, n_bones);
        let (kp, row_of_tc) = skinned_keypoints(
            &anny_rows,
            &keypoints.names,
            &rel,
            generator.skin_weights(),
            &parents,
            &unit_dense,
        );
        let Relevant {
            kept: rel_kept,
            head: head_rel,
            tail: tail_rel,
            ..
        } = rel;
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

    /// The generator's posed mesh of `params` on the solver's topology (metres), as
    /// [`IkResult::posed`] is made.
    ///
    /// # Errors
    /// Invalid shape parameters.
    pub fn posed_mesh(&self, params: &GeneratorParams) -> Result<Vec<V3>> {
        let identity = self.generator.identity(&params.shape)?;
        let posed = identity.pose(&params.pose);
        Ok(self.map.map(self.topology, &posed.vertices))
    }

    /// The generator's posed meshes of `states` (solver topology, metres), all with the one
    /// generator shape `shape` (its identity built once): [`IkSolver::pose_params`] of each
    /// state; the states' phenotype values and face units are not used.
    ///
    /// # Errors
    /// Invalid shape parameters.
    pub fn posed_meshes(&self, shape: &ShapeParams, states: &[IkState]) -> Result<Vec<Vec<V3>>> {
        let identity = self.generator.identity(shape)?;
        Ok(states
            .iter()
            .map(|st| {
                let posed = identity.pose(&self.pose_params(st));
                self.map.map(self.topology, &posed.vertices)
            })
            .collect())
    }

    /// The solver's keypoints on a mesh of its topology, by TC-133 index (`None` for a
    /// keypoint its set does not define).
    ///
    /// # Errors
    /// A vertex count other than the topology's.
    pub fn keypoints_on(&self, mesh: &[V3]) -> Result<Vec<Option<V3>>> {
        let k = self.set.try_evaluate(mesh)?;
        Ok(self.row_of_tc.iter().map(|r| r.map(|r| k[r])).collect())
    }

    /// [`IkSolver::posed_mesh`] with dual-quaternion skinning
    /// ([`panoman_human::generator::Identity::pose_dqs`]).
    ///
    /// # Errors
    /// Invalid shape parameters.
    pub fn posed_mesh_dqs(&self, params: &GeneratorParams) -> Result<Vec<V3>> {
        let identity = self.generator.identity(&params.shape)?;
        let posed = identity.pose_dqs(&params.pose);
        Ok(self.map.map(self.topology, &posed.vertices))
    }

    /// [`IkSolver::shape_params`] and [`IkSolver::pose_params`] together.
    pub fn params(&self, state: &IkState, template: &ShapeParams) -> GeneratorParams {
        GeneratorParams {
            shape: self.shape_params(state, template),
            pose: self.pose_params(state),
        }
    }
    /// Frames from heads and tails: `(local, inv_rest)`.
    /// [`IkSolver::frames`] after only the joints of the bones `moved` changed, from the
    /// local frames and inverse rest frames of `base` (the same joints but those): the rest
    /// frames of the moved bones are recomputed, and the local frames of those bones and of
    /// their children. Equal to `frames(heads, tails)` bit for bit (each frame comes from
    /// the same [`rig::rest_orientation`] call).
    pub(super) fn frames_moved(
        &self,
        heads: &[V3],
        tails: &[V3],
        moved: &[bool],
        base: &ShapeEval,
    ) -> (Vec<Affine>, Vec<Affine>) {
        let bones = &self.generator.rig().bones;
        let frame = |c: usize| {
            let m = if bones[c].parent.is_none() {
                Affine::IDENTITY.m
            } else {
                rig::rest_orientation(heads[c], tails[c], bones[c].roll)
            };
            Affine::new(m, heads[c])
        };
        let mut inv = base.inv_rest.clone();
        for (c, _) in moved.iter().enumerate().filter(|m| *m.1) {
            inv[c] = frame(c).inverse_rigid();
        }
        let mut local = base.local.clone();
        for (c, p) in self.parents.iter().enumerate() {
            if let Some(p) = *p
                && (moved[c] || moved[p])
            {
                local[c] = inv[p].compose(&frame(c));
            }
        }
        (local, inv)
    }

    pub(super) fn frames(&self, heads: &[V3], tails: &[V3]) -> (Vec<Affine>, Vec<Affine>) {
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
    pub(super) fn shape_eval(
        &self,
        grid: &PhenGrid,
        beta: &[f64; 6],
        units: &[f64; 52],
    ) -> ShapeEval {
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
    pub(super) fn kinematics(&self, shape: &ShapeEval, st: &IkState, kin: &mut Kin) {
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

    pub(super) fn keypoints_into(&self, shape: &ShapeEval, kin: &Kin, out: &mut Vec<V3>) {
        rows_into(&self.kp, &shape.x, kin, out);
    }

    pub(super) fn current(&self, state: IkState, ctx: Ctx<'_>) -> Current {
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
    pub(super) fn reevaluate(&self, state: IkState, prev: &Current, ctx: Ctx<'_>) -> Current {
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

    /// Fits the rig to `targets` (module docs: staged projected Levenberg–Marquardt).
    ///
    /// # Errors
    /// [`FitError::Invalid`]: empty targets, a non-finite position or weight, a keypoint
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
    /// As [`IkSolver::solve`]; [`FitError::Invalid`] for a point with no vertices, a vertex
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
        let template = solve_template(config)?;
        let all_rows = self.target_rows(targets)?;
        let fit_units = config.fit_face_units.unwrap_or_else(|| {
            targets
                .targets
                .iter()
                .any(|t| t.weight > 0.0 && KeypointGroup::of(t.index) == KeypointGroup::Face)
        });
        let warm = config.initial_state.is_some();
        let state = self.initial_state(config, &template, fit_units)?;
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
        let cur = self.current(state, ctx0);
        let mut cur = self.initial_placement(cur, targets, warm, ctx0);

        let rows = StageRows::new(&all_rows, targets);
        let plan = StagePlan {
            rows: &rows,
            config,
            fit_units,
            warm,
            ctx0,
            ctx_points,
            n_points,
        };
        let (stages, iterations) = self.run_stages(&mut cur, &plan);

        // Result meshes from the generator itself.
        let cost = self.cost(&cur, rows.every(), pm.as_ref(), config);
        let state = cur.state;
        let params = self.params(&state, &template);
        let identity = self.generator.identity(&params.shape)?;
        let posed_anny = identity.pose(&params.pose);
        let posed = self.map.map(self.topology, &posed_anny.vertices);
        let rest = self.map.map(self.topology, identity.rest_vertices());
        let keypoints = self.set.evaluate(&posed);
        let (residuals, group_mean_mm) = keypoint_residuals(targets, &all_rows, &keypoints);
        let point_residual_mm = pm.as_ref().map(|m| point_residual_mm(m, points, &posed));
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

    /// The set row of every target (target order).
    ///
    /// # Errors
    /// [`FitError::Invalid`] for a keypoint the set does not define.
    fn target_rows(&self, targets: &IkTargets) -> Result<Vec<Row>> {
        targets
            .targets
            .iter()
            .map(|t| {
                let row = self.row_of_tc[t.index].ok_or_else(|| {
                    FitError::Invalid(format!(
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
            .collect()
    }

    /// The starting state: the warm start of `config` (checked), else the rest pose with the
    /// shape of `template` (its face units only when they are not fitted).
    ///
    /// # Errors
    /// [`FitError::Invalid`] for a warm start of the wrong size or with a non-finite global
    /// motion, a malformed temporal prior, or a forearm roll range outside (0°, 180°].
    fn initial_state(
        &self,
        config: &IkConfig,
        template: &ShapeParams,
        fit_units: bool,
    ) -> Result<IkState> {
        let n_bones = self.parents.len();
        if let Some(t) = &config.temporal
            && (t.angles.len() != n_bones
                || t.weights.len() != n_bones
                || !t.angles.iter().flatten().all(|x| x.is_finite()))
        {
            return Err(FitError::Invalid(format!(
                "IK temporal prior: {} reference bone angles and {} weights (expected {n_bones} each) or non-finite angles",
                t.angles.len(),
                t.weights.len()
            )));
        }
        if let Some(l) = config.forearm_roll_deg
            && !(l.is_finite() && l > 0.0 && l <= 180.0)
        {
            return Err(FitError::Invalid(format!(
                "IK forearm roll range ±{l}° (must be in (0, 180])"
            )));
        }
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
                    return Err(FitError::Invalid(format!(
                        "IK warm start: {} bone angles (expected {n_bones}) or non-finite global motion",
                        s.angles.len()
                    )));
                }
                s.clone()
            }
            None => IkState::rest(n_bones, template),
        };
        if !fit_units && !warm {
            state.face_units = template.facial_actions;
        }
        Ok(state)
    }

    /// The initial global motion (module docs): weighted Kabsch of the model's torso
    /// keypoints onto their targets (all body keypoints, then all targets, if fewer than
    /// three torso targets have weight > 0; a translation of centroids below three points).
    /// A warm start keeps its global motion.
    fn initial_placement(
        &self,
        cur: Current,
        targets: &IkTargets,
        warm: bool,
        ctx0: Ctx<'_>,
    ) -> Current {
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
        self.reevaluate(st, &cur, ctx0)
    }
}

/// Checks the numbers of `config` and returns the template shape of the solve: its initial
/// shape (or the default), the fitted phenotype values clamped to `[0, 1]`.
///
/// # Errors
/// [`FitError::Invalid`] for a negative or non-finite prior or tolerance, or an invalid
/// initial shape.
fn solve_template(config: &IkConfig) -> Result<ShapeParams> {
    for (name, v) in [
        ("pose_prior", config.pose_prior),
        (
            "temporal.weights",
            config.temporal.as_ref().map_or(0.0, |t| {
                t.weights
                    .iter()
                    .copied()
                    .find(|w| !(w.is_finite() && *w >= 0.0))
                    .unwrap_or(0.0)
            }),
        ),
        ("phenotype_prior", config.phenotype_prior),
        ("face_unit_prior", config.face_unit_prior),
        ("tolerance", config.tolerance),
        ("early_prior_scale", config.early_prior_scale),
    ] {
        if !v.is_finite() || v < 0.0 {
            return Err(FitError::Invalid(format!(
                "IK config: `{name}` = {v} must be finite and ≥ 0"
            )));
        }
    }
    let mut template = config.initial_shape.clone().unwrap_or_default();
    template.validate()?;
    for name in IK_PHENOTYPE {
        if let Some(v) = template.phenotype.get_mut(name) {
            *v = v.clamp(0.0, 1.0);
        }
    }
    Ok(template)
}

/// One residual per target (target order) on the fitted `keypoints` (set order, `rows` the
/// targets' set rows) and the mean residual per group in mm.
fn keypoint_residuals(
    targets: &IkTargets,
    rows: &[Row],
    keypoints: &[V3],
) -> (Vec<IkResidual>, [Option<f64>; 5]) {
    let mut sums = [(0.0, 0usize); 5];
    let residuals: Vec<IkResidual> = targets
        .targets
        .iter()
        .zip(rows)
        .map(|(t, r)| {
            let distance = norm(sub(keypoints[r.row], t.position));
            let gi = KeypointGroup::of(t.index).position();
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
    (residuals, group_mean_mm)
}

/// Mean distance in mm of the point targets with weight > 0 to their points on `posed`
/// (along the normal for point-to-plane targets).
fn point_residual_mm(m: &PointModel, points: &[PointTarget], posed: &[V3]) -> f64 {
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
}
