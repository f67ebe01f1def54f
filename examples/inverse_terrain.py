"""Inverse design with gradients through the solve: shape a terrain so that distances hit targets.

    python examples/inverse_terrain.py [--grid N] [--steps K] [--output DIR]

A flat square heightfield (N x N vertices, default 21) has a source at its centre and four
target vertices 0.3 away from it. The heights z, from small smooth random bumps (on the flat square
the gradient with respect to z vanishes), are optimized by Adam so that the regularized distance
(alpha_hat 0.05) from the source reaches 1.3, 1.0, 1.5 and 1.15 times its value on the flat
square at the targets: a target further away needs relief between it and the source. The loss is

    L(z) = sum_k (u_k(z) - d_k)^2 + smoothness z^T W_D z,

its gradient dL/dz the z column of ``res.vjp(dL/du).vertices`` plus that of the smoothness term
(W_D of the flat square). Prints the loss and the distances at the targets every few steps and
writes inverse_terrain.png: the heights found, the distance on them, and the loss per step.
"""

import argparse
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import warp_regdist as wrd  # noqa: E402

STRETCH = np.array([1.3, 1.0, 1.5, 1.15])
SMOOTHNESS = 2e-3


def grid(n):
    """The unit square as an n x n grid of vertices, two triangles per cell."""
    t = np.linspace(0.0, 1.0, n)
    x, y = np.meshgrid(t, t, indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=int, default=21, help="vertices per side (default 21)")
    parser.add_argument("--steps", type=int, default=60, help="Adam steps (default 60)")
    parser.add_argument("--output", default="inverse-terrain")
    args = parser.parse_args()
    V, F = grid(args.grid)
    source = int(np.argmin(np.linalg.norm(V[:, :2] - 0.5, axis=1)))
    spots = 0.5 + 0.3 * np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    targets = [int(np.argmin(np.linalg.norm(V[:, :2] - p, axis=1))) for p in spots]
    flat = wrd.DistanceSolver(wrd.Mesh(V, F), 0.05, workers=1)
    W, wanted = flat.operators.stiffness, STRETCH * flat.solve([source]).distance[targets]
    z = 0.003 * np.random.default_rng(0).standard_normal(len(V))
    for _ in range(20):  # smoothed: the mean over each vertex's neighbours
        z = (W != 0).astype(float) @ z / np.asarray((W != 0).sum(axis=1)).ravel()
    m1, m2 = np.zeros(len(V)), np.zeros(len(V))
    losses = []
    for step in range(1, args.steps + 1):
        mesh = wrd.Mesh(np.column_stack([V[:, :2], z]), F)
        res = wrd.DistanceSolver(mesh, 0.05, workers=1).solve([source])
        miss = res.distance[targets] - wanted
        losses.append(float(miss @ miss + SMOOTHNESS * z @ (W @ z)))
        grad_u = np.zeros(len(V))
        grad_u[targets] = 2.0 * miss
        dz = res.vjp(grad_u).vertices[:, 2] + 2.0 * SMOOTHNESS * (W @ z)
        m1 = 0.9 * m1 + 0.1 * dz                   # Adam, learning rate 0.01
        m2 = 0.999 * m2 + 0.001 * dz * dz
        z -= 0.01 * (m1 / (1 - 0.9 ** step)) / (np.sqrt(m2 / (1 - 0.999 ** step)) + 1e-12)
        if step % 10 == 0 or step == 1:
            print(f"step {step}: loss {losses[-1]:.3e}, distances at the targets "
                  f"{np.array2string(res.distance[targets], precision=3)} (wanted {np.array2string(wanted, precision=3)})")
    os.makedirs(args.output, exist_ok=True)
    fig, ax = plt.subplots(1, 3, figsize=(14, 4.2))
    tri = ax[0].tripcolor(V[:, 0], V[:, 1], F, z, shading="gouraud", cmap="terrain")
    fig.colorbar(tri, ax=ax[0], label="height z")
    ax[0].set_title("heights found")
    tri = ax[1].tripcolor(V[:, 0], V[:, 1], F, res.distance, shading="gouraud", cmap="viridis")
    ax[1].tricontour(V[:, 0], V[:, 1], F, res.distance, levels=12, colors="white", linewidths=0.6)
    fig.colorbar(tri, ax=ax[1], label="distance")
    ax[1].set_title("distance from the centre on them")
    for a in ax[:2]:
        a.plot(*V[source, :2], "r*", ms=12)
        a.plot(*V[targets, :2].T, "ko", mfc="none", ms=9)
        for k, t in enumerate(targets):
            a.annotate(f"{res.distance[t]:.3f} / {wanted[k]:.3f}", V[t, :2], xytext=(-40, 9), textcoords="offset points", fontsize=8)
        a.set_aspect("equal")
        a.set_xticks([])
        a.set_yticks([])
    ax[2].semilogy(np.arange(1, len(losses) + 1), losses)
    ax[2].set_xlabel("Adam step")
    ax[2].set_title("loss")
    fig.tight_layout()
    path = os.path.join(args.output, "inverse_terrain.png")
    fig.savefig(path, dpi=110)
    print(f"final loss {losses[-1]:.3e} (first {losses[0]:.3e}); wrote {path}")


if __name__ == "__main__":
    main()
