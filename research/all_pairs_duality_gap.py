"""A duality-gap bound on the all-pairs error: is it tight enough to stop on? (issue 41, item 3)

    python research/all_pairs_duality_gap.py                       # the two exact minimizers in tests/data
    python research/all_pairs_duality_gap.py --larger --cache /tmp/stopping

The all-pairs problem over symmetric U with a zero diagonal (docs/method.md section 5),

    f(U) = -a^T U a + alpha sum_j a_j U_j^T W U_j,   |(G U_j)_e| <= 1 for every element e and column j,

is convex, so any multipliers bound its minimum f* from below. With Y (3m, n) the multipliers of the
symmetric splitting (research/symmetric_all_pairs.py: Z = G U, U-step
(alpha + rho/2)(W U M + M U W) = a a^T + sym(D (rho Z - Y) M) + Diag(mu)), the Lagrangian's minimum
over U is one solve in the U-step's eigenbasis:

    g(Y) = -(1/2) <C, U_C> - sum_j a_j sum_e |e| |Y_ej|,   C = a a^T - sym(D Y M) + Diag(mu),
    alpha (W U_C M + M U_C W) = C  over symmetric U_C,

mu the diagonal's multipliers of the prototype's U-step (its quadrature), shifted so that C has no
constant part (any mu gives a bound; the U-step's makes it nearly the best),
and g(Y) <= f* <= f(U') for U', the matrix symmetrized with a zero diagonal and scaled into the
constraint by 1 / max(1, max |G U|). The
quadratic's curvature then bounds the distance to the minimizer U*:

    (alpha / 2) <E, W E M + M E W> <= f(U') - g(Y) = gap,   E = U' - U*,
    ||E||_M = (sum_ij a_i a_j E_ij^2)^(1/2) <= (2 gap / (alpha kappa))^(1/2),

kappa the smallest eigenvalue of W E M + M E W against M E M on symmetric E with a zero diagonal
(inverse iteration with the U-step). The table compares that bound, as a mass-weighted RMS in % of
max U (rms_bound_pct), with the actual RMS and max errors against the minimizer: Clarabel's for the
two stored cases, for ``--larger`` the cached 5,000-iteration runs of benchmarks/all_pairs.py
--larger on intrinsic operators (whose own gap the last row of each mesh reports), and the package's
AllPairsSolver (at accuracy 0.01 and 0.005, and 0.001 on the larger meshes) bounded with the
prototype's last multipliers. The energy
bounds no single entry: on the product of two surfaces (four dimensions) point values are not
controlled by the Dirichlet energy, which is why the table gives the RMS. Each row also gives max |G U|
and the max error of the matrix itself, unscaled (result_max_pct). Writes
benchmarks/results/all_pairs_duality_gap.csv (``--larger``: all_pairs_duality_gap_larger.csv).
"""

import argparse
import itertools
import os
import sys
import time
import warnings

import numpy as np
import scipy.linalg as sl

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from symmetric_all_pairs import HERE, SymmetricADMM  # noqa: E402

sys.path.insert(0, HERE)
import stopping  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from all_pairs import LARGER, REFERENCE_ITERATIONS  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_duality_gap.csv")
LARGER_RESULTS = os.path.join(HERE, "results", "all_pairs_duality_gap_larger.csv")


