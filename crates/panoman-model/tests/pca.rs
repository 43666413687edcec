//! Shape PCA (PanoMan Eq. 2, B_S(α) = V̄ + S·α): exact reconstruction with all components,
//! orthonormal basis, unit-variance coefficients, Eckart–Young truncation error, rank
//! handling, batch projection, bad input.

use faer::Mat;
use panoman_model::pca::ShapePca;

/// SplitMix64.
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
    fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// N shapes of D coordinates: a mean shape plus `rank` decaying directions plus noise.
fn shapes(n: usize, d: usize, rank: usize, noise: f64, seed: u64) -> Mat<f64> {
    let mut rng = Rng(seed);
    let mean: Vec<f64> = (0..d).map(|_| rng.normal()).collect();
    let dirs: Vec<Vec<f64>> = (0..rank)
        .map(|_| (0..d).map(|_| rng.normal()).collect())
        .collect();
    let coef: Vec<Vec<f64>> = (0..n)
        .map(|_| {
            (0..rank)
                .map(|j| rng.normal() * 0.1 / (1.0 + j as f64))
                .collect()
        })
        .collect();
    let noise_m = Mat::<f64>::from_fn(n, d, |_, _| noise * rng.normal());
    Mat::from_fn(n, d, |i, c| {
        mean[c] + (0..rank).map(|j| coef[i][j] * dirs[j][c]).sum::<f64>() + noise_m[(i, c)]
    })
}

fn row(x: &Mat<f64>, i: usize) -> Vec<f64> {
    (0..x.ncols()).map(|j| x[(i, j)]).collect()
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()))
}

