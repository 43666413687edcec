//! The error type of the crate.

use std::path::{Path, PathBuf};

/// Errors of export, import and viewer generation. Every variant that concerns a file names it.
#[derive(Debug, thiserror::Error)]
pub enum InterchangeError {
    /// A file or directory could not be read, written or listed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// An input file is malformed or of an unknown layout; `what` says how.
    #[error("{}: {what}", path.display())]
    Format {
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// In-memory input that cannot be exported (mismatched frames, non-finite values, …).
    #[error("{0}")]
    Invalid(String),
    /// An external tool (npm) failed or a fetched file did not have the pinned digest.
    #[error("{what}")]
    Tool {
        /// What failed, including the command or file.
        what: String,
    },
    /// An error from the mesh crate (reading meshes, atomic writes).
    #[error(transparent)]
    Mesh(#[from] panoman_mesh::MeshError),
    /// An error from the human crate (TC-127 keypoints files).
    #[error(transparent)]
    Human(#[from] panoman_human::error::HumanError),
}

impl InterchangeError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            InterchangeError::Io { .. } | InterchangeError::Tool { .. } => K::File,
            InterchangeError::Format { .. } => K::Format,
            InterchangeError::Invalid(_) => K::Invalid,
            InterchangeError::Mesh(e) => e.kind(),
            InterchangeError::Human(e) => e.kind(),
        }
    }

    /// A [`InterchangeError::Format`] for `path`.
    pub fn format(path: &Path, what: impl Into<String>) -> Self {
        InterchangeError::Format {
            path: path.to_path_buf(),
            what: what.into(),
        }
    }

    /// A [`InterchangeError::Io`] for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        InterchangeError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, InterchangeError>;
