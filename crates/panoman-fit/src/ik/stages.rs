//! The stage policy of the solve (module docs, "Solver"): which variables and which targets
//! each stage of the staged Levenberg–Marquardt fits, as the [`Stage`] type, and the loop that
//! runs them.

use std::time::Instant;

use panoman_human::keypoints::{FACE_OFFSET, KeypointGroup, LHAND_OFFSET, RHAND_OFFSET};
use panoman_human::sampling::{LEFT_HAND_SLOT, N_POSABLE};

use super::keypoint_model::{Ctx, Current, Posable};
use super::lm::{Row, Var, VarSet};
use super::solver::IkSolver;
use super::targets::IkTargets;
use super::{IkConfig, IkStageReport, N_UNITS};

/// TC-133 indices of the torso keypoints: neck, body_center, shoulders, hips.
pub(super) const TORSO_KEYPOINTS: [usize; 6] = [0, 2, 3, 6, 9, 12];

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

/// One stage of the solve, in Total Capture's order ([`Stage::ORDER`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Stage {
    /// Global motion, spine, clavicles, shoulders — on the torso keypoints.
    Torso,
    /// Global motion, the body bones, phenotype — on the body keypoints, the hand roots and
    /// the rigid face points.
    Body,
    /// The finger bones, jaw, eyes and face units — on all targets, the body fixed.
    HandsFace,
    /// Every variable on all targets, and the point targets.
    All,
}

impl Stage {
    /// The stages in the order they run.
    pub(super) const ORDER: [Stage; 4] = [Stage::Torso, Stage::Body, Stage::HandsFace, Stage::All];

    /// The name in [`IkStageReport::name`].
    pub(super) fn name(self) -> &'static str {
        match self {
            Stage::Torso => "torso",
            Stage::Body => "body",
            Stage::HandsFace => "hands_face",
            Stage::All => "all",
        }
    }

    /// The final stage: point targets join it, its priors are not scaled, a warm start runs
    /// only it, and the phenotype restart applies to it.
    fn is_final(self) -> bool {
        self == Stage::All
    }

    /// Whether the global rotation and translation are free.
    fn fits_global(self) -> bool {
        self != Stage::HandsFace
    }

    /// Whether the six phenotype values are free.
    fn fits_phenotype(self, config: &IkConfig) -> bool {
        matches!(self, Stage::Body | Stage::All) && config.fit_phenotype
    }

    /// Whether the face units are free (given that the solve fits them at all).
    fn fits_units(self, fit_units: bool) -> bool {
        matches!(self, Stage::HandsFace | Stage::All) && fit_units
    }

    /// Whether the angles of posable bone `p` are free (`bone_names`: the rig's).
    fn fits_bone(self, p: &Posable, bone_names: &[String]) -> bool {
        match self {
            Stage::Torso => TORSO_BONES.contains(&bone_names[p.rig].as_str()),
            Stage::Body => p.slot < LEFT_HAND_SLOT,
            Stage::HandsFace => p.slot >= LEFT_HAND_SLOT && p.slot < N_POSABLE,
            Stage::All => true,
        }
    }

    /// The stage's iteration cap.
    fn iterations(self, config: &IkConfig) -> usize {
        if self.is_final() {
            config.max_iterations
        } else {
            config.stage_iterations
        }
    }

    /// The factor on the three priors.
    fn prior_scale(self, config: &IkConfig) -> f64 {
        if self.is_final() {
            1.0
        } else {
            config.early_prior_scale
        }
    }
}

/// The target rows of the stages (weight > 0 only).
pub(super) struct StageRows {
    torso: Vec<Row>,
    body: Vec<Row>,
    every: Vec<Row>,
}

impl StageRows {
    /// Splits `all_rows` (one per target of `targets`, same order) by stage.
    pub(super) fn new(all_rows: &[Row], targets: &IkTargets) -> StageRows {
        let in_group = |i: usize, lo: usize, hi: usize| (lo..hi).contains(&i);
        let body: Vec<Row> = all_rows
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
        let torso: Vec<Row> = all_rows
            .iter()
            .zip(&targets.targets)
            .filter(|(r, t)| TORSO_KEYPOINTS.contains(&t.index) && r.weight > 0.0)
            .map(|(r, _)| *r)
            .collect();
        let every: Vec<Row> = all_rows
            .iter()
            .copied()
            .filter(|r| r.weight > 0.0)
            .collect();
        StageRows { torso, body, every }
    }

    /// The rows `stage` fits.
    fn of(&self, stage: Stage) -> &[Row] {
        match stage {
            Stage::Torso => &self.torso,
            Stage::Body => &self.body,
            Stage::HandsFace | Stage::All => &self.every,
        }
    }

    /// Every row with weight > 0 (the rows of the reported objective).
    pub(super) fn every(&self) -> &[Row] {
        &self.every
    }
}

/// What the stage loop needs besides the current evaluation.
pub(super) struct StagePlan<'p> {
    pub(super) rows: &'p StageRows,
    pub(super) config: &'p IkConfig,
    /// The solve fits the face units.
    pub(super) fit_units: bool,
    /// Warm start: only the final stage runs, without the phenotype restart.
    pub(super) warm: bool,
    /// Evaluation context of the early stages (keypoints only).
    pub(super) ctx0: Ctx<'p>,
    /// Evaluation context of the final stage (with the point targets, if any).
    pub(super) ctx_points: Ctx<'p>,
    /// Number of point targets with weight > 0.
    pub(super) n_points: usize,
}

