"""CUDA kernel time per all-pairs iteration, kernel by kernel (Warp's CUDA event timing).

    python benchmarks/cuda_kernels.py                  # cat_rr (../shared) and the 10,088-vertex sphere
    python benchmarks/cuda_kernels.py --iterations 20  # shorter

For each mesh (cat_rr, 1,949 vertices, when ../shared is beside the checkout; the cube sphere N = 41,
10,088 vertices), float32, alpha_hat 0.03: a 3-iteration solve compiles the kernels, then one solve of
``--iterations`` iterations (one change test at 50 with the default 55) runs under
``wp.timing_begin(cuda_filter=wp.TIMING_ALL)``. Rows: the GPU milliseconds and launches per ADMM
iteration of each kernel (and of the host-device copies), then ``all recorded`` (their sum) and
``wall`` (the solve's wall-clock time per iteration: its setup of the state, the host's share of every
iteration and the final checks of the result included). Writes benchmarks/results/cuda_kernels.csv.
"""

import argparse
import collections
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import warp as wp  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.arguments import parse_device  # noqa: E402


def kernel_name(name):
    """'forward kernel all_pairs_kernels__locals__element_step_8577e...' -> 'element_step'."""
    base = name.split("__locals__")[-1].split("(")[0]
    return base.rsplit("_", 1)[0] if "__locals__" in name else base


def profile(case, mesh, device, iterations):
    """Rows of one mesh: per kernel, ms and launches per iteration, most expensive first."""
    solver = wrd.AllPairsSolver(mesh, 0.03, device=device, dtype="float32")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        solver.solve(max_iterations=3)
        wp.synchronize_device(device)
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        t = time.perf_counter()
        solver.solve(max_iterations=iterations)
        wall = time.perf_counter() - t
        results = wp.timing_end()
    total, calls = collections.defaultdict(float), collections.Counter()
    for r in results:
        total[kernel_name(r.name)] += r.elapsed
        calls[kernel_name(r.name)] += 1
    rows = [dict(case=case, vertices=mesh.n_vertices, kernel=k, ms_per_iteration=round(v / iterations, 3),
                 calls_per_iteration=round(calls[k] / iterations, 1))
            for k, v in sorted(total.items(), key=lambda kv: -kv[1])]
    rows.append(dict(case=case, vertices=mesh.n_vertices, kernel="all recorded",
                     ms_per_iteration=round(sum(total.values()) / iterations, 2)))
    rows.append(dict(case=case, vertices=mesh.n_vertices, kernel="wall", ms_per_iteration=round(1e3 * wall / iterations, 2)))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda", help="a CUDA Warp device")
    parser.add_argument("--iterations", type=int, default=55)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "cuda_kernels.csv"))
    args = parser.parse_args()
    device = parse_device(args.device)
    if not device.is_cuda:
        parser.error(f"expected a CUDA device, got {device}")
    cases = [("cat_rr", meshes.shared_mesh("cat_rr")), ("sphere", meshes.cube_sphere(41))]
    rows = [row for case, mesh in cases if mesh is not None for row in profile(case, mesh, device, args.iterations)]
    write_csv(rows, args.out)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
