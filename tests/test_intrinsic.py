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
    res = wrd.DistanceSolver(cat80, alpha_hat, options=TIGHT, refine_obtuse=False).solve([3])
    expected = rs.solve_reference(V, F, [3], alpha)
    assert res.converged and np.abs(res.distance - expected).max() <= 1e-3 * expected.max()
    on_the_mesh = rs.solve_reference(V, F, [3], alpha, triangulation="mesh")
    assert np.abs(on_the_mesh - expected).max() > 1e-2 * expected.max()       # a different discrete problem
    # the default refines the obtuse angles away: libigl's triangulation of the refined mesh, read on the input's
    solver = wrd.DistanceSolver(cat80, alpha_hat, options=TIGHT)
    refined = solver.solve_mesh
    assert refined.n_vertices > cat80.n_vertices
    expected = rs.solve_reference(refined.vertices, refined.elements, [3], alpha)[:cat80.n_vertices]
    res = solver.solve([3])
    assert res.converged and np.abs(res.distance - expected).max() <= 1e-3 * expected.max()


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
    # the flips alone (through the obtuse refinement too: test_obtuse_refinement.py, test_gradients.py)
    solver = wrd.DistanceSolver(cat80, 0.1, workers=1, refine_obtuse=False)
    assert solver.operators.intrinsic.flip_count == 42
    rng = np.random.default_rng(1)
    b = rng.random(cat80.n_vertices)
    g = solver.solve([0]).vjp(b)
    D = rng.standard_normal(cat80.vertices.shape)

    def value(h):
        moved = wrd.DistanceSolver(wrd.Mesh(cat80.vertices + h * D, cat80.elements), 0.1, workers=1, refine_obtuse=False)
        return b @ moved.solve([0]).polish().distance

    fd = (value(1e-7) - value(-1e-7)) / 2e-7
    assert (g.vertices * D).sum() == pytest.approx(fd, rel=1e-5)


