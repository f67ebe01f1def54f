"""Write the exact all-pairs minimizers of tests/data/all_pairs_bumpy42.npz and stopping_cat80.npz.

    python tools/make_all_pairs_references.py

For each file's mesh (kept as it is) and alpha_hat 0.03 and 0.1, tests/all_pairs_reference.py (cvxpy +
Clarabel, gap 1e-9, on the mesh's own triangles) solves the problem with ``source_triangles="edges"``
(keys U_003, U_01: the package's default) and "gradient" (U_003_gradient, U_01_gradient: the paper's).
bumpy42 is solved with row and column constraints (not symmetrized), cat80 over symmetric U.
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "tests", "data")
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import all_pairs_reference as apr  # noqa: E402

FILES = {"all_pairs_bumpy42.npz": False, "stopping_cat80.npz": True}   # name: symmetric


def main():
    for name, symmetric in FILES.items():
        path = os.path.join(DATA, name)
        d = dict(np.load(path))
        V, F = d["vertices"], d["faces"].astype(np.int64)
        area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
        for alpha_hat, key in ((0.03, "U_003"), (0.1, "U_01")):
            for rule, suffix in (("edges", ""), ("gradient", "_gradient")):
                d[key + suffix] = apr.solve_all_pairs_reference(V, F, alpha_hat * np.sqrt(area), symmetric=symmetric,
                                                                triangulation="mesh", source_triangles=rule)
                print(name, key + suffix, flush=True)
        np.savez_compressed(path, **d)


if __name__ == "__main__":
    main()
