//! Edge geodesics (docs/design/splocs-model.md §3.3): accuracy against exact distances on a sphere and a
//! plane, symmetry, radius truncation, triangle inequality, workspace reuse, part subsets.

use panoman_mesh::shapes::icosphere;

use panoman_mesh::Topology;
use panoman_model::geodesic::{EdgeGeodesics, PartGeodesics, Propagation};
use panoman_model::splocs::ColumnDistances;

type V3 = [f64; 3];

fn normalize(p: V3) -> V3 {
    let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / n, p[1] / n, p[2] / n]
}

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Flat n×n grid of the unit square at z = 0, every square split along the same diagonal.
fn plane(n: usize) -> (Vec<V3>, Vec<[u32; 3]>) {
    let mut v = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            v.push([i as f64 / n as f64, j as f64 / n as f64, 0.0]);
        }
    }
    let id = |i: usize, j: usize| (i * (n + 1) + j) as u32;
    let mut f = Vec::new();
    for i in 0..n {
        for j in 0..n {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, f)
}

fn midpoint(v: &[V3], e: [u32; 2]) -> V3 {
    let (a, b) = (v[e[0] as usize], v[e[1] as usize]);
    [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ]
}

fn setup(v: &[V3], f: &[[u32; 3]]) -> (Topology, EdgeGeodesics) {
    let topo = Topology::build(v.len(), f).unwrap();
    let geo = EdgeGeodesics::new(&topo, v).unwrap();
    (topo, geo)
}

/// (mean, max) relative error over edges with exact distance in [lo, hi].
fn errors(d: &[f64], exact: &[f64], lo: f64, hi: f64) -> (f64, f64, usize) {
    let (mut sum, mut max, mut cnt) = (0.0, 0.0f64, 0);
    for (&a, &b) in d.iter().zip(exact) {
        if b >= lo && b <= hi {
            let r = (a - b).abs() / b;
            sum += r;
            max = max.max(r);
            cnt += 1;
        }
    }
    (sum / cnt as f64, max, cnt)
}

/// Exact distance from the midpoint of `centre` to every edge midpoint.
fn exact_distances(v: &[V3], topo: &Topology, centre: usize, sphere: bool) -> Vec<f64> {
    let c = midpoint(v, topo.edges[centre]);
    topo.edges
        .iter()
        .map(|&e| {
            let p = midpoint(v, e);
            if sphere {
                dot(normalize(c), normalize(p)).clamp(-1.0, 1.0).acos()
            } else {
                ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
            }
        })
        .collect()
}

#[test]
fn sphere_distances_match_great_circles() {
    let (v, f) = icosphere(5);
    let topo = Topology::build(v.len(), &f).unwrap();
    let ne = topo.n_edges();
    let mut d = vec![0.0; ne];
    // (propagation, mean and max relative error beyond 10 edge lengths, beyond 40).
    for (prop, near, far) in [
        (Propagation::Dijkstra, (0.03, 0.10), (0.02, 0.05)),
        (Propagation::Unfolding, (0.01, 0.03), (0.01, 0.02)),
    ] {
        let geo = EdgeGeodesics::with_propagation(&topo, &v, prop).unwrap();
        let mut ws = geo.workspace();
        let h = (0..ne).map(|e| geo.edge_length(e)).sum::<f64>() / ne as f64;
        for &centre in &[0usize, 1234, 7777, 20000, ne - 1] {
            geo.edge_distances_from_edge(centre, f64::INFINITY, &mut ws, &mut d);
            assert_eq!(d[centre], 0.0);
            assert!(d.iter().all(|x| x.is_finite()));
            let exact = exact_distances(&v, &topo, centre, true);
            // Never much below the geodesic (chord lengths are slightly shorter than arcs).
            for (&a, &b) in d.iter().zip(&exact) {
                assert!(a >= 0.99 * b - 0.5 * h, "{a} < {b}");
            }
            let (mean, max, cnt) = errors(&d, &exact, 10.0 * h, 3.0);
            eprintln!("sphere {prop:?} centre {centre}: mean {mean:.4}, max {max:.4} over {cnt}");
            assert!(cnt > 10000);
            assert!(
                mean < near.0 && max < near.1,
                "{prop:?}: mean {mean}, max {max}"
            );
            let (mean, max, _) = errors(&d, &exact, 40.0 * h, 3.0);
            assert!(
                mean < far.0 && max < far.1,
                "{prop:?} far: mean {mean}, max {max}"
            );
            // Near the centre the error is about one edge length at most.
            for (&a, &b) in d.iter().zip(&exact) {
                if b < 10.0 * h {
                    assert!(
                        (a - b).abs() < 1.5 * h,
                        "near error {} at {b}",
                        (a - b).abs()
                    );
                }
            }
        }
    }
}

