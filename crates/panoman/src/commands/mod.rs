//! One module per `panoman` subcommand.

pub mod assets;
pub mod bench;
pub mod demo;
pub mod roundtrip;
pub mod template;
pub mod generate;
pub mod render;
