//! Rotations and rigid alignment.
//!
//! * [`nearest_rotation`]: the projection onto SO(3), `argmax_{R∈SO(3)} tr(Rᵀ M)`, i.e.
//!   `R = U·diag(1, 1, sign det(UVᵀ))·Vᵀ` for `M = U Σ Vᵀ` (used by `g` after the linear frame
//!   solve, docs/design/rla-and-g.md §3.3).
//! * [`rigid_align`]: weighted Kabsch/Procrustes, `argmin_{R,t} Σ w_i |R a_i + t − b_i|²`.

use crate::geom::{M3, V3, add, det, matvec, norm, sub, transpose};
use crate::rotation::quat_to_matrix;

/// A rigid motion `x ↦ R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid {
    /// Rotation (row-major).
    pub r: M3,
    /// Translation.
    pub t: V3,
}

impl Rigid {
    /// The identity motion.
    pub const IDENTITY: Rigid = Rigid {
        r: crate::geom::IDENTITY,
        t: [0.0; 3],
    };

    /// Applies the motion to one point.
    #[inline]
    pub fn apply(&self, x: V3) -> V3 {
        add(matvec(&self.r, x), self.t)
    }

    /// Applies the motion to all points in place.
    pub fn apply_all(&self, xs: &mut [V3]) {
        for x in xs {
            *x = self.apply(*x);
        }
    }
}

/// The rotation closest to `m` in the Frobenius norm (maximiser of `tr(Rᵀ M)` over SO(3)).
///
/// Fast path: Newton's polar iteration `X ← ½(X + X⁻ᵀ)` with determinant scaling, valid when
/// `det M > 0` (then the orthogonal polar factor is a rotation and is the answer). Otherwise,
/// or if the iteration does not settle, Horn's quaternion method: the answer is the rotation of
/// the unit eigenvector of the largest eigenvalue of a symmetric 4×4 matrix built from `M`,
/// found by cyclic Jacobi. Returns the identity for `M = 0`.
pub fn nearest_rotation(m: &M3) -> M3 {
    let d = det(m);
    let scale: f64 = m.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    if scale.is_nan() || scale <= 0.0 || !scale.is_finite() {
        return crate::geom::IDENTITY;
    }
    if d > 1e-6 * scale * scale * scale {
        let mut x = *m;
        for it in 0..30 {
            let dx = det(&x);
            let inv_t = inverse_transpose(&x, dx);
            // Scaled Newton (Higham): γ = |det X|^(−1/3) balances X and X⁻ᵀ; skip once converged.
            let g = if it < 6 {
                dx.abs().powf(-1.0 / 3.0)
            } else {
                1.0
            };
            let mut next = [[0.0; 3]; 3];
            let mut change = 0.0f64;
            for r in 0..3 {
                for c in 0..3 {
                    next[r][c] = 0.5 * (g * x[r][c] + inv_t[r][c] / g);
                    change = change.max((next[r][c] - x[r][c]).abs());
                }
            }
            x = next;
            if change < 1e-15 {
                return x;
            }
        }
        // Fall through on non-convergence.
    }
    horn_rotation(m)
}

#[inline]
fn inverse_transpose(x: &M3, d: f64) -> M3 {
    // X⁻ᵀ = cofactor(X)/det X.
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| x[r0][c0] * x[r1][c1] - x[r0][c1] * x[r1][c0];
    let inv = 1.0 / d;
    [
        [
            c(1, 2, 1, 2) * inv,
            -c(1, 2, 0, 2) * inv,
            c(1, 2, 0, 1) * inv,
        ],
        [
            -c(0, 2, 1, 2) * inv,
            c(0, 2, 0, 2) * inv,
            -c(0, 2, 0, 1) * inv,
        ],
        [
            c(0, 1, 1, 2) * inv,
            -c(0, 1, 0, 2) * inv,
            c(0, 1, 0, 1) * inv,
        ],
    ]
}