#[test]
fn plane_distances_match_euclidean() {
    let (v, f) = plane(80);
    let topo = Topology::build(v.len(), &f).unwrap();
    let ne = topo.n_edges();
    let h = 1.0 / 80.0;
    let pick = |target: V3| {
        (0..ne)
            .min_by(|&a, &b| {
                let (pa, pb) = (midpoint(&v, topo.edges[a]), midpoint(&v, topo.edges[b]));
                let da = (pa[0] - target[0]).powi(2) + (pa[1] - target[1]).powi(2);
                let db = (pb[0] - target[0]).powi(2) + (pb[1] - target[1]).powi(2);
                da.total_cmp(&db)
            })
            .unwrap()
    };
    // (links, bound on the mean, bound on the max relative error beyond 10 edge lengths):
    // plain Dijkstra on triangulated quads leaves a 45° gap between link directions.
    for (links, mean_bound, max_bound) in [
        (Propagation::Dijkstra, 0.06, 0.125),
        (Propagation::Unfolding, 0.01, 0.06),
    ] {
        let geo = EdgeGeodesics::with_propagation(&topo, &v, links).unwrap();
        let mut ws = geo.workspace();
        let mut d = vec![0.0; ne];
        for centre in [pick([0.5, 0.5, 0.0]), pick([0.1, 0.2, 0.0])] {
            geo.edge_distances_from_edge(centre, f64::INFINITY, &mut ws, &mut d);
            let exact = exact_distances(&v, &topo, centre, false);
            for (&a, &b) in d.iter().zip(&exact) {
                assert!(a >= b - 0.5 * h - 1e-12, "{a} < {b}");
            }
            let (mean, max, cnt) = errors(&d, &exact, 10.0 * h, 2.0);
            eprintln!("plane {links:?} centre {centre}: mean {mean:.4}, max {max:.4} over {cnt}");
            assert!(mean < mean_bound, "{links:?}: mean relative error {mean}");
            assert!(max < max_bound, "{links:?}: max relative error {max}");
        }
    }
}

#[test]
fn diagonals_reduce_metrication_error_and_graph_is_consistent() {
    let (v, f) = icosphere(3);
    let (topo, geo) = setup(&v, &f);
    // Every edge plus one diagonal per interior edge (none coincide on an icosphere).
    assert_eq!(geo.n_links(), 2 * 2 * topo.n_edges());
    assert_eq!(geo.n_vertices(), v.len());
    assert_eq!(geo.n_edges(), topo.n_edges());
}

#[test]
fn distances_are_nearly_symmetric() {
    let (v, f) = icosphere(4);
    let (topo, geo) = setup(&v, &f);
    let ne = topo.n_edges();
    let mut ws = geo.workspace();
    let ids: Vec<usize> = (0..12).map(|i| (i * 977 + 13) % ne).collect();
    let rows: Vec<Vec<f64>> = ids
        .iter()
        .map(|&e| {
            let mut d = vec![0.0; ne];
            geo.edge_distances_from_edge(e, f64::INFINITY, &mut ws, &mut d);
            d
        })
        .collect();
    let mut worst = 0.0f64;
    for (a, &ea) in ids.iter().enumerate() {
        for (b, &eb) in ids.iter().enumerate() {
            if a == b {
                continue;
            }
            let (x, y) = (rows[a][eb], rows[b][ea]);
            worst = worst.max((x - y).abs() / x.max(y));
        }
    }
    eprintln!("worst asymmetry {worst:.4}");
    assert!(worst < 0.01, "asymmetry {worst}");
}

