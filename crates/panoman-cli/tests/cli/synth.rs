//! `panoman synth` (the real binary) and [`panoman_human::dataset`]: byte-identical files for a
//! seed whatever the thread count, shapes and counts, the split, what each row kind moves,
//! the preview, and errors.

use panoman_human::dataset::{Dataset, KIND_BODY, KIND_FACE, KIND_HAND, KIND_REST};
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::ShapeParams;
use panoman_human::sampling::{FACE_SLOT, LEFT_HAND_SLOT, N_POSABLE, posable_bones};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::Topology;
use std::path::Path;
use std::process::Command;
use std::sync::OnceLock;

use crate::common;

/// A fresh `<tmp>/panoman-test-synth-<tag>-<pid>`, removed when the guard drops.
fn tmpdir(tag: &str) -> common::TempDir {
    common::TempDir::new(&format!("synth-{tag}"))
}

fn synth(out: &Path, threads: &str, extra: &[&str]) -> std::process::Output {
    let o = Command::new(env!("CARGO_BIN_EXE_panoman"))
        .args(["synth", "--preset", "small", "--out"])
        .arg(out)
        .args(extra)
        .env("RAYON_NUM_THREADS", threads)
        .output()
        .expect("run panoman");
    assert!(
        o.status.success(),
        "panoman synth failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn bytes(dir: &Path, name: &str) -> Vec<u8> {
    std::fs::read(dir.join(name)).unwrap()
}

/// The small preset at seed 5, written once for the tests that only read it.
fn small_dataset() -> &'static Path {
    static D: OnceLock<common::TempDir> = OnceLock::new();
    D.get_or_init(|| {
        let d = tmpdir("shared");
        synth(&d, "2", &["--seed", "5"]);
        d
    })
}

struct Fx {
    generator: Generator,
    map: TopologyMap,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("assets");
        let opts = GeneratorOptions {
            breast: false,
            local_changes: false,
        };
        let generator = Generator::load(&dir, opts).expect("generator");
        let full = full_template(&dir).unwrap();
        let small = small_template(&dir, &full).unwrap();
        let map = TopologyMap::new(&generator, &full, &small).unwrap();
        Fx { generator, map }
    })
}