class DualityGap:
    """The bound of the module docstring on one prototype (its operators, U-step and alpha)."""

    def __init__(self, prototype, kappa_iterations=40):
        self.p = prototype
        self.kappa = self._kappa(kappa_iterations)

    def objective(self, U):
        """f(U) for symmetric U (n, n)."""
        p, a = self.p, self.p.AV
        return float(p.alpha * np.einsum("ij,ij->j", U, p.stiffness @ U) @ a - a @ U @ a)

    def feasible(self, U):
        """U symmetrized with a zero diagonal, scaled by 1 / max(1, max |G U|)."""
        U = 0.5 * (U + U.T)
        np.fill_diagonal(U, 0.0)
        g = np.linalg.norm((self.p.G @ U).reshape(self.p.m, 3, -1), axis=1).max()
        return U / max(1.0, g)

    def lower(self, Y):
        """g(Y): the Lagrangian's minimum at the multipliers Y (3m, n) and the diagonal's multipliers
        mu of the prototype's U-step, shifted so that C + Diag(mu) has no constant part; the minimum is
        then over all symmetric U, exact in the eigenbasis."""
        p, a = self.p, self.p.AV
        B = p.D @ Y * a[None, :]
        C = np.outer(a, a) - 0.5 * (B + B.T)
        C += np.diag(self._diagonal_multipliers(C))
        Phi, s = p.Phi, p.s
        U = s[:, None] * (Phi @ ((Phi.T @ (s[:, None] * C * s[None, :]) @ Phi) * p.dinv) @ Phi.T) * s[None, :] / p.alpha
        element = np.linalg.norm(Y.reshape(p.m, 3, -1), axis=1)
        return float(-0.5 * np.sum(C * U) - p.element_volumes @ element @ a)

    def _diagonal_multipliers(self, C):
        """mu (n,) of alpha (W U M + M U W) = C + Diag(mu), diag(U) = 0, by the prototype's quadrature of
        the diagonal's response, shifted so that sum(C) + sum(mu) = 0."""
        p, n = self.p, len(self.p.AV)
        PY = p.Phi @ ((p.Phi.T @ (p.s[:, None] * C * p.s[None, :]) @ p.Phi) * p.dinv)
        diagonal = np.einsum("ij,ij->i", PY, p.Phi) / p.alpha
        sol = sl.lu_solve(p.border, np.concatenate([-p.s ** 2 * diagonal, [-C.sum() / p.alpha]]))
        mu = p.alpha * sol[:n] * p.AV
        return mu - (C.sum() + mu.sum()) / n

    def _kappa(self, iterations):
        """Smallest <E, W E M + M E W> / <E, M E M> over symmetric E with zero diagonal, as the Rayleigh
        quotient after ``iterations`` of inverse iteration (from above: the bound is as exact as it)."""
        p, a = self.p, self.p.AV
        E = np.random.default_rng(0).standard_normal((len(a),) * 2)
        E = 0.5 * (E + E.T)
        np.fill_diagonal(E, 0.0)
        for _ in range(iterations):
            E = p.u_step(a[:, None] * E * a[None, :], 1.0)
            np.fill_diagonal(E, 0.0)
            E /= np.sqrt(np.sum(a[:, None] * E ** 2 * a[None, :]))
        T = np.asarray(p.stiffness @ E) * a[None, :]
        return float(np.sum(E * (T + T.T)))

    def bound(self, U, Y):
        """(U', its gap f(U') - g(Y), the RMS bound on U' - U* relative to max U') for the matrix U
        and the multipliers Y."""
        Uf = self.feasible(U)
        gap = max(self.objective(Uf) - self.lower(Y), 0.0)
        return Uf, gap, np.sqrt(2 * gap / (self.p.alpha * self.kappa)) / self.p.AV.sum() / Uf.max()


def errors(U, exact, a):
    """(mass-weighted RMS, max) of |U - exact| in units of max exact."""
    E = U - exact
    return (np.sqrt(np.sum(a[:, None] * E ** 2 * a[None, :])) / a.sum() / exact.max(), np.abs(E).max() / exact.max())


def bound_row(gap, U, Y, exact):
    """The columns of one matrix U (n, n): its max |G U|, the relative gap and RMS bound of U' against
    the multipliers Y, the RMS and max errors of U' and the max error of U itself."""
    a = gap.p.AV
    Uf, g, bound = gap.bound(U, Y)
    rms, top = errors(Uf, exact, a)
    return dict(max_gradient=round(float(np.linalg.norm((gap.p.G @ U).reshape(gap.p.m, 3, -1), axis=1).max()), 4),
                relative_gap=float(f"{g / abs(gap.objective(Uf)):.3g}"), rms_bound_pct=round(100 * bound, 4),
                rms_pct=round(100 * rms, 4), max_pct=round(100 * top, 4),
                bound_over_rms=round(bound / rms, 1) if rms > 0 else None,
                result_max_pct=round(100 * errors(U, exact, a)[1], 4))


