//! [`Targets`]: what a fit is asked to match (keypoints, vertex handles, level pairs, a point
//! cloud), and their checks as data. [`crate::fit::Constraints`] adds what the fit holds fixed
//! or carries from the previous frame.
use std::collections::BTreeMap;
use std::path::Path;

use crate::error::{FitError, Result};
use crate::fit::{LevelPair, VertexHandle};
use panoman_human::keypoints::{KeypointsFile, keypoint_index};
use panoman_mesh::geom::{MAX_COORDINATE, V3, is_in_bounds};

/// A point cloud (metres), e.g. a scan, with optional unit normals (one per point).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Points (metres).
    pub positions: Vec<V3>,
    /// Unit normals, one per point (enables the normal test of correspondence rejection).
    pub normals: Option<Vec<V3>>,
}

/// The targets of one fit (one frame).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Targets {
    /// Keypoints: any subset of the 133 TC-133 keypoints (metres), each with a weight
    /// (default 1; 0 skips it). The fit's initializer needs at least a few body ones.
    pub keypoints: KeypointsFile,
    /// Vertex handles: template vertex → target position (metres), with a relative weight.
    pub handles: Vec<VertexHandle>,
    /// Level constraints between vertex pairs, `n̂ᵀ(x_a − x_b) = d` (metres; e.g. the soles
    /// of planted feet from `panoman::feet::FootContacts`), fitted by the skeletal IK.
    pub levels: Vec<LevelPair>,
    /// A point cloud fitted by ICP (skeletal ICP of the initializer, then the shell fit's
    /// point-to-plane passes).
    pub points: Option<PointCloud>,
}

impl Targets {
    /// Every keypoint of `positions` (e.g. the model's keypoints of a mesh), weight 1:
    /// 133 in TC-133 order, or 127 in the older TC-127 order (no feet).
    ///
    /// # Panics
    /// For any other count ([`KeypointsFile::from_points`] returns the error instead).
    pub fn from_keypoints(positions: &[V3]) -> Targets {
        Targets {
            keypoints: KeypointsFile::from_points(positions)
                .unwrap_or_else(|e| panic!("Targets::from_keypoints: {e}")),
            ..Default::default()
        }
    }

    /// Keypoints by TC-133 name (`{"l_wrist": [x, y, z], …}`), weight 1.
    ///
    /// # Errors
    /// [`FitError::Invalid`] naming an unknown keypoint or a non-finite position.
    pub fn from_named(points: &BTreeMap<String, V3>) -> Result<Targets> {
        let mut kp = KeypointsFile::default();
        for (name, p) in points {
            let k = keypoint_index(name)
                .ok_or_else(|| FitError::Invalid(format!("unknown keypoint '{name}'")))?;
            if !p.iter().all(|c| c.is_finite()) {
                return Err(FitError::Invalid(format!(
                    "keypoint '{name}' is not finite"
                )));
            }
            kp.points.insert(k, *p);
        }
        Ok(Targets {
            keypoints: kp,
            ..Default::default()
        })
    }

    /// Reads a TC-133 keypoint file (`{"keypoints": {name: [x, y, z]}, "weights": {...}}`,
    /// see `docs/formats.md`).
    ///
    /// # Errors
    /// [`FitError::Human`] naming the file.
    pub fn read_keypoints(path: &Path) -> Result<Targets> {
        Ok(Targets {
            keypoints: KeypointsFile::read(path)?,
            ..Default::default()
        })
    }
}

/// One handle's position (finite, within [`MAX_COORDINATE`]) and weight (finite, ≥ 0).
pub fn check_handle(i: usize, h: &VertexHandle) -> std::result::Result<(), String> {
    if !h.position.iter().all(|x| x.is_finite()) || !h.weight.is_finite() || h.weight < 0.0 {
        return Err(format!(
            "handle {i}: non-finite position or weight, or negative weight"
        ));
    }
    if !is_in_bounds(h.position) {
        return Err(format!(
            "handle {i} (vertex {}): position {:?} is out of bounds (|coordinate| > \
             {MAX_COORDINATE} m; positions are in metres)",
            h.vertex, h.position
        ));
    }
    Ok(())
}

/// The fewest points a point cloud may have.
pub const MIN_CLOUD_POINTS: usize = 3;
/// The largest extent (bounding-box diagonal, metres) of a point cloud of one person, and the
/// farthest its centroid may be from the keypoints' centroid: 10 m. A larger cloud is almost
/// surely in millimetres or centimetres.
pub const MAX_CLOUD_EXTENT: f64 = 10.0;

