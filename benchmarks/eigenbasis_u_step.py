"""Time of the eigenbasis engine's U-step (EigenbasisUStep) against six general products, one process.

    python benchmarks/eigenbasis_u_step.py                 # cat_rr decimated to 500 and 1,000, cat_rr
    python benchmarks/eigenbasis_u_step.py --repeats 9 --dtypes float32
    python benchmarks/eigenbasis_u_step.py --out benchmarks/results/eigenbasis_u_step_floor.csv

The package's U-step writes every product with a symmetric middle factor S = L + L^T as one
triangular product and one symmetric rank-2k update, and Phi^T Diag(mu) Phi as two rank-k updates:
8 n^3 flops. The baseline is the same solve written as six general products (12 n^3 flops):

    P = Phi ((Phi^T C Phi) * dinv),   mu from diag(P Phi^T),
    P += Phi ((Phi^T Diag(mu) Phi) * dinv),   U = P Phi^T,   symmetrized.

Both run on the same setup (the real stiffness and areas of each mesh, intrinsic operators) and the
same symmetric right-hand side, alternated, REPEATS calls each: the median seconds of each, their
ratio and the max difference of the two U in units of the largest |U|; and the floor, four general
products of the same size (8 n^3 flops at this machine's GEMM rate), alternated with both. Every
product is scipy's BLAS: numpy's wheel brings its own OpenBLAS, whose threads spin idle for a while
after each product and slow the other library's next one. Also the U-step's setup (eigendecomposition
and the diagonal's response), the engine's ms per iteration (30 iterations from zeros, after its
setup) for the share of the U-step in it, the same with a^T U^2 a as numpy's product (``numpy_pairs``)
for that interference in the engine, and the consensus engine's (worker processes on all cores) on
the same problem. Writes benchmarks/results/eigenbasis_u_step.csv (or ``--out``).
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np
import scipy.linalg as sl
import warp as wp

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import stopping  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.kernels.all_pairs import U2, X2  # noqa: E402
from warp_regdist.kernels.element_core import G2, R2, Z2  # noqa: E402
from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisADMM, EigenbasisUStep  # noqa: E402

RESULTS = os.path.join(HERE, "results", "eigenbasis_u_step.csv")
ITERATIONS = 30


def six_products(step, R, scale):
    """The U-step of ``step`` (an EigenbasisUStep) as six general products (scipy's BLAS, the package's):
    the baseline."""
    Phi, s, dinv, n, dt = step.Phi, step.s, step.dinv, step.n, step.dtype.type
    gemm = sl.get_blas_funcs("gemm", dtype=step.dtype)
    C = (s[:, None] * R.astype(step.dtype, copy=False)) * s[None, :]
    P = gemm(1.0, Phi, gemm(1.0, gemm(1.0, Phi, C, trans_a=1), Phi) * dinv)
    diag = np.einsum("ij,ij->i", P, Phi, dtype=np.float64) / scale
    sol = sl.lu_solve(step.border, np.concatenate([-s.astype(np.float64) ** 2 * diag,
                                                   [-R.sum(dtype=np.float64) / scale]]))
    P += gemm(1.0, Phi, gemm(scale, Phi * sol[:n].astype(step.dtype)[:, None], Phi, trans_a=1) * dinv)
    U = s[:, None] * gemm(1 / scale, P, Phi, trans_b=1) * s[None, :] + dt(sol[n])
    U = 0.5 * (U + U.T)
    np.fill_diagonal(U, 0)
    return U


def numpy_pairs(state):
    """``EigenbasisADMM.consensus`` with a^T U^2 a as numpy's product, whose wheel brings its own OpenBLAS:
    the baseline of the engine's iteration."""
    acc = state.view("acc").reshape(5, -1)
    U = state._matrix("U")
    pairs = np.zeros(5)
    pairs[X2] = pairs[U2] = float(state._areas @ (state._areas_dt @ (U * U)).astype(np.float64))
    return acc[[R2, G2, Z2]].astype(np.float64), pairs


def rows_for(name, mesh, dtypes, repeats):
    ops = wrd.build_operators(mesh, "intrinsic")
    n = mesh.n_vertices
    rows = []
    for dtype in dtypes:
        t0 = time.perf_counter()
        step = EigenbasisUStep(ops.stiffness, ops.vertex_volumes, dtype)
        setup = time.perf_counter() - t0
        R = np.random.default_rng(0).standard_normal((n, n))
        R += R.T
        A, gemm = np.asfortranarray(R, dtype=dtype), sl.get_blas_funcs("gemm", dtype=np.dtype(dtype))
        times = {"package": [], "six products": [], "floor": []}
        for _ in range(repeats):
            for label, f in (("package", step), ("six products", lambda R, s: six_products(step, R, s)),
                             ("floor", lambda R, s: [gemm(1.0, A, A) for _ in range(4)])):
                t0 = time.perf_counter()
                f(R, 2.5)
                times[label].append(time.perf_counter() - t0)
        U = step(R, 2.5)
        difference = np.abs(U.astype(np.float64) - six_products(step, R, 2.5)).max()
        iteration_ms = {}
        package_pairs = EigenbasisADMM.consensus
        for engine in ("eigenbasis", "numpy product", "consensus"):
            solver = wrd.AllPairsSolver(mesh, 0.03, device="cpu", dtype=dtype, triangulation="intrinsic",
                                        options=wrd.AllPairsOptions(engine="consensus" if engine == "consensus"
                                                                    else "eigenbasis"))
            getattr(solver, "hierarchy" if engine == "consensus" else "u_step")  # the setup, outside the timing
            EigenbasisADMM.consensus = numpy_pairs if engine == "numpy product" else package_pairs
            try:
                res = solver.solve(max_iterations=ITERATIONS)
            finally:
                EigenbasisADMM.consensus = package_pairs
            iteration_ms[engine] = round(1e3 * res.seconds / res.iterations, 1)
        package, baseline = (float(np.median(times[k])) for k in ("package", "six products"))
        rows.append(dict(mesh=name, n=n, dtype=dtype, threads=len(os.sched_getaffinity(0)), setup_s=round(setup, 2),
                         package_ms=round(1e3 * package, 1), six_products_ms=round(1e3 * baseline, 1),
                         ratio=round(baseline / package, 2), floor_ms=round(1e3 * float(np.median(times["floor"])), 1),
                         difference=float(f"{difference / np.abs(U).max():.2e}"),
                         iteration_ms=iteration_ms["eigenbasis"], numpy_iteration_ms=iteration_ms["numpy product"],
                         consensus_iteration_ms=iteration_ms["consensus"]))
        print(rows[-1], flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dtypes", nargs="+", default=["float32", "float64"])
    parser.add_argument("--decimations", type=int, nargs="*", default=[500, 1000], help="cat_rr decimated to these")
    parser.add_argument("--no-full", dest="full", action="store_false", help="leave out cat_rr itself")
    parser.add_argument("--out", default=RESULTS)
    args = parser.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    for dtype in args.dtypes:  # warm the kernel cache
        wrd.all_pairs(meshes.cube_sphere(3), 0.03, device="cpu", dtype=dtype, engine="eigenbasis", max_iterations=2)
    cases = [("cat_rr decimated", stopping.decimated("cat_rr", v)) for v in args.decimations]
    cases += [("cat_rr", meshes.shared_mesh("cat_rr"))] if args.full else []
    rows = [row for name, mesh in cases for row in rows_for(name, mesh, args.dtypes, args.repeats)]
    print(markdown_table(rows))
    write_csv(rows, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
