#![allow(clippy::needless_range_loop)]
//! Tests of the topology tables, RLA, hinge gradients, rotations and the reconstruction g.

mod common;
use common::{Rng, deform, grid, icosphere};
use panoman_mesh::align::{Rigid, aligned_error, nearest_rotation, rigid_align};
use panoman_mesh::geom::{IDENTITY, M3, V3, det, matmul, matvec, sub, transpose};
use panoman_mesh::recon::{connection_map, triangle_frame};
use panoman_mesh::rla::{
    dihedral_angle, dihedral_angles, dihedral_gradient, edge_lengths, length_gradient, wrap_angle,
};
use panoman_mesh::rotation::axis_angle;
use panoman_mesh::{Gauge, MeshError, Reconstructor, RestGeometry, Rla, Topology};
use std::f64::consts::PI;

fn bbox_diag(p: &[V3]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for x in p {
        for c in 0..3 {
            lo[c] = lo[c].min(x[c]);
            hi[c] = hi[c].max(x[c]);
        }
    }
    panoman_mesh::geom::norm(sub(hi, lo))
}

// ---------------------------------------------------------------- topology

#[test]
fn topology_tables_of_a_closed_sphere() {
    let (v, f) = icosphere(3);
    let t = Topology::build(v.len(), &f).unwrap();
    assert_eq!(t.euler_characteristic(), 2);
    assert!(t.is_closed());
    assert_eq!(t.genus(), Some(0));
    assert_eq!(t.n_vertex_components, 1);
    assert_eq!(t.n_face_components, 1);
    assert_eq!(t.n_edges() * 2, t.n_faces() * 3);
    for e in 0..t.n_edges() {
        let [i, j] = t.edges[e];
        assert!(i < j, "interior edges are stored with i < j");
        let [fl, fr] = t.edge_faces[e];
        let [k, l] = t.edge_opposite[e];
        let has = |face: u32, a: u32, b: u32| {
            let tri = t.faces[face as usize];
            (0..3).any(|s| tri[s] == a && tri[(s + 1) % 3] == b)
        };
        assert!(has(fl, i, j) && has(fr, j, i));
        assert!(t.faces[fl as usize].contains(&k) && k != i && k != j);
        assert!(t.faces[fr as usize].contains(&l) && l != i && l != j);
        // face_edges agree with edges.
        for face in [fl, fr] {
            let s = t.face_edges[face as usize]
                .iter()
                .position(|&x| x as usize == e)
                .unwrap();
            let tri = t.faces[face as usize];
            let (a, b) = (tri[s], tri[(s + 1) % 3]);
            assert_eq!((a.min(b), a.max(b)), (i, j));
        }
    }
    // The dual graph of a closed triangle mesh is 3-regular.
    assert!((0..t.n_faces()).all(|f| t.dual_neighbors_of(f).len() == 3));
    assert_eq!(t.hash_hex().len(), 16);
}

#[test]
fn topology_of_an_open_grid_has_one_boundary_loop() {
    let (v, f) = grid(6);
    let t = Topology::build(v.len(), &f).unwrap();
    assert!(!t.is_closed());
    assert_eq!(t.boundary_loops.len(), 1);
    assert_eq!(t.boundary_loops[0].len(), 24);
    assert_eq!(t.n_boundary_edges(), 24);
    assert_eq!(t.genus(), Some(0));
    for e in 0..t.n_edges() {
        if !t.is_interior(e) {
            let [i, j] = t.edges[e];
            let tri = t.faces[t.edge_faces[e][0] as usize];
            assert!((0..3).any(|s| tri[s] == i && tri[(s + 1) % 3] == j));
        }
    }
}

