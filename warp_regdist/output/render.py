"""Pictures of per-vertex scalar fields on triangle meshes, drawn with matplotlib only.

The renderer is a small software rasterizer built on matplotlib's Agg backend: the
mesh is projected orthographically, its faces are painted back to front (painter's
algorithm) as one ``PolyCollection`` with a flat Lambert-shaded colour per face, and the
isolines are one ``LineCollection`` on top.  Isoline segments hidden behind the surface
are removed with a depth buffer: the faces are drawn once more off screen with their
depth encoded in the 24 RGB bits of the colour, and a segment is kept when it lies no
further than a small lift (the median edge length) behind the surface seen at its
pixel and, on a closed consistently oriented surface, when its face looks at the
camera.  The isolines and plane sections are the exact contours of
:mod:`warp_regdist.output.contours`.  No figure is ever shown and matplotlib's global state
(backend, rcParams) is left untouched.
"""

from __future__ import annotations


import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.tri import Triangulation

from ..atomic_write import write_atomic
from .contours import isoline_segments, plane_section, surface_arrays, vertex_values

__all__ = ["render_cut", "render_distance", "render_points", "view_rotation"]

_DPI = 150
_PANEL_WIDTH_IN = 4.6  # width of one view in inches
_MARGIN = 0.06  # empty border around the mesh, as a fraction of its projected size
_LIGHT = np.array([-0.45, 0.65, 1.0]) / np.linalg.norm([-0.45, 0.65, 1.0])
_AMBIENT = 0.42
_UNREACHABLE_RGB = np.array([0.62, 0.62, 0.62])
_ISOLINE_RGBA = (0.08, 0.08, 0.08, 0.85)
_DEPTH_LEVELS = 2**24 - 2  # depth codes 1 .. 2^24 - 1 (0 is the empty background)


def _default_levels(values: np.ndarray, count: int) -> np.ndarray:
    finite = values[np.isfinite(values)]
    if count <= 0 or finite.size == 0 or finite.max() <= finite.min():
        return np.empty(0)
    lo, hi = finite.min(), finite.max()
    return lo + (hi - lo) * np.arange(1, count + 1) / (count + 1)