#[test]
fn same_seed_gives_identical_bytes_whatever_the_threads() {
    let base = tmpdir("determinism");
    let (a, b, c, d) = (
        base.join("a"),
        base.join("b"),
        base.join("c"),
        base.join("d"),
    );
    let out = synth(&a, "1", &["--seed", "3"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("132 rows (12 rest, 40 body, 40 face, 40 hand)"),
        "{text}"
    );
    assert!(text.contains("MB in"), "{text}");
    synth(&b, "2", &["--seed", "3"]);
    synth(&c, "3", &["--seed", "3"]);
    synth(&d, "2", &["--seed", "4"]);
    for name in ["dataset.safetensors", "dataset.json"] {
        let ba = bytes(&a, name);
        assert_eq!(ba, bytes(&b, name), "{name}: 1 vs 2 threads");
        assert_eq!(ba, bytes(&c, name), "{name}: 1 vs 3 threads");
        assert_ne!(ba, bytes(&d, name), "{name}: seeds 3 and 4");
    }
    // No temporary files left behind.
    let names: Vec<String> = std::fs::read_dir(&a)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    let _ = std::fs::remove_dir_all(&base);
}

#[test]
fn shapes_counts_split_and_hash() {
    let dir = small_dataset();
    let f = fx();
    let faces = f.map.faces(OutputTopology::Small);
    let hash = Topology::build(1229, faces).unwrap().hash_hex();
    let ds = Dataset::open_for(dir, &hash).expect("valid dataset");
    assert_eq!(ds.n_rows, 132);
    assert_eq!(ds.n_vertices, 1229);
    assert_eq!(ds.counts(), [12, 40, 40, 40]);
    assert_eq!(ds.theta_bones, posable_bones());
    assert_eq!(ds.theta.len(), 132 * 3 * N_POSABLE);
    assert_eq!(ds.phenotype.len(), 132 * 6);
    assert_eq!(ds.face_units.len(), 132 * 52);
    let m = &ds.meta;
    assert_eq!(m["topology"]["name"], "small");
    assert_eq!(m["seed"], 5);
    assert_eq!(m["preset"], "small");
    assert_eq!(m["generator"]["anny_version"], "0.6.2");
    // Split: disjoint, covering, about 12.5 % held out.
    assert!(!ds.held_out.is_empty());
    assert!(ds.held_out.iter().all(|h| !ds.train.contains(h)));
    assert_eq!(ds.held_out.len() + ds.train.len(), 12);
    assert_eq!(ds.held_out.len(), 2);
    // Each identity: one rest row, rows contiguous, kinds in order rest, body, face, hand.
    for r in 0..ds.n_rows {
        let rest = ds.rest_of[r] as usize;
        assert_eq!(ds.kind[rest], KIND_REST);
        assert_eq!(ds.identity[rest], ds.identity[r]);
        if r > 0 && ds.identity[r] == ds.identity[r - 1] {
            assert!(ds.kind[r] >= ds.kind[r - 1]);
        }
        let p = &ds.phenotype[6 * r..6 * r + 6];
        assert_eq!(p, &ds.phenotype[6 * rest..6 * rest + 6]);
        // Theta: rest rows zero; face rows only jaw/eyes; hand rows only hands.
        let th = ds.theta_row(r);
        let nz = |range: std::ops::Range<usize>| {
            th[3 * range.start..3 * range.end].iter().any(|&x| x != 0.0)
        };
        match ds.kind[r] {
            KIND_REST => assert!(th.iter().all(|&x| x == 0.0)),
            KIND_BODY => assert!(nz(0..LEFT_HAND_SLOT) && nz(LEFT_HAND_SLOT..FACE_SLOT)),
            KIND_FACE => {
                assert!(!nz(0..FACE_SLOT));
                assert!(ds.face_units[52 * r..52 * r + 52].iter().any(|&u| u > 0.0));
            }
            KIND_HAND => assert!(!nz(0..LEFT_HAND_SLOT) && nz(LEFT_HAND_SLOT..FACE_SLOT)),
            _ => unreachable!(),
        }
        if ds.kind[r] != KIND_FACE {
            assert!(ds.face_units[52 * r..52 * r + 52].iter().all(|&u| u == 0.0));
        }
    }
}

fn max_disp(a: &[[f32; 3]], b: &[[f32; 3]], keep: impl Fn(usize) -> bool) -> f32 {
    a.iter()
        .zip(b)
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, (p, q))| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        })
        .fold(0.0, f32::max)
}

