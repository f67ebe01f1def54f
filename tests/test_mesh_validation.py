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
    with pytest.raises(wrd.MeshError, match=r"^expected an existing mesh file, got 'mesh\.obj' \(no such file\)$"):
        wrd.load_mesh("mesh.obj")


@pytest.mark.parametrize("ext, message", [
    ("obj", r"^expected faces in 'mesh\.obj', got none \(empty file, or a point cloud\)$"),  # no 'v' or 'f' lines
    ("off", r"^could not read mesh file 'mesh\.off': not a valid OFF file( \(.+\))?$"),
    ("ply", r"^could not read mesh file 'mesh\.ply': not a valid PLY file"),
    # trimesh decodes binary garbage as ASCII STL when a charset detector is installed (then no faces)
    ("stl", r"^(could not read mesh file 'mesh\.stl': not a valid STL file|expected faces in 'mesh\.stl', got none "
            r"\(empty file, or a point cloud\))$"),
])
def test_garbage_file(in_tmp, ext, message):
    data = np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8).tobytes()
    path = _write(ext, data)
    with pytest.raises(wrd.MeshError, match=message):
        wrd.load_mesh(path)


@pytest.mark.parametrize(
    "ext, text, message",
    [
        ("off", "hello world\nthis is not a mesh\n", r"^could not read mesh file 'mesh\.off': "),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n", r"^could not read mesh file 'mesh\.off': "),  # truncated
        ("obj", "", r"^expected faces in 'mesh\.obj', got none \(empty file, or a point cloud\)$"),
    ],
)
def test_unreadable_file(in_tmp, ext, text, message):
    with pytest.raises(wrd.MeshError, match=message):
        wrd.load_mesh(_write(ext, text))


def test_unsupported_extension(in_tmp):
    path = _write("xyz", "0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(wrd.MeshError, match=r"^expected a mesh file ending in \.obj, \.off, \.ply, \.stl, \.msh, \.vtk, "
                                             r"\.vtu or \.mesh, got 'mesh\.xyz'$"):
        wrd.load_mesh(path)


def test_file_without_faces(in_tmp):
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(wrd.MeshError, match=r"^expected faces in 'mesh\.obj', got none"):
        wrd.load_mesh(path)


OFF_INDEX = r"^could not read mesh file 'mesh\.off': .*face index outside the range of its vertices"


@pytest.mark.parametrize(
    "ext, text, message",
    [
        ("obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n",
         r"^expected element vertex indices in \[0, 2\], got \[0, 1, 6\] in element 0 \(1 elements out of range\)$"),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n", OFF_INDEX),
        ("off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n", OFF_INDEX),  # negative
    ],
)
def test_file_with_bad_face_index(in_tmp, ext, text, message):
    with pytest.raises(wrd.MeshError, match=message):
        wrd.load_mesh(_write(ext, text))


def test_file_with_nan_coordinate(in_tmp):
    path = _write("obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(wrd.MeshError, match=r"^expected finite vertex coordinates, got 1 vertices with NaN/inf \(first: vertex 2\)$"):
        wrd.load_mesh(path)


@pytest.mark.parametrize("ext, text", [
    ("obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nf 1 2 3 4\nf 2 5 6 3\n"),
    ("off", "OFF\n6 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n2 1 0\n4 0 1 2 3\n4 1 4 5 2\n"),
])
def test_quads_are_fan_triangulated_with_a_warning(in_tmp, ext, text):
    path = _write(ext, text)
    with pytest.warns(UserWarning, match=rf"^mesh\.{ext}: 2 polygon faces with more than 3 corners were triangulated$") as caught:
        mesh = wrd.load_mesh(path)
    assert [w.filename for w in caught] == [__file__]  # the warning points at the caller of load_mesh
    assert mesh.n_vertices == 6 and mesh.n_elements == 4
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]])
    # each quad cut along a diagonal into two triangles of its orientation (trimesh orders OFF's differently)
    turned = np.array([np.roll(f, -np.argmin(f)) for f in mesh.faces])
    assert sorted(turned.tolist()) == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]
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
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh = wrd.load_mesh(path)
    unused = f"{path}: 1 of 6 vertices are in no element (first: vertex 2): their distance is +inf"
    assert [str(w.message)[:68] for w in caught] == [unused[:68], "1 vertex lies where another vertex of the mesh lies "
                                                                  "(first: 1 and 5)"]  # and nothing else
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
    with pytest.raises(wrd.MeshError, match=r"^expected at least one face \(triangle\) or tetrahedron, got none$"):
        wrd.Mesh(TRIANGLE, np.zeros((0, 3), dtype=np.int64))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates(bad):
    V = SQUARE.copy()
    V[2, 1] = bad
    with pytest.raises(wrd.MeshError, match=r"^expected finite vertex coordinates, got 1 vertices with NaN/inf \(first: vertex 2\)$"):
        wrd.Mesh(V, SQUARE_F)


