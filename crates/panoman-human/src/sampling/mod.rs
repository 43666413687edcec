//! Seeded samplers of identities, body poses, hand gestures and facial expressions for the
//! synthetic training data (docs/design/rig-and-ik.md §3; docs/formats.md).
//!
//! # Random numbers
//! Every draw comes from a [`ChaCha8Rng`] keyed by `(seed, domain, index)` ([`stream_rng`]):
//! the 32-byte ChaCha key is `seed ‖ domain ‖ index ‖ "panoman!"` (little-endian `u64`s), so
//! each identity, row or split gets its own independent stream. A sample depends only on its
//! key, never on the order in which samples are drawn or on the number of threads.
//! Uniforms are `U = (next_u64 >> 11) · 2⁻⁵³ ∈ [0, 1)`; normals use Box–Muller
//! (`√(−2 ln(1−U₁)) · cos 2πU₂`); Gamma uses Marsaglia–Tsang (2000) in log space, with the
//! `Gamma(a) = Gamma(a+1) · U^{1/a}` boost for `a < 1`; `Beta(a, b) = G_a / (G_a + G_b)`
//! evaluated as `1 / (1 + exp(ln G_b − ln G_a))`, which stays finite for the very small shape
//! parameters of Anny's calibration (e.g. `β = 0.0094`). "TN(μ, σ; lo, hi)" below is a
//! normal truncated to `[lo, hi]` by rejection (after 16 rejections the last draw is clamped).
//!
//! # Angles
//! Poses are [`Theta`]: local Euler angles `[x, y, z]` in degrees (`R = Rz(z)·Ry(y)·Rx(x)`,
//! [`crate::params::PoseParams`]) for the [`posable_bones`]. The samplers reason in the
//! *left-side* convention of docs/design/rig-and-ik.md §3.1/§3.3 and store right-side bones mirrored as
//! `(x, −y, −z)`; the eyes take the same angles on both sides (conjugate gaze, docs/design/rig-and-ik.md §3.1). Every
//! sampled angle lies inside [`bone_range`] (docs/design/rig-and-ik.md §3.3, with the measured twist limits
//! [`TWIST_LIMIT_DEG`]). Bones not listed stay at identity (pelvis, breasts, toes, the face
//! muscle bones, tongue), and so does the root: rows carry no global rotation or translation.

use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};

use crate::error::{HumanError, Result};
use crate::params::{PoseParams, ShapeParams};
use crate::phenotype::{FACE_UNITS, face_unit_index};

// ---------------------------------------------------------------------------------------------
// Random numbers.

/// Domain of [`stream_rng`] for identity draws (index = identity id).
pub const DOMAIN_IDENTITY: u64 = 1;
/// Domain of [`stream_rng`] for row draws (index = row number).
pub const DOMAIN_ROW: u64 = 2;
/// Domain of [`stream_rng`] for the train/held-out split (index 0).
pub const DOMAIN_SPLIT: u64 = 3;

/// The random stream of sample `index` in `domain` under `seed`: ChaCha8 with the key
/// `seed ‖ domain ‖ index ‖ "panoman!"` (each a little-endian `u64`), stream 0.
///
/// Distinct `(seed, domain, index)` give distinct keys, so streams never overlap.
pub fn stream_rng(seed: u64, domain: u64, index: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&domain.to_le_bytes());
    key[16..24].copy_from_slice(&index.to_le_bytes());
    key[24..].copy_from_slice(b"panoman!");
    ChaCha8Rng::from_seed(key)
}

/// `U ∈ [0, 1)` with 53 random bits: `(next_u64 >> 11) · 2⁻⁵³`.
#[inline]
pub fn uniform(rng: &mut (impl RngCore + ?Sized)) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// `U(lo, hi)`: `lo + (hi − lo) · U`.
#[inline]
pub fn uniform_in(rng: &mut (impl RngCore + ?Sized), lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * uniform(rng)
}

