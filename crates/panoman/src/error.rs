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
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            Error::Io { .. } => K::File,
            Error::Format { .. } => K::Format,
            Error::Invalid(_) => K::Invalid,
            Error::Mesh(e) => e.kind(),
            Error::Human(e) => e.kind(),
            Error::Model(e) => e.kind(),
            Error::Fit(e) => e.kind(),
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ErrorKind;

    /// Each failure class reaches the caller with its kind, through every wrapping crate.
    #[test]
    fn kinds_classify_errors_of_every_crate() {
        let dir = std::env::temp_dir().join(format!("panoman-kind-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = dir.join("missing.safetensors");
        assert_eq!(
            crate::Model::load(&missing).unwrap_err().kind(),
            ErrorKind::File
        );
        let garbage = dir.join("garbage.safetensors");
        std::fs::write(&garbage, b"not a safetensors file").unwrap();
        assert_eq!(
            crate::Model::load(&garbage).unwrap_err().kind(),
            ErrorKind::Format
        );
        let mesh = Error::from(panoman_mesh::MeshError::Numerical("singular".into()));
        assert_eq!(mesh.kind(), ErrorKind::Numerical);
        let fit = Error::from(panoman_fit::FitError::Human(
            panoman_human::HumanError::Invalid("unknown bone".into()),
        ));
        assert_eq!(fit.kind(), ErrorKind::Invalid);
        assert_eq!(
            Error::Invalid("x".into()).in_file("f.json").kind(),
            ErrorKind::Format
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