/// Horn's closed-form maximiser of `tr(Rᵀ M)` over SO(3) via a 4×4 symmetric eigenproblem.
fn horn_rotation(m: &M3) -> M3 {
    // With S = Mᵀ (S_ab = Σ a_a b_b for M = Σ b aᵀ), Horn's matrix N has the optimal unit
    // quaternion as its top eigenvector.
    let s = transpose(m);
    let (sxx, sxy, sxz) = (s[0][0], s[0][1], s[0][2]);
    let (syx, syy, syz) = (s[1][0], s[1][1], s[1][2]);
    let (szx, szy, szz) = (s[2][0], s[2][1], s[2][2]);
    let mut n = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|p| (p + 1..4).map(move |q| (p, q)))
            .map(|(p, q)| n[p][q] * n[p][q])
            .sum();
        let diag: f64 = (0..4).map(|p| n[p][p] * n[p][p]).sum();
        if off <= 1e-32 * diag.max(1e-300) {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if n[p][q] == 0.0 {
                    continue;
                }
                let theta = (n[q][q] - n[p][p]) / (2.0 * n[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * c;
                for k in 0..4 {
                    let (a, b) = (n[k][p], n[k][q]);
                    n[k][p] = c * a - sn * b;
                    n[k][q] = sn * a + c * b;
                }
                for k in 0..4 {
                    let (a, b) = (n[p][k], n[q][k]);
                    n[p][k] = c * a - sn * b;
                    n[q][k] = sn * a + c * b;
                }
                for row in v.iter_mut() {
                    let (a, b) = (row[p], row[q]);
                    row[p] = c * a - sn * b;
                    row[q] = sn * a + c * b;
                }
            }
        }
    }
    let best = (0..4)
        .max_by(|&a, &b| {
            n[a][a]
                .partial_cmp(&n[b][b])
                .unwrap_or(std::cmp::Ordering::Equal)
        })
        .unwrap_or(0);
    let q = [v[0][best], v[1][best], v[2][best], v[3][best]];
    let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    quat_to_matrix([q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn])
}

/// Weighted Kabsch: the rigid motion minimising `Σ w_i |R a_i + t − b_i|²` (`weights = None`
/// means all 1). With centroids `ā, b̄`, `R = nearest_rotation(Σ w (b−b̄)(a−ā)ᵀ)`, `t = b̄ − R ā`.
pub fn rigid_align(a: &[V3], b: &[V3], weights: Option<&[f64]>) -> Rigid {
    assert_eq!(a.len(), b.len());
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let mut wsum = 0.0;
    let mut ca = [0.0; 3];
    let mut cb = [0.0; 3];
    for i in 0..a.len() {
        let wi = w(i);
        wsum += wi;
        for c in 0..3 {
            ca[c] += wi * a[i][c];
            cb[c] += wi * b[i][c];
        }
    }
    if wsum.is_nan() || wsum <= 0.0 {
        return Rigid::IDENTITY;
    }
    for c in 0..3 {
        ca[c] /= wsum;
        cb[c] /= wsum;
    }
    let mut m = [[0.0; 3]; 3];
    for i in 0..a.len() {
        let wi = w(i);
        let da = sub(a[i], ca);
        let db = sub(b[i], cb);
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] += wi * db[r] * da[c];
            }
        }
    }
    let r = nearest_rotation(&m);
    Rigid {
        r,
        t: sub(cb, matvec(&r, ca)),
    }
}

/// Per-vertex distances after rigidly aligning `a` onto `b`: returns `(max, mean)` in the
/// units of the input.
pub fn aligned_error(a: &[V3], b: &[V3]) -> (f64, f64) {
    let rig = rigid_align(a, b, None);
    let mut max = 0.0f64;
    let mut sum = 0.0;
    for (x, y) in a.iter().zip(b) {
        let d = norm(sub(rig.apply(*x), *y));
        max = max.max(d);
        sum += d;
    }
    (max, sum / a.len().max(1) as f64)
}