#[test]
fn topology_rejects_invalid_meshes() {
    let (v, f) = icosphere(1);
    let msg = |r: Result<Topology, MeshError>| r.unwrap_err().to_string();
    // Inconsistent orientation: flip one face.
    let mut g = f.clone();
    g[3].swap(1, 2);
    assert!(msg(Topology::build(v.len(), &g)).contains("inconsistently oriented"));
    // Non-manifold edge: a third face on an existing edge.
    let mut g = f.clone();
    let [a, b, _] = f[0];
    g.push([b, a, 7]);
    let m = msg(Topology::build(v.len(), &g));
    assert!(
        m.contains("non-manifold edge") || m.contains("inconsistently"),
        "{m}"
    );
    let mut g = f.clone();
    g.push([a, b, 7]);
    g.push([b, a, 9]);
    assert!(msg(Topology::build(v.len(), &g)).contains("non-manifold edge"));
    // Degenerate and out-of-range faces.
    let mut g = f.clone();
    g[0] = [1, 1, 2];
    assert!(msg(Topology::build(v.len(), &g)).contains("degenerate"));
    let mut g = f.clone();
    g[0][2] = 9999;
    assert!(msg(Topology::build(v.len(), &g)).contains("9999"));
    // Unused vertex.
    assert!(msg(Topology::build(v.len() + 1, &f)).contains("not used"));
    // Non-manifold vertex: two tetrahedra sharing one vertex.
    let tet = |o: u32| {
        vec![
            [o, o + 2, o + 1],
            [o, o + 1, o + 3],
            [o + 1, o + 2, o + 3],
            [o, o + 3, o + 2],
        ]
    };
    let mut g = tet(0);
    for t in tet(3) {
        g.push(t);
    }
    assert!(msg(Topology::build(7, &g)).contains("non-manifold vertex"));
    // Empty.
    assert!(msg(Topology::build(0, &[])).contains("no faces"));
}

#[test]
fn two_components_are_counted() {
    let (v, f) = icosphere(1);
    let n = v.len() as u32;
    let mut faces = f.clone();
    faces.extend(f.iter().map(|t| [t[0] + n, t[1] + n, t[2] + n]));
    let t = Topology::build(2 * v.len(), &faces).unwrap();
    assert_eq!(t.n_vertex_components, 2);
    assert_eq!(t.n_face_components, 2);
    assert_eq!(t.genus(), None);
    assert_eq!(t.euler_characteristic(), 4);
}

// ---------------------------------------------------------------- dihedral angles

#[test]
fn dihedral_angle_properties() {
    let (xi, xj) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
    let xk = [0.3, 1.0, 0.0];
    // Flat diamond.
    assert!(dihedral_angle(xi, xj, xk, [0.6, -0.8, 0.0]).abs() < 1e-15);
    // Folds by known angles, both signs, up to near ±π.
    for &phi in &[-3.0, -2.5, -1.0, -0.2, 0.2, 1.0, 2.0, 3.0] {
        let (s, c) = f64::sin_cos(phi);
        let xl = [0.6, -0.8 * c, -0.8 * s];
        assert!(
            (dihedral_angle(xi, xj, xk, xl) - phi).abs() < 1e-13,
            "phi {phi}"
        );
    }
    // Convex sphere edges are positive; orientation reversal flips the sign.
    let (v, f) = icosphere(2);
    let t = Topology::build(v.len(), &f).unwrap();
    let phi = dihedral_angles(&t, &v);
    assert!(phi.iter().all(|&p| p > 0.05 && p < 0.5));
    let flipped: Vec<[u32; 3]> = f.iter().map(|&[a, b, c]| [a, c, b]).collect();
    let tf = Topology::build(v.len(), &flipped).unwrap();
    let phif = dihedral_angles(&tf, &v);
    let sum: f64 = phi.iter().sum();
    let sumf: f64 = phif.iter().sum();
    assert!((sum + sumf).abs() < 1e-9 * sum.abs());
    // Invariance: rigid motion, uniform scale, and the swap (i,j,k,l) → (j,i,l,k).
    let mut rng = Rng(7);
    for _ in 0..50 {
        let p: Vec<V3> = (0..4).map(|_| rng.vec3()).collect();
        let a = dihedral_angle(p[0], p[1], p[2], p[3]);
        let rot = axis_angle(rng.vec3(), rng.range(-3.0, 3.0));
        let tr = rng.vec3();
        let q: Vec<V3> = p
            .iter()
            .map(|&x| {
                let y = matvec(&rot, x);
                [2.5 * y[0] + tr[0], 2.5 * y[1] + tr[1], 2.5 * y[2] + tr[2]]
            })
            .collect();
        assert!((dihedral_angle(q[0], q[1], q[2], q[3]) - a).abs() < 1e-11);
        assert!((dihedral_angle(p[1], p[0], p[3], p[2]) - a).abs() < 1e-12);
    }
}

