//! Error type of the model crate; every variant renders as one line.

use std::path::PathBuf;

/// Errors of training, evaluation and model/dataset files.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file is malformed, truncated or inconsistent; `what` says how.
    #[error("{}: {what}", path.display())]
    Format { path: PathBuf, what: String },
    /// Inputs of the wrong size or kind.
    #[error("invalid input: {0}")]
    Invalid(String),
    /// Parameters that do not match the model (names, lengths, non-finite values); the
    /// message says what is wrong.
    #[error("{0}")]
    Params(String),
    /// A numerical step failed.
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// An error of the mesh kernel.
    #[error(transparent)]
    Mesh(#[from] panoman_mesh::MeshError),
}

impl ModelError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            ModelError::Io { .. } => K::File,
            ModelError::Format { .. } => K::Format,
            ModelError::Invalid(_) | ModelError::Params(_) => K::Invalid,
            ModelError::Numerical(_) => K::Numerical,
            ModelError::Mesh(e) => e.kind(),
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = ModelError> = std::result::Result<T, E>;