def test_face_index_out_of_range():
    with pytest.raises(wrd.MeshError, match=r"^expected element vertex indices in \[0, 3\], got \[0, 2, 4\] in element 1 "):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, 4]])


def test_negative_face_index():
    with pytest.raises(wrd.MeshError, match=r"^expected element vertex indices in \[0, 3\], got \[0, 2, -1\] in element 1 "):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, -1]])


def test_zero_area_face():
    V = np.concatenate([SQUARE, [[2.0, 0.0, 0.0]]])  # vertex 4 is collinear with 0 and 1
    with pytest.raises(wrd.MeshError, match=r"^expected non-degenerate elements, got 1 zero-area face\(s\) "
                                             r"\(first: face 2 = \[0, 1, 4\]\); load_mesh\(path, repair=True\) or "
                                             r"warp_regdist.repair_mesh\(vertices, faces\) drops them$"):
        wrd.Mesh(V, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])


def test_repeated_vertex_in_face():
    with pytest.raises(wrd.MeshError, match=r"^expected distinct vertices in every element, got element 1 = \[0, 2, 2\]"):
        wrd.Mesh(SQUARE, [[0, 1, 2], [0, 2, 2]])


def test_a_non_manifold_edge_is_accepted():
    V = np.concatenate([SQUARE, [[0.5, 0.5, 1.0]]])
    F = [[0, 1, 2], [0, 2, 3], [0, 2, 4]]  # edge (0, 2) in three faces: the operators need no manifold
    mesh = wrd.Mesh(V, F)
    assert mesh.n_elements == 3 and mesh.components().tolist() == [0] * 5


ELEMENT_SHAPE = r"^expected elements of shape \(m, 3\) \(triangles\) or \(m, 4\) \(tetrahedra\), got shape "


@pytest.mark.parametrize(
    "V, F, pattern",
    [
        (SQUARE[:, :2], SQUARE_F, r"^expected vertices of shape \(n, 3\) with n >= 1, got shape \(4, 2\)$"),
        (SQUARE.ravel(), SQUARE_F, r"^expected vertices of shape \(n, 3\) with n >= 1, got shape \(12,\)$"),
        (SQUARE, SQUARE_F[:, :2], ELEMENT_SHAPE + r"\(2, 2\)$"),
        (SQUARE, SQUARE_F.ravel(), ELEMENT_SHAPE + r"\(6,\)$"),
        (SQUARE, np.zeros((2, 5), dtype=np.int64), ELEMENT_SHAPE + r"\(2, 5\)$"),
        (SQUARE, SQUARE_F + 0.5, r"^expected integer vertex indices in the elements, got dtype float64$"),
    ],
)
def test_wrong_array_shapes_and_types(V, F, pattern):
    with pytest.raises(wrd.MeshError, match=pattern):
        wrd.Mesh(V, F)


# ------------------------------------------------------------------ solver arguments