#[test]
fn wrap_behaves_at_pi() {
    assert!((wrap_angle(PI + 0.1) - (-PI + 0.1)).abs() < 1e-15);
    assert!((wrap_angle(-PI - 0.1) - (PI - 0.1)).abs() < 1e-15);
    assert!((wrap_angle(7.0 * PI + 0.25) - (-PI + 0.25)).abs() < 1e-12);
    assert_eq!(wrap_angle(0.3), 0.3);
    // Difference of two angles across the ±π cut.
    let a = PI - 0.01;
    let b = -PI + 0.02;
    assert!((wrap_angle(b - a) - 0.03).abs() < 1e-14);
}

#[test]
fn rla_of_rest_is_zero_and_of_scaled_is_constant() {
    let (v, f) = icosphere(2);
    let t = Topology::build(v.len(), &f).unwrap();
    let rest = RestGeometry::new(&t, &v).unwrap();
    let r = Rla::compute(&t, &rest, &v).unwrap();
    assert!(r.rl.iter().chain(&r.ra).all(|&x| x == 0.0));
    let s: Vec<V3> = v
        .iter()
        .map(|p| [1.5 * p[0], 1.5 * p[1], 1.5 * p[2]])
        .collect();
    let r = Rla::compute(&t, &rest, &s).unwrap();
    assert!(r.rl.iter().all(|&x| (x - 0.5).abs() < 1e-14));
    assert!(r.ra.iter().all(|&x| x.abs() < 1e-13));
    // Errors: count mismatch and NaN.
    assert!(matches!(
        Rla::compute(&t, &rest, &s[1..]),
        Err(MeshError::Mismatch(_))
    ));
    let mut bad = s.clone();
    bad[5][1] = f64::NAN;
    assert!(matches!(
        Rla::compute(&t, &rest, &bad),
        Err(MeshError::NonFinite(_))
    ));
}

// ---------------------------------------------------------------- gradients

fn fd_check(f: impl Fn(&[V3]) -> f64, grad: &[V3], x: &[V3], h: f64) -> f64 {
    let mut worst = 0.0f64;
    let gnorm = grad.iter().flatten().map(|g| g * g).sum::<f64>().sqrt();
    for v in 0..x.len() {
        for c in 0..3 {
            let mut xp = x.to_vec();
            let mut xm = x.to_vec();
            xp[v][c] += h;
            xm[v][c] -= h;
            let fd = (f(&xp) - f(&xm)) / (2.0 * h);
            worst = worst.max((fd - grad[v][c]).abs() / gnorm);
        }
    }
    worst
}

#[test]
fn hinge_gradients_match_finite_differences() {
    let mut rng = Rng(42);
    let mut checked = 0;
    while checked < 200 {
        let p: Vec<V3> = (0..4).map(|_| rng.vec3()).collect();
        // Skip near-degenerate diamonds (height < 0.1 of the edge).
        let e = sub(p[1], p[0]);
        let le = panoman_mesh::geom::norm(e);
        let hk = panoman_mesh::geom::norm(panoman_mesh::geom::cross(e, sub(p[2], p[0]))) / le;
        let hl = panoman_mesh::geom::norm(panoman_mesh::geom::cross(e, sub(p[3], p[0]))) / le;
        if hk < 0.1 * le || hl < 0.1 * le || le < 0.1 {
            continue;
        }
        let phi = dihedral_angle(p[0], p[1], p[2], p[3]);
        if phi.abs() > 3.0 {
            continue; // avoid the ±π cut in central differences
        }
        let g = dihedral_gradient(p[0], p[1], p[2], p[3]);
        let err = fd_check(|x| dihedral_angle(x[0], x[1], x[2], x[3]), &g, &p, 1e-6);
        assert!(err < 1e-6, "dihedral gradient rel. error {err}");
        let sum: V3 = [0, 1, 2].map(|c| g.iter().map(|v| v[c]).sum::<f64>());
        assert!(sum.iter().all(|s| s.abs() < 1e-12 * (1.0 + g[2][0].abs())));
        let gl = length_gradient(p[0], p[1]);
        let err = fd_check(
            |x| panoman_mesh::geom::norm(sub(x[1], x[0])),
            &gl,
            &p[0..2],
            1e-6,
        );
        assert!(err < 1e-6, "length gradient rel. error {err}");
        checked += 1;
    }
}

