//! Motion-capture data for panoman: readers for optical marker captures (C3D, Vicon CSM),
//! Vicon subject calibrations (VSK), skeletal motion (BVH, read and write, with forward
//! kinematics), a fetch of the real captures the project evaluates on, and a retarget of
//! CMU BVH motion to the generator's 163-bone rig.
//!
//! Conventions: lengths in metres and times in seconds in the API (each reader converts
//! from the file's units and records them); geometry in `f64`. The *project frame* is Z up,
//! metres, the character facing −Y with its left along +X (see
//! [`markers::MarkerSequence::to_project_frame`] for what a reader can and cannot infer).
//!
//! Entry points:
//! * [`c3d::read_c3d`] / [`c3d::parse_c3d`] → [`c3d::C3d`] (with a [`markers::MarkerSequence`]);
//!   [`c3d::write_c3d`] writes the point subset of the format (used by tests and excerpts).
//! * [`csm::read_csm`] → [`markers::MarkerSequence`].
//! * [`vsk::read_vsk`] → [`vsk::Vsk`].
//! * [`bvh::read_bvh`] → [`bvh::Bvh`], [`bvh::Bvh::to_text`], [`bvh::Bvh::joint_positions`].
//! * [`fetch::fetch_real_mocap`] downloads the real captures (Debian packages).
//! * [`marker_map`]: marker name → template surface point + offset (shipped sets
//!   `data/cmu53.json`, `data/plugin_gait43.json`); [`solve`]: MoSh-style calibration,
//!   tracking (PanoMan or LBS) and held-out marker error; [`solve_run::solve_capture`] runs it
//!   from files; [`glitch`]: capture glitches found from the markers alone.
//! * [`jitter::mean_acceleration`]: the jitter of a solved sequence beside the markers' own.
//! * [`track::track_retarget`]: retargeted motion tracked from the TC-133 keypoints of its
//!   generated meshes (PanoMan and the LBS baseline), per-vertex error and time per frame.
//!
//! Every error is a [`MocapError`] whose message names the file and what is wrong; no
//! reader panics on malformed input, and allocations are bounded by the input's size.

#![warn(missing_docs)]

pub mod bvh;
pub mod bvh_export;
pub mod c3d;
pub mod csm;
mod error;
pub mod fetch;
pub mod glitch;
pub mod jitter;
pub mod marker_map;
pub mod markers;
pub mod retarget;
pub mod solve;
pub mod solve_run;
pub mod track;
pub mod vsk;

pub use error::{MocapError, Result};
