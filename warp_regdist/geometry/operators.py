"""Piecewise-linear finite-element operators on a simplicial mesh (docs/method.md section 2).

For element e with vertices v_0..v_d (d = 2 triangles, d = 3 tetrahedra) the hat
function of v_l has the constant gradient ``basis[e, l]`` (a 3-vector tangent to the
element). With the element volumes (areas) a_e:

    G   (3m x n):  (G u)_e = sum_l basis[e, l] u[v_l]                       (dimensionless)
    M_F (3m x 3m): diag(a_e) repeated for the three components
    D   (n x 3m):  D = G^T M_F                                                 (length^(d-1))
    W_D (n x n):   W_D = G^T M_F G, the cotangent stiffness matrix             (length^(d-2))
    A_V (n,):      lumped vertex volumes, a_e / (d + 1) to each vertex of e    (length^d)
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from .mesh import Mesh

__all__ = ["Operators", "build_operators", "assemble_operators", "element_gradients", "element_diameters",
           "largest_angles", "largest_basis_angles", "choose_triangulation"]


@dataclasses.dataclass(frozen=True)
class Operators:
    """Operators of one mesh, assembled once (float64, scipy / numpy).

    Attributes
    ----------
    elements : (m, d + 1) ndarray of int64
        The elements the operators are built on (the mesh's own).
    basis : (m, d + 1, 3) ndarray
        Hat-function gradients per element and local vertex.
    element_volumes : (m,) ndarray
        Areas (triangles) or volumes (tetrahedra) a_e.
    vertex_volumes : (n,) ndarray
        Lumped vertex areas / volumes A_V.
    total_volume : float
        A = sum(a_e).
    grad : (3m, n) scipy.sparse.csr_matrix
        G; row 3 e + c is component c of the gradient on element e.
    stiffness : (n, n) scipy.sparse.csr_matrix
        W_D = G^T M_F G (symmetric positive semi-definite, constants in its kernel).
    vertex_elements : tuple of three ndarrays (offsets (n+1,), element (k,), local (k,))
        For vertex i, entries offsets[i]:offsets[i+1] list the incident elements and the
        local index of i in each: the gather form of D.
    diameters : (m,) ndarray
        The longest edge of each element.
    intrinsic : IntrinsicTriangulation or None
        The intrinsic Delaunay triangulation the operators are built on (None: the mesh's elements).
    """

    elements: np.ndarray
    basis: np.ndarray
    element_volumes: np.ndarray
    vertex_volumes: np.ndarray
    total_volume: float
    grad: sp.csr_matrix
    stiffness: sp.csr_matrix
    vertex_elements: tuple
    diameters: np.ndarray
    intrinsic: object = None

    @property
    def length_scale(self):
        """A^(1/d): the mesh's length unit (sqrt of the area, cube root of the volume)."""
        d = self.basis.shape[1] - 1
        return float(self.total_volume ** (1.0 / d))

    def max_gradient(self, u, block=256):
        """(k,) max over elements of |G u| per column of ``u`` (n, k) (or (n,): k = 1), ``block`` columns at
        a time (G u is (3m, k)); +inf entries (unreachable vertices) count as 0, NaN gives NaN."""
        u = np.where(np.isposinf(u), 0.0, u).reshape(u.shape[0], -1)
        m = self.grad.shape[0] // 3
        with np.errstate(over="ignore", invalid="ignore"):
            return np.concatenate([np.sqrt(np.square((self.grad @ u[:, j:j + block]).reshape(m, 3, -1)).sum(axis=1))
                                   .max(axis=0, initial=0.0) for j in range(0, u.shape[1], block)])


def element_gradients(vertices, elements):
    """Hat-function gradients and volumes of simplices.

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
    elements : (m, d + 1) ndarray of int, d in {2, 3}

    Returns
    -------
    basis : (m, d + 1, 3) ndarray
        basis[e, l] = gradient of the barycentric coordinate of local vertex l.
    volumes : (m,) ndarray
        Unsigned areas (d = 2) or volumes (d = 3).

    With E = [v_1 - v_0, ..., v_d - v_0] (3 x d), the gradients of lambda_1..lambda_d are
    the rows of the pseudo-inverse (E^T E)^{-1} E^T, and grad lambda_0 = -sum of the others.
    """
    P = vertices[elements]
    d = elements.shape[1] - 1
    E = np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1))          # (m, 3, d)
    gram = np.einsum("mki,mkj->mij", E, E)                     # (m, d, d)
    rows = np.linalg.solve(gram, np.transpose(E, (0, 2, 1)))   # (m, d, 3)
    basis = np.concatenate([-rows.sum(axis=1, keepdims=True), rows], axis=1)
    volumes = np.sqrt(np.abs(np.linalg.det(gram))) / (1.0 if d == 1 else 2.0 if d == 2 else 6.0)
    return basis, volumes