def trace_rows(name, mesh, alpha_hat, triangulation, exact, iterations, every):
    """Rows along one run of the prototype (the reference run's penalty schedule), and (gap, last Y)."""
    prototype = SymmetricADMM(mesh, alpha_hat, triangulation)
    gap = DualityGap(prototype)
    rows, t0 = [], time.perf_counter()
    schedule = (lambda k: prototype.L * min(128.0, 16.0 * 2 ** (k // 300)))
    for k, (U, _, Y) in enumerate(itertools.islice(prototype.iterates(schedule), iterations), 1):
        if k % every and k != iterations:
            continue
        rows.append(dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, triangulation=triangulation,
                         run="symmetric", iterations=k, **bound_row(gap, U, Y, exact),
                         seconds=round(time.perf_counter() - t0, 1)))
        print(rows[-1], file=sys.stderr, flush=True)
    return rows, gap, Y.copy()


def package_rows(name, mesh, alpha_hat, triangulation, exact, gap, Y, accuracies):
    """The package's results at ``accuracies``, bounded with the multipliers Y of the prototype's run."""
    rows = []
    solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation=triangulation)
    for accuracy in accuracies:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            res = solver.solve(accuracy=accuracy, max_iterations=8000)
        rows.append(dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, triangulation=triangulation,
                         run=f"package accuracy {accuracy:g}", iterations=res.iterations,
                         **bound_row(gap, np.asarray(res.distance, dtype=np.float64), Y, exact),
                         seconds=round(res.seconds, 1)))
        print(rows[-1], file=sys.stderr, flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--larger", action="store_true", help="the decimations of benchmarks/all_pairs.py --larger")
    parser.add_argument("--cache", default=None, help="with --larger: the folder of benchmarks/all_pairs.py's references")
    parser.add_argument("--iterations", type=int, default=2000, help="prototype iterations on the exact cases")
    parser.add_argument("--every", type=int, default=250, help="iterations between two bounds")
    parser.add_argument("--output", default=None, help="CSV (default: benchmarks/results/all_pairs_duality_gap[_larger].csv)")
    args = parser.parse_args()
    rows = []
    if args.larger:
        if args.cache is None:
            parser.error("--larger needs --cache")
        for name, vertices, alpha_hat in LARGER:
            mesh = stopping.decimated(name, vertices)
            key = f"symmetric {REFERENCE_ITERATIONS} {name} decimated {mesh.n_vertices} {alpha_hat} intrinsic"
            reference = stopping.cached(args.cache, key, None)
            if reference is None:
                print(f"no reference {key!r} in {args.cache}: run benchmarks/all_pairs.py --larger first", file=sys.stderr)
                continue
            trace, gap, Y = trace_rows(f"{name} decimated", mesh, alpha_hat, "intrinsic", reference,
                                       REFERENCE_ITERATIONS, args.every)
            rows += trace + package_rows(f"{name} decimated", mesh, alpha_hat, "intrinsic", reference, gap, Y,
                                         (0.01, 0.005, 0.001))
    else:
        tests = os.path.join(HERE, "..", "tests", "data")
        for file, name in (("all_pairs_bumpy42.npz", "bumpy icosphere"), ("stopping_cat80.npz", "cat_rr decimated")):
            d = np.load(os.path.join(tests, file))
            mesh = wrd.Mesh(d["vertices"], d["faces"].astype(np.int64))
            for alpha_hat, exact in ((0.03, d["U_003"]), (0.1, d["U_01"])):
                trace, gap, Y = trace_rows(name, mesh, alpha_hat, "mesh", exact, args.iterations, args.every)
                rows += trace + package_rows(name, mesh, alpha_hat, "mesh", exact, gap, Y, (0.01, 0.005))
    write_csv(rows, args.output or (LARGER_RESULTS if args.larger else RESULTS))
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