// ---------------------------------------------------------------- rotations

#[test]
fn nearest_rotation_is_the_procrustes_optimum() {
    let mut rng = Rng(3);
    for trial in 0..300 {
        let mut m: M3 = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = rng.normal();
            }
        }
        if trial % 3 == 0 {
            // Near-rotations, the typical case in g.
            let r = axis_angle(rng.vec3(), rng.range(-3.0, 3.0));
            for a in 0..3 {
                for b in 0..3 {
                    m[a][b] = r[a][b] + 0.01 * m[a][b];
                }
            }
        }
        let r = nearest_rotation(&m);
        let rtr = matmul(&transpose(&r), &r);
        assert!(panoman_mesh::geom::frobenius_diff(&rtr, &IDENTITY) < 1e-12);
        assert!((det(&r) - 1.0).abs() < 1e-12);
        let score = |q: &M3| {
            (0..3)
                .map(|a| (0..3).map(|b| q[a][b] * m[a][b]).sum::<f64>())
                .sum::<f64>()
        };
        let best = score(&r);
        for _ in 0..50 {
            // Small perturbations of the optimum never score higher.
            let d = axis_angle(rng.vec3(), rng.range(-0.05, 0.05));
            assert!(score(&matmul(&r, &d)) <= best + 1e-12);
        }
    }
    // A reflection gets the proper rotation with the smallest singular direction flipped.
    let refl = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -0.5]];
    let r = nearest_rotation(&refl);
    assert!((det(&r) - 1.0).abs() < 1e-12);
    assert!(
        panoman_mesh::geom::frobenius_diff(
            &r,
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        ) < 1e-9
            || (r[2][2] - 1.0).abs() > 0.0
    );
}

#[test]
fn kabsch_recovers_a_rigid_motion() {
    let mut rng = Rng(11);
    let a: Vec<V3> = (0..50).map(|_| rng.vec3()).collect();
    let motion = Rigid {
        r: axis_angle([0.3, -1.0, 0.5], 2.7),
        t: [0.5, -2.0, 3.0],
    };
    let b: Vec<V3> = a.iter().map(|&x| motion.apply(x)).collect();
    let est = rigid_align(&a, &b, None);
    assert!(panoman_mesh::geom::frobenius_diff(&est.r, &motion.r) < 1e-12);
    assert!(panoman_mesh::geom::norm(sub(est.t, motion.t)) < 1e-12);
    let (max, mean) = aligned_error(&a, &b);
    assert!(max < 1e-12 && mean < 1e-12);
}

// ---------------------------------------------------------------- g

#[test]
fn connection_maps_match_embedded_frames() {
    let (v, f) = icosphere(2);
    let v: Vec<V3> = v.into_iter().map(deform).collect();
    let t = Topology::build(v.len(), &f).unwrap();
    let l = edge_lengths(&t, &v);
    let phi = dihedral_angles(&t, &v);
    let frame = |face: u32| {
        let [a, b, c] = t.faces[face as usize];
        triangle_frame(v[a as usize], v[b as usize], v[c as usize])
    };
    for e in 0..t.n_edges() {
        let q = connection_map(&t, e, &l, phi[e]);
        let [fl, fr] = t.edge_faces[e];
        let expect = matmul(&transpose(&frame(fl)), &frame(fr));
        assert!(panoman_mesh::geom::frobenius_diff(&q, &expect) < 1e-12);
        assert!((det(&q) - 1.0).abs() < 1e-12);
    }
}

fn round_trip(v: &[V3], f: &[[u32; 3]], rest: &[V3]) -> (f64, f64, panoman_mesh::recon::GStats) {
    let t = Topology::build(v.len(), f).unwrap();
    let rec = Reconstructor::new(&t).unwrap();
    let rg = RestGeometry::new(&t, rest).unwrap();
    let rla = Rla::compute(&t, &rg, v).unwrap();
    let mut ws = rec.workspace();
    let gauge = rec.gauge_from(rest).unwrap();
    let mut out = vec![[0.0; 3]; v.len()];
    let stats = rec
        .reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)
        .unwrap();
    let (max, mean) = aligned_error(&out, v);
    (max, mean, stats)
}

