//! Training data and model training from the assets: dataset synthesis ([`synthesize`]), a
//! model from a dataset with the LBS rig embedded ([`train`]), and the small model the
//! examples and doc tests use ([`small_model`]).
use std::path::{Path, PathBuf};
use std::sync::Arc;

use panoman_human::assets::{self, AssetDir};
use panoman_human::dataset::{self, Dataset, SynthConfig, SynthSummary};
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::TopologyMap;
use panoman_human::regions::Regions;
use panoman_human::rigfile::RigData;
use panoman_human::template::{TopologyKind, full_template, small_template};
use panoman_model::model::{KeypointRows, PanoManModel};
use panoman_model::train::{TrainConfig, TrainInputs, TrainOutput};

use crate::error::{Error, Result};

/// Writes the training set H of `config` to `out` (`panoman synth`; byte-identical per seed).
/// `progress(done, total)` is called as rows are written.
///
/// # Errors
/// Asset errors; an invalid configuration; I/O errors naming `out`.
pub fn synthesize(
    assets: &AssetDir,
    config: &SynthConfig,
    out: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary> {
    // Breast and local-change targets are not used (cupsize = firmness = 0.5, no changes).
    let opts = GeneratorOptions {
        breast: false,
        local_changes: false,
    };
    let generator = Generator::load(assets, opts)?;
    let full = full_template(assets)?;
    let small = small_template(assets, &full)?;
    let map = TopologyMap::new(&generator, &full, &small)?;
    Ok(dataset::synthesize(
        &generator, &map, config, out, progress,
    )?)
}

/// A trained model with its data, ready for [`panoman_model::train::evaluate`].
pub struct Trained {
    /// The model (LBS rig embedded) and the training report.
    pub output: TrainOutput,
    /// The dataset it was trained on.
    pub dataset: Dataset,
    /// The template regions of the model's topology.
    pub regions: Regions,
}

/// Trains a model on the dataset in `data` (`panoman train`): the template, its regions and
/// the TC-133 keypoint regressors come from the assets, and the LBS rig the fit's
/// initializer needs is embedded in the model ([`PanoManModel::rig`]), so the model file
/// alone can pose, encode, fit and track. `progress(stage)` names each stage as it starts.
///
/// # Errors
/// An unreadable dataset or an unknown topology in it (naming `data`); asset errors;
/// training failures.
pub fn train(
    assets: &AssetDir,
    data: &Path,
    cfg: &TrainConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Trained> {
    let ds = Dataset::open(data)?;
    let full = full_template(assets)?;
    let topo_name = ds.meta["topology"]["name"]
        .as_str()
        .unwrap_or("")
        .to_string();
    let full_regions = Regions::full(assets, &full)?;
    let small = small_template(assets, &full)?;
    let kp_defs = panoman_human::keypoints::load_or_build(assets, &full, &small)?;
    let (faces, regions, kind) = match topo_name.as_str() {
        "full" => (full.mesh.faces.clone(), full_regions, TopologyKind::Full),
        "small" => {
            let r = Regions::small(&full_regions, &small)
                .map_err(|e| Error::Invalid(format!("small regions: {e}")))?;
            (small.mesh.faces.clone(), r, TopologyKind::Small)
        }
        other => {
            return Err(Error::Format {
                path: data.join("dataset.json"),
                what: format!("unknown topology '{other}'"),
            });
        }
    };
    let kp = kp_defs.set(kind);
    let inputs = TrainInputs {
        dataset: &ds,
        topology_name: topo_name,
        faces,
        regions: &regions,
        keypoints: KeypointRows {
            names: kp.names.clone(),
            rows: kp.rows.clone(),
        },
    };
    let mut output =
        panoman_model::train::train(&inputs, cfg, progress).map_err(|e| Error::Format {
            path: data.to_path_buf(),
            what: e.to_string(),
        })?;
    progress("LBS rig");
    output.model.rig = Some(Arc::new(RigData::from_assets(assets)?));
    Ok(Trained {
        output,
        dataset: ds,
        regions,
    })
}

/// The dataset in `data` and the template regions of its topology (for
/// [`panoman_model::train::evaluate`] of an already trained model).
///
/// # Errors
/// An unreadable dataset or an unknown topology in it; asset errors.
pub fn dataset_and_regions(assets: &AssetDir, data: &Path) -> Result<(Dataset, Regions)> {
    let ds = Dataset::open(data)?;
    let full = full_template(assets)?;
    let full_regions = Regions::full(assets, &full)?;
    let regions = match ds.meta["topology"]["name"].as_str().unwrap_or("") {
        "full" => full_regions,
        "small" => {
            let small = small_template(assets, &full)?;
            Regions::small(&full_regions, &small)
                .map_err(|e| Error::Invalid(format!("small regions: {e}")))?
        }
        other => {
            return Err(Error::Format {
                path: data.join("dataset.json"),
                what: format!("unknown topology '{other}'"),
            });
        }
    };
    Ok((ds, regions))
}

/// Embeds the LBS rig into a model trained before rigs were embedded.
///
/// # Errors
/// Asset errors.
pub fn embed_rig(model: &mut PanoManModel, assets: &AssetDir) -> Result<()> {
    model.rig = Some(Arc::new(RigData::from_assets(assets)?));
    Ok(())
}

/// The small model of the examples and doc tests: the `small` dataset preset and training
/// preset (seconds), built once into `dir` (default `$PANOMAN_EXAMPLES`, else
/// `<system temp>/panoman-examples`) and reused while it loads. Fetches the assets on first
/// use (pip, see [`panoman_human::assets::ensure_default`]).
///
/// # Errors
/// Asset, synthesis or training errors.
pub fn small_model(dir: Option<&Path>) -> Result<PathBuf> {
    let dir = match dir {
        Some(d) => d.to_path_buf(),
        None => std::env::var_os("PANOMAN_EXAMPLES")
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
            .unwrap_or_else(|| std::env::temp_dir().join("panoman-examples")),
    };
    let path = dir.join("small.safetensors");
    if PanoManModel::load(&path).is_ok_and(|m| m.rig.is_some()) {
        return Ok(path);
    }
    std::fs::create_dir_all(&dir).map_err(|source| Error::Io {
        path: dir.clone(),
        source,
    })?;
    let assets = assets::ensure_default()?;
    // A data folder of this process, so that concurrent first uses do not share one.
    let data = dir.join(format!("small-data-{}", std::process::id()));
    synthesize(
        &assets,
        &SynthConfig::preset("small")?,
        &data,
        &mut |_, _| {},
    )?;
    let cfg = TrainConfig::preset("small")?;
    let trained = train(&assets, &data, &cfg, &mut |_| {})?;
    trained.output.model.save(&path)?;
    let _ = std::fs::remove_dir_all(&data);
    Ok(path)
}
