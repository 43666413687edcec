//! Fetch of the real multi-view video the capture is evaluated on, the way a user gets it: the
//! PyPI wheel `pose2sim==0.10.49` (BSD-3-Clause) ships Pose2Sim's demos — four calibrated
//! cameras (Qualisys `Calib.qca.txt`), 60 fps portrait videos. The wheel is downloaded with
//! `python3 -m pip download --no-deps` (or given), its SHA-256 checked against
//! [`POSE2SIM_WHEEL_SHA256`], and only the demos' calibrations, videos, `Config.toml` files and
//! the licence are extracted ([`DEMO_PREFIXES`]; the calibration pictures are left out).
//!
//! The fetch is atomic (assembled in a temporary sibling of the target, a stamp written last,
//! then renamed into place) and idempotent (a target whose stamp names the pinned wheel is left
//! alone unless forced).

pub use panoman_human::assets::FetchReport;
use std::io::Read;
use std::path::{Path, PathBuf};

use panoman_human::assets::{TempDir, sha256_file, sibling, wheel_or_download};

use crate::error::{CaptureError, Result};

/// The pinned Pose2Sim release.
pub const POSE2SIM_VERSION: &str = "0.10.49";
/// The wheel's file name.
pub const POSE2SIM_WHEEL_NAME: &str = "pose2sim-0.10.49-py3-none-any.whl";
/// SHA-256 of [`POSE2SIM_WHEEL_NAME`] (lowercase hex).
pub const POSE2SIM_WHEEL_SHA256: &str =
    "403e0dc4065898ba6a595e72a8970950310979253d60e24c2e00b16b36bf21e1";
/// Name of the completion stamp inside the target (JSON: version, sha256, files).
pub const STAMP_FILE: &str = ".panoman-pose2sim.json";
/// The licence's path in the target.
pub const LICENSE_FILE: &str = "LICENSE.pose2sim.txt";

/// The demos extracted (paths inside the wheel, below `Pose2Sim/`): each trial's videos, its
/// calibration and its `Config.toml`.
pub const DEMO_PREFIXES: [&str; 3] = ["Demo_SinglePerson/", "Demo_Batch/", "Demo_MultiPerson/"];

/// The trials of the held-out-camera evaluation: directories under the target holding
/// `videos/` (their calibration is the trial's or its parent's `calibration/Calib.qca.txt`).
pub const EVAL_TRIALS: [&str; 3] = [
    "Demo_SinglePerson",
    "Demo_Batch/Trial_1",
    "Demo_Batch/Trial_2",
];

/// The default target: `$PANOMAN_VIDEO_DATA` if set (the directory itself), else
/// `$XDG_CACHE_HOME/panoman/pose2sim-demo`, else `$HOME/.cache/panoman/pose2sim-demo`.
pub fn default_dir() -> PathBuf {
    panoman_human::assets::user_cache_dir("PANOMAN_VIDEO_DATA", "pose2sim-demo")
}

