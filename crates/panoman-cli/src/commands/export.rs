//! `panoman export`: meshes and mesh sequences as glTF 2.0 binary (.glb); the logic lives in
//! `panoman-interchange`.

use anyhow::{Context, Result, bail};
use clap::Args;
use panoman_interchange::glb::{self, GlbOptions, Interpolation, Markers};
use panoman_interchange::keypoints_in::{ImportOptions, read_keypoints};
use panoman_interchange::sequence::Sequence;
use panoman_interchange::skinned;
use std::path::PathBuf;

/// Arguments of `panoman export`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman export --mesh fit/mesh.obj --out fit.glb\n  panoman export --sequence track/ --fps 30 --out clip.glb\n  panoman export --lbs track_lbs/ --out rig.glb     # skinned armature"
)]
pub struct ExportArgs {
    /// One mesh (.obj or .ply) → a static .glb.
    #[arg(long, conflicts_with_all = ["sequence", "lbs", "params"], required_unless_present_any = ["sequence", "lbs", "params"])]
    pub mesh: Option<PathBuf>,
    /// Model parameters (α, β, placement; e.g. a fit's params.json) posed by `--model` → a
    /// static .glb.
    #[arg(long, requires = "model", conflicts_with_all = ["sequence", "lbs"])]
    pub params: Option<PathBuf>,
    /// The model for `--params`.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// A folder of per-frame meshes (e.g. `panoman track`'s output), in name order → one
    /// animated .glb (morph targets).
    #[arg(long, conflicts_with = "lbs")]
    pub sequence: Option<PathBuf>,
    /// A `panoman track --baseline lbs` folder (its `*.params.json`) → a skinned armature of
    /// the rig's bones with the pose animation (first frame's identity; needs the assets).
    #[arg(long)]
    pub lbs: Option<PathBuf>,
    /// Asset directory for --lbs (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
    /// Frame rate of the sequence's animation.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Hold each frame instead of blending consecutive frames linearly.
    #[arg(long)]
    pub step: bool,
    /// Keypoints (TC-133, OpenPose or Panoptic JSON, detected; cm for the latter two) shown
    /// as markers on a static mesh.
    #[arg(long, conflicts_with = "sequence")]
    pub keypoints: Option<PathBuf>,
    /// Output .glb.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `panoman export`.
pub fn run(a: ExportArgs) -> Result<()> {
    if let Some(dir) = &a.lbs {
        return run_lbs(dir, &a);
    }
    let input = a
        .mesh
        .as_ref()
        .or(a.sequence.as_ref())
        .or(a.params.as_ref())
        .expect("clap requires one");
    let seq = match (&a.sequence, &a.params, &a.model) {
        (Some(dir), _, _) if !dir.is_dir() => bail!("{}: not a folder", dir.display()),
        (Some(dir), _, _) => Sequence::from_dir(dir)?,
        (None, Some(p), Some(m)) => {
            let model = panoman::Model::load(m)?;
            let params = model.read_params(p)?;
            let v = model
                .pose(&params, panoman::Correction::Apply)
                .map_err(|e| anyhow::anyhow!("{}", e.in_file(p)))?;
            Sequence {
                files: vec![p.clone()],
                faces: model.faces().to_vec(),
                frames: vec![v],
            }
        }
        _ => Sequence::from_mesh(input)?,
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

/// `--lbs DIR`: the skinned export of an LBS track folder.
fn run_lbs(dir: &std::path::Path, a: &ExportArgs) -> Result<()> {
    let assets = crate::util::open_assets(a.assets.as_deref())?;
    let generator = panoman_human::generator::Generator::load(&assets, Default::default())?;
    let files = skinned::params_files(dir)?;
    let frames = files
        .iter()
        .map(|p| generator.read_params(p))
        .collect::<panoman_human::Result<Vec<_>>>()?;
    let (bytes, differing) = skinned::lbs_sequence_glb(&generator, &frames, a.fps)
        .with_context(|| dir.display().to_string())?;
    panoman_mesh::io::write_bytes_atomically(&a.out, &bytes)?;
    if differing > 0 {
        eprintln!(
            "note: {differing} frame(s) have another shape than the first; the armature uses the first"
        );
    }
    println!(
        "{}: skinned, {} frame(s), {} bones",
        a.out.display(),
        frames.len(),
        generator.bone_names().len()
    );
    Ok(())
}
