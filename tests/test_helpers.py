"""The test helpers on their own: mesh generators, closed forms, the cvxpy reference.

None of these tests imports warp_regdist: they check the yardsticks the other tests use.
"""

import numpy as np
import pytest

import closed_forms
import meshes
import reference_solver as rs


def _edge_counts(F):
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def _directed_edges_unique(F):
    """Consistent orientation: every directed edge occurs at most once."""
    d = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return len(np.unique(d, axis=0)) == len(d)


@pytest.mark.parametrize(
    "name, V_F",
    [
        ("cylinder", meshes.cylinder(16, 4, 2.0)),
        ("disk", meshes.disk(1.5, 5)),
        ("icosphere", meshes.icosphere(2, 1.0)),
        ("grid", meshes.square_grid(5, 2.0)),
    ],
)
def test_generators_are_oriented_manifolds(name, V_F):
    V, F = V_F
    assert V.dtype == np.float64 and F.dtype == np.int64
    assert V.shape[1] == 3 and F.shape[1] == 3
    assert np.array_equal(np.unique(F), np.arange(len(V)))  # no unreferenced vertex
    assert _edge_counts(F).max() <= 2
    assert _directed_edges_unique(F)
    areas, _ = rs.face_geometry(V, F)
    assert areas.min() > 1e-3 * areas.max()


def test_cylinder_geometry():
    V, F = meshes.cylinder(12, 4, 3.0)
    assert np.allclose(np.hypot(V[:, 0], V[:, 1]), 1.0)  # circumference 2 pi
    assert np.allclose(V[:, 2].min(), 0.0) and np.allclose(V[:, 2].max(), 3.0)
    line = meshes.cylinder_generator_line(12, 4)
    assert np.allclose(V[line, :2], [1.0, 0.0], atol=0.0)  # exactly at angle 0
    areas, N = rs.face_geometry(V, F)
    centroids = V[F].mean(axis=1)
    assert np.all(np.sum(N[:, :2] * centroids[:, :2], axis=1) > 0)  # outward
    assert np.isclose(areas.sum(), 12 * 2 * np.sin(np.pi / 12) * 3.0)


def test_disk_geometry():
    V, F = meshes.disk(2.0, 6)
    counts = _edge_counts(F)
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq = np.unique(e, axis=0)
    boundary = np.unique(uniq[counts == 1])
    r = np.linalg.norm(V, axis=1)
    assert np.all(np.abs(r[boundary] - 2.0) < 1e-14)
    assert len(boundary) == 36 and np.sum(np.abs(r - 2.0) < 1e-12) == 36
    _, N = rs.face_geometry(V, F)
    assert np.allclose(N, [0.0, 0.0, 1.0])
    ab, bc = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 1]]
    ca = V[F[:, 0]] - V[F[:, 2]]
    for p, q in [(ab, -ca), (bc, -ab), (ca, -bc)]:
        cos = np.sum(p * q, axis=1) / np.linalg.norm(p, axis=1) / np.linalg.norm(q, axis=1)
        assert np.degrees(np.arccos(cos)).min() > 40.0  # good-quality triangles


def test_icosphere_geometry():
    V, F = meshes.icosphere(2, 2.0)
    assert len(V) == 162 and len(F) == 320
    assert np.allclose(np.linalg.norm(V, axis=1), 2.0)
    _, N = rs.face_geometry(V, F)
    assert np.all(np.sum(N * V[F].mean(axis=1), axis=1) > 0)  # outward


