//! Fetch of the real captures the project evaluates on, the way a user gets them: the two
//! Debian packages that ship them (`dart-doc`, `assimp-testmodels`) are downloaded with
//! `apt-get download` (the package lists must be current: `apt-get update`), unpacked with
//! `dpkg-deb -x`, and only the four capture files and their licence texts are copied into
//! the target directory. The captures' SHA-256 digests are checked against
//! [`REAL_MOCAP_FILES`].
//!
//! The fetch is atomic (everything is assembled in a temporary sibling of the target and
//! renamed into place) and idempotent (a target whose captures already verify is left
//! alone).

pub use panoman_human::assets::FetchReport;
use std::path::{Path, PathBuf};
use std::process::Command;

use sha2::{Digest, Sha256};

use crate::error::{MocapError, Result, read_bytes};

/// One file taken from a Debian package.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataFile {
    /// File name in the target directory.
    pub name: &'static str,
    /// Debian package (bookworm) that ships it.
    pub package: &'static str,
    /// Path inside the package.
    pub path: &'static str,
    /// Pinned SHA-256 (lowercase hex) for the captures; `None` for licence texts.
    pub sha256: Option<&'static str>,
}

/// The Debian packages [`fetch_real_mocap`] downloads.
pub const PACKAGES: [&str; 2] = ["dart-doc", "assimp-testmodels"];

/// The files [`fetch_real_mocap`] installs: four captures (digests pinned) and the licence
/// texts that go with them.
pub const REAL_MOCAP_FILES: [DataFile; 8] = [
    DataFile {
        name: "nick_freeform_001.c3d",
        package: "dart-doc",
        path: "usr/share/doc/dart/data/c3d/nick_freeform_001.c3d",
        sha256: Some("071a483aae9ef3d6c41061de65236a9d54ab50c10fcd0cbbf9c4720580e7fae6"),
    },
    DataFile {
        name: "Nick01.vsk",
        package: "dart-doc",
        path: "usr/share/doc/dart/data/vsk/Nick01.vsk",
        sha256: Some("0cba42ec042423bd046eed463e92c7bd7b2132cf9cbea53507abf5a6892f813f"),
    },
    DataFile {
        name: "ThomasFechten.csm",
        package: "assimp-testmodels",
        path: "usr/share/assimp/models/CSM/ThomasFechten.csm",
        sha256: Some("435bc595628498a236769fec1e9cca73a4ce609628e318674fa69ec02fab62f7"),
    },
    DataFile {
        name: "01_01.bvh",
        package: "assimp-testmodels",
        path: "usr/share/assimp/models/BVH/01_01.bvh",
        sha256: Some("1d9ee909452ee62784306545cf1fcd634243db1173e0c90cecbed793e50361a8"),
    },
    DataFile {
        name: "DEBIAN_COPYRIGHT_dart-doc.txt",
        package: "dart-doc",
        path: "usr/share/doc/dart-doc/copyright",
        sha256: None,
    },
    DataFile {
        name: "DEBIAN_COPYRIGHT_assimp-testmodels.txt",
        package: "assimp-testmodels",
        path: "usr/share/doc/assimp-testmodels/copyright",
        sha256: None,
    },
    DataFile {
        name: "ThomasFechten.source.txt",
        package: "assimp-testmodels",
        path: "usr/share/assimp/models/CSM/ThomasFechten.source.txt",
        sha256: None,
    },
    DataFile {
        name: "01_nn.bvh.source.txt",
        package: "assimp-testmodels",
        path: "usr/share/assimp/models/BVH/01_nn.bvh.source.txt",
        sha256: None,
    },
];

/// The default target: `$PANOMAN_DATA` if set (the directory itself), else
/// `$XDG_CACHE_HOME/panoman/real-mocap`, else `$HOME/.cache/panoman/real-mocap` (else the
/// same below the system temporary directory).
pub fn default_dir() -> PathBuf {
    panoman_human::assets::user_cache_dir("PANOMAN_DATA", "real-mocap")
}

/// SHA-256 of bytes as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Checks that `dir` holds every file of [`REAL_MOCAP_FILES`] and that the captures'
/// digests match.
///
/// # Errors
/// [`MocapError::Io`] for a missing or unreadable file, [`MocapError::Fetch`] naming the
/// file whose digest differs.
pub fn verify_real_mocap(dir: &Path) -> Result<()> {
    for f in &REAL_MOCAP_FILES {
        let p = dir.join(f.name);
        let bytes = read_bytes(&p)?;
        if let Some(want) = f.sha256 {
            let got = sha256_hex(&bytes);
            if got != want {
                return Err(MocapError::Fetch {
                    what: format!("{}: sha256 {got}, expected {want}", p.display()),
                });
            }
        }
    }
    Ok(())
}

/// Options of [`fetch_real_mocap_with`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FetchOptions {
    /// A directory already holding the two `.deb` files (`<package>_<version>_all.deb`);
    /// when set, nothing is downloaded.
    pub debs: Option<PathBuf>,
    /// Fetch again even when the target verifies.
    pub force: bool,
}

