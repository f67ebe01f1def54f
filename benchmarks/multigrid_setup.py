"""Multigrid setup: this package's smoothed aggregation against pyamg's, same V-cycle in Warp.

    python benchmarks/multigrid_setup.py               # spot (4,764), cube spheres 100k and 1M
    python benchmarks/multigrid_setup.py --cases spot cube129

pyamg (``pip install pyamg``) is the field's standard smoothed-aggregation code. Its
hierarchy (``smoothed_aggregation_solver``: symmetric strength, standard aggregation,
Jacobi-smoothed prolongator with omega = 4/3 / rho(D^-1 A), coarsening to 256 unknowns)
is converted into this package's form M_l = S_l + R_l^T M_l+1 R_l (warp_regdist/
multigrid.py: the same damped-Jacobi smoother and dense coarse pseudo-inverse), so only
the aggregates and prolongators differ, and both are applied by the same Warp kernels.
Per mesh (stiffness matrix W_D, each in its own process): setup seconds, levels, the
operator complexity sum nnz(S_l, R_l) / nnz(A_0), and the BatchedPCG iterations and
seconds to |r| <= 1e-6 |b| for 1 and 8 columns (1-3 sources each), float64 on the CPU.
Prints a markdown table and writes benchmarks/results/multigrid_setup.csv.
"""

import argparse
import importlib.resources
import os
import sys
import time

import numpy as np
import scipy.sparse as sp
import warp as wp

wp.config.log_level = wp.LOG_WARNING
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import warp_regdist as wrd  # noqa: E402
from meshes import cube_sphere  # noqa: E402
from pcg import problem  # noqa: E402
from report import markdown_table, print_result, run_child, write_csv  # noqa: E402
from warp_regdist.linalg import multigrid  # noqa: E402
from warp_regdist.linalg.pcg import BatchedPCG  # noqa: E402

CASES = {"spot": None, "cube129": 129, "cube408": 408}
RTOL = 1e-6


def mesh_of(case):
    if CASES[case] is None:
        with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as p:
            return wrd.load_mesh(p)
    return cube_sphere(CASES[case])


def pyamg_hierarchy(K, coarse_size=256, theta=0.0):
    """pyamg's smoothed-aggregation levels as a :class:`~warp_regdist.linalg.multigrid.Hierarchy`."""
    import pyamg

    ml = pyamg.smoothed_aggregation_solver(sp.csr_matrix(K), strength=("symmetric", {"theta": theta}),
                                           max_coarse=coarse_size, max_levels=20, presmoother=None,
                                           postsmoother=None, improve_candidates=None)
    smoothers, restrictions = [], []
    for level in ml.levels[:-1]:
        A, P = level.A.tocsr(), level.P.tocsr()
        diag = A.diagonal()
        dinv = np.where(diag > 0, 1.0 / np.where(diag > 0, diag, 1.0), 0.0)
        w = (4.0 / 3.0) / multigrid._spectral_radius(A, dinv)
        Dinv = sp.diags(dinv)
        smoothers.append((2 * w * Dinv - w * w * (Dinv @ A @ Dinv)).tocsr())
        restrictions.append((P.T - w * ((P.T @ A) @ Dinv)).tocsr())
    for M in smoothers + restrictions:
        M.eliminate_zeros()
        M.sort_indices()
    return multigrid.Hierarchy(smoothers, restrictions, multigrid._pseudo_inverse(ml.levels[-1].A.tocsr()))


def pcg_run(K, hierarchy, cols):
    """(iterations, seconds) of one solve from x = 0 (after a warm-up solve that records the launches)."""
    rhs, mask, W = problem(K, cols, "float64")
    pcg = BatchedPCG(K, wp.float64, W, cols // W, "cpu", preconditioner=hierarchy)
    x = wp.zeros_like(rhs)
    pcg.solve(rhs, x, mask, RTOL, 1000)
    x.zero_()
    t = time.perf_counter()
    it, rel = pcg.solve(rhs, x, mask, RTOL, 1000)
    assert np.all(rel <= RTOL), rel.max()
    return it, time.perf_counter() - t


def run_case(case):
    K = wrd.build_operators(mesh_of(case)).stiffness
    rows = []
    for name, build in (("warp_regdist", multigrid.smoothed_aggregation), ("pyamg", pyamg_hierarchy)):
        t = time.perf_counter()
        H = build(K)
        setup = time.perf_counter() - t
        nnz = sum(M.nnz for M in H.smoothers + H.restrictions) + H.coarse_inverse.size
        row = dict(mesh=case, n=K.shape[0], setup=name, setup_s=setup, levels=len(H.sizes),
                   coarse=H.sizes[-1], complexity=nnz / K.nnz)
        for cols in (1, 8):
            row[f"cg_it_{cols}col"], row[f"cg_s_{cols}col"] = pcg_run(K, H, cols)
        rows.append(row)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--case", help=argparse.SUPPRESS)
    parser.add_argument("--output", default=os.path.join(HERE, "results", "multigrid_setup.csv"))
    args = parser.parse_args()
    if args.case:
        print_result(run_case(args.case))
        return
    rows = []
    for case in args.cases:
        rows += run_child(__file__, case) or []
        write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
