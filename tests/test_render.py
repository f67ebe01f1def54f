"""Pictures (render.render_distance) and exact isolines (render.isolines)."""

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.contours import isolines
from warp_regdist.render import render_distance, view_rotation

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path):
    """(width, height) from the IHDR chunk of a PNG file."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


@pytest.fixture
def triangle():
    return wrd.Mesh(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([[0, 1, 2]]))


@pytest.fixture
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2)
    return wrd.Mesh(s.vertices, s.faces)


@pytest.fixture
def grid():
    """Open unit square in the plane z = 0, 8 x 8 cells, two triangles each."""
    k = 9
    x, y = np.meshgrid(np.linspace(0.0, 1.0, k), np.linspace(0.0, 1.0, k), indexing="xy")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(k * k)], axis=1)
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="xy")
    a = (j * k + i).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + k + 1], 1), np.stack([a, a + k + 1, a + k], 1)])
    return wrd.Mesh(vertices, faces)


def test_isolines_single_triangle_exact(triangle):
    # u = x + 2 y is linear, so the level sets are exact straight segments.
    values = np.array([0.0, 1.0, 2.0])
    segs = isolines(triangle, values, [0.5, 1.0, 1.5, 3.0])
    assert [s.shape for s in segs] == [(1, 2, 3), (1, 2, 3), (1, 2, 3), (0, 2, 3)]
    # Values increase to the left of each segment (seen from +z, the face normal).
    np.testing.assert_array_equal(segs[0][0], [[0.0, 0.25, 0.0], [0.5, 0.0, 0.0]])
    np.testing.assert_array_equal(segs[1][0], [[0.0, 0.5, 0.0], [1.0, 0.0, 0.0]])  # through vertex 1
    np.testing.assert_array_equal(segs[2][0], [[0.0, 0.75, 0.0], [0.5, 0.5, 0.0]])


def test_isolines_skip_unreachable_and_constant(triangle):
    assert isolines(triangle, [0.0, np.inf, 2.0], [0.5])[0].shape == (0, 2, 3)
    assert isolines(triangle, [1.0, 1.0, 1.0], [1.0])[0].shape == (0, 2, 3)


def test_isolines_lie_on_level_set(grid):
    x, y = grid.vertices[:, 0], grid.vertices[:, 1]
    values = 0.3 * x + 0.7 * y
    levels = [0.2, 0.55]
    for level, segs in zip(levels, isolines(grid, values, levels)):
        ends = segs.reshape(-1, 3)
        np.testing.assert_allclose(0.3 * ends[:, 0] + 0.7 * ends[:, 1], level, atol=1e-14)
        # The pieces add up to the chord of the level line across the unit square.
        length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1).sum()
        x0, x1 = max(0.0, (level - 0.7) / 0.3), min(1.0, level / 0.3)
        np.testing.assert_allclose(length, (x1 - x0) * np.hypot(1.0, 0.3 / 0.7), rtol=1e-12)
        # Gradient (0.3, 0.7) points to the left of every segment.
        d = segs[:, 1] - segs[:, 0]
        assert np.all(-d[:, 1] * 0.3 + d[:, 0] * 0.7 > 0)


def test_isolines_rejects_bad_values(triangle):
    with pytest.raises(ValueError, match="expected one value per vertex"):
        isolines(triangle, [0.0, 1.0], [0.5])


def test_view_rotation_is_a_rotation(sphere):
    r = view_rotation(sphere.vertices * [1.0, 3.0, 2.0], 35.0, 15.0)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(r), 1.0)
    # (0, 0): the longest axis (y) is horizontal, the middle one (z) up.
    r0 = view_rotation(sphere.vertices * [1.0, 3.0, 2.0], 0.0, 0.0)
    np.testing.assert_allclose(r0[:2], [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-12)


def test_render_closed_mesh(sphere, tmp_path):
    values = np.linalg.norm(sphere.vertices - sphere.vertices[0], axis=1)
    path = tmp_path / "sphere.png"
    render_distance(sphere, values, path, sources=[0], title="sphere")
    width, height = png_size(path)
    assert width > 1200 and 500 < height < width  # two views side by side


def test_render_open_mesh_with_unreachable(grid, tmp_path):
    values = np.linalg.norm(grid.vertices - grid.vertices[0], axis=1)
    values[grid.vertices[:, 0] > 0.7] = np.inf
    path = tmp_path / "grid.png"
    render_distance(grid, values, str(path), sources=np.array([0]), isolines=[0.25, 0.5], view=(0, 0), cmap="magma")
    width, height = png_size(path)
    assert 600 < width < 1200  # one view


def test_render_rejects_bad_input(sphere, tmp_path):
    values = np.zeros(len(sphere.vertices))
    with pytest.raises(ValueError, match="expected one value per vertex"):
        render_distance(sphere, values[:-1], tmp_path / "a.png")
    with pytest.raises(ValueError, match="expected source indices"):
        render_distance(sphere, values, tmp_path / "a.png", sources=[len(values)])
    with pytest.raises(ValueError, match="expected view"):
        render_distance(sphere, values, tmp_path / "a.png", view=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="expected isolines as a count >= 0"):
        render_distance(sphere, values, tmp_path / "a.png", isolines=-1)


def test_render_distance_refuses_tetrahedra(tmp_path):
    import warp_regdist as wrd

    tet = wrd.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2, 3]]))
    with pytest.raises(ValueError, match="expected a triangle mesh, got 1 tetrahedra"):
        render_distance(tet, np.zeros(4), tmp_path / "a.png")


def test_isolines_close_up_on_a_closed_surface(sphere):
    # Neighbouring faces compute the crossing on their shared edge bit for bit alike, so
    # on a closed surface every endpoint is shared by exactly two segments.
    values = sphere.vertices @ np.array([0.3, -0.5, 0.8]) + 0.1 * sphere.vertices[:, 0] ** 2
    for segs in isolines(sphere, values, [-0.6, 0.05, 0.4]):
        assert len(segs) > 10
        _, counts = np.unique(segs.reshape(-1, 3), axis=0, return_counts=True)
        assert np.all(counts == 2)
