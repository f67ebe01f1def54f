"""Non-manifold meshes computed on (the tufted cover) against cut along their non-manifold edges.

    python benchmarks/non_manifold.py --corpus DIR [--decimate 300 1000] [--sources 2]

DIR holds mesh files (e.g. the ``data/`` folder of alecjacobson/common-3d-test-models). Every mesh is
repaired without cutting (``repair_mesh(V, F, cut=False)``: vertices merged, cracks welded, degenerate
faces dropped), its largest component kept, and, with --decimate, also decimated by
fast-simplification (the [compare] extra), which leaves non-manifold edges. Meshes with no
non-manifold edge are skipped. For --sources vertices (farthest-point sampling from vertex 0) the
table compares, at alpha_hat 0, in % of the max exact distance, the error of the distance computed on
the mesh as it is (the default: intrinsic Delaunay on its tufted cover) and on the mesh cut along its
non-manifold edges (``repair_mesh(V, F)``, the only way before), against exact geodesics (libigl's
MMP, which needs a manifold: computed on the cut mesh, so the reference favours the cut; left blank
where it returns distances below the straight line), over the vertices both reach, and how many
vertices the cut leaves unreachable from the source (+inf: a face detached by the cut, alone). Writes
benchmarks/results/non_manifold.csv.
"""

import argparse
import glob
import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from real_meshes import errors, spread  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "non_manifold.csv")


def non_manifold_edges(F):
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    _, counts = np.unique(np.minimum(a, b) * (F.max() + 1) + np.maximum(a, b), return_counts=True)
    return int(np.sum(counts > 2))


def cases(folder, sizes):
    import fast_simplification
    import trimesh
    import warp_regdist as wrd

    for path in sorted(glob.glob(os.path.join(folder, "*"))):
        if not path.lower().endswith((".obj", ".off", ".ply", ".stl")) or os.path.getsize(path) == 0:
            continue
        name = os.path.splitext(os.path.basename(path))[0]
        loaded = trimesh.load(path, process=False, force="mesh")       # the file's arrays, as they are
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = wrd.split_components(wrd.repair_mesh(loaded.vertices, loaded.faces, cut=False)[0])[0][0]
        variants = [(name, mesh)]
        for target in sizes:
            if mesh.n_vertices > 2 * target:
                W, G = fast_simplification.simplify(mesh.vertices.astype(np.float32), mesh.elements.astype(np.int32),
                                                    target_reduction=1.0 - target / mesh.n_vertices)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    small = wrd.repair_mesh(W.astype(np.float64), G.astype(np.int64), cut=False)[0]
                variants.append((f"{name} decimated", wrd.split_components(small)[0][0]))
        for label, m in variants:
            if non_manifold_edges(m.elements):
                yield label, m


def run(folder, sizes, k):
    import igl
    import warp_regdist as wrd

    rows = []
    for name, mesh in cases(folder, sizes):
        n = mesh.n_vertices
        cut = wrd.repair_mesh(mesh.vertices, mesh.elements)[0]
        solvers = {"tufted": wrd.DistanceSolver(mesh, 0.0), "cut": wrd.DistanceSolver(cut, 0.0)}
        for s in spread(mesh, k):
            exact = igl.exact_geodesic(cut.vertices, cut.elements, np.array([s]), np.array([], dtype=np.int64),
                                       np.arange(n), np.array([], dtype=np.int64))
            straight = np.linalg.norm(mesh.vertices - mesh.vertices[s], axis=1)
            reached = np.isfinite(exact)
            valid = not np.any(exact[reached] < straight[reached] - 1e-9 * straight.max())
            row = dict(mesh=name, vertices=n, non_manifold_edges=non_manifold_edges(mesh.elements), source=s)
            results = {}
            for tag, solver in solvers.items():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    results[tag] = solver.solve([s])
            u = {tag: res.distance[:n] for tag, res in results.items()}
            both = reached & np.isfinite(u["tufted"]) & np.isfinite(u["cut"])
            row["cut_unreachable"] = int(np.sum(np.isfinite(u["tufted"]) & ~np.isfinite(u["cut"])))
            for tag, res in results.items():
                row[f"{tag}_iterations"] = int(res.iterations)
                row[f"{tag}_max_pct"], row[f"{tag}_mean_pct"] = ((round(e, 3) for e in errors(u[tag][both], exact[both]))
                                                                 if valid else ("", ""))
                row[f"{tag}_min_pct"] = round(float(100.0 * u[tag][both].min() / u[tag][both].max()), 3)
            rows.append(row)
            print("  " + str(row), file=sys.stderr, flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", required=True, help="folder of mesh files")
    parser.add_argument("--decimate", type=int, nargs="*", default=[], help="also each mesh decimated to N vertices")
    parser.add_argument("--sources", type=int, default=2, help="sources per mesh (default: 2)")
    parser.add_argument("--output", default=RESULTS)
    args = parser.parse_args()
    rows = run(args.corpus, args.decimate, args.sources)
    write_csv(rows, args.output)
    print(markdown_table(rows))


if __name__ == "__main__":
    main()
