//! Small fixed-size vector and 3×3 matrix helpers (row-major `[[f64;3];3]`).

/// 3-vector.
pub type V3 = [f64; 3];

/// The largest coordinate magnitude (metres) panoman accepts in fitting targets (keypoints,
/// handles, point clouds) and in meshes to render: 10 km. Anything beyond is almost surely
/// wrong data or wrong units (huge values also overflow the squared distances of the solvers).
pub const MAX_COORDINATE: f64 = 1e4;

/// Whether every coordinate of `p` is finite and at most [`MAX_COORDINATE`] in magnitude.
#[inline]
pub fn is_in_bounds(p: V3) -> bool {
    p.iter().all(|c| c.abs() <= MAX_COORDINATE)
}
/// 3×3 matrix, row-major: `m[r][c]`.
pub type M3 = [[f64; 3]; 3];

/// a − b
#[inline]
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
/// a + b
#[inline]
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
/// s·a
#[inline]
pub fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
/// a·b
#[inline]
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
/// a × b
#[inline]
pub fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// |a|
#[inline]
pub fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}
/// a/|a|
#[inline]
pub fn normalize(a: V3) -> V3 {
    scale(a, 1.0 / norm(a))
}
/// Identity matrix.
pub const IDENTITY: M3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
/// A·B
#[inline]
pub fn matmul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for r in 0..3 {
        for k in 0..3 {
            let a_rk = a[r][k];
            for col in 0..3 {
                c[r][col] += a_rk * b[k][col];
            }
        }
    }
    c
}
/// Aᵀ
#[inline]
pub fn transpose(a: &M3) -> M3 {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}
/// A·v
#[inline]
pub fn matvec(a: &M3, v: V3) -> V3 {
    [dot(a[0], v), dot(a[1], v), dot(a[2], v)]
}
/// Aᵀ·v
#[inline]
pub fn matvec_t(a: &M3, v: V3) -> V3 {
    [
        a[0][0] * v[0] + a[1][0] * v[1] + a[2][0] * v[2],
        a[0][1] * v[0] + a[1][1] * v[1] + a[2][1] * v[2],
        a[0][2] * v[0] + a[1][2] * v[1] + a[2][2] * v[2],
    ]
}
/// det A
#[inline]
pub fn det(a: &M3) -> f64 {
    dot(a[0], cross(a[1], a[2]))
}
/// Matrix whose columns are `c0, c1, c2`.
#[inline]
pub fn from_cols(c0: V3, c1: V3, c2: V3) -> M3 {
    [
        [c0[0], c1[0], c2[0]],
        [c0[1], c1[1], c2[1]],
        [c0[2], c1[2], c2[2]],
    ]
}
/// Frobenius norm of A − B.
pub fn frobenius_diff(a: &M3, b: &M3) -> f64 {
    let mut s = 0.0;
    for r in 0..3 {
        for c in 0..3 {
            let d = a[r][c] - b[r][c];
            s += d * d;
        }
    }
    s.sqrt()
}
