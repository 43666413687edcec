//! Generator parameters: shape (phenotype docs/design/assets.md §5.1, face units docs/design/assets.md §5.4, local changes docs/design/assets.md §5.5) and pose
//! (local-bone Euler angles per bone, root rotation about world Z, docs/design/rig-and-ik.md §2.4), and their JSON form.
//!
//! JSON layout (the reference fixtures' `case_<name>.json`; every key optional):
//!
//! ```json
//! {
//!   "phenotype": {"gender": 0.2, "age": 0.7},
//!   "facial_actions": {"jawOpen": 0.4},
//!   "local_changes": {"stomach-pregnant-incr": -0.3},
//!   "pose_euler_xyz_deg": {"lowerarm01.L": [60.0, 0.0, 0.0]},
//!   "root_rotation_z_deg": 30.0,
//!   "root_translation_m": [0.0, 0.0, 0.0],
//!   "euler_convention": "informative text, ignored"
//! }
//! ```
//!
//! Missing keys mean defaults (phenotype 0.5, units 0, changes 0, identity pose). Unknown
//! top-level keys, unknown names, non-numbers, non-finite and out-of-range values are errors
//! with one line naming the key.
//!
//! Euler convention: per bone, in its rest frame (Y = head → tail), `E = Rz(z)·Ry(y)·Rx(x)`
//! (Blender "XYZ"), degrees; the delta is `D_c = [E | 0]`. Right-side bones are *not*
//! mirrored here: the angles are the bone's own (a mirrored motion of a `.L` pose is
//! `(x, −y, −z)` on the `.R` bone, docs/design/rig-and-ik.md §3.1). Root: `D_0 = [Rz(θ)·E_root | h_0 + u]` with
//! `θ = root_rotation_z_deg`, `u = root_translation_m`: the body turns about the vertical
//! through the root head, which stays in place (plus `u`).

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use crate::error::{HumanError, Result};
use crate::generator::Generator;
use crate::phenotype::{FACE_UNITS, PHENOTYPE_NAMES, Phenotype, face_unit_index};

/// Largest accepted |angle| in degrees (bone Euler angles and root rotation).
pub const MAX_ANGLE_DEG: f64 = 360.0;

/// Largest accepted |root translation| component in metres.
pub const MAX_TRANSLATION_M: f64 = 1000.0;

/// Shape parameters of an identity.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeParams {
    /// Phenotype (docs/design/assets.md §5.1).
    pub phenotype: Phenotype,
    /// Face-unit values in [`FACE_UNITS`] order, each in [0, 1] (docs/design/assets.md §5.4).
    pub facial_actions: [f64; 52],
    /// Local-change values by label, each in [−1, 1] (docs/design/assets.md §5.5).
    pub local_changes: BTreeMap<String, f64>,
}

impl Default for ShapeParams {
    /// Default phenotype, no face units, no local changes.
    fn default() -> Self {
        ShapeParams {
            phenotype: Phenotype::default(),
            facial_actions: [0.0; 52],
            local_changes: BTreeMap::new(),
        }
    }
}

impl ShapeParams {
    /// Checks ranges: phenotype (see [`Phenotype::validate`]), face units ∈ [0, 1], local
    /// changes ∈ [−1, 1], all finite. Local-change *labels* are checked by the generator.
    ///
    /// # Errors
    /// One line naming the offending parameter.
    pub fn validate(&self) -> Result<()> {
        self.validate_msg().map_err(HumanError::Invalid)
    }

    /// [`Self::validate`] with the message as a `String`.
    fn validate_msg(&self) -> std::result::Result<(), String> {
        self.phenotype.validate_msg()?;
        for (k, &v) in self.facial_actions.iter().enumerate() {
            check_range(&format!("facial action `{}`", FACE_UNITS[k]), v, 0.0, 1.0)?;
        }
        for (label, &v) in &self.local_changes {
            check_range(&format!("local change `{label}`"), v, -1.0, 1.0)?;
        }
        Ok(())
    }

    /// Sets a face unit by name.
    ///
    /// # Errors
    /// An unknown unit name.
    pub fn set_facial_action(&mut self, unit: &str, v: f64) -> Result<()> {
        self.set_facial_action_msg(unit, v)
            .map_err(HumanError::Invalid)
    }

    /// [`Self::set_facial_action`] with the message as a `String`.
    fn set_facial_action_msg(&mut self, unit: &str, v: f64) -> std::result::Result<(), String> {
        let k = face_unit_index(unit).ok_or_else(|| format!("unknown facial action `{unit}`"))?;
        self.facial_actions[k] = v;
        Ok(())
    }
}

/// Pose parameters (local-bone parameterization, docs/design/rig-and-ik.md §2.4; see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseParams {
    /// Euler angles `[x, y, z]` in degrees per bone in rig (DFS) order, `E = Rz·Ry·Rx`;
    /// empty means all zero. Entry 0 (root) composes after the Z rotation.
    pub euler_deg: Vec<[f64; 3]>,
    /// Rotation of the whole body about the world Z axis through the root head, degrees.
    pub root_rotation_z_deg: f64,
    /// Translation added to the root head, metres.
    pub root_translation: [f64; 3],
}

