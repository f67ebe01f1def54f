"""This package vs the heat method vs exact polyhedral geodesics (docs/method.md section 7).

    python benchmarks/compare.py            # all meshes, tables, CSV, both pictures
    python benchmarks/compare.py --quick    # spot and the generated blob only, no pictures
    python benchmarks/compare.py --cloud 100000   # point clouds sampled from spot (cloud.csv, point_cloud.png)

Per mesh and source: this package (``DistanceSolver``, alpha_hat in ALPHA_HATS), the heat
method (potpourri3d, t = t_coef * mean edge length^2, t_coef in T_COEFS) and exact
geodesics (libigl's MMP ``exact_geodesic``).  Columns: setup and solve time (median over
REPEATS solves; this package after one warm-up solve in the process, so the Warp kernels
are loaded), max and mean |u - u_exact| in % of max u_exact, and
``metrics.smoothness(u, k=K)`` (lower = smoother).  Prints a markdown table, writes
benchmarks/results/compare.csv, docs/compare_grid.png (rows = methods, columns = meshes,
the same isolines for all methods of a mesh) and docs/alpha_hat_grid.png (spot, one
source, alpha_hat and heat t side by side).  Needs the ``compare`` extra (potpourri3d).

``--cloud N``: N points sampled from spot (point 0 at vertex 2272), this package's
``PointCloud`` against potpourri3d's ``PointCloudHeatSolver``; errors at the points against
the exact distance on the mesh and against this package's mesh solve (alpha_hat 0.05) on spot
split twice at its edge midpoints (76k vertices, the same surface), both interpolated from the
vertices; benchmarks/results/cloud.csv and docs/point_cloud.png.
"""

import argparse
import io
import os
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import evaluation_meshes  # noqa: E402
import meshes  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import write_csv  # noqa: E402
from warp_regdist import metrics  # noqa: E402

ALPHA_HATS = (0.0, 0.01, 0.05, 0.1)
T_COEFS = (1.0, 10.0, 100.0)
K = 100
REPEATS = 3
CASES = (  # name, source vertex (None: the vertex nearest spot's 2272, or the blob's source)
    ("spot_rr", 2272),
    ("cat_rr", 0),
    ("bent_pipe_closed_lr", 4882),
    ("spot_rr_holes", None),
    ("blob", None),
)
GRID_ALPHA_HATS = (0.0, 0.02, 0.05, 0.1, 0.2)
GRID_T_COEFS = (1.0, 10.0, 100.0, 1000.0)
VIEWS = {"spot_rr": (35, 15), "cat_rr": (35, 15), "bent_pipe_closed_lr": (35, 15),
         "spot_rr_holes": (35, 15), "blob": (180, 20)}
"""Camera (azimuth, elevation) per mesh: the side away from the source, where the methods differ."""
RESULTS = os.path.join(HERE, "results")
DOCS = os.path.join(HERE, "..", "docs")


def load_case(name, source):
    """(mesh, source vertex) of a case, or None when the shared mesh is absent."""
    if name == "blob":
        mesh = evaluation_meshes.blob(28)
        return mesh, evaluation_meshes.source_vertex(mesh)
    mesh = meshes.shared_mesh(name)
    if mesh is None:
        return None
    if source is None:
        spot = meshes.shared_mesh("spot_rr")
        source = int(np.argmin(np.linalg.norm(mesh.vertices - spot.vertices[2272], axis=1)))
    return mesh, source


def median_time(fn, repeats):
    """(median seconds, last result) of ``repeats`` calls of fn()."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def exact_distance(mesh, source):
    """Exact polyhedral geodesic distance (MMP, libigl) from one vertex: (seconds, (n,))."""
    import igl
    F = mesh.faces.astype(np.int64)
    return median_time(lambda: igl.exact_geodesic(mesh.vertices, F, VS=np.array([source]),
                                                  VT=np.arange(mesh.n_vertices)), 1)


def heat_solver(mesh, t_coef):
    """potpourri3d's heat-method solver: (setup seconds, solver)."""
    import potpourri3d as pp3d
    return median_time(lambda: pp3d.MeshHeatMethodDistanceSolver(mesh.vertices, mesh.faces, t_coef=t_coef), 1)


