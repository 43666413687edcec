//! [`Targets`]: what a fit is asked to match, and readers for their files.
use std::collections::BTreeMap;
use std::path::Path;

use panoman_fit::fit::VertexHandle;
use panoman_human::keypoints::{KeypointsFile, keypoint_index};
use panoman_mesh::geom::V3;
use panoman_mesh::io;

use crate::error::{Error, Result};

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
    /// Keypoints: any subset of the 127 Total Capture keypoints (metres), each with a
    /// weight (default 1; 0 skips it). The fit's initializer needs at least a few body ones.
    pub keypoints: KeypointsFile,
    /// Vertex handles: template vertex → target position (metres), with a relative weight.
    pub handles: Vec<VertexHandle>,
    /// A point cloud fitted by ICP (skeletal ICP of the initializer, then the shell fit's
    /// point-to-plane passes).
    pub points: Option<PointCloud>,
}

impl Targets {
    /// All 127 keypoints in TC-127 order (e.g. [`crate::Model::keypoints`] of a mesh), weight 1.
    pub fn from_keypoints(positions: &[V3]) -> Targets {
        Targets {
            keypoints: KeypointsFile::from_all(positions),
            ..Default::default()
        }
    }

    /// Keypoints by TC-127 name (`{"l_wrist": [x, y, z], …}`), weight 1.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming an unknown keypoint or a non-finite position.
    pub fn from_named(points: &BTreeMap<String, V3>) -> Result<Targets> {
        let mut kp = KeypointsFile::default();
        for (name, p) in points {
            let k = keypoint_index(name)
                .ok_or_else(|| Error::Invalid(format!("unknown keypoint '{name}'")))?;
            if !p.iter().all(|c| c.is_finite()) {
                return Err(Error::Invalid(format!("keypoint '{name}' is not finite")));
            }
            kp.points.insert(k, *p);
        }
        Ok(Targets {
            keypoints: kp,
            ..Default::default()
        })
    }

    /// Reads a TC-127 keypoint file (`{"keypoints": {name: [x, y, z]}, "weights": {...}}`,
    /// see `docs/formats.md`).
    ///
    /// # Errors
    /// [`Error::Human`] naming the file.
    pub fn read_keypoints(path: &Path) -> Result<Targets> {
        Ok(Targets {
            keypoints: KeypointsFile::read(path)?,
            ..Default::default()
        })
    }
}

/// Reads a handle file `{"handles": [{"vertex": 123, "position": [x, y, z], "weight": 1}]}`
/// and checks it against a topology of `n_vertices` vertices.
///
/// # Errors
/// [`Error::Io`] / [`Error::Format`] naming the file: unreadable, malformed, a vertex out of
/// range, a non-finite position, a negative weight.
pub fn read_handles(path: &Path, n_vertices: usize) -> Result<Vec<VertexHandle>> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        handles: Vec<VertexHandle>,
    }
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |what: String| Error::Format {
        path: path.to_path_buf(),
        what,
    };
    let f: File =
        serde_json::from_str(&text).map_err(|e| bad(format!("not a valid handle file: {e}")))?;
    for (i, h) in f.handles.iter().enumerate() {
        if h.vertex as usize >= n_vertices {
            return Err(bad(format!(
                "handle {i}: vertex {} out of range (the model has {n_vertices} vertices)",
                h.vertex
            )));
        }
        if !h.position.iter().all(|x| x.is_finite()) || h.weight.is_nan() || h.weight < 0.0 {
            return Err(bad(format!(
                "handle {i}: non-finite position or negative weight"
            )));
        }
    }
    Ok(f.handles)
}

/// Reads a point cloud: PLY vertices (faces optional) or the vertices of any mesh file.
///
/// # Errors
/// Unreadable or malformed file, no points, a non-finite point (naming the file).
pub fn read_points(path: &Path) -> Result<PointCloud> {
    let pts = match io::MeshFormat::from_path(path)? {
        io::MeshFormat::Ply => io::ply::read_ply_points(path)?,
        _ => io::read_mesh(path)?.positions,
    };
    let bad = |what: String| Error::Format {
        path: path.to_path_buf(),
        what,
    };
    if pts.is_empty() {
        return Err(bad("the point cloud is empty".into()));
    }
    if let Some(i) = pts.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(bad(format!("point {i} is not finite")));
    }
    Ok(PointCloud {
        positions: pts,
        normals: None,
    })
}
