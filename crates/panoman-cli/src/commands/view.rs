//! `panoman view`: one self-contained offline HTML viewer (three.js inlined); the logic lives
//! in `panoman-interchange`.

use anyhow::{Context, Result, bail};
use clap::Args;
use panoman_interchange::glb::{self, GlbOptions};
use panoman_interchange::sequence::Sequence;
use panoman_interchange::viewer::{self, ThreeAssets, VertexErrors, ViewOptions};
use std::path::PathBuf;

/// Arguments of `panoman view`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman view clip.glb --out view.html\n  panoman view track/ --truth truth/ --out view.html   # error colouring"
)]
pub struct ViewArgs {
    /// A .glb file, a mesh (.obj / .ply) or a folder of per-frame meshes.
    pub input: PathBuf,
    /// Ground truth (a mesh or a folder, matching the input frame by frame) for the
    /// per-vertex error colouring; not with a .glb input.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Error shown in full red, in millimetres.
    #[arg(long, default_value_t = 30.0)]
    pub error_max_mm: f64,
    /// Frame rate when the input is a folder.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Output .html.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `panoman view`.
pub fn run(a: ViewArgs) -> Result<()> {
    let is_glb = a
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    let (bytes, errors) = if is_glb {
        if a.truth.is_some() {
            bail!(
                "{}: --truth needs mesh input, not a .glb",
                a.input.display()
            );
        }
        let b = std::fs::read(&a.input).with_context(|| a.input.display().to_string())?;
        (b, None)
    } else {
        let seq = Sequence::read(&a.input)?;
        let options = GlbOptions {
            fps: a.fps,
            ..Default::default()
        };
        let b = glb::export_glb(&seq.faces, &seq.frames, None, &options)
            .with_context(|| a.input.display().to_string())?;
        let errors = match &a.truth {
            Some(t) => {
                let truth = Sequence::read(t)?;
                let e = viewer::vertex_errors(&seq.frames, &truth.frames)
                    .with_context(|| t.display().to_string())?;
                Some(VertexErrors {
                    per_frame: e,
                    max_m: a.error_max_mm / 1000.0,
                })
            }
            None => None,
        };
        (b, errors)
    };
    let three = ThreeAssets::load_or_fetch()?;
    let options = ViewOptions {
        title: a
            .input
            .file_name()
            .map(|n| n.to_string_lossy().into_owned()),
        errors,
    };
    let html = viewer::view_html(&bytes, &three, &options)
        .with_context(|| a.input.display().to_string())?;
    panoman_mesh::io::write_bytes_atomically(&a.out, html.as_bytes())?;
    println!(
        "{}: {:.1} MB, opens offline",
        a.out.display(),
        html.len() as f64 / 1e6
    );
    Ok(())
}
