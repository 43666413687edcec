//! Sparse symmetric positive-definite (and quasi-definite) solves with faer: symbolic factorization once per sparsity
//! pattern, numeric factorization per matrix, allocation-free solves with caller-owned scratch.

use crate::error::{MeshError, Result};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LdltRef, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, SparseColMatRef, SymbolicSparseColMatRef, Triplet};
use faer::{Conj, MatMut, Par, Side};

/// Cholesky factor `A = L Lᵀ` of a sparse SPD matrix, or `L D Lᵀ` of a quasi-definite one
/// (AMD ordering, supernodal or simplicial as faer decides). Keeps the symbolic analysis so that [`SpdFactor::refactor`] only redoes the
/// numeric step for a new matrix with the same pattern.
pub struct SpdFactor {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    n: usize,
    /// `L D Lᵀ` of a quasi-definite matrix instead of `L Lᵀ` (see
    /// [`SpdFactor::symbolic_only_quasi_definite`]).
    ldlt: bool,
}

impl std::fmt::Debug for SpdFactor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SpdFactor {{ n: {}, nnz(L): {} }}",
            self.n,
            self.values.len()
        )
    }
}

impl SpdFactor {
    /// Builds the lower-triangular CSC matrix from `(row, col, value)` triplets (duplicates are
    /// summed; entries above the diagonal are ignored) and factors it.
    pub fn from_triplets(n: usize, triplets: &[(usize, usize, f64)]) -> Result<Self> {
        let a = lower_csc(n, triplets)?;
        Self::new(&a)
    }

    /// [`SpdFactor::from_triplets`] with the layout choice of [`SpdFactor::with_layout`].
    pub fn from_triplets_with_layout(
        n: usize,
        triplets: &[(usize, usize, f64)],
        simplicial: bool,
    ) -> Result<Self> {
        let a = lower_csc(n, triplets)?;
        Self::with_layout(&a, simplicial)
    }

    /// Symbolic + numeric factorization of `a` (its lower triangle is read); faer chooses
    /// supernodal or simplicial storage.
    pub fn new(a: &SparseColMat<usize, f64>) -> Result<Self> {
        Self::with_layout(a, false)
    }

    /// Like [`SpdFactor::new`]; `simplicial = true` forces the simplicial layout, whose
    /// triangular solves are 2–3× faster on small, very sparse matrices (Laplacians of a few
    /// 10k unknowns) where many solves follow one factorization.
    pub fn with_layout(a: &SparseColMat<usize, f64>, simplicial: bool) -> Result<Self> {
        let n = a.nrows();
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: if simplicial {
                SupernodalThreshold::FORCE_SIMPLICIAL
            } else {
                SupernodalThreshold::AUTO
            },
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(a.symbolic(), Side::Lower, SymmetricOrdering::Amd, params)
                .map_err(|e| MeshError::Numerical(format!("symbolic Cholesky failed: {e:?}")))?;
        let mut this = Self {
            values: vec![0.0; symbolic.len_val()],
            symbolic,
            n,
            ldlt: false,
        };
        this.refactor(a)?;
        Ok(this)
    }

    /// Numeric refactorization of a matrix with the same pattern as the one given at creation.
    pub fn refactor(&mut self, a: &SparseColMat<usize, f64>) -> Result<()> {
        let par = Par::Seq;
        let mut mem = MemBuffer::new(self.refactor_scratch(par));
        self.refactor_ref(a.as_ref(), par, &mut mem)
    }

    /// Symbolic analysis (AMD ordering, faer's supernodal/simplicial choice) of the lower
    /// triangle pattern `a`, without a numeric factorization: call
    /// [`SpdFactor::refactor_ref`] before solving. Used when the pattern is built once and the
    /// values are assembled into a caller-owned array (docs/design/shell-fit.md §3.3, scatter map).
    pub fn symbolic_only(a: SymbolicSparseColMatRef<'_, usize>) -> Result<Self> {
        let n = a.nrows();
        let symbolic =
            factorize_symbolic_cholesky(a, Side::Lower, SymmetricOrdering::Amd, Default::default())
                .map_err(|e| MeshError::Numerical(format!("symbolic Cholesky failed: {e:?}")))?;
        Ok(Self {
            values: vec![0.0; symbolic.len_val()],
            symbolic,
            n,
            ldlt: false,
        })
    }

