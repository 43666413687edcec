//! Rotations: matrices (row-major `M3`, acting on column vectors) from an axis and angle, a
//! rotation vector, a unit quaternion or Euler angles, and back to a rotation vector or Euler
//! angles. Angles in radians unless a name says `_deg`.
//!
//! Conventions: the rotation vector `v = θ·n` (unit axis `n`, `θ = |v| ∈ [0, π]` on the way
//! back); Euler "XYZ" as Blender and the MakeHuman rig use them, `R = Rz(z)·Ry(y)·Rx(x)` (x
//! applied first).

use crate::geom::{IDENTITY, M3, V3, dot, matmul, norm, normalize, scale};

/// Rotation matrix of the unit quaternion `(w, x, y, z)`.
pub fn quat_to_matrix(q: [f64; 4]) -> M3 {
    let [w, x, y, z] = q;
    [
        [
            w * w + x * x - y * y - z * z,
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            w * w - x * x + y * y - z * z,
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            w * w - x * x - y * y + z * z,
        ],
    ]
}

/// The unit quaternion `(w, x, y, z)` of a rotation matrix (the inverse of
/// [`quat_to_matrix`] up to the sign of `q`): Shepperd's method, from the largest of the
/// trace and the diagonal entries.
pub fn quaternion_of(m: &M3) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let [x, y, z, w] = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
            0.25 * s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[2][1] - m[1][2]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
            (m[0][2] - m[2][0]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
            (m[1][0] - m[0][1]) / s,
        ]
    };
    let n = (x * x + y * y + z * z + w * w).sqrt();
    [w / n, x / n, y / n, z / n]
}

/// Rotation by `angle` (radians) about the unit `axis` (Rodrigues' formula
/// `R = I + sin θ K + (1 − cos θ) K²`, K the cross-product matrix of the axis).
pub fn axis_angle(axis: V3, angle: f64) -> M3 {
    let a = normalize(axis);
    let (s, v) = sin_versine(angle);
    let k = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]];
    let k2 = matmul(&k, &k);
    let mut r = IDENTITY;
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] += s * k[i][j] + v * k2[i][j];
        }
    }
    r
}

/// Rotation of `angle` radians about the unit `axis` by the library `sin_cos`:
/// `R = cos θ I + sin θ [k]ₓ + (1 − cos θ) k kᵀ`. The generator's rest frames are built with
/// this form, as Anny's reference builds them; [`axis_angle`] (which also normalizes the axis)
/// differs from it by a few ulps.
pub fn rodrigues(axis: V3, angle: f64) -> M3 {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = axis;
    let t = 1.0 - c;
    [
        [c + t * x * x, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, c + t * z * z],
    ]
}

/// `(sin θ, 1 − cos θ)`, both to a few ulps. For |θ| < 1/8 by their Taylor series to θ¹¹
/// and θ¹² (remainders below 10⁻²⁰ relative), without the library call, which dominates the
/// frame solve of `g` (every face rotates by a small angle each iteration); the series of
/// `1 − cos θ` is also free of the cancellation of `1 − cos θ` computed from `cos θ`. Larger
/// angles use the half-angle forms.
#[inline]
pub fn sin_versine(angle: f64) -> (f64, f64) {
    if angle.abs() < 0.125 {
        let z = angle * angle;
        let s = angle
            * (1.0
                - z / 6.0
                    * (1.0 - z / 20.0 * (1.0 - z / 42.0 * (1.0 - z / 72.0 * (1.0 - z / 110.0)))));
        let v = z / 2.0
            * (1.0
                - z / 12.0
                    * (1.0 - z / 30.0 * (1.0 - z / 56.0 * (1.0 - z / 90.0 * (1.0 - z / 132.0)))));
        (s, v)
    } else {
        // sin θ = 2 sin(θ/2) cos(θ/2), 1 − cos θ = 2 sin²(θ/2): one call, no cancellation.
        let (sh, ch) = (0.5 * angle).sin_cos();
        (2.0 * sh * ch, 2.0 * sh * sh)
    }
}

/// The rotation of a rotation vector `v = θ·n` ([`axis_angle`]`(v, |v|)`; the identity for
/// `v = 0`).
pub fn from_rotation_vector(v: V3) -> M3 {
    let a = norm(v);
    if a == 0.0 { IDENTITY } else { axis_angle(v, a) }
}

