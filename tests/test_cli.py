"""The ``warp-regdist`` command line (warp_regdist.cli.main), run in-process."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.cli import main

DATA = Path(__file__).parent / "data"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path):
    """(width, height) from the IHDR chunk of a PNG file."""
    data = Path(path).read_bytes()
    assert data[:8] == PNG_SIGNATURE
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Small meshes on disk: a closed icosphere (OFF), two disjoint spheres (OBJ), an open grid (PLY)."""
    folder = tmp_path_factory.mktemp("meshes")
    sphere = trimesh.creation.icosphere(subdivisions=2)
    sphere.export(folder / "sphere.off")
    pair = trimesh.util.concatenate([sphere, sphere.copy().apply_translation([3.0, 0.0, 0.0])])
    pair.export(folder / "pair.obj")
    k = 8
    x, y = np.meshgrid(np.linspace(0.0, 1.0, k), np.linspace(0.0, 1.0, k))
    a = (np.arange(k - 1)[None, :] + k * np.arange(k - 1)[:, None]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + k + 1], 1), np.stack([a, a + k + 1, a + k], 1)])
    grid = trimesh.Trimesh(np.stack([x.ravel(), y.ravel(), np.zeros(k * k)], 1), faces, process=False)
    grid.export(folder / "grid.ply")
    (folder / "garbage.off").write_text("OFF\n3 1 0\n0 0 0\n1 0\nnot a mesh\n")
    (folder / "points.txt").write_text("0 0 0\n1 0 0\n0 1 0\n")
    (folder / "d.npy").mkdir()  # a directory where a file is expected
    return folder


def run(capsys, *argv):
    """main(argv) -> (exit status, stdout, stderr), without the line that announces a first compile
    (it depends on the kernel cache, not on the command)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    err = "".join(line for line in err.splitlines(keepends=True) if not line.startswith("warp-regdist: compiling"))
    return code, out, err


def test_help_in_process(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0
    assert "distance" in out and "demo" in out
    code, out, _ = run(capsys, "distance", "--help")
    assert code == 0 and "exit status" in out and "--sources" in out


def test_version(capsys):
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.strip() == f"warp-regdist {wrd.__version__}"


def test_console_script_help():
    script = Path(sys.executable).parent / "warp-regdist"
    if not script.exists():
        pytest.skip(f"console script not installed next to {sys.executable}")
    proc = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: warp-regdist")


def test_distance_npy_and_csv_round_trip(meshes, tmp_path, capsys):
    npy, csv, png = tmp_path / "u.npy", tmp_path / "u.csv", tmp_path / "u.png"
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", "0, 5", "--output", npy, "--png", png)
    assert code == 0, err
    assert "162 vertices, 320 faces" in out and "source vertices 0, 5" in out and "converged" in out
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", "5,0", "--output", csv, "--quiet")
    assert code == 0, err
    assert out == ""
    u_npy, u_csv = np.load(npy), np.loadtxt(csv)
    assert u_npy.shape == (162,) and u_npy.dtype == np.float64
    np.testing.assert_array_equal(u_csv, u_npy)  # full precision text
    assert u_npy[0] == 0.0 and u_npy[5] == 0.0 and np.all(u_npy[1:5] > 0.0)
    expected = wrd.DistanceSolver(wrd.load_mesh(meshes / "sphere.off"), alpha_hat=0.05, device="cpu").solve([0, 5])
    np.testing.assert_allclose(u_npy, expected.distance, rtol=1e-9, atol=1e-12)
    assert png_size(png)[0] > 1000


def test_distance_polish_is_within_the_exact_minimizer(tmp_path, capsys):
    """--polish on spot from vertex 2272 against the stored exact minimizer of the paper's problem (Clarabel):
    measured 3.6e-5 of the max distance, where the ADMM's distance is 0.30% away."""
    exact = np.loadtxt(Path(__file__).parent / "data" / "spot_rr__2272__a0.05_exact.txt")
    code, out, err = run(capsys, "distance", wrd.data_path("spot_rr.off"), "--sources", "2272", "--polish",
                         "--source-triangles", "gradient", "--output", tmp_path / "u.npy")
    assert code == 0, err
    assert re.search(r"polished: moved 0\.\d\d% of the largest distance", out), out
    assert np.abs(np.load(tmp_path / "u.npy") - exact).max() <= 2e-4 * exact.max()


