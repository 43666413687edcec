//! The whole fit of one frame (PanoMan §5.3, docs/design/shell-fit.md §4): skeletal IK of the LBS rig
//! to the keypoints (pose, phenotype, face units) gives the initial mesh and rest shape; α is
//! the PCA projection of that rest shape and β the projection of the IK mesh's RL/RA; then the
//! staged shell fit of [`crate::fit`]. The LBS baseline is the IK alone. With a point cloud
//! the IK is first refined on it by skeletal ICP ([`ik_icp`]: keypoints + matched surface
//! points, re-matched per pass), so the shell fit starts from a mesh whose pose and body
//! shape already follow the scan.
use crate::error::{FitError, Result};
use crate::fit::{Constraints, Init};
use crate::icp::{IcpOptions, MatchStats, VertexFaces, correspondences_on};
use crate::ik::{IkConfig, IkResult, IkSolver, IkStageReport, IkState, IkTargets, PointTarget};
use crate::quality::{IkAttempt, Problem, QualityOptions, ik_group_residuals, phenotype_at_bounds};
use panoman_human::assets::AssetDir;
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::keypoints::{KeypointSet, load_or_build};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::geom::{V3, norm, scale};
use panoman_mesh::shell::PointConstraint;
use panoman_model::model::PanoManModel;
use rayon::prelude::*;
use std::sync::Arc;

/// The LBS rig on a model's template topology: the generator, its map onto the template, and
/// the TC-133 keypoint rows of that topology. Loaded once per session.
pub struct LbsRig {
    /// The Anny-equivalent generator.
    pub generator: Arc<Generator>,
    /// Anny vertices → template vertices.
    pub map: Arc<TopologyMap>,
    /// The model's topology.
    pub topology: OutputTopology,
    /// Keypoint rows on that topology.
    pub keypoints: KeypointSet,
}

impl LbsRig {
    /// Loads the rig for `model`'s topology (`full` or `small`) from the assets.
    pub fn load(assets: &AssetDir, model: &PanoManModel) -> Result<LbsRig> {
        let topology = Self::topology_of(model)?;
        let generator = Generator::load(assets, GeneratorOptions::default())?;
        let full = full_template(assets)?;
        let small = small_template(assets, &full)?;
        let map = TopologyMap::new(&generator, &full, &small)?;
        let defs = load_or_build(assets, &full, &small)?;
        let keypoints = match topology {
            OutputTopology::Small => defs.small,
            _ => defs.full,
        };
        if keypoints.n_vertices != model.n_vertices {
            return Err(FitError::Invalid(format!(
                "model has {} vertices, its `{}` rig topology has {}",
                model.n_vertices, model.topology_name, keypoints.n_vertices
            )));
        }
        Ok(LbsRig {
            generator: Arc::new(generator),
            map: Arc::new(map),
            topology,
            keypoints,
        })
    }

    /// The rig of `model`: the one embedded in the model file when it has one (no asset
    /// access), else read from `assets` ([`LbsRig::load`]); `assets` is opened lazily, only
    /// for model files without an embedded rig.
    ///
    /// # Errors
    /// The model's topology has no rig; its keypoint rows do not fit it; asset errors.
    pub fn for_model(
        model: &PanoManModel,
        assets: impl FnOnce() -> Result<AssetDir>,
    ) -> Result<LbsRig> {
        let Some(data) = &model.rig else {
            return LbsRig::load(&assets()?, model);
        };
        let topology = Self::topology_of(model)?;
        let keypoints = KeypointSet {
            names: model.keypoints.names.clone(),
            rows: model.keypoints.rows.clone(),
            n_vertices: model.n_vertices,
        };
        if data.map.n_vertices(topology) != model.n_vertices {
            return Err(FitError::Invalid(format!(
                "model has {} vertices, its embedded `{}` rig topology has {}",
                model.n_vertices,
                model.topology_name,
                data.map.n_vertices(topology)
            )));
        }
        Ok(LbsRig {
            generator: data.generator.clone(),
            map: data.map.clone(),
            topology,
            keypoints,
        })
    }

    fn topology_of(model: &PanoManModel) -> Result<OutputTopology> {
        match model.topology_name.as_str() {
            "full" => Ok(OutputTopology::Full),
            "small" => Ok(OutputTopology::Small),
            other => Err(FitError::Invalid(format!(
                "the model's topology `{other}` has no LBS rig (expected full or small)"
            ))),
        }
    }

