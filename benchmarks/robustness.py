"""Robustness to remeshing, anisotropy, noise and scale (paper Fig. 7, 9, 10).

    python benchmarks/robustness.py [--alpha-hat 0.05]

One smooth shape (the generated blob, benchmarks/evaluation_meshes.py) in several
versions: three resolutions of a near-uniform tessellation, an anisotropic
latitude-longitude tessellation, the medium one with normal noise of 0.5 and 0.8 mean
edge length, and the medium one scaled by 10.  Each method gets the same source point;
its field on each version is compared with its own field on a finer reference
tessellation, at 2000 common surface points (closest point on each version, barycentric
interpolation; |grad u| of the containing triangle):

    distance change  = |u_v(p) / s - u_ref(p)|  in % of max u_ref   (s: the version's scale)
    gradient change  = mean_p | |grad u_v(p)| - |grad u_ref(p)| |

This package runs at one alpha_hat, the heat method at its default t (t_coef = 1).
Prints a markdown table and writes benchmarks/results/robustness.csv.
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import evaluation_meshes as em  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from compare import RESULTS, heat_distance, regularized_distance, warm_up  # noqa: E402
from report import write_csv  # noqa: E402

REFERENCE_N = 40
SCALE = 10.0
SAMPLES = 2000


def versions():
    """[(label, mesh, scale)] of the blob."""
    medium = em.blob(20)
    return [
        ("coarse (cube N=12)", em.blob(12), 1.0),
        ("medium (cube N=20)", medium, 1.0),
        ("fine (cube N=28)", em.blob(28), 1.0),
        ("anisotropic (lat-long 160 x 20)", em.blob_uv(160, 20), 1.0),
        ("medium + noise 0.5 h", em.with_normal_noise(medium, 0.5, seed=1), 1.0),
        ("medium + noise 0.8 h", em.with_normal_noise(medium, 0.8, seed=2), 1.0),
        (f"medium scaled x{SCALE:g}", wrd.Mesh(SCALE * medium.vertices, medium.faces), SCALE),
    ]


def common_points(seed=0):
    """SAMPLES points on the smooth blob (images of uniform random directions)."""
    P = np.random.default_rng(seed).standard_normal((SAMPLES, 3))
    return em.blob_map(P / np.linalg.norm(P, axis=1, keepdims=True))


def sampler(mesh, points):
    """(triangle (p,), barycentric (p, 3)) of the closest point of mesh to each point."""
    import igl
    V, F = mesh.vertices, mesh.faces.astype(np.int64)
    _, tri, closest = igl.point_mesh_squared_distance(points, V, F)
    corners = [np.ascontiguousarray(V[F[tri, i]]) for i in range(3)]
    return tri, igl.barycentric_coordinates(np.ascontiguousarray(closest), *corners)


def sample(mesh, u, where):
    """(u at the points, |grad u| of their triangles) for where = sampler(mesh, points)."""
    tri, bary = where
    grad = (wrd.build_operators(mesh).grad @ u).reshape(-1, 3)
    return (u[mesh.faces[tri]] * bary).sum(axis=1), np.linalg.norm(grad[tri], axis=1)


def fields(mesh, scale, alpha_hat):
    """{method: (n,)} from the source point of the blob scaled by `scale`."""
    s = em.source_vertex(mesh, scale)
    return {"heat t_coef=1": heat_distance(mesh, s, 1.0, 1)[2],
            f"this alpha_hat={alpha_hat:g}": regularized_distance(mesh, s, alpha_hat, 1)[2].distance}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--alpha-hat", type=float, default=0.05)
    args = ap.parse_args()
    warm_up()
    points = common_points()
    ref_mesh = em.blob(REFERENCE_N)
    where = sampler(ref_mesh, points)
    reference = {k: sample(ref_mesh, u, where) for k, u in fields(ref_mesh, 1.0, args.alpha_hat).items()}
    rows = []
    for label, mesh, scale in versions():
        where = sampler(mesh, points * scale)
        for method, u in fields(mesh, scale, args.alpha_hat).items():
            d, g = sample(mesh, u, where)
            d_ref, g_ref = reference[method]
            err = np.abs(d / scale - d_ref) / d_ref.max() * 100
            rows.append(dict(version=label, vertices=mesh.n_vertices, method=method,
                             max_distance_change_pct=err.max(), mean_distance_change_pct=err.mean(),
                             mean_gradient_change=np.abs(g - g_ref).mean(), mean_grad_norm=g.mean()))
            print(rows[-1], flush=True)
    lines = [f"reference: cube N={REFERENCE_N} ({ref_mesh.n_vertices:,} vertices), {SAMPLES} common points",
             "", "| version (vertices) | method | max dist. change % | mean dist. change % "
             "| mean abs. change of abs(grad u) | mean abs(grad u) |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['version']} ({r['vertices']:,}) | {r['method']} | {r['max_distance_change_pct']:.2f} "
                     f"| {r['mean_distance_change_pct']:.3f} | {r['mean_gradient_change']:.3f} "
                     f"| {r['mean_grad_norm']:.3f} |")
    print("\n".join(lines))
    write_csv(rows, os.path.join(RESULTS, "robustness.csv"))


if __name__ == "__main__":
    main()