def heat_distance(mesh, source, t_coef, repeats=REPEATS):
    """Heat-method distance from one vertex: (setup s, solve s, (n,))."""
    setup, solver = heat_solver(mesh, t_coef)
    solve, u = median_time(lambda: solver.compute_distance(source), repeats)
    return setup, solve, u


def regularized_distance(mesh, source, alpha_hat, repeats=REPEATS):
    """This package's distance from one vertex: (setup s, solve s, result)."""
    setup, solver = median_time(lambda: wrd.DistanceSolver(mesh, alpha_hat=alpha_hat, device="cpu"), 1)
    solve, res = median_time(lambda: solver.solve([source]), repeats)
    return setup, solve, res


def warm_up():
    """Load the Warp kernels once per process (untimed), on a small blob."""
    wrd.DistanceSolver(evaluation_meshes.blob(6), alpha_hat=0.05, device="cpu").solve([0])


def evaluate(name, mesh, source, repeats):
    """Rows (dicts) and fields {method label: (n,)} for one mesh and source."""
    exact_s, exact = exact_distance(mesh, source)
    fields, rows = {"exact (MMP)": exact}, []
    timing = {"exact (MMP)": (0.0, exact_s, "")}
    for t in T_COEFS:
        setup, solve, u = heat_distance(mesh, source, t, repeats)
        label = f"heat t_coef={t:g}"
        fields[label], timing[label] = u, (setup, solve, "")
    for a in ALPHA_HATS:
        setup, solve, res = regularized_distance(mesh, source, a, repeats)
        label = f"this alpha_hat={a:g}"
        fields[label], timing[label] = res.distance, (setup, solve, res.iterations)
    labels = list(fields)
    smooth = metrics.smoothness(np.stack([fields[k] for k in labels], 1), wrd.build_operators(mesh), K)
    scale = exact.max()
    for label, s in zip(labels, smooth):
        err = np.abs(fields[label] - exact) / scale * 100
        setup, solve, iterations = timing[label]
        rows.append(dict(mesh=name, vertices=mesh.n_vertices, source=source, method=label,
                         setup_s=setup, solve_s=solve, admm_iterations=iterations,
                         max_error_pct=err.max(), mean_error_pct=err.mean(), smoothness=s))
    return rows, fields


