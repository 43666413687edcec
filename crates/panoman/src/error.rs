//! The one error type of the library API.
use std::path::PathBuf;

/// Everything the library API can fail with. Each variant renders as one line; the ones
/// about a file start with its path (`<file>: <what is wrong>`), as the CLI prints them.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file is malformed or inconsistent with the model (`what` says how).
    #[error("{}: {what}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// An argument is invalid (wrong sizes, non-finite values, unknown names, nothing to fit).
    #[error("{0}")]
    Invalid(String),
    /// Mesh kernel (topology, `g`, I/O of meshes).
    #[error(transparent)]
    Mesh(#[from] panoman_mesh::MeshError),
    /// Assets, generator, keypoint definitions.
    #[error(transparent)]
    Human(#[from] panoman_human::HumanError),
    /// Model files and evaluation.
    #[error(transparent)]
    Model(#[from] panoman_model::ModelError),
    /// Fitting and IK.
    #[error(transparent)]
    Fit(#[from] panoman_fit::FitError),
}

impl Error {
    /// Prefixes the message of an input-dependent error with the file it came from
    /// (`Invalid`/`Fit` errors become `Format` errors of `path`); file errors are kept.
    pub fn in_file(self, path: impl Into<PathBuf>) -> Error {
        match self {
            Error::Invalid(what) => Error::Format {
                path: path.into(),
                what,
            },
            Error::Fit(e) => Error::Format {
                path: path.into(),
                what: e.to_string(),
            },
            other => other,
        }
    }
}

/// Result alias of the library API.
pub type Result<T> = std::result::Result<T, Error>;
