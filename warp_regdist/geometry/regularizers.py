"""The quadratic regularizers W of the distance problem and their scale-invariant weights (docs/method.md section 3).

    minimize_u  -A_V^T u + (alpha / 2) u^T W u   subject to |(G u)_e| <= 1, u_E = 0

    "dirichlet":     W = W_D = G^T M_F G,                                alpha = alpha_hat A^(1/d)
    "vector_field":  W = W_V = D (I + beta Vhat) G = G^T M_F (I + beta Vhat) G,
                     Vhat block-diagonal, Vhat_f = V_f V_f^T, beta = beta_hat,  alpha = alpha_hat A^(1/d)
    "hessian":       W = W_H, the curved Hessian energy (Stein et al. 2020, libigl's
                     ``curved_hessian_energy``), u^T W_H u ~ integral of |Hess u|^2,
                                                                         alpha = alpha_hat A^(3/2)

(A is the total area, d = 2, or the total volume, d = 3.) W_V penalizes the gradient's
component along the field, (G u)_f . V_f, so the isolines of u turn to follow V.
The ADMM's u-step matrix is K(rho) = alpha W + rho W_D; :class:`Regularizer` stores W
and W_D on the union of their sparsity patterns, so K(rho) for any rho is one vector
operation on the values and keeps one pattern (``BatchedPCG.set_matrix``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..arguments import check_weight

__all__ = ["REGULARIZERS", "Regularizer", "build_regularizer"]

REGULARIZERS = ("dirichlet", "vector_field", "hessian")

HESSIAN_TOLERANCE_FACTOR = 1.0 / 20.0
"""The Hessian's stopping tolerances are the defaults times this (docs/method.md section 8)."""

SMALL_ALPHA_HAT, SMALL_ALPHA_FACTOR = 0.02, 0.25
"""Below alpha_hat 0.02 the Dirichlet and vector-field tolerances shrink linearly to 1/4 at 0: towards
alpha 0 the problem nears a linear program and the ADMM creeps (docs/design/stopping.md)."""

HESSIAN_SCHEDULE = (1.0, 8.0, 1.0)
"""The Hessian's factors on rho0, rho_max and rho_doubling: its fourth-order term needs penalties up to
8 times larger to converge in a few hundred iterations."""


@dataclasses.dataclass(frozen=True)
class Regularizer:
    """One regularizer of one mesh.

    Attributes
    ----------
    name : str
        One of :data:`REGULARIZERS`.
    alpha : float
        The raw weight alpha (from alpha_hat by the table above).
    weights : (n, n) scipy.sparse.csr_matrix or None
        W on the union pattern of W and W_D; None for "dirichlet" (W = W_D, whose u-step
        matrix (alpha + rho) W_D is a rescaled W_D).
    stiffness : (n, n) scipy.sparse.csr_matrix or None
        W_D on the same pattern as ``weights`` (None for "dirichlet").
    tolerance_factor : float
        Factor on the ADMM stopping tolerances and on the u-step's CG tolerance
        (the options' ``cg_fraction``): 1; down to 1/4 below alpha_hat 0.02
        (:func:`small_alpha_factor`); 1/20 for the Hessian, whose inexact u-steps otherwise
        keep the primal residual above its tolerance.
    schedule_factors : (float, float, float)
        Factors on the options' ``rho0``, ``rho_max`` and ``rho_doubling``:
        :func:`small_alpha_schedule` for "dirichlet" and "vector_field" (on triangles, 1, 1, 1 from
        alpha_hat 0.02 up, a penalty that starts at half and doubles half as fast at 0; on tetrahedra
        1, 1, 1), ``HESSIAN_SCHEDULE`` for the Hessian.
    """

    name: str
    alpha: float
    weights: sp.csr_matrix | None
    stiffness: sp.csr_matrix | None
    tolerance_factor: float
    schedule_factors: tuple

    @property
    def rescaled(self):
        """Whether the u-step matrix is the rescaled stiffness (alpha + rho) W_D ("dirichlet"): a new rho
        only divides the right-hand side, and the PCG keeps W_D."""
        return self.weights is None

    def system(self, rho):
        """The u-step matrix K = alpha W + rho W_D, (n, n) csr on the union pattern (not for "dirichlet")."""
        W, WD = self.weights, self.stiffness
        return sp.csr_matrix((self.alpha * W.data + rho * WD.data, W.indices, W.indptr), shape=W.shape)


def small_alpha_factor(alpha_hat):
    """Tolerance factor of the Dirichlet and vector-field problems: 1 from alpha_hat
    ``SMALL_ALPHA_HAT`` up, falling linearly to ``SMALL_ALPHA_FACTOR`` at alpha_hat 0."""
    return max(SMALL_ALPHA_FACTOR, min(1.0, alpha_hat / SMALL_ALPHA_HAT))


def small_alpha_schedule(alpha_hat, element_dim):
    """Factors (rho0, rho_max, rho_doubling) of the Dirichlet and vector-field penalty schedule: on
    triangles (``element_dim`` 2) (1 - t / 2, 1, 1 + t) with t = 1 - min(1, alpha_hat /
    ``SMALL_ALPHA_HAT``), so that towards alpha 0 the penalty starts at half the default and doubles
    half as fast (0.25 L doubling every 20 iterations at alpha_hat 0): there a lower early penalty took
    a median 12% fewer iterations on public meshes as published, 4% on their decimations to 1,000
    vertices; (1, 1, 1) on tetrahedra, where it took no fewer (docs/design/single-source.md)."""
    if element_dim != 2:
        return (1.0, 1.0, 1.0)
    t = 1.0 - min(1.0, alpha_hat / SMALL_ALPHA_HAT)
    return (1.0 - 0.5 * t, 1.0, 1.0 + t)


