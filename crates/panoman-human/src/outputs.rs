//! Topology outputs of the generator: one generated vertex array on Anny's "anny" topology
//! (13,718 vertices, docs/design/assets.md §4.1) as a mesh in any of panoman's topologies.
//!
//! * **anny**: the generator's own vertices, with Anny's 27,420 triangles (quads split along
//!   the shorter diagonal of the unshaped world template, strict `<`, docs/design/assets.md §4.3, the rule of
//!   [`split_quad`]). The world map is Anny's bit-for-bit ([`crate::basemesh::world_map`]), so
//!   the triangles equal Anny's `faces` array, including the eyeball near-ties (checked
//!   against the reference fixture in `tests/outputs.rs`).
//! * **full**: the 13,348 template vertices, gathered by base index
//!   ([`Template::base_index`], [`Generator::output_index_of_base`]), with the template's
//!   26,692 triangles.
//! * **small**: the 1,229 vertices of [`SmallTopology`], each the barycentric combination
//!   ([`SmallTopology::prolong`]) of the full positions; here the bindings are composed with
//!   the gather once, so a small mesh is computed directly from anny-topology vertices with
//!   the same arithmetic (bit-identical to `small.prolong(&full)`).
//!
//! A [`TopologyMap`] is built once per generator and template and then maps any number of
//! rest or posed meshes.

use std::str::FromStr;

use panoman_mesh::TriMesh;

use crate::error::{HumanError, Result};
use crate::generator::Generator;
use crate::template::{Binding, SmallTopology, Template, split_quad};

/// Which topology a generated mesh is written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum OutputTopology {
    /// Anny's output topology: 13,718 vertices (body, eyeballs, tongue), 27,420 triangles.
    #[default]
    Anny,
    /// panoman's full template: 13,348 vertices, 26,692 triangles (closed skin).
    Full,
    /// panoman's small topology: 1,229 vertices bound to the full template.
    Small,
}

impl OutputTopology {
    /// The name used on the command line: `anny`, `full` or `small`.
    pub fn name(self) -> &'static str {
        match self {
            OutputTopology::Anny => "anny",
            OutputTopology::Full => "full",
            OutputTopology::Small => "small",
        }
    }
}

impl std::fmt::Display for OutputTopology {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for OutputTopology {
    type Err = HumanError;

    /// Parses `anny`, `full` or `small`.
    fn from_str(s: &str) -> Result<OutputTopology> {
        match s {
            "anny" => Ok(OutputTopology::Anny),
            "full" => Ok(OutputTopology::Full),
            "small" => Ok(OutputTopology::Small),
            _ => Err(HumanError::Invalid(format!(
                "unknown topology `{s}` (expected `anny`, `full` or `small`)"
            ))),
        }
    }
}

/// Maps generator outputs (anny topology) to the anny, full and small meshes (module docs).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TopologyMap {
    n_anny: usize,
    anny_faces: Vec<[u32; 3]>,
    full_from_anny: Vec<u32>,
    full_faces: Vec<[u32; 3]>,
    small_binding: Vec<Binding>,
    small_faces: Vec<[u32; 3]>,
}

impl TopologyMap {
    /// Builds the map from a loaded generator, the full template and the small topology
    /// bound to it ([`crate::template::full_template`], [`crate::template::small_template`]).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] if a template vertex is not an output vertex of the generator,
    /// or an output face is neither a triangle nor a quad (inconsistent assets).
    pub fn new(generator: &Generator, full: &Template, small: &SmallTopology) -> Result<Self> {
        let n_anny = generator.output_vertices().len();
        let full_from_anny = full
            .base_index
            .iter()
            .map(|&b| {
                generator
                    .output_index_of_base(b)
                    .map(|k| k as u32)
                    .ok_or_else(|| {
                        HumanError::Invalid(format!(
                            "template vertex with base index {b} is not a generator output vertex"
                        ))
                    })
            })
            .collect::<Result<Vec<u32>>>()?;
        let anny_faces = anny_triangles(generator)?;
        let small_binding = small
            .binding
            .iter()
            .map(|b| Binding {
                tri: b.tri.map(|i| full_from_anny[i as usize]),
                bary: b.bary,
            })
            .collect();
        Ok(TopologyMap {
            n_anny,
            anny_faces,
            full_from_anny,
            full_faces: full.mesh.faces.clone(),
            small_binding,
            small_faces: small.mesh.faces.clone(),
        })
    }

    /// Index ranges of a decoded map (see [`crate::rigfile::RigData::from_bytes`]): the first
    /// problem found, as text.
    pub(crate) fn check(&self) -> std::result::Result<(), String> {
        let faces_in = |faces: &[[u32; 3]], n: usize, what: &str| match faces
            .iter()
            .flatten()
            .find(|&&v| v as usize >= n)
        {
            Some(v) => Err(format!("{what} face vertex {v} ≥ {n}")),
            None => Ok(()),
        };
        if let Some(v) = self
            .full_from_anny
            .iter()
            .find(|&&v| v as usize >= self.n_anny)
        {
            return Err(format!(
                "full-template vertex maps to generator vertex {v} ≥ {}",
                self.n_anny
            ));
        }
        if let Some(b) = self.small_binding.iter().find(|b| {
            b.tri.iter().any(|&v| v as usize >= self.n_anny)
                || !b.bary.iter().all(|w| w.is_finite())
        }) {
            return Err(format!("small-topology binding {b:?} is out of range"));
        }
        faces_in(&self.anny_faces, self.n_anny, "anny")?;
        faces_in(&self.full_faces, self.full_from_anny.len(), "full")?;
        faces_in(&self.small_faces, self.small_binding.len(), "small")
    }

