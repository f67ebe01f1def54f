"""Fingerprints of solver outputs, to show that a refactoring changed no bit.

    python tools/bit_identity.py --write before.json       # on the commit before
    python tools/bit_identity.py --compare before.json     # after: exit 1 on any difference

Cases: single source (spot, float64 and float32), a batch of 9 columns in one and in two
processes, the Hessian and the vector-field regularizers, a tetrahedral cube from its
boundary, a warm start, and all pairs on a bumpy 162-vertex sphere with one and two
processes. Each result's arrays (distances, iterations, residuals, CG counts) are hashed
with SHA-256; every case runs in this process, on the CPU.
"""

import argparse
import hashlib
import json
import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))


def _digest(*arrays):
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(str((a.shape, a.dtype.str)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:20]


def _single(res):
    return _digest(res.distance, res.iterations, res.primal_residual, res.dual_residual, res.cg_iterations)


def cases():
    import warp as wp

    wp.config.quiet = True
    import meshes
    import warp_regdist as wrd

    warnings.simplefilter("ignore", wrd.ConvergenceWarning)
    spot = wrd.load_mesh(wrd.data_path("spot_rr.off"))
    V, F = meshes.icosphere(2, 1.0)
    bumpy = wrd.Mesh(meshes.perturbed(V, F, 0.05, seed=2), F)
    out = {}
    for dtype in ("float64", "float32"):
        out[f"spot {dtype}"] = _single(wrd.DistanceSolver(spot, 0.05, dtype=dtype, device="cpu").solve([2272]))
    sets = [[j * 500] for j in range(9)]
    for workers in (1, 2):
        with wrd.DistanceSolver(spot, 0.05, device="cpu", workers=workers) as solver:
            out[f"spot batch of 9, {workers} process(es)"] = _single(solver.solve_many(sets))
    hess = wrd.DistanceSolver(bumpy, 1e-3, regularizer="hessian", device="cpu")
    out["hessian"] = _single(hess.solve([0]))
    field = wrd.line_field(spot, faces=[0, 5000], directions=[[0, 1, 0], [1, 0, 0]], fade=0.5)
    out["vector field"] = _single(wrd.DistanceSolver(spot, 0.05, regularizer="vector_field", vector_field=field,
                                                     device="cpu").solve([2272]))
    cube = wrd.Mesh(*meshes.cube_tets(8))
    out["tet cube, boundary"] = _single(wrd.DistanceSolver(cube, 0.05, device="cpu").solve(wrd.boundary_vertices(cube)))
    first = wrd.DistanceSolver(spot, 0.05, device="cpu").solve([2272])
    out["warm start 0.05 -> 0.06"] = _single(wrd.DistanceSolver(spot, 0.06, device="cpu").solve([2272], initial=first))
    for workers in (1, 2):
        res = wrd.all_pairs(bumpy, 0.05, device="cpu", workers=workers, max_iterations=300)
        out[f"all pairs, {workers} process(es)"] = _digest(res.distance, res.history, res.cg_iterations, res.iterations)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", metavar="JSON")
    parser.add_argument("--compare", metavar="JSON")
    args = parser.parse_args()
    got = cases()
    for name, digest in got.items():
        print(f"{digest}  {name}")
    if args.write:
        with open(args.write, "w") as f:
            json.dump(got, f, indent=1)
    if args.compare:
        with open(args.compare) as f:
            before = json.load(f)
        differ = [name for name in before if before[name] != got.get(name)]
        print("identical" if not differ else f"different: {differ}")
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
