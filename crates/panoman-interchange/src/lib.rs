//! # panoman-interchange
//!
//! Getting results out of panoman and other people's data in:
//!
//! * [`glb`]: glTF 2.0 binary export of a mesh, a mesh sequence (morph-target animation at the
//!   sequence's frame rate) and keypoint/marker tracks; every file passes the Khronos
//!   glTF-Validator with no errors and no warnings (tested).
//! * [`skinned`]: the LBS rig as a skinned glTF armature (the generator's 163 bones, inverse
//!   bind matrices, four influences per vertex, per-bone rotation/translation animation).
//! * [`keypoints_in`]: OpenPose JSON (BODY_25 + face 70 + hands 2 × 21) and CMU Panoptic
//!   (`hdPose3d_stage1_coco19`, `hdFace3d`, `hdHand3d`) → TC-127 [`KeypointsFile`] targets,
//!   with the layout detected from the JSON keys (mapping tables in `docs/formats-interchange.md`).
//! * [`sequence`]: a folder of per-frame meshes (the output of `panoman track`) read as one
//!   sequence.
//! * [`viewer`]: one self-contained, offline HTML viewer around a GLB (three.js at a pinned
//!   version, fetched once from the npm registry and checked by SHA-256).
//!
//! Units are metres; panoman's axes are Z up, the character facing −Y (see [`glb`] for the
//! conversion to glTF's Y up).
//!
//! [`KeypointsFile`]: panoman_human::keypoints::KeypointsFile

#![warn(missing_docs)]

pub mod error;
pub mod glb;
pub mod keypoints_in;
pub mod sequence;
pub mod skinned;
pub mod viewer;

pub use error::{InterchangeError, Result};
