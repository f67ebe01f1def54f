"""Vector-Jacobian products of converged single-source solves (docs/method.md section 10).

The derivative is that of the smoothed problem

    minimize_u  F(u) = -A_V . u + (alpha / 2) sum_e a_e |g_e|^2 - mu sum_e log(1 - |g_e|^2),
    g_e = (G u)_e,  u = 0 on the sources,  alpha = alpha_hat A^(1/d),  mu = mu_hat A^(1 + 1/d) / m,

where on a source's own triangle (source_triangles "edges": the wedge u_a <= l_sa at its other
corners a) the barrier term is -mu sum_a log(1 - u_a / l_sa) instead,

(m elements, A their total volume) whose minimizer u_mu is a smooth function of the vertex
positions and alpha_hat and tends to the ADMM's minimizer as mu_hat -> 0
(the solver's ``options.gradient_smoothing``). Its stationarity grad_u F(u_mu; x, alpha_hat) = 0 gives, for a
loss gradient b = dL/du (free vertices), the adjoint H w = b (H = grad_u^2 F at u_mu, symmetric
positive definite) and

    dL/dx = -d/dx [w . grad_u F(u_mu; x, alpha_hat)],   dL/dalpha_hat = -A^(1/d) w . (W_D u_mu),

the first by the reverse pass of the per-element kernels in kernels/adjoint.py.

The exact problem's active-set system is singular or ill-conditioned on real meshes (faces
where |g| = 1 whose multipliers vanish); the barrier gives every element a positive multiplier
2 mu / (1 - |g|^2), so H is positive definite and the derivative is unique. Every element's
barrier has the same weight (mean element volume), not its own volume: with a_e in front, a sliver
of a thousandth of the mean area keeps Newton's method from converging. u_mu is found by Newton's
method (steps that keep a tenth of every element's slack 1 - |g|^2, then backtracking), from the
ADMM distance, along mu_hat = 10^-2, 10^-3, ... down to the final mu_hat, with a predictor step
along the central path's tangent between levels; H is factorized by MKL PARDISO's Cholesky
(the ``[pardiso]`` extra) or scipy's SuperLU (``options.gradient_factorization``).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp
from scipy.optimize import OptimizeResult

from ...errors import ConvergenceWarning
from ...geometry.intrinsic import flat_layout, flat_layout_gradient, length_gradient
from ...kernels import adjoint
from ...linalg.pardiso import PardisoCholesky, PardisoError, load_mkl
from ..common.source_triangles import SourceTriangles, corner_sides
from .sources import vertex_sources

__all__ = ["Gradients", "SmoothingProblem", "SmoothedProblem", "SmoothedSolution", "smoothed_solution", "adjoint_gradients",
           "vector_jacobian_product"]

_START = 1e-2            # mu_hat of the first level; each level divides it by _RATIO down to the final mu_hat
_RATIO = 10.0
_CENTERING = 10.0        # an intermediate level stops at a Newton decrement^2 / 2 <= this mu
_MAX_NEWTON = 60         # Newton steps per level
_INTERIOR = 1.0 - 1e-3   # the ADMM distance is scaled so that max |g| (max u_a / l_sa on wedges) is at most this
_TO_BOUNDARY = 0.9       # a Newton step keeps at least a tenth of every element's slack 1 - |g|^2



@dataclasses.dataclass(frozen=True)
class SmoothingProblem:
    """What :meth:`~warp_regdist.DistanceResult.vjp` and ``polish`` need of the solve behind a result: the
    mesh and its operators, alpha and alpha_hat, the regularizer's name, the source triangles' constraint
    and the solve's options (not the solver, whose device arrays and worker processes a result would
    otherwise keep alive)."""

    mesh: object
    operators: object
    alpha: float
    alpha_hat: float
    regularizer: str
    source_triangles: SourceTriangles
    options: object

class Gradients(OptimizeResult):
    """Result of :meth:`~warp_regdist.DistanceResult.vjp`.

    Attributes
    ----------
    vertices : (n, 3) ndarray
        dL/dx, the loss's gradient with respect to the vertex positions (summed over columns).
    alpha_hat : float
        dL/dalpha_hat.
    smoothed_distance : (n,) or (n, k) ndarray
        u_mu, the smoothed problem's minimizer whose derivative this is.
    smoothing_change : float
        max |u_mu - distance| / max distance over the columns: how far the smoothed minimizer is
        from the returned distance (the ADMM's error plus the smoothing's).
    smoothing : float
        The largest mu_hat used over the columns: the solver's ``options.gradient_smoothing``, or a larger one
        where Newton's method stalled at it (with a ConvergenceWarning).
    newton_iterations : int
        Newton steps summed over columns.
    factorization : str
        The sparse factorization of the Newton systems, "pardiso" or "superlu"
        (``options.gradient_factorization``).
    seconds : float
    points : (p, 3) ndarray or list of them
        After a solve from points: dL/db for each point's barycentric coordinates b on its face (the
        point moving with the face's vertices in ``vertices``); a list with one array per column after
        ``solve_many``. The refined mesh's ``refined_vertices`` (n', 3) and ``refined_smoothed_distance``
        come with it.
    """


def factorization_backend(name):
    """The factorization ``name`` ("auto", "pardiso" or "superlu") resolves to: "auto" is "pardiso"
    where MKL loads, else "superlu"; "pardiso" without MKL is a ValueError."""
    if name == "superlu":
        return name
    try:
        load_mkl()
    except OSError as err:
        if name == "auto":
            return "superlu"
        raise ValueError(f"expected gradient_factorization 'pardiso' to find MKL (pip install "
                         f"'warp-regdist[pardiso]', x86-64 only), got {err}") from None
    return "pardiso"


class _Factor:
    """Solves of the SPD matrix H (CSR, sorted indices, a symmetric pattern with its diagonal) through
    D H D, D = diag(H)^(-1/2), each with one step of iterative refinement (H's condition reaches 1e12
    and more). ``backend`` "pardiso": MKL PARDISO's Cholesky, refactoring the ``previous`` _Factor's
    handle (its ordering and symbolic analysis kept along a Newton path, whose Hessians share a
    pattern; ``previous`` can no longer solve), SuperLU where a pivot is not positive; "superlu":
    scipy's SuperLU, symmetric ordering, no pivoting."""

    def __init__(self, H, backend, previous=None):
        self.H = H
        rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
        self.d = 1.0 / np.sqrt(H.data[rows == H.indices])
        data = H.data * self.d[rows] * self.d[H.indices]
        self.pardiso = None
        if backend == "pardiso":
            upper = H.indices >= rows
            scaled = sp.csr_matrix((data[upper], H.indices[upper],
                                    np.concatenate([[0], np.cumsum(np.bincount(rows[upper], minlength=H.shape[0]))])),
                                   shape=H.shape)
            cholesky = None if previous is None else previous.pardiso
            try:
                if cholesky is None:
                    cholesky = PardisoCholesky(scaled)
                else:
                    cholesky.refactor(scaled)
                self.pardiso, self.generation = cholesky, cholesky.generation
                return
            except PardisoError:
                pass
        self.lu = spla.splu(sp.csc_matrix((data, H.indices, H.indptr), shape=H.shape),   # = D H D (symmetric)
                            permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))

    def _scaled_solve(self, b):
        if self.pardiso is None:
            return self.lu.solve(b)
        if self.pardiso.generation != self.generation:
            raise RuntimeError("expected the latest factorization of a PARDISO handle, got one refactored since")
        return self.pardiso.solve(b)

    def solve(self, b):
        x = self.d * self._scaled_solve(self.d * b)
        return x + self.d * self._scaled_solve(self.d * (b - self.H @ x))


