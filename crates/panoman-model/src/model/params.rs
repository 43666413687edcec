//! The model's parameters: [`BlockName`] (the six β blocks) and [`Params`] (α, β per block, the
//! rigid placement; the `params.json` layout of docs/formats.md).

use super::{BLOCK_NAMES, PanoManModel};
use crate::error::{ModelError, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The six β blocks: {RL, RA} × {body, face, hands} (PanoMan §4). Component 0 of each block is
/// the part's mean with a free coefficient, so a block trained with K components holds K + 1
/// coefficients. In files a block is its name ([`BlockName::as_str`]). The variants are
/// declared in the order of their names, so that a map keyed by blocks lists them as one keyed
/// by names would; [`BlockName::ALL`] is the model's β order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum BlockName {
    /// Relative dihedral angles of the body.
    BodyAngle,
    /// Relative edge lengths of the body.
    BodyLength,
    /// Relative dihedral angles of the face.
    FaceAngle,
    /// Relative edge lengths of the face.
    FaceLength,
    /// Relative dihedral angles of both hands.
    HandsAngle,
    /// Relative edge lengths of both hands.
    HandsLength,
}

impl BlockName {
    /// All six, in the model's β order (that of [`BLOCK_NAMES`]).
    pub const ALL: [BlockName; 6] = [
        BlockName::BodyLength,
        BlockName::FaceLength,
        BlockName::HandsLength,
        BlockName::BodyAngle,
        BlockName::FaceAngle,
        BlockName::HandsAngle,
    ];

    /// Position in [`BlockName::ALL`] (the index into [`PanoManModel::blocks`]).
    pub fn index(self) -> usize {
        match self {
            BlockName::BodyLength => 0,
            BlockName::FaceLength => 1,
            BlockName::HandsLength => 2,
            BlockName::BodyAngle => 3,
            BlockName::FaceAngle => 4,
            BlockName::HandsAngle => 5,
        }
    }

    /// The name used in files (`params.json` keys, `--block`): `body_l`, `face_l`, `hands_l`,
    /// `body_a`, `face_a`, `hands_a`.
    pub fn as_str(self) -> &'static str {
        BLOCK_NAMES[self.index()]
    }

    /// The block of a file name (see [`BlockName::as_str`]).
    ///
    /// # Errors
    /// [`ModelError::Params`] naming the unknown block and the known ones.
    pub fn parse(name: &str) -> Result<BlockName> {
        BlockName::ALL
            .into_iter()
            .find(|b| b.as_str() == name)
            .ok_or_else(|| {
                ModelError::Params(format!(
                    "unknown block '{name}' (expected one of {})",
                    BLOCK_NAMES.join(", ")
                ))
            })
    }
}

impl std::fmt::Display for BlockName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Serialize for BlockName {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for BlockName {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        BlockName::parse(&name).map_err(serde::de::Error::custom)
    }
}

/// Parameters of a PanoMan mesh: α (shape), β per block (motion), and a global rigid motion
/// applied after g (rotation as an axis-angle vector in radians, then translation in metres).
/// JSON layout of docs/formats.md; missing keys mean zeros, unknown keys are an error.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Shape coefficients (unit variance on the training identities); empty = 0.
    #[serde(default)]
    pub alpha: Vec<f64>,
    /// β per block; a missing block is all zeros.
    #[serde(default)]
    pub beta: BTreeMap<BlockName, Vec<f64>>,
    /// Translation after posing (metres).
    #[serde(default)]
    pub translation: [f64; 3],
    /// Rotation after posing, axis-angle (radians), about the origin of the posed mesh.
    #[serde(default)]
    pub rotation: [f64; 3],
}

impl Params {
    /// Reads and validates a parameter file against `model` (lengths, names, finiteness).
    pub fn read(path: &Path, model: &PanoManModel) -> Result<Params> {
        let text = std::fs::read_to_string(path).map_err(|source| ModelError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let p: Params = serde_json::from_str(&text).map_err(|e| ModelError::Format {
            path: path.to_path_buf(),
            what: format!("not a valid parameter file: {e}"),
        })?;
        p.validate_msg(model).map_err(|what| ModelError::Format {
            path: path.to_path_buf(),
            what,
        })?;
        Ok(p)
    }

    /// Checks names, lengths and finiteness against `model`; the message says what is wrong.
    ///
    /// # Errors
    /// [`ModelError::Params`] with one line.
    pub fn validate(&self, model: &PanoManModel) -> Result<()> {
        self.validate_msg(model).map_err(ModelError::Params)
    }

    /// [`Self::validate`] with the message as a `String`.
    fn validate_msg(&self, model: &PanoManModel) -> std::result::Result<(), String> {
        let k = model.shape.n_components();
        if !self.alpha.is_empty() && self.alpha.len() != k {
            return Err(format!(
                "alpha has {} values, the model has {k} shape components",
                self.alpha.len()
            ));
        }
        if let Some(i) = self.alpha.iter().position(|a| !a.is_finite()) {
            return Err(format!("alpha[{i}] is not finite"));
        }
        for (&name, b) in &self.beta {
            let block = model.block(name);
            if !b.is_empty() && b.len() != block.n_components() {
                return Err(format!(
                    "beta.{name} has {} values, the model has {} components in that block",
                    b.len(),
                    block.n_components()
                ));
            }
            if let Some(i) = b.iter().position(|x| !x.is_finite()) {
                return Err(format!("beta.{name}[{i}] is not finite"));
            }
        }
        if !self
            .translation
            .iter()
            .chain(&self.rotation)
            .all(|x| x.is_finite())
        {
            return Err("translation/rotation must be finite".into());
        }
        Ok(())
    }

    /// β of block `name` (zeros when missing or empty), with `k` entries.
    pub fn beta_of(&self, name: BlockName, k: usize) -> Vec<f64> {
        match self.beta.get(&name) {
            Some(b) if b.len() == k => b.clone(),
            _ => vec![0.0; k],
        }
    }

    /// Writes the parameters as pretty JSON, atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self).expect("params serialize");
        Ok(panoman_mesh::io::write_bytes_atomically(
            path,
            text.as_bytes(),
        )?)
    }
}
