//! Foot points: big toe, small toe and heel of each foot as vertices of the model's template —
//! what OpenPose BODY_25 (`LBigToe`, `LSmallToe`, `LHeel`, …) and COCO-WholeBody add to a body
//! layout, and what TC-127 lacks (its body stops at the ankles). Given as vertex handles
//! ([`crate::Targets::handles`]), they place the feet: the IK fits handles as point targets
//! (`docs/formats.md` §6.1), the shell fit as handles.
//!
//! Units: metres.

use panoman_human::params::{PoseParams, ShapeParams};
use panoman_mesh::geom::V3;

use crate::error::{Error, Result};
use crate::model::Model;

/// The six foot points, in the order of [`foot_points`]: `l_big_toe`, `l_small_toe`,
/// `l_heel`, `r_big_toe`, `r_small_toe`, `r_heel` ("left" is the character's left, +x; the
/// OpenPose BODY_25 indices are 19–24 in this order).
pub const FOOT_POINT_NAMES: [&str; 6] = [
    "l_big_toe",
    "l_small_toe",
    "l_heel",
    "r_big_toe",
    "r_small_toe",
    "r_heel",
];

/// The vertices of [`FOOT_POINT_NAMES`] on a standing rest mesh `rest` (`(V, 3)`, metres, Z
/// up, facing −Y, left +X, feet flat; e.g. the default identity at rest): per foot the
/// vertices within 3 cm of its lowest point (the sole), split at their mean |x| into a medial
/// and a lateral half; the big toe is the medial half's most forward vertex (least y), the
/// small toe the lateral half's, the heel the sole's rearmost (greatest y).
///
/// # Errors
/// [`Error::Invalid`] if a side of the mesh has no vertex or a sole no lateral half (not a
/// body mesh).
pub fn foot_points(rest: &[V3]) -> Result<[u32; 6]> {
    let mut out = [0u32; 6];
    for (k, side) in [1.0f64, -1.0].into_iter().enumerate() {
        let foot: Vec<usize> = (0..rest.len())
            .filter(|&i| rest[i][0] * side > 0.0)
            .collect();
        let low = foot
            .iter()
            .map(|&i| rest[i][2])
            .fold(f64::INFINITY, f64::min);
        let sole: Vec<usize> = foot
            .into_iter()
            .filter(|&i| rest[i][2] < low + 0.03)
            .collect();
        let mid = sole.iter().map(|&i| rest[i][0].abs()).sum::<f64>() / sole.len().max(1) as f64;
        let pick = |keep: &dyn Fn(usize) -> bool, key: &dyn Fn(usize) -> f64| {
            sole.iter()
                .copied()
                .filter(|&i| keep(i))
                .min_by(|&a, &b| key(a).total_cmp(&key(b)))
                .map(|i| i as u32)
                .ok_or_else(|| Error::Invalid("foot points: the mesh has no sole there".into()))
        };
        out[3 * k] = pick(&|i| rest[i][0].abs() < mid, &|i| rest[i][1])?;
        out[3 * k + 1] = pick(&|i| rest[i][0].abs() >= mid, &|i| rest[i][1])?;
        out[3 * k + 2] = pick(&|_| true, &|i| -rest[i][1])?;
    }
    Ok(out)
}

impl Model {
    /// The [`foot_points`] of this model's template, picked on the default identity's rest
    /// mesh (all phenotype values ½) of the embedded rig, in [`FOOT_POINT_NAMES`] order.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a model without an embedded rig (see `panoman embed-rig`) or on
    /// a topology the generator does not map to.
    pub fn foot_points(&self) -> Result<[u32; 6]> {
        let rig = self.inner().rig.as_ref().ok_or_else(|| {
            Error::Invalid("the model carries no rig (see `panoman embed-rig`)".into())
        })?;
        let id = rig
            .generator
            .identity(&ShapeParams::default())
            .map_err(|e| Error::Invalid(format!("default identity: {e}")))?;
        let rest = rig.map.map(
            self.output_topology()?,
            &id.pose(&PoseParams::default()).vertices,
        );
        foot_points(&rest)
    }
}
