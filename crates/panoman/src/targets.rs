//! Readers of the target files of a fit ([`Targets`] itself is [`panoman_fit::Targets`]).
use std::path::Path;

use panoman_fit::fit::VertexHandle;
use panoman_fit::targets::check_handle;
use panoman_mesh::io;

use crate::error::{Error, Result};
pub use panoman_fit::targets::{MAX_CLOUD_EXTENT, MIN_CLOUD_POINTS, PointCloud, Targets};

/// Reads a handle file `{"handles": [{"vertex": 123, "position": [x, y, z], "weight": 1}]}`
/// and checks it against a topology of `n_vertices` vertices.
///
/// # Errors
/// [`Error::Io`] / [`Error::Format`] naming the file: unreadable, malformed, a vertex out of
/// range, a non-finite position or one beyond `MAX_COORDINATE` (10 km), a negative weight.
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
        check_handle(i, h).map_err(bad)?;
    }
    Ok(f.handles)
}

/// Reads a point cloud: PLY vertices (faces optional) or the vertices of any mesh file, and
/// checks it ([`PointCloud::check`]: at least 3 points, in bounds, an extent ≤ 10 m).
///
/// # Errors
/// Unreadable or malformed file, no points, a non-finite point, too few points, a cloud in the
/// wrong units (naming the file).
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
    let cloud = PointCloud {
        positions: pts,
        normals: None,
    };
    cloud.check().map_err(|e| Error::from(e).in_file(path))?;
    Ok(cloud)
}
