"""Surface -> tetrahedra (TetGen) -> interior distance, the regular-grid sampling, and the
``warp-regdist volume`` command.

Why a wrong implementation fails:
- tetrahedra that do not fill the solid (a lost region, a cavity filled or an island
  in it removed, an inverted orientation) change the total volume, asserted to 1e-9 against the surface's enclosed
  volume, or the distance, asserted within 3% of the solid ball's closed form;
- a grid sampler with wrong barycentric coordinates or indices misses the exact values
  of a linear field (asserted to 1e-12) or puts values outside the solid;
- a surface check that lets self-intersections through crashes the test process inside
  TetGen (it does, with "malloc(): invalid size") instead of raising.
"""

import re

import numpy as np
import pytest
import meshio
import trimesh

import closed_forms
import warp_regdist as wrd
from warp_regdist.cli import main
from warp_regdist.geometry.tetrahedralize import interior_edge
from warp_regdist.geometry.volume_grid import sample_on_grid

pytest.importorskip("tetgen", reason="the optional 'tetgen' package (pip install 'warp-regdist[volume]')")

SPOT = str(wrd.__path__[0]) + "/data/spot_rr.off"


def _sphere(subdivisions=2, center=(0.0, 0.0, 0.0), radius=1.0, flip=False):
    s = trimesh.creation.icosphere(subdivisions, radius=radius)
    return s.vertices + np.asarray(center), (s.faces[:, ::-1] if flip else s.faces)


def _join(*surfaces):
    V = np.concatenate([v for v, _ in surfaces])
    offsets = np.cumsum([0] + [len(v) for v, _ in surfaces[:-1]])
    return wrd.Mesh(V, np.concatenate([f + o for (_, f), o in zip(surfaces, offsets)]))


def _enclosed_volume(mesh):
    P = mesh.vertices[mesh.faces]
    return np.einsum("ij,ij->i", P[:, 0], np.cross(P[:, 1], P[:, 2])).sum() / 6.0


def _tet_volume(mesh):
    P = mesh.vertices[mesh.elements]
    return np.linalg.det(P[:, 1:] - P[:, :1]).sum() / 6.0


def test_ball_depth_matches_closed_form():
    # measured: 2.7% of the maximum (p99 2.3%, mean 0.8%; the icosphere's faces lie up to
    # 0.45% of the radius inside the sphere), 9,216 tets, at alpha = 0.2 (the constraint is
    # active on 0.6 < r < 1); alpha scaled as sqrt(V) instead of V^(1/3) gives 11%
    surface = wrd.Mesh(*_sphere(3))
    mesh = wrd.tetrahedralize(surface, max_volume=0.001, quality=1.2, min_dihedral=18)
    assert mesh.element_dim == 3 and mesh.n_elements > 8000
    assert _tet_volume(mesh) == pytest.approx(_enclosed_volume(surface), rel=1e-9)
    solver = wrd.DistanceSolver(mesh, alpha_hat=0.125)
    res = solver.solve(wrd.boundary_vertices(mesh))
    assert res.converged
    exact = closed_forms.ball_distance(np.linalg.norm(mesh.vertices, axis=1), 1.0, solver.alpha)
    assert np.abs(res.distance - exact).max() <= 0.03 * exact.max()


def test_default_interior_resolves_alpha():
    """A unit ball from a 2,562-vertex icosphere at alpha_hat 0.05 (alpha 0.081): the default
    interior (edges <= min(mean surface edge 0.075, alpha)) meets the closed form to 3% of the
    max depth (2.1% measured); TetGen's grading from the surface alone gives 4.6%."""
    surface = wrd.Mesh(*_sphere(4))
    errors = {}
    for max_edge in ("auto", None):
        mesh = wrd.tetrahedralize(surface, max_edge=max_edge, alpha_hat=0.05)
        solver = wrd.DistanceSolver(mesh, alpha_hat=0.05)
        res = solver.solve(wrd.boundary_vertices(mesh))
        r = np.minimum(np.linalg.norm(mesh.vertices, axis=1), 1.0)
        exact = closed_forms.ball_distance(r, 1.0, solver.alpha)
        errors[max_edge] = np.abs(res.distance - exact).max() / exact.max()
    assert errors["auto"] <= 0.03 < 0.04 < errors[None]