    /// Number of vertices of the generator's output (anny topology, 13,718).
    pub fn n_anny_vertices(&self) -> usize {
        self.n_anny
    }

    /// Number of vertices of a mesh in `topology`.
    pub fn n_vertices(&self, topology: OutputTopology) -> usize {
        match topology {
            OutputTopology::Anny => self.n_anny,
            OutputTopology::Full => self.full_from_anny.len(),
            OutputTopology::Small => self.small_binding.len(),
        }
    }

    /// Triangles of `topology` (outward-facing).
    pub fn faces(&self, topology: OutputTopology) -> &[[u32; 3]] {
        match topology {
            OutputTopology::Anny => &self.anny_faces,
            OutputTopology::Full => &self.full_faces,
            OutputTopology::Small => &self.small_faces,
        }
    }

    /// Anny-topology vertex index of each full-template vertex.
    pub fn full_from_anny(&self) -> &[u32] {
        &self.full_from_anny
    }

    /// The small topology's bindings expressed on anny-topology vertices.
    pub fn small_binding(&self) -> &[Binding] {
        &self.small_binding
    }

    /// Maps anny-topology positions to `topology`, into `out` (resized; reuse it across
    /// calls to avoid allocations).
    ///
    /// # Panics
    /// If `anny.len()` is not [`TopologyMap::n_anny_vertices`].
    pub fn map_into(&self, topology: OutputTopology, anny: &[[f64; 3]], out: &mut Vec<[f64; 3]>) {
        assert_eq!(
            anny.len(),
            self.n_anny,
            "expected {} anny-topology vertices",
            self.n_anny
        );
        out.clear();
        match topology {
            OutputTopology::Anny => out.extend_from_slice(anny),
            OutputTopology::Full => {
                out.extend(self.full_from_anny.iter().map(|&k| anny[k as usize]))
            }
            OutputTopology::Small => out.extend(self.small_binding.iter().map(|b| b.eval(anny))),
        }
    }

    /// Maps anny-topology positions to `topology` (see [`TopologyMap::map_into`]).
    ///
    /// # Panics
    /// If `anny.len()` is not [`TopologyMap::n_anny_vertices`].
    pub fn map(&self, topology: OutputTopology, anny: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let mut out = Vec::with_capacity(self.n_vertices(topology));
        self.map_into(topology, anny, &mut out);
        out
    }

    /// The full-template positions of an anny-topology vertex array.
    ///
    /// # Panics
    /// If `anny.len()` is not [`TopologyMap::n_anny_vertices`].
    pub fn to_full(&self, anny: &[[f64; 3]]) -> Vec<[f64; 3]> {
        self.map(OutputTopology::Full, anny)
    }

    /// The small-topology positions of an anny-topology vertex array.
    ///
    /// # Panics
    /// If `anny.len()` is not [`TopologyMap::n_anny_vertices`].
    pub fn to_small(&self, anny: &[[f64; 3]]) -> Vec<[f64; 3]> {
        self.map(OutputTopology::Small, anny)
    }

    /// The mesh of an anny-topology vertex array in `topology` (positions and triangles).
    ///
    /// # Panics
    /// If `anny.len()` is not [`TopologyMap::n_anny_vertices`].
    pub fn mesh(&self, topology: OutputTopology, anny: &[[f64; 3]]) -> TriMesh {
        TriMesh::new(self.map(topology, anny), self.faces(topology).to_vec())
    }
}

/// Anny's triangles of the output topology (docs/design/assets.md §4.3): each output quad of the generator
/// ([`Generator::output_quads_base`]) split by [`split_quad`] on the unshaped world template,
/// two triangles per quad in quad order; triangles kept as they are. Vertex ids are output
/// (anny-topology) indices.
///
/// # Errors
/// [`HumanError::Invalid`] for a face with other than 3 or 4 corners or a corner that is not
/// an output vertex.
pub fn anny_triangles(generator: &Generator) -> Result<Vec<[u32; 3]>> {
    let template = generator.template_output();
    let quads = generator.output_quads_base();
    let mut faces = Vec::with_capacity(2 * quads.len());
    for (k, f) in quads.iter().enumerate() {
        let local = f
            .iter()
            .map(|&b| {
                generator
                    .output_index_of_base(b)
                    .map(|i| i as u32)
                    .ok_or_else(|| {
                        HumanError::Invalid(format!(
                            "output face {k} uses base vertex {b}, which is not an output vertex"
                        ))
                    })
            })
            .collect::<Result<Vec<u32>>>()?;
        match local[..] {
            [a, b, c] => faces.push([a, b, c]),
            [a, b, c, d] => {
                let q = [a, b, c, d];
                for t in split_quad(q, &template) {
                    faces.push(t.map(|s| q[s]));
                }
            }
            _ => {
                return Err(HumanError::Invalid(format!(
                    "output face {k} has {} corners (expected 3 or 4)",
                    local.len()
                )));
            }
        }
    }
    Ok(faces)
}