#[test]
fn g_round_trip_closed_mesh() {
    let (rest, f) = icosphere(4);
    let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
    let diag = bbox_diag(&posed);
    let (max, mean, stats) = round_trip(&posed, &f, &rest);
    assert!(max < 1e-9 * diag, "max {max} mean {mean} {stats:?}");
    // With the gauge taken from the target itself, no alignment is needed.
    let t = Topology::build(rest.len(), &f).unwrap();
    let rec = Reconstructor::new(&t).unwrap();
    let rg = RestGeometry::new(&t, &rest).unwrap();
    let rla = Rla::compute(&t, &rg, &posed).unwrap();
    let mut ws = rec.workspace();
    let gauge = rec.gauge_from(&posed).unwrap();
    let mut out = vec![[0.0; 3]; rest.len()];
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)
        .unwrap();
    let err = out
        .iter()
        .zip(&posed)
        .map(|(a, b)| panoman_mesh::geom::norm(sub(*a, *b)))
        .fold(0.0, f64::max);
    assert!(err < 1e-9 * diag, "gauge-from-target error {err}");
    // Zero RLA reproduces the rest shape; a second call on the same workspace agrees.
    let zero = Rla::zeros(t.n_edges());
    let gauge = rec.gauge_from(&rest).unwrap();
    rec.reconstruct_rla(&mut ws, &rg, &zero, &gauge, &mut out)
        .unwrap();
    let err = out
        .iter()
        .zip(&rest)
        .map(|(a, b)| panoman_mesh::geom::norm(sub(*a, *b)))
        .fold(0.0, f64::max);
    assert!(err < 1e-12, "zero RLA error {err}");
}

#[test]
fn g_round_trip_random_gauge_open_and_multi_component() {
    // Random gauge: the output differs by a rigid motion only.
    let (rest, f) = icosphere(3);
    let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
    let t = Topology::build(rest.len(), &f).unwrap();
    let rec = Reconstructor::new(&t).unwrap();
    let rg = RestGeometry::new(&t, &rest).unwrap();
    let rla = Rla::compute(&t, &rg, &posed).unwrap();
    let mut ws = rec.workspace();
    let gauge = Gauge {
        frames: vec![axis_angle([1.0, 2.0, 3.0], 1.3)],
        positions: vec![[5.0, -3.0, 2.0]],
    };
    let mut out = vec![[0.0; 3]; rest.len()];
    rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out)
        .unwrap();
    let (max, _) = aligned_error(&out, &posed);
    assert!(max < 1e-9 * bbox_diag(&posed), "{max}");
    assert!(ws.stats.frame_iterations <= 2, "{:?}", ws.stats);

    // Open mesh (boundary edges have no RA).
    let (g_rest, g_f) = grid(20);
    let g_posed: Vec<V3> = g_rest
        .iter()
        .map(|&[x, y, z]| [x + 0.1 * y * y, y, z + 0.4 * (x * 3.0).sin()])
        .collect();
    let (max, _, _) = round_trip(&g_posed, &g_f, &g_rest);
    assert!(max < 1e-10, "open mesh {max}");

    // Two components: each gets its own gauge.
    let n = rest.len() as u32;
    let mut faces = f.clone();
    faces.extend(f.iter().map(|t| [t[0] + n, t[1] + n, t[2] + n]));
    let mut rest2 = rest.clone();
    rest2.extend(rest.iter().map(|p| [p[0] + 3.0, p[1], p[2]]));
    let mut posed2 = posed.clone();
    posed2.extend(posed.iter().map(|p| [p[0] + 3.0, p[1], p[2]]));
    let t2 = Topology::build(rest2.len(), &faces).unwrap();
    let rec2 = Reconstructor::new(&t2).unwrap();
    assert_eq!(rec2.gauge_faces().len(), 2);
    let rg2 = RestGeometry::new(&t2, &rest2).unwrap();
    let rla2 = Rla::compute(&t2, &rg2, &posed2).unwrap();
    let mut ws2 = rec2.workspace();
    let mut out2 = vec![[0.0; 3]; rest2.len()];
    rec2.reconstruct_rla(
        &mut ws2,
        &rg2,
        &rla2,
        &rec2.gauge_from(&posed2).unwrap(),
        &mut out2,
    )
    .unwrap();
    let (max, _) = aligned_error(&out2, &posed2);
    assert!(max < 1e-9 * bbox_diag(&posed2), "two components {max}");
}