/// The left Jacobian of SO(3) at the rotation vector `v` (θ = |v|):
/// `exp([v + δ]×) ≈ exp([J_l(v) δ]×) exp([v]×)`, with
/// `J_l = I + (1 − cos θ)/θ² [v]× + (θ − sin θ)/θ³ [v]×²` (series below θ = 10⁻⁴).
pub fn left_jacobian(v: V3) -> M3 {
    let th2 = dot(v, v);
    let th = th2.sqrt();
    let (a, b) = if th < 1e-4 {
        (0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0)
    } else {
        let (s, c) = th.sin_cos();
        ((1.0 - c) / th2, (th - s) / (th2 * th))
    };
    let k = [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]];
    let mut out = IDENTITY;
    for i in 0..3 {
        for j in 0..3 {
            let k2: f64 = (0..3).map(|m| k[i][m] * k[m][j]).sum();
            out[i][j] += a * k[i][j] + b * k2;
        }
    }
    out
}

/// The rotation vector (axis·angle, radians, `θ ∈ [0, π]`) of a rotation matrix: the SO(3)
/// logarithm, `θ = atan2(|w|/2, (tr R − 1)/2)` with `w = vee(R − Rᵀ)`, `v = θ·w/|w|`; a series
/// near 0, and beyond π/2 the axis from the symmetric part (accurate up to π).
pub fn rotation_vector(r: &M3) -> V3 {
    // vee(R − Rᵀ) = 2 sin θ · n.
    let w = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]];
    let cos = ((r[0][0] + r[1][1] + r[2][2] - 1.0) * 0.5).clamp(-1.0, 1.0);
    let sin = 0.5 * norm(w);
    let th = sin.atan2(cos);
    if th < 1e-4 {
        // θ / (2 sin θ) = 1/2 + θ²/12 + O(θ⁴).
        return scale(w, 0.5 + th * th / 12.0);
    }
    if th < std::f64::consts::FRAC_PI_2 {
        return scale(w, th / (2.0 * sin));
    }
    // Towards π sin θ vanishes: (R + Rᵀ)/2 − cos θ·I = (1 − cos θ)·n nᵀ, its largest column
    // gives the axis, signed like w.
    let mut b = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            b[i][j] = 0.5 * (r[i][j] + r[j][i]) - if i == j { cos } else { 0.0 };
        }
    }
    let i = (0..3)
        .max_by(|&a, &c| b[a][a].total_cmp(&b[c][c]))
        .unwrap_or(0);
    let col = [b[0][i], b[1][i], b[2][i]];
    let mut n = scale(col, 1.0 / norm(col));
    if dot(n, w) < 0.0 {
        n = scale(n, -1.0);
    }
    scale(n, th)
}

/// Rotation about the X axis by `a` radians.
pub fn rot_x(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}