impl PointCloud {
    /// Checks the cloud on its own: at least [`MIN_CLOUD_POINTS`] points, finite and within
    /// [`MAX_COORDINATE`], an extent of at most [`MAX_CLOUD_EXTENT`] (metres, not mm or cm),
    /// one normal per point when normals are given.
    ///
    /// # Errors
    /// [`FitError::Invalid`] saying what is wrong (naming the point).
    pub fn check(&self) -> Result<()> {
        let pts = &self.positions;
        if pts.len() < MIN_CLOUD_POINTS {
            return Err(FitError::Invalid(format!(
                "the point cloud has {} point{}, a fit needs at least {MIN_CLOUD_POINTS}",
                pts.len(),
                if pts.len() == 1 { "" } else { "s" }
            )));
        }
        if let Some(i) = pts.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(FitError::Invalid(format!("point {i} is not finite")));
        }
        if let Some(i) = pts.iter().position(|p| !is_in_bounds(*p)) {
            return Err(FitError::Invalid(format!(
                "point {i} at {:?} is out of bounds (|coordinate| > {MAX_COORDINATE} m; \
                 positions are in metres)",
                pts[i]
            )));
        }
        let extent = extent(pts);
        if extent > MAX_CLOUD_EXTENT {
            return Err(FitError::Invalid(format!(
                "the point cloud spans {extent:.4} (bounding-box diagonal), more than \
                 {MAX_CLOUD_EXTENT} m: panoman expects metres; is it in millimetres or \
                 centimetres?"
            )));
        }
        if let Some(n) = &self.normals
            && n.len() != pts.len()
        {
            return Err(FitError::Invalid(format!(
                "{} normals for {} points",
                n.len(),
                pts.len()
            )));
        }
        Ok(())
    }

    /// Checks the cloud against the keypoints of the same frame: its centroid at most
    /// [`MAX_CLOUD_EXTENT`] (10 m) from theirs (otherwise the fit would reject every
    /// correspondence and silently ignore the cloud). No keypoints: nothing to check.
    ///
    /// # Errors
    /// [`FitError::Invalid`] giving the distance.
    pub fn check_against(&self, keypoints: &KeypointsFile) -> Result<()> {
        if keypoints.points.is_empty() || self.positions.is_empty() {
            return Ok(());
        }
        let kc = centroid(keypoints.points.values());
        let pc = centroid(self.positions.iter());
        let d = panoman_mesh::geom::norm(panoman_mesh::geom::sub(pc, kc));
        if d.is_nan() || d > MAX_CLOUD_EXTENT {
            return Err(FitError::Invalid(format!(
                "the point cloud's centroid is {d:.4} from the keypoints' centroid, more than \
                 {MAX_CLOUD_EXTENT} m: wrong units (millimetres?) or a different coordinate \
                 frame"
            )));
        }
        Ok(())
    }
}

/// Bounding-box diagonal of `pts`.
fn extent(pts: &[V3]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in pts {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    panoman_mesh::geom::norm(panoman_mesh::geom::sub(hi, lo))
}

fn centroid<'a>(pts: impl Iterator<Item = &'a V3>) -> V3 {
    let mut s = [0.0; 3];
    let mut n = 0usize;
    for p in pts {
        s = panoman_mesh::geom::add(s, *p);
        n += 1;
    }
    panoman_mesh::geom::scale(s, 1.0 / n.max(1) as f64)
}

impl Targets {
    /// Checks the targets as data (before they meet a model): keypoints (finite, in bounds,
    /// weights ≥ 0), handles (finite, within [`MAX_COORDINATE`], weights ≥ 0), the point
    /// cloud ([`PointCloud::check`] and [`PointCloud::check_against`] the keypoints).
    ///
    /// # Errors
    /// [`FitError::Invalid`] naming the keypoint, handle or point.
    pub fn check(&self) -> Result<()> {
        self.keypoints
            .validate()
            .map_err(|e| FitError::Invalid(e.to_string()))?;
        for (i, h) in self.handles.iter().enumerate() {
            check_handle(i, h).map_err(FitError::Invalid)?;
        }
        if let Some(p) = &self.points {
            p.check()?;
            p.check_against(&self.keypoints)?;
        }
        Ok(())
    }
}