def element_diameters(vertices, elements):
    """(m,) longest edge of each simplex, max over its vertex pairs of |v_a - v_b|."""
    P = vertices[elements]
    k = elements.shape[1]
    return np.max([np.linalg.norm(P[:, a] - P[:, b], axis=1) for a in range(k) for b in range(a + 1, k)], axis=0)


def largest_angles(vertices, faces):
    """(m,) largest interior angle of each triangle (m, 3), in degrees: the angle opposite its longest side."""
    P = vertices[faces]
    a = np.roll(P, 1, axis=1) - P   # corner c: sides to the previous and the next corner
    b = np.roll(P, -1, axis=1) - P
    cos = np.einsum("mcd,mcd->mc", a, b) / (np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max(axis=1)


def largest_basis_angles(basis):
    """(m,) largest interior angle, in degrees, of triangles given by their hat-function gradients (m, 3, 3):
    the angle at corner c is pi minus the angle between the gradients of the other two corners (each
    normal to the side opposite its corner). Works for faces laid out in any frame."""
    b0, b1, b2 = basis[:, 0], basis[:, 1], basis[:, 2]

    def between(p, q):
        cos = np.einsum("md,md->m", p, q) / (np.linalg.norm(p, axis=1) * np.linalg.norm(q, axis=1))
        return 180.0 - np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    return np.max([between(b1, b2), between(b2, b0), between(b0, b1)], axis=0)


def corner_angle(basis, corner):
    """The interior angle, in degrees, at ``corner`` of one triangle given by its hat-function gradients (3, 3)."""
    p, q = basis[(corner + 1) % 3], basis[(corner + 2) % 3]
    cos = float(p @ q) / (np.linalg.norm(p) * np.linalg.norm(q))
    return 180.0 - float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def mean_edge_length(vertices, faces):
    """Mean over the three sides of every triangle (m, 3) of |v_a - v_b| (an interior edge counts twice)."""
    P = vertices[faces]
    return float(np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2).mean())


def choose_triangulation(mesh, regularizer="dirichlet", triangulation=None):
    """The triangulation the solvers build their operators on: ``triangulation`` checked, or for None
    "intrinsic" where it applies (triangle meshes, not point clouds, not the vector-field regularizer)."""
    applies = mesh.element_dim == 2 and mesh.element_weights is None and regularizer != "vector_field"
    if triangulation is None:
        return "intrinsic" if applies else "mesh"
    if triangulation not in ("intrinsic", "mesh"):
        raise ValueError(f"expected triangulation 'intrinsic', 'mesh' or None, got {triangulation!r}")
    if triangulation == "intrinsic" and not applies:
        what = ("a tetrahedral mesh" if mesh.element_dim == 3 else "a PointCloud" if mesh.element_weights is not None
                else "the vector-field regularizer (its field lives on the mesh's faces)")
        raise ValueError(f"expected triangulation 'mesh' for {what}, got 'intrinsic'")
    return triangulation