def _on_pattern(matrix, pattern):
    """The values of ``matrix`` at the stored entries of the csr ``pattern`` (a superset of its entries)."""
    rows = np.repeat(np.arange(pattern.shape[0]), np.diff(pattern.indptr))
    values = np.asarray(matrix.tocsr()[rows, pattern.indices]).ravel()
    return sp.csr_matrix((values, pattern.indices, pattern.indptr), shape=pattern.shape)


def _vector_field_matrix(operators, field, beta):
    """W_V = G^T M_F (I + beta Vhat) G with Vhat_f = V_f V_f^T (field (m, 3))."""
    m = field.shape[0]
    blocks = np.eye(3)[None] + beta * field[:, :, None] * field[:, None, :]     # (m, 3, 3)
    blocks *= operators.element_volumes[:, None, None]
    rows = np.repeat(np.arange(3 * m).reshape(m, 3), 3, axis=1)
    cols = np.tile(np.arange(3 * m).reshape(m, 3), (1, 3))
    B = sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * m, 3 * m))
    W = (operators.grad.T @ B @ operators.grad).tocsr()
    return (W + W.T) * 0.5


def _check_field(field, m):
    if np.iscomplexobj(field):
        raise ValueError(f"expected vector_field as a real ({m}, 3) array, got complex values")
    try:
        field = np.asarray(field, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"expected vector_field as a real ({m}, 3) array, got {type(field).__name__}") from None
    if field.shape != (m, 3):
        raise ValueError(f"expected vector_field of shape ({m}, 3) (one vector per element), got {field.shape}")
    if not np.all(np.isfinite(field)):
        bad = np.flatnonzero(~np.all(np.isfinite(field), axis=1))[0]
        raise ValueError(f"expected a finite vector_field, got {field[bad].tolist()} on element {bad}")
    longest = float(np.abs(field).max(initial=0.0))
    if longest > 1e6:  # beta |V|^2 weighs the alignment: beyond this it swamps the Dirichlet term
        raise ValueError(f"expected vector_field components <= 1e6 (lengths scale beta_hat), got {longest:.3g}")
    return field


def build_regularizer(mesh, operators, name="dirichlet", alpha_hat=0.05, beta_hat=None, vector_field=None):
    """Validate the regularizer settings and assemble W (see the module docstring).

    Parameters
    ----------
    mesh : Mesh
    operators : Operators
        ``build_operators(mesh)``.
    name : {"dirichlet", "vector_field", "hessian"}
    alpha_hat : float
        Scale-invariant weight >= 0 (validated by the caller).
    beta_hat : float or None
        Alignment weight >= 0 of "vector_field" (default 10); must be None otherwise.
    vector_field : (m, 3) array_like or None
        Per-element field V of "vector_field" (required there, refused otherwise). On
        triangles only its component tangent to each face matters; its length scales the alignment
        (unit: full weight beta, 0: none), e.g. :func:`warp_regdist.line_field` output.

    Returns
    -------
    Regularizer
    """
    if name not in REGULARIZERS:
        raise ValueError(f"expected regularizer among {list(REGULARIZERS)}, got {name!r}")
    if name != "dirichlet" and mesh.element_weights is not None:
        raise ValueError(f"expected regularizer 'dirichlet' for a PointCloud (its local triangles overlap: no "
                         f"face-wise field or curved Hessian), got {name!r}")
    if name != "vector_field" and (beta_hat is not None or vector_field is not None):
        given = "beta_hat" if beta_hat is not None else "vector_field"
        raise ValueError(f"expected {given} only with regularizer 'vector_field', got it with {name!r}")
    L = operators.length_scale
    if name == "dirichlet":
        return Regularizer(name, alpha_hat * L, None, None, small_alpha_factor(alpha_hat),
                           small_alpha_schedule(alpha_hat, mesh.element_dim))
    if name == "vector_field":
        if vector_field is None:
            raise ValueError("expected a vector_field (m, 3) for regularizer 'vector_field', got None")
        field = _check_field(vector_field, mesh.n_elements)
        beta = check_weight(10.0 if beta_hat is None else beta_hat, "beta_hat")
        W = _vector_field_matrix(operators, field, beta)
        alpha, factor = alpha_hat * L, small_alpha_factor(alpha_hat)
        schedule = small_alpha_schedule(alpha_hat, mesh.element_dim)
    else:
        if mesh.elements.shape[1] != 3:
            raise ValueError(f"expected a triangle mesh for regularizer 'hessian', got a tetrahedral mesh "
                             f"({mesh.n_elements} tetrahedra)")
        import igl

        W = igl.curved_hessian_energy(np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                                      np.ascontiguousarray(mesh.elements, dtype=np.int64))
        W = sp.csr_matrix(W)
        if W.shape[0] < mesh.n_vertices:  # libigl sizes it by the largest referenced vertex
            W = sp.block_diag([W, sp.csr_matrix((mesh.n_vertices - W.shape[0],) * 2)], format="csr")
        W = (W + W.T) * 0.5
        alpha, factor, schedule = alpha_hat * operators.total_volume ** 1.5, HESSIAN_TOLERANCE_FACTOR, HESSIAN_SCHEDULE
    WD = operators.stiffness
    pattern = (abs(W) + abs(WD) + sp.identity(WD.shape[0], format="csr")).tocsr()
    pattern.sort_indices()
    return Regularizer(name, alpha, _on_pattern(W, pattern), _on_pattern(WD, pattern), factor, schedule)