#[test]
fn truncation_is_exact_and_triangle_inequality_holds() {
    let (v, f) = icosphere(4);
    let topo = Topology::build(v.len(), &f).unwrap();
    let ne = topo.n_edges();
    for prop in [Propagation::Dijkstra, Propagation::Unfolding] {
        let geo = EdgeGeodesics::with_propagation(&topo, &v, prop).unwrap();
        let mut ws = geo.workspace();
        let centre = 4321;
        let mut full = vec![0.0; ne];
        geo.edge_distances_from_edge(centre, f64::INFINITY, &mut ws, &mut full);
        // |d(a) − d(b)| ≤ ℓ_ab: distances grow continuously away from the centre.
        let dv = geo
            .vertex_distances_from_edge(centre, f64::INFINITY, &mut ws)
            .to_vec();
        for (e, &[a, b]) in topo.edges.iter().enumerate() {
            let diff = (dv[a as usize] - dv[b as usize]).abs();
            assert!(diff <= geo.edge_length(e) * (1.0 + 1e-12));
        }
        let mut prev_count = 0;
        for &r in &[0.05, 0.2, 0.5, 1.0, 4.0] {
            let mut t = vec![0.0; ne];
            geo.edge_distances_from_edge(centre, r, &mut ws, &mut t);
            let mut count = 0;
            for e in 0..ne {
                if full[e] <= r {
                    assert_eq!(
                        t[e].to_bits(),
                        full[e].to_bits(),
                        "{prop:?}: edge {e}, r = {r}"
                    );
                    count += 1;
                } else {
                    assert!(
                        t[e].is_infinite(),
                        "{prop:?}: edge {e} beyond r = {r} must be +inf"
                    );
                }
            }
            assert!(count >= prev_count);
            prev_count = count;
        }
        assert_eq!(prev_count, ne);
    }
}

#[test]
fn query_cost_is_small() {
    let (v, f) = icosphere(5); // 10,242 vertices, 30,720 edges (about the body mesh)
    let (topo, geo) = setup(&v, &f);
    let mut ws = geo.workspace();
    let mut d = vec![0.0; topo.n_edges()];
    geo.edge_distances_from_edge(0, f64::INFINITY, &mut ws, &mut d);
    let t = std::time::Instant::now();
    for c in 0..20 {
        geo.edge_distances_from_edge(c * 1000, f64::INFINITY, &mut ws, &mut d);
    }
    let full = t.elapsed().as_secs_f64() / 20.0;
    let t = std::time::Instant::now();
    for c in 0..20 {
        geo.edge_distances_from_edge(c * 1000, 0.2, &mut ws, &mut d);
    }
    let local = t.elapsed().as_secs_f64() / 20.0;
    eprintln!(
        "query: whole mesh {:.2} ms, radius 0.2 {:.2} ms",
        full * 1e3,
        local * 1e3
    );
    assert!(full < 0.1, "a whole-mesh query took {full} s");
}

#[test]
fn workspace_reuse_and_part_subsets() {
    let (v, f) = icosphere(3);
    let (topo, geo) = setup(&v, &f);
    let ne = topo.n_edges();
    let mut ws = geo.workspace();
    let mut a1 = vec![0.0; ne];
    let mut b = vec![0.0; ne];
    let mut a2 = vec![0.0; ne];
    geo.edge_distances_from_edge(10, 0.7, &mut ws, &mut a1);
    geo.edge_distances_from_edge(900, f64::INFINITY, &mut ws, &mut b);
    geo.edge_distances_from_edge(10, 0.7, &mut ws, &mut a2);
    assert!(a1.iter().zip(&a2).all(|(x, y)| x.to_bits() == y.to_bits()));
    let mut fresh = geo.workspace();
    geo.edge_distances_from_edge(10, 0.7, &mut fresh, &mut a2);
    assert!(a1.iter().zip(&a2).all(|(x, y)| x.to_bits() == y.to_bits()));

    // A part made of every third edge: column j is edge 3j.
    let cols: Vec<u32> = (0..ne as u32).step_by(3).collect();
    let part = PartGeodesics::new(&geo, cols.clone()).unwrap();
    assert_eq!(part.n_columns(), cols.len());
    let mut pw = part.new_workspace();
    let mut out = vec![0.0; cols.len()];
    part.distances_from(7, 0.9, &mut pw, &mut out);
    let mut full = vec![0.0; ne];
    geo.edge_distances_from_edge(cols[7] as usize, 0.9, &mut ws, &mut full);
    for (j, &e) in cols.iter().enumerate() {
        assert_eq!(out[j].to_bits(), full[e as usize].to_bits());
    }
    assert_eq!(out[7], 0.0);
    assert!(PartGeodesics::new(&geo, vec![ne as u32]).is_err());
}

#[test]
fn open_mesh_and_bad_input() {
    let (v, f) = plane(6);
    let (topo, geo) = setup(&v, &f);
    assert!(topo.n_boundary_edges() > 0);
    let mut ws = geo.workspace();
    let mut d = vec![0.0; topo.n_edges()];
    geo.edge_distances_from_edge(0, f64::INFINITY, &mut ws, &mut d);
    assert!(d.iter().all(|x| x.is_finite() && *x >= 0.0));
    assert!(EdgeGeodesics::new(&topo, &v[1..]).is_err());
    let mut bad = v.clone();
    bad[3][1] = f64::NAN;
    assert!(EdgeGeodesics::new(&topo, &bad).is_err());
}
