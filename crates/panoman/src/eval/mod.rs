//! The paper's experiments on open data (`panoman eval`): representation error and component
//! curves (Fig. 7, 18), fits of held-out people from exact and noisy TC-133 keypoints
//! (Fig. 19–20), a held-out motion clip tracked frame after frame, the twist study (Fig. 1,
//! 13), a composite motion (Fig. 16), the stress set (cases beyond the training sampler,
//! per case, PanoMan beside the LBS baseline) and stage timings (Table 1).
//!
//! [`run_all`] runs them in that order and returns an [`EvalOutput`]: the typed
//! [`EvalSummary`] (`summary.json`), the per-frame clip errors, the component curves and the
//! meshes a front end renders. Plots, renders and HTML are the caller's (the CLI's).
//!
//! The numerics are fixed by the preset and the seed: the same model, data, preset and seed
//! give the same figures (timings aside).
use std::path::PathBuf;
use std::time::Instant;

use panoman_fit::fit::FitOptions;
use panoman_fit::ik::IkConfig;
use panoman_fit::{FrameSolver, LbsRig};
use panoman_human::assets::AssetDir;
use panoman_human::dataset::Dataset;
use panoman_human::regions::Regions;
use panoman_human::template::{full_template, small_template};
use panoman_mesh::geom::V3;
use panoman_model::model::Params;
use panoman_model::train::CurvePoint;

use crate::error::{Error, Result};
use crate::model::Model;

mod clip;
mod composite;
mod fitting;
pub mod metrics;
mod representation;
mod stress;
pub mod summary;
mod timing;
mod twist;

pub use clip::ClipRow;
pub use metrics::{BodyRegions, Groups, PartErrors, REGION_NAMES, RegionErrors, mean_of};
pub use summary::*;

/// The sizes of an evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalPreset {
    /// `default` or `small`.
    pub name: String,
    /// Held-out people fitted from keypoints.
    pub people: usize,
    /// Frames of the held-out clip.
    pub clip_frames: usize,
    /// Keyframes of the held-out clip.
    pub clip_keyframes: usize,
    /// Twist angles of the twist study (degrees, ascending; the last is the "largest angle").
    pub twist_angles: Vec<f64>,
    /// Held-out rows per kind for the representation error.
    pub repr_rows: usize,
    /// Whether the representation error also measures the Gauss–Newton encoder.
    pub repr_gn: bool,
    /// Held-out rows per kind for the component curves.
    pub curve_rows: usize,
    /// Stress set: whole-body composites (body pose + gestures + expression).
    pub stress_composites: usize,
    /// Stress set: whole-body composites over the generator's full joint ranges.
    pub stress_whole_body: usize,
    /// Stress set: phenotypes at the sampler's edges (at most 5).
    pub stress_extremes: usize,
    /// Stress set: forearm twists (degrees).
    pub stress_twists_deg: Vec<f64>,
    /// Stress set: upper-arm and forearm rolls together, `[upper arm, forearm]` (degrees).
    pub stress_arm_rolls_deg: Vec<[f64; 2]>,
    /// Stress set: contact cases (hand on head, hand at chin; at most 2).
    pub stress_contacts: usize,
    /// Stress set: postures (deep sit, crouch, kneel, a raised foot, crossed legs; at most 5).
    pub stress_postures: usize,
}

impl EvalPreset {
    /// `default`: 10 held-out people, a 72-frame clip, twists every 30°.
    pub fn full() -> EvalPreset {
        EvalPreset {
            name: "default".into(),
            people: 10,
            clip_frames: 72,
            clip_keyframes: 5,
            twist_angles: vec![0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 170.0, 180.0],
            repr_rows: 20,
            repr_gn: true,
            curve_rows: 8,
            stress_composites: 6,
            stress_whole_body: 12,
            stress_extremes: 5,
            stress_twists_deg: vec![120.0, 150.0, 170.0, 180.0],
            stress_arm_rolls_deg: vec![[72.0, 120.0], [100.0, 170.0]],
            stress_contacts: 2,
            stress_postures: 5,
        }
    }

    /// `small` (CI): 2 people, a 6-frame clip, five twist angles.
    pub fn small() -> EvalPreset {
        EvalPreset {
            name: "small".into(),
            people: 2,
            clip_frames: 6,
            clip_keyframes: 2,
            twist_angles: vec![0.0, 90.0, 150.0, 170.0, 180.0],
            repr_rows: 4,
            repr_gn: false,
            curve_rows: 2,
            stress_composites: 1,
            stress_whole_body: 1,
            stress_extremes: 1,
            stress_twists_deg: vec![150.0],
            stress_arm_rolls_deg: Vec::new(),
            stress_contacts: 1,
            stress_postures: 1,
        }
    }

