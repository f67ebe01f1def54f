"""A multilevel warm start for the eigenbasis engine (issue 41, a measurement).

    python research/all_pairs_multilevel.py --cache /tmp/stopping
    python research/all_pairs_multilevel.py --cache /tmp/stopping --cases 'cat_rr 500 0.03' --coarse 4

The iteration count of all pairs grows with n. A coarse mesh (the same surface decimated ``--coarse``
times fewer vertices) is solved first at the same accuracy; its matrix U_c (n_c, n_c) is carried to the
fine mesh by the barycentric map P (n, n_c) of each fine vertex's closest point on the coarse surface,
U_0 = P U_c P^T with its diagonal set to 0, and the fine run starts from X = U = U_0 and the element
variable v = G U_0 (Z = Proj(G U_0); the dual Y = rho_v (v - Z) only where |G U_0| > 1). Variants of
the fine run:

- ``cold``: the package's engine from zero;
- ``warm``: from U_0, the penalty schedule from its start (2 L doubling every 100 iterations to 32 L);
- ``warm_high``: from U_0 at rho = 32 L throughout (the schedule's end);
- ``cold_high``: from zero at rho = 32 L throughout (the control of ``warm_high``).

Runs ``AllPairsSolver(engine="eigenbasis").solve(accuracy=...)`` with the run's start replaced, on
decimations of the shared meshes against their 5,000-iteration references in ``--cache`` (the ones
benchmarks/all_pairs.py computes), recording the max error after 10, 50 and 200 iterations too. Writes
benchmarks/results/all_pairs_multilevel.csv and prints a table; ``seconds`` of a warm run include the
coarse solve.
"""

import argparse
import os
import sys
import time

import numpy as np
import scipy.sparse as sp

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)

import all_pairs as bench  # noqa: E402
import stopping  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.solvers.all_pairs import solver as all_pairs_admm  # noqa: E402
from warp_regdist.solvers.common.admm import PenaltySchedule  # noqa: E402
from warp_regdist.solvers.all_pairs.run import PairsRun  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_multilevel.csv")
VARIANTS = ("cold", "cold_high", "warm", "warm_high")


def prolongation(fine, coarse, k=8):
    """P (n, n_c): the barycentric coordinates of each fine vertex's closest point on the coarse surface,
    among the triangles around its ``k`` nearest coarse vertices."""
    import trimesh
    from scipy.spatial import cKDTree

    V, F, X = coarse.vertices, coarse.elements, fine.vertices
    _, near = cKDTree(V).query(X, k=k)
    ring = sp.csr_matrix((np.ones(F.size), (F.ravel(), np.repeat(np.arange(len(F)), 3))), shape=(len(V), len(F)))
    point, face = np.zeros_like(X), np.zeros(len(X), dtype=np.int64)
    for i in range(len(X)):
        cand = np.unique(ring[near[i]].indices)
        q = trimesh.triangles.closest_point(V[F[cand]], np.repeat(X[i:i + 1], len(cand), axis=0))
        d = np.linalg.norm(q - X[i], axis=1)
        j = int(np.argmin(d))
        point[i], face[i] = q[j], cand[j]
    bary = np.clip(trimesh.triangles.points_to_barycentric(V[F[face]], point), 0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(len(X)), 3)
    return sp.csr_matrix((bary.ravel(), (rows, F[face].ravel())), shape=(len(X), len(V)))


