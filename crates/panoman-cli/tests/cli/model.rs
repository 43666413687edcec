//! Acceptance tests of the model stage on the small preset: training through the CLI, posing,
//! encoding, determinism of the model file, and bad input.

use panoman_mesh::{TriMesh, io};
use panoman_model::model::{BlockName, Evaluator, PanoManModel, Params};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::common;
use common::{ok, one_line_error, panoman, small_model, train_small};

/// A small dataset and a model trained on it, shared by the tests of this file.
fn trained() -> (&'static PathBuf, &'static PathBuf) {
    static CELL: OnceLock<(common::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    let (_, data, model) = CELL.get_or_init(|| small_model("model-test", 3));
    (data, model)
}

/// The trained small model, an evaluator of it, and a held-out body row with its rest mesh.
#[allow(clippy::type_complexity)]
fn encoder_fixture() -> (
    &'static Path,
    std::sync::Arc<PanoManModel>,
    Evaluator,
    Vec<[f64; 3]>,
    Vec<[f64; 3]>,
) {
    let (data, model_path) = trained();
    let model = std::sync::Arc::new(PanoManModel::load(model_path).unwrap());
    let ev = Evaluator::new(model.clone()).unwrap();
    let (mesh, rest, _) = held_out_row(data);
    (model_path, model, ev, mesh, rest)
}

fn held_out_row(data: &Path) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, u8) {
    let ds = panoman_human::dataset::Dataset::open(data).unwrap();
    let r = (0..ds.n_rows)
        .find(|&r| ds.kind[r] == 1 && ds.held_out.contains(&ds.identity[r]))
        .expect("a held-out body row");
    let v = |row: usize| -> Vec<[f64; 3]> {
        ds.vertices(row)
            .unwrap()
            .iter()
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect()
    };
    (v(r), v(ds.rest_of[r] as usize), ds.kind[r])
}

