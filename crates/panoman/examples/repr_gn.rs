//! Held-out representation error of the vertex-error encoder (`Evaluator::refine_beta`) with
//! chosen options, per row: least-squares and refined mean / max error (mm), iterations, g
//! solves, seconds (docs/design/splocs-model.md §8). Rows and regions as the training report's.
//!
//! `KIND=1 ROWS=40 CORR=0 GN_IT=10 GN_CG=25 GN_TOL=0.001 GN_MU=0.0001 GN_REJ=4 \
//!  cargo run --release -p panoman --example repr_gn -- M.safetensors H`
//!
//! KIND 1 body, 2 face, 3 hands; unset options take `GnOptions::default()` (`GN_TWO=0`: one start); `PART=k/n` takes every n-th row from the k-th. `SHOW_MM=60` lists
//! the worst vertices of rows whose max is above 60 mm, `DUMP=dir` also writes their truth and
//! model vertices (`ROW_truth.xyz`, `ROW_model.xyz`, OBJ vertex lines).
use panoman_human::assets::{AssetDir, default_dir};
use panoman_human::regions::Part;
use panoman_mesh::align::rigid_align;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_model::model::{Evaluator, GnOptions, PanoManModel};
use std::sync::Arc;

fn env<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

fn errs(a: &[V3], b: &[V3], groups: &[Vec<u32>]) -> (f64, f64) {
    let (mut s, mut n, mut m) = (0.0, 0usize, 0.0f64);
    for g in groups {
        let mut w = vec![0.0; a.len()];
        for &v in g {
            w[v as usize] = 1.0;
        }
        let t = rigid_align(a, b, Some(&w));
        for &v in g {
            let d = norm(sub(t.apply(a[v as usize]), b[v as usize]));
            s += d;
            n += 1;
            m = m.max(d);
        }
    }
    (1e3 * s / n as f64, 1e3 * m)
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let assets = AssetDir::open(&default_dir()).unwrap();
    let (ds, regions) = panoman::training::dataset_and_regions(&assets, a[2].as_ref()).unwrap();
    let model = Arc::new(PanoManModel::load(a[1].as_ref()).unwrap());
    let mut ev = Evaluator::new(model.clone()).unwrap();
    let kind: u8 = env("KIND", 1);
    let rows_n: usize = env("ROWS", 40);
    let corr = env("CORR", 0u8) == 1;
    let d = GnOptions::default();
    let opts = GnOptions {
        max_iterations: env("GN_IT", d.max_iterations),
        cg_iterations: env("GN_CG", d.cg_iterations),
        tolerance: env("GN_TOL", d.tolerance),
        damping: env("GN_MU", d.damping),
        max_rejections: env("GN_REJ", d.max_rejections),
        correction_jacobian: env("GN_CJ", 0u8) == 1,
        correction_two_start: env("GN_TWO", 1u8) == 1,
    };
    let groups: Vec<Vec<u32>> = match kind {
        2 => vec![regions.vertices_of(Part::Face)],
        3 => vec![
            regions.vertices_of(Part::LeftHand),
            regions.vertices_of(Part::RightHand),
        ],
        _ => vec![(0..regions.n_vertices() as u32).collect()],
    };
    let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
    let all: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == kind && held.contains(&ds.identity[r]))
        .collect();
    let rows: Vec<usize> = if all.len() <= rows_n {
        all
    } else {
        (0..rows_n).map(|i| all[i * all.len() / rows_n]).collect()
    };
    // PART=k/n: every n-th of those rows from the k-th (to split a run over processes).
    let (k, n): (usize, usize) = std::env::var("PART")
        .ok()
        .and_then(|v| {
            let (a, b) = v.split_once('/')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .unwrap_or((0, 1));
    let rows: Vec<usize> = rows.into_iter().skip(k).step_by(n.max(1)).collect();
    let v3 = |r: usize| -> Vec<V3> {
        ds.vertices(r)
            .unwrap()
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect()
    };
    let (mut sm, mut mx, mut sm_ls) = (0.0, 0.0f64, 0.0);
    let t0 = std::time::Instant::now();
    for &r in &rows {
        let mesh = v3(r);
        let rest = v3(ds.rest_of[r] as usize);
        let mut p = ev.encode(&mesh, Some(&rest), corr).unwrap();
        let ls = errs(&ev.pose(&p, corr).unwrap(), &mesh, &groups);
        let t = std::time::Instant::now();
        let rep = ev.refine_beta(&mesh, &mut p, corr, &opts).unwrap();
        let gn = errs(&ev.pose(&p, corr).unwrap(), &mesh, &groups);
        println!(
            "row {r}: ls {:.2}/{:.1} gn {:.2}/{:.1} mm, {} it, {} g, {:.2} s",
            ls.0,
            ls.1,
            gn.0,
            gn.1,
            rep.iterations,
            rep.g_solves,
            t.elapsed().as_secs_f64()
        );
        if gn.1 > env("SHOW_MM", 1e9) {
            let posed = ev.pose(&p, corr).unwrap();
            let t = rigid_align(&posed, &mesh, None);
            let mut e: Vec<(f64, usize)> = (0..mesh.len())
                .map(|v| (norm(sub(t.apply(posed[v]), mesh[v])), v))
                .collect();
            e.sort_by(|a, b| b.0.total_cmp(&a.0));
            let lh = regions.vertices_of(Part::LeftHand);
            let rh = regions.vertices_of(Part::RightHand);
            let fc = regions.vertices_of(Part::Face);
            let part = |v: usize| {
                let v = v as u32;
                if lh.contains(&v) {
                    "lhand"
                } else if rh.contains(&v) {
                    "rhand"
                } else if fc.contains(&v) {
                    "face"
                } else {
                    "body"
                }
            };
            let over = |mm: f64| e.iter().filter(|x| x.0 > mm * 1e-3).count();
            println!(
                "  >20mm {} >40mm {} >60mm {}",
                over(20.0),
                over(40.0),
                over(60.0)
            );
            for &(d, v) in e.iter().take(5) {
                println!("  v{v} {:.1} mm {} at {:?}", 1e3 * d, part(v), mesh[v]);
            }
            if let Ok(dir) = std::env::var("DUMP") {
                let w = |name: &str, x: &[V3]| {
                    let s: String = x
                        .iter()
                        .map(|p| format!("v {} {} {}\n", p[0], p[1], p[2]))
                        .collect();
                    std::fs::write(format!("{dir}/{r}_{name}.xyz"), s).unwrap();
                };
                let al: Vec<V3> = posed.iter().map(|&q| t.apply(q)).collect();
                w("truth", &mesh);
                w("model", &al);
            }
        }
        sm += gn.0;
        sm_ls += ls.0;
        mx = mx.max(gn.1);
    }
    let n = rows.len() as f64;
    println!(
        "kind {kind} corr {corr} {opts:?}: ls mean {:.3}, gn mean {:.3} max {:.1} mm over {} rows, {:.1} s",
        sm_ls / n,
        sm / n,
        mx,
        rows.len(),
        t0.elapsed().as_secs_f64()
    );
}