/// Rotation about the Y axis by `a` radians.
pub fn rot_y(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

/// Rotation about the Z axis by `a` radians.
pub fn rot_z(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}

/// Euler "XYZ" rotation, radians: `R = Rz(z)·Ry(y)·Rx(x)` (x applied first).
pub fn euler_xyz(e: [f64; 3]) -> M3 {
    matmul(&rot_z(e[2]), &matmul(&rot_y(e[1]), &rot_x(e[0])))
}

/// [`euler_xyz`] from degrees.
pub fn euler_xyz_deg(e: [f64; 3]) -> M3 {
    euler_xyz(e.map(f64::to_radians))
}

/// The Euler "XYZ" angles `[x, y, z]` (degrees) of `m = Rz(z)·Ry(y)·Rx(x)`: `y ∈ [−90°, 90°]`,
/// and `z = 0` at gimbal lock (`|y| = 90°`).
pub fn euler_xyz_deg_of(m: &M3) -> [f64; 3] {
    let sy = (-m[2][0]).clamp(-1.0, 1.0);
    let y = sy.asin();
    let (x, z) = if (1.0 - sy.abs()) > 1e-12 {
        (m[2][1].atan2(m[2][2]), m[1][0].atan2(m[0][0]))
    } else {
        ((-m[1][2]).atan2(m[1][1]), 0.0)
    };
    [x.to_degrees(), y.to_degrees(), z.to_degrees()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{frobenius_diff, matvec, sub};

    fn close(a: &M3, b: &M3, tol: f64) -> bool {
        (0..3).all(|i| (0..3).all(|j| (a[i][j] - b[i][j]).abs() < tol))
    }

    /// The series branch of [`sin_versine`] agrees with the library functions to a few ulps:
    /// `sin θ` against `f64::sin`, `1 − cos θ` against `2 sin²(θ/2)` (no cancellation), on
    /// angles from 10⁻¹² to the branch point, of both signs, and across the branch point.
    #[test]
    fn sin_versine_matches_the_library() {
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let check = |t: f64| {
            let (sn, v) = sin_versine(t);
            let v_ref = 2.0 * (0.5 * t).sin().powi(2);
            assert!(
                (sn - t.sin()).abs() <= 4.0 * f64::EPSILON * t.sin().abs(),
                "sin {t}"
            );
            assert!(
                (v - v_ref).abs() <= 4.0 * f64::EPSILON * v_ref,
                "versine {t}"
            );
        };
        for _ in 0..100_000 {
            let (u, w) = (next(), next());
            let t = 0.125 * 10f64.powf(-11.0 * u) * if w < 0.5 { -1.0 } else { 1.0 };
            check(t);
        }
        for t in [0.124_999_999, 0.125, 0.125_000_001, -0.125, 1.0, 3.0] {
            check(t);
        }
        assert_eq!(sin_versine(0.0), (0.0, 0.0));
        // A rotation from either branch is orthonormal to rounding.
        for t in [1e-9, 0.1, 0.124_999, 0.125, 2.0] {
            let r = axis_angle([1.0, 2.0, -0.5], t);
            let rt = matmul(&r, &crate::geom::transpose(&r));
            for (i, row) in rt.iter().enumerate() {
                for (j, x) in row.iter().enumerate() {
                    let id = if i == j { 1.0 } else { 0.0 };
                    assert!((x - id).abs() < 1e-15, "R Rᵀ at {t}");
                }
            }
        }
    }

    #[test]
    fn rotation_vectors_round_trip_near_zero_and_near_pi() {
        for v in [
            [0.0, 0.0, 0.0],
            [1e-9, -2e-9, 3e-10],
            [0.3, -0.2, 0.9],
            [-1.0, 2.0, 0.5],
        ] {
            let r = from_rotation_vector(v);
            let back = rotation_vector(&r);
            assert!(norm(sub(back, v)) < 1e-12, "{v:?} → {back:?}");
        }
        // Within 10⁻⁷ of π (the symmetric-part branch), either sign of the axis.
        for s in [1.0, -1.0] {
            let n = normalize([0.2, -0.7, 0.4]);
            let th = std::f64::consts::PI - 1e-7;
            let v = n.map(|x| s * x * th);
            let back = rotation_vector(&from_rotation_vector(v));
            assert!(close(
                &from_rotation_vector(back),
                &from_rotation_vector(v),
                1e-9
            ));
            assert!((norm(back) - th).abs() < 1e-9);
        }
        // The rotation of v turns v's axis onto itself and a perpendicular by |v|.
        let v = [0.0, 0.0, 0.5];
        let p = matvec(&from_rotation_vector(v), [1.0, 0.0, 0.0]);
        assert!(norm(sub(p, [0.5f64.cos(), 0.5f64.sin(), 0.0])) < 1e-15);
    }

    #[test]
    fn quaternions_round_trip_from_every_branch() {
        // Angles that make the trace and each diagonal entry the largest in turn.
        for (axis, th) in [
            ([0.2, 0.3, 0.9], 0.4),
            ([1.0, 0.1, 0.0], 3.0),
            ([0.1, 1.0, 0.2], 3.0),
            ([0.0, 0.2, 1.0], 3.1),
        ] {
            let m = axis_angle(axis, th);
            let q = quaternion_of(&m);
            assert!((q.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(close(&quat_to_matrix(q), &m, 1e-14), "{axis:?} {th}");
        }
    }

    #[test]
    fn both_axis_angle_forms_agree_to_rounding() {
        let n = normalize([0.3, -0.4, 0.8]);
        for th in [1e-8, 0.05, 0.124, 0.5, 2.0, -3.0] {
            assert!(close(&rodrigues(n, th), &axis_angle(n, th), 1e-15), "{th}");
        }
    }

    #[test]
    fn euler_angles_round_trip_and_follow_the_xyz_order() {
        for e in [[10.0, -20.0, 30.0], [-170.0, 45.0, 95.0], [0.0, 89.0, -3.0]] {
            let back = euler_xyz_deg_of(&euler_xyz_deg(e));
            assert!(
                close(&euler_xyz_deg(back), &euler_xyz_deg(e), 1e-9),
                "{e:?}"
            );
        }
        // x is applied first: Rx(90°) takes e_y to e_z, which Rz(90°) leaves.
        let r = euler_xyz_deg([90.0, 0.0, 90.0]);
        let p = matvec(&r, [0.0, 1.0, 0.0]);
        assert!(norm(sub(p, [0.0, 0.0, 1.0])) < 1e-15, "{p:?}");
        assert!(close(&euler_xyz([0.0, 0.0, 0.7]), &rot_z(0.7), 1e-15));
        // Gimbal lock: z is 0 and x carries the rest.
        let lock = euler_xyz_deg_of(&euler_xyz_deg([30.0, 90.0, 10.0]));
        assert_eq!(lock[2], 0.0);
        assert!(close(
            &euler_xyz_deg(lock),
            &euler_xyz_deg([30.0, 90.0, 10.0]),
            1e-9
        ));
    }

    /// `rotation_vector` inverts `axis_angle` for angles in (0, π], including the θ ≈ 0 and
    /// θ ≈ π branches (at π the axis sign is ambiguous: ±a·π are the same rotation).
    #[test]
    fn rotation_vector_inverts_axis_angle() {
        let axes = [
            [1.0, 0.0, 0.0],
            [0.0, 0.6, 0.8],
            [0.48, -0.6, 0.64],
            [-0.36, 0.48, 0.8],
        ];
        for a in axes {
            for theta in [1e-9, 1e-4, 0.3, 1.5, 3.0, std::f64::consts::PI - 1e-7] {
                let v = rotation_vector(&axis_angle(a, theta));
                let want = a.map(|c| c * theta);
                let err = (0..3).map(|k| (v[k] - want[k]).abs()).fold(0.0, f64::max);
                let err_flip = (0..3).map(|k| (v[k] + want[k]).abs()).fold(0.0, f64::max);
                let ok = err < 1e-9 || (theta > 3.1 && err_flip < 1e-6);
                assert!(ok, "axis {a:?} θ {theta}: got {v:?}, want {want:?}");
            }
        }
    }

    /// `J_l(v) δ` against `vee(log(exp([v+hδ]) exp([v−hδ])ᵀ))/2h` (central differences, error
    /// O(h²) ≈ 1e-8 here), on both sides of the series switch.
    #[test]
    fn left_jacobian_matches_finite_differences() {
        let d = [0.3, -0.5, 0.8];
        for v in [
            [0.0; 3],
            [2e-5, -1e-5, 3e-5],
            [0.4, 0.1, -0.7],
            [1.2, -2.0, 0.9],
        ] {
            let h = 1e-4;
            let p = from_rotation_vector([0, 1, 2].map(|k| v[k] + h * d[k]));
            let m = from_rotation_vector([0, 1, 2].map(|k| v[k] - h * d[k]));
            let mt = [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i]));
            let w = rotation_vector(&crate::geom::matmul(&p, &mt));
            let jd = crate::geom::matvec(&left_jacobian(v), d);
            for k in 0..3 {
                assert!(
                    (w[k] / (2.0 * h) - jd[k]).abs() < 1e-7,
                    "v {v:?}: FD {:?} vs J_l δ {jd:?}",
                    w.map(|x| x / (2.0 * h))
                );
            }
        }
    }

    #[test]
    fn rotation_vectors_round_trip_on_several_axes_near_zero_and_pi() {
        let axes = [[1.0, 0.0, 0.0], [0.3, -0.5, 0.8], [-0.2, 0.9, 0.1]];
        let angles = [
            0.0,
            1e-9,
            1e-5,
            0.3,
            1.5,
            2.5,
            3.1,
            std::f64::consts::PI - 1e-7,
        ];
        for a in axes {
            let n = norm(a);
            for th in angles {
                let v = [a[0] / n * th, a[1] / n * th, a[2] / n * th];
                let r = from_rotation_vector(v);
                let back = rotation_vector(&r);
                let r2 = from_rotation_vector(back);
                assert!(
                    frobenius_diff(&r, &r2) < 1e-12,
                    "θ = {th}: {v:?} → {back:?}"
                );
                if th < 3.0 {
                    assert!(norm(sub(back, v)) < 1e-9, "θ = {th}: {v:?} → {back:?}");
                }
            }
        }
    }
}