    /// As [`SpdFactor::symbolic_only`], for symmetric *quasi-definite* matrices
    /// `[A Bᵀ; B −C]` with A and C positive definite (regularised KKT systems): the numeric
    /// step is then `L D Lᵀ` without pivoting, which exists for every symmetric ordering
    /// (Vanderbei 1995).
    pub fn symbolic_only_quasi_definite(a: SymbolicSparseColMatRef<'_, usize>) -> Result<Self> {
        let mut this = Self::symbolic_only(a)?;
        this.ldlt = true;
        Ok(this)
    }

    /// Scratch needed by [`SpdFactor::refactor_ref`] with parallelism `par`.
    pub fn refactor_scratch(&self, par: Par) -> StackReq {
        if self.ldlt {
            self.symbolic
                .factorize_numeric_ldlt_scratch::<f64>(par, Default::default())
        } else {
            self.symbolic
                .factorize_numeric_llt_scratch::<f64>(par, Default::default())
        }
    }

    /// [`SpdFactor::refactor_ref`] on the rayon pool (`parallel`) or sequentially, with the
    /// scratch kept in `scratch` (allocated on first use and whenever `parallel` changes).
    pub fn refactor_cached(
        &mut self,
        a: SparseColMatRef<'_, usize, f64>,
        parallel: bool,
        scratch: &mut Option<(bool, MemBuffer)>,
    ) -> Result<()> {
        let par = if parallel { Par::rayon(0) } else { Par::Seq };
        if scratch.as_ref().map(|s| s.0) != Some(parallel) {
            *scratch = Some((parallel, MemBuffer::new(self.refactor_scratch(par))));
        }
        let buf = &mut scratch.as_mut().expect("set above").1;
        self.refactor_ref(a, par, buf)
    }

    /// Numeric refactorization of a borrowed matrix with the pattern analysed at creation, using
    /// caller-owned scratch (sized by [`SpdFactor::refactor_scratch`] for the same `par`): no
    /// allocation. Fails if the matrix is not numerically positive definite.
    pub fn refactor_ref(
        &mut self,
        a: SparseColMatRef<'_, usize, f64>,
        par: Par,
        scratch: &mut MemBuffer,
    ) -> Result<()> {
        if self.ldlt {
            self.symbolic
                .factorize_numeric_ldlt(
                    &mut self.values,
                    a,
                    Side::Lower,
                    LdltRegularization::default(),
                    par,
                    MemStack::new(scratch),
                    Default::default(),
                )
                .map_err(|e| MeshError::Numerical(format!("LDLᵀ factorization failed: {e:?}")))?;
        } else {
            self.symbolic
                .factorize_numeric_llt(
                    &mut self.values,
                    a,
                    Side::Lower,
                    LltRegularization::default(),
                    par,
                    MemStack::new(scratch),
                    Default::default(),
                )
                .map_err(|e| {
                    MeshError::Numerical(format!("matrix is not positive definite: {e:?}"))
                })?;
        }
        Ok(())
    }

    /// Dimension n.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Scratch needed by [`SpdFactor::solve_in_place`] for `ncols` right-hand sides.
    pub fn solve_scratch(&self, ncols: usize) -> StackReq {
        self.symbolic.solve_in_place_scratch::<f64>(ncols, Par::Seq)
    }

    /// Allocates a scratch buffer for `ncols` right-hand sides.
    pub fn make_scratch(&self, ncols: usize) -> MemBuffer {
        MemBuffer::new(self.solve_scratch(ncols))
    }

    /// Solves `A X = B` in place (`rhs` holds B on entry, X on exit), sequentially, using the
    /// caller's scratch (no allocation).
    pub fn solve_in_place(&self, rhs: MatMut<'_, f64>, scratch: &mut MemBuffer) {
        let stack = MemStack::new(scratch);
        if self.ldlt {
            LdltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
                Conj::No,
                rhs,
                Par::Seq,
                stack,
            );
        } else {
            LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
                Conj::No,
                rhs,
                Par::Seq,
                stack,
            );
        }
    }
}

/// Lower-triangular CSC matrix from triplets (duplicates summed, upper entries dropped).
pub fn lower_csc(n: usize, triplets: &[(usize, usize, f64)]) -> Result<SparseColMat<usize, f64>> {
    let trips: Vec<Triplet<usize, usize, f64>> = triplets
        .iter()
        .filter(|&&(r, c, _)| r >= c)
        .map(|&(r, c, v)| Triplet::new(r, c, v))
        .collect();
    SparseColMat::try_new_from_triplets(n, n, &trips)
        .map_err(|e| MeshError::Numerical(format!("sparse assembly failed: {e:?}")))
}
