//! Helpers shared by the CLI test modules: run the binary, check success or a one-line error,
//! and synthesize + train a small model.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `panoman` binary with `args`.
pub fn panoman(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(args)
        .output()
        .expect("run panoman")
}

/// Asserts success and returns stdout.
pub fn ok(o: Output) -> String {
    assert!(
        o.status.success(),
        "stdout {}\nstderr {}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// Asserts failure with exactly one stderr line `error: …` containing `needle`, no panic.
pub fn one_line_error(o: &Output, needle: &str) {
    assert!(!o.status.success(), "must fail");
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected: {err:?}");
    assert!(
        lines[0].starts_with("error: ") && lines[0].contains(needle),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// A temporary directory `<tmp>/panoman-test-<tag>-<pid>`, removed when dropped. Test binaries
/// keep some of these in statics (shared trained models), which Rust never drops:
/// [`TempDir::new`] therefore also removes the `<tmp>/panoman-test-*-<pid>` folders of earlier
/// test processes that no longer run (Linux: no `/proc/<pid>`), so at most the folders of the
/// running processes exist.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    /// A fresh, empty `<tmp>/panoman-test-<tag>-<pid>`.
    pub fn new(tag: &str) -> TempDir {
        remove_stale_test_dirs();
        let d = std::env::temp_dir().join(format!("panoman-test-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Removes `<tmp>/panoman-test-…-<pid>` directories (made by [`TempDir`]) whose process `<pid>` no longer runs (Linux only;
/// elsewhere nothing is removed).
pub fn remove_stale_test_dirs() {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("panoman-test-") else {
            continue;
        };
        let Some(pid) = rest.rsplit('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if pid != std::process::id()
            && !Path::new("/proc").join(pid.to_string()).exists()
            && e.file_type().is_ok_and(|t| t.is_dir())
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// A fresh temp directory `<tmp>/panoman-test-<tag>-<pid>` (removed when the returned guard drops)
/// holding a small dataset (`H`, seed `seed`) and a small model trained on it
/// (`M.safetensors`), made through the CLI. Returns (directory, dataset, model).
pub fn small_model(tag: &str, seed: u64) -> (TempDir, PathBuf, PathBuf) {
    panoman_human::assets::ensure_default().expect("assets");
    let d = TempDir::new(tag);
    let data = d.join("H");
    let seed = seed.to_string();
    ok(panoman(&[
        "synth",
        "--preset",
        "small",
        "--seed",
        &seed,
        "--out",
        data.to_str().unwrap(),
    ]));
    let model = d.join("M.safetensors");
    ok(train_small(&data, &model, &[]));
    (d, data, model)
}

/// `panoman train --data DATA --preset small [EXTRA…] --out OUT`.
pub fn train_small(data: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "train",
        "--data",
        data.to_str().unwrap(),
        "--preset",
        "small",
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    panoman(&args)
}

/// Keypoints of frame `f` of an `n`-frame clip: the right arm rises and the body turns.
pub fn clip_keypoints(
    model: &panoman::Model,
    g: &panoman::Generator,
    f: usize,
    n: usize,
) -> Vec<[f64; 3]> {
    let u = f as f64 / (n - 1) as f64;
    let params = g
        .parse_params(&format!(
            r#"{{"pose_euler_xyz_deg": {{"upperarm01.R": [0, 0, {:.4}], "lowerarm01.R": [{:.4}, 0, 0]}},
                "root_rotation_z_deg": {:.4}}}"#,
            60.0 * u,
            45.0 * u,
            25.0 * u
        ))
        .unwrap();
    let mesh = g
        .generate(&params, model.output_topology().unwrap())
        .unwrap();
    model.keypoints(&mesh).unwrap()
}
