"""Below zero: how often a single-source distance dips below 0 on meshes with obtuse triangles.

    python benchmarks/below_zero.py --corpus DIR --decimate 300 1000 [--sources 320] [--names bunny ...]

Every mesh of DIR (as in benchmarks/real_meshes.py: loaded with ``repair=True``, its largest
component, ``--max-vertices``) is decimated to each --decimate size by fast-simplification, and
every vertex (at most --sources of them, spread by farthest-point sampling) is a source of its own
column of ``solve_many``, at alpha_hat 0 and 0.05, in three problems: the default (the intrinsic
Delaunay triangulation with the obtuse angles it leaves refined away, the source triangles'
side-length bound), the intrinsic triangulation with |grad u| <= 1 on the source triangles too, and
the paper's (the mesh's own triangles, |grad u| <= 1); where the refinement inserts vertices, also
the default without it (``refine_obtuse=False``, triangulation "intrinsic, unrefined").
A column is *below zero* when its min is under -1e-6 of its max (the threshold of the solvers'
warning). The table gives per mesh, alpha_hat and problem the columns below zero, the lowest value
(% of that column's max) and the median ADMM iterations.
Writes benchmarks/results/below_zero.csv.
"""

import argparse
import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from real_meshes import corpus, spread  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402

RESULTS = os.path.join(HERE, "results", "below_zero.csv")
BELOW = -1e-6
PROBLEMS = (("intrinsic", "edges"), ("intrinsic", "gradient"), ("mesh", "gradient"))   # (triangulation, source_triangles)
UNREFINED = "intrinsic, unrefined"


def run(folder, sizes, k, max_vertices, names):
    import warp_regdist as wrd
    from warp_regdist.geometry.operators import largest_angles

    rows = []
    for name, mesh in corpus(folder, max_vertices, sizes, names):
        if not name.endswith(" decimated"):
            continue
        sources = list(range(mesh.n_vertices)) if mesh.n_vertices <= k else spread(mesh, k)
        obtuse = int(np.sum(largest_angles(mesh.vertices, mesh.elements) > 120))
        refined = wrd.refine_obtuse_angles(mesh)
        problems = PROBLEMS + (((UNREFINED, "edges"),) if refined.n_inserted else ())
        for alpha_hat in (0.0, 0.05):
            for tri, rule in problems:
                solver = wrd.DistanceSolver(mesh, alpha_hat, triangulation="intrinsic" if tri == UNREFINED else tri,
                                            source_triangles=rule, refine_obtuse=False if tri == UNREFINED else None)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = solver.solve_many([[s] for s in sources])
                U = np.where(np.isfinite(res.distance), res.distance, 0.0)
                low = U.min(axis=0) / U.max(axis=0)
                flips = solver.operators.intrinsic
                row = dict(mesh=name, vertices=mesh.n_vertices, obtuse_120=obtuse,
                           flips=0 if flips is None else flips.flip_count, alpha_hat=alpha_hat, triangulation=tri,
                           source_triangles=rule, sources=len(sources), below_zero=int(np.sum(low < BELOW)),
                           lowest_pct=round(float(100.0 * min(low.min(), 0.0)), 3),
                           converged=int(np.sum(res.converged)),
                           median_iterations=int(np.median(res.iterations)))
                rows.append(row)
                print("  " + str(row), file=sys.stderr, flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", required=True, help="folder of mesh files")
    parser.add_argument("--decimate", type=int, nargs="+", default=[300, 1000])
    parser.add_argument("--sources", type=int, default=100, help="at most this many sources per mesh (default 100)")
    parser.add_argument("--max-vertices", type=int, default=60_000)
    parser.add_argument("--names", nargs="*", default=[], help="only these meshes (file names without extension)")
    parser.add_argument("--output", default=RESULTS)
    args = parser.parse_args()
    rows = run(args.corpus, args.decimate, args.sources, args.max_vertices, set(args.names))
    if not rows:
        sys.exit(f"expected mesh files in {args.corpus} above twice the --decimate sizes, got none")
    write_csv(rows, args.output)
    print(markdown_table(rows))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
