"""Bad inputs give a wrd.MeshError / ValueError whose message names the problem, and
load_mesh keeps the file's vertices exactly as written (order, duplicates, unused ones)."""

import os
import re
import warnings

import numpy as np
import pytest

import warp_regdist as wrd

TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    """Work in a fresh directory, so that file names are bare: the regexes below must
    match the message itself, not a directory named after the test."""
    monkeypatch.chdir(tmp_path)


def _write(ext, text):
    """Write ``mesh.<ext>`` (a neutral name that no pattern matches); return the name."""
    name = f"mesh.{ext}"
    with open(name, "wb") as f:
        f.write(text if isinstance(text, bytes) else text.encode())
    return name


def test_mesh_error_is_a_value_error():
    assert issubclass(wrd.MeshError, ValueError)


# ------------------------------------------------------------------ files


def test_missing_file(in_tmp):
    with pytest.raises(wrd.MeshError, match=r"(?i)no such file|not exist|exist|not found"):
        wrd.load_mesh("mesh.obj")


@pytest.mark.parametrize("ext", ["obj", "off", "ply", "stl"])
def test_garbage_file(in_tmp, ext):
    data = np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8).tobytes()
    path = _write(ext, data)
    with pytest.raises(wrd.MeshError, match=r"(?i)read|pars|format|invalid|corrupt|vert|face"):
        wrd.load_mesh(path)


@pytest.mark.parametrize(
    "ext, text",
    [
        ("off", "hello world\nthis is not a mesh\n"),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n"),  # truncated
        ("obj", ""),
    ],
)
def test_unreadable_file(in_tmp, ext, text):
    with pytest.raises(wrd.MeshError, match=r"(?i)read|pars|format|invalid|vert|face|empty"):
        wrd.load_mesh(_write(ext, text))


def test_unsupported_extension(in_tmp):
    path = _write("xyz", "0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(wrd.MeshError, match=r"(?i)format|extension|suffix|\.obj|type"):
        wrd.load_mesh(path)


def test_file_without_faces(in_tmp):
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(wrd.MeshError, match=r"(?i)face|triangle|element"):
        wrd.load_mesh(path)


@pytest.mark.parametrize(
    "ext, text",
    [
        ("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n"),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n"),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n"),  # negative
    ],
)
def test_file_with_bad_face_index(in_tmp, ext, text):
    with pytest.raises(wrd.MeshError, match=r"(?i)index|range|bound"):
        wrd.load_mesh(_write(ext, text))


def test_file_with_nan_coordinate(in_tmp):
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(wrd.MeshError, match=r"(?i)finite|nan"):
        wrd.load_mesh(path)


def test_quads_are_triangulated_or_refused(in_tmp):
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nf 1 2 3 4\nf 2 5 6 3\n"
    path = _write("obj", text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mesh = wrd.load_mesh(path)
    except wrd.MeshError as exc:
        assert any(w in str(exc).lower() for w in ("polygon", "quad", "triang", "corner"))
        return
    assert mesh.n_vertices == 6 and mesh.n_elements == 4
    assert np.array_equal(mesh.vertices, np.loadtxt(text.splitlines()[:6], usecols=(1, 2, 3)))
    # the four triangles tile the 2 x 1 rectangle
    P = mesh.vertices[mesh.faces]
    areas = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    assert areas.sum() == pytest.approx(2.0) and areas.min() > 0


# vertices as written: vertex 5 duplicates vertex 1's position, vertex 2 is unused
ORDER_V = np.array(
    [[0, 0, 0], [1, 0, 0], [5, 5, 5], [0, 1, 0], [1, 1, 0], [1, 0, 0]], dtype=np.float64
)
ORDER_F = np.array([[0, 1, 3], [5, 4, 3]])
ORDER_FILES = {
    "obj": "".join(f"v {x:g} {y:g} {z:g}\n" for x, y, z in ORDER_V)
    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in ORDER_F),
    "off": f"OFF\n{len(ORDER_V)} {len(ORDER_F)} 0\n"
    + "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in ORDER_V)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in ORDER_F),
    "ply": "ply\nformat ascii 1.0\n"
    + f"element vertex {len(ORDER_V)}\nproperty float x\nproperty float y\nproperty float z\n"
    + f"element face {len(ORDER_F)}\nproperty list uchar int vertex_indices\nend_header\n"
    + "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in ORDER_V)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in ORDER_F),
}


