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


def cube_tets(n, size=1.0):
    """Cube [0, size]^3 cut into n^3 grid cells of 6 tetrahedra each (Kuhn / Freudenthal).

    Every cell is split along its diagonal (0, 0, 0) -> (1, 1, 1): one tetrahedron per
    order in which the path to the opposite corner takes the three axis steps. All cells
    use the same diagonal, so the tetrahedra of neighbouring cells share their faces
    (a conforming mesh), and all are congruent, of volume size^3 / (6 n^3).

    Returns
    -------
    V : ((n + 1)^3, 3) float64
        Vertex ``(i (n + 1) + j) (n + 1) + k`` is size (i, j, k) / n.
    T : (6 n^3, 4) int64
        Positively oriented: det(v1 - v0, v2 - v0, v3 - v0) > 0.
    """
    x = size * np.arange(n + 1) / n
    V = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    corner = idx[:-1, :-1, :-1].ravel()
    stride = np.array([(n + 1) ** 2, n + 1, 1])
    tets = []
    for perm, sign in (((0, 1, 2), 1), ((1, 2, 0), 1), ((2, 0, 1), 1),
                       ((0, 2, 1), -1), ((2, 1, 0), -1), ((1, 0, 2), -1)):
        steps = np.cumsum(stride[list(perm)])
        t = np.stack([corner, corner + steps[0], corner + steps[1], corner + steps[2]], axis=1)
        tets.append(t if sign > 0 else t[:, [0, 2, 1, 3]])
    return V, np.concatenate(tets).astype(np.int64)


def ball_tets(subdivisions, n_shells, radius=1.0):
    """Solid ball of concentric icosphere shells joined by prisms, each cut into 3 tetrahedra.

    Shell j = 1 .. n_shells is the icosphere of `icosphere(subdivisions)` scaled to radius
    ``radius j / n_shells``; the centre is joined to the innermost shell by one
    tetrahedron per triangle. A prism between the triangle (a, b, c) of shell j and the
    same triangle of shell j + 1 (primed) is cut, with the corners sorted p < q < r by
    icosphere index, into (p, q, r, r'), (p, q, q', r'), (p, p', q', r'): each side quad
    is split along the diagonal from its lower-index bottom corner to its higher-index top
    corner, the same choice in both prisms that share it, so the mesh is conforming.
    Mesh edges run along the rays, so a radial function is interpolated without the
    tangential gradient error of a distorted cube grid.

    Returns
    -------
    V : (1 + n_shells k, 3) float64
        Vertex 0 is the centre, then shell 1, shell 2, ... (k icosphere vertices each);
        the last shell (the boundary) lies exactly on the sphere of the given radius.
    T : (f (3 n_shells - 2), 4) int64
        f icosphere triangles; positively oriented.
    """
    S, F = icosphere(subdivisions, 1.0)
    k = len(S)
    r = radius * np.arange(1, n_shells + 1) / n_shells
    V = np.concatenate([np.zeros((1, 3)), (r[:, None, None] * S[None]).reshape(-1, 3)])
    tets = [np.concatenate([np.zeros((len(F), 1), np.int64), 1 + F], axis=1)]
    p, q, s = np.sort(F, axis=1).T
    for j in range(n_shells - 1):
        lo, hi = 1 + j * k, 1 + (j + 1) * k
        tets += [np.stack([lo + p, lo + q, lo + s, hi + s], axis=1),
                 np.stack([lo + p, lo + q, hi + q, hi + s], axis=1),
                 np.stack([lo + p, hi + p, hi + q, hi + s], axis=1)]
    T = np.concatenate(tets).astype(np.int64)
    flip = tet_volumes(V, T) < 0
    T[flip] = T[flip][:, [0, 2, 1, 3]]
    return V, T


def tet_volumes(V, T):
    """Signed volumes det(v1 - v0, v2 - v0, v3 - v0) / 6 of tetrahedra, shape (m,)."""
    P = V[T]
    return np.linalg.det(P[:, 1:] - P[:, :1]) / 6.0


def square_with_hole(n, size=1.0, hole=0.4):
    """`square_grid(n, size)` with the faces in the central square of side ``hole * size`` removed.

    A face is removed when its centroid lies in the open square |x - size/2| < hole size / 2,
    |y - size/2| < hole size / 2; vertices no longer referenced are dropped.

    Returns
    -------
    V : (k, 3) float64
    F : (m', 3) int64
        Counter-clockwise seen from +z; the hole's rim is a second boundary loop.
    kept : (k,) int64
        Index in `square_grid(n, size)` of every vertex (to compare functions on both meshes).
    """
    V, F = square_grid(n, size)
    c = V[F].mean(axis=1) - 0.5 * size
    F = F[np.max(np.abs(c[:, :2]), axis=1) >= 0.5 * hole * size]
    kept = np.unique(F)
    index = np.full(len(V), -1, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    return V[kept], index[F], kept
