"""The ``distance`` subcommand: the distance on a mesh file, written as .npy, .csv or .vtu."""

from __future__ import annotations

import argparse
import os

from ..atomic_write import check_room
from .common import (DEMO_ALPHA_HAT, OUTPUT_EXTENSIONS, PICTURE_BYTES, check_output, exit_status, file_values, load,
                     max_distance_option, max_iterations_option, parse_sources, parse_surface_points, repair_option,
                     single_source_options, solve, solver_options, source_triangles_option, subcommand, summary,
                     values_bytes, warn, write_or_rescue)


LOCKED_OUTPUTS = ("output", "png")


def add_parser(sub) -> None:
    distance = subcommand(
        sub, "distance",
        help="regularized distance on a mesh file, written as .npy, .csv or .vtu",
        description="Regularized geodesic distance from a set of source vertices, points or a curve on a triangle\n"
        "mesh (OBJ, OFF, PLY or STL) or a tetrahedral mesh (gmsh .msh, .vtk, .vtu, Medit\n"
        ".mesh); vertex order as in the file.",
    )
    distance.add_argument(
        "mesh",
        metavar="MESH",
        help="triangle or tetrahedral mesh file (.obj, .off, .ply, .stl, .msh, .vtk, .vtu, .mesh)",
    )
    distance.add_argument(
        "--sources",
        metavar="LIST",
        help="comma-separated 0-based vertex indices (e.g. 2272,17), 'boundary' for all "
        "boundary vertices, or a .csv file of 'x,y,z' rows: points moved to the closest surface "
        "point (within 5%% of the bounding box diagonal) and inserted into the mesh",
    )
    distance.add_argument(
        "--curve",
        metavar="FILE",
        help="a .csv file of 'x,y,z' rows: a polyline through the closest surface points, running "
        "between consecutive points along the section of the surface by a plane; u = 0 along it",
    )
    distance.add_argument(
        "--closed",
        action="store_true",
        help="the --curve returns to its first point; writes the signed distance (negative on the "
        "curve's left, seen from outside)",
    )
    distance.add_argument(
        "--alpha-hat",
        type=float,
        default=DEMO_ALPHA_HAT,
        metavar="A",
        help="scale-invariant regularization weight >= 0; alpha = A sqrt(area), or A volume^(1/3) "
        "on a tetrahedral mesh (default: 0.05)",
    )
    distance.add_argument(
        "--regularizer",
        default="dirichlet",
        choices=("dirichlet", "vector_field", "hessian"),
        help="dirichlet (default); vector_field: isolines follow the field of --directions; "
        "hessian: isolines ignore the boundary (triangle meshes; alpha = A area^(3/2), so use "
        "a much smaller A, e.g. 1e-3)",
    )
    distance.add_argument(
        "--beta-hat",
        type=float,
        default=None,
        metavar="B",
        help="alignment weight >= 0 of --regularizer vector_field (default: 10)",
    )
    distance.add_argument(
        "--directions",
        metavar="FILE",
        help="field of --regularizer vector_field: .npy of shape (faces, 3), one vector per face; "
        "or .csv with rows 'face,dx,dy,dz' (sign-free directions on a few faces, interpolated "
        "into the smoothest line field)",
    )
    distance.add_argument(
        "--output",
        required=True,
        metavar="FILE",
        help="distance per vertex: .npy (float64 array), .csv (one value per line, full "
        "precision, 'inf' for vertices no source reaches) or .vtu (the mesh with point data "
        "'distance', NaN where no source reaches; opens in ParaView)",
    )
    distance.add_argument(
        "--png",
        metavar="FILE",
        help="also write a picture of the distance (.png); on a tetrahedral mesh, its cut by the "
        "plane z = centre of the bounding box, with isolines",
    )
    distance.add_argument(
        "--polish",
        action="store_true",
        help="finish with Newton's method on the barrier-smoothed problem: within about 0.03%% of the exact "
        "minimizer, about 5 times the solve's time (vertex sources, Dirichlet regularizer; docs/method.md section 10)",
    )
    source_triangles_option(distance)
    max_distance_option(distance)
    max_iterations_option(distance)
    repair_option(distance)
    solver_options(distance)


def _regularization(args: argparse.Namespace, mesh) -> dict:
    """DistanceSolver keywords from --regularizer, --beta-hat, --directions and --source-triangles."""
    from ..geometry.line_field import read_directions

    if args.directions is None:
        if args.regularizer == "vector_field":
            raise ValueError("expected --directions FILE with --regularizer vector_field, got none")
        return {"regularizer": args.regularizer, "beta_hat": args.beta_hat,  # the solver refuses a lone beta_hat
                "source_triangles": args.source_triangles}
    if args.regularizer != "vector_field":
        raise ValueError(f"expected --directions only with --regularizer vector_field, "
                         f"got --regularizer {args.regularizer}")
    field = read_directions(args.directions, mesh)
    return {"regularizer": args.regularizer, "beta_hat": args.beta_hat, "vector_field": field,
            "source_triangles": args.source_triangles}


