//! Deterministic parallel GEMM on faer: `dst ← [dst +] α·lhs·rhs` with a **fixed chunking**.
//!
//! The product is cut into blocks whose count and size depend only on the shape `(m, n, k)`,
//! never on the number of rayon threads ([`Plan`]): row or column blocks of the output, each one
//! sequential faer GEMM over the whole inner dimension, or — for very deep products — blocks of
//! the inner dimension whose partial products are summed in block order. Either way every
//! output entry is computed by the same sequence of floating-point operations whatever thread
//! runs which block, so results are bit-identical for any pool size (docs/design/splocs-model.md §3.9).
//! Throughput on this 2-core box matches faer's own `Par::rayon(0)` for the MLP shapes.

use faer::linalg::matmul::matmul;
use faer::traits::ComplexField;
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Below this many multiply-adds a product runs as one sequential call.
const MIN_SPLIT_WORK: usize = 1 << 19;
/// Target multiply-adds per block.
const WORK_PER_BLOCK: usize = 1 << 21;
/// Upper bound on the number of blocks.
const MAX_BLOCKS: usize = 8;
/// Block sizes are multiples of this, and no block (but the last) is smaller.
const ALIGN: usize = 64;
/// Depth blocks are multiples of this.
const DEPTH_ALIGN: usize = 1024;

/// How a product of shape `(m, n, k)` is cut; a function of the shape only.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Plan {
    /// One sequential call.
    Seq,
    /// Row blocks of `dst` of this height.
    Rows(usize),
    /// Column blocks of `dst` of this width.
    Cols(usize),
    /// Blocks of the inner dimension of this length, each product into its own buffer, then
    /// summed into `dst` in block order (for deep, small products such as `Ỹ_b Ω` of the PCA
    /// head, where cutting `dst` would re-pack the huge shared operand once per block).
    Depth(usize),
}

/// The fixed block plan of a product of shape `(m, n, k)`.
pub(crate) fn plan(m: usize, n: usize, k: usize) -> Plan {
    let work = m.saturating_mul(n).saturating_mul(k);
    let nblocks = (work / WORK_PER_BLOCK).clamp(1, MAX_BLOCKS);
    if work < MIN_SPLIT_WORK || nblocks <= 1 {
        return Plan::Seq;
    }
    if k >= 16 * m.max(n) {
        let nb = nblocks.min(k.div_ceil(DEPTH_ALIGN));
        if nb > 1 {
            return Plan::Depth(k.div_ceil(nb).next_multiple_of(DEPTH_ALIGN));
        }
    }
    let dim = m.max(n);
    let nb = nblocks.min(dim.div_ceil(ALIGN));
    if nb <= 1 {
        return Plan::Seq;
    }
    let block = dim.div_ceil(nb).next_multiple_of(ALIGN);
    if m >= n {
        Plan::Rows(block)
    } else {
        Plan::Cols(block)
    }
}

/// `dst ← α·lhs·rhs` (`Accum::Replace`) or `dst ← dst + α·lhs·rhs` (`Accum::Add`), with the fixed
/// block plan of [`plan`]; bit-identical for any rayon pool size.
pub(crate) fn gemm<T>(
    dst: MatMut<'_, T>,
    accum: Accum,
    lhs: MatRef<'_, T>,
    rhs: MatRef<'_, T>,
    alpha: T,
) where
    T: ComplexField + Copy + Send + Sync,
{
    let (m, n, k) = (dst.nrows(), dst.ncols(), lhs.ncols());
    debug_assert_eq!(lhs.nrows(), m);
    debug_assert_eq!(rhs.nrows(), k);
    debug_assert_eq!(rhs.ncols(), n);
    let (split_rows, block) = match plan(m, n, k) {
        Plan::Seq => {
            matmul(dst, accum, lhs, rhs, alpha, Par::Seq);
            return;
        }
        Plan::Depth(block) => {
            let starts: Vec<usize> = (0..k).step_by(block).collect();
            let partials: Vec<Mat<T>> = starts
                .into_par_iter()
                .map(|s| {
                    let len = block.min(k - s);
                    let mut p = Mat::<T>::zeros(m, n);
                    matmul(
                        p.as_mut(),
                        Accum::Replace,
                        lhs.subcols(s, len),
                        rhs.subrows(s, len),
                        alpha,
                        Par::Seq,
                    );
                    p
                })
                .collect();
            let mut dst = dst;
            let mut parts = partials.iter();
            if accum == Accum::Replace
                && let Some(first) = parts.next()
            {
                dst.copy_from(first);
            }
            for p in parts {
                dst += p;
            }
            return;
        }
        Plan::Rows(b) => (true, b),
        Plan::Cols(b) => (false, b),
    };
    let dim = if split_rows { m } else { n };
    let mut parts = Vec::with_capacity(dim.div_ceil(block));
    let mut rest = dst;
    let mut start = 0;
    while start < dim {
        let len = block.min(dim - start);
        let (head, tail) = if split_rows {
            rest.split_at_row_mut(len)
        } else {
            rest.split_at_col_mut(len)
        };
        parts.push((start, len, head));
        rest = tail;
        start += len;
    }
    parts.into_par_iter().for_each(|(start, len, d)| {
        if split_rows {
            matmul(d, accum, lhs.subrows(start, len), rhs, alpha, Par::Seq);
        } else {
            matmul(d, accum, lhs, rhs.subcols(start, len), alpha, Par::Seq);
        }
    });
}

/// Column-major view of the first `rows·cols` entries of a buffer.
pub(crate) fn view(buf: &[f32], rows: usize, cols: usize) -> MatRef<'_, f32> {
    MatRef::from_column_major_slice(&buf[..rows * cols], rows, cols)
}

/// Mutable column-major view of the first `rows·cols` entries of a buffer.
pub(crate) fn view_mut(buf: &mut [f32], rows: usize, cols: usize) -> MatMut<'_, f32> {
    MatMut::from_column_major_slice_mut(&mut buf[..rows * cols], rows, cols)
}
