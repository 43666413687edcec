//! Error type of the mesh kernel. Every variant renders as one line that names what is wrong
//! (and the file, where one is involved), so the CLI can print `error: <file>: <what>`.

use std::path::PathBuf;

/// What kind of failure an error is, whatever crate raised it (as `std::io::ErrorKind`): every
/// crate's error type has a `kind()`, so callers (the Python binding, a CLI exit code) classify
/// any of them with one match.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// A file or directory could not be found, read, written or fetched.
    File,
    /// A file's content is malformed, truncated, inconsistent or fails its checksum.
    Format,
    /// An argument is invalid: wrong sizes, non-finite values, unknown names, nothing to do.
    Invalid,
    /// A numerical step failed (singular system, failed factorization).
    Numerical,
}

/// Errors of mesh I/O, validation and reconstruction.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is malformed or truncated; `what` says where and how.
    #[error("{}: {what}", path.display())]
    Format { path: PathBuf, what: String },
    /// The face list does not describe a valid manifold, consistently oriented mesh.
    #[error("invalid mesh topology: {0}")]
    Topology(String),
    /// Coordinates or data contain NaN or infinite values.
    #[error("non-finite value: {0}")]
    NonFinite(String),
    /// Two inputs that must agree in size or topology do not.
    #[error("mismatch: {0}")]
    Mismatch(String),
    /// A numerical step failed (singular system, failed factorization).
    #[error("numerical failure: {0}")]
    Numerical(String),
}

impl MeshError {
    /// The kind of failure.
    pub fn kind(&self) -> ErrorKind {
        match self {
            MeshError::Io { .. } => ErrorKind::File,
            MeshError::Format { .. } => ErrorKind::Format,
            MeshError::Numerical(_) => ErrorKind::Numerical,
            MeshError::Topology(_) | MeshError::NonFinite(_) | MeshError::Mismatch(_) => {
                ErrorKind::Invalid
            }
        }
    }

    /// Attach a file path to an error that has none (topology, non-finite, mismatch).
    pub fn in_file(self, path: impl Into<PathBuf>) -> MeshError {
        match self {
            MeshError::Io { .. } | MeshError::Format { .. } => self,
            other => MeshError::Format {
                path: path.into(),
                what: other.to_string(),
            },
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = MeshError> = std::result::Result<T, E>;
