//! The frame solver (docs/design/shell-fit.md §4): one stateful type that owns the LBS rig,
//! its skeletal IK and the shell fitter, built once per model and composed by every path that
//! fits a frame (the facade's `Fitter` and `Tracker`, the evaluation, the marker solver, the
//! demo); and [`Tracking`], the frame-to-frame state of a tracked sequence.
use std::time::Instant;

use crate::error::Result;
use crate::fit::{
    Constraints, FitOptions, FitResult, Init, Placement, Previous, ShellFitter, warm_fit_options,
};
use crate::icp::MatchStats;
use crate::ik::{IkConfig, IkResult, IkSolver, IkState};
use crate::pipeline::{IkIcpOptions, LbsRig, ik_fit, ik_icp, init_of, robust_ik};
use crate::quality::{IkAttempt, Problem, QualityOptions, Verdict};
use panoman_human::assets::AssetDir;
use panoman_model::model::{Evaluator, PanoManModel};
use std::sync::Arc;

/// The stateful solver of one frame (geometry-central's pattern: set up once, solve many):
/// the LBS rig on the model's topology ([`LbsRig`]), its skeletal IK ([`IkSolver`]) and the
/// discrete-shell fitter ([`ShellFitter`]). [`FrameSolver::fit`] runs PanoMan's whole fit
/// (IK initializer, skeletal ICP on a point cloud, staged shell fit), [`FrameSolver::fit_lbs`]
/// the LBS baseline; both take one target type ([`Constraints`]) and fit cold or warm.
pub struct FrameSolver {
    rig: LbsRig,
    ik: IkSolver,
    shell: ShellFitter,
    setup_seconds: f64,
}

impl FrameSolver {
    /// The solver of `model` with `rig` (e.g. [`LbsRig::load`] from the assets): builds the
    /// shell fitter and the IK.
    ///
    /// # Errors
    /// The rig's topology differs from the model's; solver setup failures.
    pub fn new(model: Arc<PanoManModel>, rig: LbsRig) -> Result<FrameSolver> {
        Self::with_shell(rig, ShellFitter::new(model)?)
    }

    fn with_shell(rig: LbsRig, shell: ShellFitter) -> Result<FrameSolver> {
        let t = Instant::now();
        if rig.keypoints.n_vertices != shell.model().n_vertices {
            return Err(crate::FitError::Invalid(format!(
                "the rig has {} vertices, the model {}",
                rig.keypoints.n_vertices,
                shell.model().n_vertices
            )));
        }
        let ik = rig.ik_solver()?;
        Ok(FrameSolver {
            rig,
            ik,
            shell,
            setup_seconds: t.elapsed().as_secs_f64(),
        })
    }

    /// The solver of a model from one of its evaluators (topology tables and `g`'s
    /// factorizations shared, not rebuilt), with the rig embedded in the model file, else the
    /// one read from `assets` (called only then; [`LbsRig::for_model`]).
    ///
    /// # Errors
    /// No usable rig; solver setup failures.
    pub fn for_model(
        ev: Evaluator,
        assets: impl FnOnce() -> Result<AssetDir>,
    ) -> Result<FrameSolver> {
        let t = Instant::now();
        let rig = LbsRig::for_model(&ev.model, assets)?;
        let shell = ShellFitter::with_evaluator(ev)?;
        let mut s = FrameSolver::with_shell(rig, shell)?;
        s.setup_seconds = t.elapsed().as_secs_f64();
        Ok(s)
    }

    /// The model.
    pub fn model(&self) -> &Arc<PanoManModel> {
        self.shell.model()
    }

    /// The LBS rig.
    pub fn rig(&self) -> &LbsRig {
        &self.rig
    }

    /// The rig's skeletal IK.
    pub fn ik(&self) -> &IkSolver {
        &self.ik
    }

    /// The shell fitter.
    pub fn shell(&self) -> &ShellFitter {
        &self.shell
    }

    /// The shell fitter, mutably (its workspaces).
    pub fn shell_mut(&mut self) -> &mut ShellFitter {
        &mut self.shell
    }