def test_obtuse_triangles_no_longer_push_distances_below_zero(cat80):
    assert (largest_angles(cat80.vertices, cat80.elements) > 150).sum() == 4
    sets = [[j] for j in range(cat80.n_vertices)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh_u = wrd.DistanceSolver(cat80, 0.0, triangulation="mesh", source_triangles="gradient").solve_many(sets).distance
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


SCANS = np.load(DATA / "scan_decimations.npz")
"""65 decimations (95-2,001 vertices) of 16 public scanned and CAD meshes (tools/make_scan_decimations.py):
closed and with boundary, 17 with non-manifold edges."""


def _scan(k):
    V, F = SCANS[f"vertices_{k}"].astype(np.float64), SCANS[f"faces_{k}"].astype(np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.MeshWarning)       # a few have vertices at one position
        return wrd.Mesh(V, F)


def _interior_weights(W, F, n):
    """The off-diagonal stiffness entries of the pairs that are not boundary edges of the input F."""
    W = W.tocoo()
    a, b = F.ravel(), np.roll(F, -1, axis=1).ravel()
    keys, counts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    pair = np.minimum(W.row, W.col) * n + np.maximum(W.row, W.col)
    return W.data[(W.row != W.col) & ~np.isin(pair, keys[counts == 1])]


@pytest.mark.parametrize("k", range(len(SCANS.files) // 3))
def test_flips_reach_the_delaunay_triangulation_of_every_decimated_scan(k):
    import igl
    import robust_laplacian

    mesh = _scan(k)
    V, F = mesh.vertices, mesh.elements
    ops = build_operators(mesh, "intrinsic")
    W = ops.stiffness
    scale = np.abs(W.data).max()
    assert _interior_weights(W, F, mesh.n_vertices).max() <= 1e-12 * scale       # every cotangent weight >= 0
    if ops.intrinsic is not None and ops.intrinsic.tufted:
        # Sharp and Crane's own implementation of the tufted cover (mollification off): L and its masses
        L, M = robust_laplacian.mesh_laplacian(V, F, mollify_factor=0.0)
        np.testing.assert_allclose(ops.vertex_volumes, M.diagonal(), rtol=1e-12)
    else:
        L = -igl.intrinsic_delaunay_cotmatrix(V, F)[0]
    assert np.abs(W - L).max() <= 1e-10 * scale                                   # measured: 1e-15 to 5e-11
    assert ops.total_volume == pytest.approx(mesh.element_volumes.sum(), rel=1e-12)


def test_the_decimations_cover_the_configurations():
    tufted = [k for k in range(len(SCANS.files) // 3) if build_operators(_scan(k), "intrinsic").intrinsic.tufted]
    assert len(tufted) == 17
    # a closed, oriented, manifold input whose Delaunay triangulation has two faces on the same three vertices
    cheburashka = _scan(20)
    assert str(SCANS["name_20"]) == "cheburashka" and cheburashka.n_vertices == 2001
    T = intrinsic_delaunay(cheburashka.vertices, cheburashka.elements)
    assert T.flip_count == 1480 and not T.tufted
    shared = np.sort(T.faces, axis=1)
    assert len(np.unique(shared, axis=0)) < len(shared)        # two faces on the same three vertices


def test_flips_go_through_faces_that_share_two_edges():
    # a pillow: one obtuse triangle on both sides, glued along all three edges. Each side of the long
    # edge has the 140-degree angle opposite it; its flip makes a loop at vertex 2 (degree 1 vertices 0, 1)
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.36, 0.0]])
    F = np.array([[0, 1, 2], [1, 0, 2]])
    T = intrinsic_delaunay(V, F)
    assert T.flip_count == 1 and not T.tufted
    assert sorted(map(sorted, T.faces.tolist())) == [[0, 2, 2], [1, 2, 2]]
    side = np.hypot(1.0, 0.36)                  # the loop round vertex 2 is twice the triangle's height
    np.testing.assert_allclose(np.sort(T.lengths, axis=1), [[0.72, side, side]] * 2, rtol=1e-14)
    ops = build_operators(wrd.Mesh(V, F), "intrinsic")
    W = ops.stiffness.toarray()
    assert (W - np.diag(np.diag(W))).max() <= 0.0 and np.abs(W.sum(axis=1)).max() < 1e-14
    import igl

    np.testing.assert_allclose(W, -igl.intrinsic_delaunay_cotmatrix(V, F)[0].toarray(), atol=1e-14)


def test_an_inconsistently_oriented_mesh_gets_the_operators_of_the_oriented_one(cat80):
    F = cat80.elements.copy()
    reversed_faces = np.arange(0, len(F), 3)
    F[reversed_faces] = F[reversed_faces][:, [0, 2, 1]]
    flipped = build_operators(wrd.Mesh(cat80.vertices, F), "intrinsic")
    oriented = build_operators(cat80, "intrinsic")
    assert not flipped.intrinsic.tufted and flipped.intrinsic.flip_count == 42
    assert np.abs(flipped.stiffness - oriented.stiffness).max() <= 1e-13 * np.abs(oriented.stiffness).max()
    np.testing.assert_allclose(flipped.vertex_volumes, oriented.vertex_volumes, rtol=1e-13)


def _moebius(k=12):
    """A Moebius strip of 2 k vertices: a manifold that cannot be oriented."""
    t = np.linspace(0.0, 2.0 * np.pi, k, endpoint=False)
    V = np.concatenate([np.stack([(1 + s * np.cos(t / 2)) * np.cos(t), (1 + s * np.cos(t / 2)) * np.sin(t),
                                  s * np.sin(t / 2)], axis=1) for s in (-0.3, 0.3)])
    i = np.arange(k)
    j = (i + 1) % k
    top = np.where(j == 0, 0, j + k)            # past the last rung the strip comes back upside down
    bottom = np.where(j == 0, k, j)
    F = np.concatenate([np.stack([i, bottom, i + k], 1), np.stack([i + k, bottom, top], 1)])
    return V, F


@pytest.mark.parametrize("case", ["book", "moebius"])
def test_non_manifold_and_non_orientable_meshes_use_the_tufted_cover(case):
    import robust_laplacian

    if case == "book":      # five obtuse pages on one spine
        angles = np.radians([0.0, 70.0, 150.0, 200.0, 290.0])
        V = np.concatenate([[[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]],
                            np.stack([0.3 * np.cos(angles), 0.3 * np.sin(angles), 0.1 * np.arange(5) - 0.2], 1)])
        F = np.array([[0, 1, 2 + p] for p in range(5)])
    else:
        V, F = _moebius()
    mesh = wrd.Mesh(V, F)
    ops = build_operators(mesh, "intrinsic")
    assert ops.intrinsic.tufted and ops.intrinsic.faces.shape == (2 * len(F), 3) and ops.intrinsic.flip_count > 0
    L, M = robust_laplacian.mesh_laplacian(V, F, mollify_factor=0.0)
    assert np.abs(ops.stiffness - L).max() <= 1e-12 * np.abs(L).max()
    np.testing.assert_allclose(ops.vertex_volumes, M.diagonal(), rtol=1e-12)
    assert ops.total_volume == pytest.approx(mesh.element_volumes.sum(), rel=1e-14)


def test_a_distance_on_a_non_manifold_scan_is_the_conic_solve_on_its_tufted_cover():
    mesh = next(m for m in map(_scan, range(len(SCANS.files) // 3)) if m.n_vertices < 200 and
                build_operators(m, "intrinsic").intrinsic.tufted)          # beast at 132 vertices
    T = build_operators(mesh, "intrinsic").intrinsic
    alpha = 0.05 * np.sqrt(mesh.element_volumes.sum())
    expected = rs.solve_reference(mesh.vertices, mesh.elements, [0], alpha,
                                  triangulation=(T.faces, T.lengths[:, [1, 2, 0]], T.area_weight))
    res = wrd.DistanceSolver(mesh, 0.05, options=TIGHT).solve([0])
    assert res.converged and np.abs(res.distance - expected).max() <= 1e-3 * expected.max()
    cut = wrd.repair_mesh(mesh.vertices, mesh.elements)[0]
    assert np.abs(wrd.DistanceSolver(cut, 0.05, options=TIGHT).solve([0]).distance[:mesh.n_vertices]
                  - expected).max() > 1e-2 * expected.max()            # cutting solves another problem


@pytest.mark.filterwarnings("ignore:1 of 1 source sets have distances below 0")   # a 100-degree angle at the source
def test_gradients_go_through_the_tufted_cover():
    V, F = _moebius(16)
    mesh = wrd.Mesh(V, F)
    solver = wrd.DistanceSolver(mesh, 0.1, workers=1)
    assert solver.operators.intrinsic.tufted
    rng = np.random.default_rng(2)
    b = rng.random(mesh.n_vertices)
    g = solver.solve([0]).vjp(b)
    D = rng.standard_normal(V.shape)

    def value(h):
        moved = wrd.DistanceSolver(wrd.Mesh(V + h * D, F), 0.1, workers=1)
        return b @ moved.solve([0]).polish().distance

    fd = (value(1e-7) - value(-1e-7)) / 2e-7
    assert (g.vertices * D).sum() == pytest.approx(fd, rel=1e-5)


def test_flips_that_do_not_end_are_one_error_naming_the_place_and_the_option(cat80, monkeypatch):
    import warp_regdist.geometry.intrinsic as intrinsic

    monkeypatch.setattr(intrinsic, "_MAX_ROUNDS", 1)           # cat80 takes more rounds than one
    with pytest.raises(wrd.MeshError, match=r"^expected the intrinsic edge flips to end, got 1 rounds still flipping "
                                            r"\(an edge between vertices \d+ and \d+\); triangulation='mesh' solves on "
                                            r"the mesh's own triangles$"):
        wrd.DistanceSolver(cat80, 0.05)