def view_rotation(vertices, azimuth: float = 35.0, elevation: float = 15.0) -> np.ndarray:
    """Camera rotation for a picture of a shape, from its bounding box and two angles.

    The base frame looks along the coordinate axis of smallest extent, with the axis of
    largest extent horizontal and the remaining axis pointing up (positive side up), so
    an upright model stays upright.  (The principal axes of the vertices are not used:
    they tilt shapes such as the spot cow by 40 degrees.)  The camera then turns by
    ``azimuth`` around the screen's up axis and rises by ``elevation``.

    Parameters
    ----------
    vertices : (n, 3) float
        Points to look at.
    azimuth, elevation : float
        Angles in degrees; (0, 0) looks straight along the axis of smallest extent, and
        ``azimuth + 180`` shows the back.

    Returns
    -------
    (3, 3) float64
        Rotation R whose rows are the screen's right, up and toward-the-camera axes in
        world coordinates: a point x is seen at ``R @ x`` (orthographic, larger z nearer).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    extent = np.ptp(vertices, axis=0)
    smallest, middle, largest = np.argsort(extent, kind="stable")
    right, up = np.eye(3)[largest], np.eye(3)[middle]
    base = np.stack([right, up, np.cross(right, up)])
    a, e = np.radians(azimuth), np.radians(elevation)
    turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    rise = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(e), -np.sin(e)], [0.0, np.sin(e), np.cos(e)]])
    return rise @ turn @ base


def _shading_normals(vertices: np.ndarray, faces: np.ndarray, face_normal: np.ndarray) -> np.ndarray:
    """Per-face unit normals for smooth-looking flat shading, (m, 3).

    The mean of the face's three vertex normals (area-weighted sums of the adjacent
    face normals) varies smoothly across the surface, unlike the face normal; where it
    vanishes (inconsistent orientation) the face normal is used.
    """
    vertex_normal = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(vertex_normal, faces[:, corner], face_normal)
    vertex_normal /= np.maximum(np.linalg.norm(vertex_normal, axis=1), np.finfo(np.float64).tiny)[:, None]
    smooth = vertex_normal[faces].sum(axis=1)
    length = np.linalg.norm(smooth, axis=1)
    flat_length = np.linalg.norm(face_normal, axis=1)
    use_flat = length < 0.5
    smooth[use_flat] = face_normal[use_flat]
    length[use_flat] = flat_length[use_flat]
    return smooth / np.maximum(length, np.finfo(np.float64).tiny)[:, None]


def _outward(vertices: np.ndarray, faces: np.ndarray) -> int:
    """+1 (-1) if the surface is closed and consistently oriented with outward (inward)
    normals, 0 otherwise (open, non-manifold or inconsistently oriented)."""
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    if not np.all(counts == 2) or len(np.unique(directed, axis=0)) != len(directed):
        return 0
    x0, x1, x2 = (vertices[faces[:, i]] for i in range(3))
    return 1 if np.einsum("ij,ij->", x0, np.cross(x1, x2)) >= 0 else -1


def _views(view, closed: bool) -> list[tuple[float, float]]:
    if view is None:
        return [(35.0, 15.0), (215.0, 15.0)] if closed else [(35.0, 15.0)]
    views = np.asarray(view, dtype=np.float64)
    if views.shape == (2,):
        views = views[None]
    if views.ndim != 2 or views.shape[1] != 2 or len(views) == 0:
        raise ValueError(
            f"expected view as (azimuth, elevation) or a list of such pairs, got {view!r}"
        )
    return [tuple(v) for v in views]


def _depth_codes(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    scale = _DEPTH_LEVELS / max(hi - lo, np.finfo(np.float64).tiny)
    return 1 + np.clip(np.rint((depth - lo) * scale), 0, _DEPTH_LEVELS).astype(np.int64)


def _depth_buffer(figsize, rects, limits, polygons, codes) -> np.ndarray:
    """Render the faces with their depth codes as colours; returns (H, W) int64 codes."""
    fig = Figure(figsize=figsize, dpi=_DPI)
    canvas = FigureCanvasAgg(fig)
    fig.patch.set_facecolor((0.0, 0.0, 0.0, 1.0))
    for rect, (xlim, ylim), poly, code in zip(rects, limits, polygons, codes):
        ax = fig.add_axes(rect)
        ax.set_axis_off()
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        rgb = np.stack([(code >> 16) & 255, (code >> 8) & 255, code & 255], axis=1) / 255.0
        ax.add_collection(
            PolyCollection(poly, facecolors=rgb, edgecolors="none", antialiased=False), autolim=False
        )
    canvas.draw()
    buf = np.asarray(canvas.buffer_rgba()).astype(np.int64)
    return (buf[..., 0] << 16) | (buf[..., 1] << 8) | buf[..., 2]


def _visible(ax, buffer, xy, code_min) -> np.ndarray:
    """True where the depth code of a point is at least the buffer's at its pixel."""
    height, width = buffer.shape
    pix = ax.transData.transform(xy)
    col = np.clip(np.floor(pix[:, 0]).astype(np.int64), 0, width - 1)
    row = np.clip(height - 1 - np.floor(pix[:, 1]).astype(np.int64), 0, height - 1)
    return code_min >= buffer[row, col]


