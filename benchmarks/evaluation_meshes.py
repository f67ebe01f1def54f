"""A generated smooth shape ("blob") in several tessellations, for the evaluation benchmarks.

The blob is the image of the unit sphere under

    p -> diag(1.5, 1, 0.8) p (1 + 0.12 sin(3 p_x) cos(2 p_y) + 0.08 p_z^2),

a smooth, closed, genus-0 surface without symmetries.  Each tessellation maps sphere
vertices through it, so all versions sample the same surface and the source direction
(1, 0, 0) is a vertex of every version.
"""

import numpy as np
import trimesh

import warp_regdist as wrd
from meshes import cube_sphere

SOURCE_DIRECTION = np.array([1.0, 0.0, 0.0])


def blob_map(P):
    """Map (k, 3) unit vectors onto the blob surface."""
    x, y, z = P.T
    r = 1.0 + 0.12 * np.sin(3 * x) * np.cos(2 * y) + 0.08 * z**2
    return P * r[:, None] * np.array([1.5, 1.0, 0.8])


def blob(N):
    """Blob from the cube sphere (6 N^2 + 2 vertices, near-uniform triangles); N even."""
    sphere = cube_sphere(N)
    return wrd.Mesh(blob_map(sphere.vertices), sphere.faces)


def blob_uv(n_lon, n_lat):
    """Blob from a latitude-longitude sphere: elongated triangles (aspect ~ n_lon / (2 n_lat)).

    n_lat even, so the equator, with the source direction (1, 0, 0), is a vertex ring.
    """
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)[1:-1]
    lon = 2 * np.pi * np.arange(n_lon) / n_lon
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    ring = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], -1).reshape(-1, 3)
    P = np.concatenate([ring, [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]])
    south, north = len(ring), len(ring) + 1
    idx = np.arange(len(ring)).reshape(n_lat - 1, n_lon)
    nxt = np.roll(idx, -1, axis=1)
    quads = [np.stack([idx[:-1], nxt[:-1], nxt[1:]], -1), np.stack([idx[:-1], nxt[1:], idx[1:]], -1)]
    caps = [np.stack([np.full(n_lon, south), nxt[0], idx[0]], -1),
            np.stack([np.full(n_lon, north), idx[-1], nxt[-1]], -1)]
    F = np.concatenate([q.reshape(-1, 3) for q in quads] + caps)
    return wrd.Mesh(blob_map(P), F)


def mean_edge_length(mesh):
    """Mean length of the unique edges of a triangle mesh."""
    return float(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).edges_unique_length.mean())


def with_normal_noise(mesh, amplitude, seed=0):
    """Each vertex moved along its normal by U(-a, a) h, h the mean edge length."""
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    shift = np.random.default_rng(seed).uniform(-amplitude, amplitude, len(tm.vertices))
    V = mesh.vertices + (shift * mean_edge_length(mesh))[:, None] * tm.vertex_normals
    return wrd.Mesh(V, mesh.faces)


def source_vertex(mesh, scale=1.0):
    """Index of the vertex closest to the blob point of SOURCE_DIRECTION (times scale)."""
    target = scale * blob_map(SOURCE_DIRECTION[None])[0]
    return int(np.argmin(np.linalg.norm(mesh.vertices - target, axis=1)))
