"""Symmetry error and triangle-inequality violations of single-source distance matrices
(paper Fig. 11-12, Table 3).

    python benchmarks/symmetry.py                                  # blob, 386 vertices
    python benchmarks/symmetry.py --cube 12 --alpha-hats 0 0.2 --t-coefs 1   # 866 vertices

On the generated blob (cube N=8: 386 vertices), D[x, :] = distance from vertex x for every x,
by exact geodesics (MMP), the heat method (t_coef in T_COEFS) and this package
(``solve_many`` over all vertices, alpha_hat in ALPHA_HATS).  Columns:
``metrics.symmetry_error`` (mean and max of |D - D^T| / sqrt(A)) and
``metrics.triangle_inequality_violations`` (exact over all n^3 ordered triplets up to
``metrics.EXACT_TRIPLET_LIMIT``, else SAMPLES random ones) of D and of
its symmetrization (D + D^T) / 2 at tolerance 0, and of D beyond a tolerance of 1% of its
largest entry (violations too large to be solver round-off).  Prints a markdown table and
writes benchmarks/results/symmetry.csv (symmetry_N<cube>.csv for other sizes).
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import evaluation_meshes as em  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from compare import RESULTS, heat_solver, warm_up  # noqa: E402
from report import write_csv  # noqa: E402
from warp_regdist import metrics  # noqa: E402

N_CUBE = 8
T_COEFS = (1.0, 10.0, 100.0)
ALPHA_HATS = (0.0, 0.01, 0.03, 0.05, 0.1, 0.2)


SAMPLES = 10**7


def matrices(mesh, t_coefs, alpha_hats):
    """{method: ((n, n) matrix with rows = sources, seconds)}."""
    import igl
    n, F = mesh.n_vertices, mesh.faces.astype(np.int64)
    out = {}
    t = time.perf_counter()
    D = np.stack([igl.exact_geodesic(mesh.vertices, F, VS=np.array([i]), VT=np.arange(n)) for i in range(n)])
    out["exact (MMP)"] = (D, time.perf_counter() - t)
    for tc in t_coefs:
        t = time.perf_counter()
        solver = heat_solver(mesh, tc)[1]
        D = np.stack([solver.compute_distance(i) for i in range(n)])
        out[f"heat t_coef={tc:g}"] = (D, time.perf_counter() - t)
    for a in alpha_hats:
        t = time.perf_counter()
        res = wrd.DistanceSolver(mesh, alpha_hat=a, device="cpu").solve_many([[i] for i in range(n)])
        out[f"this alpha_hat={a:g}"] = (res.distance.T, time.perf_counter() - t)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cube", type=int, default=N_CUBE, help="blob resolution N (6 N^2 + 2 vertices), even")
    ap.add_argument("--alpha-hats", type=float, nargs="+", default=ALPHA_HATS)
    ap.add_argument("--t-coefs", type=float, nargs="+", default=T_COEFS)
    args = ap.parse_args()
    warm_up()
    mesh = em.blob(args.cube)
    n, area = mesh.n_vertices, wrd.build_operators(mesh).total_volume
    samples = None if float(n) ** 3 <= metrics.EXACT_TRIPLET_LIMIT else SAMPLES

    def share(M, tolerance=0.0):
        return metrics.triangle_inequality_violations(M, samples=samples, tolerance=tolerance)

    rows = []
    for method, (D, seconds) in matrices(mesh, args.t_coefs, args.alpha_hats).items():
        sym = metrics.symmetry_error(D, area)
        rows.append(dict(method=method, vertices=n, seconds=seconds, symmetry_mean=sym.mean(),
                         symmetry_max=sym.max(), violations=share(D), violations_symmetrized=share(0.5 * (D + D.T)),
                         violations_beyond_1pct=share(D, 0.01 * D.max())))
        print(rows[-1], flush=True)
    triplets = f"all {n ** 3:,} ordered triplets" if samples is None else f"{samples:,} random triplets"
    lines = [f"blob, {n} vertices, area {area:.2f}; {triplets}", "",
             "| method | time (all sources) | mean sym. error | max sym. error | violating triplets "
             "| violating, symmetrized | violating by > 1% of max |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['seconds']:.1f} s | {r['symmetry_mean']:.2e} | {r['symmetry_max']:.2e} "
                     f"| {100 * r['violations']:.3f} % | {100 * r['violations_symmetrized']:.3f} % "
                     f"| {100 * r['violations_beyond_1pct']:.3f} % |")
    print("\n".join(lines))
    name = "symmetry.csv" if args.cube == N_CUBE else f"symmetry_N{args.cube}.csv"
    write_csv(rows, os.path.join(RESULTS, name))


if __name__ == "__main__":
    main()