    /// The IK solver of this rig (precomputations once; reuse it across frames).
    pub fn ik_solver(&self) -> Result<IkSolver> {
        IkSolver::new(
            self.generator.clone(),
            self.map.clone(),
            self.topology,
            &self.keypoints,
        )
    }
}

/// Skeletal IK of the rig to the constraint set's keypoints (the initializer, and the LBS
/// baseline on its own).
pub fn ik_fit(ik: &IkSolver, c: &Constraints, cfg: &IkConfig) -> Result<IkResult> {
    if c.targets.keypoints.points.is_empty() {
        return Err(FitError::Invalid(
            "the initializer needs keypoints (none given)".into(),
        ));
    }
    let targets = IkTargets::from_file(&c.targets.keypoints)?;
    let r = ik.solve(&targets, cfg)?;
    let (r, ranges) = range_continuation(ik, &targets, cfg, r)?;
    let r = phenotype_polish(ik, &targets, cfg, ranges, r)?;
    let cfg = IkConfig {
        wide_ranges: ranges.0,
        full_extension: ranges.1,
        ..cfg.clone()
    };
    handle_pass(ik, &targets, c, &cfg, r)
}

/// The vertex handles of `c` as point targets of the IK ([`IkSolver::solve_with_points`],
/// one vertex each, the handle's weight in keypoint units), and its level pairs as
/// point-to-plane targets of `x_a − x_b` ([`crate::fit::LevelPair`]): the final stage again, warm from
/// `r`, in the ranges `r` was solved in, with the keypoints and the handles. A handle on a
/// part that no keypoint places — e.g. a heel or a toe, since TC-127's body stops at the
/// ankles — then moves the rig (the foot's flexion) instead of only the shell fit's surface
/// near it. Without handles `r` is returned as it is.
fn handle_pass(
    ik: &IkSolver,
    targets: &IkTargets,
    c: &Constraints,
    cfg: &IkConfig,
    r: IkResult,
) -> Result<IkResult> {
    if c.targets.handles.is_empty() && c.targets.levels.is_empty() {
        return Ok(r);
    }
    let handles = c.targets.handles.iter().map(|h| PointTarget {
        rows: vec![(h.vertex, 1.0)],
        position: h.position,
        weight: h.weight,
        normal: None,
    });
    // A level pair: the point x_a − x_b against the plane through d·n̂ with normal n̂.
    let levels = c.targets.levels.iter().map(|l| {
        let n = scale(l.up, 1.0 / norm(l.up));
        PointTarget {
            rows: vec![(l.a, 1.0), (l.b, -1.0)],
            position: scale(n, l.offset),
            weight: l.weight,
            normal: Some(n),
        }
    });
    let points: Vec<PointTarget> = handles.chain(levels).collect();
    let warm = IkConfig {
        initial_state: Some(r.state.clone()),
        ..cfg.clone()
    };
    let h = ik.solve_with_points(targets, &points, &warm)?;
    let mut stages = r.stages.clone();
    stages.extend(h.stages.iter().cloned().map(|mut s| {
        s.name = "handles";
        s
    }));
    Ok(IkResult {
        seconds: r.seconds + h.seconds,
        iterations: r.iterations + h.iterations,
        stages,
        ..h
    })
}

/// The muscle × weight values of [`robust_ik`]'s retries and of the phenotype polish's starts.
pub const MUSCLE_WEIGHT_STARTS: [(f64, f64); 4] = [(0.2, 0.2), (0.2, 0.8), (0.8, 0.2), (0.8, 0.8)];

/// The age steps of the phenotype polish's starts: each is combined with every
/// [`MUSCLE_WEIGHT_STARTS`] pair (12 starts). A step of 0.2 crosses the age anchor at ⅓ or ⅔
/// next to the solved value (the age cells of the phenotype grid, [`crate::ik`]).
pub const POLISH_AGE_STEPS: [f64; 3] = [0.0, 0.2, -0.2];

