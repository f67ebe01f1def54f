"""One all-pairs run on a large irregular mesh, with checkpoints: iterations, time, memory, its own error tests.

    python benchmarks/all_pairs_large.py --device cuda                       # cat_rr subdivided, decimated to 10,099
    python benchmarks/all_pairs_large.py --device cuda --resume /tmp/large.npz --max-iterations 4500

The mesh: cat_rr (../shared) Loop-subdivided twice and decimated to 10,099 vertices
(``meshes.subdivided_decimated``; needs fast-simplification, the ``compare`` extra). alpha_hat 0.03,
float32, the default accuracy, a checkpoint every ``--checkpoint-seconds`` to ``--checkpoint`` (a
run cut short goes on with ``--resume``). Prints the progress every 250 iterations and a row:
iterations, seconds (of all the runs that led to this one), seconds per iteration, converged, the
error estimate (the change test), the gradient excess, the residuals' largest ratio to their tolerance,
the estimated footprint and the device's memory high-water mark (CUDA); writes
benchmarks/results/all_pairs_large.csv and, with ``--rows``, the rows 0, 2500, 5000, 7500 of the
matrix beside the mesh and the residual history (.npz).
"""

import argparse
import os
import sys
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
from devices import device_memory_gb  # noqa: E402
import numpy as np  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.arguments import parse_device  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's default device)")
    parser.add_argument("--vertices", type=int, default=10100, help="decimation target")
    parser.add_argument("--max-iterations", type=int, default=3000)
    parser.add_argument("--checkpoint", default="/tmp/all_pairs_large.npz")
    parser.add_argument("--checkpoint-seconds", type=float, default=150.0)
    parser.add_argument("--resume", default=None, help="a checkpoint of this run to go on from")
    parser.add_argument("--rows", default=None, help=".npz for four rows of the matrix, the mesh and the history")
    parser.add_argument("--out", default=os.path.join(HERE, "results", "all_pairs_large.csv"))
    args = parser.parse_args()
    device = parse_device(args.device)
    mesh = meshes.subdivided_decimated("cat_rr", args.vertices)
    if mesh is None:
        parser.error("needs ../shared/meshes/cat_rr.off beside the checkout")
    solver = wrd.AllPairsSolver(mesh, 0.03, device=device, dtype="float32")

    def progress(info):
        if info.tests and info.iteration % 250 == 0:
            print(f"  {info}", flush=True)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        res = solver.solve(max_iterations=args.max_iterations, callback=progress, checkpoint=args.checkpoint,
                           checkpoint_seconds=args.checkpoint_seconds, resume=args.resume)
    row = dict(mesh="cat_rr subdivided, decimated", vertices=mesh.n_vertices, device=device.name, dtype="float32",
               iterations=res.iterations, seconds=round(res.seconds, 1), s_per_iteration=round(res.seconds / res.iterations, 4),
               converged=bool(res.converged), error_estimate_pct=round(100 * res.error_estimate, 3),
               gradient_excess=round(res.gradient_excess, 4), residual_ratio=round(float(np.max(res.residuals / res.tolerance)), 3),
               memory_estimate_gb=round(res.memory_bytes / 1e9, 2),
               device_mem_high_gb=device_memory_gb(device))
    write_csv([row], args.out)
    print(markdown_table([row]))
    if args.rows:
        rows = [r for r in (0, 2500, 5000, 7500) if r < mesh.n_vertices]
        np.savez_compressed(args.rows, rows=np.array(rows), U=res.distance[rows].astype(np.float32),
                            vertices=mesh.vertices, faces=mesh.elements, history=res.history)


if __name__ == "__main__":
    main()
