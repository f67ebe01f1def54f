"""The vector-field and Hessian regularizers (docs/method.md section 3) against independent solutions.

The conic reference (tests/reference_solver.py, cvxpy + Clarabel) gets the regularizer
matrix assembled here, independently of warp_regdist: W_V from the reference's own
gradient matrices, W_H straight from libigl's ``curved_hessian_energy``. Why a wrong
implementation fails: the Dirichlet minimizer differs from the beta = 10 one by 57% of
the maximum on the sheet below, and from the Hessian one by 8% (square with a hole) and
277% (sphere), 80x to 2800x the tolerance 1e-3; with alpha = alpha_hat sqrt(A) instead of
A^(3/2) the Hessian problem is not scale-covariant (alpha would grow 10x instead of 1000x
with the mesh x10).
"""

import igl
import numpy as np
import pytest
import scipy.sparse as sp

import meshes
import reference_solver as rs
from same_run import assert_same_run
import warp_regdist as wrd
from conftest import TIGHT


def _sheet():
    V, F = meshes.square_grid(18, 2.0)  # 324 vertices, curved, with boundary
    V[:, 2] = 0.25 * np.sin(2.0 * V[:, 0]) * np.cos(3.0 * V[:, 1])
    return V, F


def _tangent_field(V, F, direction):
    """The constant ``direction`` projected to every face's plane, shape (m, 3) (not normalized)."""
    _, N = rs.face_geometry(V, F)
    d = np.asarray(direction, dtype=np.float64)
    return d - (N @ d)[:, None] * N


def _relative_error(u, expected):
    return np.abs(u - expected).max() / expected.max()


def test_vector_field_matches_conic_solver(device):
    V, F = _sheet()
    field = _tangent_field(V, F, [1.0, 1.0, 0.0])
    beta = 10.0
    areas, _ = rs.face_geometry(V, F)
    G = rs.gradient_matrices(V, F)
    M = sp.diags(areas)
    along = sum(sp.diags(field[:, c]) @ G[c] for c in range(3))          # (V_f . (G u)_f) per face
    W = sum(G[c].T @ M @ G[c] for c in range(3)) + beta * along.T @ M @ along
    sources = [0, 170]
    expected = rs.solve_reference(V, F, sources, 0.05 * np.sqrt(areas.sum()), W=W, triangulation="mesh")  # its field
    res = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, regularizer="vector_field", beta_hat=beta,
                             vector_field=field, device=device, options=TIGHT).solve(sources)
    assert res.converged
    assert _relative_error(res.distance, expected) <= 1e-3


@pytest.mark.parametrize("surface", ["square_with_hole", "sphere"])
def test_hessian_matches_conic_solver(device, surface):
    # Flat and round meshes: there libigl's curved Hessian energy is positive semi-definite
    # (on the bumpy sheet it has two eigenvalues near -6e-3, a non-convex problem a conic
    # solver cannot take).
    if surface == "sphere":
        V, F = meshes.icosphere(2)                  # 162 vertices
        sources = [5]
    else:
        V, F, _ = meshes.square_with_hole(18, 2.0)  # 288 vertices, two boundary loops
        sources = [0]
    areas, _ = rs.face_geometry(V, F)
    # the square's quads are cocircular: every triangulation of them is Delaunay, the mesh's own is used
    tri = "mesh" if surface == "square_with_hole" else "intrinsic"
    expected = rs.solve_reference(V, F, sources, 0.05 * areas.sum() ** 1.5, W=igl.curved_hessian_energy(V, F),
                                  triangulation=tri)
    res = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, regularizer="hessian", device=device, options=TIGHT,
                             triangulation=tri).solve(sources)
    assert res.converged
    assert _relative_error(res.distance, expected) <= 1e-3


def test_isolines_turn_toward_the_field_as_beta_grows(device):
    # Flat unit square, sources on the left edge, constant field at 45 degrees. At beta = 0
    # the distance is x (isolines vertical, 45 degrees to the field); the alignment term
    # penalizes the gradient's component along the field, so the isolines (orthogonal to the
    # gradient) turn toward it: the area-weighted mean |cos| of the angle between grad u and
    # the field falls from 0.707 to 0.60 (beta 10), 0.21 (100).
    V, F = meshes.square_grid(21, 1.0)
    mesh = wrd.Mesh(V, F)
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    field = np.tile(d, (len(F), 1))
    left = np.flatnonzero(V[:, 0] == 0.0)
    ops = wrd.build_operators(mesh)
    cosines = []
    for beta in (0.0, 10.0, 100.0):
        u = wrd.DistanceSolver(mesh, alpha_hat=0.05, regularizer="vector_field", beta_hat=beta,
                               vector_field=field, device=device).solve(left).distance
        g = (ops.grad @ u).reshape(-1, 3)
        c = np.abs(g @ d) / np.linalg.norm(g, axis=1)
        cosines.append(np.sum(ops.element_volumes * c) / ops.element_volumes.sum())
    assert abs(cosines[0] - np.sqrt(0.5)) < 0.01
    assert cosines[1] < cosines[0] - 0.05
    assert cosines[2] < cosines[1] - 0.2