def _finish(fig, cax, norm, colormap, levels, unreachable, title, fig_h, path, label="distance") -> None:
    """Colour bar (with the isoline levels) in ``cax``, the title, and the PNG at ``path``."""
    cbar = fig.colorbar(ScalarMappable(norm=norm, cmap=colormap), cax=cax)
    if len(levels):
        cbar.add_lines(levels, colors=[_ISOLINE_RGBA[:3]] * len(levels), linewidths=0.6)
    cbar.ax.tick_params(labelsize=8)
    cbar.set_label(label, fontsize=9)
    if unreachable:
        cax.text(0.5, -0.04, "grey:\nunreachable", transform=cax.transAxes, ha="center", va="top", fontsize=7)
    if title:
        fig.text(0.5, 1.0 - 0.1 / fig_h, title, ha="center", va="top", fontsize=11)
    write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=_DPI), "the picture")


def render_distance(
    mesh,
    values,
    path,
    sources=None,
    isolines: int | np.ndarray = 20,
    title: str | None = None,
    view=None,
    cmap: str = "viridis",
    limits=None,
    curves=None,
    label: str = "distance",
) -> None:
    """Write a PNG of a triangle mesh coloured by a per-vertex field, with isolines.

    Each face gets the colour map's colour of the mean of its vertex values, multiplied
    by a two-sided Lambert shade ``0.42 + 0.58 |n . l|`` (n: mean of the face's vertex
    normals, l: light from the upper left front).  Faces touching a non-finite value (``inf``: unreachable) are grey.
    Isolines are exact per-triangle level sets of the linear interpolant (see
    :func:`isolines`), drawn where the surface does not hide them.  Sources are red dots.

    Parameters
    ----------
    mesh : Mesh
        Triangle mesh; any object with ``vertices`` (n, 3) and ``faces`` (m, 3).
    values : (n,) float
        Value per vertex, e.g. a distance; ``inf``/``nan`` are drawn grey.
    path : str or os.PathLike
        Output file; written as PNG at 150 dpi.
    sources : iterable of int, optional
        Vertex indices to mark.
    isolines : int or (L,) float
        Number of evenly spaced levels strictly between the smallest and the largest
        finite value, ``lo + (hi - lo) k / (L + 1)`` for k = 1..L, or the levels
        themselves; 0 draws none.
    title : str, optional
        Text above the picture.
    view : (2,) float or list of (2,) float, optional
        Camera (azimuth, elevation) in degrees for each panel, relative to the frame of
        :func:`view_rotation`.  Default: (35, 15), plus the back (215, 15) beside it when
        the surface is closed.
    cmap : str
        Matplotlib colour map name.
    limits : (float, float) or None
        The values at the colour map's ends; None: the finite values' range.
    curves : list of (c,) int or (c, 3) float arrays, optional
        Polylines to draw on the surface (e.g. source curves), as vertex chains or points.
    label : str
        The colour bar's label.
    """
    vertices, faces = surface_arrays(mesh)
    values = vertex_values(values, len(vertices))
    outward = _outward(vertices, faces)
    views = _views(view, outward != 0)
    colormap = colormaps[cmap]
    if np.ndim(isolines) == 0:
        if isinstance(isolines, (bool, np.bool_)) or int(isolines) != isolines or isolines < 0:
            raise ValueError(f"expected isolines as a count >= 0 or a list of levels, got {isolines!r}")
        levels = _default_levels(values, int(isolines))
    else:
        levels = np.asarray(isolines, dtype=np.float64).ravel()
    sources = np.unique(np.asarray([] if sources is None else list(sources), dtype=np.int64))
    if sources.size and (sources.min() < 0 or sources.max() >= len(vertices)):
        raise ValueError(
            f"expected source indices in [0, {len(vertices)}), got {sources.min()}..{sources.max()}"
        )

    curve_points = []
    for curve in curves or []:
        curve = np.asarray(curve)
        curve_points.append(vertices[curve] if np.issubdtype(curve.dtype, np.integer) else
                            np.asarray(curve, dtype=np.float64).reshape(-1, 3))

    finite = np.isfinite(values)
    lo, hi = (values[finite].min(), values[finite].max()) if finite.any() else (0.0, 1.0)
    if limits is not None:
        lo, hi = (float(v) for v in limits)
    norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1.0)
    face_values = values[faces].mean(axis=1)
    face_finite = np.isfinite(face_values)
    base_rgb = np.tile(_UNREACHABLE_RGB, (len(faces), 1))
    base_rgb[face_finite] = colormap(norm(face_values[face_finite]))[:, :3]
    segments, segment_face, _ = isoline_segments(vertices, faces, values, levels)
    x0, x1, x2 = (vertices[faces[:, i]] for i in range(3))
    face_normal = np.cross(x1 - x0, x2 - x0)

    center = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    lift = float(np.median(np.linalg.norm(x1 - x0, axis=1)))
    rotations = [view_rotation(vertices, az, el) for az, el in views]
    if view is None and sources.size and len(rotations) == 2:
        # Show the side where the sources are first.
        if np.mean((vertices[sources] - center) @ rotations[0][2]) < 0:
            rotations.reverse()
    projected = [(vertices - center) @ r.T for r in rotations]

    # Layout: equal-size panels at one common scale, colourbar on the right.
    lows = [p[:, :2].min(axis=0) for p in projected]
    highs = [p[:, :2].max(axis=0) for p in projected]
    half = 0.5 * np.max(np.subtract(highs, lows), axis=0) * (1.0 + _MARGIN)
    half = np.maximum(half, 1e-12 + 0.02 * half.max())
    panel_h = _PANEL_WIDTH_IN * half[1] / half[0]
    top_in, bottom_in, cbar_in = (0.45 if title else 0.12), 0.12, 1.15
    fig_w = _PANEL_WIDTH_IN * len(views) + cbar_in
    fig_h = panel_h + top_in + bottom_in
    rects = [
        (i * _PANEL_WIDTH_IN / fig_w, bottom_in / fig_h, _PANEL_WIDTH_IN / fig_w, panel_h / fig_h)
        for i in range(len(views))
    ]
    mids = [0.5 * (lo + hi) for lo, hi in zip(lows, highs)]
    limits = [((m[0] - half[0], m[0] + half[0]), (m[1] - half[1], m[1] + half[1])) for m in mids]

    shading_normals = _shading_normals(vertices, faces, face_normal)
    polygons, colors, codes, depth_range = [], [], [], []
    for p, rot in zip(projected, rotations):
        tri = p[faces]  # (m, 3, 3) in view coordinates
        lambert = np.abs(shading_normals @ (rot.T @ _LIGHT))
        depth = tri[:, :, 2].mean(axis=1)
        order = np.argsort(depth, kind="stable")  # far to near
        polygons.append(tri[order, :, :2])
        colors.append(base_rgb[order] * (_AMBIENT + (1.0 - _AMBIENT) * lambert[order])[:, None])
        zlo, zhi = p[:, 2].min(), p[:, 2].max() + 3.0 * lift
        depth_range.append((zlo, zhi))
        codes.append(_depth_codes(depth[order], zlo, zhi))
    figsize = (fig_w, fig_h)
    buffer = _depth_buffer(figsize, rects, limits, polygons, codes)

    fig = Figure(figsize=figsize, dpi=_DPI)
    FigureCanvasAgg(fig)  # attaches the Agg canvas that savefig draws with
    fig.patch.set_facecolor("white")
    for rect, (xlim, ylim), poly, col, rot, (zlo, zhi) in zip(
        rects, limits, polygons, colors, rotations, depth_range
    ):
        ax = fig.add_axes(rect)
        ax.set_axis_off()
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.add_collection(
            PolyCollection(poly, facecolors=col, edgecolors=col, linewidths=0.25, antialiased=True),
            autolim=False,
        )
        if len(segments):
            seg = (segments - center) @ rot.T  # (s, 2, 3)
            mid = seg.mean(axis=1)
            keep = _visible(ax, buffer, mid[:, :2], _depth_codes(mid[:, 2] + lift, zlo, zhi))
            if outward:  # closed surface: back faces are hidden
                keep &= outward * (face_normal[segment_face] @ rot[2]) > 0
            ax.add_collection(
                LineCollection(seg[keep, :, :2], colors=[_ISOLINE_RGBA], linewidths=0.7, capstyle="round"),
                autolim=False,
            )
        for curve in curve_points:
            c = (curve - center) @ rot.T
            seen = _visible(ax, buffer, c[:, :2], _depth_codes(c[:, 2] + 3.0 * lift, zlo, zhi))
            pieces = np.stack([c[:-1, :2], c[1:, :2]], axis=1)[seen[:-1] & seen[1:]]
            ax.add_collection(LineCollection(pieces, colors="#e41a1c", linewidths=2.0, capstyle="round", zorder=3),
                              autolim=False)
        if sources.size:
            s = (vertices[sources] - center) @ rot.T
            keep = _visible(ax, buffer, s[:, :2], _depth_codes(s[:, 2] + 3.0 * lift, zlo, zhi))
            ax.scatter(
                s[keep, 0], s[keep, 1], s=42, c="#e41a1c", edgecolors="white", linewidths=1.0, zorder=3, clip_on=False
            )

    cax = fig.add_axes(
        (
            (_PANEL_WIDTH_IN * len(views) + 0.15) / fig_w,
            (bottom_in + 0.1 * panel_h) / fig_h,
            0.16 / fig_w,
            0.8 * panel_h / fig_h,
        )
    )
    _finish(fig, cax, norm, colormap, levels, not finite.all(), title, fig_h, path, label)