@pytest.mark.parametrize("ext", sorted(ORDER_FILES))
def test_load_mesh_keeps_vertex_order(in_tmp, ext):
    path = _write(ext, ORDER_FILES[ext])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a pure triangle file is no reason for a warning
        mesh = wrd.load_mesh(path)
    assert mesh.n_vertices == 6
    assert mesh.vertices.dtype == np.float64
    assert np.array_equal(mesh.vertices, ORDER_V)
    assert np.array_equal(mesh.faces, ORDER_F)
    assert mesh.faces.dtype == np.int64


def test_obj_negative_relative_indices(in_tmp):
    # in OBJ, index -1 means the last vertex written so far (valid, not an error)
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = wrd.load_mesh(path)
    assert np.array_equal(mesh.faces, [[0, 1, 2]])


# ------------------------------------------------------------------ arrays


def test_valid_arrays():
    mesh = wrd.Mesh(SQUARE.tolist(), SQUARE_F.tolist())
    assert mesh.n_vertices == 4 and mesh.n_elements == 2 and mesh.element_dim == 2
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    assert np.array_equal(wrd.boundary_vertices(mesh), [0, 1, 2, 3])


def test_no_faces():
    with pytest.raises(wrd.MeshError, match=r"(?i)face|element|triangle"):
        wrd.Mesh(TRIANGLE, np.zeros((0, 3), dtype=np.int64))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates(bad):
    V = SQUARE.copy()
    V[2, 1] = bad
    with pytest.raises(wrd.MeshError, match=r"(?i)finite|nan|inf"):
        wrd.Mesh(V, SQUARE_F)


def test_face_index_out_of_range():
    with pytest.raises(wrd.MeshError, match=r"(?i)index|range|bound"):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, 4]])


def test_negative_face_index():
    with pytest.raises(wrd.MeshError, match=r"(?i)index|range|negative|bound"):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, -1]])


def test_zero_area_face():
    V = np.concatenate([SQUARE, [[2.0, 0.0, 0.0]]])  # vertex 4 is collinear with 0 and 1
    with pytest.raises(wrd.MeshError, match=r"(?i)degenerate|zero.area|area"):
        wrd.Mesh(V, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])


def test_repeated_vertex_in_face():
    with pytest.raises(wrd.MeshError, match=r"(?i)degenerate|distinct|repeat|duplicate"):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, 2]])


def test_non_manifold_edge():
    V = np.concatenate([SQUARE, [[0.5, 0.5, 1.0]]])
    F = [[0, 1, 2], [0, 2, 3], [0, 2, 4]]  # edge (0, 2) in three faces
    with pytest.raises(wrd.MeshError, match=r"(?i)manifold|edge"):
        wrd.Mesh(V, F)


@pytest.mark.parametrize(
    "V, F, pattern",
    [
        (SQUARE[:, :2], SQUARE_F, r"(?i)shape|vert|\(n, ?3\)"),
        (SQUARE.ravel(), SQUARE_F, r"(?i)shape|vert|\(n, ?3\)"),
        (SQUARE, SQUARE_F[:, :2], r"(?i)shape|face|element|\(m, ?3\)"),
        (SQUARE, SQUARE_F.ravel(), r"(?i)shape|face|element|\(m, ?3\)"),
        (SQUARE, np.zeros((2, 5), dtype=np.int64), r"(?i)shape|face|element|\(m, ?3\)"),
        (SQUARE, SQUARE_F + 0.5, r"(?i)integer|int|index"),
    ],
)
def test_wrong_array_shapes_and_types(V, F, pattern):
    with pytest.raises(wrd.MeshError, match=pattern):
        wrd.Mesh(V, F)


# ------------------------------------------------------------------ solver arguments


@pytest.fixture(scope="module")
def square_solver():
    return wrd.DistanceSolver(wrd.Mesh(SQUARE, SQUARE_F), alpha_hat=0.05, device="cpu")


