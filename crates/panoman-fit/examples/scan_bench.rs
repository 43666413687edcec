//! Point-cloud benchmark (issue acceptance: keypoints + a partial noisy scan on the full template).
//!
//! ```sh
//! cargo run --release -p panoman-fit --example scan_bench -- MODEL DATASET [N_ROWS] [key=value …]
//! ```
//!
//! Per held-out body row (kind 1, identity in `held_out`, evenly spread): 5,000 area-uniform
//! surface points with 2 mm Gaussian noise, the 30 % with the largest y (the back) dropped,
//! and the TC-133 keypoints of the true mesh (exact, or with `kpnoise=σ` Gaussian noise and
//! `ik_config_for_noise(σ)`). Prints the mean per-vertex error (mm) of
//!
//! * `lbs`: the keypoint IK;
//! * `pm-kp`: `FrameSolver::fit` without the scan (PanoMan from keypoints);
//! * `old`: the shell fit with the scan from the keypoint IK mesh (`Fitter::fit` with points,
//!   the previous behaviour; skipped with `old=0`);
//! * `ik-icp`: the skeletal ICP (`ik_icp`) mesh;
//! * `pm-pts`: `FrameSolver::fit` with the scan (skeletal ICP, then the shell fit with its ICP);
//!
//! and timings: the point model of the first pass's matches (`IkSolver::model_points`), one
//! warm-started solve with them (20 iterations at most), `ik_icp` and `FrameSolver::fit` in total.
//! Options: `passes=3 sigma=0.003 plane=1 iters=20 starts=1` (skeletal ICP), `icpp=1` (the
//! shell fit's ICP passes after the skeletal ICP); `check=1` prints full-precision
//! keypoint-only IK results (for bitwise comparisons of the solver).
use panoman_fit::fit::FitOptions;
use panoman_fit::icp::{VertexFaces, correspondences_on, simulated_scan};
use panoman_fit::ik::{IkConfig, IkTargets, PointTarget};
use panoman_fit::{Constraints, FrameSolver, IkIcpOptions, LbsRig, ik_config_for_noise};
use panoman_human::dataset::Dataset;
use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_model::model::PanoManModel;
use std::time::Instant;