def test_interior_edge_is_the_mean_surface_edge_or_alpha():
    outer, inner = _sphere(3), _sphere(2, radius=0.5, flip=True)
    V, F = outer
    P = V[F]
    mean_edge = np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2).mean()
    volume = abs(_enclosed_volume(wrd.Mesh(*outer)))
    assert interior_edge(V, F, 1.0) == pytest.approx(mean_edge, rel=1e-12)
    assert interior_edge(V, F, None) == interior_edge(V, F, 0.0) == pytest.approx(mean_edge, rel=1e-12)
    assert interior_edge(V, F + 0, 0.01) == pytest.approx(0.01 * volume ** (1 / 3), rel=1e-9)
    hollow = _join(outer, inner)  # the cavity's volume is not the solid's
    solid = volume - abs(_enclosed_volume(wrd.Mesh(*inner)))
    assert interior_edge(hollow.vertices + 3.0, hollow.faces, 0.01) == pytest.approx(0.01 * solid ** (1 / 3), rel=1e-9)
    coarse = wrd.tetrahedralize(wrd.Mesh(V, F), max_edge=None)
    assert wrd.tetrahedralize(wrd.Mesh(V, F), max_volume=0.05).n_elements < coarse.n_elements * 3  # replaces auto
    assert wrd.tetrahedralize(wrd.Mesh(V, F), alpha_hat=0.125).n_elements > coarse.n_elements * 4
    with pytest.raises(ValueError, match=r"expected max_edge 'auto', a length > 0 or None, got -1"):
        wrd.tetrahedralize(wrd.Mesh(V, F), max_edge=-1)
    with pytest.raises(ValueError, match=r"expected max_edge 'auto', a length > 0 or None, got 'fine'"):
        wrd.tetrahedralize(wrd.Mesh(V, F), max_edge="fine")
    with pytest.raises(ValueError, match=r"expected a finite alpha_hat >= 0, got -0\.1"):
        wrd.tetrahedralize(wrd.Mesh(V, F), alpha_hat=-0.1)


def test_same_surface_gives_same_tetrahedra_and_keeps_surface_vertices_first():
    V, F = _sphere(2)
    V = np.concatenate([V, [[5.0, 5.0, 5.0]]])  # unreferenced: dropped
    first = wrd.tetrahedralize(wrd.Mesh(V, F), max_volume=0.02)
    second = wrd.tetrahedralize(wrd.Mesh(V, F), max_volume=0.02)
    assert np.array_equal(first.vertices, second.vertices) and np.array_equal(first.elements, second.elements)
    assert np.array_equal(first.vertices[: len(V) - 1], V[:-1])
    assert not np.any(np.all(first.vertices == [5.0, 5.0, 5.0], axis=1))
    assert wrd.tetrahedralize(wrd.Mesh(V, F), max_volume=0.005).n_elements > 2 * first.n_elements


def test_vertices_at_one_position_are_welded():
    V, F = _sphere(2)
    seam = np.concatenate([V, V[:1]])  # a copy of vertex 0, used by half of its faces: open by indices
    F = F.copy()
    fan = np.flatnonzero((F == 0).any(axis=1))[::2]
    F[fan] = np.where(F[fan] == 0, len(V), F[fan])
    with pytest.warns(wrd.MeshWarning, match="1 vertex lies where another vertex of the mesh lies"):
        cut = wrd.Mesh(seam, F)
    mesh = wrd.tetrahedralize(cut, max_volume=0.02)
    assert np.array_equal(mesh.vertices[: len(V)], V)
    assert _tet_volume(mesh) == pytest.approx(_enclosed_volume(wrd.Mesh(V, _sphere(2)[1])), rel=1e-9)


