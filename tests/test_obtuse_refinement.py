"""Obtuse angles refined away (geometry/obtuse_refinement.py): a boundary foot and an interior
circumcenter exactly, the maximum principle and no angle above 120 degrees on every decimated scan, the
inserted vertices' derivative against central differences, and the solver's default (refine_obtuse): a
distance that no longer dips below 0, per input vertex, with warm starts, polish and gradients."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import meshes
import warp_regdist as wrd
from warp_regdist.geometry.obtuse_refinement import obtuse_angles

SCANS = np.load(Path(__file__).parent / "data" / "scan_decimations.npz")
BOATS = np.load(Path(__file__).parent / "data" / "boat_decimations.npz")
"""odedstein/meshes' boat decimated to 501 and 1,001 vertices (tools/make_boat_decimations.py): closed, with
angles up to 176 degrees that the flips keep."""


def _scan(k, data=SCANS):
    V, F = data[f"vertices_{k}"].astype(np.float64), data[f"faces_{k}"].astype(np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.MeshWarning)       # a few have vertices at one position
        return wrd.Mesh(V, F)


def test_one_obtuse_triangle_is_split_at_the_foot_of_its_altitude():
    # the angle at (0.5, 0.3) is obtuse; the foot of its altitude on the side from (0, 0) to (2, 0) is at 0.25
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.5, 0.3, 0.0]])
    split = wrd.refine_obtuse_angles(wrd.Mesh(V, [[0, 1, 2]]))
    assert split.n_inserted == 1 and split.remaining == 0
    np.testing.assert_allclose(split.weights.toarray(), [[0.75, 0.25, 0.0]], atol=1e-15)
    np.testing.assert_allclose(split.mesh.vertices[3], [0.5, 0.0, 0.0], atol=1e-15)
    assert split.mesh.elements.tolist() == [[0, 3, 2], [3, 1, 2]] and split.parent.tolist() == [0, 0]
    W = wrd.build_operators(split.mesh, "intrinsic").stiffness.toarray()
    # two right triangles: the sides opposite the right angles have weight 0, every other weight is > 0
    assert W[0, 2] == pytest.approx(0.0, abs=1e-15) and W[1, 2] == pytest.approx(0.0, abs=1e-15)
    assert max(W[0, 3], W[1, 3], W[2, 3]) < 0.0


def test_a_foot_near_a_corner_is_one_split():
    # the altitude from (0.1, 0.05) falls at 0.05 of the side: two right triangles, no side left obtuse
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.1, 0.05, 0.0]])
    split = wrd.refine_obtuse_angles(wrd.Mesh(V, [[0, 1, 2]]))
    np.testing.assert_allclose(split.weights.toarray(), [[0.95, 0.05, 0.0]], atol=1e-15)
    assert split.remaining == 0
    assert obtuse_angles(split.mesh.vertices, split.mesh.elements)[0].size == 0
    assert split.mesh.element_volumes.sum() == pytest.approx(0.05, rel=1e-14)
    np.testing.assert_allclose(split.interpolation() @ V, split.mesh.vertices, atol=1e-15)


def test_a_needle_thin_face_is_left_with_a_warning():
    # splitting a face of area 5e-12 x its longest side squared could leave parts below the degenerate-element
    # tolerance (1e-12): it is not split, and the angle left is reported
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1e-11, 0.0]])
    with pytest.warns(wrd.MeshWarning, match=r"got 1 left \(a circumcenter beside a vertex or in a needle-thin face"):
        split = wrd.refine_obtuse_angles(wrd.Mesh(V, [[0, 1, 2]]))
    assert split.n_inserted == 0 and split.remaining == 1


def test_a_mesh_without_such_angles_comes_back_as_it_is():
    mesh = wrd.Mesh(*meshes.icosphere(1, 1.0))
    split = wrd.refine_obtuse_angles(mesh)
    assert split.mesh is mesh and split.n_inserted == 0 and split.weights.shape == (0, mesh.n_vertices)


def test_an_interior_obtuse_triangle_gets_its_circumcenter():
    # a b c with a 157-degree angle at c = (1, 0.2), its edge a b Delaunay (18.9 degrees at d = (1, -6)): the
    # circumcenter (1, -2.4) lies inside a b d (coordinates 0.3, 0.3, 0.4). Its triangles with the boundary sides
    # a d and b d have 157 degrees at it: the next round splits those sides at the feet, 15.4 / 37 from a and b
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, -6.0, 0.0]])
    split = wrd.refine_obtuse_angles(wrd.Mesh(V, [[0, 1, 2], [1, 0, 3]]))
    assert split.n_inserted == 3 and split.remaining == 0
    np.testing.assert_allclose(split.mesh.vertices[4], [1.0, -2.4, 0.0], atol=1e-14)
    t = 15.4 / 37.0
    rows = sorted(split.weights.toarray().round(12).tolist())
    np.testing.assert_allclose(rows, [[0.0, 1 - t, 0.0, t], [0.3, 0.3, 0.0, 0.4], [1 - t, 0.0, 0.0, t]], atol=1e-12)
    assert split.mesh.elements[1].tolist() == [1, 0, 4] and split.parent.tolist() == [0] + [1] * 5
    assert obtuse_angles(split.mesh.vertices, split.mesh.elements)[0].size == 0
    W = wrd.build_operators(split.mesh, "intrinsic").stiffness.toarray()
    assert (W - np.diag(np.diag(W))).max() <= 1e-15
    np.testing.assert_allclose(split.mesh.element_volumes.sum(), 6.2, rtol=1e-14)


@pytest.mark.parametrize("k", range(len(SCANS.files) // 3))
def test_every_decimated_scan_is_refined_to_its_bound(k):
    mesh = _scan(k)
    split = wrd.refine_obtuse_angles(mesh)
    n = mesh.n_vertices
    assert split.remaining == 0
    assert obtuse_angles(split.mesh.vertices, split.mesh.elements)[0].size == 0
    W = wrd.build_operators(split.mesh, "intrinsic").stiffness.tocoo()
    off = W.row != W.col
    assert W.data[off].max() <= 1e-12 * np.abs(W.data).max()          # every weight >= 0, the boundary's too
    np.testing.assert_array_equal(split.mesh.vertices[:n], mesh.vertices)
    scale = np.abs(mesh.vertices).max()
    np.testing.assert_allclose(split.interpolation() @ mesh.vertices, split.mesh.vertices, atol=1e-14 * scale)
    beta = split.weights
    assert np.allclose(beta.sum(axis=1), 1.0, atol=1e-12) and (beta.data > 0.0).all()   # points of the surface
    # the same surface: every refined face lies in its parent, and the areas add up face by face
    areas = np.bincount(split.parent, weights=split.mesh.element_volumes, minlength=mesh.elements.shape[0])
    np.testing.assert_allclose(areas, mesh.element_volumes, rtol=1e-9, atol=1e-14 * areas.max())


def test_the_split_takes_the_distance_off_below_zero():
    # alligator decimated to 630 vertices: from vertex 401 the distance dips to -0.27% of its max at vertex 26,
    # beside an obtuse boundary triangle (measured; the conic solver on the same problem agrees that it dips)
    mesh = _scan(0)
    assert str(SCANS["name_0"]) == "alligator" and mesh.n_vertices == 630
    with pytest.warns(wrd.MeshWarning, match=r"refine_obtuse=True inserts vertices there"):
        u = wrd.DistanceSolver(mesh, 0.0, workers=1, refine_obtuse=False).solve([401]).distance
    assert u.min() < -2e-3 * u.max() and int(np.argmin(u)) == 26
    split = wrd.refine_obtuse_angles(mesh)
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        solver = wrd.DistanceSolver(mesh, 0.0, workers=1)
        res = solver.solve([401])
        v = wrd.DistanceSolver(split.mesh, 0.0, workers=1).solve([401]).distance[:mesh.n_vertices]
    # the default refines the mesh and reports the input's vertices: the same as solving on the refined mesh
    assert solver.solve_mesh.n_vertices == split.mesh.n_vertices == 630 + split.n_inserted
    assert res.distance.shape == (630,) and res.duals.shape == (split.mesh.elements.shape[0], 3)
    np.testing.assert_array_equal(res.distance, v)
    assert v.min() >= -1e-6 * v.max()
    assert np.abs(v - u).mean() < 0.01 * u.max()                        # the same distance elsewhere


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="expected a warp_regdist.Mesh, got ndarray"):
        wrd.refine_obtuse_angles(np.zeros((3, 3)))
    T, tets = meshes.cube_tets(2)
    with pytest.raises(ValueError, match="expected a triangle mesh for refine_obtuse_angles, got a tetrahedral mesh"):
        wrd.refine_obtuse_angles(wrd.Mesh(T, tets))
    points = wrd.Mesh(*meshes.icosphere(1, 1.0)).vertices
    with pytest.raises(ValueError, match="expected a triangle mesh for refine_obtuse_angles, got a PointCloud"):
        wrd.refine_obtuse_angles(wrd.PointCloud(points))
    mesh = _scan(12)
    with pytest.raises(ValueError, match=r"expected interior_angle in \(90, 180\] degrees, got 90"):
        wrd.refine_obtuse_angles(mesh, interior_angle=90)
    with pytest.raises(ValueError, match="expected refine_obtuse as True, False or None, got 'yes'"):
        wrd.DistanceSolver(mesh, refine_obtuse="yes")
    with pytest.raises(ValueError, match="expected triangulation 'intrinsic' with refine_obtuse=True .*, got 'mesh'"):
        wrd.DistanceSolver(mesh, triangulation="mesh", refine_obtuse=True)
    with pytest.raises(ValueError, match="expected triangulation 'intrinsic' with refine_obtuse=True .*, got 'mesh'"):
        wrd.DistanceSolver(wrd.Mesh(T, tets), refine_obtuse=True)
    assert wrd.DistanceSolver(mesh, triangulation="mesh").refinement is None     # it goes with the intrinsic one
    # the Hessian's minimizer dips below 0 on a boundary with or without it (beetle-alt 112: 16 of 20 sources)
    assert wrd.DistanceSolver(mesh, regularizer="hessian").refinement is None
    assert wrd.DistanceSolver(mesh, regularizer="hessian", refine_obtuse=True).refinement.n_inserted == 30


@pytest.mark.parametrize("k, data", [(0, SCANS), (12, SCANS), (14, SCANS), (0, BOATS)])
def test_the_refinement_vjp_matches_central_differences(k, data):
    # alligator 630 (119 inserted), beetle-alt 112 (30) and 1,414 (375, several rounds), boat 501 (70, most of
    # them circumcenters found across flipped edges): the inserted vertices move with the corners of their
    # faces and with their coordinates, functions of the flipped triangulation's lengths
    mesh = _scan(k, data)
    split = wrd.refine_obtuse_angles(mesh)
    rng = np.random.default_rng(k)
    w, D = rng.standard_normal(split.mesh.vertices.shape), rng.standard_normal(mesh.vertices.shape)
    h = 1e-8 * np.abs(mesh.vertices).max()     # small enough that no near-tie (order of insertions, SNAP) changes

    def value(V):
        moved = wrd.refine_obtuse_angles(wrd.Mesh(V, mesh.elements))
        assert np.array_equal(moved.mesh.elements, split.mesh.elements)
        return np.sum(w * moved.mesh.vertices)

    fd = (value(mesh.vertices + h * D) - value(mesh.vertices - h * D)) / (2 * h)
    assert np.sum(split.vjp(w) * D) == pytest.approx(fd, rel=1e-6)
    # the coordinates held fixed (the interpolation alone) would be off by 20-60%
    assert abs(np.sum((split.interpolation().T @ w) * D) - fd) > 0.05 * abs(fd)
    with pytest.raises(ValueError, match=rf"expected a gradient of shape \({split.mesh.n_vertices}, 3\)"):
        split.vjp(np.zeros((mesh.n_vertices, 3)))


def test_warm_starts_polish_and_points_on_a_refined_mesh():
    # beetle-alt decimated to 112 vertices, 30 inserted: every output per input vertex, the refined mesh's inside
    mesh = _scan(12)
    n = mesh.n_vertices
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    on_split = wrd.DistanceSolver(solver.solve_mesh, 0.05, workers=1)
    assert on_split.refinement is None and solver.refinement.n_inserted == 30
    res = solver.solve([5])
    warm = solver.solve([5], initial=res)
    assert warm.iterations < res.iterations and np.abs(warm.distance - res.distance).max() < 5e-3 * res.distance.max()
    polished = res.polish()
    np.testing.assert_allclose(polished.distance, on_split.solve([5]).polish().distance[:n], rtol=1e-9, atol=1e-12)
    assert polished.distance.shape == (n,) and polished.polish_change < 5e-3
    assert polished.vjp(np.ones(n)).vertices.shape == (n, 3)
    both = solver.solve_many([[5], [60]], points=[[(0, (0.2, 0.3, 0.5))], [(30, (0.6, 0.2, 0.2))]])
    assert both.distance.shape == (n, 2)
    g = both.vjp(np.ones((n, 2)))
    assert g.vertices.shape == (n, 3) and g.refined_vertices.shape == (both.refined_mesh.n_vertices, 3)
    assert g.smoothed_distance.shape == (n, 2) and np.isfinite(g.vertices).all()


def test_a_cut_mesh_warns_once_not_again_when_refined():
    # two obtuse triangles on a doubled side (vertices 0, 1 and 3, 4 at one place): the mesh warns of the cut,
    # the solver splits both boundary sides without repeating it
    V = np.array([[0, 0, 0], [2, 0, 0], [0.5, 0.3, 0], [0, 0, 0], [2, 0, 0], [0.5, -0.3, 0]], dtype=float)
    with pytest.warns(wrd.MeshWarning, match="2 vertices lie where another vertex of the mesh lies"):
        mesh = wrd.Mesh(V, [[0, 1, 2], [4, 3, 5]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    assert solver.refinement.n_inserted == 2


@pytest.mark.parametrize("k, data, alpha_hat, sources", [
    (12, SCANS, 0.0, [72]), (61, SCANS, 0.05, [55, 32]), (62, SCANS, 0.05, [82]),
    (0, BOATS, 0.0, [0, 60, 170, 175, 240]), (1, BOATS, 0.05, [0, 355, 485])])
def test_the_columns_that_dipped_below_zero_do_not_by_default(k, data, alpha_hat, sources):
    # beetle-alt 112, woody 127 and 135 (measured: -0.20%, -0.88% and -0.07%, -1.17% of the max unrefined, beside
    # obtuse boundary angles); the closed boat 501 and 1,001 (-0.17% to -0.65%, -0.15% to -0.55%, beside interior
    # angles up to 176 degrees)
    mesh = _scan(k, data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", wrd.MeshWarning)
        unsplit = wrd.DistanceSolver(mesh, alpha_hat, workers=1, refine_obtuse=False).solve_many([[s] for s in sources])
    assert np.all(unsplit.distance.min(axis=0) < -5e-4 * unsplit.distance.max(axis=0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        res = wrd.DistanceSolver(mesh, alpha_hat, workers=1).solve_many([[s] for s in sources])
    assert res.converged.all() and np.all(res.distance.min(axis=0) >= -1e-6 * res.distance.max(axis=0))


def test_the_boundary_as_source_stays_a_source_where_it_is_split():
    # an inserted vertex on a boundary edge lies between two sources: it is a source too, so u = 0 along the
    # whole boundary as without the refinement (beetle-alt 112: 30 inserted, 23 of them on the boundary)
    mesh = _scan(12)
    n = mesh.n_vertices
    boundary = wrd.boundary_vertices(mesh).tolist()
    solver = wrd.DistanceSolver(mesh, 0.05, workers=1)
    inserted = [int(v) for v in wrd.boundary_vertices(solver.solve_mesh) if v >= n]
    assert len(inserted) == 23 and solver.refinement.n_inserted == 30
    assert solver.source_mask(boundary)[0].tolist() == sorted(boundary) + inserted
    assert solver.source_mask([0])[0].tolist() == [0]
    res = solver.solve(boundary)
    on_split = wrd.DistanceSolver(solver.solve_mesh, 0.05, workers=1)
    np.testing.assert_array_equal(res.distance, on_split.solve(boundary + inserted).distance[:n])
    loose = on_split.solve(boundary).distance                       # the inserted vertices free: above 0
    assert loose[inserted].max() > 0.01 * loose.max()
    polished = res.polish()
    assert polished.polish_change < 5e-3 and np.abs(polished.distance - res.distance).max() < 5e-3 * res.distance.max()
