//! # panoman-mesh
//!
//! The geometric kernel of panoman: triangle meshes and their topology tables, OBJ/PLY I/O,
//! the RLA representation of PanoMan (relative edge lengths `RL = l/l_rest − 1` and relative
//! signed dihedral angles `RA = wrap(φ − φ_rest)`, paper §4.1) with analytic gradients, and the
//! reconstruction `g` (RL, RA, rest shape → vertices, paper Appendix A).
//!
//! Conventions (see `docs/design/rla-and-g.md` §1): geometry in `f64` metres; faces are
//! counter-clockwise seen from outside (outward normals); vertex and face indices are `u32`.

// Numeric kernels index several per-element arrays in lockstep (positions, tables, outputs);
// index loops state that more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod align;
pub mod error;
pub mod geom;
pub mod io;
pub mod measure;
pub mod mesh;
pub mod recon;
pub mod rla;
pub mod rotation;
pub mod shapes;
pub mod shell;
pub mod sparse;
pub mod stats;
pub mod topology;

pub use error::{ErrorKind, MeshError, Result};
pub use mesh::TriMesh;
pub use recon::{GDerivative, GLinearization, GWorkspace, Gauge, Reconstructor};
pub use rla::{RestGeometry, Rla};
pub use topology::Topology;
