"""Write tests/data/boat_decimations.npz: a closed developable mesh decimated to slivers, whose intrinsic
Delaunay triangulation keeps angles up to 176 degrees, and where the distance from some sources dips
below 0 unless those angles are refined (geometry/obtuse_refinement.py).

    python tools/make_boat_decimations.py PATH/TO/boat.obj

boat.obj is odedstein/meshes' objects/boat/boat.obj ("Boat", Oded Stein, Eitan Grinspun and Keenan
Crane, 2019, CC BY 4.0: github.com/odedstein/meshes/tree/master/objects/boat). It is loaded with
``repair=True``, its largest component kept, and decimated by fast-simplification (the ``[compare]``
extra) to 501 and 1,001 vertices as ``benchmarks/real_meshes.py --decimate`` does. Stored per case:
``name_k``, ``vertices_k`` (float32) and ``faces_k`` (uint16).
"""

import os
import sys
import warnings

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(HERE, "benchmarks"))
OUT = os.path.join(HERE, "tests", "data", "boat_decimations.npz")


def main(path):
    import warp_regdist as wrd
    from real_meshes import _decimated

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = wrd.split_components(wrd.load_mesh(path, repair=True))[0][0]
    cases = {}
    for k, target in enumerate((500, 1000)):
        small = _decimated(mesh, target)
        cases[f"name_{k}"] = np.array(f"boat {small.n_vertices}")
        cases[f"vertices_{k}"] = small.vertices.astype(np.float32)
        cases[f"faces_{k}"] = small.elements.astype(np.uint16)
    np.savez_compressed(OUT, **cases)
    print(f"wrote {len(cases) // 3} decimations to {OUT} ({os.path.getsize(OUT) / 1e3:.0f} kB)")


if __name__ == "__main__":
    main(sys.argv[1])