#[test]
fn rows_move_what_their_kind_says() {
    let dir = small_dataset();
    let ds = Dataset::open(dir).unwrap();
    let f = fx();
    let names = f.generator.bone_names();
    let neck = names.iter().position(|b| b == "neck01").unwrap();
    let (mut n_face, mut n_body, mut n_hand) = (0, 0, 0);
    let mut worst_face_body = 0.0f32;
    for r in 0..ds.n_rows {
        let rest = ds.rest_of[r] as usize;
        if r == rest {
            continue;
        }
        let v = ds.vertices(r).unwrap();
        let v0 = ds.vertices(rest).unwrap();
        // The neck height of this identity (phenotype from the file).
        let p = &ds.phenotype[6 * r..6 * r + 6];
        let mut shape = ShapeParams::default();
        let ph = &mut shape.phenotype;
        (
            ph.gender,
            ph.age,
            ph.muscle,
            ph.weight,
            ph.height,
            ph.proportions,
        ) = (
            p[0] as f64,
            p[1] as f64,
            p[2] as f64,
            p[3] as f64,
            p[4] as f64,
            p[5] as f64,
        );
        let ident = f.generator.identity(&shape).unwrap();
        let neck_z = ident.bone_heads()[neck][2] as f32;
        let rest_mesh = f.map.to_small(ident.rest_vertices());
        // The stored rest row is this identity's rest mesh (f32 phenotype: ~1e-6 m).
        assert!(
            max_disp(
                &v0,
                &rest_mesh
                    .iter()
                    .map(|p| p.map(|x| x as f32))
                    .collect::<Vec<_>>(),
                |_| true
            ) < 1e-4
        );
        let below_neck = |i: usize| v0[i][2] < neck_z - 0.08;
        let all = max_disp(&v, &v0, |_| true);
        match ds.kind[r] {
            KIND_BODY => {
                assert!(all > 0.02, "body row {r} moves only {all} m");
                n_body += 1;
            }
            KIND_FACE => {
                // Face units reach about 2 cm below the neck01 joint (jawOpen: 0.1 mm there)
                // and the jaw bone's LBS weights the front of the throat (0.3-0.5 mm at the
                // base of the neck for a 6-13° jaw); 8 cm below the neck01 joint nothing moves.
                let body = max_disp(&v, &v0, below_neck);
                assert!(body < 1e-6, "expression row {r} moves the body by {body} m");
                worst_face_body = worst_face_body.max(body);
                assert!(all > 1e-4, "expression row {r} moves nothing ({all} m)");
                n_face += 1;
            }
            KIND_HAND => {
                let body = max_disp(&v, &v0, |i| {
                    v0[i][2] > neck_z - 0.5 && v0[i][0].abs() < 0.12
                });
                assert!(body < 1e-6, "hand row {r} moves the trunk by {body} m");
                assert!(all > 0.005, "hand row {r} moves only {all} m");
                n_hand += 1;
            }
            _ => unreachable!(),
        }
    }
    assert_eq!((n_body, n_face, n_hand), (40, 40, 40));
    eprintln!("expression rows: largest displacement below the neck {worst_face_body:e} m");
}

#[test]
fn preview_and_full_topology() {
    let dir = tmpdir("preview");
    let png = dir.join("sheet.png");
    let data = dir.join("data");
    synth(
        &data,
        "2",
        &[
            "--topology",
            "full",
            "--identities",
            "3",
            "--body",
            "6",
            "--face",
            "6",
            "--hand",
            "6",
            "--preview",
            png.to_str().unwrap(),
        ],
    );
    let ds = Dataset::open(&data).unwrap();
    assert_eq!((ds.n_rows, ds.n_vertices), (21, 13348));
    assert_eq!(ds.meta["topology"]["name"], "full");
    let img = std::fs::read(&png).unwrap();
    assert_eq!(&img[..8], b"\x89PNG\r\n\x1a\n");
    assert!(img.len() > 50_000, "preview is only {} bytes", img.len());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_arguments_fail_with_one_line() {
    let dir = tmpdir("bad");
    for (args, want) in [
        (vec!["--preset", "huge"], "unknown preset `huge`"),
        (vec!["--topology", "anny"], "not `anny`"),
        (vec!["--identities", "0"], "at least one identity"),
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_panoman"))
            .args(["synth", "--out"])
            .arg(dir.join("x"))
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    }
    // A truncated tensor file is refused by the reader.
    let data = dir.join("t");
    synth(
        &data,
        "2",
        &[
            "--identities",
            "2",
            "--body",
            "2",
            "--face",
            "2",
            "--hand",
            "2",
        ],
    );
    let path = data.join("dataset.safetensors");
    let mut b = std::fs::read(&path).unwrap();
    b.truncate(b.len() - 1);
    std::fs::write(&path, &b).unwrap();
    let e = Dataset::open(&data).unwrap_err().to_string();
    assert!(e.contains("dataset.safetensors"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