def test_polish_of_an_unconverged_solve_is_skipped_with_a_warning(meshes, tmp_path, capsys):
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", "0", "--polish",
                         "--max-iterations", "2", "--output", tmp_path / "u.npy")
    assert code == 1 and "NOT converged" in out and "error not yet estimated" in out
    lines = err.strip().splitlines()
    assert len(lines) == 2 and lines[1] == ("warp-regdist: warning: --polish skipped: the ADMM did not converge, "
                                            "the distance written is its iterate")


def test_distance_csv_writes_inf_for_unreachable(meshes, tmp_path, capsys):
    csv = tmp_path / "u.csv"
    code, _, err = run(capsys, "distance", meshes / "pair.obj", "--sources", "3", "--output", csv, "--alpha-hat", "0.1")
    assert code == 0, err
    lines = csv.read_text().splitlines()
    assert len(lines) == 324 and lines[3] == "0.0"
    assert lines[162:] == ["inf"] * 162
    u = np.loadtxt(csv)
    assert np.all(np.isfinite(u[:162])) and np.all(np.isinf(u[162:]))


def test_distance_from_boundary(meshes, tmp_path, capsys):
    npy = tmp_path / "u.npy"
    code, out, err = run(capsys, "distance", meshes / "grid.ply", "--sources", "boundary", "--output", npy)
    assert code == 0, err
    assert "28 boundary vertices" in out
    mesh = wrd.load_mesh(meshes / "grid.ply")
    u = np.load(npy)
    boundary = wrd.boundary_vertices(mesh)
    assert np.all(u[boundary] == 0.0) and u.max() > 0.0


def test_not_converged_is_a_warning(meshes, tmp_path, capsys):
    npy = tmp_path / "u.npy"
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", "0", "--max-iterations", "2",
                         "--output", npy)
    assert code == 1
    assert npy.exists()
    assert "NOT converged" in out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warp-regdist: warning: the ADMM did not converge")


# expected: the whole error line after "warp-regdist: error: ", with {m} / {t} the mesh and
# output folders; "..." stands for a part that is not ours (a parser's or the device list)
BAD_INPUTS = {
    "missing mesh": (["distance", "{m}/nope.off", "--sources", "0", "--output", "{t}/u.npy"],
                     "expected an existing mesh file, got '{m}/nope.off' (no such file)"),
    "bad mesh": (["distance", "{m}/garbage.off", "--sources", "0", "--output", "{t}/u.npy"],
                 "could not read mesh file '{m}/garbage.off': ..."),
    "mesh is a directory": (["distance", "{t}", "--sources", "0", "--output", "{t}/u.npy"],
                            "expected an existing mesh file, got '{t}' (no such file)"),
    "bad mesh extension": (["distance", "{m}/points.txt", "--sources", "0", "--output", "{t}/u.npy"],
                           "expected a mesh file ending in .obj, .off, .ply, .stl, .msh, .vtk, .vtu or .mesh, "
                           "got '{m}/points.txt'"),
    "letters as sources": (["distance", "{m}/sphere.off", "--sources", "a,b", "--output", "{t}/u.npy"],
                           "expected --sources as comma-separated vertex indices (e.g. 2272,17) or 'boundary', "
                           "got 'a,b'"),
    "empty source": (["distance", "{m}/sphere.off", "--sources", "0,,1", "--output", "{t}/u.npy"],
                     "expected --sources as comma-separated vertex indices (e.g. 2272,17) or 'boundary', got '0,,1'"),
    "source out of range": (["distance", "{m}/sphere.off", "--sources", "0,162", "--output", "{t}/u.npy"],
                            "expected --sources in [0, 161] (the mesh has 162 vertices), got 162"),
    "negative source": (["distance", "{m}/sphere.off", "--sources", "-1", "--output", "{t}/u.npy"],
                        "expected --sources in [0, 161] (the mesh has 162 vertices), got -1"),
    "boundary of closed mesh": (["distance", "{m}/sphere.off", "--sources", "boundary", "--output", "{t}/u.npy"],
                                "expected a mesh with a boundary for --sources boundary, got a closed mesh"),
    "output extension": (["distance", "{m}/sphere.off", "--sources", "0", "--output", "{t}/u.txt"],
                         "expected --output ending in .npy or .csv or .vtu, got '{t}/u.txt'"),
    "png extension": (["distance", "{m}/sphere.off", "--sources", "0", "--output", "{t}/u.npy", "--png", "{t}/u.jpg"],
                      "expected --png ending in .png, got '{t}/u.jpg'"),
    "output directory": (["distance", "{m}/sphere.off", "--sources", "0", "--output", "{t}/no/u.npy"],
                         "expected --output in an existing directory, got '{t}/no/u.npy' (no directory '{t}/no')"),
    "negative alpha_hat": (["distance", "{m}/sphere.off", "--sources", "0", "--alpha-hat", "-0.5", "--output",
                            "{t}/u.npy"], "expected a finite alpha_hat >= 0, got -0.5"),
    "unavailable device": (["distance", "{m}/sphere.off", "--sources", "0", "--device", "cuda:99", "--output",
                            "{t}/u.npy"], "expected a Warp device among [...], got 'cuda:99'"),
    "demo output is a file": (["demo", "--output", "{m}/sphere.off"],
                              "expected --output as a directory, got the file '{m}/sphere.off'"),
    "output is a directory": (["distance", "{m}/sphere.off", "--sources", "0", "--output", "{m}/d.npy"],
                              "expected --output as a file name, got the directory '{m}/d.npy'"),
    "allpairs output is a directory": (["allpairs", "{m}/sphere.off", "--output", "{m}/d.npy"],
                                       "expected --output as a file name, got the directory '{m}/d.npy'"),
    "polish with the hessian": (["distance", "{m}/sphere.off", "--sources", "0", "--regularizer", "hessian",
                                 "--alpha-hat", "0.001", "--polish", "--output", "{t}/u.npy"],
                                "expected the Dirichlet regularizer on a mesh to polish, got 'hessian'"),
}


