//! Dense kernels on column-major slices (panels, Gram matrices, small Cholesky).

use super::*;

pub(super) fn panel_width(n: usize) -> usize {
    ((1usize << 21) / n.max(1)).clamp(16, 2048)
}

/// Converts columns `j0..j0+jb` of the f32 N×M matrix into the f64 panel buffer.
pub(super) fn load_panel(x: &[f32], n: usize, j0: usize, jb: usize, buf: &mut [f64]) {
    buf[..n * jb]
        .par_chunks_mut(n)
        .zip(x[j0 * n..(j0 + jb) * n].par_chunks(n))
        .for_each(|(b, s)| {
            for (bi, &si) in b.iter_mut().zip(s) {
                *bi = si as f64;
            }
        });
}

/// out (K×M) = Wᵀ·X, with X f32 N×M converted to f64 panel by panel.
pub(super) fn wt_x(
    x: &[f32],
    n: usize,
    m: usize,
    w: &[f64],
    k: usize,
    out: &mut [f64],
    buf: &mut Vec<f64>,
) {
    let nb = panel_width(n).min(m.max(1));
    buf.resize(n * nb, 0.0);
    let wv = MatRef::from_column_major_slice(w, n, k);
    for j0 in (0..m).step_by(nb) {
        let jb = nb.min(m - j0);
        load_panel(x, n, j0, jb, buf);
        let xp = MatRef::from_column_major_slice(&buf[..n * jb], n, jb);
        let dst = MatMut::from_column_major_slice_mut(&mut out[j0 * k..(j0 + jb) * k], k, jb);
        matmul(dst, Accum::Replace, wv.transpose(), xp, 1.0, Par::rayon(0));
    }
}

/// out (N×K) = X·Cᵀ, accumulated over panels of X in a fixed order.
pub(super) fn x_ct(
    x: &[f32],
    n: usize,
    m: usize,
    c: &[f64],
    k: usize,
    out: &mut [f64],
    buf: &mut Vec<f64>,
) {
    let nb = panel_width(n).min(m.max(1));
    buf.resize(n * nb, 0.0);
    out.fill(0.0);
    for j0 in (0..m).step_by(nb) {
        let jb = nb.min(m - j0);
        load_panel(x, n, j0, jb, buf);
        let xp = MatRef::from_column_major_slice(&buf[..n * jb], n, jb);
        let cp = MatRef::from_column_major_slice(&c[j0 * k..(j0 + jb) * k], k, jb);
        let dst = MatMut::from_column_major_slice_mut(out, n, k);
        let acc = if j0 == 0 { Accum::Replace } else { Accum::Add };
        matmul(dst, acc, xp, cp.transpose(), 1.0, Par::rayon(0));
    }
}

/// out[e] = X[:,e]ᵀ·v in f64 (GEMV over the f32 data, 4 accumulators, fixed order).
pub(super) fn xt_vec(x: &[f32], n: usize, v: &[f64], out: &mut [f64]) {
    out.par_chunks_mut(64).enumerate().for_each(|(ci, oc)| {
        for (jj, o) in oc.iter_mut().enumerate() {
            let j = ci * 64 + jj;
            let col = &x[j * n..(j + 1) * n];
            let mut acc = [0.0f64; 4];
            let mut it = col.chunks_exact(4).zip(v.chunks_exact(4));
            for (cx, cv) in &mut it {
                acc[0] += cx[0] as f64 * cv[0];
                acc[1] += cx[1] as f64 * cv[1];
                acc[2] += cx[2] as f64 * cv[2];
                acc[3] += cx[3] as f64 * cv[3];
            }
            let r = n - n % 4;
            let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
            for i in r..n {
                s += col[i] as f64 * v[i];
            }
            *o = s;
        }
    });
}

/// AᵀA (cols×cols) of a column-major rows×cols matrix.
pub(super) fn gram_of_cols(a: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut g = vec![0.0; cols * cols];
    let av = MatRef::from_column_major_slice(a, rows, cols);
    matmul(
        MatMut::from_column_major_slice_mut(&mut g, cols, cols),
        Accum::Replace,
        av.transpose(),
        av,
        1.0,
        Par::rayon(0),
    );
    g
}

/// C·Cᵀ (K×K) of a column-major K×M matrix.
pub(super) fn gram_of_rows(c: &[f64], k: usize, m: usize) -> Vec<f64> {
    let mut g = vec![0.0; k * k];
    let cv = MatRef::from_column_major_slice(c, k, m);
    matmul(
        MatMut::from_column_major_slice_mut(&mut g, k, k),
        Accum::Replace,
        cv,
        cv.transpose(),
        1.0,
        Par::rayon(0),
    );
    g
}