#[test]
fn full_pca_reconstructs_exactly_with_orthonormal_basis() {
    let (n, d) = (60, 300);
    let x = shapes(n, d, 80, 1e-3, 1);
    let pca = ShapePca::fit(x.as_ref(), usize::MAX).unwrap();
    // Centring removes one dimension: rank N − 1.
    assert_eq!(pca.n_components(), n - 1);
    assert_eq!(pca.dim(), d);
    assert_eq!(pca.n_samples, n);
    let scale = (0..n)
        .flat_map(|i| row(&x, i))
        .fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..n {
        let xi = row(&x, i);
        let alpha = pca.project(&xi);
        let rec = pca.reconstruct(&alpha);
        let err = max_abs_diff(&rec, &xi);
        assert!(err < 1e-11 * scale, "shape {i}: reconstruction error {err}");
    }
    // Orthonormal basis.
    let q = pca.basis();
    let mut worst = 0.0f64;
    for a in 0..q.ncols() {
        for b in 0..q.ncols() {
            let dot: f64 = (0..d).map(|r| q[(r, a)] * q[(r, b)]).sum();
            let target = if a == b { 1.0 } else { 0.0 };
            worst = worst.max((dot - target).abs());
        }
    }
    eprintln!("‖QᵀQ − I‖_max = {worst:.2e}");
    assert!(worst < 1e-12);
    // Variance ratios: nonincreasing and summing to 1.
    let r = &pca.explained_variance_ratio;
    assert!(r.windows(2).all(|w| w[0] >= w[1]));
    assert!((r.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(pca.std_devs.windows(2).all(|w| w[0] >= w[1]));
    let var_sum: f64 = pca.std_devs.iter().map(|s| s * s).sum();
    assert!((var_sum - pca.total_variance).abs() < 1e-10 * pca.total_variance);
}

#[test]
fn coefficients_have_unit_variance_and_batch_projection_agrees() {
    let (n, d) = (120, 450);
    let x = shapes(n, d, 30, 1e-3, 2);
    let pca = ShapePca::fit(x.as_ref(), 20).unwrap();
    assert_eq!(pca.n_components(), 20);
    let a = pca.project_rows(x.as_ref());
    for j in 0..20 {
        let mean: f64 = (0..n).map(|i| a[(i, j)]).sum::<f64>() / n as f64;
        let var: f64 = (0..n).map(|i| (a[(i, j)] - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        assert!(mean.abs() < 1e-10, "component {j}: mean {mean}");
        assert!((var - 1.0).abs() < 1e-10, "component {j}: variance {var}");
        // Uncorrelated across components.
        if j > 0 {
            let cov: f64 = (0..n).map(|i| a[(i, j)] * a[(i, j - 1)]).sum::<f64>() / (n - 1) as f64;
            assert!(cov.abs() < 1e-10);
        }
    }
    for i in [0, 7, n - 1] {
        let single = pca.project(&row(&x, i));
        for j in 0..20 {
            assert!((single[j] - a[(i, j)]).abs() < 1e-10);
        }
    }
    // S = Q·diag(σ): ‖S_j‖ = σ_j, and the canonical sign makes the largest entry positive.
    for j in 0..20 {
        let col: Vec<f64> = (0..d).map(|r| pca.components[(r, j)]).collect();
        let norm = col.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - pca.std_devs[j]).abs() < 1e-12 * pca.std_devs[j]);
        let big = col
            .iter()
            .copied()
            .fold(0.0f64, |m, v| if v.abs() > m.abs() { v } else { m });
        assert!(big > 0.0);
    }
    // Shorter α means the remaining coefficients are 0.
    let r3 = pca.reconstruct(&[1.0, -0.5, 2.0]);
    let mut r3_full = vec![0.0; 20];
    r3_full[..3].copy_from_slice(&[1.0, -0.5, 2.0]);
    assert!(max_abs_diff(&r3, &pca.reconstruct(&r3_full)) == 0.0);
    assert_eq!(pca.reconstruct(&[]), pca.mean);
}

#[test]
fn truncation_error_matches_dropped_variance() {
    let (n, d) = (80, 200);
    let x = shapes(n, d, 40, 1e-2, 3);
    let full = ShapePca::fit(x.as_ref(), usize::MAX).unwrap();
    for k in [1, 5, 20, 50] {
        let pca = ShapePca::fit(x.as_ref(), k).unwrap();
        // Leading components agree with the full PCA.
        for j in 0..k {
            assert!((pca.std_devs[j] - full.std_devs[j]).abs() < 1e-12 * full.std_devs[0]);
        }
        let mut err = 0.0;
        for i in 0..n {
            let xi = row(&x, i);
            let rec = pca.reconstruct(&pca.project(&xi));
            err += xi
                .iter()
                .zip(&rec)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
        }
        let dropped: f64 = full.std_devs[k..].iter().map(|s| s * s).sum::<f64>() * (n - 1) as f64;
        assert!(
            (err - dropped).abs() < 1e-9 * dropped,
            "k = {k}: error {err}, dropped variance {dropped}"
        );
    }
}

#[test]
fn rank_deficient_data_keeps_the_rank() {
    let (n, d) = (50, 120);
    let x = shapes(n, d, 4, 0.0, 4);
    let pca = ShapePca::fit(x.as_ref(), 30).unwrap();
    assert_eq!(pca.n_components(), 4);
    for i in 0..n {
        let xi = row(&x, i);
        let rec = pca.reconstruct(&pca.project(&xi));
        assert!(max_abs_diff(&rec, &xi) < 1e-11);
    }
}

#[test]
fn deterministic_and_bad_input() {
    let x = shapes(30, 90, 10, 1e-3, 5);
    let a = ShapePca::fit(x.as_ref(), 10).unwrap();
    let b = ShapePca::fit(x.as_ref(), 10).unwrap();
    for j in 0..10 {
        for r in 0..90 {
            assert_eq!(
                a.components[(r, j)].to_bits(),
                b.components[(r, j)].to_bits()
            );
        }
    }
    assert!(ShapePca::fit(x.as_ref(), 0).is_err());
    assert!(ShapePca::fit(x.as_ref().subrows(0, 1), 3).is_err());
    let same = Mat::<f64>::from_fn(5, 9, |_, j| j as f64);
    assert!(ShapePca::fit(same.as_ref(), 3).is_err());
    let mut bad = x.clone();
    bad[(3, 4)] = f64::NAN;
    assert!(ShapePca::fit(bad.as_ref(), 3).is_err());
}

#[test]
fn realistic_size_runs_quickly() {
    // 300 identities of a 13k-vertex mesh (D = 40,000): one thin SVD.
    let (n, d) = (300, 40_000);
    let x = shapes(n, d, 20, 1e-4, 6);
    let t = std::time::Instant::now();
    let pca = ShapePca::fit(x.as_ref(), 200).unwrap();
    let secs = t.elapsed().as_secs_f64();
    eprintln!(
        "PCA {n}×{d} → {}: {secs:.2} s, first ratios {:?}",
        pca.n_components(),
        &pca.explained_variance_ratio[..3]
    );
    assert_eq!(pca.n_components(), 200);
    let xi = row(&x, 17);
    let alpha = pca.project(&xi);
    assert_eq!(alpha.len(), 200);
}
