//! Linear capacity of RL/RA: the best any K-dimensional linear basis can do. Dense PCA of the
//! RL and RA of `N_TRAIN` training rows of one kind (on the edges of the given parts), then
//! each of 10 held-out rows is projected on the first K components (truth kept on the other
//! edges), rebuilt with `g` and compared (each part rigidly aligned on itself; the whole mesh
//! for the body). A sparse decomposition with K components cannot beat these figures.
//!
//! `cargo run --release -p panoman-model --example linear_capacity -- M.safetensors DATA N_TRAIN [KIND=1] [PARTS=0]`
//! (kind 1 body poses / 2 expressions / 3 gestures; parts 0 body, 1 face, 2,3 hands).
use faer::Mat;
use panoman_human::dataset::Dataset;
use panoman_mesh::{
    RestGeometry, Rla,
    align::rigid_align,
    geom::{norm, sub},
};
use panoman_model::model::{Evaluator, PanoManModel};
type V3 = [f64; 3];
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let model = PanoManModel::load(a[1].as_ref()).unwrap();
    let ds = Dataset::open(a[2].as_ref()).unwrap();
    let ntrain: usize = a[3].parse().unwrap();
    let kind: u8 = a.get(4).map_or(1, |s| s.parse().unwrap());
    let mut ev = Evaluator::new(std::sync::Arc::new(model.clone())).unwrap();
    let topo = ev.topology().clone();
    let parts: Vec<u8> = a.get(5).map_or(vec![0], |s| {
        s.split(',').map(|x| x.parse().unwrap()).collect()
    });
    let body: Vec<usize> = (0..topo.n_edges())
        .filter(|&e| parts.contains(&model.edge_part[e]))
        .collect();
    let nv = model.n_vertices;
    let mut vpart = vec![0u8; nv];
    for (e, &[i, j]) in topo.edges.iter().enumerate() {
        for v in [i, j] {
            vpart[v as usize] = vpart[v as usize].max(model.edge_part[e]);
        }
    }
    let groups: Vec<Vec<usize>> = if parts == [0] {
        vec![(0..nv).collect()]
    } else {
        parts
            .iter()
            .map(|&p| (0..nv).filter(|&v| vpart[v] == p).collect())
            .collect()
    };
    let held: std::collections::BTreeSet<u32> = ds.held_out.iter().copied().collect();
    let to_v3 = |x: Vec<[f32; 3]>| {
        x.iter()
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64])
            .collect::<Vec<V3>>()
    };
    let rla_of = |r: usize| {
        let mesh = to_v3(ds.vertices(r).unwrap());
        let rest = to_v3(ds.vertices(ds.rest_of[r] as usize).unwrap());
        let rg = RestGeometry::new(&topo, &rest).unwrap();
        (Rla::compute(&topo, &rg, &mesh).unwrap(), mesh, rest)
    };
    let tr: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == kind && !held.contains(&ds.identity[r]))
        .collect();
    let tr: Vec<usize> = (0..ntrain.min(tr.len()))
        .map(|i| tr[i * tr.len() / ntrain.min(tr.len())])
        .collect();
    let n = tr.len();
    let eb = body.len();
    let mut x = Mat::<f64>::zeros(n, 2 * eb);
    for (i, &r) in tr.iter().enumerate() {
        let (rla, _, _) = rla_of(r);
        for (c, &e) in body.iter().enumerate() {
            x[(i, c)] = rla.rl[e];
            x[(i, eb + c)] = rla.ra[e];
        }
    }
    let mean: Vec<f64> = (0..2 * eb)
        .map(|j| (0..n).map(|i| x[(i, j)]).sum::<f64>() / n as f64)
        .collect();
    for j in 0..2 * eb {
        for i in 0..n {
            x[(i, j)] -= mean[j];
        }
    }
    // separate PCA for RL and RA, like the model blocks
    let t = std::time::Instant::now();
    let xl = Mat::<f64>::from_fn(n, eb, |i, j| x[(i, j)]);
    let xa = Mat::<f64>::from_fn(n, eb, |i, j| x[(i, eb + j)]);
    let vl = xl.thin_svd().unwrap().V().to_owned();
    let va = xa.thin_svd().unwrap().V().to_owned();
    println!("svd {:.1}s, n={n}, eb={eb}", t.elapsed().as_secs_f64());
    let ho: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == kind && held.contains(&ds.identity[r]))
        .collect();
    let ho: Vec<usize> = (0..10).map(|i| ho[i * ho.len() / 10]).collect();
    for k in [10usize, 25, 50, 100, 250, 500, 1000] {
        if k > n {
            continue;
        }
        let mut tot = 0.0;
        let mut ral = 0.0;
        for &r in &ho {
            let (truth, mesh, rest) = rla_of(r);
            let mut mix = truth.clone();
            for (q, v) in [(0usize, &vl), (1, &va)] {
                let y: Vec<f64> = body
                    .iter()
                    .enumerate()
                    .map(
                        |(c, &e)| if q == 0 { truth.rl[e] } else { truth.ra[e] } - mean[q * eb + c],
                    )
                    .collect();
                let mut rec = vec![0.0; eb];
                for j in 0..k {
                    let cj = v.col(j);
                    let d: f64 = (0..eb).map(|i| cj[i] * y[i]).sum();
                    for i in 0..eb {
                        rec[i] += d * cj[i];
                    }
                }
                for (c, &e) in body.iter().enumerate() {
                    let val = rec[c] + mean[q * eb + c];
                    if q == 0 {
                        mix.rl[e] = val
                    } else {
                        ral += (mix.ra[e] - val).powi(2);
                        mix.ra[e] = val
                    }
                }
            }
            let out = ev.reconstruct(&rest, &mix).unwrap();
            for g in &groups {
                let mut w = vec![0.0; nv];
                for &v in g {
                    w[v] = 1.0;
                }
                let m = rigid_align(&out, &mesh, Some(&w));
                tot += g
                    .iter()
                    .map(|&v| norm(sub(m.apply(out[v]), mesh[v])))
                    .sum::<f64>()
                    / g.len() as f64
                    / groups.len() as f64;
            }
            let _ = ral;
        }
        println!(
            "K={k}: mesh err {:.2} mm, RA rms {:.4}",
            tot / ho.len() as f64 * 1e3,
            (ral / (ho.len() * eb) as f64).sqrt()
        );
    }
}
