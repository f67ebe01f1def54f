"""Sources anywhere on the surface: a point inside a face, and a closed curve with its signed distance.

    python examples/sources_anywhere.py                         # shipped spot
    python examples/sources_anywhere.py MESH --point 0,0.1,0.9 --loops 8 --output out/

The point source is the surface point closest to --point (default: the mesh's vertex farthest
along its longest principal axis, moved 0.3 of the way into one of its faces). The closed curve is
a loop of --loops points round the vertex at the other end of that axis, in its tangent plane,
each moved to the closest surface point. Writes, in
--output: point.png (distance from the point), signed.png (signed distance to the curve:
negative on its left, diverging colours) and both fields as .npy on the original vertices.
"""

import argparse
import os
from importlib.resources import files

import numpy as np

import warp_regdist as wrd
from warp_regdist.output.render import render_distance


def principal_frame(vertices):
    """Centroid and principal axes (rows, the longest first) of a point set."""
    centre = vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(vertices - centre, full_matrices=False)
    return centre, axes


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh", nargs="?", default=str(files("warp_regdist") / "data" / "spot_rr.off"))
    ap.add_argument("--point", help="x,y,z of the point source (default: see above)")
    ap.add_argument("--loops", type=int, default=12, help="points on the closed curve (default 12)")
    ap.add_argument("--alpha-hat", type=float, default=0.05)
    ap.add_argument("--output", default="sources-anywhere")
    args = ap.parse_args()
    os.makedirs(args.output, exist_ok=True)
    mesh = wrd.load_mesh(args.mesh)
    solver = wrd.DistanceSolver(mesh, alpha_hat=args.alpha_hat)
    centre, axes = principal_frame(mesh.vertices)
    reach = 2.0 * np.ptp(mesh.vertices, axis=0).max()     # accept any --point near the mesh

    if args.point is None:
        tip = int(np.argmax((mesh.vertices - centre) @ axes[0]))
        face = int(np.flatnonzero((mesh.faces == tip).any(axis=1))[0])
        bary = np.where(mesh.faces[face] == tip, 0.7, 0.15)
        point = [(face, tuple(bary))]
    else:
        point = wrd.surface_points(mesh, [float(c) for c in args.point.split(",")], max_distance=reach)
    res = solver.solve(points=point)
    at = np.flatnonzero(res.refined_distance == 0)
    render_distance(res.refined_mesh, res.refined_distance, os.path.join(args.output, "point.png"), sources=at,
                    title=f"distance from a point inside face {point[0][0]}, alpha_hat {args.alpha_hat:g}")
    np.save(os.path.join(args.output, "point.npy"), res.distance)

    # a loop of --loops points round the vertex at the other end of the longest axis, in its
    # tangent plane, each moved to the closest surface point
    other = int(np.argmin((mesh.vertices - centre) @ axes[0]))
    at = mesh.faces[(mesh.faces == other).any(axis=1)]
    normal = np.cross(mesh.vertices[at[:, 1]] - mesh.vertices[at[:, 0]], mesh.vertices[at[:, 2]] - mesh.vertices[at[:, 0]])
    normal = normal.sum(axis=0) / np.linalg.norm(normal.sum(axis=0))
    e1 = np.cross(normal, axes[1] if abs(normal @ axes[1]) < 0.9 else axes[2])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    angles = 2 * np.pi * np.arange(args.loops) / args.loops
    radius = 0.25 * np.ptp(mesh.vertices, axis=0).max()
    ring = mesh.vertices[other] + radius * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
    curve = wrd.surface_points(mesh, ring, max_distance=reach)
    res = solver.solve(curve=curve, closed=True)
    # colours symmetric about 0, saturating at twice the depth of the inside
    top = min(2.0 * max(-res.signed_distance.min(), 1e-12), res.signed_distance.max())
    render_distance(mesh, res.signed_distance, os.path.join(args.output, "signed.png"),
                    isolines=np.arange(-top, res.signed_distance.max(), top / 5), cmap="RdBu", limits=(-top, top),
                    title="signed distance to a closed curve (negative on its left)")
    np.save(os.path.join(args.output, "signed.npy"), res.signed_distance)
    print(f"{os.path.basename(args.mesh)}: wrote {args.output}/point.png and signed.png")


if __name__ == "__main__":
    main()
