"""Write tests/data/scan_decimations.npz: random decimations of public scanned and CAD meshes.

    python tools/make_scan_decimations.py CORPUS_DIR

CORPUS_DIR holds the OBJ files of alecjacobson/common-3d-test-models (data/*.obj). Each mesh is
loaded with ``repair=True``, its largest component kept, and decimated by fast-simplification (the
``[compare]`` extra) to four distinct vertex counts drawn from 100-2,000 (at most 2/3 of the mesh's;
seed 0), plus cheburashka at 2,000 (whose flips pass through two faces on the same three vertices).
The decimations keep what decimation makes: non-manifold edges, boundaries. Stored per case:
``name_k``, ``vertices_k`` (float32) and ``faces_k`` (uint16).
"""

import glob
import os
import sys
import warnings

import numpy as np

NAMES = ["alligator", "beast", "beetle", "beetle-alt", "cheburashka", "cow", "fandisk", "homer", "nefertiti", "ogre",
         "rocker-arm", "spot", "stanford-bunny", "suzanne", "teapot", "woody"]
OUT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests", "data", "scan_decimations.npz")


def main(folder):
    import fast_simplification
    import warp_regdist as wrd

    rng = np.random.default_rng(0)
    cases = {}
    for name in NAMES:
        path = glob.glob(os.path.join(folder, f"{name}.obj"))[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = wrd.split_components(wrd.load_mesh(path, repair=True))[0][0]
        top = min(2000, 2 * mesh.n_vertices // 3)
        targets = sorted(rng.choice(np.arange(100, top + 1), 4, replace=False).tolist())
        for target in targets + ([2000] if name == "cheburashka" else []):
            V, F = fast_simplification.simplify(mesh.vertices.astype(np.float32), mesh.elements.astype(np.int32),
                                                target_reduction=1.0 - target / mesh.n_vertices)
            k = len(cases) // 3
            cases[f"name_{k}"] = np.array(name)
            cases[f"vertices_{k}"] = V.astype(np.float32)
            cases[f"faces_{k}"] = F.astype(np.uint16)
            print(f"{name}: {len(V)} vertices, {len(F)} faces", file=sys.stderr)
    np.savez_compressed(OUT, **cases)
    print(f"wrote {len(cases) // 3} decimations to {OUT} ({os.path.getsize(OUT) / 1e6:.2f} MB)")


if __name__ == "__main__":
    main(sys.argv[1])