/// Fetches the real captures into `dir` (see the module docs).
///
/// # Errors
/// See [`fetch_real_mocap_with`].
pub fn fetch_real_mocap(dir: &Path) -> Result<FetchReport> {
    fetch_real_mocap_with(dir, &FetchOptions::default())
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> MocapError + '_ {
    move |source| MocapError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Fetches the real captures into `dir`, with options.
///
/// # Errors
/// [`MocapError::Fetch`] when `apt-get` or `dpkg-deb` cannot be run or fails (with the
/// command's stderr), a package's `.deb` is not found, a file is missing from a
/// package, or a digest differs; [`MocapError::Io`] for file-system failures (naming the
/// path). On error the target is unchanged and the temporary directory is removed.
pub fn fetch_real_mocap_with(dir: &Path, opts: &FetchOptions) -> Result<FetchReport> {
    if !opts.force && verify_real_mocap(dir).is_ok() {
        return Ok(FetchReport {
            dir: dir.to_path_buf(),
            files: file_names(),
            already_present: true,
        });
    }
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(io(&parent))?;
    let base = dir.file_name().map(|n| n.to_string_lossy().into_owned());
    let base = base.unwrap_or_else(|| "real-mocap".into());
    let tmp = parent.join(format!(".{base}.fetch-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
    let result = assemble(&tmp, opts).and_then(|out| install(&out, dir, &tmp));
    let _ = std::fs::remove_dir_all(&tmp);
    result.map(|()| FetchReport {
        dir: dir.to_path_buf(),
        files: file_names(),
        already_present: false,
    })
}

/// The names of [`REAL_MOCAP_FILES`].
fn file_names() -> Vec<String> {
    REAL_MOCAP_FILES
        .iter()
        .map(|f| f.name.to_string())
        .collect()
}

/// Downloads (or takes) the packages, extracts them and assembles `tmp/out`.
fn assemble(tmp: &Path, opts: &FetchOptions) -> Result<PathBuf> {
    let debs = match &opts.debs {
        Some(d) => d.clone(),
        None => {
            let d = tmp.join("debs");
            std::fs::create_dir_all(&d).map_err(io(&d))?;
            let mut cmd = Command::new("apt-get");
            cmd.arg("download").args(PACKAGES).current_dir(&d);
            run(
                cmd,
                "apt-get download dart-doc assimp-testmodels (are the lists current? run `apt-get update`)",
            )?;
            d
        }
    };
    let x = tmp.join("x");
    for pkg in PACKAGES {
        let deb = find_deb(&debs, pkg)?;
        let into = x.join(pkg);
        std::fs::create_dir_all(&into).map_err(io(&into))?;
        let mut cmd = Command::new("dpkg-deb");
        cmd.arg("-x").arg(&deb).arg(x.join(pkg));
        run(cmd, &format!("dpkg-deb -x {}", deb.display()))?;
    }
    let out = tmp.join("out");
    std::fs::create_dir_all(&out).map_err(io(&out))?;
    for f in &REAL_MOCAP_FILES {
        let src = x.join(f.package).join(f.path);
        if !src.is_file() {
            return Err(MocapError::Fetch {
                what: format!("package {} has no /{}", f.package, f.path),
            });
        }
        let dst = out.join(f.name);
        std::fs::copy(&src, &dst).map_err(io(&dst))?;
    }
    verify_real_mocap(&out)?;
    Ok(out)
}

/// Moves `out` to `dir`, replacing an old (unverified) `dir` only once `out` is complete.
fn install(out: &Path, dir: &Path, tmp: &Path) -> Result<()> {
    if dir.exists() {
        let old = tmp.join("old");
        std::fs::rename(dir, &old).map_err(io(dir))?;
        if let Err(e) = std::fs::rename(out, dir) {
            let _ = std::fs::rename(&old, dir);
            return Err(io(dir)(e));
        }
        Ok(())
    } else {
        std::fs::rename(out, dir).map_err(io(dir))
    }
}

/// The `.deb` of `pkg` in `dir` (`<pkg>_*.deb`).
fn find_deb(dir: &Path, pkg: &str) -> Result<PathBuf> {
    let prefix = format!("{pkg}_");
    let entries = std::fs::read_dir(dir).map_err(io(dir))?;
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(&prefix) && n.ends_with(".deb"))
        })
        .collect();
    found.sort();
    found.pop().ok_or_else(|| MocapError::Fetch {
        what: format!("no {prefix}*.deb in {}", dir.display()),
    })
}

/// Runs a command; failure to start or a non-zero exit is a [`MocapError::Fetch`].
fn run(mut cmd: Command, what: &str) -> Result<()> {
    let out = cmd.output().map_err(|e| MocapError::Fetch {
        what: format!("could not run {what}: {e}"),
    })?;
    if out.status.success() {
        return Ok(());
    }
    let stderr = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = stderr
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    let mut msg = lines.join("; ");
    if msg.len() > 400 {
        let cut = (0..=400)
            .rev()
            .find(|&i| msg.is_char_boundary(i))
            .unwrap_or(0);
        msg.truncate(cut);
        msg.push('…');
    }
    Err(MocapError::Fetch {
        what: format!("{what} failed ({}): {msg}", out.status),
    })
}
