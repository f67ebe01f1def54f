"""Sources anywhere on a triangle mesh: points in faces and on edges, xyz points, curves.

The refinement is checked geometrically (same surface, conforming, the point is a vertex);
the solve on it against closed forms under refinement (flat disc, sphere equator) and against
an independent conic solve of the refined problem (tests/reference_solver.py).
"""

import warnings

import numpy as np
import pytest

import conftest
import meshes
import reference_solver as rs
import warp_regdist as wrd
from warp_regdist.geometry.surface_points import refine

TIGHT = conftest.TIGHT.replace(eps_change=1e-6)


def _sphere(subdivisions):
    return wrd.Mesh(*meshes.icosphere(subdivisions))


def _disk(rings):
    V, F = meshes.disk(1.0, rings)
    return wrd.Mesh(V, F)


def _edges(F):
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    keys, counts = np.unique(e, axis=0, return_counts=True)
    return {tuple(k): c for k, c in zip(keys.tolist(), counts)}


def _mean_edge(mesh):
    V, F = mesh.vertices, mesh.faces
    return np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2).mean()


# ---------------------------------------------------------------------- refinement
def test_refinement_keeps_the_surface_and_conforms():
    mesh = _sphere(2)
    F = mesh.faces
    faces = np.array([5, 5, 17, 40, 40])
    bary = np.array([[0.2, 0.3, 0.5], [0.6, 0.2, 0.2], [0.5, 0.5, 0.0], [0.0, 0.25, 0.75], [1e-4, 0.5, 0.4999]])
    R = refine(mesh, faces, bary)
    V2, F2 = R.mesh.vertices, R.mesh.faces
    assert np.array_equal(V2[:mesh.n_vertices], mesh.vertices)
    assert R.mesh.element_volumes.sum() == pytest.approx(mesh.element_volumes.sum(), rel=1e-12)
    # every refined face lies in the plane of its original face, with the same orientation
    n0 = np.cross(mesh.vertices[F[:, 1]] - mesh.vertices[F[:, 0]], mesh.vertices[F[:, 2]] - mesh.vertices[F[:, 0]])
    n2 = np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]])
    cos = np.einsum("ij,ij->i", n0[R.parent], n2) / np.linalg.norm(n0[R.parent], axis=1) / np.linalg.norm(n2, axis=1)
    assert cos.min() > 1 - 1e-12
    # closed and conforming: every edge in exactly two faces (a hanging vertex would leave edges in one)
    assert set(_edges(F2).values()) == {2}
    expected = np.einsum("pi,pij->pj", bary, mesh.vertices[F[faces]])
    moved = np.linalg.norm(V2[R.point_vertices] - expected, axis=1)
    assert moved[:4].max() < 1e-14 and np.allclose(R.displacement, moved)
    # the last point is 1e-4 from an edge (below tolerances.point_snap): moved onto it
    assert R.point_vertices[4] != R.point_vertices[3] and 0 < moved[4] < 1e-3 * _mean_edge(mesh)
    assert np.unique(R.point_vertices).size == 5


def test_no_obtuse_angle_at_a_source_point_and_no_negative_distance():
    """A split alone leaves an angle >= 120 degrees at a point inside a face; with the feet of the
    perpendiculars every angle at the point is <= 90 degrees, and u stays >= 0 (it went to -0.4 h)."""
    mesh = wrd.load_mesh(wrd.data_path("spot_rr.off"))
    rng = np.random.default_rng(0)
    faces, blocked = [], np.zeros(mesh.n_vertices, dtype=bool)
    for f in rng.permutation(mesh.n_elements):      # faces apart, so that no two points' feet interact
        if not blocked[mesh.faces[f]].any():
            faces.append(f)
            blocked[mesh.faces[np.isin(mesh.faces, mesh.faces[f]).any(axis=1)].ravel()] = True
        if len(faces) == 40:
            break
    faces = np.array(faces)
    bary = rng.dirichlet([2, 2, 2], size=40)
    bary[:10] = [[0.59, 0.09, 0.32]] * 10          # near an edge
    bary[10:12] = [[0.5, 0.5, 0.0], [0.0, 0.3, 0.7]]   # on edges
    R = refine(mesh, faces, bary)
    V, F = R.mesh.vertices, R.mesh.faces
    for v in R.point_vertices:
        for tri in F[(F == v).any(axis=1)]:
            a, b = (V[w] - V[v] for w in tri if w != v)
            assert np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b))) <= 90 + 1e-6
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
    for f, b in ((3085, (0.59, 0.09, 0.32)), (4100, (0.08, 0.62, 0.30))):
        assert solver.solve(points=[(f, b)]).refined_distance.min() >= 0.0


