//! Timing and memory of the sparse localized decomposition at realistic sizes, on synthetic
//! data (planted localized signed components + noise on a torus mesh).
//!
//! `cargo run --release -p panoman-model --example splocs_bench -- N M K ITERS SCALE`
//! SCALE: "body" (major radius 0.5 m, d_min ∈ [0.04, 0.30]) or "small" (0.08 m, [0.005, 0.05]).

use std::time::Instant;

use panoman_mesh::Topology;
use panoman_model::geodesic::{EdgeGeodesics, PartGeodesics};
use panoman_model::splocs::{self, SplocsOptions};

struct Rng(u64);
impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn torus(a: usize, b: usize, big: f64, small: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
    let mut v = Vec::new();
    for i in 0..a {
        for j in 0..b {
            let (u, w) = (
                2.0 * std::f64::consts::PI * i as f64 / a as f64,
                2.0 * std::f64::consts::PI * j as f64 / b as f64,
            );
            let r = big + small * w.cos();
            v.push([r * u.cos(), r * u.sin(), small * w.sin()]);
        }
    }
    let id = |i: usize, j: usize| ((i % a) * b + (j % b)) as u32;
    let mut f = Vec::new();
    for i in 0..a {
        for j in 0..b {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, f)
}

fn peak_rss_mb() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    for l in s.lines() {
        if let Some(r) = l.strip_prefix("VmHWM:") {
            let kb: f64 = r
                .trim()
                .trim_end_matches("kB")
                .trim()
                .parse()
                .unwrap_or(0.0);
            return kb / 1024.0;
        }
    }
    0.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map_or(2000, |s| s.parse().unwrap());
    let m_target: usize = args.get(2).map_or(40000, |s| s.parse().unwrap());
    let k: usize = args.get(3).map_or(250, |s| s.parse().unwrap());
    let iters: usize = args.get(4).map_or(5, |s| s.parse().unwrap());
    let body = args.get(5).is_none_or(|s| s == "body");
    let (big, small, bounds) = if body {
        (0.5, 0.15, [0.04, 0.30])
    } else {
        (0.08, 0.025, [0.005, 0.05])
    };
    // Torus a×b has 3ab edges; aspect ≈ big/small.
    let ab = m_target / 3;
    let b = ((ab as f64) * small / big).sqrt().round().max(3.0) as usize;
    let a = ab / b;
    let (v, f) = torus(a, b, big, small);
    let topo = Topology::build(v.len(), &f).unwrap();
    let geo = EdgeGeodesics::new(&topo, &v).unwrap();
    let m = topo.n_edges();
    eprintln!(
        "torus {a}×{b}: {} vertices, {m} edges; N {n}, K {k}",
        v.len()
    );

    // Planted components: K bumps with signed profiles at random centres.
    let t = Instant::now();
    let mut rng = Rng(1);
    let mut ws = geo.workspace();
    let mut d = vec![0.0; m];
    let mut col_entries: Vec<Vec<(u32, f32)>> = vec![Vec::new(); m];
    for j in 0..k {
        let centre = (rng.next_u64() % m as u64) as usize;
        let radius = bounds[0] + (bounds[1] - bounds[0]) * 0.6 * rng.uniform();
        geo.edge_distances_from_edge(centre, radius, &mut ws, &mut d);
        let amp = if rng.uniform() < 0.5 { -1.0 } else { 1.0 } * (0.5 + rng.uniform());
        for e in 0..m {
            let t = d[e] / radius;
            if t < 1.0 {
                let val = amp * (1.0 - t * t).powi(2) * (1.0 - 2.5 * t * t);
                col_entries[e].push((j as u32, val as f32));
            }
        }
    }
    let wt: Vec<f32> = (0..n * k)
        .map(|_| (2.0 * rng.uniform() - 1.0) as f32)
        .collect();
    let mut x = vec![0.0f32; n * m];
    for e in 0..m {
        let col = &mut x[e * n..(e + 1) * n];
        for (i, xv) in col.iter_mut().enumerate() {
            let mut s = 0.1 * (2.0 * rng.uniform() - 1.0) as f32;
            for &(j, c) in &col_entries[e] {
                s += wt[i * k + j as usize] * c;
            }
            *xv = s;
        }
    }
    drop(col_entries);
    eprintln!(
        "data: {:.1} s, {:.0} MB",
        t.elapsed().as_secs_f64(),
        (n * m * 4) as f64 / 1e6
    );

    let cols: Vec<u32> = (0..m as u32).collect();
    let part = PartGeodesics::new(&geo, cols).unwrap();
    let mut opts = SplocsOptions::new(k, bounds);
    opts.max_outer_iters = iters;
    opts.monotone_weights = std::env::var("PM_PLAIN").is_err();
    let t = Instant::now();
    let dec = splocs::fit_col_major(x, n, &part, &opts, |r| {
        eprintln!(
            "  it {:2}: {:.2} s, obj {:.6e}, rel {:.2e}, safeguards {}, rejected {}, supports {}, reseeded {}",
            r.iteration,
            r.seconds,
            r.objective,
            r.relative_decrease,
            r.weight_safeguards,
            r.admm_rejected,
            r.support_changes,
            r.reseeded
        )
    })
    .unwrap();
    let total = t.elapsed().as_secs_f64();
    let per_it: Vec<f64> = dec.history.iter().map(|r| r.seconds).collect();
    let mean_it = per_it.iter().sum::<f64>() / per_it.len().max(1) as f64;
    println!(
        "N {n} M {m} K {k}: init {:.1} s, {} iterations at {:.2} s mean, total {:.1} s, explained {:.4}, nnz {} ({:.1}% dense), peak RSS {:.0} MB",
        dec.init_seconds,
        per_it.len(),
        mean_it,
        total,
        dec.explained_variance,
        dec.components.nnz(),
        100.0 * dec.components.nnz() as f64 / (k * m) as f64,
        peak_rss_mb()
    );
    let t = Instant::now();
    let enc = dec.encoder(0.0).unwrap();
    let t_factor = t.elapsed().as_secs_f64();
    let sample: Vec<f32> = dec.mean.clone();
    let t = Instant::now();
    let _ = enc.encode(&sample).unwrap();
    println!(
        "encoder: factor {:.1} ms, encode {:.2} ms",
        t_factor * 1e3,
        t.elapsed().as_secs_f64() * 1e3
    );
}
