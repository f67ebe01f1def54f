"""The ``volume`` subcommand: a closed surface tetrahedralized, then the distance inside it."""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from .common import (DEMO_ALPHA_HAT, LISTED_SOURCES, check_output, exit_status, max_iterations_option,
                     single_source_options, load, parse_sources, read_xyz, solve,
                     solver_options, subcommand, summary)


LOCKED_OUTPUTS = ("output", "png")


def _insert_points(surface, xyz):
    """The surface refined at the closest surface points of xyz (their vertices are kept by TetGen,
    which numbers the surface's vertices first), and how far each point moved."""
    from ..geometry.surface_points import check_surface_points, refine, surface_points

    points, moved = surface_points(surface, xyz, return_distance=True)
    return refine(surface, *check_surface_points(surface, points, "--sources")), moved


def add_parser(sub) -> None:
    volume = subcommand(
        sub, "volume",
        help="tetrahedralize a closed surface, then the distance inside it (.vtu, optional grid)",
        description="Fill a closed triangle surface (STL, OBJ, OFF, PLY) with tetrahedra (TetGen,\n"
        "pip install 'warp-regdist[volume]'), solve the regularized distance inside from the\n"
        "boundary or from points, write it per vertex (.vtu) and optionally sampled on a regular\n"
        "grid (NaN outside the solid) for SDF-like use.",
    )
    volume.add_argument("surface", metavar="SURFACE", help="closed triangle surface (.stl, .obj, .off, .ply)")
    volume.add_argument(
        "--sources",
        required=True,
        metavar="boundary|FILE",
        help="'boundary' (distance to the surface: depth) or a .csv file of rows 'x,y,z': points moved "
        "to the closest surface point (within 5%% of the bounding box diagonal) and inserted into the "
        "surface before it is tetrahedralized, so that each is a vertex of the tetrahedral mesh",
    )
    volume.add_argument("--alpha-hat", type=float, default=DEMO_ALPHA_HAT, metavar="A",
                        help="scale-invariant regularization weight >= 0; alpha = A volume^(1/3) (default: 0.05)")
    volume.add_argument("--output", required=True, metavar="FILE",
                        help="the tetrahedral mesh with point data 'distance' (.vtu, opens in ParaView)")
    volume.add_argument("--png", metavar="FILE", help="also write the distance's cut by the plane z = centre (.png)")
    volume.add_argument("--grid", type=int, metavar="N",
                        help="also sample the distance on a regular grid of N points along the longest side "
                        "of the bounding box (needs --grid-output)")
    volume.add_argument("--grid-output", metavar="FILE",
                        help="the grid samples: .npy (nx, ny, nz) array, or .npz with 'values', 'origin' and "
                        "'spacing' (point (i, j, k) at origin + spacing (i, j, k)); NaN outside the solid")
    volume.add_argument("--max-edge", type=float, metavar="L",
                        help="longest interior edge in the surface's units (default without --max-volume: the "
                        "smaller of the surface's mean edge and alpha = A volume^(1/3), so the interior resolves "
                        "the distance's smooth cap)")
    volume.add_argument("--max-volume", type=float, metavar="V",
                        help="largest tetrahedron volume in the surface's units cubed (replaces the default --max-edge)")
    volume.add_argument("--quality", type=float, default=1.5, metavar="Q",
                        help="largest radius-edge ratio of a tetrahedron, > 1 (default: 1.5)")
    max_iterations_option(volume)
    solver_options(volume)


