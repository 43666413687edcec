//! # panoman
//!
//! The PanoMan library API (work in progress: see the crate docs once it lands).
