"""The headline workloads on one Warp device: a GPU beside the CPU tables of the other benchmarks.

    python benchmarks/devices.py                  # on Warp's default device (the first GPU, if any)
    python benchmarks/devices.py --device cpu --quick   # small sizes, to try the script

Cases, after every kernel is compiled on small meshes (no time includes compilation):

- ``spot single``: one source on spot (4,764 vertices), alpha_hat 0.05, float64, median of 3 solves;
- ``spot 64 sources``: one ``solve_many`` of 64 single-vertex sources on spot;
- ``sphere single``: one source on the cube sphere N = 330 (653,402 vertices): setup and solve;
- ``cat_rr all pairs``: ``all_pairs`` on cat_rr (1,949 vertices, ../shared/meshes) at alpha_hat 0.03,
  float32, accuracy 0.005 (skipped with ``--quick`` and when ../shared is not beside the checkout);
- ``sphere all pairs``: ``all_pairs`` on the cube sphere N = 41 (10,088 vertices), float32, capped at
  150 iterations: seconds per iteration with the change test every 50 iterations included.

Columns: iterations, setup and solve seconds, seconds per iteration, converged, the result's error
estimate (all pairs) and the device's memory high-water mark so far (CUDA). Writes
benchmarks/results/devices_cpu.csv or devices_cuda.csv.
"""

import argparse
import os
import statistics
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import meshes  # noqa: E402
import warp as wp  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import write_csv  # noqa: E402
from warp_regdist.arguments import parse_device  # noqa: E402

SPOT = os.path.join(HERE, "..", "warp_regdist", "data", "spot_rr.off")
SIZES = {False: dict(sphere=330, pairs_sphere=41, pairs_iterations=150),
         True: dict(sphere=40, pairs_sphere=10, pairs_iterations=60)}


def device_memory_gb(device):
    """The device's memory-pool high-water mark so far, GB (CUDA; None on the CPU)."""
    return round(wp.get_mempool_used_mem_high(device) / 1e9, 2) if device.is_cuda else None


def _warm(device):
    """Compile every kernel the cases launch, on small meshes."""
    small = meshes.cube_sphere(6)
    solver = wrd.DistanceSolver(small, 0.05, device=device)
    solver.solve([0])
    solver.solve_many([[i] for i in range(64)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.ConvergenceWarning)
        wrd.all_pairs(meshes.cube_sphere(4), 0.03, device=device, dtype="float32", max_iterations=60, accuracy=0.005)


def _row(case, device, mesh, **columns):
    row = dict(case=case, device=str(device), device_name=device.name, vertices=mesh.n_vertices, **columns,
               device_mem_high_gb=device_memory_gb(device))
    print(row, flush=True)
    return row


def run(device, quick):
    sizes = SIZES[quick]
    _warm(device)
    rows = []
    spot = wrd.load_mesh(SPOT)
    solver = wrd.DistanceSolver(spot, 0.05, device=device)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        res = solver.solve([2272])
        times.append(time.perf_counter() - t)
    rows.append(_row("spot single", device, spot, dtype="float64", seconds=round(statistics.median(times), 3),
                     iterations=int(res.iterations), converged=bool(res.converged)))
    t = time.perf_counter()
    many = solver.solve_many([[i] for i in range(0, 64 * 70, 70)])
    rows.append(_row("spot 64 sources", device, spot, dtype="float64", seconds=round(time.perf_counter() - t, 3),
                     iterations=int(many.iterations.max()), converged=bool(many.converged.all())))

    sphere = meshes.cube_sphere(sizes["sphere"])
    t = time.perf_counter()
    solver = wrd.DistanceSolver(sphere, 0.05, device=device)
    setup = time.perf_counter() - t
    t = time.perf_counter()
    res = solver.solve([0])
    rows.append(_row("sphere single", device, sphere, dtype="float64", setup_s=round(setup, 2),
                     seconds=round(time.perf_counter() - t, 2), iterations=int(res.iterations),
                     converged=bool(res.converged)))
    del solver

    cat = meshes.shared_mesh("cat_rr")
    pairs = [] if cat is None or quick else [("cat_rr all pairs", cat, dict(accuracy=0.005))]
    pairs.append(("sphere all pairs", meshes.cube_sphere(sizes["pairs_sphere"]),
                  dict(max_iterations=sizes["pairs_iterations"])))
    for case, mesh, options in pairs:
        t = time.perf_counter()
        solver = wrd.AllPairsSolver(mesh, 0.03, device=device, dtype="float32")
        setup = time.perf_counter() - t
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wrd.ConvergenceWarning)
            res = solver.solve(**options)
        rows.append(_row(case, device, mesh, dtype="float32", setup_s=round(setup, 2), seconds=round(res.seconds, 2),
                         iterations=int(res.iterations), s_per_iteration=round(res.seconds / res.iterations, 4),
                         converged=bool(res.converged), error_estimate_pct=round(100 * res.error_estimate, 3)))
        del solver, res
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's default device)")
    parser.add_argument("--quick", action="store_true", help="small sizes, to try the script")
    parser.add_argument("--out", default=None, help="CSV path (default: benchmarks/results/devices_cpu.csv or "
                                                     "devices_cuda.csv)")
    args = parser.parse_args()
    device = parse_device(args.device)
    out = args.out or os.path.join(HERE, "results", f"devices_{'cuda' if device.is_cuda else 'cpu'}.csv")
    rows = run(device, args.quick)
    write_csv(rows, out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
