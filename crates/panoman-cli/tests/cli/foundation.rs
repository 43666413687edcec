//! Acceptance tests of the foundation: templates, RLA round trips on real human poses (the anny
//! oracle fixtures), robustness of g, bad input, and the bench output schema. They run the real
//! `panoman` binary where the acceptance is about the CLI.

use panoman_human::assets;
use panoman_human::npy::read_npy_f64;
use panoman_human::template::{Template, full_template};
use panoman_mesh::align::aligned_error;
use panoman_mesh::io::{self, ply::PlyFormat};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology, TriMesh};
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common;
use common::panoman;

const CASES: [&str; 3] = ["default", "seed000", "seed001"];

fn fixtures() -> PathBuf {
    std::env::var_os("PANOMAN_FIXTURES")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"))
}

/// A fresh `<tmp>/panoman-test-foundation-<tag>-<pid>`, removed when the guard drops.
fn tmpdir(tag: &str) -> common::TempDir {
    common::TempDir::new(&format!("foundation-{tag}"))
}

fn template() -> Template {
    let a = assets::ensure_default().expect("assets");
    full_template(&a).expect("template")
}

/// Rest and posed meshes of a fixture case, restricted to the template's vertices.
fn case_meshes(t: &Template, case: &str) -> (TriMesh, TriMesh) {
    let dir = fixtures().join("anny-oracle");
    let (_, bmi) = read_npy_f64(dir.join("base_mesh_vertex_indices.npy")).unwrap();
    let bmi: Vec<u32> = bmi.iter().map(|&x| x as u32).collect();
    let restrict = |file: &str| -> Vec<[f64; 3]> {
        let (shape, v) = read_npy_f64(dir.join(file)).unwrap();
        assert_eq!(shape, vec![bmi.len(), 3]);
        t.base_index
            .iter()
            .map(|b| {
                let k = bmi
                    .binary_search(b)
                    .expect("template vertex in anny topology");
                [v[3 * k], v[3 * k + 1], v[3 * k + 2]]
            })
            .collect()
    };
    (
        TriMesh::new(
            restrict(&format!("case_{case}_rest_vertices.npy")),
            t.mesh.faces.clone(),
        ),
        TriMesh::new(
            restrict(&format!("case_{case}_vertices.npy")),
            t.mesh.faces.clone(),
        ),
    )
}

