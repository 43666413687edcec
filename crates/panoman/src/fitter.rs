//! [`Fitter`]: PanoMan (or the LBS baseline) fitted to [`Targets`], one frame at a time.
use std::collections::BTreeMap;

use panoman_fit::fit::{FitOptions, GroupResidual, StageReport, keypoint_residuals};
use panoman_fit::ik::IkResult;
use panoman_fit::quality::{IkAttempt, QualityOptions, Verdict};
use panoman_fit::{
    Constraints, FrameSolver, ShapeCalibration, ShapeCalibrationOptions, calibrate_shape,
    ik_config_for_noise,
};
use panoman_human::assets;
use panoman_human::keypoints::KeypointGroup;
use panoman_human::params::{GeneratorParams, ShapeParams};
use panoman_mesh::geom::V3;
use panoman_model::model::Params;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::model::Model;
use crate::targets::Targets;

/// Which model is fitted. In files its lowercase name (`panoman`, `lbs`); the variants are
/// declared in the order of their names, so that a map keyed by methods lists them as one
/// keyed by names would.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The LBS rig alone (skeletal IK with pose, phenotype and face units): the baseline.
    Lbs,
    /// Skeletal IK of the LBS rig (the initializer), then the discrete-shell fit toward the
    /// model's guidance pose `B_P(α, β)` (PanoMan §5).
    #[default]
    PanoMan,
}

/// Motion data θ: local Euler angles (radians, `R = Rz·Ry·Rx`) by rig bone name; through the
/// model's motion MLP they constrain the body coefficients (`β_B ← (β_LS + τ β_θ)/(1 + τ)`).
pub type MotionData = BTreeMap<String, [f64; 3]>;

/// How one fit is run.
#[derive(Clone, Debug)]
pub struct FitRequest {
    /// PanoMan or the LBS baseline. Default PanoMan.
    pub method: Method,
    /// Expected keypoint noise σ (metres per coordinate): the initializer's pose, shape and
    /// expression priors grow with σ² ([`panoman_fit::ik_config_for_noise`]). Default 0.
    pub keypoint_sigma: f64,
    /// λ_K: keypoint weight of the shell fit (dimensionless). Default 10.
    pub keypoint_weight: f64,
    /// Parameter edits held fixed: α when non-empty, and the β blocks present.
    pub fixed: Option<Params>,
    /// Motion data θ (PanoMan only) and its weight τ_θ ≥ 0 (default 1).
    pub motion: Option<MotionData>,
    /// See `motion`.
    pub motion_weight: f64,
}

impl Default for FitRequest {
    fn default() -> Self {
        let o = FitOptions::default();
        FitRequest {
            method: Method::PanoMan,
            keypoint_sigma: 0.0,
            keypoint_weight: o.keypoint_weight,
            fixed: None,
            motion: None,
            motion_weight: o.motion_weight,
        }
    }
}

impl FitRequest {
    fn check(&self) -> Result<()> {
        if !(self.keypoint_sigma >= 0.0 && self.keypoint_sigma.is_finite()) {
            return Err(Error::Invalid(
                "keypoint sigma must be a finite value ≥ 0 (metres)".into(),
            ));
        }
        if !(self.motion_weight >= 0.0 && self.motion_weight.is_finite()) {
            return Err(Error::Invalid(
                "motion weight must be a finite value ≥ 0".into(),
            ));
        }
        if !(self.keypoint_weight > 0.0 && self.keypoint_weight.is_finite()) {
            return Err(Error::Invalid(
                "keypoint weight must be finite and > 0".into(),
            ));
        }
        if self.method == Method::Lbs && self.motion.is_some() {
            return Err(Error::Invalid(
                "motion data constrains PanoMan's β_B; it does not apply to the LBS baseline"
                    .into(),
            ));
        }
        Ok(())
    }

    /// The shell-fit options of this request.
    pub(crate) fn options(&self) -> FitOptions {
        FitOptions {
            keypoint_weight: self.keypoint_weight,
            motion_weight: self.motion_weight,
            quality: self.quality(),
            ..FitOptions::default()
        }
    }

    /// The quality thresholds of this request (noise level `keypoint_sigma`).
    pub(crate) fn quality(&self) -> QualityOptions {
        QualityOptions::for_noise(self.keypoint_sigma)
    }
}

/// One stage of the skeletal IK (`torso`, `body`, `hands_face`, `all`, ICP passes).
#[derive(Clone, Debug, Serialize)]
pub struct IkStage {
    /// Stage name.
    pub name: String,
    /// Wall time (s).
    pub seconds: f64,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
    /// Free variables.
    pub variables: usize,
    /// Objective before the stage.
    pub cost_before: f64,
    /// Objective after the stage.
    pub cost_after: f64,
}

/// What the skeletal IK (initializer, or the LBS baseline itself) did.
#[derive(Clone, Debug, Serialize)]
pub struct IkReport {
    /// Wall time (s), skeletal ICP passes included.
    pub seconds: f64,
    /// Levenberg–Marquardt iterations over all stages.
    pub iterations: usize,
    /// Mean keypoint distance after the IK (mm).
    pub keypoint_mean_mm: f64,
    /// Per stage.
    pub stages: Vec<IkStage>,
}

