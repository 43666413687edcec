//! Property tests (proptest) of `g` and the shell solver on degenerate or adversarial inputs:
//! scales from 1e-9 to 1e6, translations up to 1 km, every handle at one point, handles 1 km
//! away, a single handle, duplicated handles with contradicting positions, a mesh collapsed to
//! a point. Each case must give an error or a finite result, never a panic.
//! Case counts: `g` 64 cases, collapsed meshes 32, shell solver 48.
#![allow(clippy::needless_range_loop)]

mod common;

use common::{deform, icosphere};
use panoman_mesh::geom::V3;
use panoman_mesh::shell::{Handle, ShellOptions, ShellSolver, ShellTargets};
use panoman_mesh::{Reconstructor, RestGeometry, Rla, Topology};
use proptest::prelude::*;

fn finite(x: &[V3]) -> bool {
    x.iter().all(|p| p.iter().all(|c| c.is_finite()))
}

fn sphere() -> (Vec<V3>, Topology) {
    let (v, f) = icosphere(2);
    let t = Topology::build(v.len(), &f).unwrap();
    (v, t)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// g on a posed sphere at any scale and placement: Ok with finite vertices, or an error.
    #[test]
    fn g_is_finite_or_an_error_at_any_scale(
        log_scale in -9.0f64..6.0,
        shift in prop::array::uniform3(-1000.0f64..1000.0),
        posed_scale in 0.5f64..2.0,
    ) {
        let (rest, t) = sphere();
        let s = 10f64.powf(log_scale);
        let rest: Vec<V3> = rest.iter().map(|p| p.map(|c| c * s)).collect();
        let posed: Vec<V3> = rest
            .iter()
            .map(|&p| {
                let q = deform(p.map(|c| c / s));
                [0, 1, 2].map(|k| q[k] * s * posed_scale + shift[k])
            })
            .collect();
        let rec = Reconstructor::new(&t).unwrap();
        let Ok(rg) = RestGeometry::new(&t, &rest) else { return Ok(()) };
        let Ok(rla) = Rla::compute(&t, &rg, &posed) else { return Ok(()) };
        let Ok(gauge) = rec.gauge_from(&posed) else { return Ok(()) };
        let mut ws = rec.workspace();
        let mut out = vec![[0.0; 3]; posed.len()];
        if rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out).is_ok() {
            prop_assert!(finite(&out));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// A mesh collapsed to (nearly) one point, as rest or as posed shape.
    #[test]
    fn g_on_a_collapsed_mesh_is_finite_or_an_error(
        at in prop::array::uniform3(-1000.0f64..1000.0),
        jitter in 0.0f64..1e-12,
        collapse_rest in any::<bool>(),
    ) {
        let (rest, t) = sphere();
        let point: Vec<V3> = rest
            .iter()
            .enumerate()
            .map(|(i, _)| [at[0] + jitter * i as f64, at[1], at[2]])
            .collect();
        let (r, p) = if collapse_rest { (&point, &rest) } else { (&rest, &point) };
        let rec = Reconstructor::new(&t).unwrap();
        let Ok(rg) = RestGeometry::new(&t, r) else { return Ok(()) };
        let Ok(rla) = Rla::compute(&t, &rg, p) else { return Ok(()) };
        let Ok(gauge) = rec.gauge_from(p) else { return Ok(()) };
        let mut ws = rec.workspace();
        let mut out = vec![[0.0; 3]; p.len()];
        if rec.reconstruct_rla(&mut ws, &rg, &rla, &gauge, &mut out).is_ok() {
            prop_assert!(finite(&out));
        }
    }
}

/// Which handles a shell case uses.
#[derive(Clone, Copy, Debug)]
enum HandleCase {
    /// Every handle at one point.
    AllAtOnePoint,
    /// Handles 1 km away from the mesh.
    FarAway,
    /// One handle only.
    Single,
    /// The same vertex twice with contradicting positions.
    Duplicated,
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// The shell solver with degenerate handles, at scales 1e-9 … 1e6: Ok with finite
    /// vertices, or an error.
    #[test]
    fn shell_solver_is_finite_or_an_error_with_degenerate_handles(
        case in prop_oneof![
            Just(HandleCase::AllAtOnePoint),
            Just(HandleCase::FarAway),
            Just(HandleCase::Single),
            Just(HandleCase::Duplicated),
        ],
        log_scale in -9.0f64..6.0,
        point in prop::array::uniform3(-1.0f64..1.0),
        n_handles in 1usize..12,
        weight in 1e-3f64..1e3,
    ) {
        let (x0, t) = sphere();
        let s = 10f64.powf(log_scale);
        let x: Vec<V3> = x0.iter().map(|p| deform(*p).map(|c| c * s)).collect();
        let targets0 = ShellTargets::from_positions(&t, &x, 1.0).unwrap();
        let w = weight / (s * s);
        let nv = x.len() as u32;
        let handles: Vec<Handle> = match case {
            HandleCase::AllAtOnePoint => (0..n_handles as u32)
                .map(|k| Handle { vertex: (k * 7) % nv, position: point.map(|c| c * s), weight: w })
                .collect(),
            HandleCase::FarAway => (0..n_handles as u32)
                .map(|k| {
                    let v = (k * 11) % nv;
                    let p = x[v as usize];
                    Handle { vertex: v, position: [p[0] + 1000.0, p[1], p[2] - 1000.0], weight: w }
                })
                .collect(),
            HandleCase::Single => vec![Handle { vertex: 0, position: point.map(|c| c * s), weight: w }],
            HandleCase::Duplicated => vec![
                Handle { vertex: 5, position: point.map(|c| c * s), weight: w },
                Handle { vertex: 5, position: point.map(|c| -c * s), weight: w },
            ],
        };
        let targets = ShellTargets { handles, ..targets0 };
        let mut solver = ShellSolver::new(&t).unwrap();
        let mut y = x.clone();
        let opts = ShellOptions { max_iterations: 15, ..Default::default() };
        if let Ok(rep) = solver.solve(&targets, &mut y, &opts) {
            prop_assert!(finite(&y), "{case:?}: non-finite vertices");
            prop_assert!(rep.energies.iter().all(|e| e.is_finite()), "{case:?}: {:?}", rep.energies);
        }
    }
}