def render_points(
    points,
    values,
    path,
    sources=None,
    title: str | None = None,
    view=None,
    cmap: str = "viridis",
    limits=None,
    label: str = "distance",
) -> None:
    """Write a PNG of a point cloud coloured by a per-point field: each point a disk (splat) the size
    of its spacing, painted back to front, from the front and the back side by side.

    Parameters
    ----------
    points : (n, 3) float
    values : (n,) float
        Value per point; ``inf``/``nan`` are drawn grey.
    path : str or os.PathLike
        Output file; written as PNG at 150 dpi.
    sources : iterable of int, optional
        Points to mark (red, on top, also where other points hide them).
    title, view, cmap, limits, label
        As in :func:`render_distance`.
    """
    from scipy.spatial import cKDTree

    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
        raise ValueError(f"expected points of shape (n, 3) with n >= 2, got shape {P.shape}")
    values = vertex_values(values, len(P))
    sources = np.unique(np.asarray([] if sources is None else list(sources), dtype=np.int64))
    if sources.size and (sources.min() < 0 or sources.max() >= len(P)):
        raise ValueError(f"expected source indices in [0, {len(P)}), got {sources.min()}..{sources.max()}")
    views = _views(view, True)
    colormap = colormaps[cmap]
    finite = np.isfinite(values)
    lo, hi = (values[finite].min(), values[finite].max()) if finite.any() else (0.0, 1.0)
    if limits is not None:
        lo, hi = (float(v) for v in limits)
    norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1.0)
    rgb = np.tile(_UNREACHABLE_RGB, (len(P), 1))
    rgb[finite] = colormap(norm(values[finite]))[:, :3]
    spacing = float(np.median(cKDTree(P).query(P, k=2)[0][:, 1]))

    center = 0.5 * (P.min(axis=0) + P.max(axis=0))
    rotations = [view_rotation(P, az, el) for az, el in views]
    if view is None and sources.size and len(rotations) == 2 and np.mean((P[sources] - center) @ rotations[0][2]) < 0:
        rotations.reverse()
    projected = [(P - center) @ r.T for r in rotations]
    lows = [p[:, :2].min(axis=0) for p in projected]
    highs = [p[:, :2].max(axis=0) for p in projected]
    half = 0.5 * np.max(np.subtract(highs, lows), axis=0) * (1.0 + _MARGIN) + spacing   # room for the splats
    half = np.maximum(half, 1e-12 + 0.02 * half.max())
    panel_h = _PANEL_WIDTH_IN * half[1] / half[0]
    top_in, bottom_in, cbar_in = (0.45 if title else 0.12), 0.12, 1.15
    fig_w = _PANEL_WIDTH_IN * len(views) + cbar_in
    fig_h = panel_h + top_in + bottom_in
    fig = Figure(figsize=(fig_w, fig_h), dpi=_DPI)
    FigureCanvasAgg(fig)
    fig.patch.set_facecolor("white")
    size = (1.25 * spacing / (2.0 * half[0]) * _PANEL_WIDTH_IN * 72.0) ** 2   # marker area in points^2
    for i, p in enumerate(projected):
        ax = fig.add_axes((i * _PANEL_WIDTH_IN / fig_w, bottom_in / fig_h, _PANEL_WIDTH_IN / fig_w, panel_h / fig_h))
        ax.set_axis_off()
        mid = 0.5 * (lows[i] + highs[i])
        ax.set_xlim(mid[0] - half[0], mid[0] + half[0])
        ax.set_ylim(mid[1] - half[1], mid[1] + half[1])
        order = np.argsort(p[:, 2], kind="stable")                    # far to near
        depth = (p[order, 2] - p[:, 2].min()) / max(np.ptp(p[:, 2]), 1e-300)
        shade = (_AMBIENT + (1.0 - _AMBIENT) * depth)[:, None]          # nearer points brighter
        ax.scatter(p[order, 0], p[order, 1], s=size, c=rgb[order] * shade, marker="o", linewidths=0)
        if sources.size:
            ax.scatter(p[sources, 0], p[sources, 1], s=60, c="#e41a1c", edgecolors="white", linewidths=1.2,
                       zorder=3, clip_on=False)
    cax = fig.add_axes(((_PANEL_WIDTH_IN * len(views) + 0.15) / fig_w, (bottom_in + 0.1 * panel_h) / fig_h,
                        0.16 / fig_w, 0.8 * panel_h / fig_h))
    _finish(fig, cax, norm, colormap, np.empty(0), not finite.all(), title, fig_h, path, label)