impl IkReport {
    fn of(r: &IkResult) -> IkReport {
        IkReport {
            seconds: r.seconds,
            iterations: r.iterations,
            keypoint_mean_mm: r.mean_residual_mm(),
            stages: r
                .stages
                .iter()
                .map(|s| IkStage {
                    name: s.name.to_string(),
                    seconds: s.seconds,
                    iterations: s.iterations,
                    variables: s.n_variables,
                    cost_before: s.cost_before,
                    cost_after: s.cost_after,
                })
                .collect(),
        }
    }
}

/// Everything a fit reports (the layout of `report.json`, see `docs/formats.md`).
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    /// The method fitted.
    pub method: Method,
    /// Seconds spent before the first iteration (model load, rig, solvers), when the caller
    /// measured it (the CLI does).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub setup_seconds: Option<f64>,
    /// The skeletal IK.
    pub ik: IkReport,
    /// The shell fit's stages (PanoMan only): time, LM iterations tried/accepted, energies.
    pub stages: Vec<StageReport>,
    /// Wall time of the shell fit (s; 0 for LBS).
    pub fit_seconds: f64,
    /// IK + shell fit (s).
    pub total_seconds: f64,
    /// Keypoint residual per group (`body`, `face`, `left_hand`, `right_hand`; mm).
    pub keypoint_residuals: BTreeMap<KeypointGroup, GroupResidual>,
    /// The quality check (flattened into report.json): `converged`, `reason` when not,
    /// the `thresholds` (mm), whether the initializer was `retried` and its `ik_attempts`
    /// (docs/design/shell-fit.md §7). A fit with `converged: false` is still returned; the
    /// CLI warns and exits 3.
    #[serde(flatten)]
    pub verdict: Verdict,
}

impl FitReport {
    /// Whether the fit passed the quality check ([`FitReport::verdict`]).
    pub fn converged(&self) -> bool {
        self.verdict.converged
    }

    /// Shell LM steps (tried, accepted) over all stages.
    pub fn steps(&self) -> (usize, usize) {
        self.stages
            .iter()
            .fold((0, 0), |(t, a), s| (t + s.iterations, a + s.accepted))
    }
}

/// The result of one fit.
#[derive(Clone, Debug)]
pub struct FitOutput {
    /// Fitted vertices (the model's topology, metres).
    pub vertices: Vec<V3>,
    /// PanoMan parameters (α, β and the rigid placement; `None` for the LBS baseline).
    pub params: Option<Params>,
    /// The rig's parameters from the skeletal IK (phenotype, face units, bone angles).
    pub rig_params: GeneratorParams,
    /// The report.
    pub report: FitReport,
}

/// Fits a [`Model`] (its rig, IK solver and shell solver built once; reuse it for many
/// frames). `fit` takes `&mut self` (solver workspaces); make one per thread.
pub struct Fitter {
    model: Model,
    solver: FrameSolver,
}

impl Fitter {
    /// Builds the fitting state: the LBS rig (from the model file; model files without an
    /// embedded rig read it from the asset tree, `$PANOMAN_ASSETS` or the user cache), its IK
    /// solver, and the shell solver sharing the model's topology setup.
    ///
    /// # Errors
    /// The model has no usable rig (and the assets are missing); solver setup failures.
    pub fn new(model: &Model) -> Result<Fitter> {
        Fitter::with_assets(model, None)
    }