def markdown(rows):
    lines = [f"| mesh (n, source) | method | setup | solve | max err % | mean err % | smoothness (k={K}) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        it = f" ({r['admm_iterations']} it.)" if r["admm_iterations"] != "" else ""
        lines.append(f"| {r['mesh']} ({r['vertices']:,}, {r['source']}) | {r['method']} | {r['setup_s']:.3f} s "
                     f"| {r['solve_s']:.3f} s{it} | {r['max_error_pct']:.2f} | {r['mean_error_pct']:.2f} "
                     f"| {r['smoothness']:.2e} |")
    return "\n".join(lines)


def tile(cells, path, row_labels, titles, cell_width=2.2):
    """Tile rendered PNGs (cells[r][c] a path or None, titles[r][c] a str or None) into one PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image
    images = [[plt.imread(c) if c else None for c in row] for row in cells]
    aspect = max(im.shape[0] / im.shape[1] for row in images for im in row if im is not None)
    fig, axes = plt.subplots(len(cells), len(cells[0]), squeeze=False,
                             figsize=(cell_width * len(cells[0]) + 0.9, cell_width * aspect * len(cells) + 0.3))
    for r, row in enumerate(images):
        for c, im in enumerate(row):
            ax = axes[r][c]
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
            if im is not None:
                ax.imshow(im, interpolation="lanczos")
            if c == 0:
                ax.set_ylabel(row_labels[r], fontsize=8)
            if titles[r][c]:
                ax.set_title(titles[r][c], fontsize=8)
    fig.subplots_adjust(left=0.07, right=0.995, top=0.97, bottom=0.005, wspace=0.02, hspace=0.02)
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=110)
    plt.close(fig)
    # a 256-colour palette keeps the picture under 500 KB
    Image.open(buffer).convert("RGB").quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)


def render_cells(tmp, mesh, source, fields, levels, view, tag):
    """Render each field of one mesh to tmp/<tag>_<i>.png: list of paths."""
    from warp_regdist.output.render import render_distance
    paths = []
    for i, u in enumerate(fields):
        path = os.path.join(tmp, f"{tag}_{i}.png")
        render_distance(mesh, u, path, sources=[source], isolines=levels, view=[view])
        paths.append(path)
    return paths


def compare_grid(cases, path):
    """docs/compare_grid.png: rows = methods, columns = meshes; isolines at exact levels."""
    with tempfile.TemporaryDirectory() as tmp:
        columns, labels = [], None
        for name, mesh, source, fields in cases:
            labels = list(fields)
            levels = np.linspace(0, fields["exact (MMP)"].max(), 17)[1:-1]
            columns.append(render_cells(tmp, mesh, source, [fields[k] for k in labels], levels,
                                        VIEWS[name], name))
        cells = [[col[r] for col in columns] for r in range(len(labels))]
        titles = [[c[0] if r == 0 else None for c in cases] for r in range(len(labels))]
        tile(cells, path, labels, titles)


def alpha_hat_grid(path):
    """docs/alpha_hat_grid.png: spot from 2272, this package's alpha_hat (top row) vs heat t (bottom)."""
    case = load_case("spot_rr", 2272)
    name, (mesh, source) = ("spot_rr", case) if case else ("blob", load_case("blob", None))
    view = VIEWS[name]
    ours = [regularized_distance(mesh, source, a, 1)[2].distance for a in GRID_ALPHA_HATS]
    heat = [heat_distance(mesh, source, t, 1)[2] for t in GRID_T_COEFS]
    levels = np.linspace(0, ours[0].max(), 22)[1:-1]
    with tempfile.TemporaryDirectory() as tmp:
        top = render_cells(tmp, mesh, source, ours, levels, view, "ours")
        bottom = render_cells(tmp, mesh, source, heat, levels, view, "heat") + [None]
        titles = [[f"alpha_hat = {a:g}" for a in GRID_ALPHA_HATS],
                  [f"t_coef = {t:g}" for t in GRID_T_COEFS] + [None]]
        tile([top, bottom], path, ["this package", "heat method"], titles, cell_width=2.6)


def clouds(count):
    """Rows of the point-cloud comparison on ``count`` points sampled from spot, and the picture."""
    import potpourri3d as pp3d
    import trimesh

    mesh, source = wrd.load_mesh(wrd.data_path("spot_rr.off")), 2272
    P, _ = trimesh.sample.sample_surface(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), count - 1, seed=0)
    P = np.concatenate([mesh.vertices[source][None], P])
    at = wrd.surface_points(mesh, P)

    def at_points(u):
        return np.array([np.asarray(b) @ u[mesh.faces[f]] for f, b in at])

    _, exact = exact_distance(mesh, source)
    # the mesh solve on spot split twice at its edge midpoints (76k vertices, the same surface and
    # source vertex), at a resolution near the cloud's
    fine_V, fine_F = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(mesh.vertices, mesh.faces))
    fine = wrd.Mesh(fine_V, fine_F)
    fine_at = wrd.surface_points(fine, P)
    fine_u = wrd.DistanceSolver(fine, alpha_hat=0.05).solve([source]).distance
    references = {"exact": at_points(exact),
                  "mesh 0.05": np.array([np.asarray(b) @ fine_u[fine.faces[f]] for f, b in fine_at])}
    fields, rows = {"exact on the mesh": references["exact"]}, []
    build, cloud = median_time(lambda: wrd.PointCloud(P), 1)
    for a in (0.0, 0.05):
        solver = wrd.DistanceSolver(cloud, alpha_hat=a)
        solve, res = median_time(lambda: solver.solve([0]), 1)
        fields[f"this PointCloud, alpha_hat={a:g}"] = res.distance
        rows.append((f"this PointCloud, alpha_hat={a:g}", build, solve, res.iterations, res.distance))
    setup, heat = median_time(lambda: pp3d.PointCloudHeatSolver(P), 1)
    solve, u = median_time(lambda: heat.compute_distance(0), 1)
    fields["potpourri3d PointCloudHeatSolver"] = u
    rows.append(("potpourri3d PointCloudHeatSolver", setup, solve, "", u))
    out = []
    for method, setup, solve, iterations, u in rows:
        row = dict(points=count, method=method, setup_s=setup, solve_s=solve, admm_iterations=iterations)
        for name, ref in references.items():
            far = ref > 0.05 * ref.max()
            row[f"median_rel_error_vs_{name.replace(' ', '_')}_pct"] = 100 * np.median(np.abs(u[far] - ref[far]) / ref[far])
        out.append(row)
    _cloud_picture(P, fields, os.path.join(DOCS, "point_cloud.png"))
    return out


