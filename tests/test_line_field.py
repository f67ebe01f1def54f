"""Line-field design (warp_regdist/geometry/line_field.py) against exactly known fields.

On an intrinsically flat surface parallel transport has no holonomy, so the smoothest
field through one constraint is the parallel field through it, which the test meshes
let us write down: a constant direction on a flat square, a helix of constant pitch
angle on a cylinder (the unrolled cylinder is a flat strip, and every face's frame is
different, so a wrong transport angle or a missing angle doubling turns the field).
"""

import numpy as np
import pytest

import meshes
import warp_regdist as wrd
from warp_regdist.geometry.line_field import read_directions


def _normals(V, F):
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return c / np.linalg.norm(c, axis=1, keepdims=True)


def test_one_constraint_on_a_cylinder_gives_the_helix_through_it():
    V, F = meshes.cylinder(24, 10, 3.0)
    axis = np.array([0.0, 0.0, 1.0])
    around = np.cross(axis, _normals(V, F))          # horizontal, tangent to each (flat) face
    around /= np.linalg.norm(around, axis=1, keepdims=True)
    helix = np.cos(np.radians(30.0)) * axis + np.sin(np.radians(30.0)) * around
    f0 = 7
    field = wrd.line_field(wrd.Mesh(V, F), [f0], [-helix[f0]])  # sign-free: -d is the same line
    np.testing.assert_allclose(np.linalg.norm(field, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(field * helix, axis=1)), 1.0, atol=1e-9)


def test_constraints_are_met_exactly_and_the_field_is_tangent_and_unit():
    V, F = meshes.square_grid(12, 1.0)
    V[:, 2] = 0.2 * np.sin(3.0 * V[:, 0]) * V[:, 1]   # curved: constraints must be projected
    N = _normals(V, F)
    faces = np.array([3, 100, 150])
    directions = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [1.0, -1.0, 2.0]])
    field = wrd.line_field(wrd.Mesh(V, F), faces, directions)
    projected = directions - np.sum(directions * N[faces], axis=1, keepdims=True) * N[faces]
    projected /= np.linalg.norm(projected, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.sum(field[faces] * projected, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(field, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(field * N, axis=1), 0.0, atol=1e-12)
    # between the two flat-ish constraints at 0 and 90 degrees the field takes intermediate angles
    assert np.ptp(np.abs(field[:, 0])) > 0.9


def test_fade_is_a_gaussian_of_the_distance_to_the_constraints():
    V, F = meshes.square_grid(15, 2.0)
    field = wrd.line_field(wrd.Mesh(V, F), [0], [[1.0, 0.0, 0.0]], fade=0.3)
    # flat square, one constraint: the unit field is (1, 0, 0) everywhere; its length is
    # exp(-d^2 / (2 sigma^2)) with sigma = 0.3 sqrt(area 4) = 0.6 and d the mean corner
    # distance to the corners of face 0 (the exact geodesic distance is Euclidean on a
    # flat convex square)
    length = np.linalg.norm(field, axis=1)
    np.testing.assert_allclose(np.abs(field[:, 0]), length, atol=1e-12)
    assert length[0] == pytest.approx(1.0, abs=1e-12)
    corners = V[F[0]]
    d = np.mean(np.min(np.linalg.norm(V[F][:, :, None, :] - corners[None, None], axis=3), axis=2), axis=1)
    np.testing.assert_allclose(length, np.exp(-d * d / (2 * 0.6 ** 2)), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("faces, directions, fade, message", [
    ([3], [[0.0, 0.0, 1.0]], None, "expected directions with a component tangent to their face"),
    ([3, 3], [[1.0, 0, 0], [0, 1.0, 0]], None, "expected distinct constrained faces"),
    ([500], [[1.0, 0, 0]], None, r"expected face indices in \[0, 241\]"),
    ([3], [[1.0, 0, 0], [0, 1.0, 0]], None, r"expected directions of shape \(1, 3\)"),
    ([3], [[np.nan, 0, 0]], None, "expected finite directions"),
    ([], np.zeros((0, 3)), None, "expected a non-empty 1-d array of integer face indices"),
    ([3], [[1.0, 0, 0]], -1.0, "expected fade as a finite number > 0 or None"),
])
def test_bad_constraints_are_refused(faces, directions, fade, message):
    V, F = meshes.square_grid(12, 1.0)
    with pytest.raises(ValueError, match=message):
        wrd.line_field(wrd.Mesh(V, F), faces, directions, fade=fade)


def test_a_component_without_constraints_is_refused():
    V, F = meshes.square_grid(4, 1.0)
    V2 = np.concatenate([V, V + [5.0, 0.0, 0.0]])
    F2 = np.concatenate([F, F + len(V)])
    with pytest.raises(ValueError, match="expected a constrained face in every connected component"):
        wrd.line_field(wrd.Mesh(V2, F2), [0], [[1.0, 0.0, 0.0]])


def test_read_directions_from_npy_and_csv(tmp_path):
    V, F = meshes.square_grid(6, 1.0)
    mesh = wrd.Mesh(V, F)
    field = np.random.default_rng(1).normal(size=(len(F), 3))
    np.save(tmp_path / "field.npy", field)
    np.testing.assert_array_equal(read_directions(tmp_path / "field.npy", mesh), field)
    (tmp_path / "dirs.csv").write_text("# face,dx,dy,dz\n3,1,1,0\n40,0,1,0\n")
    np.testing.assert_array_equal(read_directions(str(tmp_path / "dirs.csv"), mesh),
                                  wrd.line_field(mesh, [3, 40], [[1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]))


@pytest.mark.parametrize("name, content, message", [
    ("dirs.txt", "3,1,0,0\n", r"^expected a directions file ending in \.npy or \.csv, got '.*dirs\.txt'$"),
    ("none.csv", None, r"^expected an existing directions file, got '.*none\.csv' \(no such file\)$"),
    ("dirs.csv", "3,1,0\n", r"^expected CSV rows 'face,dx,dy,dz', got 3 columns in '.*dirs\.csv'$"),
    ("dirs.csv", "", r"^expected CSV rows 'face,dx,dy,dz', got 0 columns in '.*dirs\.csv'$"),
    ("dirs.csv", "3,a,0,0\n", r"^expected CSV rows 'face,dx,dy,dz' of numbers, got unreadable rows in '.*dirs\.csv'$"),
    ("dirs.csv", "3.5,1,0,0\n", r"^expected integer face indices in the first column, got 3\.5 in '.*dirs\.csv'$"),
    ("dirs.npy", b"not an array", r"^expected a numeric \.npy array of shape \(elements, 3\), got an unreadable file "),
])
def test_read_directions_refuses_bad_files(tmp_path, name, content, message):
    V, F = meshes.square_grid(6, 1.0)
    if content is not None:
        (tmp_path / name).write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ValueError, match=message):
        read_directions(tmp_path / name, wrd.Mesh(V, F))