def render_cut(
    mesh,
    values,
    path,
    plane_normal=(0.0, 0.0, 1.0),
    offset=None,
    levels: int | np.ndarray = 20,
    title: str | None = None,
    cmap: str = "viridis",
) -> None:
    """Write a PNG of a planar cut through a tetrahedral mesh, coloured by a field, with isolines.

    The section (:func:`plane_section`) is drawn in the plane's own frame: the horizontal
    axis is the coordinate axis least aligned with the normal, made orthogonal to it, the
    vertical axis the normal crossed with it (for the default normal z: x to the right,
    y up).  Colours are interpolated linearly inside each section triangle (Gouraud
    shading, exact for the piecewise-linear field); triangles touching a non-finite value
    are grey.  Isolines are the exact level sets of the field in the section (marching
    triangles, :func:`isolines`).  The colour range and the default levels are those of
    the whole field, so cuts at different offsets share one scale.

    Parameters
    ----------
    mesh : Mesh
        Tetrahedral mesh.
    values : (n,) float
        Value per vertex, e.g. a distance; ``inf``/``nan`` are drawn grey.
    path : str or os.PathLike
        Output file, written as PNG at 150 dpi.
    plane_normal : (3,) float
        Normal of the cutting plane.
    offset : float, optional
        The plane is {x : n . x = offset} for the unit normal n; default: through the
        centre of the bounding box.
    levels : int or (L,) float
        Number of evenly spaced isoline levels strictly between the smallest and the
        largest finite value of the field, or the levels themselves; 0 draws none.
    title : str, optional
        Text above the picture.
    cmap : str
        Matplotlib colour map name.

    Raises
    ------
    ValueError
        For a triangle mesh, a zero normal, or a plane that misses the mesh.
    """
    points, point_values = plane_section(mesh, values, plane_normal, offset)
    if len(points) == 0:
        raise ValueError(f"expected a plane that cuts the mesh, got normal {tuple(plane_normal)} and offset {offset}")
    values = np.asarray(values, dtype=np.float64)
    normal = np.asarray(plane_normal, dtype=np.float64) / np.linalg.norm(plane_normal)
    axis = np.eye(3)[np.argmin(np.abs(normal))]
    right = axis - (axis @ normal) * normal
    right /= np.linalg.norm(right)
    up = np.cross(normal, right)
    xy = np.stack([points @ right, points @ up], axis=-1)  # (t, 3, 2)

    colormap = colormaps[cmap]
    finite = np.isfinite(values)
    lo, hi = (values[finite].min(), values[finite].max()) if finite.any() else (0.0, 1.0)
    norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1.0)
    if np.ndim(levels) == 0:
        levels = _default_levels(values, int(levels))
    else:
        levels = np.asarray(levels, dtype=np.float64).ravel()
    tri_finite = np.isfinite(point_values).all(axis=1)

    low, high = xy.reshape(-1, 2).min(axis=0), xy.reshape(-1, 2).max(axis=0)
    half = 0.5 * (high - low) * (1.0 + _MARGIN)
    half = np.maximum(half, 1e-12 + 0.02 * half.max())
    mid = 0.5 * (low + high)
    panel_h = _PANEL_WIDTH_IN * half[1] / half[0]
    left_in, top_in, bottom_in, cbar_in = 0.75, (0.45 if title else 0.15), 0.45, 1.15
    fig_w, fig_h = left_in + _PANEL_WIDTH_IN + cbar_in, panel_h + top_in + bottom_in
    fig = Figure(figsize=(fig_w, fig_h), dpi=_DPI)
    FigureCanvasAgg(fig)
    fig.patch.set_facecolor("white")
    ax = fig.add_axes((left_in / fig_w, bottom_in / fig_h, _PANEL_WIDTH_IN / fig_w, panel_h / fig_h))
    ax.set_xlim(mid[0] - half[0], mid[0] + half[0])
    ax.set_ylim(mid[1] - half[1], mid[1] + half[1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_xlabel(f"along ({right[0]:.3g}, {right[1]:.3g}, {right[2]:.3g})", fontsize=8)
    ax.set_ylabel(f"along ({up[0]:.3g}, {up[1]:.3g}, {up[2]:.3g})", fontsize=8)
    if tri_finite.any():
        good = xy[tri_finite].reshape(-1, 2)
        ax.tripcolor(Triangulation(good[:, 0], good[:, 1], np.arange(len(good)).reshape(-1, 3)),
                     point_values[tri_finite].ravel(), shading="gouraud", cmap=colormap, norm=norm)
    if not tri_finite.all():
        ax.add_collection(PolyCollection(xy[~tri_finite], facecolors=_UNREACHABLE_RGB,
                                          edgecolors=_UNREACHABLE_RGB, linewidths=0.5, antialiased=False),
                          autolim=False)
    if len(levels) and tri_finite.any():
        flat = points[tri_finite].reshape(-1, 3)
        segments, _, _ = isoline_segments(flat, np.arange(len(flat)).reshape(-1, 3),
                                           point_values[tri_finite].ravel(), levels)
        seg2 = np.stack([segments @ right, segments @ up], axis=-1)
        ax.add_collection(LineCollection(list(seg2), colors=[_ISOLINE_RGBA], linewidths=0.7, capstyle="round"),
                          autolim=False)
    cax = fig.add_axes(((left_in + _PANEL_WIDTH_IN + 0.15) / fig_w, (bottom_in + 0.1 * panel_h) / fig_h,
                        0.16 / fig_w, 0.8 * panel_h / fig_h))
    _finish(fig, cax, norm, colormap, levels, not tri_finite.all(), title, fig_h, path)
