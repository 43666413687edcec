//! `panoman export`: meshes and mesh sequences as glTF 2.0 binary (.glb); the logic lives in
//! `panoman-interchange`.

use anyhow::{Context, Result, bail};
use clap::Args;
use panoman_interchange::glb::{self, GlbOptions, Interpolation, Markers};
use panoman_interchange::keypoints_in::{ImportOptions, read_keypoints};
use panoman_interchange::sequence::Sequence;
use std::path::PathBuf;

/// Arguments of `panoman export`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman export --mesh fit/mesh.obj --out fit.glb\n  panoman export --sequence track/ --fps 30 --out clip.glb"
)]
pub struct ExportArgs {
    /// One mesh (.obj or .ply) → a static .glb.
    #[arg(
        long,
        conflicts_with = "sequence",
        required_unless_present = "sequence"
    )]
    pub mesh: Option<PathBuf>,
    /// A folder of per-frame meshes (e.g. `panoman track`'s output), in name order → one
    /// animated .glb (morph targets).
    #[arg(long)]
    pub sequence: Option<PathBuf>,
    /// Frame rate of the sequence's animation.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Hold each frame instead of blending consecutive frames linearly.
    #[arg(long)]
    pub step: bool,
    /// Keypoints (TC-127, OpenPose or Panoptic JSON, detected; cm for the latter two) shown
    /// as markers on a static mesh.
    #[arg(long, conflicts_with = "sequence")]
    pub keypoints: Option<PathBuf>,
    /// Output .glb.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `panoman export`.
pub fn run(a: ExportArgs) -> Result<()> {
    let input = a
        .mesh
        .as_ref()
        .or(a.sequence.as_ref())
        .expect("clap requires one");
    let seq = match &a.sequence {
        Some(dir) if !dir.is_dir() => bail!("{}: not a folder", dir.display()),
        Some(dir) => Sequence::from_dir(dir)?,
        None => Sequence::from_mesh(input)?,
    };
    let markers = match &a.keypoints {
        Some(k) => Some(Markers::from_keypoints(&[read_keypoints(
            k,
            &ImportOptions::default(),
        )?])),
        None => None,
    };
    let options = GlbOptions {
        fps: a.fps,
        interpolation: if a.step {
            Interpolation::Step
        } else {
            Interpolation::Linear
        },
        ..Default::default()
    };
    let bytes = glb::export_glb(&seq.faces, &seq.frames, markers.as_ref(), &options)
        .with_context(|| input.display().to_string())?;
    panoman_mesh::io::write_bytes_atomically(&a.out, &bytes)?;
    println!(
        "{}: {} frame(s), {} vertices, {:.1} MB",
        a.out.display(),
        seq.frames.len(),
        seq.frames[0].len(),
        bytes.len() as f64 / 1e6
    );
    Ok(())
}