/// Σ_i a_i·b_i over two equally long slices, in fixed chunks summed in order.
pub(super) fn dot_chunked(a: &[f64], b: &[f64]) -> f64 {
    const CH: usize = 1 << 14;
    a.par_chunks(CH)
        .zip(b.par_chunks(CH))
        .map(|(x, y)| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

/// Per component k, Σ_e Λ_{k,e}|C_{k,e}| (K×M column-major inputs).
pub(super) fn penalties(lam: &[f64], c: &[f64], k: usize) -> Vec<f64> {
    let parts: Vec<Vec<f64>> = lam
        .par_chunks(COL_CHUNK * k)
        .zip(c.par_chunks(COL_CHUNK * k))
        .map(|(l, cc)| {
            let mut acc = vec![0.0f64; k];
            for (lc, ccol) in l.chunks_exact(k).zip(cc.chunks_exact(k)) {
                for ((a, &li), &ci) in acc.iter_mut().zip(lc).zip(ccol) {
                    *a += li * ci.abs();
                }
            }
            acc
        })
        .collect();
    let mut out = vec![0.0f64; k];
    for p in parts {
        for (o, v) in out.iter_mut().zip(p) {
            *o += v;
        }
    }
    out
}

/// ½‖X‖² − ⟨W, P⟩ + ½⟨WᵀW, G⟩ (the fit term of docs/design/splocs-model.md §3.8 without the residual).
pub(super) fn fit_from_p(x_sq: f64, w: &[f64], p: &[f64], a0: &[f64], g: &[f64]) -> f64 {
    let wp: f64 = w.iter().zip(p).map(|(a, b)| a * b).sum();
    let ag: f64 = a0.iter().zip(g).map(|(a, b)| a * b).sum();
    0.5 * x_sq - wp + 0.5 * ag
}

/// Lower Cholesky factor (row-major n×n) of the symmetric matrix whose lower triangle is
/// read from the column-major `a`. Err(i) if the i-th pivot is not positive.
pub(super) fn cholesky(a: &[f64], n: usize) -> std::result::Result<Vec<f64>, usize> {
    let mut l = vec![0.0f64; n * n];
    for i in 0..n {
        for j in 0..=i {
            // a is column-major: A[i,j] = a[j*n + i] with i ≥ j (lower triangle).
            let mut s = a[j * n + i];
            for t in 0..j {
                s -= l[i * n + t] * l[j * n + t];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 || !s.is_finite() {
                    return Err(i);
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    Ok(l)
}

/// Solves L·Lᵀ·x = b in place (L row-major lower from [`cholesky`]).
pub(super) fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for t in 0..i {
            s -= l[i * n + t] * b[t];
        }
        b[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for t in i + 1..n {
            s -= l[t * n + i] * b[t];
        }
        b[i] = s / l[i * n + i];
    }
}

/// Inverse (column-major, symmetric) of the SPD matrix with Cholesky factor `l`.
pub(super) fn cholesky_inverse(l: &[f64], n: usize) -> Vec<f64> {
    let mut inv = vec![0.0f64; n * n];
    let mut col = vec![0.0f64; n];
    for j in 0..n {
        col.fill(0.0);
        col[j] = 1.0;
        cholesky_solve(l, n, &mut col);
        inv[j * n..(j + 1) * n].copy_from_slice(&col);
    }
    // Exact symmetry (the two triangles can differ in the last bit).
    for j in 0..n {
        for i in j + 1..n {
            let v = 0.5 * (inv[j * n + i] + inv[i * n + j]);
            inv[j * n + i] = v;
            inv[i * n + j] = v;
        }
    }
    inv
}

/// Objective of docs/design/splocs-model.md §3.1 without forming the residual (docs/design/splocs-model.md §3.8):
/// `½(‖X‖² − 2⟨W, X·Cᵀ⟩ + ⟨WᵀW, C·Cᵀ⟩) + Σ Λ|C|`.
///
/// `x`: N×M f32, `w`: N×K f64, `c` and `lam`: K×M f64, all column-major. Products with X are
/// computed in f64 (panel conversion), so the value agrees with the explicit residual to f64
/// rounding.
///
/// Panics on inconsistent slice lengths.
pub fn objective_residual_free(
    x: &[f32],
    n: usize,
    m: usize,
    w: &[f64],
    c: &[f64],
    lam: &[f64],
    k: usize,
) -> ObjectiveParts {
    assert_eq!(x.len(), n * m);
    assert_eq!(w.len(), n * k);
    assert_eq!(c.len(), k * m);
    assert_eq!(lam.len(), k * m);
    let x_sq: f64 = x
        .par_chunks(1 << 16)
        .map(|ch| ch.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    let mut p = vec![0.0; n * k];
    let mut buf = Vec::new();
    x_ct(x, n, m, c, k, &mut p, &mut buf);
    let a0 = gram_of_cols(w, n, k);
    let g = gram_of_rows(c, k, m);
    let fit = fit_from_p(x_sq, w, &p, &a0, &g);
    let penalty: f64 = penalties(lam, c, k).iter().sum();
    ObjectiveParts {
        fit,
        penalty,
        total: fit + penalty,
    }
}
