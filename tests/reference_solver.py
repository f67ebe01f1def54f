"""Independent reference for the discrete Dirichlet problem (docs/method.md section 2).

Assembles the per-face gradient, the face areas and the lumped vertex areas itself in
numpy (deliberately not importing ``warp_regdist``), on the mesh's faces or on libigl's
intrinsic Delaunay triangulation, and solves

    minimize_u   -A_V^T u + (alpha / 2) sum_f a_f |(G u)_f|^2
    subject to   |(G u)_f| <= 1 for every face f,   u_i = 0 for i in E

(with ``source_triangles="edges"``, on a triangle with exactly one corner s in E the cone is replaced
by u_a <= l_sa at its other corners a, l_sa the length of the side sa in the triangulation)

with cvxpy + Clarabel (an interior-point conic solver).
"""

import numpy as np
import scipy.sparse as sp


def tet_geometry(V, T):
    """Tetrahedron volumes and hat-function gradients from the affine map's inverse.

    The barycentric coordinates lambda of x in tetrahedron (v0, v1, v2, v3) solve
    P lambda = (1, x) with the 4 x 4 matrix P = [[1, 1, 1, 1], [v0, v1, v2, v3]], so
    grad lambda_k = (P^-1)[k, 1:4].

    Parameters
    ----------
    V : (n, 3) float64
    T : (m, 4) int64

    Returns
    -------
    volumes : (m,) float64
        |det P| / 6.
    grads : (m, 4, 3) float64
        grads[t, k] = gradient of the hat function of corner k of tetrahedron t.
    """
    P = np.ones((len(T), 4, 4))
    P[:, 1:, :] = np.transpose(V[T], (0, 2, 1))
    return np.abs(np.linalg.det(P)) / 6.0, np.linalg.inv(P)[:, :, 1:]


def face_geometry(V, F):
    """Face areas and unit normals (tetrahedra: volumes, and None for the normals).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) or (m, 4) int64

    Returns
    -------
    areas : (m,) float64
        a_f = |(v1 - v0) x (v2 - v0)| / 2 (tetrahedra: the volumes of `tet_geometry`).
    normals : (m, 3) float64 or None
        N_f = (v1 - v0) x (v2 - v0) / (2 a_f).
    """
    if F.shape[1] == 4:
        return tet_geometry(V, F)[0], None
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    double = np.linalg.norm(c, axis=1)
    return 0.5 * double, c / double[:, None]


def gradient_matrices(V, F):
    """Per-face gradient of piecewise-linear functions, one matrix per component.

    The hat function of corner k of face f has the constant gradient
    N_f x e_k / (2 a_f), e_k = v_{k+2} - v_{k+1} (the opposite edge, counter-clockwise).

    Returns
    -------
    list of 3 (m, n) scipy CSR
        ``G[c] @ u`` is component c of the gradient of u on every face.
    """
    n, m = len(V), len(F)
    rows = np.repeat(np.arange(m), F.shape[1])
    cols = F.ravel()
    if F.shape[1] == 4:  # tetrahedra: see tet_geometry
        grads = tet_geometry(V, F)[1]
    else:
        areas, normals = face_geometry(V, F)
        grads = np.empty((m, 3, 3))
        for k in range(3):
            e = V[F[:, (k + 2) % 3]] - V[F[:, (k + 1) % 3]]
            grads[:, k, :] = np.cross(normals, e) / (2.0 * areas[:, None])
    return [
        sp.csr_matrix((grads[:, :, c].ravel(), (rows, cols)), shape=(m, n)) for c in range(3)
    ]


def vertex_areas(V, F):
    """Barycentric lumped vertex areas A_V[i] = (1/3) sum of a_f over faces at i, shape (n,);
    for tetrahedra (1/4) of the adjacent volumes."""
    areas, _ = face_geometry(V, F)
    A_V = np.zeros(len(V))
    for k in range(F.shape[1]):
        np.add.at(A_V, F[:, k], areas / F.shape[1])
    return A_V


def intrinsic_geometry(V, F):
    """Face areas, per-face gradient matrices and lumped vertex areas on the intrinsic Delaunay
    triangulation of a triangle mesh, from libigl's ``intrinsic_delaunay_triangulation`` (an
    implementation independent of the package's).

    Returns
    -------
    areas : (m,), grads : list of 3 (m, n) CSR, A_V : (n,)
    """
    import igl

    l0 = igl.edge_lengths(np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64))
    l, Fi = igl.intrinsic_delaunay_triangulation(l0, np.asarray(F, dtype=np.int64))[:2]
    return length_geometry(len(V), Fi, l)


def length_geometry(n, Fi, l, weight=1.0):
    """(areas, grads, A_V) of a triangulation known by its faces Fi (m, 3) over n vertices and lengths
    l (m, 3), l[:, k] opposite corner k: each face laid out flat (corner 0 at the origin, corner 1 on
    the x axis), the gradients 2-vectors (z = 0); every area counts ``weight`` times."""
    m = len(Fi)
    a, b, c = l[:, 0], l[:, 1], l[:, 2]                     # opposite corners 0, 1, 2
    P = np.zeros((m, 3, 3))
    P[:, 1, 0] = c
    P[:, 2, 0] = (c * c + b * b - a * a) / (2.0 * c)
    P[:, 2, 1] = np.sqrt(np.maximum(b * b - P[:, 2, 0] ** 2, 0.0))
    flat = P.reshape(-1, 3)
    corners = np.arange(3 * m).reshape(m, 3)
    areas = weight * face_geometry(flat, corners)[0]
    local = gradient_matrices(flat, corners)                  # (m, 3m): columns are corners
    to_vertex = sp.csr_matrix((np.ones(3 * m), (np.arange(3 * m), np.asarray(Fi).ravel())), shape=(3 * m, n))
    grads = [(g @ to_vertex).tocsr() for g in local]
    A_V = np.zeros(n)
    for k in range(3):
        np.add.at(A_V, Fi[:, k], areas / 3.0)
    return areas, grads, A_V