@pytest.fixture(scope="module")
def square_solver():
    return wrd.DistanceSolver(wrd.Mesh(SQUARE, SQUARE_F), alpha_hat=0.05, device="cpu")


@pytest.mark.parametrize("sources, shown", [([4], "4"), ([0, 7], "7"), ([-1], "-1"), ([2, -5], "-5")])
def test_source_index_out_of_range(square_solver, sources, shown):
    with pytest.raises(ValueError, match=rf"^expected source vertex indices in \[0, 3\] in source set 0, got {shown}$"):
        square_solver.solve(sources)


def test_empty_source_set(square_solver):
    with pytest.raises(ValueError, match=r"^expected at least one source vertex in source set 0, got none$"):
        square_solver.solve([])
    with pytest.raises(ValueError, match=r"^expected at least one source vertex in source set 1, got none$"):
        square_solver.solve_many([[0], []])
    with pytest.raises(ValueError, match=r"^expected at least one source set, got none$"):
        square_solver.solve_many([])


@pytest.mark.parametrize("sources, shown", [([1.5], r"\[1\.5\]"), ([0, 2.25], r"\[0\.0, 2\.25\]"), (["a"], r"\['a'\]"),
                                             ([None], r"\[None\]"), ([True], r"\[True\]")])
def test_non_integer_sources(square_solver, sources, shown):
    with pytest.raises(ValueError, match=rf"^expected integer vertex indices in source set 0, got {shown}$"):
        square_solver.solve(sources)


def test_a_string_is_not_a_source_set(square_solver):
    with pytest.raises(ValueError, match=r"^expected source set 0 as vertex indices, got the string '0'$"):
        square_solver.solve("0")


@pytest.mark.parametrize("sources", [3, np.int64(3), [[0], [1, 2]]])
def test_scalar_or_nested_source_set(square_solver, sources):
    with pytest.raises(ValueError, match=r"expected source set 0 as a (flat )?list of vertex indices"):
        square_solver.solve(sources)
    with pytest.raises(ValueError, match=r"expected source set 0 as a list"):
        square_solver.solve_many([0, 1])  # one set per vertex is [[0], [1]]


def test_no_sources(square_solver):
    with pytest.raises(ValueError, match=r"^expected sources, points or a curve, got none$"):
        square_solver.solve(None)


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


def test_mesh_arrays_are_read_only_copies_and_derived_data_is_kept():
    V, F = SQUARE.copy(), SQUARE_F.copy()
    mesh = wrd.Mesh(V, F)
    V[0, 0] = 5.0  # the caller's arrays stay theirs
    assert mesh.vertices[0, 0] == 0.0
    for array in (mesh.vertices, mesh.elements, mesh.element_volumes, mesh.components()):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1
    with pytest.raises(AttributeError):
        mesh.vertices = V
    assert mesh.components() is mesh.components()
    assert np.array_equal(mesh.element_volumes, [0.5, 0.5])  # two halves of the unit square
    import pickle

    copy = pickle.loads(pickle.dumps(mesh))  # as sent to worker processes
    assert not copy.vertices.flags.writeable and np.array_equal(copy.components(), [0, 0, 0, 0])


def test_tetrahedron_volumes_and_row_keys_beyond_int64():
    from warp_regdist.geometry.mesh import _row_keys

    cube = wrd.Mesh(np.array([[0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, 4.0]]), [[0, 1, 2, 3]])
    assert cube.element_volumes.tolist() == pytest.approx([4.0], rel=1e-14)  # 2 * 3 * 4 / 6
    rows = np.array([[2**40, 1, 7], [3, 2**40, 7], [2**40, 1, 7]])  # (2^40 + 1)^3 overflows int64
    keys = _row_keys(rows)
    assert keys[0] == keys[2] != keys[1]
    assert np.array_equal(_row_keys(np.array([[1, 2], [2, 1], [1, 2]])), [5, 7, 5])  # base 3: 1*3 + 2, 2*3 + 1