def run(args: argparse.Namespace) -> int:
    import time

    from ..arguments import parse_device
    from ..atomic_write import write_atomic
    from ..output.export import save_vtu
    from ..output.render import render_cut
    from ..geometry.tetrahedralize import tetrahedralize
    from ..geometry.volume_grid import sample_on_grid

    check_output(args.output, (".vtu",), "--output")
    if args.png is not None:
        check_output(args.png, (".png",), "--png")
    parse_device(args.device)                      # before the tetrahedralization says anything
    if (args.grid is None) != (args.grid_output is None):
        raise ValueError("expected --grid N and --grid-output FILE together, got only "
                         f"{'--grid' if args.grid_output is None else '--grid-output'}")
    if args.grid is not None:
        check_output(args.grid_output, (".npy", ".npz"), "--grid-output")
        if args.grid < 2:
            raise ValueError(f"expected --grid N >= 2, got {args.grid}")
    if args.max_edge is not None and not (np.isfinite(args.max_edge) and args.max_edge > 0):
        raise ValueError(f"expected --max-edge as a length > 0, got {args.max_edge}")
    if args.sources.strip().lower() != "boundary" and not args.sources.lower().endswith(".csv"):
        raise ValueError(f"expected --sources 'boundary' or a .csv file of 'x,y,z' rows, got {args.sources!r}")
    points = None if args.sources.strip().lower() == "boundary" else read_xyz(args.sources, "--sources")
    surface = load(args.surface)
    if points is not None:
        refined, moved = _insert_points(surface, points)
    name = os.path.basename(args.surface)
    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    say(f"{name}: tetrahedralizing {surface.n_vertices} vertices, {surface.n_elements} faces with TetGen...")
    start = time.perf_counter()
    try:
        max_edge = "auto" if args.max_edge is None else args.max_edge
        mesh = tetrahedralize(surface if points is None else refined.mesh, max_volume=args.max_volume, quality=args.quality, max_edge=max_edge,
                              alpha_hat=args.alpha_hat)
    except ModuleNotFoundError as exc:
        raise ValueError(str(exc)) from None
    if args.max_edge is None and args.max_volume is None:
        from ..geometry.tetrahedralize import interior_edge

        max_edge = interior_edge(surface.vertices, surface.faces, args.alpha_hat)
    bounds = "" if max_edge == "auto" else f", max edge {max_edge:.3g}"
    bounds += "" if args.max_volume is None else f", max volume {args.max_volume:g}"
    meshed = (f"TetGen: {mesh.n_elements} tetrahedra (quality {args.quality:g}{bounds}, "
              f"{mesh.components().max() + 1} connected component(s)) in {time.perf_counter() - start:.2f} s")
    say(meshed)
    if points is None:
        sources, described = parse_sources(args.sources, mesh)
    else:
        sources = np.unique(refined.point_vertices)
        if not np.array_equal(mesh.vertices[sources], refined.mesh.vertices[sources]):
            raise RuntimeError("TetGen renumbered the surface's vertices: the point sources are lost")
        listed = ", ".join(str(s) for s in sources[:LISTED_SOURCES])
        more = f", ... ({sources.size} in all)" if sources.size > LISTED_SOURCES else ""
        described = (f"{len(points)} surface points, vertices {listed}{more} (moved onto the surface by at most "
                     f"{moved.max():.3g})")
    solver, result = solve(mesh, sources, args.alpha_hat, args.device, args.dtype, verbose=not args.quiet,
                           quiet=args.quiet, options=single_source_options(args))
    save_vtu(args.output, mesh, {"distance": result.distance})
    written = [args.output]
    if args.png is not None:
        render_cut(mesh, result.distance, args.png,
                   title=f"{name}: regularized distance, alpha_hat {solver.alpha_hat:g}, cut z = centre")
        written.append(args.png)
    if args.grid is not None:
        say(f"sampling the distance on a grid of {args.grid} points along the longest side...")
        grid = sample_on_grid(mesh, result.distance, args.grid)
        if args.grid_output.lower().endswith(".npz"):
            write_atomic(args.grid_output, lambda tmp: np.savez(tmp, values=grid.values, origin=grid.origin,
                                                                spacing=grid.spacing), "--grid-output")
        else:
            write_atomic(args.grid_output, lambda tmp: np.save(tmp, grid.values), "--grid-output",
                         size=grid.values.nbytes + 128)
        written.append(f"{args.grid_output} ({' x '.join(map(str, grid.values.shape))} grid, origin "
                       f"{np.array2string(grid.origin, precision=4, separator=', ')}, spacing {grid.spacing:.4g}, "
                       "NaN outside)")
    if not args.quiet:
        print(f"{meshed}. " + summary(name, mesh, described, solver, result, written))
    return exit_status(result)