def run(args: argparse.Namespace) -> int:
    from ..output.export import save_vtu

    check_output(args.output, OUTPUT_EXTENSIONS, "--output")
    if args.png is not None:
        check_output(args.png, (".png",), "--png")
    if args.sources is None and args.curve is None:
        raise ValueError("expected --sources or --curve, got neither")
    if args.closed and args.curve is None:
        raise ValueError("expected --closed with a --curve, got no --curve")
    mesh = load(args.mesh, args.repair)
    n = mesh.n_vertices if mesh.input_index is None else mesh.input_index.size
    planned = [(args.output, values_bytes(args.output, n, mesh.n_elements), "--output")]
    if args.png is not None:
        planned.append((args.png, PICTURE_BYTES, "--png"))
    check_room(planned)                       # before the solve, not after it
    sources, where, described = None, {}, []
    if args.sources is not None and args.sources.lower().endswith(".csv"):
        where["points"], text = parse_surface_points(args.sources, mesh, "--sources", args.max_distance)
        described.append(text)
    elif args.sources is not None:
        sources, text = parse_sources(args.sources, mesh)
        described.append(text)
    if args.curve is not None:
        where["curve"], text = parse_surface_points(args.curve, mesh, "--curve", args.max_distance)
        where["closed"] = args.closed
        described.append(("the closed curve through " if args.closed else "the curve through ") + text)
    solver, result = solve(mesh, sources, args.alpha_hat, args.device, args.dtype, verbose=not args.quiet,
                           where=where, quiet=args.quiet, options=single_source_options(args),
                           **_regularization(args, mesh))
    if args.polish and result.converged:
        result = result.polish()
    elif args.polish:
        warn("--polish skipped: the ADMM did not converge, the distance written is its iterate")
    values = result.signed_distance if args.closed else result.distance
    field = "signed_distance" if args.closed else "distance"
    called = "the " + field.replace("_", " ")
    if args.output.lower().endswith(".vtu"):
        write_or_rescue(args.output, file_values(mesh, values), "--output", called,
                        write=lambda target: save_vtu(target, mesh, {field: values}))
    else:
        write_or_rescue(args.output, file_values(mesh, values), "--output", called)
    written = [args.output]
    if args.png is not None:
        marked = sources if args.sources is not None and args.sources.strip().lower() != "boundary" else None
        _picture(args, mesh, solver, result, marked)
        written.append(args.png)
    if not args.quiet:
        print(summary(os.path.basename(args.mesh), mesh, " and ".join(described), solver, result, written))
    return exit_status(result)


def _picture(args: argparse.Namespace, mesh, solver, result, marked) -> None:
    """The --png of a solve: a cut of a tetrahedral mesh; a point cloud as splats; a surface with its
    source vertices and points marked and its curves drawn, a signed distance diverging around 0."""
    import numpy as np

    from ..output.render import render_cut, render_distance, render_points

    title = f"{os.path.basename(args.mesh)}: regularized geodesic distance, alpha_hat {solver.alpha_hat:g}"
    if mesh.element_dim == 3:
        render_cut(mesh, result.distance, args.png, title=f"{title}, cut z = centre")
        return
    if mesh.element_weights is not None:
        render_points(mesh.vertices, result.distance, args.png, sources=marked, title=title)
        return
    shown, values, curves = mesh, result.distance, []
    if "refined_mesh" in result:           # the refined mesh has the points and curves as vertices and edges
        shown, values, curves = result.refined_mesh, result.refined_distance, list(result.refined_curves)
        on_curves = np.concatenate(curves) if curves else np.zeros(0, dtype=np.int64)
        points = np.setdiff1d(np.flatnonzero(values == 0), on_curves)
        marked = points if marked is None else np.union1d(marked, points)
    if args.closed:
        values = result.refined_signed_distance
        top = float(np.max(np.abs(values[np.isfinite(values)]), initial=0.0)) or 1.0
        render_distance(shown, values, args.png, sources=marked, curves=curves, cmap="RdBu_r", limits=(-top, top),
                        label="signed distance", title=f"{title}, signed (negative on the curve's left)")
    else:
        render_distance(shown, values, args.png, sources=marked, curves=curves, title=title)
