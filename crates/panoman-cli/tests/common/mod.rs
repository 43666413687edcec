//! Helpers shared by the CLI test files (`mod common;`): run the binary, check success or a
//! one-line error, and synthesize + train a small model once per test binary.
#![allow(dead_code)]

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

/// A fresh temp directory `<tmp>/panoman-<tag>-<pid>` holding a small dataset (`H`, seed
/// `seed`) and a small model trained on it (`M.safetensors`), made through the CLI.
/// Returns (directory, dataset, model).
pub fn small_model(tag: &str, seed: u64) -> (PathBuf, PathBuf, PathBuf) {
    panoman_human::assets::ensure_default().expect("assets");
    let d = std::env::temp_dir().join(format!("panoman-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
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