impl PoseParams {
    /// Checks finiteness and ranges: |angles| ≤ [`MAX_ANGLE_DEG`], |translation| ≤
    /// [`MAX_TRANSLATION_M`]; `bone_names` names the entries in messages and fixes the length.
    ///
    /// # Errors
    /// One line naming the offending value.
    pub fn validate(&self, bone_names: &[String]) -> Result<()> {
        self.validate_msg(bone_names).map_err(HumanError::Invalid)
    }

    /// [`Self::validate`] with the message as a `String`.
    fn validate_msg(&self, bone_names: &[String]) -> std::result::Result<(), String> {
        if !self.euler_deg.is_empty() && self.euler_deg.len() != bone_names.len() {
            return Err(format!(
                "pose has {} Euler triples, expected {} (one per bone) or none",
                self.euler_deg.len(),
                bone_names.len()
            ));
        }
        for (e, name) in self.euler_deg.iter().zip(bone_names) {
            for (a, axis) in e.iter().zip(["x", "y", "z"]) {
                let what = format!("pose angle `{name}`.{axis} (degrees)");
                check_range(&what, *a, -MAX_ANGLE_DEG, MAX_ANGLE_DEG)?;
            }
        }
        check_range(
            "`root_rotation_z_deg`",
            self.root_rotation_z_deg,
            -MAX_ANGLE_DEG,
            MAX_ANGLE_DEG,
        )?;
        for (t, axis) in self.root_translation.iter().zip(["x", "y", "z"]) {
            let what = format!("`root_translation_m`.{axis}");
            check_range(&what, *t, -MAX_TRANSLATION_M, MAX_TRANSLATION_M)?;
        }
        Ok(())
    }
}

/// Shape and pose of one generated mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeneratorParams {
    /// Identity parameters.
    pub shape: ShapeParams,
    /// Pose parameters.
    pub pose: PoseParams,
}

/// The JSON file layout (see the module docs).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParamsFile {
    #[serde(default)]
    phenotype: BTreeMap<String, f64>,
    #[serde(default)]
    facial_actions: BTreeMap<String, f64>,
    #[serde(default)]
    local_changes: BTreeMap<String, f64>,
    #[serde(default)]
    pose_euler_xyz_deg: BTreeMap<String, [f64; 3]>,
    #[serde(default)]
    root_rotation_z_deg: f64,
    #[serde(default)]
    root_translation_m: [f64; 3],
    #[serde(default)]
    #[allow(dead_code)]
    euler_convention: Option<String>,
}

fn check_range(what: &str, v: f64, lo: f64, hi: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{what} is not a finite number ({v})"));
    }
    if v < lo || v > hi {
        return Err(format!("{what} = {v} is outside its range [{lo}, {hi}]"));
    }
    Ok(())
}

impl GeneratorParams {
    /// Parses and validates parameters in the JSON layout of the module docs.
    ///
    /// `bone_names` (rig order) and `local_change_labels` are the names the assets define
    /// ([`Generator::bone_names`], [`Generator::local_change_labels`]).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] with one line: invalid JSON or an unknown top-level key (serde's
    /// message with line/column), an unknown phenotype / facial action / local change / bone
    /// name, a non-finite or out-of-range value.
    pub fn from_json(
        text: &str,
        bone_names: &[String],
        local_change_labels: &[String],
    ) -> Result<GeneratorParams> {
        let f: ParamsFile = serde_json::from_str(text)
            .map_err(|e| HumanError::Invalid(format!("invalid parameters: {e}")))?;
        let inv = HumanError::Invalid;
        let mut shape = ShapeParams::default();
        for (name, &v) in &f.phenotype {
            let slot = shape.phenotype.get_mut(name).ok_or_else(|| {
                inv(format!(
                    "unknown phenotype `{name}` (expected one of {})",
                    PHENOTYPE_NAMES.join(", ")
                ))
            })?;
            *slot = v;
        }
        for (unit, &v) in &f.facial_actions {
            shape.set_facial_action(unit, v)?;
        }
        for (label, &v) in &f.local_changes {
            if !local_change_labels.iter().any(|l| l == label) {
                return Err(inv(format!("unknown local change `{label}`")));
            }
            shape.local_changes.insert(label.clone(), v);
        }
        shape.validate()?;
        let mut pose = PoseParams {
            euler_deg: Vec::new(),
            root_rotation_z_deg: f.root_rotation_z_deg,
            root_translation: f.root_translation_m,
        };
        if !f.pose_euler_xyz_deg.is_empty() {
            pose.euler_deg = vec![[0.0; 3]; bone_names.len()];
            for (bone, &e) in &f.pose_euler_xyz_deg {
                let c = bone_names
                    .iter()
                    .position(|b| b == bone)
                    .ok_or_else(|| inv(format!("unknown bone `{bone}` in pose_euler_xyz_deg")))?;
                pose.euler_deg[c] = e;
            }
        }
        pose.validate(bone_names)?;
        Ok(GeneratorParams { shape, pose })
    }

