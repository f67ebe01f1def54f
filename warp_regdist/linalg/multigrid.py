"""Smoothed-aggregation algebraic multigrid: the hierarchy (host-side setup, scipy) and its
V-cycle as a PCG preconditioner on a Warp device (:class:`MultigridPreconditioner`).

The preconditioner of the u-step is one symmetric V-cycle for the stiffness matrix
A_0 = W_D, built once per matrix. Level l has the Galerkin operator A_l, its diagonal
D_l, an aggregation-based prolongator P_l and the damped-Jacobi weight
w_l = (4/3) / rho(D_l^-1 A_l):

    P_l     = (I - w_l D_l^-1 A_l) T_l                    (T_l: tentative, one column per aggregate)
    A_l+1   = P_l^T A_l P_l

The aggregates are the strong neighbourhoods (|a_ij| >= theta max_k |a_ik|) of a
distance-2 maximal independent set, chosen in vectorized rounds (no Python loop over
vertices): about 10 vertices each, so a level has ~1/10 of the unknowns of the previous
one and the sparse levels together hold ~1.2 nnz(A_0).

A V(1,1)-cycle with one Jacobi sweep before and after the coarse correction is, written
out, the symmetric recursion

    M_l = S_l + R_l^T M_l+1 R_l,    S_l = 2 w_l D_l^-1 - w_l^2 D_l^-1 A_l D_l^-1,
                                    R_l = P_l^T (I - w_l A_l D_l^-1),
    M_L = A_L^+                     (dense pseudo-inverse on the coarsest level),

so applying M_0 takes one sparse product per level on the way down (R_l) and one fused
pair per level on the way up (S_l and R_l^T): SpMV-only kernels, no triangular solves,
the same on CPU and CUDA. S_l is positive definite (w_l rho < 2) on the rows with a
nonzero diagonal, hence M_0 is, and mask M_0 mask is a valid CG preconditioner for every
column's mask (rows with a zero diagonal, vertices no element references, are never
free). The pseudo-inverse
ignores the constants (the kernel of W_D on each connected component) instead of
inflating them, which keeps float32 applications accurate.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
import warp as wp

from ..kernels.lanes import lane_type, row_dim, thread_span
from ..kernels.multigrid import multigrid_kernels
from .csr import csr_arrays

__all__ = ["Hierarchy", "MultigridPreconditioner", "prolongator", "smoothed_aggregation"]


@dataclasses.dataclass(frozen=True)
class Hierarchy:
    """A symmetric V-cycle  M_l = S_l + R_l^T M_l+1 R_l,  M_L = A_L^+  (see the module docstring).

    Attributes
    ----------
    smoothers : list of (n_l, n_l) scipy.sparse.csr_matrix
        S_l, the symmetrized Jacobi smoother of each level but the coarsest.
    restrictions : list of (n_l+1, n_l) scipy.sparse.csr_matrix
        R_l = P_l^T (I - w_l A_l D_l^-1).
    coarse_inverse : (n_L, n_L) ndarray
        Dense pseudo-inverse of the coarsest operator A_L.
    """

    smoothers: list
    restrictions: list
    coarse_inverse: np.ndarray

    @property
    def sizes(self):
        """Unknowns per level, finest first."""
        return [S.shape[0] for S in self.smoothers] + [self.coarse_inverse.shape[0]]

    def apply(self, r):
        """z = M_0 r on the host, for (n,) or (n, k) arrays (a reference for the kernels)."""
        ys = [np.asarray(r, dtype=np.float64)]
        for R in self.restrictions:
            ys.append(R @ ys[-1])
        z = self.coarse_inverse @ ys[-1]
        for S, R, y in zip(reversed(self.smoothers), reversed(self.restrictions), reversed(ys[:-1])):
            z = S @ y + R.T @ z
        return z


def _row_max(S, values):
    """max over the stored entries of each row of S of ``values[column]`` (rows must be non-empty)."""
    return np.maximum.reduceat(values[S.indices], S.indptr[:-1])


def _strength(A, theta, active):
    """Strong-connection pattern with self loops on the active rows.

    j is a strong neighbour of i when |a_ij| >= theta max_k!=i |a_ik| or the same holds
    from j's side (symmetrized, so every active row keeps its strongest neighbour).
    """
    C = A.tocoo()
    off = (C.row != C.col) & active[C.row] & active[C.col]
    row, col, mag = C.row[off], C.col[off], np.abs(C.data[off])
    rmax = np.zeros(A.shape[0])
    np.maximum.at(rmax, row, mag)
    keep = (mag >= theta * rmax[row]) | (mag >= theta * rmax[col])
    diag = np.flatnonzero(active)
    n = A.shape[0]
    S = sp.csr_matrix((np.ones(keep.sum() + diag.size), (np.concatenate([row[keep], diag]),
                                                          np.concatenate([col[keep], diag]))), shape=(n, n))
    S.sum_duplicates()
    return S


def _aggregate(S, active, rng):
    """Aggregates of a distance-2 maximal independent set of the strength graph.

    Roots are chosen in parallel rounds (a vertex whose random weight is the largest within
    two hops among the undecided ones); each root takes its neighbours, and the remaining
    vertices join a neighbouring aggregate. Returns agg (n,) with -1 on inactive rows.
    """
    n = S.shape[0]
    if not active.any():
        return np.full(n, -1)
    S = S[active][:, active].tocsr()
    m = S.shape[0]
    weight = rng.permutation(m).astype(np.float64)
    undecided = np.ones(m, dtype=bool)
    root = np.zeros(m, dtype=bool)
    while undecided.any():
        w = np.where(undecided, weight, -1.0)
        new = undecided & (w == _row_max(S, _row_max(S, w)))
        root |= new
        undecided &= _row_max(S, _row_max(S, new.astype(np.float64))) == 0
    agg = np.full(m, -1)
    agg[root] = np.arange(root.sum())
    owner = np.zeros(m, dtype=np.int64)
    owner[weight[root].astype(np.int64)] = agg[root]
    best = _row_max(S, np.where(root, weight, -1.0))
    join = (agg < 0) & (best >= 0)
    agg[join] = owner[best[join].astype(np.int64)]
    while (agg < 0).any():
        near = _row_max(S, agg.astype(np.float64)).astype(np.int64)
        agg = np.where(agg < 0, near, agg)
    out = np.full(n, -1)
    out[active] = agg
    return out


def _spectral_radius(A, dinv, steps=12):
    """rho(D^-1 A) = largest eigenvalue of D^-1/2 A D^-1/2, from a short Lanczos run.

    The largest Ritz value after 12 steps is within a few percent below rho; 5% is added
    (the smoother stays positive definite for any estimate above 2/3 rho).
    """
    s = np.sqrt(dinv)
    v = np.random.default_rng(0).standard_normal(A.shape[0]) * (s > 0)
    v_prev = np.zeros_like(v)
    alpha, beta = [], [0.0]
    v /= np.linalg.norm(v)
    for _ in range(min(steps, A.shape[0])):
        w = s * (A @ (s * v)) - beta[-1] * v_prev
        alpha.append(w @ v)
        w -= alpha[-1] * v
        b = np.linalg.norm(w)
        if b <= 1e-12 * abs(alpha[-1]):
            break
        beta.append(b)
        v_prev, v = v, w / b
    T = np.diag(alpha) + np.diag(beta[1:len(alpha)], 1) + np.diag(beta[1:len(alpha)], -1)
    return 1.05 * float(np.linalg.eigvalsh(T)[-1])


def _pseudo_inverse(A):
    """Dense symmetric pseudo-inverse, eigenvalues below 1e-9 of the largest treated as zero."""
    w, U = np.linalg.eigh(A.toarray())
    keep = w > 1e-9 * w.max(initial=0.0)
    Ui = U[:, keep]
    inv = (Ui / w[keep]) @ Ui.T
    return 0.5 * (inv + inv.T)


def prolongator(A, theta, rng):
    """One coarsening step of smoothed aggregation: P = (I - w D^-1 A) T, w = (4/3) / rho(D^-1 A).

    Parameters
    ----------
    A : (n, n) scipy.sparse.csr_matrix
        Symmetric, non-negative diagonal; rows with a zero diagonal join no aggregate.
    theta : float
        Strength threshold (see :func:`smoothed_aggregation`).
    rng : numpy.random.Generator
        Order of the aggregation's root choice.

    Returns
    -------
    (P, w, dinv) : ((n, nc) csr_matrix, float, (n,) ndarray), or None when no coarser level
        exists (nc = 0 or nc = n). T has one column per aggregate, 1 / sqrt(size) on its
        rows, so P reproduces the constants of A's kernel: P (sqrt(size)) = 1 on active rows.
    """
    diag = A.diagonal()
    active = diag > 1e-14 * max(diag.max(initial=0.0), 1e-300)
    dinv = np.where(active, 1.0 / np.where(active, diag, 1.0), 0.0)
    agg = _aggregate(_strength(A, theta, active), active, rng)
    nc = agg.max() + 1
    if nc >= A.shape[0] or nc == 0:
        return None
    size = np.bincount(agg[active], minlength=nc)
    rows = np.flatnonzero(active)
    T = sp.csr_matrix((1.0 / np.sqrt(size[agg[rows]]), (rows, agg[rows])), shape=(A.shape[0], nc))
    w = (4.0 / 3.0) / _spectral_radius(A, dinv)
    return (T - w * (sp.diags(dinv) @ (A @ T))).tocsr(), w, dinv


def smoothed_aggregation(matrix, theta=0.5, coarse_size=256, max_levels=20, seed=0):
    """Build the V-cycle :class:`Hierarchy` of a symmetric positive semi-definite matrix.

    Parameters
    ----------
    matrix : (n, n) scipy.sparse matrix
        Symmetric, non-negative diagonal (W_D: zero row sums, zero rows on vertices no
        element references). Rows with a zero diagonal are left out of every coarse level.
    theta : float
        Strength threshold, relative to each row's largest off-diagonal magnitude.
    coarse_size : int
        Coarsen until a level has at most this many unknowns (dense pseudo-inverse there).
    max_levels : int
        Cap on the number of levels (the last one is solved densely whatever its size).
    seed : int
        Seed of the aggregation's random vertex order (the hierarchy is deterministic).

    Returns
    -------
    Hierarchy
    """
    A = sp.csr_matrix(matrix, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"expected a square matrix, got shape {A.shape}")
    rng = np.random.default_rng(seed)
    smoothers, restrictions = [], []
    while A.shape[0] > coarse_size and len(smoothers) + 1 < max_levels:
        level = prolongator(A, theta, rng)
        if level is None:
            break
        P, w, dinv = level
        Dinv = sp.diags(dinv)
        smoothers.append((2 * w * Dinv - w * w * (Dinv @ A @ Dinv)).tocsr())
        PtA = P.T @ A
        restrictions.append((P.T - w * (PtA @ Dinv)).tocsr())
        A = (PtA @ P).tocsr()
        A = ((A + A.T) * 0.5).tocsr()
    for M in smoothers + restrictions:
        M.eliminate_zeros()
        M.sort_indices()
    return Hierarchy(smoothers, restrictions, _pseudo_inverse(A))


class MultigridPreconditioner:
    """z = M_0 r with a :class:`Hierarchy`'s V-cycle on a Warp device, a preconditioner of
    :class:`~warp_regdist.linalg.pcg.BatchedPCG` for (n, nb) lane-vector columns.

    Each PCG needs its own (it holds the coarse levels' (n_l, nb) vectors); one Hierarchy
    can serve many. A one-level hierarchy (n <= coarse size) applies its dense
    pseudo-inverse as S_0 with no coarse correction (an empty R_0^T).

    Parameters
    ----------
    hierarchy : Hierarchy
    scalar : warp scalar type
    width : int
        Lanes per vector.
    blocks : int
        Column blocks nb.
    device : warp device
    """

    def __init__(self, hierarchy, scalar, width, blocks, device):
        self.kernels = multigrid_kernels(scalar, width)
        V = lane_type(scalar, width)
        self.device = wp.get_device(device)
        self.sizes = hierarchy.sizes
        self.n = self.sizes[0]
        if hierarchy.smoothers:
            smoothers, restrictions = hierarchy.smoothers, hierarchy.restrictions
            self.inverse = wp.array(hierarchy.coarse_inverse, dtype=scalar, device=device)
        else:
            smoothers, restrictions = [hierarchy.coarse_inverse], []
            self.sizes = [self.n]
        self.smoothers = [csr_arrays(S, scalar, device) for S in smoothers]
        self.restrictions = [csr_arrays(R, scalar, device) for R in restrictions]
        self.prolongations = ([csr_arrays(R.T, scalar, device) for R in restrictions]
                              or [csr_arrays(sp.csr_matrix((self.n, 1)), scalar, device)])
        self.y = [wp.zeros((m, blocks), dtype=V, device=device) for m in self.sizes[1:]]
        self.z = [wp.zeros((m, blocks), dtype=V, device=device) for m in self.sizes[1:]]

    def record(self, r, z, blocks):
        """Recorded launches computing z = M_0 r on column blocks 0..blocks-1 of (n, nb) ``r``, ``z``."""
        k, dev, sizes = self.kernels, self.device, self.sizes
        ys, zs = [r] + self.y, [z] + self.z
        levels = len(sizes)

        def rec(kernel, level, *inputs, span=None):
            span = span or thread_span(dev, blocks, rows=sizes[level])
            return wp.launch(kernel, row_dim(sizes[level], span, blocks), device=dev, record_cmd=True,
                             inputs=[*inputs, *span, sizes[level]])

        launches = [rec(k.mg_restrict, l + 1, *R, ys[l], ys[l + 1]) for l, R in enumerate(self.restrictions)]
        if levels > 1:
            # on the CPU one thread per block walks all coarse rows, its column of y staying in the L1 cache
            launches.append(rec(k.mg_coarse, levels - 1, self.inverse, ys[-1], zs[-1],
                                span=None if dev.is_cuda else (sizes[-1], 1)))
        for l in range(max(levels - 2, 0), -1, -1):
            launches.append(rec(k.mg_prolong, l, *self.smoothers[l], *self.prolongations[l], ys[l],
                                zs[l + 1] if levels > 1 else r, zs[l]))
        return launches

    def set_matrix(self, matrix):
        """Keep the hierarchy when the PCG's matrix changes (it only needs to stay spectrally close)."""