    /// Seconds the set-up took (rig, IK, shell pattern and symbolic factor).
    pub fn setup_seconds(&self) -> f64 {
        self.setup_seconds
    }

    /// The rig's bone names (the keys of motion data and of generator parameter files).
    pub fn bone_names(&self) -> &[String] {
        self.rig.generator.bone_names()
    }

    /// One frame: skeletal IK (cold, or warm-started from `warm`, e.g. the previous frame's
    /// [`IkResult::state`], which runs only the IK's final stage), with a point cloud in `c`
    /// refined by [`ik_icp`] (default options; no phenotype restarts when warm-started), then the
    /// staged PanoMan fit (with its own ICP passes on the surface) from the IK mesh. Returns the
    /// IK result (after the skeletal ICP) and the fit.
    ///
    /// The frame runs on a worker of rayon's global pool (called from outside the pool,
    /// `rayon::scope` hands it to a worker and blocks): a frame makes dozens of small fork-joins
    /// (IK columns, assembly halves, PCG chunks), which start cheaply from a worker, and no idle
    /// worker spins beside the calling thread (docs/design/shell-fit.md §3.5.1).
    pub fn fit(
        &mut self,
        c: &Constraints,
        ik_cfg: &IkConfig,
        opts: &FitOptions,
        warm: Option<&IkState>,
    ) -> Result<(IkResult, FitResult)> {
        let mut out = None;
        rayon::scope(|_| out = Some(self.fit_here(c, ik_cfg, opts, warm)));
        out.expect("the scope ran its closure")
    }

    /// [`FrameSolver::fit`] on the calling thread.
    fn fit_here(
        &mut self,
        c: &Constraints,
        ik_cfg: &IkConfig,
        opts: &FitOptions,
        warm: Option<&IkState>,
    ) -> Result<(IkResult, FitResult)> {
        let (rig, ik, fitter) = (&self.rig, &self.ik, &mut self.shell);
        fitter.validate(c)?;
        let cfg = IkConfig {
            initial_state: warm.cloned(),
            ..ik_cfg.clone()
        };
        // The first β-step's correction residual depends only on the previous frame: computed
        // while the IK runs (the IK's sequential parts leave a core free).
        let model = fitter.model().clone();
        let (ik_out, ()) = rayon::join(
            || robust_ik(&model, ik, c, &cfg, &opts.quality),
            || fitter.prefetch_correction(c, opts),
        );
        let (mut r, attempts) = ik_out?;
        if c.targets.points.is_some() {
            let icp = IkIcpOptions {
                // A warm-started frame keeps its phenotype basin.
                phenotype_starts: if warm.is_some() {
                    Vec::new()
                } else {
                    IkIcpOptions::default().phenotype_starts
                },
                ..IkIcpOptions::default()
            };
            r = ik_icp(rig, ik, c, ik_cfg, &r, &icp)?.0;
        }
        let init = init_of(&r, ik, rig.generator.bone_names());
        let after_skeletal;
        let opts = if c.targets.points.is_some() {
            after_skeletal = FitOptions {
                icp_passes: opts.icp_passes_after_skeletal,
                ..opts.clone()
            };
            &after_skeletal
        } else {
            opts
        };
        let mut fit = fitter.fit(c, &init, opts)?;
        let chosen = attempts.iter().find(|a| a.chosen);
        let mut problems: Vec<Problem> = chosen
            .map(|a| {
                a.problems
                    .iter()
                    .map(|p| Problem::Initializer(Box::new(p.clone())))
                    .collect()
            })
            .unwrap_or_default();
        problems.append(&mut fit.report.verdict.problems);
        if !problems.is_empty() && attempts.len() > 1 {
            problems.push(Problem::StartsTried(attempts.len()));
        }
        fit.report.verdict = Verdict::from_problems(problems, &opts.quality, attempts);
        Ok((r, fit))
    }

