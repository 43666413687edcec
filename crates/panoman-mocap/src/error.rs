//! The error type of `panoman-mocap`. Every variant renders as one line that names the file
//! (or the step) involved and what is wrong, so a CLI can print `error: <file>: <what>`.

use std::path::PathBuf;

/// Errors of reading, writing and fetching motion-capture files.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MocapError {
    /// A file or directory could not be opened, read, written or renamed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file is malformed; `what` says where (byte offset or line) and how.
    #[error("{}: {what}", path.display())]
    Format {
        /// The malformed file (or the name given to an in-memory parse).
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// A request cannot be carried out on valid data (unknown marker name, a value a writer
    /// cannot represent, …).
    #[error("{what}")]
    Invalid {
        /// What is wrong.
        what: String,
    },
    /// An external step of the data fetch failed (a command, a checksum, a missing file).
    #[error("data fetch: {what}")]
    Fetch {
        /// What failed.
        what: String,
    },
}

impl MocapError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            MocapError::Io { .. } | MocapError::Fetch { .. } => K::File,
            MocapError::Format { .. } => K::Format,
            MocapError::Invalid { .. } => K::Invalid,
        }
    }
}

/// `Result` with [`MocapError`].
pub type Result<T> = std::result::Result<T, MocapError>;

/// A [`MocapError::Format`] for `path`.
pub(crate) fn format_err(path: &std::path::Path, what: impl Into<String>) -> MocapError {
    MocapError::Format {
        path: path.to_path_buf(),
        what: what.into(),
    }
}

/// Reads a whole file, mapping I/O errors to [`MocapError::Io`].
pub(crate) fn read_bytes(path: &std::path::Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| MocapError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a whole UTF-8 text file; invalid UTF-8 is a [`MocapError::Format`].
pub(crate) fn read_text(path: &std::path::Path) -> Result<String> {
    let bytes = read_bytes(path)?;
    String::from_utf8(bytes).map_err(|e| {
        format_err(
            path,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

/// Writes a file atomically (the project's one atomic writer,
/// [`panoman_mesh::io::write_bytes_atomically`]), mapping its errors to [`MocapError::Io`] or
/// [`MocapError::Format`] naming `path`.
pub(crate) fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    use panoman_mesh::MeshError;
    panoman_mesh::io::write_bytes_atomically(path, bytes).map_err(|e| match e {
        MeshError::Io { path, source } => MocapError::Io { path, source },
        other => format_err(path, other.to_string()),
    })
}
