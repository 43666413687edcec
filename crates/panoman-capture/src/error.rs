//! The error type of `panoman-capture`. Every variant renders as one line that names the file
//! (and, for calibration files, the camera and field) involved and what is wrong.

use std::path::{Path, PathBuf};

/// Errors of reading and writing calibrations and of triangulation.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CaptureError {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A calibration file is malformed; `what` names the camera and field and says how.
    #[error("{}: {what}", path.display())]
    Format {
        /// The malformed file (or the name given to an in-memory parse).
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// In-memory input that cannot be used (an invalid camera, an observation of a camera
    /// that does not exist, a non-finite pixel, …).
    #[error("{0}")]
    Invalid(String),
    /// Downloading or verifying the demo data failed (pip's message or the digest quoted).
    #[error("fetch: {0}")]
    Fetch(String),
}

impl CaptureError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            CaptureError::Io { .. } | CaptureError::Fetch(_) => K::File,
            CaptureError::Format { .. } => K::Format,
            CaptureError::Invalid(_) => K::Invalid,
        }
    }

    /// A [`CaptureError::Format`] for `path`.
    pub fn format(path: &Path, what: impl Into<String>) -> Self {
        CaptureError::Format {
            path: path.to_path_buf(),
            what: what.into(),
        }
    }

    /// A [`CaptureError::Io`] for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        CaptureError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// `Result` with [`CaptureError`].
pub type Result<T> = std::result::Result<T, CaptureError>;

/// Reads a whole text file, mapping I/O and UTF-8 errors to the file.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| CaptureError::io(path, e))?;
    String::from_utf8(bytes)
        .map_err(|e| CaptureError::format(path, format!("not UTF-8 text ({e})")))
}
