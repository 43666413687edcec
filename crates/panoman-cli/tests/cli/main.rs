//! The CLI's integration tests, one module per area, in one test binary (one link instead of
//! sixteen). Each module's tests run the `panoman` binary (`CARGO_BIN_EXE_panoman`) or the
//! library; `common` holds the shared helpers.

#[allow(dead_code)]
mod common;

mod capture_cli;
mod faults;
mod fit;
mod foundation;
mod generate;
mod interchange_cli;
mod interchange_fit;
mod keypoints_cli;
mod mocap_cli;
mod model;
mod render;
mod robust;
mod self_contained;
mod synth;
mod track_jobs;
mod track_resume;