/// Phenotype polish of a cold keypoint solve ([`IkConfig::phenotype_polish`]): the final
/// stage again, warm-started from the solved pose with the age moved by each of
/// [`POLISH_AGE_STEPS`] (clamped to `[0, 1]`) and muscle × weight set to each of
/// [`MUSCLE_WEIGHT_STARTS`] (the other values as solved). The 12 starts are screened in
/// parallel with [`IkConfig::polish_screen_iterations`] iterations each; the one with the
/// lowest objective `E` is continued to convergence and kept if its `E` is below the solve's
/// own (a strict decrease: the result never gets worse by the objective).
///
/// Why: age, muscle and weight move the keypoints by a few millimetres at most, and the
/// phenotype grid is multilinear per cell with kinks at its anchors (age ⅓, ⅔; muscle and
/// weight ½), so the staged solve, which fits them while the pose is still far off, often
/// ends in a wrong cell — measured on the stress set's composites from exact keypoints: the
/// solve's `E` two to five times that of the same solve with the true phenotype held, body
/// keypoints 1.2–1.8 mm off instead of 0.1 mm, body vertices 40–50 mm off. With the pose in
/// place the cells' minima separate (docs/design/rig-and-ik.md §4.4.2). `ranges`
/// (`(wide_ranges, full_extension)`) are the ranges `r` was solved in (see
/// [`range_continuation`]): the polish keeps them, so that the objectives compare.
fn phenotype_polish(
    ik: &IkSolver,
    targets: &IkTargets,
    cfg: &IkConfig,
    ranges: (bool, bool),
    r: IkResult,
) -> Result<IkResult> {
    if !cfg.fit_phenotype || !cfg.phenotype_polish || cfg.initial_state.is_some() {
        return Ok(r);
    }
    let (ai, mi, wi) = (
        phenotype_slot("age")?,
        phenotype_slot("muscle")?,
        phenotype_slot("weight")?,
    );
    let warm = |st: IkState, iterations: usize| IkConfig {
        wide_ranges: ranges.0,
        full_extension: ranges.1,
        initial_state: Some(st),
        max_iterations: iterations,
        ..cfg.clone()
    };
    let starts: Vec<IkState> = POLISH_AGE_STEPS
        .iter()
        .flat_map(|&da| MUSCLE_WEIGHT_STARTS.iter().map(move |&mw| (da, mw)))
        .map(|(da, (m, w))| {
            let mut st = r.state.clone();
            st.phenotype[ai] = (st.phenotype[ai] + da).clamp(0.0, 1.0);
            st.phenotype[mi] = m;
            st.phenotype[wi] = w;
            st
        })
        .collect();
    let t0 = std::time::Instant::now();
    let screen = cfg.polish_screen_iterations.min(cfg.max_iterations);
    let screened = starts
        .into_par_iter()
        .map(|st| ik.solve(targets, &warm(st, screen)))
        .collect::<Result<Vec<_>>>()?;
    let mut iterations: usize = screened.iter().map(|t| t.iterations).sum();
    // The first of the lowest (deterministic on ties), if it is below the solve's own.
    let best = screened
        .into_iter()
        .reduce(|b, t| if t.cost < b.cost { t } else { b })
        .filter(|b| b.cost < r.cost);
    let polished = match best {
        Some(b) if screen < cfg.max_iterations => {
            let done = ik.solve(targets, &warm(b.state, cfg.max_iterations))?;
            iterations += done.iterations;
            Some(done).filter(|d| d.cost < r.cost)
        }
        other => other,
    };
    let seconds = t0.elapsed().as_secs_f64();
    let last = r.stages.last();
    let report = IkStageReport {
        name: "phenotype_polish",
        n_variables: last.map_or(0, |s| s.n_variables),
        n_targets: last.map_or(0, |s| s.n_targets),
        n_points: 0,
        iterations,
        cost_before: r.cost,
        cost_after: polished.as_ref().map_or(r.cost, |p| p.cost),
        seconds,
    };
    let mut stages = r.stages.clone();
    stages.push(report);
    let (total_s, total_it) = (r.seconds + seconds, r.iterations + iterations);
    Ok(IkResult {
        seconds: total_s,
        iterations: total_it,
        stages,
        ..polished.unwrap_or(r)
    })
}

/// Index of a phenotype value in [`IkState::phenotype`].
fn phenotype_slot(name: &str) -> Result<usize> {
    crate::ik::IK_PHENOTYPE
        .iter()
        .position(|n| *n == name)
        .ok_or_else(|| FitError::Invalid(format!("the IK fits no phenotype value `{name}`")))
}

