"""Meshes as users have them: triangle-strip PLY files, and repair_mesh / load_mesh(repair=True) for
vertices at one position, degenerate faces, non-manifold edges and several components."""

import struct
import warnings

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.cli import main

GRID = np.array([[x, y, 0.0] for y in (0.0, 1.0) for x in (0.0, 1.0, 2.0, 3.0)])   # 0-3 bottom row, 4-7 top
STRIP = [0, 4, 1, 5, 2, 6, 3, 7]                                                 # up, down, up, down, ...


def _ply(path, vertices, strips, binary=True, normals=False):
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    head += ["property float nx", "property float ny", "property float nz"] if normals else []
    head += [f"element tristrips {len(strips)}", "property list int int vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode())
        for v in vertices:
            row = list(v) + ([0.0, 0.0, 1.0] if normals else [])
            f.write(struct.pack(f"<{len(row)}f", *row) if binary else (" ".join(map(str, row)) + "\n").encode())
        for s in strips:
            f.write(struct.pack(f"<i{len(s)}i", len(s), *s) if binary else (" ".join(map(str, [len(s)] + s)) + "\n").encode())


@pytest.mark.parametrize("binary", [True, False])
def test_triangle_strip_ply_is_read_with_its_orientation(tmp_path, binary):
    path = tmp_path / "strip.ply"
    _ply(path, GRID, [STRIP[:6] + [-1] + STRIP[4:]], binary=binary, normals=True)   # a restart: 4 + 2 triangles
    mesh = wrd.load_mesh(path)
    assert mesh.faces.tolist() == [[0, 4, 1], [1, 4, 5], [1, 5, 2], [2, 5, 6], [2, 6, 3], [3, 6, 7]]
    normals = np.cross(GRID[mesh.faces[:, 1]] - GRID[mesh.faces[:, 0]], GRID[mesh.faces[:, 2]] - GRID[mesh.faces[:, 0]])
    assert np.all(normals[:, 2] < 0)        # one orientation for every triangle of the strip


def _book():
    """Three pages on one spine (edge 0-1): a non-manifold edge; page 2 is also a zero-area sliver's
    neighbour and vertex 6 is a copy of vertex 2."""
    V = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0.5], [-1, 0, 0.5], [0, 1, 0.5], [0, 0, 0.5], [1, 0, 0.5]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 4, 1], [1, 5, 0]])   # the last: collinear, zero area
    return V, F


def test_repair_merges_drops_and_cuts_and_says_so():
    V, F = _book()
    with pytest.raises(wrd.MeshError, match=r"repair=True\) or warp_regdist\.repair_mesh\(vertices, faces\) drops them"):
        wrd.Mesh(V, F)
    mesh, done = wrd.repair_mesh(V, F[:3])
    assert (done.merged_vertices, done.dropped_faces, done.cut_edges, done.components) == (0, 0, 1, 2)
    assert str(done) == ("cut the mesh along 1 non-manifold edges (faces beyond a pair detached); "
                         "2 connected component(s)")     # the third page hung on the spine only
    assert mesh.n_elements == 3 and mesh.n_vertices == 7 + 2      # the detached page got copies of 0 and 1
    a, b = mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).T
    _, counts = np.unique(np.sort(np.stack([a, b], 1), axis=1), axis=0, return_counts=True)
    assert counts.max() == 2
    mesh, done = wrd.repair_mesh(V, np.vstack([F, [[6, 0, 3]]]))
    assert (done.merged_vertices, done.dropped_faces, done.cut_edges) == (1, 1, 1)
    assert mesh.input_index.tolist()[:7] == [0, 1, 2, 3, 4, 5, 2]


def test_a_repaired_duplicate_of_the_source_is_at_distance_zero(tmp_path, capsys):
    s = trimesh.creation.icosphere(subdivisions=2)
    V = np.vstack([s.vertices, s.vertices[[0]]])
    F = s.faces.copy()
    fan = np.flatnonzero((F == 0).any(axis=1))[:2]
    F[fan] = np.where(F[fan] == 0, len(V) - 1, F[fan])      # two faces of vertex 0 use its copy
    path = tmp_path / "seam.obj"
    with open(path, "w") as f:
        f.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
    with pytest.warns(wrd.MeshWarning, match=r"seam\.obj: merged 1 vertices into others at the same position; "
                                             r"1 connected component\(s\)"):
        mesh = wrd.load_mesh(path, repair=True)
    u = wrd.DistanceSolver(mesh, 0.05).solve([0]).distance[mesh.input_index]
    assert u.shape == (163,) and u[162] == 0.0 and u[0] == 0.0
    code, _, err = main(["distance", str(path), "--sources", "162", "--repair", "--output", str(tmp_path / "u.npy"),
                         "--quiet"]), *capsys.readouterr()
    assert code == 0 and "warp-regdist: warning:" in err and "merged 1 vertices" in err
    cli = np.load(tmp_path / "u.npy")
    assert cli.shape == (163,) and cli[0] == cli[162] == 0.0 and np.allclose(cli, u, atol=1e-12)