impl IkSolver {
    /// Runs the stages in order on `cur`, skipping those without rows or iterations (and,
    /// warm, all but the final one). Returns the stage reports and the total iterations.
    pub(super) fn run_stages(
        &self,
        cur: &mut Current,
        plan: &StagePlan<'_>,
    ) -> (Vec<IkStageReport>, usize) {
        let config = plan.config;
        let every = plan.rows.every();
        let mut stages = Vec::new();
        let mut iterations = 0;
        for stage in Stage::ORDER {
            let rows = plan.rows.of(stage);
            if rows.is_empty() || stage.iterations(config) == 0 || (plan.warm && !stage.is_final())
            {
                continue;
            }
            let t = Instant::now();
            // Point targets join the final stage.
            let ctx = if stage.is_final() {
                plan.ctx_points
            } else {
                plan.ctx0
            };
            let vs = self.stage_variables(stage, rows, ctx, plan.config, plan.fit_units);
            if ctx.pts.is_some() && cur.pts.is_none() {
                *cur = self.reevaluate(cur.state.clone(), cur, ctx);
            }
            let cost_before = self.cost(cur, every, ctx.pts, config);
            let it = self.run_stage(stage, cur, &vs, rows, ctx, plan);
            iterations += it;
            stages.push(IkStageReport {
                name: stage.name(),
                n_variables: vs.vars.len(),
                n_targets: rows.len(),
                n_points: if ctx.pts.is_some() { plan.n_points } else { 0 },
                iterations: it,
                cost_before,
                cost_after: self.cost(cur, every, ctx.pts, config),
                seconds: t.elapsed().as_secs_f64(),
            });
        }
        (stages, iterations)
    }

    /// The free variables of `stage`: those of its policy that a stage row (or a point of
    /// `ctx` with weight > 0) depends on structurally.
    fn stage_variables(
        &self,
        stage: Stage,
        rows: &[Row],
        ctx: Ctx<'_>,
        config: &IkConfig,
        fit_units: bool,
    ) -> VarSet {
        let n_bones = self.parents.len();
        // Bones that influence a stage keypoint (or point).
        let mut influences = vec![false; n_bones];
        for r in rows {
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
        if stage.fits_global() {
            for a in 0..3 {
                vs.push(Var::Trans(a));
                vs.push(Var::Rot(a));
            }
        }
        let bone_names = self.generator.bone_names();
        for p in &self.posable {
            if !stage.fits_bone(p, bone_names) || !influences[p.rig] {
                continue;
            }
            for axis in 0..3 {
                let ([lo, hi], prior) = p.axis(axis, config);
                if lo < hi {
                    vs.push(Var::Angle {
                        bone: p.rig,
                        axis,
                        lo,
                        hi,
                        prior,
                    });
                }
            }
        }
        if stage.fits_phenotype(config) {
            for i in 0..6 {
                vs.push(Var::Phen(i));
            }
        }
        if stage.fits_units(fit_units) && self.has_face_rows(rows) {
            for j in 0..N_UNITS {
                vs.push(Var::Unit(j));
            }
        }
        vs
    }

    /// True if a row is a face keypoint.
    fn has_face_rows(&self, rows: &[Row]) -> bool {
        rows.iter().any(|r| {
            self.kp.rows[r.row]
                .tc
                .is_some_and(|t| KeypointGroup::of(t) == KeypointGroup::Face)
        })
    }

    /// The Levenberg–Marquardt iterations of one stage with its scaled priors; the final
    /// stage with the phenotype restart runs from two starts in parallel (the staged state and
    /// the same pose at the default phenotype) and keeps the lower objective. Returns the
    /// iterations (both starts counted).
    fn run_stage(
        &self,
        stage: Stage,
        cur: &mut Current,
        vs: &VarSet,
        rows: &[Row],
        ctx: Ctx<'_>,
        plan: &StagePlan<'_>,
    ) -> usize {
        let config = plan.config;
        let scale = stage.prior_scale(config);
        let stage_config = IkConfig {
            pose_prior: config.pose_prior * scale,
            phenotype_prior: config.phenotype_prior * scale,
            face_unit_prior: config.face_unit_prior * scale,
            ..config.clone()
        };
        let iters = stage.iterations(config);
        if stage.is_final()
            && stage.fits_phenotype(config)
            && config.phenotype_restart
            && !plan.warm
        {
            // Second start: the same pose from the default phenotype.
            let mut st = cur.state.clone();
            st.phenotype = [0.5; 6];
            let mut other = self.reevaluate(st, cur, ctx);
            let (a, b) = rayon::join(
                || self.lm_stage(&mut *cur, vs, rows, &stage_config, ctx, iters),
                || self.lm_stage(&mut other, vs, rows, &stage_config, ctx, iters),
            );
            let every = plan.rows.every();
            if self.cost(&other, every, ctx.pts, config) < self.cost(cur, every, ctx.pts, config) {
                *cur = other;
            }
            a + b
        } else {
            self.lm_stage(cur, vs, rows, &stage_config, ctx, iters)
        }
    }
}
