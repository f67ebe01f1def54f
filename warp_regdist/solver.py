"""Regularized geodesic distance from source sets: ADMM (Algorithm 1 of the paper, SPEC section 4).

For each source set E the solver returns the minimizer of

    minimize_u  -A_V^T u + (alpha / 2) u^T W_D u
    subject to  |(G u)_e| <= 1 on every element e,   u_i = 0 for i in E,

with alpha = alpha_hat * A^(1/d) (A the total area, or volume for d = 3), so that
alpha_hat is scale-invariant. Many source sets are solved as one batched ADMM whose
per-element, per-vertex and linear-solve steps are Warp kernels over (rows x columns).
"""

from __future__ import annotations

import math
import sys
import time
import warnings

import numpy as np
import warp as wp
from scipy.optimize import OptimizeResult, OptimizeWarning

from .kernels.admm import DY2, GU2, R2, S2, Z2, admm_kernels
from .kernels.lanes import SCALARS, chunk_size, lane_type, lane_width
from .mesh import Mesh
from .multigrid import smoothed_aggregation
from .operators import build_operators
from .pcg import BatchedPCG
from .tolerances import tolerances

__all__ = ["DistanceSolver", "DistanceResult", "ConvergenceWarning"]


class ConvergenceWarning(OptimizeWarning):
    """The ADMM stopped at ``tolerances.max_iterations`` before meeting its stopping test."""


class DistanceResult(OptimizeResult):
    """Result of :meth:`DistanceSolver.solve` (scalars) or :meth:`DistanceSolver.solve_many` (per column).

    Attributes
    ----------
    distance : (n,) or (n, k) ndarray of float64
        Regularized distance; 0 on the sources, +inf on vertices no source can reach
        (other connected components, vertices referenced by no element).
    iterations : int or (k,) ndarray of int
        ADMM iterations until the stopping test held.
    converged : bool or (k,) ndarray of bool
    primal_residual, dual_residual : float or (k,) ndarray
        Final r = |sqrt(M_F)(G u - z)| and s = rho |D (z - z_old)|.
    cg_iterations : int
        PCG iterations summed over ADMM iterations (shared by all columns of a batch).
    seconds : float
        Wall time of the solve.
    """


def _parse_device(device):
    try:
        return wp.get_device(device)
    except Exception:
        names = [str(d) for d in wp.get_devices()]
        raise ValueError(f"expected a Warp device among {names}, got {device!r}") from None