    /// [`Fitter::new`] with the asset directory used for model files without an embedded rig
    /// (`None`: `$PANOMAN_ASSETS` or the user cache; fetched with pip when missing).
    ///
    /// # Errors
    /// See [`Fitter::new`].
    pub fn with_assets(model: &Model, assets: Option<&std::path::Path>) -> Result<Fitter> {
        let dir = assets.map_or_else(assets::default_dir, std::path::Path::to_path_buf);
        let solver = FrameSolver::for_model(model.evaluator(), || Ok(assets::ensure(&dir)?))?;
        Ok(Fitter {
            model: model.clone(),
            solver,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Seconds [`Fitter::new`] took.
    pub fn setup_seconds(&self) -> f64 {
        self.solver.setup_seconds()
    }

    /// The rig's bone names (the keys of [`MotionData`] and of generator parameter files).
    pub fn bone_names(&self) -> &[String] {
        self.solver.bone_names()
    }

    /// The frame solver (rig, IK, shell fitter) this fitter composes, for pipelines that
    /// drive its stages themselves (the marker solver, the evaluation).
    pub fn solver(&self) -> &FrameSolver {
        &self.solver
    }

    /// The frame solver, mutably (its workspaces).
    pub fn solver_mut(&mut self) -> &mut FrameSolver {
        &mut self.solver
    }

    /// Reads a generator parameter file (e.g. a `params.json` of the LBS baseline or a mocap
    /// pose) as motion data θ: its non-zero bone angles in radians.
    ///
    /// # Errors
    /// The file is unreadable or not a valid parameter file (naming it).
    pub fn read_motion(&self, path: &std::path::Path) -> Result<MotionData> {
        let gp = self.solver.rig().generator.read_params(path)?;
        Ok(self
            .bone_names()
            .iter()
            .zip(&gp.pose.euler_deg)
            .filter(|(_, e)| **e != [0.0; 3])
            .map(|(n, e)| (n.clone(), e.map(f64::to_radians)))
            .collect())
    }

    pub(crate) fn constraints(&self, t: &Targets, req: &FitRequest) -> Result<Constraints> {
        req.check()?;
        t.check()?;
        if req.motion.is_some() && self.model.inner().motion.is_none() {
            return Err(Error::Invalid(
                "motion data given, but the model has no motion MLP".into(),
            ));
        }
        let c = Constraints {
            targets: t.clone(),
            fixed: req.fixed.clone(),
            motion: req.motion.clone(),
            previous: None,
        };
        self.solver.shell().validate(&c)?;
        Ok(c)
    }

    /// Fits one frame from scratch (cold IK).
    ///
    /// # Errors
    /// Invalid targets or request (nothing to fit, unknown keypoints, non-finite values,
    /// handle vertices out of range); numerical failures.
    pub fn fit(&mut self, targets: &Targets, req: &FitRequest) -> Result<FitOutput> {
        let c = self.constraints(targets, req)?;
        let ikc = ik_config_for_noise(req.keypoint_sigma);
        match req.method {
            Method::Lbs => {
                let (r, attempts) = self.solver.fit_lbs(&c, &ikc, &req.quality(), None)?;
                Ok(self.lbs_output(&c, r, attempts, &req.quality()))
            }
            Method::PanoMan => {
                let (r, fit) = self.solver.fit(&c, &ikc, &req.options(), None)?;
                Ok(self.panoman_output(&r, fit))
            }
        }
    }

    pub(crate) fn lbs_output(
        &self,
        c: &Constraints,
        r: IkResult,
        attempts: Vec<IkAttempt>,
        q: &QualityOptions,
    ) -> FitOutput {
        let keypoint_residuals =
            keypoint_residuals(self.model.inner(), &c.targets.keypoints, &r.posed);
        // The IK is the result: its check (the initializer's thresholds, after a skeletal
        // ICP if any) decides.
        let mut problems = panoman_fit::pipeline::ik_problems(self.model.inner(), &r, q);
        if !problems.is_empty() && attempts.len() > 1 {
            problems.push(panoman_fit::quality::Problem::StartsTried(attempts.len()));
        }
        let report = FitReport {
            method: Method::Lbs,
            setup_seconds: None,
            ik: IkReport::of(&r),
            stages: Vec::new(),
            fit_seconds: 0.0,
            total_seconds: r.seconds,
            keypoint_residuals,
            verdict: Verdict::from_problems(problems, q, attempts),
        };
        FitOutput {
            vertices: r.posed,
            params: None,
            rig_params: r.params,
            report,
        }
    }

    pub(crate) fn panoman_output(&self, r: &IkResult, fit: panoman_fit::FitResult) -> FitOutput {
        let report = FitReport {
            method: Method::PanoMan,
            setup_seconds: None,
            ik: IkReport::of(r),
            stages: fit.report.stages,
            fit_seconds: fit.report.seconds,
            total_seconds: r.seconds + fit.report.seconds,
            keypoint_residuals: fit.report.keypoint_residuals,
            verdict: fit.report.verdict,
        };
        FitOutput {
            vertices: fit.vertices,
            params: Some(fit.params),
            rig_params: r.params.clone(),
            report,
        }
    }

    /// Calibrates the identity's lengths from several frames of targets (MoSh's shape stage
    /// for keypoints, [`panoman_fit::shape_calibration`]): each frame fitted by the IK, then
    /// the length knobs of `opts` fitted to the frames' segment lengths (keypoint pairs on
    /// one segment, rigid handle pairs) with the poses held, alternating with the IK (3
    /// rounds by default). Give the result's `shape` to
    /// [`crate::Tracker::set_shape`]. Frames are best spread over the sequence (different
    /// poses make the lengths observable); 4–8 suffice.
    ///
    /// # Errors
    /// Invalid targets or request (naming the frame), no frames; IK failures.
    pub fn calibrate_shape(
        &self,
        frames: &[Targets],
        request: &FitRequest,
        opts: &ShapeCalibrationOptions,
    ) -> Result<ShapeCalibration> {
        let c = frames
            .iter()
            .enumerate()
            .map(|(i, t)| {
                self.constraints(t, request)
                    .map_err(|e| Error::Invalid(format!("calibration frame {i}: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        let cfg = ik_config_for_noise(request.keypoint_sigma);
        Ok(calibrate_shape(
            self.solver.ik(),
            &c,
            &ShapeParams::default(),
            &cfg,
            opts,
        )?)
    }
}
