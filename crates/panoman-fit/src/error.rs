//! Errors of the fitting stage.
use thiserror::Error;

/// Everything that can go wrong while fitting.
#[derive(Debug, Error)]
pub enum FitError {
    /// Inputs that cannot be fitted (empty target set, NaN, wrong sizes); the message says why.
    #[error("{0}")]
    Invalid(String),
    /// An error of the model stage.
    #[error(transparent)]
    Model(#[from] panoman_model::ModelError),
    /// An error of the mesh kernel.
    #[error(transparent)]
    Mesh(#[from] panoman_mesh::MeshError),
    /// An error of the human stage (IK, keypoints).
    #[error(transparent)]
    Human(#[from] panoman_human::HumanError),
}

impl FitError {
    /// The kind of failure ([`panoman_mesh::ErrorKind`]).
    pub fn kind(&self) -> panoman_mesh::ErrorKind {
        use panoman_mesh::ErrorKind as K;
        match self {
            FitError::Invalid(_) => K::Invalid,
            FitError::Model(e) => e.kind(),
            FitError::Mesh(e) => e.kind(),
            FitError::Human(e) => e.kind(),
        }
    }
}

/// Result alias of the fitting stage.
pub type Result<T> = std::result::Result<T, FitError>;
