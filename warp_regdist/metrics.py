"""Quality measures of distance fields and distance matrices (docs/method.md section 7).

Usable on the output of any method (this package, the heat method, exact geodesics):

- :func:`symmetry_error`: ``|D - D^T| / sqrt(A)`` of an (n, n) distance matrix.
- :func:`triangle_inequality_violations`: share of triplets with
  ``D[x, z] > D[x, y] + D[y, z]``, exact or sampled.
- :func:`smoothness`: residual of projecting a field onto the first k Laplace-Beltrami
  eigenvectors (lower = smoother).
"""

from __future__ import annotations

import numbers

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["symmetry_error", "triangle_inequality_violations", "smoothness", "EXACT_TRIPLET_LIMIT", "DENSE_EIGEN_VERTICES"]

EXACT_TRIPLET_LIMIT = 2e8
"""Largest n^3 that :func:`triangle_inequality_violations` counts exactly (n <= 584)."""

_CHUNK_ELEMENTS = 2**22
"""Entries of the (rows, n, n) block of sums D[x, y] + D[y, z] held at once (32 MiB)."""


def _square_matrix(distance):
    """Validated finite float64 (n, n) matrix."""
    D = np.asarray(distance, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or D.shape[0] == 0:
        raise ValueError(f"expected a square (n, n) distance matrix with n >= 1, got shape {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError(f"expected finite distances, got {np.count_nonzero(~np.isfinite(D))} non-finite entries")
    return D


def symmetry_error(distance, total_area):
    """Pointwise symmetry error of a distance matrix, the paper's measure.

    Parameters
    ----------
    distance : (n, n) array_like of float
        D[x, y] = distance from source x to point y (any orientation convention).
    total_area : float
        A > 0, the surface area (volume for solids); makes the error scale-invariant.

    Returns
    -------
    (n, n) ndarray
        ``|D[x, y] - D[y, x]| / sqrt(A)``: symmetric, zero diagonal.
    """
    D = _square_matrix(distance)
    if not isinstance(total_area, numbers.Real) or not np.isfinite(total_area) or total_area <= 0:
        raise ValueError(f"expected a finite total_area > 0, got {total_area!r}")
    return np.abs(D - D.T) / np.sqrt(float(total_area))


def _int_at_least(value, low, name):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"expected an integer {name} >= {low}, got {value!r}")
    return int(value)


def triangle_inequality_violations(distance, samples=None, tolerance=0.0, seed=0):
    """Share of ordered triplets (x, y, z) violating the triangle inequality.

    A triplet violates it when ``D[x, z] > D[x, y] + D[y, z] + tolerance``.  All n^3
    ordered triplets count, the degenerate ones (x = y or y = z, which never violate on a
    matrix with zero diagonal) included.

    Parameters
    ----------
    distance : (n, n) array_like of float
        D[x, y] = distance from x to y; need not be symmetric.
    samples : int, optional
        None: count exactly over all n^3 triplets (vectorized in blocks of
        ``_CHUNK_ELEMENTS`` sums, so memory stays bounded); refused with ValueError when
        n^3 > ``EXACT_TRIPLET_LIMIT`` (about 2e8, n > 584), since the count would take
        minutes: pass ``samples`` then.  An integer >= 1: estimate from that many triplets
        drawn uniformly with replacement (standard error sqrt(p (1 - p) / samples)).
    tolerance : float
        Slack >= 0 in the distance's units (e.g. a solver tolerance times the diameter).
    seed : int
        Seed of ``numpy.random.default_rng`` for the sampled estimate.

    Returns
    -------
    float
        Violating triplets / triplets considered, in [0, 1].
    """
    D = _square_matrix(distance)
    if not isinstance(tolerance, numbers.Real) or not np.isfinite(tolerance) or tolerance < 0:
        raise ValueError(f"expected a finite tolerance >= 0, got {tolerance!r}")
    n = D.shape[0]
    if samples is not None:
        samples = _int_at_least(samples, 1, "samples")
        x, y, z = np.random.default_rng(seed).integers(0, n, size=(3, samples))
        return float(np.count_nonzero(D[x, z] > D[x, y] + D[y, z] + tolerance)) / samples
    if float(n) ** 3 > EXACT_TRIPLET_LIMIT:
        raise ValueError(
            f"expected n^3 <= {EXACT_TRIPLET_LIMIT:.0e} triplets for the exact count, got n = {n} "
            f"(n^3 = {float(n) ** 3:.1e}); pass samples=10**6 for a sampled estimate")
    rows = max(1, _CHUNK_ELEMENTS // (n * n))
    violating = 0
    for start in range(0, n, rows):
        block = D[start:start + rows]                                   # D[x, y], (r, n)
        paths = block[:, :, None] + D[None, :, :] + tolerance           # D[x, y] + D[y, z], (r, n, n)
        violating += np.count_nonzero(block[:, None, :] > paths)        # D[x, z] broadcast over y
    return violating / float(n) ** 3


DENSE_EIGEN_VERTICES = 2000
"""Up to this many vertices :func:`smoothness` takes its eigenvectors from a dense eigendecomposition."""


def _low_eigenvectors(operators, area, k):
    """The k M-orthonormal generalized eigenvectors of W_D phi = lambda M phi with the smallest lambda (n, k).

    Dense (``scipy.linalg.eigh`` of M^(-1/2) W_D M^(-1/2)) up to ``DENSE_EIGEN_VERTICES`` vertices, which
    keeps every copy of a repeated eigenvalue (meshes with symmetries); above, ARPACK's shift-invert
    Lanczos just below the spectrum from a fixed start vector, the same basis on every call."""
    n = area.size
    if n <= DENSE_EIGEN_VERTICES:
        scale = 1.0 / np.sqrt(area)
        A = scale[:, None] * operators.stiffness.toarray() * scale[None, :]
        _, psi = scipy.linalg.eigh(A, subset_by_index=[0, k - 1])
        return scale[:, None] * psi
    sigma = -1e-2 / operators.total_volume ** (2.0 / (operators.basis.shape[1] - 1))   # W_D - sigma M > 0
    start = np.random.default_rng(0).standard_normal(n)
    _, phi = spla.eigsh(operators.stiffness.tocsc(), k=k, M=sp.diags(area).tocsc(), sigma=sigma, which="LM", v0=start)
    return phi


def smoothness(values, operators, k=50):
    """Relative residual of projecting field(s) onto the first k Laplace-Beltrami eigenvectors.

    With the generalized eigenpairs ``W_D phi_i = lambda_i M phi_i`` (M = diag(vertex
    areas), phi_i M-orthonormal, the k smallest lambda_i) and Phi = [phi_1 .. phi_k]:

        s(f) = || f - Phi Phi^T M f ||_M / || f ||_M,      ||g||_M^2 = g^T M g.

    0 for a field in the span (a constant, a low eigenvector), near 1 for noise; a
    smoother distance keeps more of its energy in the low frequencies, so lower = smoother.

    Parameters
    ----------
    values : (n,) or (n, c) array_like of float
        One field per column, finite and not identically zero.
    operators : Operators
        From :func:`warp_regdist.build_operators` (uses ``stiffness`` and ``vertex_volumes``).
    k : int
        Number of eigenvectors, 1 <= k < n (dense up to ``DENSE_EIGEN_VERTICES`` vertices, ARPACK above).

    Returns
    -------
    float or (c,) ndarray
        s(f) per field (a float for a 1-D input).
    """
    if not hasattr(operators, "stiffness") or not hasattr(operators, "vertex_volumes"):
        raise ValueError(f"expected warp_regdist.Operators, got {type(operators).__name__}")
    area = np.asarray(operators.vertex_volumes, dtype=np.float64)
    n = area.size
    F = np.asarray(values, dtype=np.float64)
    if F.ndim not in (1, 2) or F.shape[0] != n:
        raise ValueError(f"expected values of shape ({n},) or ({n}, c), got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError("expected finite values, got inf or nan")
    k = _int_at_least(k, 1, "k")
    if k >= n:
        raise ValueError(f"expected k < n = {n}, got {k}")
    G = F.reshape(n, -1)
    norms = np.sqrt(np.einsum("i,ic,ic->c", area, G, G))
    if np.any(norms == 0):
        raise ValueError("expected fields that are not identically zero, got a zero field")
    phi = _low_eigenvectors(operators, area, k)
    residual = G - phi @ (phi.T @ (area[:, None] * G))
    s = np.sqrt(np.einsum("i,ic,ic->c", area, residual, residual)) / norms
    return float(s[0]) if F.ndim == 1 else s