/// Mean keypoint residual of a group (mm) above which [`ik_fit`] tries the wide ranges.
pub const WIDE_RETRY_MM: f64 = 1.0;

/// The relative drop of the mean keypoint residual the wide-range continuation must reach to
/// be kept (against the bounded solve's).
pub const WIDE_RETRY_GAIN: f64 = 0.25;

/// Range continuation: when a keypoint group is missed by more than [`WIDE_RETRY_MM`] on
/// average, the solve is continued from its own result (a warm start runs the final stage
/// only, so a continuation stays in the bounded solve's basin and only moves the joints
/// further) with, in turn,
///
/// 1. the wide joint ranges ([`IkConfig::wide_ranges`]: arm twists ±180°, deeper hips, knees,
///    shoulders) — how a forearm twist beyond the training sampler's ±30°, a crouch or a hand
///    on the head reaches the rig;
/// 2. if that is not kept or still misses a group, the sampler's ranges with elbows and knees
///    free to straighten ([`IkConfig::full_extension`]) — how straight arms and legs (a
///    T-pose, a standing person) reach it. Not part of 1: with the elbow's extension in the
///    wide ranges, the 170° and 180° forearm twists of `panoman eval`'s stress set went to
///    wrong minima (keypoints 0.06 → 5.0 mm off).
///
/// A continuation is kept when the mean keypoint residual drops by at least
/// [`WIDE_RETRY_GAIN`] against the best so far; both start from the bounded solve, and the
/// result's time and iterations count every solve tried. Returns the result and the ranges
/// it was solved in (`(wide_ranges, full_extension)`), so that the phenotype polish keeps
/// them and the objectives compare. This lets a cold solve reach those poses without
/// wandering into the wrong minima wider ranges open.
fn range_continuation(
    ik: &IkSolver,
    targets: &IkTargets,
    cfg: &IkConfig,
    r: IkResult,
) -> Result<(IkResult, (bool, bool))> {
    let misses = |r: &IkResult| r.group_mean_mm.iter().flatten().any(|&m| m > WIDE_RETRY_MM);
    let own = (cfg.wide_ranges, cfg.full_extension);
    if cfg.wide_ranges || !misses(&r) {
        return Ok((r, own));
    }
    let (mut seconds, mut iterations) = (r.seconds, r.iterations);
    let (mut best, mut ranges) = (r.clone(), own);
    for (wide, full) in [(true, cfg.full_extension), (false, true)] {
        if (wide, full) == own || (ranges != own && !misses(&best)) {
            continue;
        }
        let c = IkConfig {
            wide_ranges: wide,
            full_extension: full,
            initial_state: Some(r.state.clone()),
            ..cfg.clone()
        };
        let w = ik.solve(targets, &c)?;
        seconds += w.seconds;
        iterations += w.iterations;
        if w.mean_residual_mm() < (1.0 - WIDE_RETRY_GAIN) * best.mean_residual_mm() {
            (best, ranges) = (w, (wide, full));
        }
    }
    // Time and iterations of the bounded solve and of every continuation tried.
    Ok((
        IkResult {
            seconds,
            iterations,
            ..best
        },
        ranges,
    ))
}

