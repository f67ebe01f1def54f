"""Pictures (render.render_distance) and exact isolines (contours.isolines)."""

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.output.contours import isolines
from warp_regdist.output.render import render_distance, view_rotation

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


def _sheet(nx, ny, width, z):
    """Flat rectangle [0, width] x [0, 1] at height z, nx x ny cells, two triangles each."""
    x, y = np.meshgrid(np.linspace(0.0, width, nx + 1), np.linspace(0.0, 1.0, ny + 1), indexing="xy")
    vertices = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    a = (j * (nx + 1) + i).ravel()
    k = nx + 1
    return vertices, np.concatenate([np.stack([a, a + 1, a + k + 1], 1), np.stack([a, a + k + 1, a + k], 1)])


def _dark_columns(rgb):
    """Number of separate vertical dark lines in an (h, w, 3) image block."""
    dark = (rgb.max(axis=2) < 0.3).mean(axis=0) > 0.5
    return int(np.count_nonzero(dark[1:] & ~dark[:-1]) + dark[0])


def test_the_depth_test_hides_isolines_behind_a_nearer_surface(tmp_path, monkeypatch):
    # A far 2 x 1 sheet with u = x and isolines at x = 0.1, 0.2, ..., 1.9, and in front of
    # its left half a 1 x 1 sheet at the top of the colour map (u = 3), seen head-on. The
    # near sheet must cover the far one's left half and every isoline behind it.
    import matplotlib.image

    import warp_regdist.output.render as render

    far_v, far_f = _sheet(16, 8, 2.0, 0.0)
    toward_camera = view_rotation(np.concatenate([far_v, [[0.0, 0.0, 0.5]]]), 0.0, 0.0)[2, 2]
    near_v, near_f = _sheet(8, 8, 1.0, 0.5 * np.sign(toward_camera))
    mesh = wrd.Mesh(np.concatenate([far_v, near_v]), np.concatenate([far_f, near_f + len(far_v)]))
    values = np.concatenate([far_v[:, 0], np.full(len(near_v), 3.0)])

    def draw(name):
        path = tmp_path / name
        render_distance(mesh, values, path, isolines=np.linspace(0.1, 1.9, 19), view=(0.0, 0.0))
        return matplotlib.image.imread(path)[..., :3]

    rgb = draw("occluded.png")
    yellow = (rgb[..., 0] > 0.6) & (rgb[..., 1] > 0.6) & (rgb[..., 2] < 0.35)  # viridis' top: the near sheet
    rows, cols = np.nonzero(yellow[:, :rgb.shape[1] * 2 // 3])  # the mesh panel, not the colour bar
    r0, r1, c0, c1 = rows.min() + 3, rows.max() - 3, cols.min() + 3, cols.max() - 3
    assert c1 - c0 > 200 and r1 - r0 > 200
    assert yellow[r0:r1, c0:c1].mean() > 0.95  # the near sheet is painted over the far one
    assert _dark_columns(rgb[r0:r1, c0:c1]) == 0  # no isoline shows through it
    right = rgb[r0:r1, c1 + 6:c1 + 6 + (c1 - c0)]  # the far sheet's visible half, x in (1, 2)
    assert 9 <= _dark_columns(right) <= 10  # its isolines at 1.1 ... 1.9 (and 1.0 on the edge)
    # the same picture without the depth test: the hidden isolines appear over the near sheet
    monkeypatch.setattr(render, "_visible", lambda ax, buffer, xy, code_min: np.ones(len(xy), dtype=bool))
    assert _dark_columns(draw("no_depth_test.png")[r0:r1, c0:c1]) >= 9


def _pixels(path):
    import matplotlib.image as mpimg

    return mpimg.imread(path)[..., :3]


def _marked(image):
    """Pixels of the red that marks sources and curves (#e41a1c)."""
    return int((np.abs(image - np.array([228, 26, 28]) / 255).max(axis=2) < 0.04).sum())


@pytest.fixture(scope="module")
def picture_inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pictures")
    s = trimesh.creation.icosphere(subdivisions=3)
    s.export(folder / "sphere.off")
    t = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    np.savetxt(folder / "loop.csv", np.stack([np.cos(t), np.sin(t), 0.0 * t], axis=1), delimiter=",")
    np.savetxt(folder / "point.csv", [[0.3, 0.3, 0.9]], delimiter=",")
    np.savetxt(folder / "cloud.xyz", s.vertices)
    return folder


def test_a_signed_distance_picture_diverges_around_zero_and_draws_its_curve(picture_inputs, tmp_path):
    from warp_regdist.cli import main

    png = tmp_path / "signed.png"
    assert main(["distance", str(picture_inputs / "sphere.off"), "--curve", str(picture_inputs / "loop.csv"),
                 "--closed", "--output", str(tmp_path / "u.npy"), "--png", str(png), "--quiet"]) == 0
    image = _pixels(png)
    reds = ((image[..., 0] > 0.6) & (image[..., 2] < 0.35)).sum()
    blues = ((image[..., 2] > 0.45) & (image[..., 0] < 0.3)).sum()
    assert reds > 20_000 and blues > 20_000          # both signs, in two hues
    assert _marked(image) > 2_000                    # the curve


def test_point_sources_and_point_clouds_are_marked_and_clouds_have_no_holes(picture_inputs, tmp_path):
    from warp_regdist.cli import main

    for name, args in (("point", ["sphere.off", "--sources", str(picture_inputs / "point.csv")]),
                       ("cloud", ["cloud.xyz", "--sources", "0"])):
        png = tmp_path / f"{name}.png"
        assert main(["distance", str(picture_inputs / args[0]), *args[1:], "--output", str(tmp_path / "u.npy"),
                     "--png", str(png), "--quiet"]) == 0
        image = _pixels(png)
        assert _marked(image) > 50, name
        shape = (image[:, :690] < 0.97).any(axis=2)    # the first view, 4.6 in at 150 dpi
        ys, xs = np.nonzero(shape)
        cy, cx, hy, hx = (ys.min() + ys.max()) // 2, (xs.min() + xs.max()) // 2, np.ptp(ys) // 5, np.ptp(xs) // 5
        assert shape[cy - hy:cy + hy, cx - hx:cx + hx].mean() > 0.98, name   # covered, not speckled
