//! `panoman data …`: fetch the real motion captures (Debian packages `dart-doc`,
//! `assimp-testmodels`) with their licences; see `panoman_mocap::fetch`.

use anyhow::Result;
use clap::Subcommand;
use panoman_mocap::fetch;
use std::path::PathBuf;
use std::time::Instant;

/// Data subcommands.
#[derive(Subcommand, Debug)]
pub enum DataCommand {
    /// Download the real captures with `apt-get download`, verify sha256, keep 4 files + licences.
    #[command(
        after_help = "Examples:\n  panoman data fetch                  # into $PANOMAN_DATA or ~/.cache/panoman/real-mocap\n  panoman data fetch --dir ./real-mocap --debs ./debs   # offline, from downloaded .debs\n\nNeeds apt-get and dpkg-deb with current package lists (`apt-get update`)."
    )]
    Fetch {
        /// Target directory (default: $PANOMAN_DATA, else the user cache directory).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// A directory holding dart-doc_*.deb and assimp-testmodels_*.deb (no download).
        #[arg(long)]
        debs: Option<PathBuf>,
        /// Fetch again even if the target already verifies.
        #[arg(long)]
        force: bool,
    },
}

/// Runs a data subcommand.
pub fn run(cmd: DataCommand) -> Result<()> {
    match cmd {
        DataCommand::Fetch { dir, debs, force } => {
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