/// Controls of [`ik_icp`].
#[derive(Clone, Debug)]
pub struct IkIcpOptions {
    /// Matching passes; each re-matches the scan to the current IK mesh and re-solves the IK
    /// warm-started. Default 3.
    pub passes: usize,
    /// σ_p: the expected point-to-surface error of a matched scan point (noise plus matching
    /// error, metres). Each point gets the weight `w = max(λ_θ, 1e−6) / (4σ_p²)` in IK
    /// keypoint-weight units, `λ_θ` the IK's [`IkConfig::pose_prior`]: with the convention
    /// of [`ik_config_for_noise`] (`λ_θ = 1e−6 + 4σ_k²` for keypoint noise σ_k) that is the
    /// MAP ratio `σ_k²/σ_p²` of the keypoints' and the points' variances (exact keypoints
    /// count as σ_k = 0.5 mm). Measured on held-out people (3,500 points, 2 mm noise): the
    /// best error for exact and for 2 and 5 mm keypoint noise lies within a factor of ~3 of
    /// this weight. Default 3 mm.
    pub point_sigma: f64,
    /// Point-to-plane residuals `n̂ᵀ(Σ b x − p)` along the IK mesh's normal at the match
    /// (true, default) instead of point-to-point `Σ b x − p`.
    pub point_to_plane: bool,
    /// Rejection of the first pass (farther pairs, and with scan normals pairs whose normals
    /// differ too much, are dropped). Default: 5 cm, 60°.
    pub first: IcpOptions,
    /// Rejection of the later passes. Default: 2 cm, 60°.
    pub later: IcpOptions,
    /// Levenberg–Marquardt iteration cap of each pass's solve. Default 20.
    pub iterations: usize,
    /// Extra starts of the first pass (when the phenotype is fitted): the current state with
    /// these phenotype values overridden (`None` keeps a value;
    /// [`crate::ik::IK_PHENOTYPE`] order).
    /// Keypoints barely observe muscle and weight, and with the surface the objective has
    /// separate basins for them (measured: a wrong basin leaves 3–8 mm); every start is
    /// solved (in parallel) and the one whose mesh fits the scan and keypoints best (see
    /// [`ik_icp`]) is kept. Default: muscle × weight ∈ {0.2, 0.8}²; empty: no restarts.
    pub phenotype_starts: Vec<[Option<f64>; 6]>,
    /// Levenberg–Marquardt iteration cap of each screened start's solve (on the subsample,
    /// before the chosen one is re-solved on all points). Default 10: the screen only ranks
    /// the starts, and the chosen one is re-solved on all points (measured on 10 held-out
    /// people with `panoman bench --only fit_scan`, three alternating rounds: 20 → 10
    /// iterations took the skeletal ICP median 1.18 → 0.92 s and the scan fit's error
    /// 2.058 → 2.037 mm; 12 iterations: 2.036 mm, 8: 2.062 mm).
    pub screen_iterations: usize,
    /// Points of the subsample the starts are screened on (about). Default 1,000.
    pub screen_points: usize,
}

impl Default for IkIcpOptions {
    fn default() -> Self {
        IkIcpOptions {
            passes: 3,
            point_sigma: 0.003,
            point_to_plane: true,
            first: IcpOptions::default(),
            later: IcpOptions {
                max_distance: 0.02,
                ..IcpOptions::default()
            },
            iterations: 20,
            phenotype_starts: [(0.2, 0.2), (0.2, 0.8), (0.8, 0.2), (0.8, 0.8)]
                .map(|(m, w)| [None, None, Some(m), Some(w), None, None])
                .to_vec(),
            screen_iterations: 10,
            screen_points: 1000,
        }
    }
}