def test_disjoint_shells_become_components_and_quality_none_meshes_coarsely():
    surface = _join(_sphere(1), _sphere(1, center=(3.0, 0.0, 0.0), radius=0.5))
    mesh = wrd.tetrahedralize(surface, quality=None)
    labels = mesh.components()
    assert labels.max() == 1
    assert _tet_volume(mesh) == pytest.approx(_enclosed_volume(surface), rel=1e-9)
    assert mesh.n_vertices == surface.n_vertices  # no refinement: only the surface's points
    refined = wrd.tetrahedralize(surface, quality=1.2)
    assert refined.n_vertices > mesh.n_vertices


@pytest.mark.parametrize("flip", [False, True], ids=["inner shell outward", "inner shell inward"])
def test_shell_inside_a_shell_is_a_cavity_and_a_shell_inside_that_a_solid(flip):
    outer, inner = _sphere(3), _sphere(2, radius=0.5, flip=flip)
    hollow = _join(outer, inner)
    mesh = wrd.tetrahedralize(hollow, max_volume=0.005)
    expected = abs(_enclosed_volume(wrd.Mesh(*outer))) - abs(_enclosed_volume(wrd.Mesh(*inner)))
    assert _tet_volume(mesh) == pytest.approx(expected, rel=1e-9)
    if flip:
        return  # the hole point is found on either side of the inner shell; the rest is the same
    res = wrd.DistanceSolver(mesh, alpha_hat=0.02).solve(wrd.boundary_vertices(mesh))
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert np.all(res.distance[(r > 0.999) | (r < 0.501)] == 0.0)  # both spheres are boundary
    assert 0.7 < r[np.argmax(res.distance)] < 0.8 and 0.2 < res.distance.max() <= 0.25  # exact: 0.25 at r = 0.75
    island = wrd.tetrahedralize(_join(outer, inner, _sphere(1, radius=0.3)), quality=None)
    assert island.components().max() == 1
    assert _tet_volume(island) == pytest.approx(expected + abs(_enclosed_volume(wrd.Mesh(*_sphere(1, radius=0.3)))),
                                                rel=1e-9)


def test_touching_shells_are_refused_and_tetgen_leaves_no_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, b = trimesh.creation.box(), trimesh.creation.box()
    b.apply_translation([1.0, 0.5, 0.0])  # a coplanar contact, which the crossing test does not see
    with pytest.raises(ValueError, match=r"expected a surface TetGen can tetrahedralize, got its error: "
                                         r"The input surface mesh contain self-intersections"):
        wrd.tetrahedralize(_join((a.vertices, a.faces), (b.vertices, b.faces)))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "surface, message",
    [
        (lambda: wrd.Mesh(_sphere(2)[0], _sphere(2)[1][1:]),
         r"expected a closed \(watertight\) surface, got 3 boundary edges \(first: between vertices \[\d+, \d+\]\)"),
        (lambda: _join(_sphere(2), _sphere(2, center=(1.0, 0.0, 0.0))),
         r"expected a surface that does not intersect itself, got \d+ crossing face pairs \(first: faces \d+ and \d+\)"),
        (lambda: wrd.tetrahedralize(wrd.Mesh(*_sphere(1)), quality=None),
         r"expected a triangle surface, got a tetrahedral mesh \(\d+ tetrahedra\)"),
        (lambda: np.zeros((4, 3)), r"expected a triangle surface \(a Mesh or a file path\), got ndarray"),
    ],
    ids=["open", "self-intersecting", "tetrahedra", "array"],
)
def test_unusable_surfaces_are_refused(surface, message):
    with pytest.raises(ValueError, match=message):
        wrd.tetrahedralize(surface())


