"""Hessian regularization ignores holes' boundaries (the paper's Fig. 1e), on spot with and without holes.

    python examples/hessian_holes.py [HOLES_MESH [CLOSED_MESH]] [--output DIR]

Defaults: ../shared/meshes/spot_rr_holes.off and spot_rr.off beside this checkout (the
holed mesh is not shipped with the package; pass its path otherwise). The two meshes have
different vertices, so the source on each is the vertex nearest to one point (default:
vertex 2272 of spot_rr, as in the demo). For the Dirichlet and the Hessian regularizer the
script solves on both meshes and writes one PNG per regularizer with the two side by side
(dirichlet_holes.png, hessian_holes.png), and prints, per regularizer, how much the
distance on the holed mesh differs from the closed one at the holed mesh's vertices (the
closed mesh's distance interpolated at the nearest vertex), in % of the maximal distance.
The Dirichlet isolines bend to meet the hole rims at right angles (natural boundary
condition du/dn = 0); the Hessian ones run on as if the holes were not there.
"""

import argparse
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

import warp_regdist as wrd  # noqa: E402
from warp_regdist.output.render import render_distance  # noqa: E402

SHARED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "meshes")
SETTINGS = {"dirichlet": 0.05, "hessian": 1e-3}  # alpha_hat: the Hessian's alpha scales as A^(3/2)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("holes", nargs="?", default=os.path.join(SHARED, "spot_rr_holes.off"))
    parser.add_argument("closed", nargs="?", default=os.path.join(SHARED, "spot_rr.off"))
    parser.add_argument("--point", help="source point x,y,z (default: vertex 2272 of the closed mesh)")
    parser.add_argument("--output", default="hessian-holes")
    args = parser.parse_args()
    for path in (args.holes, args.closed):
        if not os.path.isfile(path):
            parser.exit(2, f"{path} not found: pass the meshes' paths (spot_rr_holes.off and spot_rr.off "
                           "are in the project's shared/meshes folder)\n")
    meshes = {"holes": wrd.load_mesh(args.holes), "closed": wrd.load_mesh(args.closed)}
    point = (meshes["closed"].vertices[2272] if args.point is None
             else np.array([float(c) for c in args.point.split(",")]))
    sources = {k: int(cKDTree(m.vertices).query(point)[1]) for k, m in meshes.items()}
    nearest = cKDTree(meshes["closed"].vertices).query(meshes["holes"].vertices)[1]
    os.makedirs(args.output, exist_ok=True)
    for regularizer, alpha_hat in SETTINGS.items():
        u, panels = {}, []
        for key, mesh in meshes.items():
            res = wrd.DistanceSolver(mesh, alpha_hat=alpha_hat, regularizer=regularizer).solve([sources[key]])
            u[key] = res.distance
            panel = os.path.join(args.output, f"panel_{regularizer}_{key}.png")
            render_distance(mesh, res.distance, panel, sources=[sources[key]], view=[(35.0, 15.0)],
                            title=f"{key}: {res.iterations} ADMM iterations")
            panels.append(panel)
            print(f"{regularizer} (alpha_hat {alpha_hat:g}) on {key} {mesh}: {res.iterations} ADMM iterations, "
                  f"{res.cg_iterations} CG, converged {res.converged}, {res.seconds:.1f} s")
        diff = np.abs(u["holes"] - u["closed"][nearest]).max() / u["closed"].max()
        print(f"{regularizer}: max difference holes vs closed {100 * diff:.2f}% of the maximal distance")
        fig, axes = plt.subplots(1, 2, figsize=(14, 6))
        for ax, panel in zip(axes, panels):
            ax.imshow(plt.imread(panel))
            ax.axis("off")
        fig.suptitle(f"{regularizer}, alpha_hat {alpha_hat:g}: with holes (left) and without; "
                     f"max difference {100 * diff:.1f}%")
        fig.savefig(os.path.join(args.output, f"{regularizer}_holes.png"), dpi=100, bbox_inches="tight")
        plt.close(fig)
        for panel in panels:
            os.remove(panel)
    print(f"wrote {args.output}/dirichlet_holes.png and {args.output}/hessian_holes.png")


if __name__ == "__main__":
    main()