def _cloud_picture(P, fields, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    show = np.random.default_rng(0).permutation(len(P))[:30000]
    fig = plt.figure(figsize=(4.2 * len(fields), 4.4))
    top = max(np.nanmax(u) for u in fields.values())
    centre, half = P.mean(axis=0), 0.5 * np.ptp(P, axis=0).max()
    for i, (label, u) in enumerate(fields.items()):
        ax = fig.add_subplot(1, len(fields), i + 1, projection="3d")
        colour = plt.get_cmap("viridis")(u[show] / top)
        colour[np.mod(u[show] / top * 16, 1.0) < 0.12, :3] = 0.1           # 16 isoline bands
        ax.scatter(P[show, 0], P[show, 2], P[show, 1], c=colour, s=2.0, linewidths=0)
        for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre[[0, 2, 1]]):
            set_lim(c - 0.75 * half, c + 0.75 * half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(15, 35)
        ax.set_axis_off()
        ax.set_title(label, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="spot and the blob only, 1 repeat, no pictures")
    ap.add_argument("--cloud", type=int, metavar="N", help="only the point-cloud comparison, on N points")
    args = ap.parse_args()
    try:
        import potpourri3d  # noqa: F401
    except ImportError:
        sys.exit("compare.py needs potpourri3d: pip install -e '.[compare]'")
    if args.cloud is not None:
        warm_up()
        rows = clouds(args.cloud)
        for row in rows:
            print(" | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in row.values()))
        write_csv(rows, os.path.join(RESULTS, "cloud.csv"))
        return
    repeats = 1 if args.quick else REPEATS
    warm_up()
    rows, rendered = [], []
    for name, source in CASES:
        if args.quick and name not in ("spot_rr", "blob"):
            continue
        case = load_case(name, source)
        if case is None:
            print(f"skipping {name}: ../shared/meshes/{name}.off not found")
            continue
        mesh, source = case
        r, fields = evaluate(name, mesh, source, repeats)
        rows += r
        rendered.append((name, mesh, source, fields))
        print(markdown(r).split("\n", 2)[2], flush=True)
    print(markdown(rows))
    write_csv(rows, os.path.join(RESULTS, "compare.csv"))
    if not args.quick:
        compare_grid(rendered, os.path.join(DOCS, "compare_grid.png"))
        alpha_hat_grid(os.path.join(DOCS, "alpha_hat_grid.png"))


if __name__ == "__main__":
    main()
