"""MKL PARDISO's Cholesky through ctypes (warp_regdist/linalg/pardiso.py): solves against dense
ones, its refusals; skipped where MKL is not installed (the [pardiso] extra, x86-64 only)."""

import numpy as np
import pytest
import scipy.sparse as sp

from warp_regdist.linalg.pardiso import PardisoCholesky, PardisoError, load_mkl

try:
    load_mkl()
except OSError:
    pytest.skip("MKL not installed (pip install 'warp-regdist[pardiso]')", allow_module_level=True)


def spd(n=300, seed=0):
    """A sparse SPD matrix with condition ~1e6: a random graph Laplacian plus a small shift."""
    rng = np.random.default_rng(seed)
    B = sp.random(n, n, density=5.0 / n, random_state=rng)
    L = sp.csgraph.laplacian((B + B.T).tocsr())
    return (L + 1e-6 * sp.eye(n) * abs(L).max()).tocsr()


@pytest.mark.parametrize("triangle", ["both", "upper"])
def test_solves_match_dense(triangle):
    A = spd()
    rng = np.random.default_rng(1)
    b = rng.standard_normal(A.shape[0])
    x = PardisoCholesky(A if triangle == "both" else sp.triu(A)).solve(b)
    exact = np.linalg.solve(A.toarray(), b)
    assert np.abs(x - exact).max() <= 1e-6 * np.abs(exact).max()


def test_indefinite_matrix_is_refused():
    A = spd() - 0.5 * sp.eye(300) * abs(spd()).max()
    with pytest.raises(PardisoError, match="expected PARDISO phase 12 to succeed, got error -4"):
        PardisoCholesky(A)


def test_released_factor_refuses_to_solve():
    c = PardisoCholesky(spd())
    c.release()
    c.release()
    with pytest.raises(RuntimeError, match="expected a PardisoCholesky not yet released, got a released one"):
        c.solve(np.ones(300))


def test_refactor_reuses_the_pattern_and_follows_a_new_one():
    """A second matrix on the same pattern (numerical phase only), then one on another pattern (a
    new analysis): each solve matches the dense one, and ``generation`` counts the factorizations."""
    A = spd()
    b = np.random.default_rng(2).standard_normal(300)
    c = PardisoCholesky(A)
    for B in (A + sp.diags(np.linspace(1.0, 2.0, 300)), spd(seed=5)):
        c.refactor(B)
        exact = np.linalg.solve(B.toarray(), b)
        assert np.abs(c.solve(b) - exact).max() <= 1e-6 * np.abs(exact).max()
    assert c.generation == 2
    with pytest.raises(PardisoError, match="got error -4"):
        c.refactor(A - 0.5 * sp.eye(300) * abs(A).max())
    with pytest.raises(RuntimeError, match="got a released one"):
        c.solve(b)
