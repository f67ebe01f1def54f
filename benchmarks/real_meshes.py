"""Real meshes: scanned and CAD meshes from public repositories, distances against exact geodesics.

    python benchmarks/real_meshes.py --corpus DIR [--sources 2] [--max-vertices 60000]

DIR holds mesh files, e.g. the ``data/`` folder of github.com/alecjacobson/common-3d-test-models and
the ``objects/*/`` meshes of github.com/odedstein/meshes (not shipped: clone them). Every mesh is
loaded with ``repair=True``; meshes above --max-vertices are skipped, and --decimate N adds each mesh
decimated to N vertices by fast-simplification (the [compare] extra), where obtuse triangles abound.
For --sources vertices of every mesh (spread by farthest-point sampling from vertex 0) the table
compares, in % of the max exact distance (libigl's MMP, ``igl.exact_geodesic``), the max and mean
error of the regularized distance at alpha_hat 0 in the default problem (the intrinsic Delaunay
triangulation, the source triangles' side-length bound) and in the paper's (the mesh's own
triangles, |grad u| <= 1 on every one), and of potpourri3d's heat method in its default and its robust
(intrinsic Delaunay, mollified) mode; with the ADMM iterations, the solve's seconds and the lowest
value of each solve (in % of its max: below 0 the discretization dips). Writes
benchmarks/results/real_meshes.csv, and real_meshes_summary.csv with one row for the meshes as
they are and one for the decimations (medians, and the sources where the regularized distance's
error is at most the robust heat method's). ``--summarize`` rewrites the summary from an existing
CSV, with that CSV's stamp.
"""

import argparse
import csv
import glob
import json
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from report import _stamp_path, markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "real_meshes.csv")
SUMMARY = os.path.join(HERE, "results", "real_meshes_summary.csv")


def corpus(folder, max_vertices, decimate, names=()):
    """(name, Mesh) of every mesh file in ``folder`` (only ``names``, file names without extension, when
    given) that loads (repaired) with at most ``max_vertices``."""
    import warp_regdist as wrd

    out = []
    for path in sorted(glob.glob(os.path.join(folder, "*"))):
        if not path.lower().endswith((".obj", ".off", ".ply", ".stl")) or os.path.getsize(path) == 0:
            continue
        name = os.path.splitext(os.path.basename(path))[0]
        if names and name not in names:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                mesh = wrd.load_mesh(path, repair=True)
            except (ValueError, OSError) as exc:
                print(f"  {name}: skipped ({exc})", file=sys.stderr)
                continue
        if mesh.n_vertices > max_vertices:
            print(f"  {name}: skipped ({mesh.n_vertices} vertices)", file=sys.stderr)
            continue
        parts = wrd.split_components(mesh)
        out.append((name, parts[0][0]))                      # the largest component
        for target in decimate:
            small = _decimated(parts[0][0], target)
            if small is not None:
                out.append((f"{name} decimated", small))
    return out


def _decimated(mesh, target):
    import fast_simplification
    import warp_regdist as wrd

    if mesh.n_vertices <= 2 * target:
        return None
    V, F = fast_simplification.simplify(mesh.vertices.astype(np.float32), mesh.elements.astype(np.int32),
                                        target_reduction=1.0 - target / mesh.n_vertices)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            small, _ = wrd.repair_mesh(V.astype(np.float64), F.astype(np.int64))
        except ValueError:
            return None
    return wrd.split_components(small)[0][0]


def spread(mesh, k):
    """k vertices by farthest-point sampling (Euclidean) from vertex 0."""
    V = mesh.vertices
    chosen = [0]
    d = np.linalg.norm(V - V[0], axis=1)
    for _ in range(k - 1):
        chosen.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(V - V[chosen[-1]], axis=1))
    return chosen


def errors(u, exact):
    top = exact.max()
    e = np.abs(u - exact)
    return float(100.0 * e.max() / top), float(100.0 * e.mean() / top)