def test_hessian_distance_ignores_a_hole(device):
    # The paper's Fig. 1e: distance from a corner of the unit square, with and without a
    # hole of side 0.4 in the middle. Both regularizers must bend around the hole (|grad u|
    # <= 1), but the Dirichlet distance also bends its isolines toward the new boundary
    # (natural boundary condition du/dn = 0). Measured: max difference on the common
    # vertices 11.5% (Dirichlet) vs 2.2% (Hessian) of the maximal distance, ratio 0.19.
    V, F = meshes.square_grid(21, 1.0)
    Vh, Fh, kept = meshes.square_with_hole(21, 1.0, 0.4)
    diff = {}
    for regularizer in ("dirichlet", "hessian"):
        full = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, regularizer=regularizer, device=device).solve([0])
        hole = wrd.DistanceSolver(wrd.Mesh(Vh, Fh), alpha_hat=0.05, regularizer=regularizer, device=device).solve([0])
        assert full.converged and hole.converged
        diff[regularizer] = np.abs(full.distance[kept] - hole.distance).max() / full.distance.max()
    assert diff["dirichlet"] > 0.08
    assert diff["hessian"] < 0.3 * diff["dirichlet"]


def test_hessian_distance_scales_with_the_mesh(device):
    # alpha = alpha_hat A^(3/2) makes the problem scale-covariant: mesh x10 -> distance x10.
    V, F = meshes.icosphere(2)
    u1 = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, regularizer="hessian", device=device).solve([5])
    u10 = wrd.DistanceSolver(wrd.Mesh(10.0 * V, F), alpha_hat=0.05, regularizer="hessian", device=device).solve([5])
    assert np.abs(u10.distance - 10.0 * u1.distance).max() <= 1e-3 * 10.0 * u1.distance.max()


# ---------------------------------------------------------------- validation

_V, _F = meshes.square_grid(3, 1.0)
_FIELD = np.tile([1.0, 0.0, 0.0], (len(_F), 1))


@pytest.mark.parametrize("kwargs, message", [
    (dict(regularizer="laplacian"), "expected regularizer among"),
    (dict(regularizer="vector_field"), "expected a vector_field"),
    (dict(regularizer="vector_field", vector_field=_FIELD[:-1]), r"expected vector_field of shape \(8, 3\)"),
    (dict(regularizer="vector_field", vector_field=np.where(np.eye(8, 3) > 0, np.nan, _FIELD)),
     "expected a finite vector_field"),
    (dict(regularizer="vector_field", vector_field=_FIELD, beta_hat=-1.0), "expected a finite beta_hat >= 0"),
    (dict(regularizer="vector_field", vector_field=_FIELD, beta_hat="big"), "expected a real beta_hat"),
    (dict(regularizer="dirichlet", beta_hat=2.0), "expected beta_hat only with regularizer 'vector_field'"),
    (dict(regularizer="hessian", vector_field=_FIELD), "expected vector_field only with"),
    (dict(regularizer="vector_field", vector_field=1e200 * _FIELD), r"expected vector_field components <= 1e6"),
    (dict(regularizer="vector_field", vector_field=_FIELD + 1j), "expected vector_field as a real"),
])
def test_bad_regularizer_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        wrd.DistanceSolver(wrd.Mesh(_V, _F), alpha_hat=0.05, device="cpu", **kwargs)


def test_hessian_with_an_unreferenced_vertex(device):
    # libigl sizes W_H by the largest referenced vertex; the extra vertex gets +inf
    V = np.vstack([_V, [[9.0, 9.0, 9.0]]])
    res = wrd.DistanceSolver(wrd.Mesh(V, _F), alpha_hat=0.05, regularizer="hessian", device=device).solve([0])
    assert np.isinf(res.distance[-1]) and np.all(np.isfinite(res.distance[:-1])) and res.converged


@pytest.mark.parametrize("fade", [True, 0.0, float("nan"), "1"])
def test_line_field_bad_fade(fade):
    with pytest.raises(ValueError, match="expected fade as a finite number > 0 or None"):
        wrd.line_field(wrd.Mesh(_V, _F), [0], [[1.0, 0.0, 0.0]], fade=fade)