/// The calibration of a trial directory: `calibration/Calib.qca.txt` in it or in its parent
/// (Demo_Batch's trials share one).
///
/// # Errors
/// [`CaptureError::Invalid`] naming both places when neither holds one.
pub fn trial_calibration(trial: &Path) -> Result<PathBuf> {
    let own = trial.join("calibration").join("Calib.qca.txt");
    if own.is_file() {
        return Ok(own);
    }
    if let Some(parent) = trial.parent() {
        let p = parent.join("calibration").join("Calib.qca.txt");
        if p.is_file() {
            return Ok(p);
        }
    }
    Err(CaptureError::Invalid(format!(
        "{}: no calibration/Calib.qca.txt in it or its parent",
        trial.display()
    )))
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Stamp {
    pose2sim_version: String,
    wheel_sha256: String,
    files: Vec<String>,
}

/// Reads the stamp of `dir` and checks that it names the pinned wheel and that its files exist.
fn verify(dir: &Path) -> Option<Vec<String>> {
    let text = std::fs::read_to_string(dir.join(STAMP_FILE)).ok()?;
    let stamp: Stamp = serde_json::from_str(&text).ok()?;
    let ok = stamp.pose2sim_version == POSE2SIM_VERSION
        && stamp.wheel_sha256 == POSE2SIM_WHEEL_SHA256
        && stamp.files.iter().all(|f| dir.join(f).is_file());
    ok.then_some(stamp.files)
}

/// Fetches Pose2Sim's demos into `dir` ([`default_dir`] is the usual target).
///
/// The wheel is `wheel` if given, else `$PANOMAN_POSE2SIM_WHEEL`, else downloaded with pip into
/// a temporary directory deleted afterwards. With `force`, a verified target is fetched again.
///
/// # Errors
/// [`CaptureError::Fetch`] when pip fails or the wheel's digest differs (nothing written),
/// [`CaptureError::Io`] / [`CaptureError::Format`] for an unreadable wheel or a target that
/// exists but is not a verified demo directory.
pub fn fetch_video_demo(dir: &Path, wheel: Option<&Path>, force: bool) -> Result<FetchReport> {
    if let Some(files) = verify(dir).filter(|_| !force) {
        return Ok(FetchReport {
            dir: dir.to_path_buf(),
            files,
            already_present: true,
        });
    }
    let human = |e: panoman_human::HumanError| CaptureError::Fetch(e.to_string());
    let (wheel_path, download) = wheel_or_download(
        wheel,
        "PANOMAN_POSE2SIM_WHEEL",
        &format!("pose2sim=={POSE2SIM_VERSION}"),
        POSE2SIM_WHEEL_NAME,
        dir,
    )
    .map_err(human)?;
    let got = sha256_file(&wheel_path).map_err(human)?;
    if got != POSE2SIM_WHEEL_SHA256 {
        return Err(CaptureError::Fetch(format!(
            "{}: sha256 {got}, expected {POSE2SIM_WHEEL_SHA256} (pose2sim=={POSE2SIM_VERSION})",
            wheel_path.display()
        )));
    }
    let mut tmp = TempDir::create(sibling(dir, "tmp").map_err(human)?).map_err(human)?;
    let files = extract(&wheel_path, tmp.path())?;
    drop(download);
    let stamp = Stamp {
        pose2sim_version: POSE2SIM_VERSION.into(),
        wheel_sha256: POSE2SIM_WHEEL_SHA256.into(),
        files: files.clone(),
    };
    let stamp_path = tmp.path().join(STAMP_FILE);
    std::fs::write(
        &stamp_path,
        serde_json::to_vec_pretty(&stamp).expect("the stamp serializes"),
    )
    .map_err(|e| CaptureError::io(&stamp_path, e))?;
    if force && dir.exists() && verify(dir).is_some() {
        std::fs::remove_dir_all(dir).map_err(|e| CaptureError::io(dir, e))?;
    }
    let _ = std::fs::remove_dir(dir); // an empty directory is replaced
    match std::fs::rename(tmp.path(), dir) {
        Ok(()) => tmp.keep(),
        Err(e) => {
            if verify(dir).is_none() {
                return Err(CaptureError::format(
                    dir,
                    format!(
                        "cannot install the demos here ({e}): the directory exists but holds no \
                         verified pose2sim {POSE2SIM_VERSION} demos; remove it or choose another"
                    ),
                ));
            }
        }
    }
    Ok(FetchReport {
        dir: dir.to_path_buf(),
        files,
        already_present: false,
    })
}

/// Whether a wheel entry (below `Pose2Sim/`) is kept: a demo's videos, calibration file or
/// `Config.toml`.
fn wanted(rel: &str) -> bool {
    DEMO_PREFIXES.iter().any(|p| rel.starts_with(p))
        && (rel.contains("/videos/")
            || rel.ends_with("Calib.qca.txt")
            || rel.ends_with("Config.toml"))
        && !rel.ends_with('/')
}

/// Extracts the kept entries and the licence into `dest`; returns their relative paths.
fn extract(wheel: &Path, dest: &Path) -> Result<Vec<String>> {
    let zip_err = |e: zip::result::ZipError| CaptureError::format(wheel, format!("zip: {e}"));
    let file = std::fs::File::open(wheel).map_err(|e| CaptureError::io(wheel, e))?;
    let mut zip = zip::ZipArchive::new(file).map_err(zip_err)?;
    let license = format!("pose2sim-{POSE2SIM_VERSION}.dist-info/licenses/LICENSE");
    let mut out = Vec::new();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(zip_err)?;
        let name = entry.name().map_err(zip_err)?.into_owned();
        let rel = if name == license {
            LICENSE_FILE.to_string()
        } else {
            match name.strip_prefix("Pose2Sim/") {
                Some(r) if wanted(r) => r.to_string(),
                _ => continue,
            }
        };
        if rel.split('/').any(|c| c == ".." || c.is_empty()) {
            return Err(CaptureError::format(
                wheel,
                format!("unsafe entry name {name:?}"),
            ));
        }
        let path = dest.join(&rel);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| CaptureError::io(parent, e))?;
        }
        let mut bytes = Vec::with_capacity(entry.size() as usize);
        entry
            .read_to_end(&mut bytes)
            .map_err(|e| CaptureError::format(wheel, format!("{name}: {e}")))?;
        std::fs::write(&path, bytes).map_err(|e| CaptureError::io(&path, e))?;
        out.push(rel);
    }
    if !out.iter().any(|f| f == LICENSE_FILE) {
        return Err(CaptureError::format(
            wheel,
            format!("no {license} in the wheel"),
        ));
    }
    for t in EVAL_TRIALS {
        if !out.iter().any(|f| f.starts_with(&format!("{t}/videos/"))) {
            return Err(CaptureError::format(
                wheel,
                format!("no videos of {t} in the wheel"),
            ));
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_only_videos_calibrations_and_configs() {
        assert!(wanted("Demo_SinglePerson/videos/cam01.mp4"));
        assert!(wanted("Demo_Batch/calibration/Calib.qca.txt"));
        assert!(wanted("Demo_Batch/Trial_1/Config.toml"));
        assert!(!wanted(
            "Demo_SinglePerson/calibration/extrinsics/cam01_ext.png"
        ));
        assert!(!wanted(
            "Demo_SinglePerson/calibration/intrinsics/int_cam01_img/cam01_01_int.jpg"
        ));
        assert!(!wanted("Utilities/foo.py"));
        assert!(!wanted("Demo_SinglePerson/videos/"));
    }

    #[test]
    fn a_wheel_of_another_digest_is_refused_and_nothing_is_written() {
        let dir = std::env::temp_dir().join(format!("panoman-fetch-video-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let fake = dir.join(POSE2SIM_WHEEL_NAME);
        std::fs::write(&fake, b"not a wheel").unwrap();
        let target = dir.join("demo");
        let e = fetch_video_demo(&target, Some(&fake), false).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("sha256") && msg.contains(POSE2SIM_WHEEL_NAME),
            "{msg}"
        );
        assert!(!target.exists());
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "only the fake wheel remains");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
