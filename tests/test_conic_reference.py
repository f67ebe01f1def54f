"""The solver against an independent interior-point solution of the same discrete problem,
and the finite-element operators against exact values.

The reference (tests/reference_solver.py) assembles G, a_f and A_V itself and solves
docs/method.md section 2 with cvxpy + Clarabel to a duality gap of 1e-9. At tight ADMM tolerances
the two must agree to 1e-3 of the maximal distance. Why a wrong implementation fails:
doubling alpha (or the vertex areas, or using A instead of sqrt(A)) moves these
minimizers by 5.7% and 6.7% of the maximum (the reference with 2 alpha; alpha = 0 moves
them by 4.8% and 4.7%), 50x the tolerance; a wrong gradient scale changes the Lipschitz
bound and every distance.
"""

import numpy as np
import pytest

import meshes
import reference_solver as rs
from same_run import on_cuda
import warp_regdist as wrd
from conftest import TIGHT
from warp_regdist.geometry.operators import build_operators


def _bumpy_sphere():
    V, F = meshes.icosphere(3, 1.0)  # 642 vertices
    return meshes.perturbed(V, F, 0.02, seed=1), F


def _bumpy_sheet():
    V, F = meshes.square_grid(18, 2.0)  # 324 vertices, open (with boundary)
    V[:, 2] = 0.25 * np.sin(2.0 * V[:, 0]) * np.cos(3.0 * V[:, 1])
    return V, F


def _check_against_reference(V, F, sources, alpha_hat, device):
    areas, _ = rs.face_geometry(V, F)
    alpha = alpha_hat * np.sqrt(areas.sum())
    expected = rs.solve_reference(V, F, sources, alpha)
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=alpha_hat, device=device, options=TIGHT)
    res = solver.solve(sources)
    assert res.converged
    err = np.abs(res.distance - expected).max() / expected.max()
    assert err <= 1e-3, err


def test_single_source_matches_conic_solver(device):
    V, F = _bumpy_sphere()
    _check_against_reference(V, F, [100], 0.05, device)


def test_several_sources_matches_conic_solver(device):
    V, F = _bumpy_sheet()
    _check_against_reference(V, F, [0, 17, 170, 310], 0.05, device)


@pytest.mark.parametrize("alpha_hat", [0.3, 2.0])
def test_no_active_gradient_constraint_converges_at_defaults(device, alpha_hat):
    # boundary sources on a coarse square: |G u| < 1 on every face, so the multiplier y is 0
    # and a dual test relative to |D y| alone never held (10,000 iterations, no convergence)
    V, F = meshes.square_grid(12)
    mesh = wrd.Mesh(V, F)
    sources = wrd.boundary_vertices(mesh)
    res = wrd.DistanceSolver(mesh, alpha_hat=alpha_hat, device=device).solve(sources)
    assert res.converged and res.iterations < 100, res.iterations
    areas, _ = rs.face_geometry(V, F)
    # a grid of right triangles: every quad is cocircular, so the mesh is its own intrinsic Delaunay triangulation
    expected = rs.solve_reference(V, F, sources, alpha_hat * np.sqrt(areas.sum()), triangulation="mesh")
    assert np.abs(res.distance - expected).max() / expected.max() <= 1e-3


def test_alpha_one_converges_at_defaults(device):
    # the warm-started u-step met its fixed CG tolerance without moving, and r stalled at
    # 1.4x its tolerance for 10,000 iterations (cured by the option cg_primal_fraction)
    # (on the grid's own triangles: its Delaunay triangulation is not unique, libigl's and the package's flips differ)
    V, F = meshes.square_grid(12)
    res = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=1.0, device=device, triangulation="mesh").solve([0])
    assert res.converged and res.iterations < 200, res.iterations
    areas, _ = rs.face_geometry(V, F)
    expected = rs.solve_reference(V, F, [0], np.sqrt(areas.sum()), triangulation="mesh")
    assert np.abs(res.distance - expected).max() / expected.max() <= 2e-4