def test_barycentric_corner_equals_the_vertex_solve():
    mesh = wrd.load_mesh(wrd.data_path("spot_rr.off"))
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
    face = int(np.flatnonzero((mesh.faces == 2272).any(axis=1))[0])
    b = (mesh.faces[face] == 2272).astype(float)
    vertex = solver.solve([2272]).distance
    point = solver.solve(points=[(face, tuple(b))]).distance
    assert np.abs(point - vertex).max() <= 1e-8 * vertex.max()
    # a batch shares one refined mesh: column 0 is solved on the mesh refined at column 1's point, in
    # its source's face (a change of the discretization next to the source: 0.2% of the max here)
    inside = solver.solve(points=[(face, (0.2, 0.3, 0.5))]).distance
    many = solver.solve_many(points=[[(face, b)], [(face, (0.2, 0.3, 0.5))]])
    assert many.distance.shape == (mesh.n_vertices, 2)
    assert np.abs(many.distance[:, 1] - inside).max() <= 1e-6 * inside.max()
    assert np.abs(many.distance[:, 0] - vertex).max() <= 5e-3 * vertex.max()
    assert "refined_mesh" in many and many.refined_distance.shape == (many.refined_mesh.n_vertices, 2)


def test_point_in_a_face_converges_to_the_euclidean_distance():
    """Flat disc, alpha_hat 0: u is the PL distance from the point, within O(h) of |x - p|."""
    p = np.array([0.123, 0.071, 0.0])
    errors = []
    for rings in (6, 12, 24):
        mesh = _disk(rings)
        (face, b), = wrd.surface_points(mesh, p)
        res = wrd.DistanceSolver(mesh, alpha_hat=0.0, options=TIGHT).solve(points=[(face, b)])
        zero = np.flatnonzero(res.refined_distance == 0.0)
        assert zero.size == 1 and np.allclose(res.refined_mesh.vertices[zero[0]], p, atol=1e-15)
        errors.append(np.abs(res.distance - np.linalg.norm(mesh.vertices - p, axis=1)).max() / _mean_edge(mesh))
    errors = np.array(errors) * np.array([1 / 6, 1 / 12, 1 / 24]) / (1 / 6)     # in units of the coarsest h
    assert errors[1] < 0.75 * errors[0] and errors[2] < 0.75 * errors[1]


def test_points_on_edges_and_vertices_and_combined_sources():
    mesh = _sphere(2)
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
    F = mesh.faces
    res = solver.solve([0], points=[(3, (0.5, 0.5, 0.0)), (7, (0.0, 0.0, 1.0))])
    assert res.distance[0] == 0 and res.distance[F[7, 2]] == 0
    new_zero = np.flatnonzero(res.refined_distance[mesh.n_vertices:] == 0) + mesh.n_vertices
    assert new_zero.size == 1
    assert np.allclose(res.refined_mesh.vertices[new_zero[0]], mesh.vertices[F[3, :2]].mean(axis=0))


def test_refined_problem_matches_the_conic_solve():
    V, F = meshes.icosphere(3)
    V = meshes.perturbed(V, F, 0.02, seed=3)
    mesh = wrd.Mesh(V, F)
    points = [(11, (0.2, 0.5, 0.3)), (300, (0.0, 0.4, 0.6))]
    # the refinement's right angles at the feet make cocircular quads, where the independent intrinsic
    # triangulation may flip ties; the refined mesh's own triangulation is the same problem for both
    res = wrd.DistanceSolver(mesh, alpha_hat=0.05, options=TIGHT, triangulation="mesh").solve(points=points)
    R = res.refined_mesh
    sources = np.flatnonzero(res.refined_distance == 0)
    assert sources.size == 2 and sources.min() >= mesh.n_vertices
    alpha = 0.05 * np.sqrt(R.element_volumes.sum())
    expected = rs.solve_reference(R.vertices, R.faces, sources, alpha, triangulation="mesh")
    assert np.abs(res.refined_distance - expected).max() <= 1e-3 * expected.max()


# ---------------------------------------------------------------------- xyz points
def test_surface_points_finds_the_closest_point():
    mesh = _sphere(3)
    rng = np.random.default_rng(0)
    X = rng.normal(size=(20, 3))
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    pts, dist = wrd.surface_points(mesh, 1.01 * X, return_distance=True)
    V, F = mesh.vertices, mesh.faces
    Y = np.array([np.asarray(b) @ V[F[f]] for f, b in pts])
    assert np.allclose(np.linalg.norm(Y - 1.01 * X, axis=1), dist)
    # no face vertex is closer than the point found (a brute-force check over every vertex)
    nearest_vertex = np.linalg.norm(V[None] - 1.01 * X[:, None], axis=2).min(axis=1)
    assert (dist <= nearest_vertex + 1e-12).all() and dist.max() < 0.02