class DistanceSolver:
    """Precompute once, solve for many source sets (cf. potpourri3d's solver objects).

    Parameters
    ----------
    mesh : Mesh
        Triangle or tetrahedral mesh.
    alpha_hat : float
        Scale-invariant regularization weight >= 0 (0: the discrete geodesic distance).
    device : str or None
        Warp device ("cpu", "cuda", "cuda:0"); None: Warp's default device.
    dtype : {"float64", "float32"}
        Precision of the solver's arrays (float32 halves memory; agreement ~1e-3).

    Examples
    --------
    >>> solver = DistanceSolver(load_mesh("spot.off"), alpha_hat=0.05)
    >>> u = solver.solve([2272]).distance
    """

    def __init__(self, mesh, alpha_hat=0.05, device=None, dtype="float64"):
        if not isinstance(mesh, Mesh):
            raise ValueError(f"expected a warp_regdist.Mesh, got {type(mesh).__name__}")
        try:
            alpha_hat = float(alpha_hat)
        except (TypeError, ValueError):
            raise ValueError(f"expected a real alpha_hat >= 0, got {alpha_hat!r}") from None
        if not math.isfinite(alpha_hat) or alpha_hat < 0:
            raise ValueError(f"expected a finite alpha_hat >= 0, got {alpha_hat!r}")
        if dtype not in SCALARS:
            raise ValueError(f"expected dtype 'float64' or 'float32', got {dtype!r}")
        wp.init()
        self.device = _parse_device(device)
        self.mesh = mesh
        self.alpha_hat = alpha_hat
        self.dtype = dtype
        self.scalar = SCALARS[dtype]
        self.operators = ops = build_operators(mesh)
        self.alpha = alpha_hat * ops.length_scale
        self._labels = mesh.components()
        sc, dev = self.scalar, self.device
        T = mesh.elements
        self._elements = wp.array(T.astype(np.int32), dtype=wp.int32, device=dev)
        self._basis = wp.array(ops.basis, dtype=wp.types.vector(3, sc), device=dev)
        self._volumes = wp.array(ops.element_volumes, dtype=sc, device=dev)
        self._vertex_volumes = wp.array(ops.vertex_volumes, dtype=sc, device=dev)
        off, inc, loc = ops.vertex_elements
        self._vertex_offsets = wp.array(off.astype(np.int32), dtype=wp.int32, device=dev)
        self._incident = wp.array(inc.astype(np.int32), dtype=wp.int32, device=dev)
        self._pair_weights = wp.array(ops.element_volumes[inc, None] * ops.basis[inc, loc],
                                      dtype=wp.types.vector(3, sc), device=dev)
        self._hierarchy = smoothed_aggregation(ops.stiffness)
        self._workspaces = {}

    # ------------------------------------------------------------------ input checks
    def _source_mask(self, sources, column):
        """Validated sources -> (indices (s,), reachable (n,) bool)."""
        n = self.mesh.n_vertices
        if isinstance(sources, (str, bytes)):
            raise ValueError(f"expected source set {column} as vertex indices, got the string {sources!r}")
        arr = np.asarray(list(sources) if not isinstance(sources, np.ndarray) else sources)
        if arr.size == 0:
            raise ValueError(f"expected at least one source vertex in source set {column}, got none")
        if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or
                                     (np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)))):
            raise ValueError(f"expected integer vertex indices in source set {column}, got {arr.ravel()[:5].tolist()}")
        arr = arr.astype(np.int64).ravel()
        bad = arr[(arr < 0) | (arr >= n)]
        if bad.size:
            raise ValueError(f"expected source vertex indices in [0, {n - 1}] in source set {column}, got {bad[0]}")
        labels = self._labels
        comps = np.unique(labels[arr])
        reachable = np.isin(labels, comps[comps >= 0])
        reachable[arr] = True
        return np.unique(arr), reachable

    # ------------------------------------------------------------------ public API
    def solve(self, sources, verbose=False):
        """Distance from one source set (iterable of vertex indices); see :class:`DistanceResult`."""
        res = self.solve_many([sources], verbose=verbose)
        for key in ("iterations", "converged", "primal_residual", "dual_residual"):
            res[key] = res[key][0].item()
        res["distance"] = res["distance"][:, 0]
        return res

    def solve_many(self, source_sets, verbose=False):
        """Distances from k source sets as one batched ADMM: ``distance`` is (n, k)."""
        if isinstance(source_sets, (str, bytes)) or not hasattr(source_sets, "__iter__"):
            raise ValueError(f"expected a list of source sets, got {source_sets!r}")
        sets = [self._source_mask(s, j) for j, s in enumerate(source_sets)]
        if not sets:
            raise ValueError("expected at least one source set, got none")
        return self._admm(sets, verbose)

    # ------------------------------------------------------------------ ADMM
    def _workspace(self, W, nb):
        key = (W, nb)
        if key not in self._workspaces:
            V = lane_type(self.scalar, W)
            n, m, dev = self.mesh.n_vertices, self.mesh.n_elements, self.device
            ws = dict(
                u=wp.zeros((n, nb), dtype=V, device=dev), mask=wp.zeros((n, nb), dtype=V, device=dev),
                Dy=wp.zeros((n, nb), dtype=V, device=dev), Dz=wp.zeros((n, nb), dtype=V, device=dev),
                rhs=wp.zeros((n, nb), dtype=V, device=dev),
                z=wp.zeros((m, 3, nb), dtype=V, device=dev), y=wp.zeros((m, 3, nb), dtype=V, device=dev),
                dz=wp.zeros((m, 3, nb), dtype=V, device=dev),
                rho=wp.zeros(nb, dtype=V, device=dev), acc=wp.zeros((5, nb), dtype=V, device=dev),
                pcg=BatchedPCG(self.operators.stiffness, self.scalar, W, nb, dev, preconditioner=self._hierarchy),
            )
            self._workspaces = {key: ws}  # keep one workspace: memory scales with the batch
        return self._workspaces[key]

    def _admm(self, sets, verbose):
        t0 = time.perf_counter()
        tol = tolerances
        k = len(sets)
        n, m = self.mesh.n_vertices, self.mesh.n_elements
        W = lane_width(self.scalar, k)
        nb = -(-k // W)
        cols = nb * W
        ws = self._workspace(W, nb)
        kern = admm_kernels(self.scalar, W, self.mesh.elements.shape[1])
        dev, chunk = self.device, chunk_size(self.device)

        free = np.zeros((n, cols))
        for j in range(cols):
            src, reach = sets[j] if j < k else sets[0]
            free[:, j] = reach
            free[src, j] = 0.0
        n_free = np.maximum(free.sum(axis=0), 1.0)
        ws["mask"].assign(free.reshape(n, nb, W))
        for name in ("u", "z", "y", "dz", "Dy", "Dz"):
            ws[name].zero_()
        L = self.operators.length_scale
        A = self.operators.total_volume
        rho = np.full(cols, tol.rho0 * L)
        ws["rho"].assign(rho.reshape(nb, W))

        eps_pri_abs = math.sqrt(3 * m) * tol.eps_abs * math.sqrt(A)
        eps_dual_abs = np.sqrt(n_free) * tol.eps_abs * A
        elem_dim = ((m + chunk - 1) // chunk, nb)
        vert_dim = ((n + chunk - 1) // chunk, nb)
        sc = self.scalar
        # Recorded launches: the arguments are fixed for the whole solve (rho lives in a device array).
        divergence = wp.launch(kern.vertex_divergence, vert_dim, device=dev, record_cmd=True, inputs=[
            self._vertex_offsets, self._incident, self._pair_weights, ws["mask"], ws["y"], ws["z"], ws["dz"],
            ws["Dy"], ws["Dz"], ws["acc"], chunk, n])
        u_rhs = wp.launch(kern.u_rhs, vert_dim, device=dev, record_cmd=True, inputs=[
            self._vertex_volumes, ws["mask"], ws["Dy"], ws["Dz"], ws["rho"], sc(self.alpha), ws["rhs"], chunk, n])
        element_step = wp.launch(kern.element_step, elem_dim, device=dev, record_cmd=True, inputs=[
            self._elements, self._basis, self._volumes, ws["u"], ws["rho"], sc(tol.relaxation),
            ws["z"], ws["y"], ws["dz"], ws["acc"], chunk, m])
        iterations = np.full(cols, -1)
        out = np.zeros((n, k))
        r_out, s_out = np.zeros(k), np.zeros(k)
        r = s = np.zeros(cols)
        eps_dual = dual_scale = eps_dual_abs
        cg_total = 0
        it = 0
        last_print = t0
        for it in range(tol.max_iterations + 1):
            divergence.launch()
            if it > 0:
                acc = ws["acc"].numpy().reshape(5, cols)
                r = np.sqrt(acc[R2])
                s = rho * np.sqrt(acc[S2])
                eps_pri = eps_pri_abs + tol.eps_rel * np.sqrt(np.maximum(acc[GU2], acc[Z2]))
                dual_scale = eps_dual_abs + np.sqrt(acc[DY2])
                eps_dual = eps_dual_abs + tol.eps_rel_dual * np.sqrt(acc[DY2])
                done = (r <= eps_pri) & (s <= eps_dual)  # <=: a source-only column has r = s = eps = 0
                new = np.flatnonzero((iterations < 0) & done)
                new = new[new < k]
                if new.size:  # freeze each column at the iterate that met its stopping test
                    iterations[new] = it
                    out[:, new] = ws["u"].numpy().reshape(n, cols)[:, new]
                    r_out[new], s_out[new] = r[new], s[new]
                if verbose and (time.perf_counter() - last_print > 2.0):
                    last_print = time.perf_counter()
                    print(f"  ADMM iteration {it}: {np.count_nonzero(iterations[:k] >= 0)}/{k} converged, "
                          f"max r/eps_pri {np.max(r / eps_pri):.3g}, max s/eps_dual {np.max(s / eps_dual):.3g}, "
                          f"{last_print - t0:.1f} s", file=sys.stderr)
                if np.all(iterations[:k] >= 0) or it == tol.max_iterations:
                    break
                rho = np.full(cols, L * min(tol.rho_max, tol.rho0 * 2.0 ** (it / tol.rho_doubling)))
                ws["rho"].assign(rho.reshape(nb, W))
            ws["acc"].zero_()
            u_rhs.launch()
            cg_atol = np.minimum(tol.cg_fraction * dual_scale, 0.1 * eps_dual) / (self.alpha + rho)
            cg_it, _ = ws["pcg"].solve(ws["rhs"], ws["u"], ws["mask"], tol.cg_rtol, tol.cg_max_iterations, cg_atol)
            cg_total += cg_it
            element_step.launch()

        late = np.flatnonzero(iterations[:k] < 0)
        out[:, late] = ws["u"].numpy().reshape(n, cols)[:, late]
        r_out[late], s_out[late] = r[late], s[late]
        u = out
        for j, (src, reach) in enumerate(sets):
            u[~reach, j] = np.inf
            u[src, j] = 0.0
        converged = iterations[:k] >= 0
        if not converged.all():
            warnings.warn(f"ADMM did not converge in {tol.max_iterations} iterations for "
                          f"{np.count_nonzero(~converged)} of {k} source sets", ConvergenceWarning, stacklevel=3)
        return DistanceResult(
            distance=u, iterations=np.where(converged, iterations[:k], it), converged=converged,
            primal_residual=r_out, dual_residual=s_out, cg_iterations=cg_total, seconds=time.perf_counter() - t0)
