"""Mesh files to :class:`~warp_regdist.geometry.mesh.Mesh`: triangle surfaces (OBJ, OFF, PLY, STL) and
tetrahedral volumes (gmsh, VTK, Medit), in the file's vertex order.

OBJ is read by our own reader (trimesh splits an OBJ by material and renumbers it),
OFF / PLY / STL by trimesh with ``process=False``, the volume formats by meshio.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from ..errors import MeshError, MeshWarning
from .mesh import Mesh

__all__ = ["load_mesh", "load_points", "data_path", "POINT_FORMATS"]

POINT_FORMATS = (".xyz", ".npy", ".ply")
"""Point-cloud files of :func:`load_points` (PLY: a file without faces)."""

_VOLUME_FORMATS = {".msh": ("gmsh", "ansys"), ".vtk": ("vtk",), ".vtu": ("vtu",), ".mesh": ("medit",)}  # meshio
_SURFACE_FORMATS = (".off", ".ply", ".stl")  # read by trimesh (OBJ by _read_obj)


def data_path(name):
    """Path (str) of a mesh shipped with the package, e.g. ``data_path("spot_rr.off")`` (spot, 4,764
    vertices, the demo's mesh); ValueError naming the shipped files for another name."""
    folder = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")
    shipped = sorted(f for f in os.listdir(folder) if not f.startswith("."))
    if name not in shipped:
        raise ValueError(f"expected one of the shipped files {shipped}, got {name!r}")
    return os.path.join(folder, name)


def load_mesh(path: str | os.PathLike, repair: bool = False) -> Mesh:
    """Read a triangle or tetrahedral mesh file, keeping the file's vertex order.

    Triangle surfaces: OBJ (:func:`_read_obj`), OFF, PLY (faces or triangle strips), STL (trimesh);
    polygons with more than three corners are fan-triangulated, with a warning that says how many.
    STL stores every triangle's corners separately: corners with identical coordinates are merged
    into one vertex, numbered in order of first appearance. Tetrahedral (or
    triangle) meshes: gmsh ``.msh`` (ASCII or binary, versions 2.2 and 4.1; also ANSYS
    Fluent ``.msh``), VTK ``.vtk`` / ``.vtu``, Medit ``.mesh`` (meshio),
    see :func:`_read_volume_file` for which cells are used. Raises :class:`MeshError`
    for a missing or unreadable file and for every defect :class:`Mesh` checks.

    ``repair=True`` (triangle meshes) merges vertices at one position, welds cracks, drops degenerate
    faces and cuts non-manifold edges (:func:`~warp_regdist.repair_mesh`), with a :class:`~warp_regdist.MeshWarning`
    that says what it changed; the mesh's ``input_index`` maps the file's vertices to its own.
    """
    path = os.fsdecode(os.fspath(path))
    if not os.path.isfile(path):
        raise MeshError(f"expected an existing mesh file, got {path!r} (no such file)")
    if not isinstance(repair, (bool, np.bool_)):
        raise ValueError(f"expected repair as True or False, got {repair!r}")
    ext = os.path.splitext(path)[1].lower()
    if ext in _VOLUME_FORMATS:
        V, T = _read_volume_file(path, ext)
        if repair and T.shape[1] == 4:
            raise MeshError(f"expected a triangle mesh for repair=True, got tetrahedra in {path!r}")
        return _mesh(path, V, T, repair)
    if ext == ".obj":
        V, F, n_poly = _read_obj(path)
        _warn_polygons(path, n_poly)
        return _mesh(path, V, F, repair)
    if ext not in _SURFACE_FORMATS:
        raise MeshError(f"expected a mesh file ending in .obj, .off, .ply, .stl, .msh, .vtk, .vtu or .mesh, "
                        f"got {path!r}")
    import trimesh

    if ext == ".ply":
        check_ascii_ply_complete(path)
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types for malformed files (ImportError when it
        # looks for an optional text decoder for binary garbage, which some environments have)
        detail = "" if isinstance(exc, ImportError) or not str(exc) else f" ({exc})"
        raise MeshError(f"could not read mesh file {path!r}: not a valid {ext[1:].upper()} file{detail}") from None
    V = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))))
    F = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))))
    if F.size == 0 and ext == ".ply":
        V, F = read_ply_strips(path)
    if F.size == 0:
        raise MeshError(f"expected faces in {path!r}, got none (empty file, or a point cloud)")
    if V.shape[0] == 0:
        raise MeshError(f"expected vertices in {path!r}, got none")
    if ext == ".stl":
        V, F = _merge_equal_vertices(V, F)
    _warn_polygons(path, _count_off_polygons(path) if ext == ".off" else 0)
    return _mesh(path, V, F, repair)