# ---------------------------------------------------------------------- curves
def test_equator_curve_on_the_sphere():
    """Equator as a closed curve at alpha_hat 0: u = |pi/2 - theta| within 2h, falling under refinement."""
    errors = []
    th = np.linspace(0, 2 * np.pi, 12, endpoint=False) + 0.1
    ring = np.stack([np.cos(th), np.sin(th), 0 * th], axis=1)
    for sub in (3, 4):
        mesh = _sphere(sub)
        res = wrd.DistanceSolver(mesh, alpha_hat=0.0, options=TIGHT).solve(curve=wrd.surface_points(mesh, ring), closed=True)
        Z = mesh.vertices[:, 2]
        exact = np.abs(np.pi / 2 - np.arccos(np.clip(Z / np.linalg.norm(mesh.vertices, axis=1), -1, 1)))
        err = np.abs(res.distance - exact).max()
        assert err <= 2 * _mean_edge(mesh)
        errors.append(err)
        on_curve = res.refined_mesh.vertices[res.refined_distance == 0]
        # crossings near a vertex move to it (tolerances.curve_snap): within 0.2 h of the equator
        assert np.abs(on_curve[:, 2]).max() < 0.2 * _mean_edge(mesh) and len(on_curve) > 12
        assert (res.signed_distance[Z > 1e-9] < 0).all() and (res.signed_distance[Z < -1e-9] > 0).all()
    assert errors[1] < 0.7 * errors[0]


def test_equator_through_vertices_rounded_as_a_file_rounds_them():
    """The icosphere's equator runs along its edges. Vertices rounded as a file rounds them (10
    decimals in trimesh's OFF, float32 in STL) tilt the faces' normals, so the section plane
    passes 1e-11 to 1e-8 above or below the equator's vertices: the curve must still cut the
    sphere into the same two halves."""
    th = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    ring = np.stack([np.cos(th), np.sin(th), 0 * th], axis=1)
    exact = _sphere(3)
    signs = []
    for mesh in (exact, wrd.Mesh(np.round(exact.vertices, 10), exact.elements),
                 wrd.Mesh(exact.vertices.astype(np.float32).astype(np.float64), exact.elements)):
        res = wrd.DistanceSolver(mesh, alpha_hat=0.05).solve(curve=wrd.surface_points(mesh, ring), closed=True)
        signs.append(np.sign(res.signed_distance))
        Z = exact.vertices[:, 2]
        assert (res.signed_distance[Z > 1e-9] < 0).all() and (res.signed_distance[Z < -1e-9] > 0).all()
    np.testing.assert_array_equal(signs[1], signs[0])
    np.testing.assert_array_equal(signs[2], signs[0])


def test_open_curve_is_zero_along_its_edges():
    mesh = _sphere(3)
    pts = wrd.surface_points(mesh, [[1, 0, 0.3], [0.3, 1, 0.2], [-0.2, 0.9, -0.4]], max_distance=1.0)
    res = wrd.DistanceSolver(mesh, alpha_hat=0.05).solve(curve=pts)
    zero = np.flatnonzero(res.refined_distance == 0)
    F = res.refined_mesh.faces
    # the zero vertices form one path of edges: a connected set with two ends of degree 1
    E = {e for e in _edges(F) if e[0] in set(zero) and e[1] in set(zero)}
    degree = np.bincount(np.array(list(E)).ravel(), minlength=res.refined_mesh.n_vertices)[zero]
    assert len(E) == len(zero) - 1 and sorted(degree)[:3] == [1, 1, 2]
    assert "signed_distance" not in res


# ---------------------------------------------------------------------- bad input
@pytest.mark.parametrize("points, message", [
    ([(10 ** 6, (1, 0, 0))], r"expected a face index in \[0, 319\] in points of column 0\[0\], got 1000000"),
    ([(1, (0.5, 0.7, -0.2))], r"expected barycentric coordinates >= 0 that sum to 1"),
    ([(1, (0.5, 0.7, 0.2))], r"expected barycentric coordinates >= 0 that sum to 1 .* \(sum 1.4\)"),
    ([(1, (0.5, 0.5))], r"expected 3 finite barycentric coordinates"),
    ([(1.5, (1, 0, 0))], r"expected an integer face index"),
    ([], r"expected at least one surface point"),
])
def test_bad_points(points, message):
    solver = wrd.DistanceSolver(_sphere(2))
    with pytest.raises(ValueError, match=message):
        solver.solve(points=points)