#[test]
fn template_command_writes_valid_full_and_small_meshes() {
    let _ = template();
    let d = tmpdir("template");
    for (topo, nv, nf) in [("full", 13_348, 26_692), ("small", 1_229, 2_454)] {
        let out = d.join(format!("{topo}.obj"));
        let o = panoman(&[
            "template",
            "--topology",
            topo,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let m = io::read_mesh(&out).unwrap();
        let t = Topology::build(m.n_vertices(), &m.faces).unwrap();
        assert_eq!((t.n_vertices, t.n_faces()), (nv, nf), "{topo}");
        assert!(t.is_closed(), "{topo} must be closed");
        assert_eq!(t.n_vertex_components, 1);
        assert_eq!(t.genus(), Some(0));
        if topo == "full" {
            assert_eq!(t.n_edges(), 40_038);
        }
    }
}

#[test]
fn roundtrip_on_real_poses_is_exact_library_and_cli() {
    let t = template();
    let topo = Topology::build(t.mesh.n_vertices(), &t.mesh.faces).unwrap();
    let rec = Reconstructor::new(&topo).unwrap();
    let mut ws = rec.workspace();
    let d = tmpdir("roundtrip");
    for case in CASES {
        let (rest, posed) = case_meshes(&t, case);
        // Library.
        let rg = RestGeometry::new(&topo, &rest.positions).unwrap();
        let rla = Rla::compute(&topo, &rg, &posed.positions).unwrap();
        let mut out = vec![[0.0; 3]; topo.n_vertices];
        rec.reconstruct_rla(
            &mut ws,
            &rg,
            &rla,
            &rec.gauge_from(&rest.positions).unwrap(),
            &mut out,
        )
        .unwrap();
        let (max, mean) = aligned_error(&out, &posed.positions);
        assert!(
            max <= 1e-8,
            "{case}: library max error {max} m (mean {mean})"
        );
        // CLI, through OBJ files (writers print round-trip-exact coordinates).
        let (rp, mp) = (
            d.join(format!("{case}_rest.obj")),
            d.join(format!("{case}_posed.obj")),
        );
        io::write_mesh(&rp, &rest).unwrap();
        io::write_mesh(&mp, &posed).unwrap();
        assert_eq!(
            io::read_mesh(&mp).unwrap(),
            posed,
            "OBJ must round-trip exactly"
        );
        let o = panoman(&[
            "roundtrip",
            "--rest",
            rp.to_str().unwrap(),
            "--mesh",
            mp.to_str().unwrap(),
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8(o.stdout).unwrap();
        let lines: Vec<&str> = stdout.lines().collect();
        assert_eq!(lines.len(), 1, "one JSON object: {stdout}");
        let j: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
        let max = j["max_error_m"].as_f64().unwrap();
        assert!(max <= 1e-8, "{case}: CLI max error {max}");
        assert!(j["mean_error_m"].as_f64().unwrap() <= max);
        assert!(j["g_ms"].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn g_on_noisy_rla_of_a_real_pose_is_finite() {
    let t = template();
    let (rest, posed) = case_meshes(&t, "seed001");
    let topo = Topology::build(rest.n_vertices(), &rest.faces).unwrap();
    let rec = Reconstructor::new(&topo).unwrap();
    let rg = RestGeometry::new(&topo, &rest.positions).unwrap();
    let mut rla = Rla::compute(&topo, &rg, &posed.positions).unwrap();
    // 1 % length noise, 0.05 rad angle noise (deterministic pseudo-random normals).
    let mut s = 12345u64;
    let mut normal = || {
        let mut u = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u1, u2) = (u(), u());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    for x in rla.rl.iter_mut() {
        *x = (1.0 + *x) * (1.0 + 0.01 * normal()) - 1.0;
    }
    for x in rla.ra.iter_mut() {
        *x += 0.05 * normal();
    }
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; topo.n_vertices];
    rec.reconstruct_rla(
        &mut ws,
        &rg,
        &rla,
        &rec.gauge_from(&rest.positions).unwrap(),
        &mut out,
    )
    .unwrap();
    assert!(out.iter().flatten().all(|c| c.is_finite()));
    // Still a body of the right size: the bounding-box diagonal within 20 % of the target's.
    let diag =
        |p: &[[f64; 3]]| panoman_mesh::measure::bbox_diagonal(&TriMesh::new(p.to_vec(), vec![]));
    let ratio = diag(&out) / diag(&posed.positions);
    assert!((0.8..1.2).contains(&ratio), "bbox ratio {ratio}");
}

fn assert_one_line_error(o: &std::process::Output, file: &str, what: &str) {
    assert!(!o.status.success(), "{what}: must fail");
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{what}: one line expected, got {err:?}");
    assert!(lines[0].starts_with("error: "), "{what}: {err}");
    assert!(lines[0].contains(file), "{what}: must name {file}: {err}");
    assert!(!err.contains("panicked"), "{what}: {err}");
}

#[test]
fn bad_input_gives_one_clear_error_line() {
    let t = template();
    let d = tmpdir("bad");
    let (rest, posed) = case_meshes(&t, "seed000");
    let rp = d.join("rest.obj");
    io::write_mesh(&rp, &rest).unwrap();
    let rest_s = rp.to_str().unwrap();
    let run = |mesh: &Path| {
        panoman(&[
            "roundtrip",
            "--rest",
            rest_s,
            "--mesh",
            mesh.to_str().unwrap(),
            "--json",
        ])
    };

    // Truncated OBJ (cut mid-line inside the face list).
    let full = std::fs::read_to_string(&rp).unwrap();
    let cut = d.join("truncated.obj");
    let at = full.len() * 3 / 4;
    let at = full[..at].rfind("\nf ").unwrap() + 4;
    std::fs::write(&cut, &full[..at]).unwrap();
    assert_one_line_error(&run(&cut), "truncated.obj", "truncated OBJ");

    // Truncated binary PLY.
    let ply = d.join("posed.ply");
    io::ply::write_ply(&ply, &posed, PlyFormat::BinaryLittleEndian).unwrap();
    let bytes = std::fs::read(&ply).unwrap();
    let tply = d.join("truncated.ply");
    std::fs::write(&tply, &bytes[..bytes.len() / 2]).unwrap();
    assert_one_line_error(&run(&tply), "truncated.ply", "truncated PLY");

    // Vertex-count mismatch.
    let fewer = d.join("fewer.obj");
    let mut m = posed.clone();
    m.positions.pop();
    m.faces
        .retain(|f| f.iter().all(|&v| (v as usize) < m.positions.len()));
    io::write_mesh(&fewer, &m).unwrap();
    assert_one_line_error(&run(&fewer), "fewer.obj", "vertex count mismatch");

    // NaN coordinates.
    let nan = d.join("nan.obj");
    let text: Vec<String> = std::fs::read_to_string(&rp)
        .unwrap()
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i > 0 && l.starts_with("v ") && i < 20 {
                "v nan 0 0".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(&nan, text.join("\n")).unwrap();
    assert_one_line_error(&run(&nan), "nan.obj", "NaN coordinates");

    // Inconsistent orientation (one face flipped, rest and mesh alike).
    let mut flipped = rest.clone();
    flipped.faces[100].swap(1, 2);
    let fp = d.join("flipped.obj");
    io::write_mesh(&fp, &flipped).unwrap();
    let o = panoman(&[
        "roundtrip",
        "--rest",
        fp.to_str().unwrap(),
        "--mesh",
        fp.to_str().unwrap(),
    ]);
    assert_one_line_error(&o, "flipped.obj", "inconsistent orientation");
    assert!(String::from_utf8_lossy(&o.stderr).contains("inconsistently oriented"));

    // Non-manifold edge: a third triangle on an edge of a tetrahedron.
    let nm = d.join("nonmanifold.obj");
    std::fs::write(
        &nm,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\nf 1 2 5\n",
    )
    .unwrap();
    let o = panoman(&[
        "roundtrip",
        "--rest",
        nm.to_str().unwrap(),
        "--mesh",
        nm.to_str().unwrap(),
    ]);
    assert_one_line_error(&o, "nonmanifold.obj", "non-manifold mesh");
    assert!(String::from_utf8_lossy(&o.stderr).contains("non-manifold"));

    // Missing file.
    let o = panoman(&[
        "roundtrip",
        "--rest",
        rest_s,
        "--mesh",
        d.join("missing.obj").to_str().unwrap(),
    ]);
    assert_one_line_error(&o, "missing.obj", "missing file");

    // Missing assets: a clear hint, no panic.
    let o = Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(["template", "--out", d.join("t.obj").to_str().unwrap()])
        .env("PANOMAN_ASSETS", d.join("no-assets-here"))
        .output()
        .unwrap();
    assert_one_line_error(&o, "no-assets-here", "missing assets");
    assert!(String::from_utf8_lossy(&o.stderr).contains("panoman assets fetch"));
    assert!(!d.join("t.obj").exists(), "nothing half-written");
}

#[test]
fn bench_prints_one_json_object_per_line() {
    let _ = template();
    let o = panoman(&["bench", "--json", "--runs", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    let mut names = Vec::new();
    for line in stdout.lines() {
        let j: serde_json::Value = serde_json::from_str(line).expect("each line is JSON");
        for key in ["median_ms", "min_ms", "max_ms"] {
            assert!(j[key].as_f64().unwrap() >= 0.0, "{line}");
        }
        assert!(j["runs"].as_u64().unwrap() >= 1);
        names.push(j["name"].as_str().unwrap().to_string());
    }
    for need in ["g_full", "rla_full", "g_small", "setup_full"] {
        assert!(
            names.iter().any(|n| n == need),
            "missing {need} in {names:?}"
        );
    }
}

/// Subcommand names listed under "Commands:" in a `--help` text.
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .filter(|c| c != "help")
        .collect()
}

#[test]
fn every_command_has_help_with_an_example() {
    let top = String::from_utf8(panoman(&["--help"]).stdout).unwrap();
    let cmds = subcommands(&top);
    assert!(cmds.len() >= 5, "{top}");
    let mut checked = 0;
    for c in &cmds {
        let help = String::from_utf8(panoman(&[c, "--help"]).stdout).unwrap();
        let subs = subcommands(&help);
        if subs.is_empty() {
            assert!(
                help.contains("Example"),
                "`panoman {c} --help` has no example:\n{help}"
            );
            checked += 1;
        } else {
            for s in subs {
                let o = panoman(&[c, &s, "--help"]);
                let help = String::from_utf8(o.stdout).unwrap();
                assert!(
                    help.contains("Example"),
                    "`panoman {c} {s} --help` has no example:\n{help}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 6);
}