/// Standard normal by Box–Muller: `√(−2 ln(1 − U₁)) · cos(2π U₂)` (one value per two
/// uniforms; `1 − U₁ ∈ (0, 1]` keeps the logarithm finite).
#[inline]
pub fn normal(rng: &mut (impl RngCore + ?Sized)) -> f64 {
    let u1 = 1.0 - uniform(rng);
    let u2 = uniform(rng);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Truncated normal TN(μ, σ; lo, hi): redraws `μ + σ·N(0,1)` until it falls in `[lo, hi]`
/// (at most 16 times, then clamps the last draw).
pub fn truncated_normal(
    rng: &mut (impl RngCore + ?Sized),
    mean: f64,
    sd: f64,
    lo: f64,
    hi: f64,
) -> f64 {
    let mut x = mean;
    for _ in 0..16 {
        x = mean + sd * normal(rng);
        if (lo..=hi).contains(&x) {
            return x;
        }
    }
    x.clamp(lo, hi)
}

/// `ln G` for `G ~ Gamma(shape a, scale 1)`, `a > 0`.
///
/// Marsaglia–Tsang: with `d = a − 1/3`, `c = 1/√(9d)`, draw `x ~ N(0,1)`, `v = (1 + c x)³`
/// (reject `v ≤ 0`) and `u ~ U(0,1]`; accept `d·v` if `ln u < x²/2 + d(1 − v + ln v)`. For
/// `a < 1`: `ln G_a = ln G_{a+1} + ln(u)/a` (log space, so tiny shapes cannot underflow).
pub fn ln_gamma_sample(rng: &mut (impl RngCore + ?Sized), a: f64) -> f64 {
    assert!(a > 0.0 && a.is_finite(), "Gamma shape must be positive");
    if a < 1.0 {
        let u = 1.0 - uniform(rng);
        return ln_gamma_sample(rng, a + 1.0) + u.ln() / a;
    }
    let d = a - 1.0 / 3.0;
    let c = 1.0 / (9.0 * d).sqrt();
    loop {
        let x = normal(rng);
        let t = 1.0 + c * x;
        if t <= 0.0 {
            continue;
        }
        let v = t * t * t;
        let u = 1.0 - uniform(rng);
        let x2 = x * x;
        if u < 1.0 - 0.0331 * x2 * x2 || u.ln() < 0.5 * x2 + d * (1.0 - v + v.ln()) {
            return d.ln() + v.ln();
        }
    }
}

/// `Beta(a, b)` from two Gamma draws: `G_a / (G_a + G_b) = 1 / (1 + exp(ln G_b − ln G_a))`,
/// in `[0, 1]`.
pub fn beta(rng: &mut (impl RngCore + ?Sized), a: f64, b: f64) -> f64 {
    let la = ln_gamma_sample(rng, a);
    let lb = ln_gamma_sample(rng, b);
    (1.0 / (1.0 + (lb - la).exp())).clamp(0.0, 1.0)
}

/// Picks index `i` with probability `w_i / Σ w`.
fn choose_weighted(rng: &mut (impl RngCore + ?Sized), weights: &[f64]) -> usize {
    let total: f64 = weights.iter().sum();
    let mut u = uniform(rng) * total;
    for (i, &w) in weights.iter().enumerate() {
        if u < w {
            return i;
        }
        u -= w;
    }
    weights.len() - 1
}

mod body;
mod bones;
mod face;
mod hands;
mod identity;

pub use body::*;
pub use bones::*;
pub use face::*;
pub use hands::*;
pub use identity::*;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beta_moments_and_tiny_shapes() {
        let mut rng = stream_rng(7, 99, 0);
        for (a, b) in [(2.0, 5.0), (0.3, 0.7), (21.6, 58.6)] {
            let n = 20000;
            let xs: Vec<f64> = (0..n).map(|_| beta(&mut rng, a, b)).collect();
            let m = xs.iter().sum::<f64>() / n as f64;
            let want = a / (a + b);
            assert!((m - want).abs() < 0.01, "Beta({a},{b}) mean {m} vs {want}");
        }
        for _ in 0..1000 {
            let x = beta(&mut rng, 0.273, 0.00937);
            assert!((0.0..=1.0).contains(&x));
            let y = beta(&mut rng, 0.00996, 0.2929);
            assert!((0.0..=1.0).contains(&y));
        }
    }

    #[test]
    fn interp_matches_anchors() {
        assert_eq!(anny_age_of_years(0.0), 0.0);
        assert!((anny_age_of_years(16.0) - 0.67).abs() < 1e-15);
        assert!((anny_age_of_years(90.0) - (0.83 + 26.0 / 46.0 * 0.17)).abs() < 1e-12);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 3.0, false), 4.0);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 3.0, true), 8.0);
    }

    #[test]
    fn mirror_units() {
        assert_eq!(mirror_unit("browDownLeft"), Some("browDownRight"));
        assert_eq!(mirror_unit("mouthSmileRight"), Some("mouthSmileLeft"));
        assert_eq!(mirror_unit("jawLeft"), None);
        assert_eq!(mirror_unit("cheekPuff"), None);
    }
}