class StartedRun(PairsRun):
    """PairsRun that starts from ``U0`` (class attribute; None: cold) and records the max error against
    ``reference`` after each iteration of ``MARKS``."""

    U0 = reference = None
    errors = {}

    def iterate(self, t0):
        if self.U0 is not None:
            st, U0 = self.state, self.U0
            n, nb, W = st.n, st.setup.nb, st.setup.W
            lanes = np.zeros((n, nb * W))
            lanes[:, :n] = U0
            v = np.zeros((3 * st.m, nb * W))
            v[:, :n] = st.setup.operators.grad.tocsr() @ U0
            st.put("U", lanes.reshape(n, nb, W).astype(st.view("U").dtype))
            st.put("v", v.reshape(st.m, 3, nb, W).astype(st.view("v").dtype))
            st.rho_v = self.schedule.rho(0)
            st.divergences_from_element_state()
            self.change_test.reset(st.view("U").reshape(-1, 1))
        return super().iterate(t0)

    def status(self, it):
        if it in MARKS and StartedRun.reference is not None:
            ref = StartedRun.reference
            StartedRun.errors[it] = float(np.abs(self.state.distance() - ref).max() / ref.max())
        return super().status(it)


MARKS = (10, 50, 200)


def solve(mesh, alpha_hat, accuracy, dtype, U0=None, schedule=None, reference=None):
    options = wrd.AllPairsOptions(engine="eigenbasis", schedule=schedule)
    solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", dtype=dtype, workers=1, triangulation="intrinsic",
                                options=options)
    StartedRun.U0, StartedRun.reference, StartedRun.errors = U0, reference, {}
    all_pairs_admm.PairsRun = StartedRun
    try:
        return solver.solve(accuracy=accuracy), dict(StartedRun.errors)
    finally:
        all_pairs_admm.PairsRun = PairsRun


def coarse_start(mesh, path, alpha_hat, accuracy, dtype, ratio):
    """The coarse solve carried to ``mesh``: (U_0, coarse vertices, its iterations, seconds)."""
    coarse = stopping.decimated(path, round(mesh.n_vertices / ratio))
    t0 = time.perf_counter()
    res, _ = solve(coarse, alpha_hat, accuracy, dtype)
    P = prolongation(mesh, coarse)
    U0 = P @ res.distance @ P.T
    U0 = 0.5 * (U0 + U0.T)
    np.fill_diagonal(U0, 0.0)
    return U0, coarse.n_vertices, res.iterations, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", required=True, help="folder of the 5,000-iteration references")
    ap.add_argument("--cases", nargs="+", default=None,
                    help="'mesh vertices alpha_hat' (a shared mesh or a file); default: benchmarks/all_pairs.py LARGER")
    ap.add_argument("--coarse", type=float, nargs="+", default=[4.0], help="fine / coarse vertex ratio")
    ap.add_argument("--accuracy", type=float, default=0.01)
    ap.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    cases = bench.parse_cases(args.cases)
    rows = []
    for (path, _, _), (name, mesh, alpha_hat, reference, _) in zip(cases, bench.larger_cases(args.cache, "intrinsic",
                                                                                                cases)):
        L = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation="intrinsic").operators.length_scale
        runs = [(v, "") for v in args.variants if v.startswith("cold")]
        runs += [(v, r) for r in args.coarse for v in args.variants if v.startswith("warm")]
        for variant, ratio in runs:
            U0, extra = None, {}
            if variant.startswith("warm"):
                U0, nc, itc, secc = coarse_start(mesh, path, alpha_hat, args.accuracy, args.dtype, ratio)
                extra = dict(coarse_n=nc, coarse_iterations=itc, coarse_s=round(secc, 1),
                             start_error_pct=round(100 * float(np.abs(U0 - reference).max() / reference.max()), 2))
            schedule = PenaltySchedule(32.0, 32.0, float("inf"), L) if variant.endswith("_high") else None
            res, errors = solve(mesh, alpha_hat, args.accuracy, args.dtype, U0, schedule, reference)
            row = dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, dtype=args.dtype, accuracy=args.accuracy,
                       ratio=ratio, variant=variant,
                       **{f"error_{k}_pct": round(100 * errors.get(k, np.nan), 2) for k in MARKS},
                       **bench._run_columns(res, reference), seconds=round(res.seconds + extra.get("coarse_s", 0.0), 1),
                       **extra)
            rows.append(row)
            print(row, flush=True)
            write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