    /// The preset called `name` (`default` or `small`).
    ///
    /// # Errors
    /// [`Error::Invalid`] for another name.
    pub fn named(name: &str) -> Result<EvalPreset> {
        match name {
            "default" => Ok(EvalPreset::full()),
            "small" => Ok(EvalPreset::small()),
            other => Err(Error::Invalid(format!(
                "unknown preset `{other}` (expected `default` or `small`)"
            ))),
        }
    }
}

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct EvalConfig {
    /// The model file.
    pub model: PathBuf,
    /// The dataset the model was trained on (its held-out identities are evaluated).
    pub data: PathBuf,
    /// The sizes.
    pub preset: EvalPreset,
    /// Seed of the held-out clip and the keypoint noise.
    pub seed: u64,
    /// Fit the stress set from the older TC-127 layout: its cases' six foot keypoints are
    /// left out of the targets (what a body detector without foot points gives).
    pub stress_without_feet: bool,
    /// Also measure the representation of the stress set's composites (both kinds): each
    /// ground truth encoded ([`Model::encode`] with the person's true rest shape, correction
    /// applied) and posed again (about a minute per case on the default model).
    pub stress_representation: bool,
}

/// Progress of [`run_all`], for a front end's spinner.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EvalProgress<'a> {
    /// An experiment starts (its name).
    Experiment(&'a str),
    /// What the current experiment is doing now (e.g. `representation error: body row 3/20`).
    Detail(&'a str),
    /// `done` of `total` steps (fits, frames) of the current experiment are done.
    Step {
        /// Steps done.
        done: usize,
        /// Steps of the experiment.
        total: usize,
    },
}

/// Ground truth, PanoMan and the LBS baseline on one target (the model's topology, metres).
#[derive(Clone, Debug)]
pub struct MeshTriple {
    /// The target.
    pub truth: Vec<V3>,
    /// PanoMan's fit.
    pub panoman: Vec<V3>,
    /// The LBS rig's fit.
    pub lbs: Vec<V3>,
}

/// One twist of the forearm: the twisted target, its LBS fit and PanoMan fit.
#[derive(Clone, Debug)]
pub struct TwistRender {
    /// The twist (degrees).
    pub angle_deg: f64,
    /// The meshes.
    pub meshes: MeshTriple,
}

/// The composite motion (Fig. 16): three fits and the composite of their blocks.
#[derive(Clone, Debug)]
pub struct CompositeMeshes {
    /// Posed fits: body, expression, gesture, and the composite.
    pub posed: [Vec<V3>; 4],
    /// The composite's parameters (`composite.params.json`).
    pub params: Params,
}

/// The meshes of an evaluation worth rendering (faces: [`Model::faces`]).
#[derive(Clone, Debug, Default)]
pub struct EvalMeshes {
    /// The first held-out person, exact keypoints.
    pub fit_example: Option<MeshTriple>,
    /// The middle clip frame (the spatial error map, Fig. 21).
    pub error_map: Option<MeshTriple>,
    /// The forearm twisted by 90°, 150° and 180° (those of the preset's angles).
    pub twist_forearm: Vec<TwistRender>,
    /// The composite motion.
    pub composite: Option<CompositeMeshes>,
    /// Every case of the stress set, by name (the worst is `summary.stress.worst_case`).
    pub stress: Vec<(String, MeshTriple)>,
}

/// Everything [`run_all`] measures.
#[derive(Clone, Debug)]
pub struct EvalOutput {
    /// The model evaluated.
    pub model: Model,
    /// Every number (`summary.json`).
    pub summary: EvalSummary,
    /// The Fig. 7 curves.
    pub curves: Vec<CurvePoint>,
    /// Per clip frame (`clip.csv`).
    pub clip_frames: Vec<ClipRow>,
    /// Meshes to render.
    pub meshes: EvalMeshes,
}

/// The shared state of the experiments: the model, its dataset, the fitting machinery.
pub(crate) struct Bench {
    pub(crate) model: Model,
    pub(crate) ds: Dataset,
    pub(crate) regions: Regions,
    pub(crate) groups: metrics::Groups,
    pub(crate) body_regions: metrics::BodyRegions,
    pub(crate) solver: FrameSolver,
    pub(crate) opts: FitOptions,
    pub(crate) ikc: IkConfig,
}

impl Bench {
    fn open(cfg: &EvalConfig, assets: &AssetDir) -> Result<Bench> {
        let model = Model::load(&cfg.model)?;
        let pm = model.inner().clone();
        let ds = Dataset::open(&cfg.data)?;
        if ds.topology_hash != pm.topology_hash {
            return Err(Error::Format {
                path: cfg.data.clone(),
                what: format!(
                    "the dataset's topology ({}) is not the model's ({})",
                    ds.meta["topology"]["name"].as_str().unwrap_or("?"),
                    pm.topology_name
                ),
            });
        }
        let full = full_template(assets)?;
        let full_regions = Regions::full(assets, &full)?;
        let regions = match pm.topology_name.as_str() {
            "small" => {
                let small = small_template(assets, &full)?;
                Regions::small(&full_regions, &small)
                    .map_err(|e| Error::Invalid(format!("small regions: {e}")))?
            }
            _ => full_regions,
        };
        let groups = metrics::Groups::of(&regions);
        // The rig from the assets (as the figures were first measured), not the embedded one.
        let rig = LbsRig::load(assets, &pm)?;
        let body_regions =
            metrics::BodyRegions::of_rig(&rig.generator, &rig.map, rig.topology, &regions);
        let solver = FrameSolver::new(pm, rig)?;
        Ok(Bench {
            model,
            ds,
            regions,
            groups,
            body_regions,
            solver,
            opts: FitOptions::default(),
            ikc: IkConfig::default(),
        })
    }

    /// The LBS rig (read from the assets).
    pub(crate) fn rig(&self) -> &LbsRig {
        self.solver.rig()
    }

    /// Rows of the held-out identities of `kind` (1 body, 2 face, 3 hands), in row order.
    pub(crate) fn held_out_rows(&self, kind: u8) -> Vec<usize> {
        let ds = &self.ds;
        let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
        (0..ds.n_rows)
            .filter(|&r| ds.kind[r] == kind && held.contains(&ds.identity[r]))
            .collect()
    }
}

/// The stress set alone ([`run_all`]'s last experiment): its summary and, per case, the
/// ground truth and both fits.
pub struct StressOutput {
    /// Every case, their means and the worst case.
    pub summary: StressSummary,
    /// Per case (in order) its name and meshes (metres, the model's topology).
    pub meshes: Vec<(String, MeshTriple)>,
}

/// Runs only the stress set of `cfg.preset` on `cfg.model` (`cfg.data` is opened as by
/// [`run_all`]); `progress` hears each case.
///
/// # Errors
/// Those of [`run_all`].
pub fn run_stress(
    cfg: &EvalConfig,
    assets: &AssetDir,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<StressOutput> {
    progress(EvalProgress::Experiment("loading the model, data and rig"));
    let mut b = Bench::open(cfg, assets)?;
    progress(EvalProgress::Experiment("stress set"));
    let run = stress::run(&mut b, &cfg.preset, cfg.seed, cfg, progress)?;
    Ok(StressOutput {
        summary: run.summary,
        meshes: run.meshes,
    })
}

/// Runs every experiment (see the module docs) on `cfg.model` and its dataset `cfg.data`;
/// `assets` provide the template regions and the LBS rig. `progress` hears each experiment as
/// it starts and its steps as they finish.
///
/// # Errors
/// Unreadable or mismatched model and dataset (naming the file), a dataset without
/// held-out body rows, asset errors, numerical failures.
pub fn run_all(
    cfg: &EvalConfig,
    assets: &AssetDir,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<EvalOutput> {
    let t_all = Instant::now();
    let preset = &cfg.preset;
    progress(EvalProgress::Experiment("loading the model, data and rig"));
    let mut b = Bench::open(cfg, assets)?;

    progress(EvalProgress::Experiment(
        "representation error and component curves",
    ));
    let (representation, curves) = representation::run(&b, preset, progress)?;

    progress(EvalProgress::Experiment("fitting held-out people"));
    let held = fitting::run(&mut b, preset, cfg.seed, &cfg.data, progress)?;

    progress(EvalProgress::Experiment("held-out motion clip"));
    let clip = clip::run(&mut b, preset, cfg.seed, progress)?;

    progress(EvalProgress::Experiment("twist study"));
    let twist = twist::run(&mut b, preset, progress)?;

    progress(EvalProgress::Experiment("composite motion"));
    let composite = composite::run(&mut b, &held, progress)?;

    progress(EvalProgress::Experiment("stress set"));
    let stress = stress::run(&mut b, preset, cfg.seed, cfg, progress)?;

    let timing = timing::summary(&held.stage_times, &clip.warm_stage_times, &clip.warm_s);
    let meta = EvalMeta {
        data: cfg.data.display().to_string(),
        model: cfg.model.display().to_string(),
        preset: preset.name.clone(),
        seconds: t_all.elapsed().as_secs_f64(),
        seed: cfg.seed,
        topology: b.model.topology_name().to_string(),
    };
    let headline = timing::headline(&held.summary, &clip.summary, &twist.summary, &timing);
    let summary = EvalSummary {
        composite: composite.as_ref().map(|c| c.0),
        clip: clip.summary,
        fit_held_out: held.summary,
        headline,
        meta,
        representation,
        stress: stress.summary,
        timing,
        twist: twist.summary,
    };
    Ok(EvalOutput {
        model: b.model.clone(),
        summary,
        curves,
        clip_frames: clip.frames,
        meshes: EvalMeshes {
            fit_example: held.first_fit,
            error_map: clip.map_frame,
            twist_forearm: twist.forearm,
            composite: composite.map(|c| c.1),
            stress: stress.meshes,
        },
    })
}
