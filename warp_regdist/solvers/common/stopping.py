"""The stopping rule both solvers use (docs/method.md section 8): relative tolerances with their
floors, the change tests, and the u-step's CG tolerance.

Every residual test has the form  residual <= floor + eps_rel scale  (:func:`tolerance`), the
scale being the larger of the iterate's own size and a floor that does not vanish where the
duals do (:func:`dual_scale`): a test relative to |D y| alone never holds where no gradient
constraint is active. A column (a source set, or the all-pairs matrix as one column) also
waits for its change test: :class:`ChangeTest` (single sources: the change of the last
window, and its error estimate :func:`vertex_extrapolation`) or :class:`ExtrapolatedChangeTest`
(all pairs: the change still to come at the slower of the last two windows' rate and 1 / k,
and :func:`gradient_excess`). The u-step's PCG stops at :func:`cg_tolerance`.

DistanceSolver runs this rule on the device (kernels/single_source.py ``change_measure`` and
``admm_check``, with the constants of ``single_source.batch``); the tests run the
kernel and these functions on the same inputs. all_pairs runs it on the host.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["tolerance", "dual_scale", "cg_tolerance", "ChangeTest", "ExtrapolatedChangeTest", "vertex_extrapolation",
           "steep_columns", "gradient_excess", "steepest_element", "ESTIMATE_RATE_CAP"]

ESTIMATE_RATE_CAP = 0.95
"""The largest rate per window at which :func:`vertex_extrapolation` extends a vertex's change
(at most 1 / (1 - 0.95) = 20 times the last window's): a vertex whose change shrinks slowly, or
grows, counts as creeping at this rate (chosen against exact minimizers: docs/design/stopping.md)."""


def tolerance(floor, eps_rel, scale):
    """floor + eps_rel scale: a residual's tolerance (scalars or arrays)."""
    return floor + eps_rel * scale


def dual_scale(dual_norm, load_norm):
    """max(|D y|, |load|): the scale of the dual residual, floored by the load the duals balance."""
    return np.maximum(dual_norm, load_norm)


def cg_tolerance(cg_fraction, scale, eps_dual=math.inf, primal_term=math.inf):
    """min(cg_fraction scale, eps_dual / 10, primal_term): the u-step's absolute CG tolerance (before
    the division by the u-step matrix's shift + scale rho). Single sources pass their dual
    tolerance and cg_primal r (alpha + rho); all pairs only the scale."""
    return np.minimum(np.minimum(cg_fraction * scale, 0.1 * eps_dual), primal_term)


def vertex_extrapolation(u, snapshot, moved_last, rate_cap=ESTIMATE_RATE_CAP):
    """The single-source error estimate per column (the host statement of kernels/single_source.py
    ``change_measure`` and ``admm_check``), u and snapshot (n, k) the iterate now and one window
    before, moved_last (n, k) the last comparison's |u - snapshot| (zeros before the first):

        d = |u - snapshot|,  estimate = max_i d_i / (1 - q_i) / max_i |u_i|,
        q_i = min(d_i / moved_last_i, rate_cap)   (rate_cap where moved_last_i = 0),

    the change still to come if every vertex kept converging at its rate of the last two windows
    (0 where d or u is 0). Returns (estimate (k,), d (n, k)).
    """
    d = np.abs(u - snapshot)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(d < rate_cap * moved_last, d / moved_last, rate_cap)
        top = np.abs(u).max(axis=0)
        estimate = np.where((d.max(axis=0) > 0) & (top > 0), (d / (1 - q)).max(axis=0) / top, 0.0)
    return estimate, d


def steep_columns(constraints, u, limit, sources):
    """(steep (k,) bool, max gauge (k,)) of the columns of ``u`` (n, k), column j from vertices
    ``sources[j]``: steep where some element's constraint gauge (|G u_j|, or the wedge's on a source's
    triangle: :class:`~warp_regdist.solvers.common.source_triangles.SourceTriangles` ``constraints``) exceeds
    ``limit`` or is NaN. A result whose relative stopping tests held can still break its constraints
    (iterations that blew up on needle-like elements, a consensus not yet settled): both solvers
    report such columns as not converged."""
    gradient = constraints.max_gauge(u, sources)
    return ~(gradient <= limit), gradient


def gradient_excess(constraints, diameters, u, block=64):
    """The steepness of the all-pairs columns u beyond their constraints, in units of max u:

        max over elements e and columns j of (gauge_ej - 1)_+ diam(e) / max u,

    what column j gains across element e above its bound (0 where every gauge is <= 1, or u = 0; NaN
    where u holds NaN or inf). The gauge is |(G u_j)_e|, or the wedge's on the triangles at vertex j
    (column j's source; :class:`~warp_regdist.solvers.common.source_triangles.SourceTriangles` ``constraints``).
    diameters (m,); u (n, k), ``block`` columns at a time. The all-pairs minimizer has none: an
    iterate's consensus can still be far from settled where its residuals and its change have
    become small (docs/method.md section 8).
    """
    return steepest_element(constraints, diameters, u, block)[0]


def steepest_element(constraints, diameters, u, block=64):
    """(:func:`gradient_excess` of u, e, j): the excess and the element e and column j where it is
    reached ((-1, -1) where it is 0 or NaN)."""
    m = diameters.size
    top, worst, where = float(u.max(initial=0.0)), 0.0, (-1, -1)
    if not math.isfinite(top):
        return math.nan, -1, -1
    for j0 in range(0, u.shape[1], block):
        g = (constraints.grad @ np.asarray(u[:, j0:j0 + block], dtype=np.float64)).reshape(m, 3, -1)
        over = (constraints.gauge(g, j0) - 1.0) * diameters[:, None]
        e, j = np.unravel_index(np.argmax(over), over.shape)
        if over[e, j] > worst:
            worst, where = float(over[e, j]), (int(e), j0 + int(j))
    return (worst / top if top > 0 else 0.0), *where


class ChangeTest:
    """Per column: every ``window`` iterations u_k is compared with u_(k - window); a column is
    settled while the last comparison moved it by at most eps max|u_k|:
    max_i |u_k - u_(k - window)| <= eps max_i |u_k| (or not at all; eps = inf: no change test,
    settled at every comparison of a nonzero u).

    Holds ``snapshot`` (rows, columns), the u of the last comparison (``reset``'s dtype, else
    the first ``update``'s), and ``settled`` (columns,) bool. Before ``reset`` the first
    ``update`` only records u.
    """

    def __init__(self, window, eps, columns):
        if not (isinstance(window, (int, np.integer)) and window >= 1):
            raise ValueError(f"expected a change-test window as an integer >= 1, got {window!r}")
        self.window, self.eps = int(window), float(eps)  # a Python float keeps float32 columns in float32
        self.snapshot = None
        self.settled = np.zeros(columns, dtype=bool)

    def due(self, k):
        """Whether iteration k compares (every ``window`` iterations)."""
        return k % self.window == 0

    def reset(self, u0):
        """Start from u0 (rows, columns), e.g. zeros or a warm start's u: the next ``update`` compares with it."""
        self.snapshot = np.array(u0)
        self._unsettle()

    def update(self, u):
        """Compare the first c columns with ``u`` (rows, c) host values, record u; returns settled[:c]."""
        c = u.shape[1]
        if self.snapshot is None:
            self.snapshot = np.zeros((u.shape[0], self.settled.size), dtype=u.dtype)
        else:
            moved = np.subtract(u, self.snapshot[:, :c])
            self._judge(np.abs(moved, out=moved).max(axis=0), u)
        self.snapshot[:, :c] = u
        return self.settled[:c]

    def _judge(self, moved, u):
        """settled[:c] from moved = max |u - snapshot| per column (c,)."""
        with np.errstate(invalid="ignore"):  # eps = inf times max |u| = 0
            self.settled[:moved.size] = (moved == 0) | (moved <= self.eps * np.abs(u).max(axis=0))

    def _unsettle(self):
        self.settled[:] = False

    def state(self):
        """The test's state as a dict of arrays: ``snapshot`` itself (None before any update; not
        a copy, it can be as large as the all-pairs matrix) and copies of the per-column flags."""
        return dict(snapshot=self.snapshot, settled=self.settled.copy())

    def restore(self, state):
        """The state of :meth:`state` back; the test takes ``snapshot`` over (updates write into it)."""
        self.snapshot = state["snapshot"]
        self.settled[:] = state["settled"]


class ExtrapolatedChangeTest(ChangeTest):
    """Per column, with c_k = max_i |u_k - u_(k - window)| / max(max_i u_k, 1e-300) (u >= 0) and k the
    iteration of the comparison: settled while

        change = max(c_k / (1 - q),  c_(k - window) min(k / window, 1 / (1 - rate_cap))) <= eps,
        q = min(c_k / c_(k - window), rate_cap),

    the change still to come if u converged no faster than at the rate of the last two windows (the
    rest of a geometric series, its rate capped as in :func:`vertex_extrapolation`) nor than like 1 / k
    (u_k - u_inf ~ 1 / k leaves about k / window windows' changes to come, counted with the previous
    window's, which is the larger while c shrinks; at most as many windows as the capped rate gives).
    All-pairs iterates on obtuse meshes creep at about 1 / k, where the geometric rest alone fell up
    to 14 times short of the error at the stop (docs/design/all-pairs.md). change is inf before the
    third comparison (the first only records u), 0 once u stops moving. eps = inf: always settled.

    Holds ``window_change`` (c of the last comparison) and ``change`` (columns,) besides
    ``snapshot`` and ``settled``.
    """

    def __init__(self, window, eps, columns, rate_cap=ESTIMATE_RATE_CAP):
        self.window_change = np.full(columns, math.inf)
        self.change = np.full(columns, math.inf)
        self.iteration, self.rate_cap = 0, rate_cap
        super().__init__(window, eps, columns)
        self._unsettle()

    def update(self, u, iteration):
        """Compare the first c columns with ``u`` (rows, c), the iterate after ``iteration`` iterations."""
        self.iteration = iteration
        return super().update(u)

    def _judge(self, moved, u):
        top = u.max(axis=0)
        windows = min(self.iteration / self.window, 1.0 / (1.0 - self.rate_cap))
        for j in range(moved.size):
            c = float(moved[j] / max(top[j], 1e-300))
            before = self.window_change[j]
            if c == 0.0:  # u did not move: a fixed point
                self.change[j] = 0.0
            elif before < math.inf:
                q = c / before if c < self.rate_cap * before else self.rate_cap
                self.change[j] = max(c / (1.0 - q), before * windows)
            else:  # the first comparison
                self.change[j] = math.inf
            self.window_change[j] = c
        self.settled[:moved.size] = self.change[:moved.size] <= self.eps

    def _unsettle(self):
        self.window_change[:] = self.change[:] = math.inf
        self.settled[:] = self.change <= self.eps

    def state(self):
        return dict(snapshot=self.snapshot, window_change=self.window_change.copy(), change=self.change.copy())

    def restore(self, state):
        self.snapshot = state["snapshot"]
        self.window_change[:] = state["window_change"]
        self.change[:] = state["change"]
        self.settled[:] = self.change <= self.eps
