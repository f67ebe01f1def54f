"""Time per CG iteration of BatchedPCG's three loops, in one process (medians of REPEATS solves).

    python benchmarks/pcg.py                       # spot (4,764 vertices)
    python benchmarks/pcg.py --repeats 9 --columns 1 64

On spot's stiffness matrix (masks with 1-3 sources per column, as the u-step has), for
each preconditioner (multigrid, jacobi), dtype and number of columns: the host-checked
loop (the host reads the device's ``running`` flag after every iteration,
check_every=1), the device-checked loop (check_every=4: up to 3 wasted preconditioner
applications per solve) and the captured loop (``capture=True``: the whole solve is one
replayed Warp graph whose loop is ``wp.capture_while``). Every solve starts from x = 0,
so all three do the same iterations. Prints a markdown table (ratio: the loop's time
per solve over the host-checked one's, same case) and writes benchmarks/results/pcg.csv.
"""

import argparse
import os
import sys
import time

import numpy as np
import warp as wp

wp.config.log_level = wp.LOG_WARNING
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.kernels.lanes import SCALARS, lane_type, lane_width  # noqa: E402
from warp_regdist.linalg.multigrid import smoothed_aggregation  # noqa: E402
from warp_regdist.linalg.pcg import BatchedPCG  # noqa: E402

RTOL = {("multigrid", "float64"): 1e-8, ("multigrid", "float32"): 1e-4,
        ("jacobi", "float64"): 1e-4, ("jacobi", "float32"): 1e-3}
LOOPS = {"host-checked": dict(check_every=1), "device-checked (4)": dict(check_every=4),
         "captured": dict(capture=True)}


def problem(K, cols, dtype, seed=0):
    """Lane arrays (rhs, mask) with 1-3 sources per column, and the lane width."""
    rng = np.random.default_rng(seed)
    n = K.shape[0]
    mask = np.ones((n, cols))
    for j in range(cols):
        mask[rng.choice(n, size=1 + j % 3, replace=False), j] = 0.0
    b = mask * rng.uniform(0.5, 1.5, size=(n, cols))
    W = lane_width(SCALARS[dtype], cols)
    V = lane_type(SCALARS[dtype], W)

    def lanes(a):
        out = wp.zeros((n, cols // W), dtype=V, device="cpu")
        out.assign(a.reshape(n, cols // W, W))
        return out

    return lanes(b), lanes(mask), W


def measure(K, hierarchy, preconditioner, dtype, cols, repeats):
    """Rows of one case: each loop's iterations and median time per solve and per iteration."""
    rhs, mask, W = problem(K, cols, dtype)
    spec = hierarchy if preconditioner == "multigrid" else "jacobi"
    solvers = {name: BatchedPCG(K, SCALARS[dtype], W, cols // W, "cpu", preconditioner=spec, **options)
               for name, options in LOOPS.items()}
    x = wp.zeros_like(rhs)
    rtol = RTOL[preconditioner, dtype]
    times = {name: [] for name in LOOPS}
    its = {}
    for r in range(repeats + 1):  # the first round records (and captures) the launches
        for name, pcg in solvers.items():  # interleaved, so load changes hit every loop alike
            x.zero_()
            t = time.perf_counter()
            its[name], _ = pcg.solve(rhs, x, mask, rtol, 5000)
            if r:
                times[name].append(time.perf_counter() - t)
    base = np.median(times["host-checked"])
    rows = []
    for name in LOOPS:
        t = float(np.median(times[name]))
        rows.append(dict(preconditioner=preconditioner, dtype=dtype, columns=cols, loop=name, rtol=rtol,
                         iterations=its[name], ms_per_solve=1e3 * t, us_per_iteration=1e6 * t / its[name],
                         ratio=t / base))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default=None, help="surface file (default: spot, shipped with the package)")
    parser.add_argument("--columns", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--dtypes", nargs="+", default=["float64", "float32"])
    parser.add_argument("--preconditioners", nargs="+", default=["multigrid", "jacobi"])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--output", default=os.path.join(HERE, "results", "pcg.csv"))
    args = parser.parse_args()
    if args.mesh is None:
        import importlib.resources
        with importlib.resources.as_file(importlib.resources.files("warp_regdist") / "data" / "spot_rr.off") as p:
            mesh = wrd.load_mesh(p)
    else:
        mesh = wrd.load_mesh(args.mesh)
    K = wrd.build_operators(mesh).stiffness
    hierarchy = smoothed_aggregation(K)
    print(f"n = {K.shape[0]}, nnz = {K.nnz}, multigrid levels {hierarchy.sizes}", file=sys.stderr)
    rows = []
    for preconditioner in args.preconditioners:
        for dtype in args.dtypes:
            for cols in args.columns:
                case = measure(K, hierarchy, preconditioner, dtype, cols, args.repeats)
                for row in case:
                    print("  " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                           for k, v in row.items()), file=sys.stderr, flush=True)
                rows += case
                write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
