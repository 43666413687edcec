//! Shared helpers of the commands: timing, assets lookup, JSON output, test poses.

use anyhow::Result;
use panoman_human::assets::{self, AssetDir};
use panoman_mesh::geom::V3;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Milliseconds elapsed since `t`.
pub fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Runs `f` `runs` times after `warmup` untimed runs; returns per-run milliseconds.
pub fn time_runs(warmup: usize, runs: usize, mut f: impl FnMut()) -> Vec<f64> {
    for _ in 0..warmup {
        f();
    }
    (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            ms_since(t)
        })
        .collect()
}

/// (median, min, max) of a sample ([`panoman::eval::MedianMinMax::of`]); NaN when empty.
pub fn median_min_max(xs: &[f64]) -> (f64, f64, f64) {
    let m = panoman::eval::MedianMinMax::of(xs);
    (m.median, m.min, m.max)
}

/// The asset directory: `--assets` if given, else `$PANOMAN_ASSETS` or the user cache.
pub fn asset_dir(arg: Option<&Path>) -> PathBuf {
    arg.map(Path::to_path_buf)
        .unwrap_or_else(assets::default_dir)
}

/// Opens the assets, failing with a one-line hint to run `panoman assets fetch`.
pub fn open_assets(arg: Option<&Path>) -> Result<AssetDir> {
    Ok(AssetDir::open(&asset_dir(arg))?)
}

/// Writes `bytes` (text or binary) to `path` atomically (the project's one atomic writer,
/// `panoman_mesh::io::write_bytes_atomically`); the error names `path`.
pub fn write_atomic(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    Ok(panoman_mesh::io::write_bytes_atomically(
        path,
        bytes.as_ref(),
    )?)
}

/// A smooth, large, non-rigid test deformation of a standing body (Z up): the upper body
/// twists about the vertical axis (up to ~70° at the head), the trunk leans forward and the
/// arms (|x| beyond the shoulders) bend down. Used by `bench` and `demo` where no generator
/// pose is needed; every vertex moves, so RL and RA are non-trivial everywhere.
pub fn twist_bend_pose(rest: &[V3]) -> Vec<V3> {
    let zmin = rest.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    let zmax = rest.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    let h = (zmax - zmin).max(1e-9);
    rest.iter()
        .map(|&[x, y, z]| {
            let s = ((z - zmin) / h).clamp(0.0, 1.0); // 0 at the feet, 1 at the head
            // Arms: bend about the y axis around the shoulder, growing with |x|.
            let ax = (x.abs() - 0.18).max(0.0);
            let bend = 0.9 * ax / 0.5 * x.signum();
            let (sb, cb) = bend.sin_cos();
            let (x, z) = if ax > 0.0 {
                let x0 = 0.18 * x.signum();
                let z0 = zmin + 0.82 * h;
                let (dx, dz) = (x - x0, z - z0);
                (x0 + cb * dx + sb * dz, z0 - sb * dx + cb * dz)
            } else {
                (x, z)
            };
            // Twist about the vertical axis, stronger towards the head.
            let a = 1.2 * s * s;
            let (sa, ca) = a.sin_cos();
            let (x, y) = (ca * x - sa * y, sa * x + ca * y);
            // Forward lean of the trunk.
            let lean = 0.25 * s * s;
            [x, y - lean * (z - zmin) * 0.3, z - 0.05 * lean]
        })
        .collect()
}

/// SplitMix64 — a tiny deterministic generator for benchmark and demo noise.
pub struct SplitMix(pub u64);

impl SplitMix {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Standard normal sample (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let u2 = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// Adds i.i.d. Gaussian noise to an RLA: RL gets relative length noise `len_sigma`
/// (ℓ ← ℓ·(1 + σ n)), RA gets `angle_sigma` radians.
pub fn add_rla_noise(rla: &mut panoman_mesh::Rla, len_sigma: f64, angle_sigma: f64, seed: u64) {
    let mut rng = SplitMix(seed);
    for rl in rla.rl.iter_mut() {
        *rl = (1.0 + *rl) * (1.0 + len_sigma * rng.normal()) - 1.0;
    }
    for ra in rla.ra.iter_mut() {
        *ra += angle_sigma * rng.normal();
    }
}

/// A progress bar `{what} [====>   ] pos/len  eta` on stderr (hidden when not a terminal).
pub fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template(&format!(
        "{{spinner}} {what} [{{bar:40}}] {{pos}}/{{len}}  {{per_sec}}  eta {{eta}}"
    )) {
        pb.set_style(style.progress_chars("=> "));
    }
    pb
}

/// Exit status of a fit whose result was written but did not pass the quality check
/// (`converged: false` in report.json; `panoman fit`, `panoman track --strict`).
pub const EXIT_NOT_CONVERGED: u8 = 3;

/// A command that finished its outputs but ends with a warning and a non-zero exit status.
#[derive(Debug)]
pub struct WarnExit {
    /// Exit status.
    pub code: u8,
    /// One-line warning (printed as `warning: …`).
    pub message: String,
}

impl std::fmt::Display for WarnExit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for WarnExit {}
