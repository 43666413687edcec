//! # panoman-fit
//!
//! Fitting PanoMan to sparse 3D data (paper §5, Total Capture's staging; docs/design/shell-fit.md §1):
//! the discrete-shell energy toward the model's guidance pose with keypoint, vertex-handle and
//! point-cloud (ICP) constraints, minimised by Levenberg–Marquardt V-steps alternating with
//! least-squares β-steps ([`fit`]); closest-point matching ([`icp`]); skeletal IK of the LBS rig
//! ([`ik`]); and [`FrameSolver`], the one type that fits a frame (rig + IK + shell fitter).

pub mod error;
pub mod fit;
pub mod frame;
pub mod icp;
pub mod ik;
pub mod pipeline;
pub mod quality;
pub mod shape_calibration;
pub mod targets;

pub use error::{FitError, Result};
pub use fit::{
    Constraints, FitOptions, FitResult, Init, LevelPair, Placement, Previous, ShellFitReport,
    ShellFitter, VertexHandle,
};
pub use frame::{FrameSolver, Tracking, TrackingState, WARM_IK_TOLERANCE};
pub use pipeline::{IkIcpOptions, LbsRig, ik_config_for_noise, ik_fit, ik_icp, init_of};
pub use shape_calibration::{
    LENGTH_KNOBS, ShapeCalibration, ShapeCalibrationOptions, ShapeKnob, calibrate_shape,
};
pub use targets::{PointCloud, Targets};
pub mod twist;