#[test]
fn small_model_trains_poses_and_encodes() {
    let (data, model_path) = trained();
    let model = PanoManModel::load(model_path).unwrap();
    assert_eq!(model.topology_name, "small");
    assert_eq!(model.blocks.len(), 6);
    assert!(model.correction.is_some() && model.motion.is_some());
    // The TC-127 keypoints travel with the model and evaluate on its meshes.
    assert_eq!(model.keypoints.names.len(), 133);
    assert_eq!(model.keypoints.names[0], "neck");
    assert!(model.keypoints.rows.iter().all(|r| !r.is_empty()));
    // The report file reads as the typed report, and the model file carries its own part
    // and the configuration.
    let report: panoman_model::train::TrainReport = serde_json::from_str(
        &std::fs::read_to_string(model_path.with_extension("report.json")).unwrap(),
    )
    .unwrap();
    let repr = report.representation_error.as_ref().expect("evaluated");
    for part in [&repr.body, &repr.face, &repr.hands] {
        assert!(part.mean_mm.is_finite() && part.rows > 0);
    }
    assert_eq!(model.report.as_ref(), Some(&report.model));
    assert_eq!(report.preset, "small");
    assert_eq!(
        model.config.as_ref().map(|c| c.preset.as_str()),
        Some("small")
    );
    let blocks = &report.model.blocks;
    for b in [&blocks.body_l, &blocks.face_l, &blocks.hands_l] {
        assert!(b.as_ref().expect("block summary").components > 0);
    }
    assert!(blocks.correction.is_some() && blocks.motion.is_some());
    assert!(report.timings["total_s"] > 0.0 && report.timings.contains_key("evaluation_s"));
    assert!(model_path.with_extension("fig7.png").exists());
    assert!(model_path.with_extension("fig7.csv").exists());

    // Posing: zero parameters give the mean shape with the mean motion, finite and closed.
    let mut ev = Evaluator::new(std::sync::Arc::new(model.clone())).unwrap();
    let zero = ev.pose(&Params::default(), true).unwrap();
    assert!(zero.iter().flatten().all(|c| c.is_finite()));
    assert_eq!(
        model.n_body_mlp(),
        model.body_beta_f32(&Params::default()).len()
    );
    // Keypoints evaluate on posed meshes: each is an affine combination, so it lies inside
    // the bounding box of the mesh.
    let kp = model.keypoints.evaluate(&zero);
    assert_eq!(kp.len(), 133);
    for c in 0..3 {
        let lo = zero.iter().map(|p| p[c]).fold(f64::INFINITY, f64::min);
        let hi = zero.iter().map(|p| p[c]).fold(f64::NEG_INFINITY, f64::max);
        let slack = 0.05 * (hi - lo);
        assert!(kp.iter().all(|p| p[c] >= lo - slack && p[c] <= hi + slack));
    }
    // Encoding a held-out mesh and posing it back reproduces it far better than the rest
    // shape does (the motion is captured), and the encoding is consistent: encode(pose(p))
    // recovers the RLA of pose(p).
    let (mesh, rest, _) = held_out_row(data);
    let p = ev.encode(&mesh, Some(&rest), false).unwrap();
    let back = ev.pose(&p, false).unwrap();
    let (_, err_model) = panoman_mesh::align::aligned_error(&back, &mesh);
    let (_, err_rest) = panoman_mesh::align::aligned_error(&rest, &mesh);
    assert!(
        err_model < 0.5 * err_rest,
        "model error {err_model} m must be well below the unposed error {err_rest} m"
    );
    // Parameters survive their JSON file exactly.
    let pf = model_path.with_file_name("params-roundtrip.json");
    p.write(&pf).unwrap();
    assert_eq!(Params::read(&pf, &model).unwrap(), p);

    // The CLI round trip: encode → params file → pose.
    let dir = model_path.parent().unwrap();
    let faces = model.faces.clone();
    io::write_mesh(
        &dir.join("x.obj"),
        &TriMesh::new(mesh.clone(), faces.clone()),
    )
    .unwrap();
    io::write_mesh(&dir.join("r.obj"), &TriMesh::new(rest.clone(), faces)).unwrap();
    let m = model_path.to_str().unwrap();
    ok(panoman(&[
        "encode",
        "--model",
        m,
        "--mesh",
        dir.join("x.obj").to_str().unwrap(),
        "--rest",
        dir.join("r.obj").to_str().unwrap(),
        "--out",
        dir.join("p.json").to_str().unwrap(),
    ]));
    ok(panoman(&[
        "pose",
        "--model",
        m,
        "--params",
        dir.join("p.json").to_str().unwrap(),
        "--out",
        dir.join("y.obj").to_str().unwrap(),
    ]));
    let y = io::read_mesh(&dir.join("y.obj")).unwrap();
    assert_eq!(y.n_vertices(), model.n_vertices);
    // Components drawn on the mesh (Fig. 8): a PNG for a body and a face block.
    for block in ["body_a", "face_l"] {
        let png = dir.join(format!("{block}.png"));
        let out = ok(panoman(&[
            "components",
            "--model",
            m,
            "--block",
            block,
            "--count",
            "3",
            "--out",
            png.to_str().unwrap(),
        ]));
        assert!(out.contains("support"), "{out}");
        assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    }
}

