//! Data fetch: digests, verification, atomicity on failure (with small fake `.deb`s built
//! by `dpkg-deb -b` when it is installed), and — gated — a real fetch.
//!
//! `PANOMAN_FETCH_DEBS=dir` (a directory with the two real `.deb`s) or
//! `PANOMAN_FETCH_NET=1` (download with `apt-get`) run the real fetch.

use std::path::{Path, PathBuf};
use std::process::Command;

use panoman_mocap::MocapError;
use panoman_mocap::fetch::{
    FetchOptions, REAL_MOCAP_FILES, fetch_real_mocap_with, sha256_hex, verify_real_mocap,
};

fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("panoman-mocap-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn sha256_known_vector() {
    assert_eq!(
        sha256_hex(b"abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
}

#[test]
fn verify_names_the_bad_file() {
    let d = scratch("verify");
    for f in &REAL_MOCAP_FILES {
        std::fs::write(d.join(f.name), b"not the capture").unwrap();
    }
    let e = verify_real_mocap(&d).unwrap_err();
    assert!(matches!(e, MocapError::Fetch { .. }));
    assert!(
        e.to_string().contains("nick_freeform_001.c3d: sha256"),
        "{e}"
    );
    std::fs::remove_file(d.join("Nick01.vsk")).unwrap();
    std::fs::write(d.join("nick_freeform_001.c3d"), b"").unwrap();
    let _ = std::fs::remove_dir_all(&d);
}

/// Builds `<pkg>_1.0_all.deb` in `out` holding `files` (paths in the package → bytes).
fn fake_deb(out: &Path, pkg: &str, files: &[(&str, &[u8])]) -> bool {
    let root = out.join(format!("{pkg}-root"));
    std::fs::create_dir_all(root.join("DEBIAN")).unwrap();
    let control = format!(
        "Package: {pkg}\nVersion: 1.0\nArchitecture: all\nMaintainer: t <t@t>\nDescription: t\n"
    );
    std::fs::write(root.join("DEBIAN/control"), control).unwrap();
    for (p, b) in files {
        let f = root.join(p);
        std::fs::create_dir_all(f.parent().unwrap()).unwrap();
        std::fs::write(f, b).unwrap();
    }
    let deb = out.join(format!("{pkg}_1.0_all.deb"));
    Command::new("dpkg-deb")
        .args(["-b", "--root-owner-group"])
        .arg(&root)
        .arg(&deb)
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn failed_fetch_leaves_the_target_alone() {
    let d = scratch("fake");
    let debs = d.join("debs");
    std::fs::create_dir_all(&debs).unwrap();
    let mut ok = true;
    for pkg in ["dart-doc", "assimp-testmodels"] {
        let files: Vec<(&str, &[u8])> = REAL_MOCAP_FILES
            .iter()
            .filter(|f| f.package == pkg)
            .map(|f| (f.path, b"fake".as_slice()))
            .collect();
        ok &= fake_deb(&debs, pkg, &files);
    }
    if !ok {
        eprintln!("dpkg-deb not available: skipping the fake-package fetch test");
        return;
    }
    let target = d.join("target");
    std::fs::create_dir_all(&target).unwrap();
    std::fs::write(target.join("keep.txt"), b"old").unwrap();
    let opts = FetchOptions {
        debs: Some(debs.clone()),
        force: false,
    };
    let e = fetch_real_mocap_with(&target, &opts).unwrap_err();
    assert!(e.to_string().contains("sha256"), "{e}");
    assert_eq!(std::fs::read(target.join("keep.txt")).unwrap(), b"old");
    assert_eq!(std::fs::read_dir(&target).unwrap().count(), 1);
    // No temporary directory is left beside the target.
    let left: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 2, "{left:?}");
    // A package without one of the files: the error names it.
    std::fs::remove_dir_all(&debs).unwrap();
    std::fs::create_dir_all(&debs).unwrap();
    assert!(fake_deb(&debs, "dart-doc", &[("usr/share/doc/x", b"x")]));
    assert!(fake_deb(
        &debs,
        "assimp-testmodels",
        &[("usr/share/doc/y", b"y")]
    ));
    let e = fetch_real_mocap_with(&d.join("new"), &opts).unwrap_err();
    assert!(
        e.to_string()
            .contains("package dart-doc has no /usr/share/doc/dart/data/c3d"),
        "{e}"
    );
    assert!(!d.join("new").exists());
    // No .deb at all.
    let e = fetch_real_mocap_with(
        &d.join("new"),
        &FetchOptions {
            debs: Some(d.join("target")),
            force: false,
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("no dart-doc_*.deb"), "{e}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn real_fetch_when_enabled() {
    let debs = std::env::var_os("PANOMAN_FETCH_DEBS").map(PathBuf::from);
    let net = std::env::var_os("PANOMAN_FETCH_NET").is_some();
    if debs.is_none() && !net {
        eprintln!("PANOMAN_FETCH_DEBS / PANOMAN_FETCH_NET not set: skipping the real fetch");
        return;
    }
    let d = scratch("real");
    let target = d.join("real-mocap");
    let opts = FetchOptions { debs, force: false };
    let r = fetch_real_mocap_with(&target, &opts).unwrap();
    assert!(!r.already_present);
    verify_real_mocap(&target).unwrap();
    assert_eq!(
        std::fs::read_dir(&target).unwrap().count(),
        REAL_MOCAP_FILES.len()
    );
    // Idempotent: the second call finds it complete.
    assert!(
        fetch_real_mocap_with(&target, &opts)
            .unwrap()
            .already_present
    );
    let _ = std::fs::remove_dir_all(&d);
}