@pytest.mark.parametrize(
    "options, message",
    [
        ({"max_volume": 0.0}, r"expected max_volume > 0 \(or None\), got 0.0"),
        ({"max_volume": float("nan")}, r"expected max_volume > 0 \(or None\), got nan"),
        ({"quality": 1.0}, r"expected quality \(largest radius-edge ratio\) > 1 \(or None\), got 1.0"),
        ({"max_volume": "0.1"}, r"expected max_volume > 0 \(or None\), got '0.1'"),
        ({"quality": True}, r"expected quality \(largest radius-edge ratio\) > 1 \(or None\), got True"),
        ({"min_dihedral": 30}, r"expected min_dihedral in \[0, 18\] degrees, got 30"),
    ],
)
def test_bad_settings_are_refused(options, message):
    with pytest.raises(ValueError, match=message):
        wrd.tetrahedralize(wrd.Mesh(*_sphere(1)), **options)


def test_missing_tetgen_is_a_clear_error(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tetgen", None)
    with pytest.raises(ModuleNotFoundError, match=r"expected the optional package 'tetgen' for tetrahedralize "
                                                  r"\(pip install 'warp-regdist\[volume\]'\), got none installed"):
        wrd.tetrahedralize(wrd.Mesh(*_sphere(1)))


def test_grid_samples_a_linear_field_exactly_and_nan_outside():
    mesh = wrd.tetrahedralize(wrd.Mesh(*_sphere(3)))
    coefficients = np.array([1.0, 2.0, -1.0])
    grid = sample_on_grid(mesh, mesh.vertices @ coefficients + 0.5, resolution=31)
    assert grid.values.shape == (31, 31, 31)
    assert np.allclose(grid.origin, -1.0) and grid.spacing == pytest.approx(2.0 / 30)
    points = grid.origin + grid.spacing * np.indices(grid.values.shape).reshape(3, -1).T
    values = grid.values.reshape(-1)
    r = np.linalg.norm(points, axis=1)
    assert np.isfinite(values[r < 0.99]).all()  # the icosphere's faces are > 0.995 from the centre
    assert np.isnan(values[r > 1.0 + 1e-12]).all()
    inside = np.isfinite(values)
    assert np.abs(values[inside] - (points[inside] @ coefficients + 0.5)).max() <= 1e-12


def test_grid_refuses_bad_input():
    mesh = wrd.tetrahedralize(wrd.Mesh(*_sphere(1)), quality=None)
    with pytest.raises(ValueError, match=r"expected values of shape \(42,\) \(one per vertex\), got \(41,\)"):
        sample_on_grid(mesh, np.zeros(41))
    with pytest.raises(ValueError, match=r"expected an integer resolution >= 2, got 1"):
        sample_on_grid(mesh, np.zeros(42), resolution=1)
    with pytest.raises(ValueError, match=r"expected a tetrahedral Mesh, got a triangle mesh"):
        sample_on_grid(wrd.Mesh(*_sphere(1)), np.zeros(42))


def test_cli_volume_spot_depth(tmp_path, capsys):
    out, grid_out, png = tmp_path / "depth.vtu", tmp_path / "depth.npz", tmp_path / "cut.png"
    code = main(["volume", SPOT, "--sources", "boundary", "--alpha-hat", "0.2", "--output", str(out),
                 "--png", str(png), "--grid", "24", "--grid-output", str(grid_out), "--max-edge", "0.08"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    found = re.search(r"TetGen: \d+ tetrahedra \(quality 1\.5, max edge 0\.08, .* from (\d+) boundary vertices",
                      captured.out)
    assert found, captured.out
    assert re.search(r"depth\.npz \(\d+ x \d+ x 24 grid, origin \[.*\], spacing [\d.]+, NaN outside\)", captured.out)
    read = meshio.read(out)
    mesh = wrd.Mesh(read.points, read.cells_dict["tetra"])
    depth = read.point_data["distance"]
    boundary = wrd.boundary_vertices(mesh)
    interior = np.setdiff1d(np.arange(mesh.n_vertices), boundary)
    assert boundary.size == int(found[1]) >= 4764 and interior.size > 100
    assert np.array_equal(boundary[:4764], np.arange(4764))  # the surface's vertices first
    assert np.isfinite(depth).all()
    assert np.all(depth[boundary] == 0.0)
    assert depth[interior].min() > 0.0
    assert png.read_bytes().startswith(b"\x89PNG\r\n\x1a\n")
    with np.load(grid_out) as saved:
        values, spacing = saved["values"], float(saved["spacing"])
    assert max(values.shape) == 24 and np.isfinite(values).any() and np.isnan(values).any()
    assert np.nanmin(values) >= 0.0 and np.nanmax(values) <= depth.max() + 1e-12
    assert spacing == pytest.approx(np.ptp(read.points, axis=0).max() / 23)


def test_cli_volume_point_sources_are_vertices(tmp_path, capsys):
    """Points near the surface are inserted into it before TetGen: u = 0 exactly there, nowhere else."""
    V, F = _sphere(2)
    trimesh.Trimesh(V, F, process=False).export(tmp_path / "ball.stl")
    points = np.array([[0.3, 0.2, 0.95], [0.0, -0.99, 0.05]])
    (tmp_path / "points.csv").write_text("# x,y,z\n" + "\n".join(",".join(str(float(x)) for x in p) for p in points) + "\n")
    out = tmp_path / "u.vtu"
    code = main(["volume", str(tmp_path / "ball.stl"), "--sources", str(tmp_path / "points.csv"),
                 "--output", str(out), "--max-volume", "0.05"])
    assert code == 0, capsys.readouterr().err
    said = capsys.readouterr().out
    read = meshio.read(out)
    u = read.point_data["distance"]
    zero = np.flatnonzero(u == 0.0)
    assert f"2 surface points, vertices {zero[0]}, {zero[1]} (moved onto the surface by at most" in said
    candidates = [trimesh.triangles.closest_point(V[F], np.repeat(p[None], len(F), axis=0)) for p in points]
    expected = [c[np.argmin(np.linalg.norm(c - p, axis=1))] for c, p in zip(candidates, points)]
    assert zero.size == 2 and zero.min() >= 162 and np.allclose(read.points[zero], expected, atol=1e-12)
    (tmp_path / "far.csv").write_text("0,0,0\n")
    code = main(["volume", str(tmp_path / "ball.stl"), "--sources", str(tmp_path / "far.csv"), "--output", str(out)])
    assert code == 2
    assert "expected points within 0.1" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--sources", "3,4"], r"expected --sources 'boundary' or a \.csv file of 'x,y,z' rows, got '3,4'"),
        (["--sources", "missing.csv"], r"expected --sources as an existing \.csv file of 'x,y,z' rows, got '.*missing\.csv' \(no such file\)"),
        (["--sources", "boundary", "--grid", "16"], r"expected --grid N and --grid-output FILE together, got only --grid"),
        (["--sources", "boundary", "--max-volume", "-1"], r"expected max_volume > 0 \(or None\), got -1\.0"),
        (["--sources", "boundary", "--max-edge", "0"], r"expected --max-edge as a length > 0, got 0\.0"),
    ],
)
def test_cli_volume_bad_input(tmp_path, capsys, extra, message):
    V, F = _sphere(1)
    trimesh.Trimesh(V, F, process=False).export(tmp_path / "ball.stl")
    extra = [str(tmp_path / e) if e == "missing.csv" else e for e in extra]
    code = main(["volume", str(tmp_path / "ball.stl"), "--output", str(tmp_path / "u.vtu"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("warp-regdist: error: ") and sum("error" in line for line in err) == 1
    assert re.search(message, err[-1]), err


def test_cli_volume_open_surface_is_one_error_line(tmp_path, capsys):
    V, F = _sphere(1)
    trimesh.Trimesh(V, F[1:], process=False).export(tmp_path / "open.obj")
    code = main(["volume", str(tmp_path / "open.obj"), "--sources", "boundary", "--output", str(tmp_path / "u.vtu")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("warp-regdist: error: expected a closed (watertight) surface, got 3 boundary edges")
