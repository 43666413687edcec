//! Deterministic parallel GEMM on faer: `dst ← [dst +] α·lhs·rhs` with a **fixed chunking**.
//!
//! The output is cut into row blocks (when `m ≥ n`) or column blocks, whose count and size
//! depend only on the shape `(m, n, k)`, never on the number of rayon threads. Each block is one
//! sequential faer GEMM over the **whole** inner dimension `k`, so no sum is ever split between
//! threads: the result is bit-identical whatever the thread count (algorithms.md §6 item 15).
//! Throughput on this 2-core box matches faer's own `Par::rayon(0)` for the MLP shapes.

use faer::linalg::matmul::matmul;
use faer::traits::ComplexField;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Below this many multiply-adds a product runs as one sequential call.
const MIN_SPLIT_WORK: usize = 1 << 19;
/// Target multiply-adds per block.
const WORK_PER_BLOCK: usize = 1 << 21;
/// Upper bound on the number of blocks.
const MAX_BLOCKS: usize = 16;
/// Block sizes are multiples of this (SIMD/microkernel friendly).
const ALIGN: usize = 16;

/// The fixed block plan of a product of shape `(m, n, k)`: `(split_rows, block)`; `block == 0`
/// means "one sequential call".
pub(crate) fn plan(m: usize, n: usize, k: usize) -> (bool, usize) {
    let work = m.saturating_mul(n).saturating_mul(k);
    let split_rows = m >= n;
    let dim = if split_rows { m } else { n };
    let nblocks = (work / WORK_PER_BLOCK)
        .clamp(1, MAX_BLOCKS)
        .min(dim.div_ceil(ALIGN));
    if work < MIN_SPLIT_WORK || nblocks <= 1 {
        return (split_rows, 0);
    }
    (split_rows, dim.div_ceil(nblocks).next_multiple_of(ALIGN))
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
    let (split_rows, block) = plan(m, n, k);
    if block == 0 {
        matmul(dst, accum, lhs, rhs, alpha, Par::Seq);
        return;
    }
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