def check_ascii_ply_complete(path):
    """MeshError unless an ASCII PLY file holds as many data lines after its header as its ``element``
    lines declare records (one line each); binary files are checked by their reader."""
    with open(path, "rb") as f:
        if f.read(3) != b"ply":
            return                              # not a PLY header: the reader says what is wrong
        header = []
        for line in f:                          # the header, then the data lines, streamed
            if line.strip() == b"end_header":
                break
            header.append(line.decode("ascii", errors="replace").split())
        else:
            return
        if ["format", "ascii"] not in [words[:2] for words in header]:
            return
        found = sum(1 for line in f if line.strip())
    declared = [(words[1], int(words[2])) for words in header
                if len(words) == 3 and words[0] == "element" and words[2].isdigit()]
    if found < sum(count for _, count in declared):
        what = " and ".join(f"{count} {name} lines" for name, count in declared)
        raise MeshError(f"expected {what} after the header of {path!r}, as it declares, got {found} lines: the file "
                        "is truncated")


def _mesh(path, V, F, repair):
    """Mesh(V, F), or with ``repair`` the repaired mesh and a warning saying what changed; a warning
    names the file's vertices that no face uses (their distance is +inf)."""
    F = np.asarray(F)
    if F.ndim == 2 and F.size and np.issubdtype(F.dtype, np.integer) and 0 <= F.min() and F.max() < len(V):
        unused = np.setdiff1d(np.arange(len(V)), F.ravel())
        if unused.size:
            warnings.warn(f"{path}: {unused.size} of {len(V)} vertices are in no element (first: vertex "
                          f"{unused[0]}): their distance is +inf", MeshWarning, stacklevel=3)
    if not repair:
        return Mesh(V, F)
    from .repair import repair_mesh

    mesh, done = repair_mesh(V, F)
    if str(done) != "nothing to repair":
        warnings.warn(f"{path}: {done}", MeshWarning, stacklevel=3)
    return mesh


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply_strips(path):
    """Vertices (n, 3) and triangles of a PLY file whose faces are triangle strips (``element
    tristrips`` with a ``vertex_indices`` list, -1 restarting a strip): strip s_0, s_1, ... gives the
    triangles (s_k, s_k+1, s_k+2), every other one reversed to keep the orientation, without the
    ones that repeat a vertex. Returns empty triangles for a file without strips."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header")
    if end < 0:
        raise MeshError(f"could not read mesh file {path!r}: no PLY header")
    body = data[data.index(b"\n", end) + 1:]
    elements, fmt = [], "ascii"
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        words = line.split()
        if words[:1] == ["format"]:
            fmt = words[1]
        elif words[:1] == ["element"]:
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"] and elements:
            elements[-1][2].append(words[1:])
    if not any(name == "tristrips" for name, _, _ in elements):
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    try:
        if fmt == "ascii":
            values = iter(body.split())
            V, strips = _ply_elements_ascii(elements, values)
        else:
            V, strips = _ply_elements_binary(elements, body, "<" if fmt == "binary_little_endian" else ">")
    except (ValueError, KeyError, IndexError, StopIteration) as exc:
        raise MeshError(f"could not read mesh file {path!r}: not a valid PLY file of triangle strips ({exc})") from None
    return V, _strip_triangles(strips)


def _ply_elements_ascii(elements, values):
    V, strips = None, []
    for name, count, props in elements:
        rows = []
        for _ in range(count):
            row = []
            for prop in props:
                if prop[0] == "list":
                    row.append([float(next(values)) for _ in range(int(next(values)))])
                else:
                    row.append(float(next(values)))
            rows.append(row)
        if name == "vertex":
            names = [p[-1] for p in props]
            V = np.array([[r[names.index(c)] for c in "xyz"] for r in rows], dtype=np.float64).reshape(-1, 3)
        elif name == "tristrips":
            strips += [np.asarray(r[0], dtype=np.int64) for r in rows]
    return V, strips


def _ply_elements_binary(elements, body, order):
    V, strips, at = None, [], 0
    for name, count, props in elements:
        if all(p[0] != "list" for p in props):
            dtype = np.dtype([(p[1], order + _PLY_TYPES[p[0]]) for p in props])
            block = np.frombuffer(body, dtype=dtype, count=count, offset=at)
            at += dtype.itemsize * count
            if name == "vertex":
                V = np.stack([block[c].astype(np.float64) for c in "xyz"], axis=1)
            continue
        for _ in range(count):
            for prop in props:
                if prop[0] != "list":
                    at += np.dtype(_PLY_TYPES[prop[0]]).itemsize
                    continue
                size_type, item_type = np.dtype(order + _PLY_TYPES[prop[1]]), np.dtype(order + _PLY_TYPES[prop[2]])
                k = int(np.frombuffer(body, dtype=size_type, count=1, offset=at)[0])
                at += size_type.itemsize
                items = np.frombuffer(body, dtype=item_type, count=k, offset=at).astype(np.int64)
                at += item_type.itemsize * k
                if name == "tristrips":
                    strips.append(items)
    return V, strips


def _strip_triangles(strips):
    """Triangles (m, 3) of triangle strips (-1 restarts a strip)."""
    out = []
    for strip in strips:
        for piece in np.split(strip, np.flatnonzero(strip < 0)):
            piece = piece[piece >= 0]
            if piece.size < 3:
                continue
            k = np.arange(piece.size - 2)
            tri = np.stack([piece[k], piece[k + 1], piece[k + 2]], axis=1)
            tri[1::2] = tri[1::2][:, [1, 0, 2]]                  # every other triangle reversed
            keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
            out.append(tri[keep])
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


def _warn_polygons(path, count):
    if count:
        warnings.warn(f"{path}: {count} polygon faces with more than 3 corners were triangulated", stacklevel=3)


def _merge_equal_vertices(V, F):
    """One vertex per distinct position, numbered by first appearance in V (for STL)."""
    V = np.asarray(V, dtype=np.float64) + 0.0  # -0.0 -> 0.0
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return V[first[order]], rank[inverse.ravel()][np.asarray(F)]


def _read_obj(path):
    """Vertices and triangles of a Wavefront OBJ file, in the file's order.

    Reads ``v x y z`` and ``f i j k ...`` lines (corners ``i``, ``i/t``, ``i//n`` or
    ``i/t/n``; 1-based, negative = relative to the vertices read so far) and ignores
    everything else (texture coordinates, normals, groups, materials, lines). Polygons
    are fan-triangulated. Unlike trimesh, materials and groups neither split nor
    renumber the vertices.

    Returns
    -------
    V : (n, 3) ndarray of float64
    F : (m, 3) ndarray of int64 (indices may be out of range: :class:`Mesh` checks them)
    polygons : int, number of faces with more than three corners
    """
    with open(path, "rb") as f:
        lines = f.read().splitlines()
    coords, faces, polygons = [], [], 0
    try:
        for number, line in enumerate(lines, 1):
            tokens = line.split()
            if not tokens or tokens[0] not in (b"v", b"f"):
                continue
            if len(tokens) < 4:
                raise ValueError(f"line {number}: expected 3 or more values, got {line[:60]!r}")
            if tokens[0] == b"v":
                coords.append(b" ".join(tokens[1:4]))
                continue
            corners = [int(t.split(b"/", 1)[0]) for t in tokens[1:]]
            if min(corners) < 0 or 0 in corners:
                if 0 in corners:
                    raise ValueError(f"line {number}: expected 1-based or negative vertex indices, got 0")
                corners = [c if c > 0 else len(coords) + c + 1 for c in corners]
            polygons += len(corners) > 3
            faces.extend((corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1))
        V = np.array(b" ".join(coords).split(), dtype=np.float64).reshape(-1, 3)
    except ValueError as exc:
        raise MeshError(f"could not read mesh file {path!r}: {exc}") from None
    if not faces:
        raise MeshError(f"expected faces in {path!r}, got none (empty file, or a point cloud)")
    return V, np.array(faces, dtype=np.int64) - 1, polygons


def load_points(path, neighbours=30):
    """Read a point cloud as a :class:`~warp_regdist.PointCloud`: ``.xyz`` (text, x y z first on each
    line, '#' comments), ``.npy`` ((p, 3) array) or ``.ply`` (its vertices; faces are ignored)."""
    from .point_cloud import PointCloud

    path = os.fsdecode(os.fspath(path))
    if not os.path.isfile(path):
        raise MeshError(f"expected an existing point file, got {path!r} (no such file)")
    ext = os.path.splitext(path)[1].lower()
    if ext not in POINT_FORMATS:
        raise MeshError(f"expected a point file ending in .xyz, .npy or .ply, got {path!r}")
    try:
        if ext == ".xyz":
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")       # an empty file: numpy warns, then the shape check refuses it
                P = np.loadtxt(path, comments="#", ndmin=2)
            P = P[:, :3] if P.ndim == 2 and P.shape[1] >= 3 else P
        elif ext == ".npy":
            P = np.load(path, allow_pickle=False)
        else:
            import trimesh

            check_ascii_ply_complete(path)
            P = np.asarray(trimesh.load(path, process=False).vertices)
    except MeshError:
        raise
    except Exception as exc:  # numpy and trimesh raise many types for malformed files
        raise MeshError(f"could not read point file {path!r}: not a valid {ext[1:].upper()} file ({exc})") from None
    try:
        return PointCloud(P, neighbours=neighbours)
    except ValueError as exc:
        raise MeshError(f"{exc} in {path!r}") from None


def _read_volume_file(path, ext):
    """Points and elements of a gmsh / VTK / Medit file, read with meshio.

    The elements are all ``tetra`` cells of the file, in file order, when it has any; the
    file's lower-dimensional cells (boundary triangles, lines, points, as gmsh writes them)
    are then ignored. Without tetrahedra, the ``triangle`` cells are used. Any other cell
    type of the dimension used (hexahedra, wedges, pyramids, quadratic tetrahedra beside
    or instead of tetrahedra; quads beside or instead of triangles) is refused rather than
    dropped. meshio returns 0-based point indices in the file's point order for every
    format (Medit's 1-based indices and gmsh's node tags are converted); 2-D points get
    z = 0.

    Returns
    -------
    V : (n, 3) ndarray of float64
    T : (m, 4) or (m, 3) ndarray of int64
    """
    import meshio

    reasons = []
    for fmt in _VOLUME_FORMATS[ext]:
        try:
            # the format's own reader: meshio.read() calls sys.exit on a file it cannot parse
            data = getattr(meshio, fmt).read(path)
            break
        except Exception as exc:  # meshio raises ReadError, but also ValueError, UnicodeDecodeError, ...
            reasons.append(str(exc).strip() or f"not a valid {fmt} file")
    else:
        raise MeshError(f"could not read mesh file {path!r}: {'; '.join(reasons)}")
    counts = {}
    for block in data.cells:
        counts.setdefault((block.dim, block.type), 0)
        counts[(block.dim, block.type)] += len(block.data)
    listing = ", ".join(f"{k} {t}" for (_, t), k in counts.items()) or "no cells"
    for dim, kind in ((3, "tetra"), (2, "triangle")):
        others = sorted(t for (d, t) in counts if d == dim and t != kind)
        if others and (dim, kind) in counts:
            raise MeshError(f"expected only {kind} cells among the {dim}-D cells of {path!r}, got mixed cells "
                            f"({listing}); {', '.join(others)} are not supported")
        if others:
            raise MeshError(f"expected tetrahedra ('tetra') or triangles in {path!r}, got unsupported "
                            f"{dim}-D cells ({listing})")
        if (dim, kind) in counts:
            T = np.concatenate([b.data for b in data.cells if b.type == kind])
            break
    else:
        raise MeshError(f"expected tetrahedra ('tetra') or triangles in {path!r}, got {listing}")
    V = np.asarray(data.points)
    if V.ndim == 2 and V.shape[1] == 2:
        V = np.concatenate([V, np.zeros((len(V), 1))], axis=1)
    return V, T


def _count_off_polygons(path):
    """Number of faces with more than three corners in an OFF file."""
    with open(path, "rb") as f:
        tokens = [ln.split(b"#")[0].split() for ln in f.read().splitlines()]
    tokens = [t for t in tokens if t]
    if not tokens or not tokens[0][0].upper().endswith(b"OFF"):
        return 0
    head = tokens[0][1:] or tokens[1]
    start = 1 if tokens[0][1:] else 2
    try:
        nv, nf = int(head[0]), int(head[1])
        return sum(1 for t in tokens[start + nv:start + nv + nf] if int(t[0]) > 3)
    except (ValueError, IndexError):
        return 0
