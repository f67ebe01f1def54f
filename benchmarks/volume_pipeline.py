"""Surface -> tetrahedra -> depth -> grid: the ``warp-regdist volume`` path, stage by stage.

    python benchmarks/volume_pipeline.py                    # icosphere4, spot_rr, cat_rr, bent_pipe_closed_lr
    python benchmarks/volume_pipeline.py --meshes spot_rr   # a subset

For every closed surface (the shared real meshes, spot_rr also shipped with the package,
and a unit icosphere of 2,562 vertices): the surface checks and TetGen
(`wrd.tetrahedralize`, quality 1.5, the default interior edge min(mean surface edge, alpha)),
a second tetrahedralization compared with the first (TetGen's seed is fixed, so
they must be identical), DistanceSolver setup, one solve from every boundary vertex
(alpha_hat 0.05, float64, CPU), writing the .vtu and sampling a 128-point grid. Each
surface runs in its own process after the kernels are loaded; then the whole command
(`warp-regdist volume SURFACE --sources boundary --output depth.vtu --grid 128
--grid-output depth.npy`, a fresh Python process: imports, kernel cache, everything) is
timed from the shell's point of view. Prints a markdown table and writes
benchmarks/results/volume_pipeline.csv.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import markdown_table, print_result, run_child, write_csv  # noqa: E402

MESHES = ("icosphere4", "spot_rr", "cat_rr", "bent_pipe_closed_lr")
ALPHA_HAT = 0.05
GRID = 128


def _surface_path(name):
    if name == "icosphere4":  # the unit ball, whose depth has a closed form
        import trimesh

        path = os.path.join(tempfile.gettempdir(), "warp_regdist_icosphere4.off")
        trimesh.creation.icosphere(4, radius=1.0).export(path)
        return path
    from meshes import SHARED

    path = os.path.join(SHARED, "meshes", f"{name}.off")
    if os.path.isfile(path):
        return path
    import warp_regdist

    shipped = os.path.join(os.path.dirname(warp_regdist.__file__), "data", f"{name}.off")
    return shipped if os.path.isfile(shipped) else None


def run_case(name):
    """One surface in this process -> dict of measurements (seconds per stage)."""
    import warp as wp

    wp.config.quiet = True
    import warp_regdist as wrd
    from warp_regdist.geometry.tetrahedralize import interior_edge
    from warp_regdist.geometry.volume_grid import sample_on_grid

    surface = wrd.load_mesh(_surface_path(name))
    warm = wrd.tetrahedralize(surface, max_volume=None, quality=None)
    wrd.DistanceSolver(warm, alpha_hat=ALPHA_HAT, device="cpu").solve(wrd.boundary_vertices(warm)[:1])  # load kernels
    t = time.perf_counter()
    mesh = wrd.tetrahedralize(surface, alpha_hat=ALPHA_HAT)
    mesh_s = time.perf_counter() - t
    again = wrd.tetrahedralize(surface, alpha_hat=ALPHA_HAT)
    same = np.array_equal(mesh.vertices, again.vertices) and np.array_equal(mesh.elements, again.elements)
    t = time.perf_counter()
    solver = wrd.DistanceSolver(mesh, alpha_hat=ALPHA_HAT, device="cpu")
    setup_s = time.perf_counter() - t
    boundary = wrd.boundary_vertices(mesh)
    res = solver.solve(boundary)
    with tempfile.TemporaryDirectory() as folder:
        t = time.perf_counter()
        wrd.save_vtu(os.path.join(folder, "depth.vtu"), mesh, {"distance": res.distance})
        vtu_s = time.perf_counter() - t
    t = time.perf_counter()
    grid = sample_on_grid(mesh, res.distance, GRID)
    grid_s = time.perf_counter() - t
    interior = np.setdiff1d(np.arange(mesh.n_vertices), boundary)
    ball_error = surface_only_error = float("nan")
    if name == "icosphere4":  # max |u - closed form| / max depth, and the same with TetGen's own grading
        sys.path.insert(0, os.path.join(HERE, "..", "tests"))
        from closed_forms import ball_distance

        def error(m, u):
            exact = ball_distance(np.minimum(np.linalg.norm(m.vertices, axis=1), 1.0), 1.0, solver.alpha)
            return float(np.abs(u - exact).max() / exact.max())

        ball_error = error(mesh, res.distance)
        coarse = wrd.tetrahedralize(surface, max_edge=None)
        surface_only_error = error(coarse, wrd.DistanceSolver(coarse, alpha_hat=ALPHA_HAT, device="cpu")
                                   .solve(wrd.boundary_vertices(coarse)).distance)
    return {"surface": name, "surface_vertices": surface.n_vertices,
            "max_edge": interior_edge(surface.vertices, surface.faces, ALPHA_HAT), "tets": mesh.n_elements,
            "vertices": mesh.n_vertices, "tetrahedralize_s": mesh_s, "repeatable": bool(same),
            "setup_s": setup_s, "solve_s": res.seconds, "admm_iterations": int(res.iterations),
            "converged": bool(res.converged), "vtu_s": vtu_s, "grid": "x".join(map(str, grid.values.shape)),
            "grid_s": grid_s, "grid_inside": int(np.isfinite(grid.values).sum()),
            "max_depth": float(res.distance.max()), "min_interior_depth": float(res.distance[interior].min()),
            "ball_error": ball_error, "surface_grading_ball_error": surface_only_error}


def command_seconds(name):
    """Wall time of the whole ``warp-regdist volume`` command in a fresh process."""
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "warp_regdist.cli", "volume", _surface_path(name), "--sources", "boundary",
                   "--alpha-hat", str(ALPHA_HAT), "--output", os.path.join(folder, "depth.vtu"),
                   "--grid", str(GRID), "--grid-output", os.path.join(folder, "depth.npy"), "--quiet"]
        t = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True)
        seconds = time.perf_counter() - t
    if done.returncode != 0:
        print(done.stderr[-2000:], file=sys.stderr)
        return float("nan")
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", nargs="+", default=list(MESHES))
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case is not None:
        print_result(run_case(args.case))
        return
    rows = []
    for name in args.meshes:
        if _surface_path(name) is None:
            print(f"skipping {name}: no such mesh", file=sys.stderr)
            continue
        print(f"{name}...", file=sys.stderr, flush=True)
        row = run_child(__file__, name)
        if row is not None:
            row["command_s"] = command_seconds(name)
            rows.append(row)
    print(markdown_table(rows))
    write_csv(rows, os.path.join(HERE, "results", "volume_pipeline.csv"))


if __name__ == "__main__":
    main()