fn arg<T: std::str::FromStr>(a: &[String], k: &str, d: T) -> T {
    a.iter()
        .find_map(|s| {
            s.strip_prefix(&format!("{k}="))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(d)
}

/// Keypoint noise draws, continuing the stream `simulated_scan` advances (xorshift64 on the
/// same state, Box–Muller normals).
struct Rng(u64);

impl Rng {
    fn gauss(&mut self) -> f64 {
        let mut u = || {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b) = (u().max(1e-300), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let model = PanoManModel::load(a[1].as_ref()).unwrap();
    let ds = Dataset::open(a[2].as_ref()).unwrap();
    let n_rows: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(6);
    let kpn: f64 = arg(&a, "kpnoise", 0.0);
    let ikc = ik_config_for_noise(kpn);
    let defaults = IkIcpOptions::default();
    let icp_opts = IkIcpOptions {
        passes: arg(&a, "passes", defaults.passes),
        point_sigma: arg(&a, "sigma", defaults.point_sigma),
        point_to_plane: arg(&a, "plane", 1) == 1,
        iterations: arg(&a, "iters", defaults.iterations),
        screen_iterations: arg(&a, "siters", defaults.screen_iterations),
        screen_points: arg(&a, "spts", defaults.screen_points),
        phenotype_starts: if arg(&a, "starts", 1) == 1 {
            defaults.phenotype_starts.clone()
        } else {
            Vec::new()
        },
        ..defaults
    };
    let assets = panoman_human::assets::ensure_default().unwrap();
    let mut solver = FrameSolver::new(
        std::sync::Arc::new(model.clone()),
        LbsRig::load(&assets, &model).unwrap(),
    )
    .unwrap();
    let to_v3 = |x: Vec<[f32; 3]>| -> Vec<V3> {
        x.iter()
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64])
            .collect()
    };
    let rows: Vec<usize> = (0..ds.n_rows)
        .filter(|&r| ds.kind[r] == 1 && ds.held_out.contains(&ds.identity[r]))
        .collect();
    if arg(&a, "check", 0) == 1 {
        for i in 0..3 {
            let r = rows[i * rows.len() / 3];
            let truth = to_v3(ds.vertices(r).unwrap());
            let c = Constraints::from_keypoints(KeypointsFile::from_all(
                &model.keypoints.evaluate(&truth),
            ));
            let ikr = solver.ik_fit(&c, &Default::default()).unwrap();
            let h: f64 = ikr.posed.iter().flatten().sum();
            println!(
                "row {r}: cost {:.17e} sum {:.17e} it {}",
                ikr.cost, h, ikr.iterations
            );
            let mut st = ikr.state.clone();
            st.angles[5][0] += 0.05;
            st.phenotype[2] = 0.4;
            let cfg = IkConfig {
                initial_state: Some(st),
                ..Default::default()
            };
            let w = solver.ik_fit(&c, &cfg).unwrap();
            let h: f64 = w.posed.iter().flatten().sum();
            println!(
                "  warm: cost {:.17e} sum {:.17e} it {}",
                w.cost, h, w.iterations
            );
        }
        return;
    }
    let faces_owned = solver.rig().map.faces(solver.rig().topology).to_vec();
    let faces = &faces_owned[..];
    let vf = VertexFaces::from_faces(model.n_vertices, faces);
    let mut rng = Rng(12345);
    let mut sums = [0.0f64; 5];
    let mut times = [0.0f64; 5];
    let mut sums_icp = (0.0f64, 0.0f64);
    println!(
        "row: lbs pm-kp old | ik-icp pm-pts (mm) | setup N pts, warm solve (it), ik-icp, FrameSolver::fit"
    );
    for i in 0..n_rows {
        let r = rows[i * rows.len() / n_rows];
        let truth = to_v3(ds.vertices(r).unwrap());
        let pts = simulated_scan(&truth, &model.faces, 5000, 0.002, &mut rng.0);
        let mut kpts = model.keypoints.evaluate(&truth);
        for p in kpts.iter_mut() {
            for c in p.iter_mut() {
                *c += kpn * rng.gauss();
            }
        }
        let c = Constraints::from_keypoints(KeypointsFile::from_all(&kpts));
        let mut cp = c.clone();
        cp.targets.points = Some(panoman_fit::PointCloud {
            positions: pts.clone(),
            normals: None,
        });
        let err = |x: &[V3]| {
            1e3 * x
                .iter()
                .zip(&truth)
                .map(|(p, q)| norm(sub(*p, *q)))
                .sum::<f64>()
                / truth.len() as f64
        };
        let opts = FitOptions::default();
        let (ikr, pm_kp) = solver.fit(&c, &ikc, &opts, None).unwrap();
        let old = if arg(&a, "old", 1) == 1 {
            err(&solver.fit_from_ik(&cp, &ikr, &opts).unwrap().vertices)
        } else {
            f64::NAN
        };
        // The point model and one warm solve of the first pass's matches.
        let (cons, _) =
            correspondences_on(faces, &vf, &ikr.posed, &pts, None, 1.0, &Default::default());
        let w = ikc.pose_prior.max(1e-6) / (4.0 * icp_opts.point_sigma.powi(2));
        let ptargets: Vec<PointTarget> = cons
            .into_iter()
            .map(|pc| PointTarget {
                rows: pc.rows,
                position: pc.target,
                weight: w,
                normal: pc.normal,
            })
            .collect();
        let t = Instant::now();
        solver
            .ik()
            .model_points(&ikr.state, &Default::default(), &ptargets)
            .unwrap();
        let t_setup = t.elapsed().as_secs_f64();
        let targets = IkTargets::from_file(&c.targets.keypoints).unwrap();
        let t = Instant::now();
        let warm = solver
            .ik()
            .solve_with_points(
                &targets,
                &ptargets,
                &IkConfig {
                    initial_state: Some(ikr.state.clone()),
                    max_iterations: 20,
                    ..ikc.clone()
                },
            )
            .unwrap();
        let t_warm = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (icp, _) = solver.ik_icp(&cp, &ikc, &ikr, &icp_opts).unwrap();
        let t_icp = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let opts_pts = FitOptions {
            icp_passes: arg(&a, "icpp", opts.icp_passes_after_skeletal),
            icp_passes_after_skeletal: arg(&a, "icpp", opts.icp_passes_after_skeletal),
            ..opts.clone()
        };
        let (_, pm_pts) = solver.fit(&cp, &ikc, &opts_pts, None).unwrap();
        let t_frame = t.elapsed().as_secs_f64();
        // The shell fit from this run's skeletal ICP (FrameSolver::fit's path with these options).
        let t = Instant::now();
        let (icp2, _) = solver.ik_icp(&cp, &ikc, &ikr, &icp_opts).unwrap();
        let pm_icp = solver.fit_from_ik(&cp, &icp2, &opts_pts).unwrap();
        let t_pm_icp = t.elapsed().as_secs_f64();
        let t = Instant::now();
        for _ in 0..10 {
            std::hint::black_box(correspondences_on(
                faces,
                &vf,
                &icp2.posed,
                &pts,
                None,
                1.0,
                &Default::default(),
            ));
        }
        let t_match = t.elapsed().as_secs_f64() / 10.0;
        println!(
            "  pm-icp (these options): {:.2} mm in {:.2} s (skeletal ICP + shell fit); one matching {:.1} ms",
            err(&pm_icp.vertices),
            t_pm_icp,
            1e3 * t_match
        );
        sums_icp.0 += err(&pm_icp.vertices);
        sums_icp.1 += t_pm_icp;
        let e = [
            err(&ikr.posed),
            err(&pm_kp.vertices),
            old,
            err(&icp.posed),
            err(&pm_pts.vertices),
        ];
        let tm = [t_setup, t_warm, t_icp, t_frame, warm.iterations as f64];
        for k in 0..5 {
            sums[k] += e[k];
            times[k] += tm[k];
        }
        println!(
            "row {r}: {:.2} {:.2} {:.2} | {:.2} {:.2} | {:.0} ms {} pts, {:.0} ms ({} it), {:.0} ms, {:.2} s",
            e[0],
            e[1],
            e[2],
            e[3],
            e[4],
            1e3 * t_setup,
            ptargets.len(),
            1e3 * t_warm,
            warm.iterations,
            1e3 * t_icp,
            t_frame
        );
    }
    let n = n_rows as f64;
    println!(
        "mean pm-icp (these options): {:.2} mm, {:.2} s",
        sums_icp.0 / n,
        sums_icp.1 / n
    );
    println!(
        "mean: lbs {:.2} pm-kp {:.2} old {:.2} | ik-icp {:.2} pm-pts {:.2} | setup {:.0} ms, warm solve {:.0} ms ({:.1} it), ik-icp {:.0} ms, FrameSolver::fit {:.2} s",
        sums[0] / n,
        sums[1] / n,
        sums[2] / n,
        sums[3] / n,
        sums[4] / n,
        1e3 * times[0] / n,
        1e3 * times[1] / n,
        times[4] / n,
        1e3 * times[2] / n,
        times[3] / n
    );
}
