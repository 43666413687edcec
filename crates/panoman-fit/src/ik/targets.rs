//! Target keypoints and surface point targets of the solve.

use crate::error::{FitError, Result};
use panoman_human::keypoints::{
    KeypointGroup, KeypointsFile, N_KEYPOINTS, keypoint_index, keypoint_names,
};
use panoman_mesh::geom::V3;
/// One target keypoint: TC-133 index, position `k̂` (metres) and weight `w ≥ 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkTarget {
    /// TC-133 index ([`keypoint_names`]).
    pub index: usize,
    /// Target position in metres (world frame).
    pub position: V3,
    /// Weight `w_k ≥ 0` of the squared residual.
    pub weight: f64,
}

/// A set of target keypoints (any subset of the TC-133 names, each at most once).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct IkTargets {
    /// The targets (validated by [`IkTargets::validate`] before every solve).
    pub targets: Vec<IkTarget>,
}

fn check_target(t: &IkTarget) -> Result<()> {
    let name = keypoint_names()
        .get(t.index)
        .ok_or_else(|| {
            FitError::Invalid(format!(
                "target keypoint index {} is out of range (0..{N_KEYPOINTS})",
                t.index
            ))
        })?
        .as_str();
    if !t.position.iter().all(|x| x.is_finite()) {
        return Err(FitError::Invalid(format!(
            "target keypoint `{name}` has a non-finite position {:?}",
            t.position
        )));
    }
    if !t.weight.is_finite() || t.weight < 0.0 {
        return Err(FitError::Invalid(format!(
            "target keypoint `{name}` has an invalid weight {} (must be finite and ≥ 0)",
            t.weight
        )));
    }
    Ok(())
}

impl IkTargets {
    /// No targets.
    pub fn new() -> IkTargets {
        IkTargets::default()
    }

    /// Sets (or replaces) the target of TC-133 keypoint `index`.
    ///
    /// # Errors
    /// [`FitError::Invalid`]: index out of range, non-finite position, weight negative or
    /// non-finite.
    pub fn set(&mut self, index: usize, position: V3, weight: f64) -> Result<()> {
        let t = IkTarget {
            index,
            position,
            weight,
        };
        check_target(&t)?;
        match self.targets.iter_mut().find(|x| x.index == index) {
            Some(x) => *x = t,
            None => self.targets.push(t),
        }
        Ok(())
    }

    /// [`IkTargets::set`] by keypoint name.
    ///
    /// # Errors
    /// An unknown name, or the errors of [`IkTargets::set`].
    pub fn set_named(&mut self, name: &str, position: V3, weight: f64) -> Result<()> {
        let i = keypoint_index(name)
            .ok_or_else(|| FitError::Invalid(format!("unknown keypoint `{name}`")))?;
        self.set(i, position, weight)
    }

    /// All 133 keypoints of `points` (TC-133 order), weight 1 each.
    ///
    /// # Errors
    /// Not 133 points, or a non-finite point.
    pub fn all(points: &[V3]) -> Result<IkTargets> {
        if points.len() != N_KEYPOINTS {
            return Err(FitError::Invalid(format!(
                "expected {N_KEYPOINTS} keypoints, got {}",
                points.len()
            )));
        }
        let mut t = IkTargets::new();
        for (i, &p) in points.iter().enumerate() {
            t.set(i, p, 1.0)?;
        }
        Ok(t)
    }

    /// The targets of a keypoints file ([`KeypointsFile`]: positions and weights).
    ///
    /// # Errors
    /// As [`IkTargets::set`].
    pub fn from_file(file: &KeypointsFile) -> Result<IkTargets> {
        let mut t = IkTargets::new();
        for (&i, &p) in &file.points {
            t.set(i, p, file.weight(i))?;
        }
        Ok(t)
    }

    /// The targets of the given groups only.
    pub fn only(&self, groups: &[KeypointGroup]) -> IkTargets {
        IkTargets {
            targets: self
                .targets
                .iter()
                .filter(|t| t.index < N_KEYPOINTS && groups.contains(&KeypointGroup::of(t.index)))
                .copied()
                .collect(),
        }
    }

    /// Number of targets.
    pub fn len(&self) -> usize {
        self.targets.len()
    }

    /// True when there are no targets.
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// Checks the set: not empty, every target valid (see [`IkTargets::set`]), no index twice,
    /// positive total weight.
    ///
    /// # Errors
    /// [`FitError::Invalid`] with one line.
    pub fn validate(&self) -> Result<()> {
        if self.targets.is_empty() {
            return Err(FitError::Invalid("no target keypoints given".into()));
        }
        let mut seen = [false; N_KEYPOINTS];
        let mut total = 0.0;
        for t in &self.targets {
            check_target(t)?;
            if std::mem::replace(&mut seen[t.index], true) {
                return Err(FitError::Invalid(format!(
                    "target keypoint `{}` is given twice",
                    keypoint_names()[t.index]
                )));
            }
            total += t.weight;
        }
        if total <= 0.0 {
            return Err(FitError::Invalid(
                "every target keypoint has weight 0".into(),
            ));
        }
        Ok(())
    }
}

/// An extra surface point target of [`super::IkSolver::solve_with_points`]: a fixed linear
/// combination `P(p) = Σ_m b_m x_m(p)` of vertices `m` of the solver's topology (e.g. the
/// barycentric weights of a triangle, or one vertex with coefficient 1), a target position
/// `p̂` (metres) and a weight `w ≥ 0` in the units of the keypoint weights.
///
/// Residual: point-to-point `√w (P − p̂)`, or, with a `normal` `n̂` (any non-zero length;
/// normalised), point-to-plane `√w n̂ᵀ(P − p̂)`, which lets the point slide along the
/// target's tangent plane (the usual ICP linearisation of a distance to a surface).
#[derive(Clone, Debug, PartialEq)]
pub struct PointTarget {
    /// `(vertex of the solver's topology, b_m)` pairs.
    pub rows: Vec<(u32, f64)>,
    /// Target position `p̂` in metres (world frame).
    pub position: V3,
    /// Weight `w ≥ 0` of the squared residual (same units as [`IkTarget::weight`]).
    pub weight: f64,
    /// Normal `n̂` of a point-to-plane residual; `None`: point-to-point.
    pub normal: Option<V3>,
}