def test_bad_xyz_and_curves():
    mesh = _sphere(2)
    with pytest.raises(ValueError, match=r"expected points within 0.1\d+ of the surface \(max_distance\), got point 1"):
        wrd.surface_points(mesh, [[1, 0, 0], [0, 0, 3]])
    with pytest.raises(ValueError, match=r"expected finite xyz points, got 1 with NaN/inf"):
        wrd.surface_points(mesh, [[np.nan, 0, 0]])
    with pytest.raises(ValueError, match=r"expected xyz points of shape \(p, 3\)"):
        wrd.surface_points(mesh, np.zeros((0, 3)))
    solver = wrd.DistanceSolver(mesh)
    with pytest.raises(ValueError, match="expected a curve of at least 2 points, got 1"):
        solver.solve(curve=[(1, (1, 0, 0))])
    with pytest.raises(ValueError, match="expected sources, points or a curve, got none"):
        solver.solve()
    with pytest.raises(ValueError, match=r"expected one entry per column .* got lengths \{'source sets': 2, 'points': 1\}"):
        solver.solve_many([[0], [1]], points=[[(1, (1, 0, 0))]])
    with pytest.raises(ValueError, match="expected initial=None with points or curves"):
        solver.solve(points=[(1, (1, 0, 0))], initial=solver.solve([0]))


# ---------------------------------------------------------------------- command line
def test_cli_points_and_closed_curve(tmp_path, capsys):
    from warp_regdist.cli import main

    mesh = _sphere(3)
    path = tmp_path / "sphere.off"
    import trimesh
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
    (tmp_path / "points.csv").write_text("# x,y,z\n0.3,0.2,0.93\n")
    th = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    (tmp_path / "ring.csv").write_text("".join(f"{np.cos(t)},{np.sin(t)},0\n" for t in th))
    out = tmp_path / "u.npy"
    assert main(["distance", str(path), "--sources", str(tmp_path / "points.csv"), "--output", str(out)]) == 0
    assert "from 1 surface points of points.csv (moved onto the surface by at most" in capsys.readouterr().out
    read = wrd.load_mesh(path)  # the mesh as the CLI reads it (the OFF file rounds the vertices)
    (face, b), = wrd.surface_points(read, [0.3, 0.2, 0.93])
    np.testing.assert_allclose(np.load(out), wrd.DistanceSolver(read).solve(points=[(face, b)]).distance, rtol=0, atol=1e-12)
    assert main(["distance", str(path), "--curve", str(tmp_path / "ring.csv"), "--closed", "--output", str(out),
                 "--quiet"]) == 0
    signed = np.load(out)
    Z = mesh.vertices[:, 2]
    assert (signed[Z > 1e-9] < 0).all() and (signed[Z < -1e-9] > 0).all()
    assert main(["distance", str(path), "--closed", "--sources", "0", "--output", str(out)]) == 2
    assert "expected --closed with a --curve, got no --curve" in capsys.readouterr().err
    assert main(["distance", str(path), "--output", str(out)]) == 2
    assert "expected --sources or --curve, got neither" in capsys.readouterr().err


def test_distance_matrix_with_landmark_points(tmp_path):
    mesh = _sphere(2)
    points = [(3, (0.2, 0.3, 0.5)), (50, (0.5, 0.5, 0.0)), (100, (1.0, 0.0, 0.0))]
    D = wrd.distance_matrix(mesh, points=points, chunk=2)
    columns = wrd.DistanceSolver(mesh).solve_many(points=[[p] for p in points]).distance
    assert D.shape == (3, mesh.n_vertices) and np.abs(D - columns.T).max() <= 1e-9 * D.max()
    stored = wrd.distance_matrix(mesh, points=points, chunk=2, out=tmp_path / "D.npy")
    assert np.array_equal(np.asarray(stored), D)
    with pytest.raises(ValueError, match="expected sources or points, got both"):
        wrd.distance_matrix(mesh, sources=[0], points=points)
    with pytest.raises(ValueError, match=r"expected distinct points, got points 0 and 1 at the same place"):
        wrd.distance_matrix(mesh, points=[points[0], points[0]])


# ---------------------------------------------------------------------- tetrahedral meshes
def _boundary_area(mesh):
    F, _ = wrd.boundary_faces(mesh)
    V = mesh.vertices
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()