def test_line_field_numpy_fade():
    mesh = wrd.Mesh(_V, _F)
    assert np.allclose(wrd.line_field(mesh, [0], [[1.0, 0.0, 0.0]], fade=np.float32(0.5)),
                       wrd.line_field(mesh, [0], [[1.0, 0.0, 0.0]], fade=0.5), rtol=1e-6)


def test_hessian_on_tetrahedra_is_refused():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(ValueError, match="expected a triangle mesh for regularizer 'hessian'"):
        wrd.DistanceSolver(wrd.Mesh(V, np.array([[0, 1, 2, 3]])), regularizer="hessian", device="cpu")


def test_batched_columns_equal_single_solves_with_the_vector_field(device):
    # rho is shared by the columns, so the replaced u-step matrix serves all of them
    V, F = _sheet()
    solver = wrd.DistanceSolver(wrd.Mesh(V, F), alpha_hat=0.05, regularizer="vector_field",
                                vector_field=_tangent_field(V, F, [1.0, 0.0, 0.0]), device=device)
    many = solver.solve_many([[0], [170, 17]])
    for j, sources in enumerate(([0], [170, 17])):
        single = solver.solve(sources)
        assert many.iterations[j] == single.iterations
        assert_same_run(many.distance[:, j], single.distance, device)


def test_cli_vector_field_from_a_directions_csv(tmp_path, capsys):
    from warp_regdist.cli import main

    V, F = _sheet()
    mesh_path, csv_path, out = tmp_path / "sheet.off", tmp_path / "dirs.csv", tmp_path / "u.npy"
    with open(mesh_path, "w") as f:
        f.write(f"OFF\n{len(V)} {len(F)} 0\n")
        f.writelines(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in V)
        f.writelines(f"3 {a} {b} {c}\n" for a, b, c in F)
    csv_path.write_text("# face,dx,dy,dz\n5,1,1,0\n400,0,1,0\n")
    argv = ["distance", mesh_path, "--sources", "0", "--output", out, "--regularizer", "vector_field",
            "--beta-hat", "20", "--directions", csv_path, "--device", "cpu", "--quiet"]
    assert main([str(a) for a in argv]) == 0
    mesh = wrd.Mesh(V, F)
    field = wrd.line_field(mesh, [5, 400], [[1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    expected = wrd.DistanceSolver(mesh, alpha_hat=0.05, regularizer="vector_field", beta_hat=20.0,
                                  vector_field=field, device="cpu").solve([0]).distance
    np.testing.assert_allclose(np.load(out), expected, rtol=0, atol=1e-12)
    without_directions = argv[:argv.index("--directions")] + argv[argv.index("--directions") + 2:]
    assert main([str(a) for a in without_directions]) == 2
    assert "expected --directions FILE with --regularizer vector_field" in capsys.readouterr().err


@pytest.mark.parametrize("alpha_hat, factors", [(0.0, (0.5, 1.0, 2.0)), (0.01, (0.75, 1.0, 1.5)),
                                                (0.02, (1.0, 1.0, 1.0)), (0.05, (1.0, 1.0, 1.0))])
def test_penalty_schedule_slows_towards_alpha_zero(alpha_hat, factors):
    # Dirichlet and vector field on triangles: rho0 x (1 - t/2), doubling x (1 + t), t = 1 - alpha_hat / 0.02 (from
    # 0.02 up, 0); tetrahedra and the Hessian keep their own factors at every alpha_hat
    solver = wrd.DistanceSolver(wrd.Mesh(_V, _F), alpha_hat=alpha_hat, device="cpu")
    assert solver.regularizer.schedule_factors == pytest.approx(factors, abs=1e-12)
    field = wrd.DistanceSolver(wrd.Mesh(_V, _F), alpha_hat=alpha_hat, device="cpu", regularizer="vector_field",
                               vector_field=_FIELD)
    assert field.regularizer.schedule_factors == pytest.approx(factors, abs=1e-12)
    hessian = wrd.DistanceSolver(wrd.Mesh(_V, _F), alpha_hat=alpha_hat, device="cpu", regularizer="hessian")
    assert hessian.regularizer.schedule_factors == (1.0, 8.0, 1.0)
    tets = wrd.DistanceSolver(wrd.Mesh(*meshes.cube_tets(2)), alpha_hat=alpha_hat, device="cpu")   # no faster there
    assert tets.regularizer.schedule_factors == (1.0, 1.0, 1.0)
