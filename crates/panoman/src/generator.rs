//! [`Generator`]: Anny-equivalent meshes (phenotype, face units, local changes, 163-bone pose)
//! on the anny, full or small topology.
use std::sync::Arc;

use panoman_human::generator::Generator as RawGenerator;
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::GeneratorParams;
use panoman_human::rigfile::RigData;
use panoman_mesh::geom::V3;

use crate::error::{Error, Result};
use crate::model::Model;

/// The open human generator (equal to anny 0.6.2's forward pass to ≤ 2.3e-15 m on the
/// reference cases), with its map onto the template topologies. Cheap to clone.
#[derive(Clone)]
pub struct Generator {
    generator: Arc<RawGenerator>,
    map: Arc<TopologyMap>,
}

impl Generator {
    /// Loads the generator from the asset tree (`$PANOMAN_ASSETS` or the user cache; fetched
    /// with pip on first use).
    ///
    /// # Errors
    /// Asset errors.
    pub fn load() -> Result<Generator> {
        let assets = panoman_human::assets::ensure_default()?;
        let rig = RigData::from_assets(&assets)?;
        Ok(Generator {
            generator: rig.generator,
            map: rig.map,
        })
    }

    /// The generator embedded in a model file (no asset access).
    ///
    /// # Errors
    /// [`Error::Invalid`] if the model file carries no rig.
    pub fn from_model(model: &Model) -> Result<Generator> {
        let rig = model.inner().rig.as_ref().ok_or_else(|| {
            Error::Invalid("the model file carries no rig (see `panoman embed-rig`)".into())
        })?;
        Ok(Generator {
            generator: rig.generator.clone(),
            map: rig.map.clone(),
        })
    }

    /// The rig's bone names (DFS order; the keys of `pose_euler_xyz_deg`).
    pub fn bone_names(&self) -> &[String] {
        self.generator.bone_names()
    }

    /// The posed mesh of `params` on `topology` (metres).
    ///
    /// # Errors
    /// Invalid parameters (ranges, unknown local changes).
    pub fn generate(&self, params: &GeneratorParams, topology: OutputTopology) -> Result<Vec<V3>> {
        params
            .shape
            .validate()
            .and_then(|()| params.pose.validate(self.generator.bone_names()))
            .map_err(|w| Error::Invalid(format!("generator parameters: {w}")))?;
        let id = self.generator.identity(&params.shape)?;
        let posed = id.pose(&params.pose);
        Ok(self.map.map(topology, &posed.vertices))
    }

    /// Parses generator parameters from their JSON layout (`docs/formats.md`: phenotype, face
    /// units, local changes, per-bone Euler XYZ angles in degrees, root rotation/translation).
    ///
    /// # Errors
    /// Malformed JSON, unknown names, values out of range.
    pub fn parse_params(&self, json: &str) -> Result<GeneratorParams> {
        Ok(self.generator.parse_params(json)?)
    }

    /// The faces of `topology`.
    pub fn faces(&self, topology: OutputTopology) -> &[[u32; 3]] {
        self.map.faces(topology)
    }
}