def test_points_and_curves_on_the_boundary_of_a_tet_mesh():
    mesh = wrd.Mesh(*meshes.ball_tets(2, 4))
    rng = np.random.default_rng(0)
    X = rng.normal(size=(4, 3))
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    points = wrd.surface_points(mesh, X, max_distance=0.1)
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
    res = solver.solve(points=points)
    R = res.refined_mesh
    # the same solid, conforming: no face in more than two tetrahedra, the boundary as before
    assert R.element_volumes.sum() == pytest.approx(mesh.element_volumes.sum(), rel=1e-12)
    faces = np.sort(R.elements[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2 and _boundary_area(R) == pytest.approx(_boundary_area(mesh), rel=1e-12)
    F, _ = wrd.boundary_faces(mesh)
    at = np.array([np.asarray(b) @ mesh.vertices[F[f]] for f, b in points])
    zero = R.vertices[res.refined_distance == 0]
    assert len(zero) == 4 and all(np.linalg.norm(zero - x, axis=1).min() < 1e-12 for x in at)
    # a boundary point leaves u at most slightly negative next to it (the split tetrahedra are not Delaunay)
    assert res.refined_distance.min() > -0.05 * _mean_edge(wrd.Mesh(mesh.vertices, F))
    th = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    ring = wrd.surface_points(mesh, np.stack([np.cos(th), np.sin(th), 0 * th], axis=1), max_distance=0.1)
    with wrd.tolerances.override(curve_snap=1e-3):
        res = solver.solve(curve=ring, closed=True)
    on_curve = res.refined_mesh.vertices[res.refined_distance == 0]
    assert len(on_curve) > 10 and np.abs(on_curve[:, 2]).max() < 1e-12
    assert "signed_distance" not in res


def test_cli_matrix_of_landmark_points(tmp_path, capsys):
    from warp_regdist.cli import main
    import trimesh

    mesh = _sphere(2)
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(tmp_path / "sphere.off")
    X = np.array([[0.3, 0.2, 0.93], [0.0, -0.99, 0.1], [0.6, 0.6, -0.5]])
    (tmp_path / "landmarks.csv").write_text("".join(f"{x},{y},{z}\n" for x, y, z in X))
    out = tmp_path / "D.npy"
    assert main(["matrix", str(tmp_path / "sphere.off"), "--sources", str(tmp_path / "landmarks.csv"),
                 "--output", str(out), "--quiet"]) == 0
    expected = wrd.distance_matrix(mesh, points=wrd.surface_points(mesh, X))
    assert np.abs(np.load(out) - expected).max() < 1e-6 * expected.max()   # the OFF file rounds the vertices


def test_curves_on_spot_keep_u_nonnegative_and_may_cross_themselves():
    """Loops and arcs of 2-3 h radius around vertices of spot: u >= 0 next to them (curve_snap, and
    the feet of the curve's own points), no warning; a self-crossing curve inserts its crossing."""
    import warnings

    mesh = wrd.load_mesh(wrd.data_path("spot_rr.off"))
    V, F = mesh.vertices, mesh.faces
    normals = np.zeros_like(V)
    for k in range(3):
        np.add.at(normals, F[:, k], np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
    rng = np.random.default_rng(5)
    th = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    for trial in range(6):
        v = rng.integers(mesh.n_vertices)
        e1 = np.cross(normals[v], [0.3, 0.5, 0.8])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(normals[v], e1)
        ring = V[v] + rng.uniform(0.06, 0.15) * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
        closed = trial % 2 == 0
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            res = solver.solve(curve=wrd.surface_points(mesh, ring if closed else ring[:5], max_distance=0.1),
                               closed=closed)
        assert res.refined_distance.min() >= 0.0
    eight = V[v] + 0.1 * (np.sin(2 * th)[:, None] * e1 + np.sin(th)[:, None] * e2)      # crosses itself once
    res = solver.solve(curve=wrd.surface_points(mesh, np.concatenate([eight, eight[:1]]), max_distance=0.1))
    assert res.converged


def test_a_cut_mesh_warns_once_not_again_when_refined_at_points():
    # two triangles on a doubled side: the mesh warns of the cut, a refinement at a point does not repeat it
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0], [0, -1, 0]], dtype=float)
    with pytest.warns(wrd.MeshWarning, match="2 vertices lie where another vertex of the mesh lies"):
        mesh = wrd.Mesh(V, [[0, 1, 2], [4, 3, 5]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        res = wrd.DistanceSolver(mesh, 0.05, workers=1).solve(points=[(0, (0.2, 0.3, 0.5))])
    assert res.refined_mesh.n_vertices > 6 and np.isinf(res.distance[3:]).all() and np.isfinite(res.distance[:3]).all()