#[test]
fn g_on_noisy_rla_is_finite_and_close() {
    let (rest, f) = icosphere(4);
    let posed: Vec<V3> = rest.iter().map(|&p| deform(p)).collect();
    let t = Topology::build(rest.len(), &f).unwrap();
    let rec = Reconstructor::new(&t).unwrap();
    let rg = RestGeometry::new(&t, &rest).unwrap();
    let mut rla = Rla::compute(&t, &rg, &posed).unwrap();
    let mut rng = Rng(5);
    for e in 0..t.n_edges() {
        // 1 % length noise and 0.05 rad angle noise (the acceptance's robustness case).
        rla.rl[e] = (1.0 + rla.rl[e]) * (1.0 + 0.01 * rng.normal()) - 1.0;
        rla.ra[e] += 0.05 * rng.normal();
    }
    let mut ws = rec.workspace();
    let mut out = vec![[0.0; 3]; rest.len()];
    let stats = rec
        .reconstruct_rla(
            &mut ws,
            &rg,
            &rla,
            &rec.gauge_from(&rest).unwrap(),
            &mut out,
        )
        .unwrap();
    assert!(out.iter().flatten().all(|c| c.is_finite()));
    let (max, mean) = aligned_error(&out, &posed);
    eprintln!("noisy g: max {max:.4} m, mean {mean:.4} m, {stats:?}");
    // Noise is not integrable, so g spreads it: the shape must still be recognisably the
    // target (mean error well below the 2.3 m bbox diagonal; typically a few % of it).
    assert!(mean < 0.1 * bbox_diag(&posed), "mean {mean} {stats:?}");
    // RL below −1 (impossible lengths from blended data) is clamped, not an error; raw
    // non-positive target lengths and NaN are rejected.
    rla.rl[3] = -1.5;
    let st = rec
        .reconstruct_rla(
            &mut ws,
            &rg,
            &rla,
            &rec.gauge_from(&rest).unwrap(),
            &mut out,
        )
        .unwrap();
    assert_eq!(st.clamped_lengths, 1);
    assert!(out.iter().flatten().all(|c| c.is_finite()));
    let mut lengths = panoman_mesh::rla::edge_lengths(&t, &posed);
    let angles = dihedral_angles(&t, &posed);
    lengths[7] = -0.1;
    assert!(
        rec.reconstruct(
            &mut ws,
            &lengths,
            &angles,
            &rec.gauge_from(&rest).unwrap(),
            &mut out
        )
        .is_err()
    );
    rla.rl[3] = f64::NAN;
    assert!(
        rec.reconstruct_rla(
            &mut ws,
            &rg,
            &rla,
            &rec.gauge_from(&rest).unwrap(),
            &mut out
        )
        .is_err()
    );
}

#[test]
fn g_handles_angles_across_pi() {
    // A sheet folded sharply along x = 0.5: by −3.0 rad at rest and by +3.0 rad when posed, so
    // φ − φ_r = 6.0 wraps to 6 − 2π and φ* leaves (−π, π]: only wrapped differences work.
    let (flat, f) = grid(12);
    let fold = |a: f64| -> Vec<V3> {
        flat.iter()
            .map(|&[x, y, _]| {
                if x <= 0.5 {
                    [x, y, 0.0]
                } else {
                    let d = x - 0.5;
                    [0.5 + d * a.cos(), y, d * a.sin()]
                }
            })
            .collect()
    };
    let rest = fold(-3.0);
    let posed = fold(3.0);
    let t = Topology::build(rest.len(), &f).unwrap();
    let rg = RestGeometry::new(&t, &rest).unwrap();
    let rla = Rla::compute(&t, &rg, &posed).unwrap();
    assert!(rla.ra.iter().all(|r| r.abs() <= PI));
    assert!(
        rla.ra
            .iter()
            .any(|r| (r.abs() - (2.0 * PI - 6.0)).abs() < 1e-9)
    );
    let (max, _, _) = round_trip(&posed, &f, &rest);
    assert!(max < 1e-9, "{max}");
}
