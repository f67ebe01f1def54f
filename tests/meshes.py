"""Small procedural triangle meshes for the tests.

Every generator returns ``(V, F)``: vertex positions of shape (n, 3) float64 and
triangles of shape (m, 3) int64, consistently oriented (counter-clockwise seen from
outside for closed surfaces, from +z for flat meshes, from outside the axis for the
cylinder).
"""

import numpy as np
import trimesh


def cylinder(n_theta, n_h, height):
    """Open cylinder S^1 x [0, height] of circumference 2 pi (radius 1).

    Parameters
    ----------
    n_theta : int
        Vertices around the circle, at angles theta_j = 2 pi j / n_theta; column j = 0
        lies exactly at angle 0 (the generator line x = 1, y = 0).
    n_h : int
        Vertices along the axis, at z_i = height * i / (n_h - 1).
    height : float
        Length of the cylinder.

    Returns
    -------
    V : (n_theta * n_h, 3) float64
        Vertex ``i * n_theta + j`` is (cos theta_j, sin theta_j, z_i).
    F : (2 * n_theta * (n_h - 1), 3) int64
        Each grid quad split into two right triangles along the same diagonal, so the
        cotangent weight of every diagonal edge is zero and a function of theta alone
        has the same discrete energy and gradient norm in every row.
    """
    theta = 2.0 * np.pi * np.arange(n_theta) / n_theta
    z = height * np.arange(n_h) / (n_h - 1)
    V = np.stack(
        [np.tile(np.cos(theta), n_h), np.tile(np.sin(theta), n_h), np.repeat(z, n_theta)],
        axis=1,
    )
    j = np.arange(n_theta)
    jn = (j + 1) % n_theta
    faces = []
    for i in range(n_h - 1):
        a, b = i * n_theta + j, i * n_theta + jn
        c, d = (i + 1) * n_theta + jn, (i + 1) * n_theta + j
        faces.append(np.stack([a, b, c], axis=1))
        faces.append(np.stack([a, c, d], axis=1))
    return V, np.concatenate(faces).astype(np.int64)


def cylinder_generator_line(n_theta, n_h):
    """Indices of the vertices at angle 0 of `cylinder(n_theta, n_h, h)`, shape (n_h,)."""
    return np.arange(n_h, dtype=np.int64) * n_theta


def disk(radius, n_rings):
    """Flat disk of the given radius in the plane z = 0, made of concentric rings.

    Ring k (k = 1 .. n_rings) has radius ``radius * k / n_rings`` and 6 k vertices at
    angles 2 pi i / (6 k). Neighbouring rings are zipped together, closing each quad
    along its shorter diagonal, which gives near-equilateral triangles (all angles
    between 44 and 90 degrees). The outermost ring lies exactly on the circle of the
    given radius (it is the boundary).

    Returns
    -------
    V : (1 + 3 n_rings (n_rings + 1), 3) float64
        Vertex 0 is the centre, then ring 1, ring 2, ...
    F : (6 n_rings^2, 3) int64
        Counter-clockwise seen from +z.
    """
    pts = [np.zeros((1, 3))]
    starts = [0]
    for k in range(1, n_rings + 1):
        t = 2.0 * np.pi * np.arange(6 * k) / (6 * k)
        r = radius * k / n_rings
        starts.append(starts[-1] + (1 if k == 1 else 6 * (k - 1)))
        pts.append(np.stack([r * np.cos(t), r * np.sin(t), np.zeros_like(t)], axis=1))
    V = np.concatenate(pts)
    faces = [(0, starts[1] + i, starts[1] + (i + 1) % 6) for i in range(6)]
    for k in range(1, n_rings):
        n_in, n_out = 6 * k, 6 * (k + 1)
        s_in, s_out = starts[k], starts[k + 1]
        i = j = 0
        while i < n_in or j < n_out:
            # close the quad (in_i, out_j, out_j+1, in_i+1) along its shorter diagonal
            a, b = s_in + i % n_in, s_out + j % n_out
            a1, b1 = s_in + (i + 1) % n_in, s_out + (j + 1) % n_out
            if j == n_out or (
                i < n_in and np.linalg.norm(V[a1] - V[b]) < np.linalg.norm(V[b1] - V[a])
            ):
                faces.append((a, b, a1))
                i += 1
            else:
                faces.append((a, b, b1))
                j += 1
    return V, np.asarray(faces, dtype=np.int64)


def icosphere(subdivisions, radius=1.0):
    """Subdivided icosahedron with all vertices on the sphere of the given radius.

    Returns
    -------
    V : (10 * 4^subdivisions + 2, 3) float64
    F : (20 * 4^subdivisions, 3) int64
        Outward oriented.
    """
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


def square_grid(n, size=1.0):
    """Flat square [0, size]^2 in the plane z = 0 with n x n vertices.

    Returns
    -------
    V : (n * n, 3) float64
        Vertex ``i * n + j`` is (size j / (n - 1), size i / (n - 1), 0).
    F : (2 (n - 1)^2, 3) int64
        Counter-clockwise seen from +z.
    """
    x = size * np.arange(n) / (n - 1)
    X, Y = np.meshgrid(x, x)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b, c, d = a + 1, a + n + 1, a + n
    F = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
    return V, F.astype(np.int64)


def perturbed(V, F, amplitude, seed=0):
    """Move every vertex along its (area-weighted) vertex normal by a random amount.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    amplitude : float
        Offsets are uniform in [-amplitude, amplitude].
    seed : int

    Returns
    -------
    (n, 3) float64
    """
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals = np.zeros_like(V)
    for k in range(3):
        np.add.at(normals, F[:, k], c)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    return V + amplitude * rng.uniform(-1.0, 1.0, size=(len(V), 1)) * normals
