"""Sparse symmetric positive-definite solves with a reusable symbolic analysis.

:class:`SPDSolver` wraps CHOLMOD (scikit-sparse) when it is importable and
falls back to scipy's ``splu`` (COLAMD ordering) otherwise. The intended use
is an iterative method whose normal matrix keeps the same sparsity pattern
while its values change:

    solver = SPDSolver()
    solver.factor(A0)          # first call: symbolic analysis + numeric factor
    x = solver.solve(b)        # b (n,) or (n, k)
    solver.factor(A1)          # same pattern: numeric factorisation only

``solver.name`` says which backend ran ("cholmod" or "splu").
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

try:  # optional fast path (extra "fast")
    from sksparse.cholmod import analyze as _cholmod_analyze
    HAVE_CHOLMOD = True
except Exception:  # pragma: no cover - depends on the installation
    _cholmod_analyze = None
    HAVE_CHOLMOD = False


class SPDSolver:
    """Factor-and-solve for SPD matrices sharing one sparsity pattern.

    prefer: "auto" (CHOLMOD if available), "cholmod" or "splu".
    """

    def __init__(self, prefer: str = "auto"):
        use_cholmod = HAVE_CHOLMOD and prefer in ("auto", "cholmod")
        self.name = "cholmod" if use_cholmod else "splu"
        self._symbolic = None
        self._lu = None
        self.n_factorizations = 0
        self.n_solves = 0

    def factor(self, A: sp.spmatrix) -> None:
        """Numeric factorisation of A (n, n) SPD; the first call also runs the
        symbolic analysis (fill-reducing ordering), later calls reuse it."""
        A = sp.csc_matrix(A)
        if self.name == "cholmod":
            if self._symbolic is None:
                self._symbolic = _cholmod_analyze(A)
            self._symbolic.cholesky_inplace(A)
        else:
            from scipy.sparse.linalg import splu
            self._lu = splu(A, permc_spec="COLAMD")
        self.n_factorizations += 1

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve A x = b for b (n,) or (n, k) with the last factorised A."""
        self.n_solves += 1
        if self.name == "cholmod":
            return self._symbolic(b)
        return self._lu.solve(np.asarray(b, dtype=np.float64))
