"""Independent reference for the all-pairs problem on M x M (docs/method.md section 5, Algorithm 2's problem).

Uses the numpy assembly of ``reference_solver`` (not ``warp_regdist``) and solves

    minimize_U   -A_V^T U A_V + (alpha / 2) (sum_j A_V[j] E(U[:, j]) + sum_i A_V[i] E(U[i, :]))
    subject to   |(G U[:, j])_f| <= 1,  |(G U[i, :])_f| <= 1  for every face f, row i, column j,
                 U >= 0,  U_ii <= 0,

with E(u) = sum_f a_f |(G u)_f|^2 = u^T W_D u (so the energy term is
(alpha / 2) Tr(M_V U^T W_D U + U W_D U^T M_V)), by cvxpy + Clarabel (interior point).

``symmetric=True`` solves the same problem over symmetric U only, with the column
constraints alone: the problem is invariant under U -> U^T and its minimizer is unique
(Theorem 6.1 of the paper), so the minimizer is symmetric and both versions agree. It has
half the cones. Clarabel factors its KKT systems with faer's supernodal LDL^T (on all cores),
5.6 times faster than its default QDLDL at 136 vertices, which puts 300 vertices within
a quarter of an hour.
"""

import numpy as np

import reference_solver as rs


def solve_all_pairs_reference(V, F, alpha, symmetric=False, gap_tol=1e-9, feas_tol=1e-8, triangulation="intrinsic",
                              source_triangles="edges"):
    """Exact minimizer U (n, n) of the all-pairs problem with raw weight ``alpha``.

    Parameters
    ----------
    V : (n, 3) float64
        Connected mesh, every vertex in a face.
    F : (m, 3) int64
    alpha : float
        Raw regularization weight (alpha_hat * sqrt(total area)).
    symmetric : bool
        Optimize over symmetric U with the column constraints only (see the module docstring).
    gap_tol, feas_tol : float
        Clarabel's duality-gap (absolute and relative) and feasibility tolerances.
    triangulation : {"intrinsic", "mesh"}
        As in ``reference_solver.discrete_operators``.
    source_triangles : {"edges", "gradient"}
        "edges": on each triangle f at vertex j, column j's (and row j's) cone is replaced by
        U[a, j] <= l_ja at the other two corners a (``reference_solver.solve_reference``); "gradient": the
        cone everywhere.

    Returns
    -------
    (n, n) float64
    """
    import cvxpy as cp  # only the conic solves need it: the helpers run without cvxpy
    n = len(V)
    areas, grads, A_V = rs.discrete_operators(V, F, triangulation)
    U = cp.Variable((n, n), symmetric=symmetric)
    sides = [U] if symmetric else [U, U.T]
    constraints = [U >= 0, cp.diag(U) == 0]
    m = len(areas)
    cone = np.ones((m, n), dtype=bool)       # (face, column) pairs with the cone
    bounds = []                              # (row, column, length): U[row, column] <= length
    if source_triangles == "edges":
        Fi, l = rs.triangulation_lengths(V, F, triangulation)
        for f in range(m):
            for c in range(3):
                j = Fi[f, c]
                cone[f, j] = False
                for a, opposite in (((c + 1) % 3, (c + 2) % 3), ((c + 2) % 3, (c + 1) % 3)):
                    bounds.append((Fi[f, a], j, l[f, opposite]))
    elif source_triangles != "gradient":
        raise ValueError(f"expected source_triangles 'edges' or 'gradient', got {source_triangles!r}")
    keep = np.flatnonzero(cone.ravel(order="F"))
    energy = 0
    weight = np.sqrt(areas)[:, None] * np.sqrt(A_V)[None, :]  # (m, n): sqrt(a_f A_V[j])
    for side in sides:
        comps = [Gc @ side for Gc in grads]  # 3 x (m, n): gradient of every column
        constraints.append(cp.SOC(np.ones(keep.size), cp.vstack([cp.vec(c, order="F")[keep] for c in comps]), axis=0))
        if bounds:
            rows, cols, lengths = (np.array(x) for x in zip(*bounds))
            constraints.append(side[rows, cols] <= lengths)
        energy = energy + sum(cp.sum_squares(cp.multiply(weight, c)) for c in comps)
    if symmetric:
        energy = 2 * energy  # the row term equals the column term for symmetric U
    objective = -A_V @ U @ A_V + 0.5 * alpha * energy
    problem = cp.Problem(cp.Minimize(objective), constraints)
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=gap_tol, tol_gap_rel=gap_tol, tol_feas=feas_tol, max_iter=500,
                  direct_solve_method="faer")
    if problem.status != cp.OPTIMAL:
        raise RuntimeError(f"expected status optimal, got {problem.status}")
    return np.asarray(U.value)