def test_circle_closed_form_is_c1_and_solves_poisson():
    alpha = 0.8
    L = np.pi - alpha
    h = 1e-6
    for x in (L, 2 * np.pi - L):  # value and slope continuous at the junctions
        left, right = closed_forms.circle_distance(np.array([x - h, x + h]), alpha)
        assert abs(right - left) < 3e-6
    around_L = np.array([L - 2 * h, L - h, L + h, L + 2 * h])
    slopes = np.diff(closed_forms.circle_distance(around_L, alpha)) / h
    assert np.allclose(slopes[[0, 2]], [1.0, 1.0], atol=1e-4)  # slope 1 on both sides
    x = np.linspace(L + 0.1, 2 * np.pi - L - 0.1, 7)
    h = 1e-3
    second = (
        closed_forms.circle_distance(x + h, alpha)
        - 2 * closed_forms.circle_distance(x, alpha)
        + closed_forms.circle_distance(x - h, alpha)
    ) / h**2
    assert np.allclose(second, -1.0 / alpha, rtol=1e-5)
    assert np.isclose(closed_forms.circle_distance(np.array([np.pi]), alpha)[0], np.pi - alpha / 2)


def test_disk_closed_form_is_c1_and_solves_poisson():
    R, alpha = 1.0, 0.3
    r0, h = 2 * alpha, 1e-6
    u = closed_forms.disk_distance(np.array([r0 - h, r0, r0 + h]), R, alpha)
    assert abs(u[2] - u[0]) / (2 * h) == pytest.approx(1.0, abs=1e-4)
    # radial Laplacian u'' + u' / r = -1 / alpha inside r < 2 alpha
    r = np.linspace(0.1, 0.5, 5)
    h = 1e-3
    f = lambda s: closed_forms.disk_distance(s, R, alpha)  # noqa: E731
    lap = (f(r + h) - 2 * f(r) + f(r - h)) / h**2 + (f(r + h) - f(r - h)) / (2 * h) / r
    assert np.allclose(lap, -1.0 / alpha, rtol=1e-5)


def test_reference_gradient_of_linear_function_is_tangential_part():
    V, F = meshes.icosphere(2)
    V = meshes.perturbed(V, F, 0.05)
    c = np.array([0.3, -1.2, 0.7])
    G = rs.gradient_matrices(V, F)
    g = np.stack([Gc @ (V @ c) for Gc in G], axis=1)
    _, N = rs.face_geometry(V, F)
    assert np.allclose(g, c - (N @ c)[:, None] * N, atol=1e-12)
    areas, _ = rs.face_geometry(V, F)
    assert np.isclose(rs.vertex_areas(V, F).sum(), areas.sum())


def test_reference_single_triangle():
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2]])
    areas, N = rs.face_geometry(V, F)
    assert np.allclose(areas, [1.0]) and np.allclose(N, [[0, 0, 1]])
    G = np.stack([Gc.toarray()[0] for Gc in rs.gradient_matrices(V, F)], axis=1)  # (3 hats, 3)
    assert np.allclose(G, [[-0.5, -1.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert np.allclose(rs.vertex_areas(V, F), [1 / 3, 1 / 3, 1 / 3])


def test_reference_solver_matches_circle_closed_form():
    # the cylinder problem separates: the discrete minimizer depends on the angle only
    n_theta, n_h, alpha = 48, 3, 0.75
    V, F = meshes.cylinder(n_theta, n_h, 1.0)
    u = rs.solve_reference(V, F, meshes.cylinder_generator_line(n_theta, n_h), alpha, triangulation="mesh")
    assert np.ptp(u.reshape(n_h, n_theta), axis=0).max() < 1e-7
    exact = closed_forms.circle_distance(np.arctan2(V[:, 1], V[:, 0]), alpha)
    assert np.abs(u - exact).max() < 1e-3 * exact.max()
    wrong = closed_forms.circle_distance(np.arctan2(V[:, 1], V[:, 0]), 2 * alpha)
    assert np.abs(u - wrong).max() > 0.1 * exact.max()


def test_reference_solver_unregularized_is_below_great_circle_distance():
    V, F = meshes.icosphere(2)
    u = rs.solve_reference(V, F, [0], 0.0, source_triangles="gradient")   # the paper's problem
    exact = np.arccos(np.clip(V @ V[0], -1.0, 1.0))
    # the inscribed polyhedron is shorter than the sphere; PL functions are Lipschitz-1
    assert np.all(u <= exact + 1e-6)
    assert np.abs(u - exact).max() < 0.08 * np.pi