#[test]
fn gauss_newton_encoder_lowers_the_vertex_error_below_least_squares() {
    let (model_path, _, mut ev, mesh, rest) = encoder_fixture();
    let opts = panoman_model::model::GnOptions::default();
    for corr in [false, true] {
        let ls = ev.encode(&mesh, Some(&rest), corr).unwrap();
        let (_, e_ls) = panoman_mesh::align::aligned_error(&ev.pose(&ls, corr).unwrap(), &mesh);
        let (gn, rep) = ev.encode_gn(&mesh, Some(&rest), corr, &opts).unwrap();
        let (_, e_gn) = panoman_mesh::align::aligned_error(&ev.pose(&gn, corr).unwrap(), &mesh);
        // α is the least-squares encoder's; only β moves, and the RMS never rises.
        assert_eq!(gn.alpha, ls.alpha);
        assert!(rep.rms <= rep.rms_start && rep.iterations >= 1, "{rep:?}");
        assert!(
            e_gn < 0.9 * e_ls,
            "correction {corr}: Gauss–Newton mean error {e_gn} m is not below the \
             least-squares {e_ls} m ({rep:?})"
        );
        // The iteration is deterministic and monotone: a run cut after 2 accepted iterations
        // is the same run's prefix, so it ends at an RMS no lower than the full run's (one
        // start: the second start of the corrected encoder is not a prefix of itself).
        let one = panoman_model::model::GnOptions {
            correction_two_start: false,
            ..opts
        };
        let (_, rep1) = ev.encode_gn(&mesh, Some(&rest), corr, &one).unwrap();
        let short = panoman_model::model::GnOptions {
            max_iterations: 2,
            ..one
        };
        let (_, rep2) = ev.encode_gn(&mesh, Some(&rest), corr, &short).unwrap();
        assert_eq!(rep2.rms_start, rep1.rms_start);
        assert!(
            rep2.iterations <= 2 && rep1.rms <= rep2.rms,
            "{rep2:?} vs {rep1:?}"
        );
        // The two-start encoder keeps the better of its starts, the first being the
        // one-start run: never worse than it; without the correction the same run.
        if corr {
            assert!(rep.rms <= rep1.rms, "two starts {rep:?} vs one {rep1:?}");
            // The returned β is the start whose RMS is reported.
            let x = ev.pose(&gn, corr).unwrap();
            let t = panoman_mesh::align::rigid_align(&x, &mesh, None);
            let rms = (x
                .iter()
                .zip(&mesh)
                .map(|(a, b)| {
                    let d = panoman_mesh::geom::sub(t.apply(*a), *b);
                    panoman_mesh::geom::dot(d, d)
                })
                .sum::<f64>()
                / x.len() as f64)
                .sqrt();
            assert!(
                (rms - rep.rms).abs() <= 1e-6 * rep.rms,
                "returned β has RMS {rms}, reported {}",
                rep.rms
            );
            assert!(rep.g_solves > rep1.g_solves, "{rep:?} vs {rep1:?}");
        } else {
            assert_eq!(rep, rep1);
        }
    }
    // Through the library: the default encoder is the Gauss–Newton one and re-poses closer.
    let lib = panoman::Model::load(model_path).unwrap();
    let c = panoman::Correction::Skip;
    let p_ls = lib
        .encode_with(&mesh, Some(&rest), c, panoman::Encoder::LeastSquares)
        .unwrap();
    let p_gn = lib.encode(&mesh, Some(&rest), c).unwrap();
    let err = |p: &Params| {
        let x = lib.pose(p, c).unwrap();
        x.iter()
            .zip(&mesh)
            .map(|(a, b)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*a, *b)))
            .sum::<f64>()
            / mesh.len() as f64
    };
    assert!(err(&p_gn) < err(&p_ls));
}

#[test]
fn same_data_and_seed_give_a_byte_identical_model() {
    let (data, model_path) = trained();
    let again = model_path.with_file_name("M2.safetensors");
    ok(train_small(data, &again, &[]));
    let a = std::fs::read(model_path).unwrap();
    let b = std::fs::read(&again).unwrap();
    assert!(a == b, "models differ ({} vs {} bytes)", a.len(), b.len());
    // A different seed changes the model.
    let other = model_path.with_file_name("M3.safetensors");
    ok(train_small(data, &other, &["--seed", "9"]));
    assert!(std::fs::read(&other).unwrap() != a);
    // --shape-components overrides the preset's 6 (and 0 is refused).
    let shape = model_path.with_file_name("M4.safetensors");
    ok(train_small(data, &shape, &["--shape-components", "3"]));
    let m = panoman_model::model::PanoManModel::load(&shape).unwrap();
    assert_eq!(m.shape.n_components(), 3);
    one_line_error(
        &train_small(data, &shape, &["--shape-components", "0"]),
        "--shape-components",
    );
}