def test_blown_up_iterate_is_not_reported_as_converged(device):
    # one needle triangle (height 1e-7): on the CPU the iteration blows up to ~1e154 while its
    # relative stopping test holds, and the |grad u| <= 1 check must catch it; on CUDA, whose
    # rounding differs, the iteration stays bounded and reaches the iteration cap instead
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1e-7, 0.0]])
    solver = wrd.DistanceSolver(wrd.Mesh(V, [[0, 1, 2]]), device=device)
    message = r"did not converge in 10000 iterations" if on_cuda(device) else "steeper than their constraint allows"
    with pytest.warns(wrd.ConvergenceWarning, match=message):
        res = solver.solve([0])
    assert not res.converged


# ---------------------------------------------------------------- operators


def test_gradient_of_linear_function_is_its_tangential_gradient():
    V, F = _bumpy_sphere()
    ops = build_operators(wrd.Mesh(V, F))
    c = np.array([0.7, -0.2, 1.3])
    g = (ops.grad @ (V @ c)).reshape(-1, 3)
    _, N = rs.face_geometry(V, F)
    assert np.abs(g - (c - (N @ c)[:, None] * N)).max() < 1e-12


def test_operators_match_independent_assembly():
    V, F = _bumpy_sheet()
    ops = build_operators(wrd.Mesh(V, F))
    areas, _ = rs.face_geometry(V, F)
    G = np.stack([Gc.toarray() for Gc in rs.gradient_matrices(V, F)], axis=1)  # (m, 3, n)
    assert ops.grad.shape == (3 * len(F), len(V))
    assert np.allclose(ops.grad.toarray(), G.reshape(3 * len(F), len(V)), rtol=0, atol=1e-12)
    assert np.allclose(ops.element_volumes, areas, rtol=1e-13, atol=0)
    assert np.allclose(ops.vertex_volumes, rs.vertex_areas(V, F), rtol=1e-13, atol=0)
    W = G.reshape(3 * len(F), len(V))
    W = W.T @ (np.repeat(areas, 3)[:, None] * W)
    assert np.allclose(ops.stiffness.toarray(), W, rtol=0, atol=1e-12)


def test_stiffness_annihilates_constants_and_is_psd():
    V, F = _bumpy_sphere()
    ops = build_operators(wrd.Mesh(V, F))
    W = ops.stiffness
    assert np.abs(W @ np.ones(len(V))).max() < 1e-12 * np.abs(W).max()
    assert abs(W - W.T).max() < 1e-14 * np.abs(W).max()
    x = np.random.default_rng(0).standard_normal(len(V))
    assert x @ (W @ x) > 0


def test_vertex_areas_sum_to_total_area():
    for V, F in (_bumpy_sphere(), _bumpy_sheet(), meshes.disk(1.0, 4)):
        ops = build_operators(wrd.Mesh(V, F))
        areas, _ = rs.face_geometry(V, F)
        assert ops.total_volume == pytest.approx(areas.sum(), rel=1e-13)
        assert ops.vertex_volumes.sum() == pytest.approx(ops.total_volume, rel=1e-13)
        assert ops.element_volumes.sum() == pytest.approx(ops.total_volume, rel=1e-13)


def test_single_triangle_exact():
    # right triangle with legs 2 (along x) and 1 (along y), tilted out of the plane by a
    # rotation about x: area 1, hats 1 - x/2 - y, x/2, y in the triangle's own frame
    c, s = np.cos(0.4), np.sin(0.4)
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) @ R.T + [1.0, 2.0, 3.0]
    F = np.array([[0, 1, 2]])
    ops = build_operators(wrd.Mesh(V, F))
    assert ops.element_volumes == pytest.approx([1.0], rel=1e-14)
    assert ops.total_volume == pytest.approx(1.0, rel=1e-14)
    assert ops.vertex_volumes == pytest.approx([1 / 3] * 3, rel=1e-14)
    hats = np.array([[-0.5, -1.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, 0.0]]) @ R.T  # (3 hats, 3)
    assert np.allclose(ops.grad.toarray(), hats.T, rtol=0, atol=1e-14)
    # cotangent weights: W_ij = -cot(angle opposite ij) / 2; angles 90 deg at vertex 0,
    # atan(1/2) at vertex 1 (cot 2) and atan(2) at vertex 2 (cot 1/2)
    W = np.array([[1.25, -0.25, -1.0], [-0.25, 0.25, 0.0], [-1.0, 0.0, 1.0]])
    assert np.allclose(ops.stiffness.toarray(), W, rtol=0, atol=1e-14)