/// Skeletal ICP: the IK of the rig refined on a point cloud. Each pass matches every scan
/// point `p` to its closest point on the current IK mesh (nearest vertex, then the closest
/// point of its triangles: barycentric row `b` of a triangle with normal `n̂`; far pairs are
/// rejected, see [`IkIcpOptions`]) and re-solves the IK warm-started from the current state
/// ([`IkSolver::solve_with_points`], final stage only) with the keypoints of `c` plus
///
/// `Σ_p w (n̂_pᵀ(Σ_m b_pm x_m(θ, β, f) − p))²`  (point-to-plane; point-to-point without n̂),
///
/// `w = max(λ_θ, 1e−6)/(4σ_p²)` (see [`IkIcpOptions::point_sigma`]).
///
/// The first pass also solves from [`IkIcpOptions::phenotype_starts`] (every start, the
/// current state included, on a subsample of about 1,000 of the matched points with the
/// weights scaled up accordingly), keeps the candidate with the lowest scan score
///
/// `Σ_k w_k |K_k − k̂_k|² + w Σ_p min(d_p, τ)²`
///
/// (`d_p` the distance of scan point `p` to the candidate's surface, `τ` the later passes'
/// rejection distance), which is computed by re-matching, so candidates are compared on
/// their own surfaces, and re-solves it on all points.
///
/// Unlike the shell fit's ICP, this moves the skeleton, the phenotype and the face units, so
/// it resolves what keypoints leave open (foot angles, limb twists, pelvis tilt, body
/// shape). Returns the refined IK and the match statistics per pass; without points in `c`
/// it returns `start`. The result's `seconds`, `iterations` and `stages` cover `start` and
/// every pass (the screened starts' iterations counted, their stages not).
///
/// # Errors
/// No keypoints in `c`; invalid IK input (see [`IkSolver::solve_with_points`]).
pub fn ik_icp(
    rig: &LbsRig,
    ik: &IkSolver,
    c: &Constraints,
    cfg: &IkConfig,
    start: &IkResult,
    opts: &IkIcpOptions,
) -> Result<(IkResult, Vec<MatchStats>)> {
    let Some(crate::targets::PointCloud {
        positions: pts,
        normals: nrm,
    }) = &c.targets.points
    else {
        return Ok((start.clone(), Vec::new()));
    };
    if c.targets.keypoints.points.is_empty() {
        return Err(FitError::Invalid(
            "the skeletal ICP needs keypoints (none given)".into(),
        ));
    }
    let targets = IkTargets::from_file(&c.targets.keypoints)?;
    if !(opts.point_sigma.is_finite() && opts.point_sigma > 0.0) {
        return Err(FitError::Invalid(format!(
            "ICP point sigma {} must be positive",
            opts.point_sigma
        )));
    }
    let w = cfg.pose_prior.max(1e-6) / (4.0 * opts.point_sigma * opts.point_sigma);
    let faces = rig.map.faces(rig.topology);
    let vf = VertexFaces::from_faces(start.posed.len(), faces);
    let matches = |x: &[V3], rejection: &IcpOptions| {
        correspondences_on(faces, &vf, x, pts, nrm.as_deref(), 1.0, rejection)
    };
    let to_targets = |cons: Vec<PointConstraint>| -> Vec<PointTarget> {
        cons.into_iter()
            .map(|pc| PointTarget {
                rows: pc.rows,
                position: pc.target,
                weight: w,
                normal: if opts.point_to_plane { pc.normal } else { None },
            })
            .collect()
    };
    let solve = |state: &IkState, points: &[PointTarget]| {
        let pass_cfg = IkConfig {
            initial_state: Some(state.clone()),
            max_iterations: opts.iterations,
            ..cfg.clone()
        };
        ik.solve_with_points(&targets, points, &pass_cfg)
    };
    // The scan score of a candidate (see above).
    let tau = opts.later.max_distance;
    let wide = IcpOptions {
        max_distance: f64::INFINITY,
        ..opts.later.clone()
    };
    let score = |r: &IkResult| -> f64 {
        let (cons, _) = matches(&r.posed, &wide);
        let kp: f64 = r
            .residuals
            .iter()
            .map(|e| e.weight * e.distance * e.distance)
            .sum();
        let sc: f64 = cons
            .iter()
            .map(|pc| {
                let d = norm(pc.offset(&r.posed)).min(tau);
                d * d
            })
            .sum();
        kp + w * sc
    };
    let t0 = std::time::Instant::now();
    let mut cur = start.clone();
    let (mut iterations, mut stages) = (start.iterations, start.stages.clone());
    let mut stats = Vec::with_capacity(opts.passes);
    for pass in 0..opts.passes {
        let rejection = if pass == 0 { &opts.first } else { &opts.later };
        let (cons, st) = matches(&cur.posed, rejection);
        stats.push(st);
        if cons.is_empty() {
            break;
        }
        let points = to_targets(cons);
        if pass == 0 && cfg.fit_phenotype && !opts.phenotype_starts.is_empty() {
            // Every start (the current state first) on a subsample of about
            // `screen_points` points, weights scaled to keep the points' total weight.
            let k = points.len().div_ceil(opts.screen_points.max(1)).max(1);
            let sub: Vec<PointTarget> = points
                .iter()
                .step_by(k)
                .map(|p| PointTarget {
                    weight: p.weight * k as f64,
                    ..p.clone()
                })
                .collect();
            let mut starts = vec![cur.state.clone()];
            for over in &opts.phenotype_starts {
                let mut s = cur.state.clone();
                for (v, o) in s.phenotype.iter_mut().zip(over) {
                    if let Some(o) = o {
                        *v = o.clamp(0.0, 1.0);
                    }
                }
                starts.push(s);
            }
            let results = starts
                .par_iter()
                .map(|s| {
                    let cfg = IkConfig {
                        initial_state: Some(s.clone()),
                        max_iterations: opts.screen_iterations,
                        ..cfg.clone()
                    };
                    let r = ik.solve_with_points(&targets, &sub, &cfg)?;
                    let sc = score(&r);
                    Ok((r, sc))
                })
                .collect::<Result<Vec<_>>>()?;
            iterations += results.iter().map(|r| r.0.iterations).sum::<usize>();
            let (best, _) = results
                .into_iter()
                .reduce(|a, b| if b.1 < a.1 { b } else { a })
                .expect("at least one start");
            // The chosen start on all points (correspondences of this pass).
            cur = solve(&best.state, &points)?;
        } else {
            cur = solve(&cur.state, &points)?;
        }
        iterations += cur.iterations;
        stages.extend(cur.stages.iter().cloned());
    }
    cur.iterations = iterations;
    cur.stages = stages;
    cur.seconds = start.seconds + t0.elapsed().as_secs_f64();
    Ok((cur, stats))
}