#[test]
fn bad_model_params_and_meshes_give_clear_errors() {
    let (data, model_path) = trained();
    let dir = model_path.parent().unwrap().join("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let m = model_path.to_str().unwrap();
    let out = dir.join("out.obj");
    let out_s = out.to_str().unwrap();

    // Truncated and corrupted model files.
    let bytes = std::fs::read(model_path).unwrap();
    let trunc = dir.join("truncated.safetensors");
    std::fs::write(&trunc, &bytes[..bytes.len() / 3]).unwrap();
    std::fs::write(dir.join("p0.json"), "{}").unwrap();
    let p0 = dir.join("p0.json");
    one_line_error(
        &panoman(&[
            "pose",
            "--model",
            trunc.to_str().unwrap(),
            "--params",
            p0.to_str().unwrap(),
            "--out",
            out_s,
        ]),
        "truncated.safetensors",
    );
    let mut corrupt = bytes.clone();
    let n = corrupt.len();
    for b in &mut corrupt[n - 64..] {
        *b = 0xff; // NaNs in the last tensor's data
    }
    let cp = dir.join("corrupt.safetensors");
    std::fs::write(&cp, &corrupt).unwrap();
    let o = panoman(&[
        "pose",
        "--model",
        cp.to_str().unwrap(),
        "--params",
        p0.to_str().unwrap(),
        "--out",
        out_s,
    ]);
    one_line_error(&o, "corrupt.safetensors");
    assert!(!out.exists(), "nothing written on error");

    // Mismatched β length, unknown block, unknown key, NaN.
    let model = PanoManModel::load(model_path).unwrap();
    let k = model.blocks[0].n_components();
    for (name, text, needle) in [
        (
            "len.json",
            format!("{{\"beta\": {{\"body_l\": {:?}}}}}", vec![0.0; k + 1]),
            "body_l",
        ),
        (
            "block.json",
            "{\"beta\": {\"tail_l\": [1.0]}}".to_string(),
            "tail_l",
        ),
        ("key.json", "{\"betas\": {}}".to_string(), "betas"),
        ("alpha.json", "{\"alpha\": [1, 2]}".to_string(), "alpha"),
    ] {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        let o = panoman(&[
            "pose",
            "--model",
            m,
            "--params",
            p.to_str().unwrap(),
            "--out",
            out_s,
        ]);
        one_line_error(&o, name);
        assert!(String::from_utf8_lossy(&o.stderr).contains(needle));
    }

    // Wrong topology: a full-template mesh given to a small model.
    let full = dir.join("full.obj");
    ok(panoman(&["template", "--out", full.to_str().unwrap()]));
    let o = panoman(&[
        "encode",
        "--model",
        m,
        "--mesh",
        full.to_str().unwrap(),
        "--out",
        dir.join("p.json").to_str().unwrap(),
    ]);
    one_line_error(&o, "full.obj");
    assert!(String::from_utf8_lossy(&o.stderr).contains("topology"));

    // A corrupted dataset.
    let bad_data = dir.join("H");
    std::fs::create_dir_all(&bad_data).unwrap();
    std::fs::copy(data.join("dataset.json"), bad_data.join("dataset.json")).unwrap();
    let t = std::fs::read(data.join("dataset.safetensors")).unwrap();
    std::fs::write(bad_data.join("dataset.safetensors"), &t[..t.len() - 100]).unwrap();
    let o = panoman(&[
        "train",
        "--data",
        bad_data.to_str().unwrap(),
        "--preset",
        "small",
        "--out",
        dir.join("m.safetensors").to_str().unwrap(),
    ]);
    one_line_error(&o, "dataset.safetensors");
    assert!(!dir.join("m.safetensors").exists());
}

/// The vertex-error encoder's linearization (docs/design/splocs-model.md §8) against central
/// differences: the correction MLP's Jacobian `∂R/∂β·d` against `R(β ± h d)`, and the vertex
/// product `∂x/∂β·d` with and without it against `pose(β ± h d)`.
#[test]
fn encoder_linearization_matches_finite_differences() {
    let (_, model, mut ev, mesh, rest) = encoder_fixture();
    let mut p = ev.encode(&mesh, Some(&rest), true).unwrap();
    p.translation = [0.0; 3];
    p.rotation = [0.0; 3];
    // A fixed direction over every block (entries in [−1, 1]).
    let mut dir = p.clone();
    for (b, blk) in model.blocks.iter().enumerate() {
        let d: Vec<f64> = (0..blk.n_components())
            .map(|k| (1.3 * k as f64 + 0.7 * b as f64).sin())
            .collect();
        dir.beta.insert(blk.name, d);
    }
    let shifted = |s: f64| {
        let mut q = p.clone();
        for (name, d) in &dir.beta {
            let b = q.beta.get_mut(name).unwrap();
            for (x, dx) in b.iter_mut().zip(d) {
                *x += s * dx;
            }
        }
        q
    };
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    // 1. The correction alone. R is piecewise linear (ReLU) and evaluated in f32: with
    // h = 1e-3 the central difference is exact up to f32 rounding of R (|R| ε₃₂ / h ≈ 1e-4 |R|
    // per entry) unless a unit changes sign inside ±h; 1 % of ‖J d‖ bounds both.
    let h = 1e-3;
    let jd = model
        .correction_jacobian_product(&p, &dir)
        .unwrap()
        .unwrap();
    let rp = model.correction_residual(&shifted(h)).unwrap();
    let rm = model.correction_residual(&shifted(-h)).unwrap();
    let fd: Vec<f64> = rp
        .iter()
        .zip(&rm)
        .map(|(a, b)| (*a as f64 - *b as f64) / (2.0 * h))
        .collect();
    let diff: Vec<f64> = fd.iter().zip(&jd).map(|(a, b)| a - b).collect();
    assert!(norm(&jd) > 0.0);
    assert!(
        norm(&diff) <= 1e-2 * norm(&jd),
        "correction Jacobian: |FD − J d| = {} vs |J d| = {}",
        norm(&diff),
        norm(&jd)
    );
    // 2. Vertices. J_g is g's Gauss–Newton derivative (rla-and-g.md §3.7: exact at consistent
    // RL/RA, and the model's RLA are not exactly consistent), so the product is compared with
    // the same J_g's error on the uncorrected model at the same point: adding the correction's
    // term must leave the corrected product no further from its central difference than
    // that (up to the f32 correction's rounding), whereas dropping the term (what the encoder
    // did before) misses the correction's whole share of the change.
    let fd_of = |ev: &mut Evaluator, corr: bool| {
        let a = ev.pose(&shifted(h), corr).unwrap();
        let b = ev.pose(&shifted(-h), corr).unwrap();
        a.iter()
            .zip(&b)
            .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]) / (2.0 * h)))
            .collect::<Vec<f64>>()
    };
    let fd_corr = fd_of(&mut ev, true);
    let fd_plain = fd_of(&mut ev, false);
    let flat = |v: Vec<[f64; 3]>| v.into_iter().flatten().collect::<Vec<f64>>();
    let with = flat(ev.vertex_jacobian_product(&p, true, &dir).unwrap());
    let without = flat(ev.vertex_jacobian_product(&p, false, &dir).unwrap());
    let err =
        |fd: &[f64], j: &[f64]| norm(&fd.iter().zip(j).map(|(a, b)| a - b).collect::<Vec<_>>());
    let e_base = err(&fd_plain, &without);
    let e_with = err(&fd_corr, &with);
    let e_dropped = err(&fd_corr, &without);
    eprintln!(
        "|FD| {} base {e_base} with {e_with} dropped {e_dropped}",
        norm(&fd_corr)
    );
    assert!(
        e_with <= 1.5 * e_base + 1e-2 * norm(&fd_corr),
        "corrected product off by {e_with}, the uncorrected by {e_base}"
    );
    assert!(e_with < 0.5 * e_dropped, "{e_with} vs {e_dropped}");
    // 3. The transpose the CGLS uses is the adjoint: ⟨J d, u⟩ = ⟨d, Jᵀ u⟩ for a fixed u, with
    // and without the correction (its f32 products round at ~1e-6 relative).
    let u: Vec<[f64; 3]> = (0..mesh.len())
        .map(|v| {
            let t = v as f64;
            [(0.3 * t).sin(), (0.7 * t).cos(), (1.1 * t).sin()]
        })
        .collect();
    let uf: Vec<f64> = u.iter().flatten().copied().collect();
    for (corr, jd) in [(true, &with), (false, &without)] {
        let jt = ev.vertex_jacobian_transpose_product(&p, corr, &u).unwrap();
        let lhs: f64 = jd.iter().zip(&uf).map(|(a, b)| a * b).sum();
        let rhs: f64 = dir
            .beta
            .iter()
            .map(|(name, d)| {
                d.iter()
                    .zip(&jt.beta[name])
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
            })
            .sum();
        let scale = norm(jd) * norm(&uf);
        assert!(
            (lhs - rhs).abs() <= 1e-5 * scale,
            "correction {corr}: <J d, u> = {lhs}, <d, J^T u> = {rhs}"
        );
    }
    // 4. A direction with a block of the wrong length is an error, not a silent zero (an
    // unknown block cannot be written: β is keyed by `BlockName`; the JSON reader's test is
    // `bad_model_params_and_meshes_give_clear_errors`).
    let mut bad = dir.clone();
    bad.beta.get_mut(&BlockName::BodyLength).unwrap().pop();
    let e = ev.vertex_jacobian_product(&p, true, &bad).unwrap_err();
    assert!(e.to_string().contains("body_l"), "{e}");
    assert!(model.correction_jacobian_product(&p, &bad).is_err());
}