class _HessianPattern:
    """H = G^T blockdiag(B_e) G on its fixed pattern for B_e = c_e I + w_e g_e g_e^T: with b_ea the
    gradient of element e's a-th free hat function (G's rows 3e..3e+2),

        H_ij = sum over e, a, b with i_a = i, i_b = j of c_e (b_ea . b_eb) + w_e (b_ea . g_e)(b_eb . g_e),

    summed by one bincount into the CSR entries (sorted; the pattern does not depend on c, w, g)."""

    def __init__(self, G, m):
        f = G.shape[1]
        coo = G.tocoo()
        row, col = coo.row.astype(np.int64), coo.col.astype(np.int64)
        pairs, first = np.unique((row // 3) * f + col, return_inverse=True)   # (element, vertex), no int32 overflow
        element, vertex = pairs // f, pairs % f
        b = np.zeros((pairs.size, 3))
        np.add.at(b, (first, row % 3), coo.data)
        counts = np.bincount(element, minlength=m)
        slot = np.arange(pairs.size) - np.concatenate([[0], np.cumsum(counts)[:-1]])[element]
        k = int(counts.max(initial=0))
        local = np.full((m, k), -1)
        local[element, slot] = vertex
        self.basis = np.zeros((m, k, 3))
        self.basis[element, slot] = b
        self.dots = np.einsum("eac,ebc->eab", self.basis, self.basis)
        self.valid = (local[:, :, None] >= 0) & (local[:, None, :] >= 0)
        rows, cols = np.broadcast_to(local[:, :, None], self.valid.shape), np.broadcast_to(local[:, None, :], self.valid.shape)
        entries, self.scatter = np.unique(rows[self.valid] * f + cols[self.valid], return_inverse=True)
        self.indices = entries % f
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(entries // f, minlength=f))])
        self.shape = (f, f)

    def matrix(self, c, w, g):
        """H (f, f) CSR for c, w (m,) and g (m, 3)."""
        s = np.einsum("eac,ec->ea", self.basis, g)
        values = c[:, None, None] * self.dots + w[:, None, None] * s[:, :, None] * s[:, None, :]
        data = np.bincount(self.scatter, weights=values[self.valid], minlength=self.indices.size)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


class SmoothedProblem:
    """The smoothed problem of one column (module docstring): operators of a Mesh (``ops``),
    alpha, mu_hat, ``free`` (n,) bool, the vertices that are neither sources nor unreachable, the
    ``factorization`` of its Newton systems ("superlu" or "pardiso", :func:`factorization_backend`)
    and the column's ``wedges`` (faces (r,), source corners (r,)): its triangles with the wedge
    constraint (:meth:`~warp_regdist.solvers.common.source_triangles.SourceTriangles.corners`; None: none)."""

    def __init__(self, ops, alpha, mu_hat, free, factorization="superlu", wedges=None):
        m = ops.element_volumes.size
        self.ball = np.ones(m, dtype=bool)
        index = np.cumsum(free) - 1                       # vertex -> its free unknown
        if wedges is not None and wedges[0].size:
            faces, corners = wedges
            self.ball[faces] = False
            T, basis = ops.elements[faces], ops.basis[faces]
            others = np.stack([(corners + 1) % 3, (corners + 2) % 3], axis=1)          # (r, 2)
            rows = np.arange(faces.size)[:, None]
            self.bound_at = index[T[rows, others]].ravel()       # u_a <= l_sa: the unknown of a, and l_sa
            self.bound = np.linalg.norm(corner_sides(basis)[rows, corners[:, None], np.arange(2)[None, :]],
                                        axis=-1).ravel()
        else:
            self.bound_at, self.bound = np.zeros(0, dtype=np.int64), np.zeros(0)
        self.ops, self.alpha = ops, float(alpha)
        self.mu = float(mu_hat) * ops.total_volume * ops.length_scale / m
        self.G = ops.grad[:, free].tocsr()
        self.m = m
        self.hessian = _HessianPattern(self.G, m)
        self.load = ops.vertex_volumes[free]
        self.mu_hat = float(mu_hat)
        self.scale = ops.total_volume * ops.length_scale    # the units of F
        self.factorization = factorization
        self._last = None    # the last _Factor, whose PARDISO handle the next one refactors

    def _g(self, v):
        """(g = G v (m, 3), |g|^2 (m,)): valid anywhere, the constraint's boundary included."""
        g = (self.G @ v).reshape(self.m, 3)
        return g, np.einsum("ec,ec->e", g, g)

    def _g_inv(self, v):
        """(g, 1 / (1 - |g|^2) on the ball's elements and 0 on the wedges (m,)), v strictly inside."""
        g, t = self._g(v)
        inv = np.zeros(self.m)
        inv[self.ball] = 1.0 / (1.0 - t[self.ball])
        return g, inv

    def _wedge_slack(self, v):
        """l_sa - u_a of every wedge bound (2r,)."""
        return self.bound - v[self.bound_at]

    def objective(self, v, mu):
        _, t = self._g(v)
        a = self.ops.element_volumes
        return (-self.load @ v + 0.5 * self.alpha * (a @ t) - mu * np.sum(np.log1p(-t[self.ball]))
                - mu * np.sum(np.log(self._wedge_slack(v) / self.bound)))

    def barrier_gradient(self, v):
        """d grad F / d mu (f,): G^T (2 g_e / (1 - |g_e|^2)) on the ball's elements, 1 / (l_sa - u_a) at
        each wedge bound's vertex."""
        g, inv = self._g_inv(v)
        return (self.G.T @ ((2.0 * inv)[:, None] * g).ravel()
                + np.bincount(self.bound_at, 1.0 / self._wedge_slack(v), minlength=self.load.size))

    def gradient_hessian(self, v, mu):
        """grad F (f,) and H (f, f) CSR on the free vertices at v (inside the constraints): per element
        c_e = alpha a_e + 2 mu / (1 - |g_e|^2) (alpha a_e on the wedges) and
        H = G^T blockdiag(c_e I + 4 mu g_e g_e^T / (1 - |g_e|^2)^2) G + diag(sum of mu / (l_sa - u_a)^2 at a)."""
        g, inv = self._g_inv(v)
        c = self.ops.element_volumes * self.alpha + 2.0 * mu * inv
        slack = self._wedge_slack(v)
        grad = (-self.load + self.G.T @ (c[:, None] * g).ravel()
                + np.bincount(self.bound_at, mu / slack, minlength=self.load.size))
        H = self.hessian.matrix(c, 4.0 * mu * inv ** 2, g)
        if slack.size:
            H = (H + sp.diags(np.bincount(self.bound_at, mu / slack ** 2, minlength=self.load.size))).tocsr()
        return grad, H

    def max_gauge(self, v):
        """max over elements of the constraint's gauge: |g| on the ball's, u_a / l_sa on the wedges'."""
        _, t = self._g(v)
        wedge = np.max(v[self.bound_at] / self.bound, initial=0.0)
        return max(float(np.sqrt(np.max(t[self.ball], initial=0.0))), float(wedge))

    def step_length(self, v, step, keep=1.0 - _TO_BOUNDARY):
        """The largest s <= 1 that keeps every slack at least ``keep`` times its value: 1 - |g + s dg|^2 >=
        keep (1 - |g|^2) on the ball's elements (g = G v, dg = G step: the positive root of
        |dg|^2 s^2 + 2 (g . dg) s - (1 - keep) (1 - |g|^2)), and l_sa - u_a - s du_a >= keep (l_sa - u_a)."""
        g, t = self._g(v)
        dg = (self.G @ step).reshape(self.m, 3)
        a, b = np.einsum("ec,ec->e", dg, dg), 2.0 * np.einsum("ec,ec->e", g, dg)
        c = -(1.0 - keep) * (1.0 - t)
        with np.errstate(divide="ignore", invalid="ignore"):
            roots = (-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)     # a > 0 > c: one positive root
        du = step[self.bound_at]
        rising = du > 0
        wedge = (1.0 - keep) * self._wedge_slack(v)[rising] / du[rising]
        return float(min(1.0, np.min(roots[(a > 0) & self.ball], initial=1.0), np.min(wedge, initial=1.0)))

    def _center(self, v, mu, tight):
        """Newton's method on F at mu from v until the decrement grad F . H^-1 grad F <= 2 ``tight``
        (or rounding stops it from halving below 1e-14 A L): (v, the factors of H there, steps, converged)."""
        last = np.inf
        for count in range(1, _MAX_NEWTON + 1):
            grad, H = self.gradient_hessian(v, mu)
            lu = self._last = _Factor(H, self.factorization, self._last)
            step = -lu.solve(grad)
            decrement = -grad @ step
            if decrement <= 2.0 * tight or (decrement <= 1e-14 * self.scale and decrement > 0.5 * last):
                return v, lu, count, True
            last = decrement
            s = self.step_length(v, step)
            if decrement > 1e-10 * self.scale:  # Armijo, where F's rounding does not hide the decrease
                f0 = self.objective(v, mu)
                while s > 1e-12 and self.objective(v + s * step, mu) > f0 - 0.25 * s * decrement:
                    s *= 0.5
            v = v + s * step
        return v, lu, _MAX_NEWTON, False

    def minimize(self, v):
        """u_mu on the free vertices from v (f,): (u, the factors of H there, Newton steps, the mu_hat
        reached). Where Newton's method stalls at the final mu (an element's slack 1 - |g|^2 so small
        that H's condition defeats the factorization), the last level that converges tightly is
        returned instead, with its larger mu_hat."""
        top = self.max_gauge(v)
        if top >= _INTERIOR:
            v = v * (_INTERIOR / top)
        steps, centred = 0, []
        levels = max(0, int(np.ceil(np.log(_START / self.mu_hat) / np.log(_RATIO))))
        for level in range(levels, -1, -1):
            mu = self.mu * _RATIO ** level
            v, lu, count, converged = self._center(v, mu, 1e-20 * self.scale if level == 0 else _CENTERING * mu)
            steps += count
            if not converged:
                break
            if level == 0:
                return v, lu, steps, self.mu_hat
            centred.append((level, v))
            # predictor along the central path's tangent du/dmu = -H^-1 d(grad F)/dmu, keeping half the slack
            tangent = lu.solve(self.barrier_gradient(v)) * (mu - mu / _RATIO)
            v = v + self.step_length(v, tangent, keep=0.5) * tangent
        for level, start in reversed(centred):
            v, lu, count, converged = self._center(start, self.mu * _RATIO ** level, 1e-20 * self.scale)
            steps += count
            if converged:
                return v, lu, steps, self.mu_hat * _RATIO ** level
        raise RuntimeError(f"expected the smoothed problem's Newton iteration to converge, got none of its levels "
                           f"(mu_hat {_START:g} to {self.mu_hat:g}) within {_MAX_NEWTON} steps")


def _position_gradient(mesh, ops, u, w, alpha_hat, mu_hat, wedges):
    """-d/dx [w . grad_u F(u; x, alpha_hat)] (n, 3) by the reverse pass of kernels/adjoint.py (``wedges``
    (faces, corners) the column's triangles with the wedge constraint):
    w . grad_u F = sum(load) + alpha sum(dirichlet) + mu sum(barrier), alpha = alpha_hat A^(1/d),
    mu = mu_hat A^(1 + 1/d) / m, A = sum(volume). On intrinsic operators the kernel runs on every face
    laid out flat from its lengths, and the derivative goes back through the layout and the flips."""
    intrinsic = ops.intrinsic
    weight = 1.0 if intrinsic is None else intrinsic.area_weight      # a_e of the operators / a_e of the layout
    if intrinsic is None:
        x, T, uc, wc = mesh.vertices, mesh.elements, u, w
    else:
        m3 = intrinsic.faces.size
        x, T = flat_layout(intrinsic.lengths).reshape(-1, 3), np.arange(m3).reshape(-1, 3)
        uc, wc = u[intrinsic.faces].ravel(), w[intrinsic.faces].ravel()
    m, d = T.shape[0], T.shape[1] - 1
    xw = wp.array(np.ascontiguousarray(x), dtype=wp.vec3d, device="cpu", requires_grad=True)
    out = [wp.zeros(m, dtype=wp.float64, device="cpu", requires_grad=True) for _ in range(4)]
    inputs = [xw, wp.array(T.astype(np.int32), dtype=wp.int32, device="cpu"), wp.array(uc, dtype=wp.float64, device="cpu"),
              wp.array(wc, dtype=wp.float64, device="cpu")]
    if d == 2:
        corner = np.full(m, -1, dtype=np.int32)
        corner[wedges[0]] = wedges[1]
        inputs.append(wp.array(corner, dtype=wp.int32, device="cpu"))
    tape = wp.Tape()
    with tape:
        wp.launch(adjoint.triangle_terms if d == 2 else adjoint.tetrahedron_terms, m, device="cpu", inputs=inputs,
                  outputs=out)
    dirichlet, barrier, A = (float(o.numpy().sum()) for o in out[1:])
    dirichlet, A = weight * dirichlet, weight * A
    s = A ** (1.0 / d)
    alpha, mu = alpha_hat * s, mu_hat * A * s / m
    dA = (alpha * dirichlet / d + mu * barrier * (1.0 + 1.0 / d)) / A   # through alpha(A) and mu(A)
    seeds = (weight, weight * alpha, mu, weight * dA)
    tape.backward(grads={o: wp.full(m, c, dtype=wp.float64, device="cpu") for o, c in zip(out, seeds)})
    grad = -xw.grad.numpy()
    if intrinsic is None:
        return grad
    return length_gradient(intrinsic, mesh.vertices,
                           flat_layout_gradient(intrinsic.lengths, grad.reshape(-1, 3, 3)))


class SmoothedSolution(NamedTuple):
    """u_mu of one column: ``distance`` (n,) (inf where no source reaches), ``free`` (n,) bool, the
    ``wedges`` (faces, corners) of its source triangles, the factors ``lu`` of the Hessian on the free
    vertices, Newton ``steps``, the ``mu_hat`` reached and ``change``, max |u_mu - u| / max u from the
    distance u it started from."""
    distance: np.ndarray
    free: np.ndarray
    wedges: tuple
    lu: object
    steps: int
    mu_hat: float
    change: float


def smoothed_solution(problem, distance, sources, column=0):
    """The :class:`SmoothedSolution` of ``problem`` (a :class:`SmoothingProblem`) from vertex ``sources``, by
    Newton's method from ``distance`` (n,), a converged solve's (``column`` names the source set in errors),
    at the barrier weight ``options.gradient_smoothing`` with ``options.gradient_factorization`` of the
    problem's options."""
    options = problem.options
    mu_hat = float(options.gradient_smoothing)
    mesh = problem.mesh
    sources, reachable = vertex_sources(sources, column, mesh.n_vertices, mesh.components())
    free = reachable.copy()
    free[sources] = False
    backend = factorization_backend(options.gradient_factorization)
    wedges = problem.source_triangles.corners(sources)
    v, lu, steps, reached = SmoothedProblem(problem.operators, problem.alpha, mu_hat, free, backend, wedges).minimize(
        distance[free])
    if reached > mu_hat:
        warnings.warn(f"the smoothed problem of source set {column} was solved at gradient_smoothing {reached:g}, not "
                      f"{mu_hat:g}: at the smaller value an element's slack 1 - |grad u|^2 fell below what float64 "
                      "resolves", ConvergenceWarning, stacklevel=3)
    u = np.where(reachable, 0.0, np.inf)
    u[free] = v
    top = np.max(distance[reachable], initial=0.0)
    change = float(np.abs(u[reachable] - distance[reachable]).max() / top) if top > 0 else 0.0
    return SmoothedSolution(u, free, wedges, lu, steps, reached, change)


def adjoint_gradients(problem, solution, b):
    """(dL/dx (n, 3), dL/dalpha_hat) for dL/du = ``b`` (n,) at a :class:`SmoothedSolution`: H w = b on the
    free vertices, then the module docstring's formulas."""
    f = solution.free
    rhs = np.ascontiguousarray(b[f], dtype=np.float64)
    w = np.zeros(f.size)
    w[f] = solution.lu.solve(rhs)
    u = np.where(f, solution.distance, 0.0)
    dx = _position_gradient(problem.mesh, problem.operators, u, w, problem.alpha_hat, solution.mu_hat, solution.wedges)
    return dx, -problem.operators.length_scale * float(w @ (problem.operators.stiffness @ u))


def vector_jacobian_product(problem, distance, source_sets, grad_u):
    """The :class:`Gradients` of sum(grad_u * distance) (module docstring) for the columns of a
    converged solve of ``problem`` (a :class:`SmoothingProblem`) from vertex ``source_sets``;
    ``distance``, ``grad_u`` (n, k)."""
    options = problem.options
    t0 = time.perf_counter()
    n, k = distance.shape
    vertices, alpha_hat, steps, change, smoothing = np.zeros((n, 3)), 0.0, 0, 0.0, 0.0
    smoothed = np.zeros((n, k))
    for j in range(k):
        solution = smoothed_solution(problem, distance[:, j], source_sets[j], j)
        dx, da = adjoint_gradients(problem, solution, grad_u[:, j])
        vertices += dx
        alpha_hat += da
        steps += solution.steps
        smoothing = max(smoothing, solution.mu_hat)
        change = max(change, solution.change)
        smoothed[:, j] = solution.distance
    return Gradients(vertices=vertices, alpha_hat=alpha_hat, smoothed_distance=smoothed, smoothing_change=change,
                     smoothing=smoothing, newton_iterations=steps,
                     factorization=factorization_backend(options.gradient_factorization),
                     seconds=time.perf_counter() - t0)