def build_operators(mesh: Mesh, triangulation: str = "mesh", flipped=None) -> Operators:
    """Assemble the :class:`Operators` of a :class:`~warp_regdist.Mesh`.

    ``triangulation``: "mesh" builds them on the mesh's own elements; "intrinsic" on the intrinsic
    Delaunay triangulation of a triangle mesh's vertices (:mod:`warp_regdist.geometry.intrinsic`):
    the same vertices and surface, faces known by their edge lengths and laid out flat, so the
    gradients are 2-vectors in each face's own frame (z = 0); on a non-manifold mesh they are those
    of its tufted cover, each face at half its area. The element volumes are multiplied by
    ``mesh.element_weights`` where it has them (point clouds, always on their own elements).
    ``flipped``: the mesh's intrinsic Delaunay triangulation where it was computed already.
    """
    if triangulation not in ("mesh", "intrinsic"):
        raise ValueError(f"expected triangulation 'mesh' or 'intrinsic', got {triangulation!r}")
    n = mesh.n_vertices
    if triangulation == "intrinsic" and mesh.element_dim == 2 and mesh.element_weights is None:
        from .intrinsic import flat_layout, intrinsic_delaunay

        T = intrinsic_delaunay(mesh.vertices, mesh.elements) if flipped is None else flipped
        if T.flip_count == 0:       # the mesh is intrinsically Delaunay already: its own operators
            return build_operators(mesh)
        m = T.faces.shape[0]
        basis, vol = element_gradients(flat_layout(T.lengths).reshape(-1, 3), np.arange(3 * m).reshape(m, 3))
        return assemble_operators(T.faces, basis, vol * T.area_weight, n, T.lengths.max(axis=1), intrinsic=T)
    T = mesh.elements
    basis, vol = element_gradients(mesh.vertices, T)
    if mesh.element_weights is not None:
        vol = vol * mesh.element_weights
    return assemble_operators(T, basis, vol, n, element_diameters(mesh.vertices, T))


def assemble_operators(T, basis, vol, n, diameters, intrinsic=None):
    """The :class:`Operators` of elements T (m, d + 1) on n vertices with hat-function gradients
    ``basis`` (m, d + 1, 3) and volumes ``vol`` (m,).

    G is written in CSR form directly (row 3 e + c holds the element's vertices in
    increasing order) and M_F G^T from the vertex-element incidence (one counting sort),
    so that W_D = (G^T M_F) G is a single sparse product, with no COO or CSC conversions.
    """
    m, k = T.shape
    index = np.int32 if max(3 * m * k, 3 * m, n) < 2 ** 31 else np.int64
    local = np.argsort(T, axis=1)
    columns = np.broadcast_to(np.take_along_axis(T, local, axis=1)[:, None, :].astype(index), (m, 3, k))
    values = np.take_along_axis(basis.transpose(0, 2, 1), local[:, None, :], axis=2)          # (m, 3, k)
    G = sp.csr_matrix((values.ravel(), columns.ravel(), np.arange(0, 3 * m * k + 1, k, dtype=index)), shape=(3 * m, n))
    incidence = sp.csr_matrix((np.arange(m * k), T.ravel(), np.arange(0, m * k + 1, k)), shape=(m, n)).tocsc()
    offsets, element, corner = incidence.indptr.astype(np.int64), incidence.data // k, incidence.data % k
    weights = basis.reshape(m * k, 3)[incidence.data] * vol[element, None]                   # M_F G^T, (k m, 3)
    GtM = sp.csr_matrix((weights.ravel(), (3 * element[:, None] + np.arange(3)).astype(index).ravel(),
                         3 * offsets.astype(index)), shape=(n, 3 * m))
    W = GtM @ G
    W = ((W + W.T) * 0.5).tocsr()
    W.sort_indices()
    AV = np.bincount(T.ravel(), weights=np.repeat(vol / k, k), minlength=n)
    return Operators(T, basis, vol, AV, float(vol.sum()), G, W, (offsets, element, corner), diameters, intrinsic)