    /// The LBS baseline of one frame: the rig's IK (warm-started from `warm`) with the
    /// quality check and retries ([`robust_ik`]), refined on a point cloud in `c` by the
    /// skeletal ICP ([`ik_icp`], default options).
    ///
    /// # Errors
    /// No keypoints in `c`; invalid IK input.
    pub fn fit_lbs(
        &self,
        c: &Constraints,
        ik_cfg: &IkConfig,
        q: &QualityOptions,
        warm: Option<&IkState>,
    ) -> Result<(IkResult, Vec<IkAttempt>)> {
        let cfg = IkConfig {
            initial_state: warm.cloned(),
            ..ik_cfg.clone()
        };
        let (mut r, attempts) = robust_ik(self.model(), &self.ik, c, &cfg, q)?;
        if c.targets.points.is_some() {
            r = self.ik_icp(c, ik_cfg, &r, &IkIcpOptions::default())?.0;
        }
        Ok((r, attempts))
    }

    /// The IK initializer alone, without retries ([`ik_fit`]).
    ///
    /// # Errors
    /// As [`ik_fit`].
    pub fn ik_fit(&self, c: &Constraints, cfg: &IkConfig) -> Result<IkResult> {
        ik_fit(&self.ik, c, cfg)
    }

    /// The skeletal ICP of `start` on `c`'s point cloud ([`ik_icp`]).
    ///
    /// # Errors
    /// As [`ik_icp`].
    pub fn ik_icp(
        &self,
        c: &Constraints,
        cfg: &IkConfig,
        start: &IkResult,
        opts: &IkIcpOptions,
    ) -> Result<(IkResult, Vec<MatchStats>)> {
        ik_icp(&self.rig, &self.ik, c, cfg, start, opts)
    }

    /// The fit's start from an IK result ([`init_of`]).
    pub fn init_of(&self, r: &IkResult) -> Init {
        init_of(r, &self.ik, self.rig.generator.bone_names())
    }

    /// The staged shell fit from an IK result (no initializer run): [`ShellFitter::fit`] from
    /// [`FrameSolver::init_of`].
    ///
    /// # Errors
    /// As [`ShellFitter::fit`].
    pub fn fit_from_ik(
        &mut self,
        c: &Constraints,
        r: &IkResult,
        opts: &FitOptions,
    ) -> Result<FitResult> {
        let init = self.init_of(r);
        self.shell.fit(c, &init, opts)
    }
}

/// What a [`Tracking`] carries from one frame to the next ([`Tracking::state`]).
#[derive(Clone, Debug, Default)]
pub struct TrackingState {
    /// Frames fitted so far.
    pub frames: usize,
    /// The last frame's IK state (warm start of the next IK).
    pub ik: Option<IkState>,
    /// The last frame's fit (temporal terms, shape α, propagated placement).
    pub previous: Option<Previous>,
}

/// The default [`Tracking::warm_ik_tolerance`]: the relative decrease below which the IK of a
/// warm-started frame stops (cold solves: [`IkConfig::tolerance`], 1e−9).
pub const WARM_IK_TOLERANCE: f64 = 1e-4;

/// Frame-to-frame state of a tracked sequence (paper §5.3 for sequences; Total Capture's
/// temporal propagation): the previous frame's IK state warm-starts the IK, and its fit gives
/// the temporal terms, the shape α kept for the sequence and the propagated placement
/// ([`Previous`]). The first frame is fitted with the cold options, the next ones with the
/// warm options.
pub struct Tracking {
    /// Options of the first frame. Default [`FitOptions::default`].
    pub cold: FitOptions,
    /// Options of the following frames. Default [`warm_fit_options`].
    pub warm: FitOptions,
    /// Skeletal IK settings.
    pub ik: IkConfig,
    /// Run every frame's IK cold (no warm start), e.g. for large motion between frames; the
    /// temporal terms stay. Default false.
    pub cold_ik: bool,
    /// Every this many frames a warm frame is placed by [`Placement::Aligned`] (one `g`
    /// solve) instead of propagating the previous placement, so that the propagated torso
    /// motion cannot drift. Default 30; 0 never.
    pub reanchor_every: usize,
    /// Stopping tolerance of the IK of warm-started frames ([`IkConfig::tolerance`] there;
    /// `None`: the cold frames' `ik.tolerance`). Default [`WARM_IK_TOLERANCE`] (1e−4): on the
    /// eval's 72-frame clip a warm IK then takes 7 LM iterations instead of 9 (1e−9), tracking
    /// error 3.2674 → 3.2620 mm (docs/design/shell-fit.md §5). The LBS baseline's trackers
    /// take theirs from [`Tracking::ik_config`].
    pub warm_ik_tolerance: Option<f64>,
    frames: usize,
    state: Option<IkState>,
    previous: Option<Previous>,
}