@pytest.mark.parametrize("argv, expected", BAD_INPUTS.values(), ids=BAD_INPUTS.keys())
def test_bad_input_is_one_line_and_exit_2(meshes, tmp_path, capsys, argv, expected):
    argv = [a.format(m=meshes, t=tmp_path) for a in argv]
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    pattern = ".+".join(re.escape(part) for part in expected.format(m=meshes, t=tmp_path).split("..."))
    assert re.fullmatch("warp-regdist: error: " + pattern, lines[0]), lines[0]
    assert not any(tmp_path.iterdir())  # nothing written


def test_usage_error_exits_2(capsys):
    code, _, err = run(capsys, "distance", "mesh.off")  # --sources and --output missing
    assert code == 2
    assert "required" in err and "Traceback" not in err


def test_demo_writes_npy_and_png(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    code, out, err = run(capsys, "demo", "--output", out_dir, "--device", "cpu")
    assert code == 0, err
    assert "4764 vertices" in out and "2272" in out and "alpha_hat 0.05" in out
    assert str(out_dir / "distance.png") in out
    u = np.load(out_dir / "distance.npy")
    reference = np.loadtxt(DATA / "spot_rr__2272__a0.05_rgd.txt")
    assert np.max(np.abs(u - reference)) < 1e-2 * reference.max()
    width, height = png_size(out_dir / "distance.png")
    assert width > 1200 and height > 500
    assert (out_dir / "distance.png").stat().st_size > 100_000


def test_max_distance_admits_points_farther_from_the_surface(meshes, tmp_path, capsys):
    far = tmp_path / "far.csv"
    far.write_text("0,0,3\n")                      # 2 from the unit sphere, whose box diagonal is 3.5
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", far, "--output", tmp_path / "u.npy")
    assert code == 2 and "expected points within 0.173205 of the surface (max_distance), got point 0" in err
    code, out, err = run(capsys, "distance", meshes / "sphere.off", "--sources", far, "--max-distance", "2.5",
                         "--output", tmp_path / "u.npy")
    assert code == 0, err
    assert "moved onto the surface by at most 2" in out
    u = np.load(tmp_path / "u.npy")
    top = np.argmax(wrd.load_mesh(meshes / "sphere.off").vertices[:, 2])   # nearest to the point's foot (0, 0, 1)
    assert u[top] < 0.05 * u.max()


def test_a_first_compile_is_announced(tmp_path, capsys, monkeypatch):
    import warp as wp

    from warp_regdist.cli.common import announce_compile

    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    announce_compile("float32", quiet=False)
    announcement = (f"warp-regdist: compiling the Warp kernels for float32, once (seconds to a minute; they are "
                    f"cached in {tmp_path})\n")
    assert capsys.readouterr().err == announcement
    (tmp_path / "wp_warp_regdist_pcg_float32_16_0123abc").mkdir()
    announce_compile("float32", quiet=False)
    announce_compile("float64", quiet=True)
    assert capsys.readouterr().err == ""
