//! One module per `panoman` subcommand.

pub mod assets;
pub mod bench;
pub mod bench_fit;
pub mod capture;
pub mod components;
pub mod data;
pub mod demo;
pub mod embed_rig;
pub mod encode;
pub mod eval;
pub mod export;
pub mod fit;
pub mod generate;
pub mod keypoints;
pub mod mocap;
pub mod mocap_eval;
pub mod pose;
pub mod render;
pub mod roundtrip;
pub mod synth;
pub mod template;
pub mod train;
pub mod view;