/// `Evaluator::pose_vjp` against central differences of `Evaluator::pose_precise`, per
/// parameter group: `⟨vjp(u), d⟩` vs `(⟨u, pose(p + h d)⟩ − ⟨u, pose(p − h d)⟩) / 2h`. Without
/// the correction every step is exact up to g's converged frames and the FD's O(h²)
/// truncation (h = 1e-4 in parameter units; ~1e-7 relative), so 1e-5 is the bound; with it,
/// the MLP runs in f32 (its rounding over 2h, ~1e-4 |R| / |FD| here) and is piecewise linear,
/// so the bound is 0.1 % (measured ~4e-6).
#[test]
fn pose_gradient_matches_finite_differences() {
    let (_, model, mut ev, mesh, rest) = encoder_fixture();
    let mut p = ev.encode(&mesh, Some(&rest), true).unwrap();
    p.rotation = [0.3, -0.2, 0.5];
    p.translation = [0.1, 0.2, -0.3];
    let u: Vec<[f64; 3]> = (0..mesh.len())
        .map(|v| {
            let t = v as f64;
            [(0.3 * t).sin(), (0.7 * t).cos(), (1.1 * t).sin()]
        })
        .collect();
    let mut zero = p.clone();
    zero.alpha.iter_mut().for_each(|a| *a = 0.0);
    for b in zero.beta.values_mut() {
        b.iter_mut().for_each(|x| *x = 0.0);
    }
    zero.rotation = [0.0; 3];
    zero.translation = [0.0; 3];
    let wave =
        |n: usize, k: f64| -> Vec<f64> { (0..n).map(|i| (1.3 * i as f64 + k).sin()).collect() };
    let mut groups: Vec<(&str, Params)> = Vec::new();
    let mut d = zero.clone();
    d.alpha = wave(p.alpha.len(), 0.2);
    groups.push(("alpha", d));
    let mut d = zero.clone();
    for (b, blk) in model.blocks.iter().enumerate() {
        d.beta
            .insert(blk.name, wave(blk.n_components(), 0.7 * b as f64));
    }
    groups.push(("beta", d));
    let mut d = zero.clone();
    d.rotation = [0.4, -0.9, 0.2];
    groups.push(("rotation", d));
    let mut d = zero.clone();
    d.translation = [0.5, 0.3, -0.8];
    groups.push(("translation", d));
    let axpy = |s: f64, d: &Params| {
        let mut q = p.clone();
        for (a, x) in q.alpha.iter_mut().zip(&d.alpha) {
            *a += s * x;
        }
        for (name, dv) in &d.beta {
            for (b, x) in q.beta.get_mut(name).unwrap().iter_mut().zip(dv) {
                *b += s * x;
            }
        }
        for k in 0..3 {
            q.rotation[k] += s * d.rotation[k];
            q.translation[k] += s * d.translation[k];
        }
        q
    };
    let inner = |x: &[[f64; 3]]| -> f64 {
        x.iter()
            .zip(&u)
            .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .sum()
    };
    let dot_params = |g: &Params, d: &Params| -> f64 {
        let a: f64 = g.alpha.iter().zip(&d.alpha).map(|(x, y)| x * y).sum();
        let b: f64 = d
            .beta
            .iter()
            .map(|(n, dv)| g.beta[n].iter().zip(dv).map(|(x, y)| x * y).sum::<f64>())
            .sum();
        let r: f64 = (0..3)
            .map(|k| g.rotation[k] * d.rotation[k] + g.translation[k] * d.translation[k])
            .sum();
        a + b + r
    };
    for corr in [false, true] {
        let g = ev.pose_vjp(&p, corr, &u).unwrap();
        let (h, tol) = if corr { (1e-3, 1e-3) } else { (1e-4, 1e-5) };
        for (name, d) in &groups {
            let fp = inner(&ev.pose_precise(&axpy(h, d), corr).unwrap());
            let fm = inner(&ev.pose_precise(&axpy(-h, d), corr).unwrap());
            let fd = (fp - fm) / (2.0 * h);
            let an = dot_params(&g, d);
            eprintln!("correction {corr} {name}: FD {fd:.9e} analytic {an:.9e}");
            assert!(
                fd.abs() > 1e-3,
                "{name}: the direction has no effect ({fd})"
            );
            assert!(
                (fd - an).abs() <= tol * fd.abs(),
                "correction {corr}, {name}: FD {fd} vs ⟨vjp, d⟩ {an}"
            );
        }
    }
    // The mean shape given as an empty α still gets a gradient for every shape component.
    let mut mean = p.clone();
    mean.alpha.clear();
    let g = ev.pose_vjp(&mean, true, &u).unwrap();
    assert_eq!(g.alpha.len(), model.shape.n_components());
    assert!(g.alpha.iter().any(|a| *a != 0.0));
    // A covector of the wrong length or with a NaN is an error, not a panic.
    assert!(ev.pose_vjp(&p, true, &u[1..]).is_err());
    let mut bad = u.clone();
    bad[5][1] = f64::NAN;
    let e = ev.pose_vjp(&p, true, &bad).unwrap_err();
    assert!(e.to_string().contains("vertex 5"), "{e}");
}