    /// Reads a parameter file ([`GeneratorParams::from_json`]).
    ///
    /// # Errors
    /// I/O, or [`HumanError::Format`] naming the file and what is wrong.
    pub fn read(
        path: &Path,
        bone_names: &[String],
        local_change_labels: &[String],
    ) -> Result<GeneratorParams> {
        let text = std::fs::read_to_string(path).map_err(|e| HumanError::io(path, e))?;
        GeneratorParams::from_json(&text, bone_names, local_change_labels).map_err(|e| match e {
            HumanError::Invalid(what) => HumanError::format(path, what),
            other => other,
        })
    }

    /// The parameters as JSON in the same layout (non-default entries only; angles per bone
    /// name).
    pub fn to_json(&self, bone_names: &[String]) -> serde_json::Value {
        use serde_json::{Map, Value, json};
        let mut phen = Map::new();
        for name in PHENOTYPE_NAMES {
            let v = self.shape.phenotype.get(name).unwrap_or(0.5);
            if v != 0.5 || name_is_default_six(name) {
                phen.insert(name.into(), json!(v));
            }
        }
        let mut fa = Map::new();
        for (k, &v) in self.shape.facial_actions.iter().enumerate() {
            if v != 0.0 {
                fa.insert(FACE_UNITS[k].into(), json!(v));
            }
        }
        let lc: Map<String, Value> = self
            .shape
            .local_changes
            .iter()
            .filter(|(_, v)| **v != 0.0)
            .map(|(k, v)| (k.clone(), json!(v)))
            .collect();
        let mut pose = Map::new();
        for (e, name) in self.pose.euler_deg.iter().zip(bone_names) {
            if *e != [0.0; 3] {
                pose.insert(name.clone(), json!(e));
            }
        }
        json!({
            "phenotype": phen,
            "facial_actions": fa,
            "local_changes": lc,
            "pose_euler_xyz_deg": pose,
            "root_rotation_z_deg": self.pose.root_rotation_z_deg,
            "root_translation_m": self.pose.root_translation,
        })
    }
}

fn name_is_default_six(name: &str) -> bool {
    PHENOTYPE_NAMES[..6].contains(&name)
}

impl Generator {
    /// [`GeneratorParams::from_json`] with this generator's bone and local-change names.
    ///
    /// # Errors
    /// As [`GeneratorParams::from_json`].
    pub fn parse_params(&self, text: &str) -> Result<GeneratorParams> {
        GeneratorParams::from_json(text, self.bone_names(), &self.local_change_labels())
    }

    /// [`GeneratorParams::read`] with this generator's bone and local-change names.
    ///
    /// # Errors
    /// As [`GeneratorParams::read`].
    pub fn read_params(&self, path: &Path) -> Result<GeneratorParams> {
        GeneratorParams::read(path, self.bone_names(), &self.local_change_labels())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> (Vec<String>, Vec<String>) {
        (
            vec!["root".into(), "jaw".into()],
            vec!["nose-trans-up".into()],
        )
    }

    #[test]
    fn parses_and_rejects() {
        let (b, l) = names();
        let p = GeneratorParams::from_json(
            r#"{"phenotype": {"age": 0.7}, "facial_actions": {"jawOpen": 0.5},
                "local_changes": {"nose-trans-up": -0.2},
                "pose_euler_xyz_deg": {"jaw": [10, 0, -1]}, "root_rotation_z_deg": 5,
                "euler_convention": "x"}"#,
            &b,
            &l,
        )
        .unwrap();
        assert_eq!(p.shape.phenotype.age, 0.7);
        assert_eq!(p.shape.phenotype.gender, 0.5);
        assert_eq!(p.shape.facial_actions[24], 0.5);
        assert_eq!(p.pose.euler_deg, vec![[0.0; 3], [10.0, 0.0, -1.0]]);
        let err = |t: &str| {
            GeneratorParams::from_json(t, &b, &l)
                .unwrap_err()
                .to_string()
        };
        assert!(err(r#"{"phenotype": {"agee": 0.5}}"#).contains("unknown phenotype `agee`"));
        assert!(err(r#"{"phenotype": {"age": 1.5}}"#).contains("outside its range"));
        assert!(err(r#"{"phenotype": {"age": NaN}}"#).contains("invalid parameters"));
        assert!(err(r#"{"facial_actions": {"jawOpem": 0.5}}"#).contains("`jawOpem`"));
        assert!(err(r#"{"local_changes": {"x": 0.5}}"#).contains("unknown local change `x`"));
        assert!(err(r#"{"pose_euler_xyz_deg": {"arm": [0,0,0]}}"#).contains("unknown bone `arm`"));
        assert!(err(r#"{"pose_euler_xyz_deg": {"jaw": [0,1e9,0]}}"#).contains("jaw"));
        assert!(err(r#"{"pose": {}}"#).contains("unknown field `pose`"));
    }
}