/// What fails the quality check in an IK result (empty: passes): its keypoint residuals per
/// group (against the initializer's thresholds, [`QualityOptions::for_initializer`]) and the
/// plausibility of its shape (α = the PCA projection of its rest mesh, see
/// [`crate::quality`]); with a failure, the phenotype values on their bounds are noted.
pub fn ik_problems(model: &PanoManModel, r: &IkResult, q: &QualityOptions) -> Vec<Problem> {
    let mut p = q
        .for_initializer()
        .keypoint_problems(&ik_group_residuals(r));
    if r.rest.len() == model.n_vertices {
        let flat: Vec<f64> = r.rest.iter().flatten().copied().collect();
        p.extend(q.shape_problems(model, &model.shape.project(&flat)));
    }
    let bounds = phenotype_at_bounds(r);
    if !p.is_empty() && !bounds.is_empty() {
        p.push(Problem::PhenotypeAtBounds(bounds));
    }
    p
}

/// The starts [`robust_ik`] retries: name, configuration, and whether the result is then
/// continued (warm-started) with `cfg`'s own priors and phenotype fit.
fn retry_starts(cfg: &IkConfig) -> Vec<(String, IkConfig, bool)> {
    let cold = IkConfig {
        initial_state: None,
        ..cfg.clone()
    };
    let mut out = Vec::new();
    if cfg.initial_state.is_some() {
        out.push(("cold".to_string(), cold.clone(), false));
    }
    out.push((
        "strong_priors".to_string(),
        IkConfig {
            pose_prior: 100.0 * cold.pose_prior,
            phenotype_prior: 100.0 * cold.phenotype_prior,
            face_unit_prior: 100.0 * cold.face_unit_prior,
            ..cold.clone()
        },
        true,
    ));
    if cold.fit_phenotype {
        out.push((
            "mean_shape".to_string(),
            IkConfig {
                fit_phenotype: false,
                initial_shape: None,
                ..cold.clone()
            },
            true,
        ));
        for (m, w) in MUSCLE_WEIGHT_STARTS {
            let mut shape = cold.initial_shape.clone().unwrap_or_default();
            if let Some(v) = shape.phenotype.get_mut("muscle") {
                *v = m;
            }
            if let Some(v) = shape.phenotype.get_mut("weight") {
                *v = w;
            }
            out.push((
                format!("phenotype m{m} w{w}"),
                IkConfig {
                    initial_shape: Some(shape),
                    ..cold.clone()
                },
                false,
            ));
        }
    }
    out
}