impl Default for Tracking {
    fn default() -> Self {
        Tracking::new(
            FitOptions::default(),
            warm_fit_options(),
            IkConfig::default(),
            false,
        )
    }
}

impl Tracking {
    /// A new sequence with the given options for the first and following frames and IK
    /// settings (no frame fitted yet).
    pub fn new(cold: FitOptions, warm: FitOptions, ik: IkConfig, cold_ik: bool) -> Self {
        Tracking {
            cold,
            warm,
            ik,
            cold_ik,
            reanchor_every: 30,
            warm_ik_tolerance: Some(WARM_IK_TOLERANCE),
            frames: 0,
            state: None,
            previous: None,
        }
    }

    /// The frame-to-frame state after the frames fitted so far (frame count, last IK state,
    /// previous fit): with [`Tracking::set_state`] on a sequence of the same options it
    /// continues exactly as this one would (e.g. a resumed `panoman track`).
    pub fn state(&self) -> TrackingState {
        TrackingState {
            frames: self.frames,
            ik: self.state.clone(),
            previous: self.previous.clone(),
        }
    }

    /// Replaces the frame-to-frame state (see [`Tracking::state`]).
    pub fn set_state(&mut self, s: TrackingState) {
        self.frames = s.frames;
        self.state = s.ik;
        self.previous = s.previous;
    }

    /// `base` with [`Tracking::warm_ik_tolerance`] as its tolerance (if set) and
    /// [`IkConfig::full_extension`] when the frame is warm started (a limb straightened
    /// since the previous frame must be reachable; a cold frame reaches it through the range
    /// continuation of [`ik_fit`]): the IK settings of this sequence's frames, which an LBS
    /// tracker of the same targets uses too so that both methods share the IK.
    pub fn ik_config(&self, base: &IkConfig, warm: bool) -> IkConfig {
        if !warm {
            return base.clone();
        }
        IkConfig {
            tolerance: self.warm_ik_tolerance.unwrap_or(base.tolerance),
            full_extension: true,
            ..base.clone()
        }
    }

    /// Fits the next frame (`c.previous` is set from the sequence) and records it.
    pub fn fit_next(
        &mut self,
        solver: &mut FrameSolver,
        c: &Constraints,
    ) -> Result<(IkResult, FitResult)> {
        let c = Constraints {
            previous: self.previous.clone(),
            ..c.clone()
        };
        let warm = if self.cold_ik {
            None
        } else {
            self.state.as_ref()
        };
        let reanchor = self.reanchor_every > 0 && self.frames.is_multiple_of(self.reanchor_every);
        let opts = match (&self.previous, reanchor) {
            (None, _) => self.cold.clone(),
            (Some(_), false) => self.warm.clone(),
            (Some(_), true) => FitOptions {
                placement: Placement::Aligned,
                ..self.warm.clone()
            },
        };
        let ik_cfg = self.ik_config(&self.ik, warm.is_some());
        let (r, fit) = solver.fit(&c, &ik_cfg, &opts, warm)?;
        self.frames += 1;
        self.state = Some(r.state.clone());
        self.previous = Some(Previous {
            vertices: fit.vertices.clone(),
            params: fit.params.clone(),
            init: Some(r.posed.clone()),
        });
        Ok((r, fit))
    }
}
