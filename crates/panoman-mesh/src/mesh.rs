//! The triangle mesh container.

use crate::error::{MeshError, Result};

/// A triangle mesh: `positions` is #V×3 (metres), `faces` is #F×3 vertex indices, counter-clockwise
/// seen from outside. Topology tables live in [`crate::Topology`], built once per connectivity.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// #V vertex positions.
    pub positions: Vec<[f64; 3]>,
    /// #F triangles as vertex indices.
    pub faces: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Builds a mesh from positions and faces without validation.
    pub fn new(positions: Vec<[f64; 3]>, faces: Vec<[u32; 3]>) -> Self {
        Self { positions, faces }
    }

    /// Number of vertices #V.
    pub fn n_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles #F.
    pub fn n_faces(&self) -> usize {
        self.faces.len()
    }

    /// Checks that every coordinate is finite and every face index is `< #V`.
    pub fn check_basic(&self) -> Result<()> {
        if let Some((i, p)) = self
            .positions
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::NonFinite(format!(
                "vertex {i} has coordinates {p:?}"
            )));
        }
        let n = self.positions.len();
        if let Some((f, t)) = self
            .faces
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
        {
            return Err(MeshError::Topology(format!(
                "face {f} {t:?} refers to a vertex beyond the {n} vertices"
            )));
        }
        Ok(())
    }
}