/// The initializer with failure detection and recovery (docs/design/shell-fit.md §7): the IK
/// of `cfg`; if it fails the quality check ([`ik_problems`]) and `q.retry`, the IK again from
/// other starts (in parallel): cold (when `cfg` was warm-started), stronger priors (×100, then
/// continued with `cfg`'s), the mean shape with the phenotype held (then continued with it
/// fitted), and muscle × weight ∈ {0.2, 0.8}². Kept: among the results that pass (else among
/// all) the one with the lowest keypoint term `Σ_k w_k |K_k − k̂_k|²`; the attempts are returned
/// in order (the first is the plain IK), the kept one marked `chosen`.
///
/// # Errors
/// As [`ik_fit`].
pub fn robust_ik(
    model: &PanoManModel,
    ik: &IkSolver,
    c: &Constraints,
    cfg: &IkConfig,
    q: &QualityOptions,
) -> Result<(IkResult, Vec<IkAttempt>)> {
    let first = ik_fit(ik, c, cfg)?;
    let problems = ik_problems(model, &first, q);
    let mut attempts = vec![IkAttempt::of("first", &first, problems)];
    if attempts[0].problems.is_empty() || !q.retry {
        attempts[0].chosen = true;
        return Ok((first, attempts));
    }
    let starts = retry_starts(cfg);
    let tried = starts
        .par_iter()
        .map(|(name, sc, cont)| {
            let mut r = ik_fit(ik, c, sc)?;
            if *cont {
                let base = IkConfig {
                    initial_state: Some(r.state.clone()),
                    ..cfg.clone()
                };
                let its = r.iterations;
                r = ik_fit(ik, c, &base)?;
                r.iterations += its;
            }
            let p = ik_problems(model, &r, q);
            Ok((IkAttempt::of(name, &r, p), r))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut results = vec![first];
    for (a, r) in tried {
        attempts.push(a);
        results.push(r);
    }
    let data = |r: &IkResult| -> f64 {
        r.residuals
            .iter()
            .map(|e| e.weight * e.distance * e.distance)
            .sum()
    };
    let best = (0..results.len())
        .min_by(|&a, &b| {
            let ka = (!attempts[a].problems.is_empty(), data(&results[a]));
            let kb = (!attempts[b].problems.is_empty(), data(&results[b]));
            ka.partial_cmp(&kb).unwrap_or(std::cmp::Ordering::Equal)
        })
        .expect("at least one attempt");
    attempts[best].chosen = true;
    Ok((results.swap_remove(best), attempts))
}

/// The fit's starting point from an IK result: its posed and rest meshes, its skeleton pose
/// (local Euler angles in radians by bone name, for the motion MLP) and, when the IK twisted
/// an arm's `*02` bone beyond the sampler's range, the guide mesh of [`Init::guide`] (the same
/// pose with those twists clamped to the range, where the rig's skin does not collapse).
pub fn init_of(r: &IkResult, ik: &IkSolver, names: &[String]) -> Init {
    let pose = ik.pose_params(&r.state);
    let theta = names
        .iter()
        .zip(&pose.euler_deg)
        .filter(|(_, e)| **e != [0.0; 3])
        .map(|(n, e)| (n.clone(), e.map(f64::to_radians)))
        .collect();
    let mut clamped = r.params.clone();
    let mut changed = false;
    for (n, e) in names.iter().zip(clamped.pose.euler_deg.iter_mut()) {
        if crate::ik::ik_wide_range(n)[1].is_none() {
            continue;
        }
        if let Some([_, [lo, hi], _]) = panoman_human::sampling::bone_range(n)
            && (e[1] < lo || e[1] > hi)
        {
            e[1] = e[1].clamp(lo, hi);
            changed = true;
        }
    }
    // Beyond the sampler's twist range the start is the same pose skinned by dual quaternions
    // (no candy-wrapper collapse: the shell does not undo a collapsed start, whose folded
    // dihedral angles sit in another basin), and the first guidance is projected from the
    // clamped-twist LBS mesh.
    let wide = || {
        Some((
            ik.posed_mesh_dqs(&r.params).ok()?,
            ik.posed_mesh(&clamped).ok()?,
        ))
    };
    let (posed, guide) = match changed.then(wide).flatten() {
        Some((dqs, g)) => (dqs, Some(g)),
        None => (r.posed.clone(), None),
    };
    Init {
        posed,
        rest: r.rest.clone(),
        theta: Some(theta),
        guide,
    }
}

/// IK settings for keypoints with Gaussian noise of standard deviation `sigma` (m) per
/// coordinate: the priors grow with the noise variance (a MAP estimate whose data term is
/// `Σ |k − k̂|²` in m²): pose `1e−6 + 4σ²` per rad², phenotype `1e−5 + 4σ²`, face units
/// `1e−7 + 0.4σ²` (at σ = 5 mm: 1e−4, 1.1e−4, 1e−5, chosen on held-out people, where they
/// bring the LBS error from 18.5 to 11.9 mm). `sigma = 0` gives the exact-keypoint defaults.
pub fn ik_config_for_noise(sigma: f64) -> IkConfig {
    let v = sigma * sigma;
    IkConfig {
        pose_prior: 1e-6 + 4.0 * v,
        phenotype_prior: 1e-5 + 4.0 * v,
        face_unit_prior: 1e-7 + 0.4 * v,
        ..IkConfig::default()
    }
}