def triangulation_lengths(V, F, triangulation="intrinsic"):
    """(Fi (m, 3), l (m, 3)) of the triangulation of :func:`discrete_operators` of a triangle mesh,
    l[:, k] the length of the side opposite corner k."""
    import igl

    if not isinstance(triangulation, str):
        return np.asarray(triangulation[0]), np.asarray(triangulation[1])
    F = np.asarray(F, dtype=np.int64)
    l0 = igl.edge_lengths(np.asarray(V, dtype=np.float64), F)
    if triangulation == "intrinsic":
        l, Fi = igl.intrinsic_delaunay_triangulation(l0, F)[:2]
        return np.asarray(Fi), np.asarray(l)
    return F, np.asarray(l0)


def discrete_operators(V, F, triangulation="intrinsic"):
    """(areas, grads, A_V) of the problem on the mesh's own elements ("mesh"), on the intrinsic
    Delaunay triangulation (triangle meshes; tetrahedra always use their own), or on a given
    triangulation (Fi, l, weight) (:func:`length_geometry`)."""
    if not isinstance(triangulation, str):
        return length_geometry(len(V), *triangulation)
    if triangulation == "intrinsic" and F.shape[1] == 3:
        return intrinsic_geometry(V, F)
    return face_geometry(V, F)[0], gradient_matrices(V, F), vertex_areas(V, F)


def solve_reference(V, F, sources, alpha, gap_tol=1e-9, feas_tol=1e-8, W=None, triangulation="intrinsic",
                    source_triangles="edges"):
    """Exact minimizer of the discrete Dirichlet-regularized distance problem.

    Parameters
    ----------
    V : (n, 3) float64
        Every vertex must belong to a face and the mesh must be connected (otherwise
        the problem is unbounded).
    F : (m, 3) int64
    sources : (s,) int
        The source set E.
    alpha : float
        Raw regularization weight (not alpha_hat).
    gap_tol : float
        Clarabel's absolute and relative duality-gap tolerance.
    feas_tol : float
        Clarabel's feasibility tolerance (much below 1e-8 it stalls at "almost solved").
    W : (n, n) array_like or None
        Another quadratic regularizer (symmetric PSD) in place of the Dirichlet energy:
        the objective becomes -A_V^T u + (alpha / 2) u^T W u, written as |R u|^2 with
        R = diag(sqrt(lambda)) Q^T from the dense eigendecomposition W = Q diag(lambda) Q^T
        (eigenvalues below 0, round-off, clipped to 0; for a few hundred vertices).
    triangulation : {"intrinsic", "mesh"} or (Fi, l, weight)
        The triangulation of the gradient constraint, the energy and the lumped areas
        (:func:`discrete_operators`), as the package's ``triangulation``, or one given by its faces
        and lengths.
    source_triangles : {"edges", "gradient"}
        "edges": on each triangle with exactly one corner s among the sources, u_a <= l_sa at its other
        corners instead of the cone (triangle meshes; tetrahedra keep the cone); "gradient": the cone
        everywhere.

    Returns
    -------
    (n,) float64
        The minimizer u.
    """
    import cvxpy as cp  # only the conic solves need it: the helpers run without cvxpy
    n = len(V)
    areas, (Gx, Gy, Gz), A_V = discrete_operators(V, F, triangulation)
    u = cp.Variable(n)
    g = cp.vstack([Gx @ u, Gy @ u, Gz @ u])  # (3, m)
    objective = -A_V @ u
    if alpha > 0 and W is not None:
        lam, Q = np.linalg.eigh(np.asarray(W.todense() if hasattr(W, "todense") else W))
        R = np.sqrt(np.maximum(lam, 0.0))[:, None] * Q.T
        objective = objective + 0.5 * alpha * cp.sum_squares(R @ u)
    elif alpha > 0:
        w = np.sqrt(areas)
        energy = (
            cp.sum_squares(cp.multiply(w, Gx @ u))
            + cp.sum_squares(cp.multiply(w, Gy @ u))
            + cp.sum_squares(cp.multiply(w, Gz @ u))
        )
        objective = objective + 0.5 * alpha * energy
    cone = np.ones(len(areas), dtype=bool)
    constraints = [u[np.asarray(sources)] == 0]
    if source_triangles == "edges" and np.shape(F)[1] == 3:
        Fi, l = triangulation_lengths(V, F, triangulation)
        at = np.isin(Fi, np.asarray(sources))
        wedge = at.sum(axis=1) == 1
        cone[wedge] = False
        for f in np.flatnonzero(wedge):
            c = int(np.argmax(at[f]))
            for a, opposite in (((c + 1) % 3, (c + 2) % 3), ((c + 2) % 3, (c + 1) % 3)):
                constraints.append(u[Fi[f, a]] <= l[f, opposite])
    elif source_triangles not in ("edges", "gradient"):
        raise ValueError(f"expected source_triangles 'edges' or 'gradient', got {source_triangles!r}")
    constraints.append(cp.SOC(np.ones(int(cone.sum())), g[:, np.flatnonzero(cone)], axis=0))
    problem = cp.Problem(cp.Minimize(objective), constraints)
    problem.solve(
        solver=cp.CLARABEL,
        tol_gap_abs=gap_tol,
        tol_gap_rel=gap_tol,
        tol_feas=feas_tol,
        max_iter=500,
    )
    if problem.status != cp.OPTIMAL:
        raise RuntimeError(f"expected status optimal, got {problem.status}")
    return np.asarray(u.value)