def test_the_command_line_names_repair_where_it_fixes_a_refusal(tmp_path, capsys):
    V, F = _book()
    path = tmp_path / "book.obj"
    with open(path, "w") as f:
        f.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F[:3])
        f.write("f 2 6 1\n")                                  # the zero-area face
    code = main(["distance", str(path), "--sources", "0", "--output", str(tmp_path / "u.npy")])
    err = capsys.readouterr().err
    assert code == 2 and err.strip().endswith("got 1 zero-area face(s) (first: face 3 = [1, 5, 0]); --repair drops them")
    assert main(["distance", str(path), "--sources", "0", "--repair", "--output", str(tmp_path / "u.npy"),
                 "--quiet"]) == 0
    assert np.load(tmp_path / "u.npy").shape == (7,)


def test_split_components_gives_each_component_as_a_mesh():
    a = trimesh.creation.icosphere(subdivisions=1)
    b = trimesh.creation.icosphere(subdivisions=2)
    V = np.vstack([[[9.0, 9.0, 9.0]], a.vertices, b.vertices + 5.0])       # vertex 0 in no face
    F = np.vstack([a.faces, b.faces + len(a.vertices)]) + 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parts = wrd.split_components(wrd.Mesh(V, F))
    assert [(m.n_vertices, idx[0]) for m, idx in parts] == [(162, 43), (42, 1)]
    assert np.array_equal(parts[0][0].vertices, V[43:205])
    with pytest.raises(ValueError, match=r"expected a connected mesh, got 2 connected components \(warp_regdist\."
                                         r"split_components\(mesh\) gives each"):
        wrd.AllPairsSolver(wrd.Mesh(V[1:], F - 1))


def _cracked_sphere(gap):
    """An icosphere (642 vertices) whose northern faces use copies of the 48 equator vertices, each moved
    ``gap`` (times the unit radius) in a random direction: a closed surface cracked along the equator."""
    s = trimesh.creation.icosphere(subdivisions=3)
    V, F = s.vertices, s.faces
    north = V[F].mean(axis=1)[:, 2] > 0
    equator = np.intersect1d(np.unique(F[north]), np.unique(F[~north]))
    offset = np.random.default_rng(0).standard_normal((len(equator), 3))
    copies = V[equator] + gap * offset / np.linalg.norm(offset, axis=1, keepdims=True)
    remap = np.arange(len(V))
    remap[equator] = len(V) + np.arange(len(equator))
    return s, np.vstack([V, copies]), np.where(north[:, None], remap[F], F)


@pytest.mark.parametrize("gap", [1e-15, 3e-5])
def test_a_crack_warns_on_loading_and_repair_welds_it(tmp_path, gap):
    sphere, V, F = _cracked_sphere(gap)
    path = tmp_path / "cracked.obj"
    with open(path, "w") as f:
        f.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
    with pytest.warns(wrd.MeshWarning, match=r"^48 pairs of boundary vertices lie within 0.001 of the bounding box "
                                             r"diagonal of each other \(first: \d+ and \d+, [0-9.e-]+ apart\): the "
                                             r"surface is cracked there and no distance crosses the crack; "
                                             r"load_mesh\(path, repair=True\) or warp_regdist.repair_mesh\(vertices, "
                                             r"faces\) welds them$"):
        cracked = wrd.load_mesh(path)
    assert np.unique(cracked.components()).size == 2
    with pytest.warns(wrd.MeshWarning, match=r"cracked\.obj: welded 48 boundary vertices onto others across cracks "
                                             r"\(within 0.001 of the bounding box diagonal\); 1 connected component"):
        mesh = wrd.load_mesh(path, repair=True)
    assert mesh.n_vertices == 642 and np.array_equal(mesh.vertices, sphere.vertices)   # welded onto the originals
    assert np.array_equal(mesh.faces, sphere.faces)
    whole = wrd.DistanceSolver(wrd.Mesh(sphere.vertices, sphere.faces), 0.05).solve([0]).distance
    u = wrd.DistanceSolver(mesh, 0.05).solve([0]).distance[mesh.input_index]
    np.testing.assert_array_equal(u[:642], whole)
    assert np.all(np.isfinite(u)) and np.abs(u[642:] - whole[mesh.input_index[642:]]).max() == 0.0


def test_close_vertices_that_are_no_crack_are_left_alone():
    # a slit as wide as a fifth of its edges, and an interior edge 1e-6 long: neither is a crack
    s = trimesh.creation.icosphere(subdivisions=3)
    _, V, F = _cracked_sphere(0.0)
    north = np.flatnonzero(V[:642, 2] > 0.5)
    V = V.copy()
    edge = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).min()
    V[642:] = V[642:] + 0.2 * edge * V[642:] / np.linalg.norm(V[642:], axis=1, keepdims=True)   # raised by 0.2 edge
    V[north[1]] = V[north[0]] + 1e-6 * (V[north[1]] - V[north[0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", wrd.MeshWarning)
        wrd.Mesh(V, F)
    mesh, done = wrd.repair_mesh(V, F)
    assert done.welded_vertices == 0 and mesh.n_vertices == len(V) == len(s.vertices) + 48
