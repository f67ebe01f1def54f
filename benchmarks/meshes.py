"""Meshes for the benchmarks: the shared real meshes and subdivided (cube-)spheres of any size."""

import os

import numpy as np

import warp_regdist as wrd

SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared")


def shared_mesh(name):
    """A mesh of ../shared/meshes by name, or a mesh file's path; None when there is no such file."""
    path = name if os.path.isfile(name) else os.path.join(SHARED, "meshes", f"{name}.off")
    return wrd.load_mesh(path) if os.path.isfile(path) else None


def cube_sphere(N):
    """Unit sphere from a cube whose faces are split into N x N quads (2 triangles each).

    n = 6 N^2 + 2 vertices, m = 12 N^2 faces; N = 129 gives ~100k vertices, N = 408 ~1M.
    """
    t = np.linspace(-1.0, 1.0, N + 1)
    a, b = np.meshgrid(t, t, indexing="ij")
    a, b = a.ravel(), b.ravel()
    one = np.ones_like(a)
    idx = np.arange((N + 1) ** 2).reshape(N + 1, N + 1)
    q = np.stack([idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()], 1)
    P, F = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            xyz = [None, None, None]
            xyz[axis] = sign * one
            xyz[(axis + 1) % 3], xyz[(axis + 2) % 3] = (a, b) if sign > 0 else (b, a)
            base = sum(len(p) for p in P)
            P.append(np.stack(xyz, 1))
            F.append(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]) + base)
    P, F = np.concatenate(P), np.concatenate(F)
    key = np.round(P * (4 * N)).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    V = P[first]
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    return wrd.Mesh(V, inv.ravel()[F])


def subdivided_decimated(name, vertices, levels=2, aggressiveness=3):
    """shared mesh ``name`` Loop-subdivided ``levels`` times, then decimated to about ``vertices`` vertices by
    fast-simplification (its quadric decimation at ``aggressiveness``, 3 of 0-10: smallest angle 5.3 degrees on
    cat_rr to 10,099 vertices, where 7 leaves 0.6): a large irregular mesh of a real shape; None without
    ../shared."""
    import fast_simplification
    import trimesh

    mesh = shared_mesh(name)
    if mesh is None:
        return None
    V, F = trimesh.remesh.subdivide_loop(np.array(mesh.vertices), np.array(mesh.elements), iterations=levels)
    V, F = fast_simplification.simplify(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                                        target_reduction=1 - vertices / len(V), agg=aggressiveness)
    merged = trimesh.Trimesh(V, F, process=True)
    return wrd.Mesh(np.array(merged.vertices, dtype=np.float64), np.array(merged.faces, dtype=np.int64))