@pytest.mark.parametrize("sources", [[4], [0, 7], [-1], [2, -5]])
def test_source_index_out_of_range(square_solver, sources):
    with pytest.raises(ValueError, match=r"(?i)range|index|\[0, 3\]"):
        square_solver.solve(sources)


def test_empty_source_set(square_solver):
    with pytest.raises(ValueError, match=r"(?i)empty|none|at least|no source"):
        square_solver.solve([])
    with pytest.raises(ValueError, match=r"(?i)empty|none|at least|no source"):
        square_solver.solve_many([[0], []])
    with pytest.raises(ValueError, match=r"(?i)empty|none|at least|no source"):
        square_solver.solve_many([])


@pytest.mark.parametrize("sources", [[1.5], [0, 2.25], ["a"], "0", [None], [True]])
def test_non_integer_sources(square_solver, sources):
    with pytest.raises(ValueError, match=r"(?i)integer|int|index|string"):
        square_solver.solve(sources)


@pytest.mark.parametrize("sources", [3, np.int64(3), None, [[0], [1, 2]]])
def test_scalar_or_nested_source_set(square_solver, sources):
    with pytest.raises(ValueError, match=r"expected source set 0 as a (flat )?list of vertex indices"):
        square_solver.solve(sources)
    with pytest.raises(ValueError, match=r"expected source set 0 as a list"):
        square_solver.solve_many([0, 1])  # one set per vertex is [[0], [1]]


@pytest.mark.parametrize("sources, shown", [([np.inf], "inf"), ([1e20], "1e+20"),
                                            (np.array([2**63 + 3], np.uint64), str(2**63 + 3))])
def test_out_of_range_error_shows_the_given_value(square_solver, sources, shown):
    with pytest.raises(ValueError, match=r"in \[0, 3\] in source set 0, got " + re.escape(shown)):
        square_solver.solve(sources)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(alpha_hat=True), r"expected a real alpha_hat"),
        (dict(alpha_hat="0.05"), r"expected a real alpha_hat"),
        (dict(alpha_hat=-0.1), r"(?i)alpha"),
        (dict(alpha_hat=np.nan), r"(?i)alpha"),
        (dict(dtype="float16"), r"(?i)dtype|float"),
        (dict(device="tpu"), r"(?i)device"),
    ],
)
def test_bad_solver_arguments(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        wrd.DistanceSolver(wrd.Mesh(SQUARE, SQUARE_F), **kwargs)


def test_obj_materials_and_groups_keep_the_files_numbering(in_tmp):
    # trimesh splits an OBJ by material and renumbers the vertices; the file's order must stay
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvn 0 0 1\no A\nusemtl a\nf 1/1/1 2/1/1 3/1/1\n"
            "o B\ng side\nusemtl b\ns 1\nf 2//1 4//1 3//1\nl 1 4\n")
    mesh = wrd.load_mesh(_write("obj", text))
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert np.array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])


def test_obj_negative_indices_are_relative_to_the_face_line(in_tmp):
    mesh = wrd.load_mesh(_write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 1 1 0\nf 2 -1 3\n"))
    assert np.array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])


def test_bytes_path(in_tmp):
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert wrd.load_mesh(os.fsencode(path)).n_elements == 1


def test_obj_index_zero_is_refused(in_tmp):
    with pytest.raises(wrd.MeshError, match="line 4: expected 1-based"):
        wrd.load_mesh(_write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"))


def test_stl_corners_merged_in_order_of_first_appearance(in_tmp):
    import trimesh

    sphere = trimesh.creation.icosphere(1)
    path = _write("stl", trimesh.exchange.stl.export_stl(sphere))
    mesh = wrd.load_mesh(path)
    assert mesh.n_vertices == 42 and mesh.n_elements == 80
    assert (mesh.components() == 0).all()
    corners = sphere.vertices[sphere.faces].reshape(-1, 3)  # the file's corner order
    _, first = np.unique(corners, axis=0, return_index=True)
    assert np.allclose(mesh.vertices, corners[np.sort(first)], atol=1e-6)
    assert np.allclose(mesh.vertices[mesh.faces], sphere.vertices[sphere.faces], atol=1e-6)