def run(folder, k, max_vertices, decimate):
    import igl
    import potpourri3d as pp3d
    import warp_regdist as wrd
    from warp_regdist.geometry.operators import largest_angles

    rows = []
    for name, mesh in corpus(folder, max_vertices, decimate):
        V, F = mesh.vertices, mesh.elements
        angles = largest_angles(V, F)
        heat = {robust: pp3d.MeshHeatMethodDistanceSolver(V, F, use_robust=robust) for robust in (False, True)}
        solvers = {"intrinsic": wrd.DistanceSolver(mesh, 0.0),
                   "mesh": wrd.DistanceSolver(mesh, 0.0, triangulation="mesh", source_triangles="gradient")}
        flips = solvers["intrinsic"].operators.intrinsic
        for s in spread(mesh, k):
            exact = igl.exact_geodesic(V, F, np.array([s]), np.array([], dtype=np.int64),
                                       np.arange(len(V)), np.array([], dtype=np.int64))
            straight = np.linalg.norm(V - V[s], axis=1)
            if not (np.all(np.isfinite(exact)) and np.all(exact >= straight - 1e-9 * straight.max())):
                print(f"  {name} source {s}: skipped (MMP returned distances below the straight line)", file=sys.stderr)
                continue
            row = dict(mesh=name, vertices=mesh.n_vertices, obtuse_120=int(np.sum(angles > 120)),
                       flips=0 if flips is None else flips.flip_count, source=s)
            for tri, solver in solvers.items():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = solver.solve([s])
                row[f"{tri}_iterations"] = int(res.iterations)
                row[f"{tri}_seconds"] = round(res.seconds, 2)
                row[f"{tri}_max_pct"], row[f"{tri}_mean_pct"] = errors(res.distance, exact)
                row[f"{tri}_min_pct"] = float(100.0 * res.distance.min() / res.distance.max())
            for robust, solver in heat.items():
                tag = "heat_robust" if robust else "heat"
                t = time.perf_counter()
                u = solver.compute_distance(s)
                row[f"{tag}_seconds"] = round(time.perf_counter() - t, 3)
                row[f"{tag}_max_pct"], row[f"{tag}_mean_pct"] = errors(u, exact)
            rows.append(row)
            print("  " + str(row), file=sys.stderr, flush=True)
    return rows


def summarize(rows):
    """One row for the meshes as they are and one for the decimations: counts, median iterations and
    errors, the sources whose max (mean) error is at most the robust heat method's, sources below 0."""
    out = []
    for label, decimated in (("as published", False), ("decimated", True)):
        group = [r for r in rows if str(r["mesh"]).endswith(" decimated") == decimated]
        if not group:
            continue

        def col(key):
            return np.array([float(r[key]) for r in group])

        def median(key):
            return round(float(np.median(col(key))), 3)

        out.append(dict(meshes=label, count=len({r["mesh"] for r in group}), sources=len(group),
                        intrinsic_iterations=median("intrinsic_iterations"), mesh_iterations=median("mesh_iterations"),
                        intrinsic_max_pct=median("intrinsic_max_pct"), intrinsic_mean_pct=median("intrinsic_mean_pct"),
                        mesh_max_pct=median("mesh_max_pct"), mesh_mean_pct=median("mesh_mean_pct"),
                        heat_robust_max_pct=median("heat_robust_max_pct"),
                        heat_robust_mean_pct=median("heat_robust_mean_pct"), heat_max_pct=median("heat_max_pct"),
                        max_at_most_robust=int(np.sum(col("intrinsic_max_pct") <= col("heat_robust_max_pct"))),
                        mean_at_most_robust=int(np.sum(col("intrinsic_mean_pct") <= col("heat_robust_mean_pct"))),
                        intrinsic_below_zero=int(np.sum(col("intrinsic_min_pct") < -1e-4)),
                        mesh_below_zero=int(np.sum(col("mesh_min_pct") < -1e-4))))
    return out


def write_summary(rows, path, stamp_of=None):
    """The summary of ``rows`` to ``path``; with ``stamp_of`` (a CSV) that CSV's stamp instead of this run's."""
    summary = summarize(rows)
    write_csv(summary, path)
    if stamp_of is not None:
        with open(_stamp_path(stamp_of)) as f:
            stamp = json.load(f)
        with open(_stamp_path(path), "w") as f:
            json.dump(stamp, f, indent=1)
    print(markdown_table(summary))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", help="folder of mesh files")
    parser.add_argument("--sources", type=int, default=2, help="sources per mesh (default: 2)")
    parser.add_argument("--max-vertices", type=int, default=60_000)
    parser.add_argument("--decimate", type=int, nargs="*", default=[], help="also each mesh decimated to N vertices")
    parser.add_argument("--output", default=RESULTS)
    parser.add_argument("--summarize", metavar="CSV", help="only rewrite the summary of this results CSV")
    args = parser.parse_args()
    if args.summarize:
        with open(args.summarize, newline="") as f:
            write_summary(list(csv.DictReader(f)), SUMMARY, stamp_of=args.summarize)
        return
    if not args.corpus:
        parser.error("expected --corpus DIR (or --summarize CSV), got neither")
    rows = run(args.corpus, args.sources, args.max_vertices, args.decimate)
    write_csv(rows, args.output)
    print(markdown_table(rows))
    write_summary(rows, SUMMARY)


if __name__ == "__main__":
    main()
