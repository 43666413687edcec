//! The whole fit of one frame (PanoMan §5.3, algorithms.md §4.6): skeletal IK of the LBS rig
//! to the keypoints (pose, phenotype, face units) gives the initial mesh and rest shape; α is
//! the PCA projection of that rest shape and β the projection of the IK mesh's RL/RA; then the
//! staged shell fit of [`crate::fit`]. The LBS baseline is the IK alone.
use crate::error::{FitError, Result};
use crate::fit::{Constraints, FitOptions, FitResult, Fitter, Init};
use panoman_human::assets::AssetDir;
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::ik::{IkConfig, IkResult, IkSolver, IkState, IkTargets};
use panoman_human::keypoints::{KeypointSet, load_or_build};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::template::{full_template, small_template};
use panoman_model::model::PanoManModel;

/// The LBS rig on a model's template topology: the generator, its map onto the template, and
/// the TC-127 keypoint rows of that topology. Loaded once per session.
pub struct Rig {
    /// The Anny-equivalent generator.
    pub generator: Generator,
    /// Anny vertices → template vertices.
    pub map: TopologyMap,
    /// The model's topology.
    pub topology: OutputTopology,
    /// Keypoint rows on that topology.
    pub keypoints: KeypointSet,
}

impl Rig {
    /// Loads the rig for `model`'s topology (`full` or `small`) from the assets.
    pub fn load(assets: &AssetDir, model: &PanoManModel) -> Result<Rig> {
        let topology = match model.topology_name.as_str() {
            "full" => OutputTopology::Full,
            "small" => OutputTopology::Small,
            other => {
                return Err(FitError::Invalid(format!(
                    "the model's topology `{other}` has no LBS rig (expected full or small)"
                )));
            }
        };
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
        Ok(Rig {
            generator,
            map,
            topology,
            keypoints,
        })
    }

    /// The IK solver of this rig (precomputations once; reuse it across frames).
    pub fn ik_solver(&self) -> Result<IkSolver<'_>> {
        Ok(IkSolver::new(
            &self.generator,
            &self.map,
            self.topology,
            &self.keypoints,
        )?)
    }
}

/// Skeletal IK of the rig to the constraint set's keypoints (the initializer, and the LBS
/// baseline on its own).
pub fn ik_fit(ik: &IkSolver<'_>, c: &Constraints, cfg: &IkConfig) -> Result<IkResult> {
    if c.keypoints.points.is_empty() {
        return Err(FitError::Invalid(
            "the initializer needs keypoints (none given)".into(),
        ));
    }
    let targets = IkTargets::from_file(&c.keypoints)?;
    Ok(ik.solve(&targets, cfg)?)
}

/// One frame: skeletal IK (cold, or warm-started from `warm`, e.g. the previous frame's
/// [`IkResult::state`], which runs only the IK's final stage), then the staged PanoMan fit
/// from the IK mesh. Returns the IK result and the fit.
pub fn fit_frame(
    rig: &Rig,
    ik: &IkSolver<'_>,
    fitter: &mut Fitter<'_>,
    c: &Constraints,
    ik_cfg: &IkConfig,
    opts: &FitOptions,
    warm: Option<&IkState>,
) -> Result<(IkResult, FitResult)> {
    fitter.validate(c)?;
    let cfg = IkConfig {
        initial_state: warm.cloned(),
        ..ik_cfg.clone()
    };
    let r = ik_fit(ik, c, &cfg)?;
    let init = init_of(&r, ik, rig.generator.bone_names());
    let fit = fitter.fit(c, &init, opts)?;
    Ok((r, fit))
}

/// The fit's starting point from an IK result: its posed and rest meshes and its skeleton pose
/// (local Euler angles in radians by bone name, for the motion MLP).
pub fn init_of(r: &IkResult, ik: &IkSolver<'_>, names: &[String]) -> Init {
    let pose = ik.pose_params(&r.state);
    let theta = names
        .iter()
        .zip(&pose.euler_deg)
        .filter(|(_, e)| **e != [0.0; 3])
        .map(|(n, e)| (n.clone(), e.map(f64::to_radians)))
        .collect();
    Init {
        posed: r.posed.clone(),
        rest: r.rest.clone(),
        theta: Some(theta),
    }
}
