"""Intrinsic Delaunay operators (geometry/intrinsic.py): one flip exactly, the triangulation against
libigl's independent implementation, its derivative against finite differences, the solves against the
conic solver on libigl's triangulation, and what they change where the mesh has obtuse triangles."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import meshes
import reference_solver as rs
import warp_regdist as wrd
from conftest import TIGHT
from warp_regdist.geometry.intrinsic import intrinsic_delaunay, length_gradient
from warp_regdist.geometry.operators import build_operators, largest_angles

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def cat80():
    """cat_rr decimated to 80 vertices: 17 triangles above 120 degrees (up to 171), 42 edges to flip."""
    d = np.load(DATA / "stopping_cat80.npz")
    return wrd.Mesh(d["vertices"], d["faces"].astype(np.int64))


def test_one_flip_gives_the_other_diagonal_exactly():
    # two flat triangles on the edge (0, 1) whose opposite angles sum to more than pi
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, -0.2, 0.0]])
    F = np.array([[0, 1, 2], [1, 0, 3]])
    T = intrinsic_delaunay(V, F)
    assert T.flip_count == 1
    assert T.faces.tolist() == [[0, 3, 2], [1, 2, 3]]
    side = np.hypot(1.0, 0.2)
    np.testing.assert_allclose(T.lengths, [[side, 0.4, side], [side, 0.4, side]], rtol=1e-15, atol=1e-15)


def test_triangulation_is_libigls_on_a_decimated_mesh(cat80):
    import igl

    mine = intrinsic_delaunay(cat80.vertices, cat80.elements)
    lengths = igl.edge_lengths(cat80.vertices, cat80.elements)
    l, F = igl.intrinsic_delaunay_triangulation(lengths, cat80.elements)[:2]
    assert mine.flip_count == 42
    # each face as (its corners, its lengths), sorted: two faces may have the same corners (they do here)
    theirs = sorted((tuple(sorted(f)), tuple(sorted(x))) for f, x in zip(F.tolist(), l.tolist()))
    ours = sorted((tuple(sorted(f)), tuple(sorted(x))) for f, x in zip(mine.faces.tolist(), mine.lengths.tolist()))
    assert [f for f, _ in ours] == [f for f, _ in theirs]
    np.testing.assert_allclose([x for _, x in ours], [x for _, x in theirs], rtol=1e-12)
    ops = build_operators(cat80, "intrinsic")
    assert ops.total_volume == pytest.approx(cat80.element_volumes.sum(), rel=1e-12)   # the same surface
    def off_diagonal(W):
        W = W.toarray()
        return W - np.diag(np.diag(W))

    assert off_diagonal(ops.stiffness).max() <= 1e-12      # Delaunay: every cotangent weight >= 0
    assert off_diagonal(build_operators(cat80).stiffness).max() > 0.1   # the mesh's own: negative ones


def test_the_derivative_of_the_flipped_lengths_is_the_finite_difference(cat80):
    rng = np.random.default_rng(3)
    T = intrinsic_delaunay(cat80.vertices, cat80.elements)
    weights = rng.standard_normal(T.lengths.shape)
    D = rng.standard_normal(cat80.vertices.shape)
    grad = length_gradient(T, cat80.vertices, weights)

    def value(h):
        moved = intrinsic_delaunay(cat80.vertices + h * D, cat80.elements)
        assert np.array_equal(moved.faces, T.faces)            # the same flips near the mesh
        return (weights * moved.lengths).sum()

    fd = (value(1e-7) - value(-1e-7)) / 2e-7
    assert (grad * D).sum() == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("alpha_hat", [0.0, 0.05])
def test_single_source_matches_the_conic_solve_on_libigls_triangulation(cat80, alpha_hat):
    V, F = cat80.vertices, cat80.elements
    alpha = alpha_hat * np.sqrt(rs.face_geometry(V, F)[0].sum())
    res = wrd.DistanceSolver(cat80, alpha_hat, options=TIGHT).solve([3])
    expected = rs.solve_reference(V, F, [3], alpha)
    assert res.converged and np.abs(res.distance - expected).max() <= 1e-3 * expected.max()
    on_the_mesh = rs.solve_reference(V, F, [3], alpha, triangulation="mesh")
    assert np.abs(on_the_mesh - expected).max() > 1e-2 * expected.max()       # a different discrete problem


def test_all_pairs_matches_the_conic_solve_on_libigls_triangulation():
    import all_pairs_reference as apr

    V, F = meshes.icosphere(1, 1.0)
    V = V + 0.35 * np.random.default_rng(5).standard_normal(V.shape)   # 42 vertices jittered on the sphere
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    mesh = wrd.Mesh(V, F)
    assert build_operators(mesh, "intrinsic").intrinsic.flip_count == 27
    alpha = 0.1 * np.sqrt(rs.face_geometry(V, F)[0].sum())
    expected = apr.solve_all_pairs_reference(V, F, alpha, symmetric=True)
    res = wrd.all_pairs(mesh, 0.1, eps_rel=2e-6, eps_rel_consensus=2e-7, eps_rel_dual=2e-4, cg_fraction=1e-8,
                        max_iterations=10_000)
    assert res.converged and np.abs(res.distance - expected).max() <= 1e-3 * expected.max()


def test_gradients_go_through_the_flips(cat80):
    solver = wrd.DistanceSolver(cat80, 0.1, workers=1)
    assert solver.operators.intrinsic.flip_count == 42
    rng = np.random.default_rng(1)
    b = rng.random(cat80.n_vertices)
    g = solver.solve([0]).vjp(b)
    D = rng.standard_normal(cat80.vertices.shape)

    def value(h):
        moved = wrd.DistanceSolver(wrd.Mesh(cat80.vertices + h * D, cat80.elements), 0.1, workers=1)
        return b @ moved.solve([0]).polish().distance

    fd = (value(1e-7) - value(-1e-7)) / 2e-7
    assert (g.vertices * D).sum() == pytest.approx(fd, rel=1e-5)


def test_obtuse_triangles_no_longer_push_distances_below_zero(cat80):
    assert (largest_angles(cat80.vertices, cat80.elements) > 150).sum() == 4
    sets = [[j] for j in range(cat80.n_vertices)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh_u = wrd.DistanceSolver(cat80, 0.0, triangulation="mesh").solve_many(sets).distance
    assert (mesh_u.min(axis=0) < -1e-6 * mesh_u.max(axis=0)).sum() == 8   # down to -4.5% of the max
    message = [str(w.message) for w in caught if issubclass(w.category, wrd.MeshWarning)]
    assert len(message) == 1 and message[0].startswith("8 of 80 source sets have distances below 0, down to -4.46% "
                                                       "of the max distance at vertex 55 (source set 34: [34]; the "
                                                       "triangle at that vertex and source 34 has a 133-degree angle "
                                                       "at the source)")
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        u = wrd.DistanceSolver(cat80, 0.0).solve_many(sets).distance
    assert (u.min(axis=0) >= -1e-6 * u.max(axis=0)).all()


def test_the_triangulation_argument(cat80):
    V, F = meshes.icosphere(2, 1.0)
    regular = wrd.Mesh(V, F)                                  # already intrinsically Delaunay: its own operators
    a = wrd.DistanceSolver(regular, 0.05, triangulation="mesh").solve([0])
    b = wrd.DistanceSolver(regular, 0.05).solve([0])
    assert np.array_equal(a.distance, b.distance) and a.iterations == b.iterations
    assert wrd.DistanceSolver(cat80, 0.05).triangulation == "intrinsic"
    field = np.tile([1.0, 0.0, 0.0], (cat80.n_elements, 1))
    assert wrd.DistanceSolver(cat80, 0.05, regularizer="vector_field", vector_field=field).triangulation == "mesh"
    with pytest.raises(ValueError, match="expected triangulation 'mesh' for the vector-field regularizer"):
        wrd.DistanceSolver(cat80, 0.05, regularizer="vector_field", vector_field=field, triangulation="intrinsic")
    cube = wrd.Mesh(*meshes.cube_tets(3))
    with pytest.raises(ValueError, match="expected triangulation 'mesh' for a tetrahedral mesh, got 'intrinsic'"):
        wrd.DistanceSolver(cube, 0.05, triangulation="intrinsic")
    with pytest.raises(ValueError, match="expected triangulation 'intrinsic', 'mesh' or None, got 'delaunay'"):
        wrd.DistanceSolver(cat80, 0.05, triangulation="delaunay")
