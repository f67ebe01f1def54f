"""The documentation stays true: the site builds strictly (a broken link or API reference
fails), the measured tables equal their CSVs, the code blocks of the README and the docs
run, every example runs at a small size, and the interactive viewer works headless
(polyscope's mock backend)."""

import os
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import warp_regdist as wrd
from warp_regdist.cli import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAGES = ["README.md"] + sorted(os.path.relpath(os.path.join(d, f), ROOT)
                               for d, _, files in os.walk(os.path.join(ROOT, "docs")) for f in files if f.endswith(".md"))
NOT_RUN = "# not run"  # first line of a code block that needs what a test machine lacks (a GPU, a cluster)


def _code_blocks(page):
    with open(os.path.join(ROOT, page), encoding="utf-8") as f:
        text = f.read()
    return [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if not b.startswith(NOT_RUN)]


def test_docs_build_strictly(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "DistanceSolver" in api and "solve_many" in api and "expected" not in api[:0]


def test_tables_equal_their_csvs():
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    try:
        import report
    finally:
        sys.path.pop(0)
    pages = report.rendered_pages(ROOT)
    assert os.path.join(ROOT, "README.md") in pages
    stale = [os.path.relpath(p, ROOT) for p, (old, new) in pages.items() if old != new]
    assert stale == [], f"run python benchmarks/report.py: {stale}"
    for _, (text, _) in pages.items():
        for body in report.MARKER.finditer(text):
            assert body.group("body").count("|") > 4 and "*Measured 20" in body.group("body")


@pytest.mark.parametrize("page", [p for p in PAGES if _code_blocks(p)])
def test_code_blocks_run(page, tmp_path, monkeypatch):
    """Each page's python blocks, in order, in one namespace, in an empty directory."""
    pytest.importorskip("tetgen")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    for i, block in enumerate(_code_blocks(page)):
        try:
            exec(compile(block, f"{page}, python block {i + 1}", "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{page}, python block {i + 1} failed: {exc!r}\n{block}") from exc


def _readme_blocks(language):
    """The README's fenced ``language`` blocks, as (first line, text), the "not run" ones left out."""
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        blocks = re.findall(rf"```{language}\n(.*?)```", f.read(), re.S)
    return [(b.splitlines()[0], b) for b in blocks if not b.startswith(NOT_RUN)]


def test_the_readme_python_runs_on_the_base_install(tmp_path, monkeypatch):
    """The README's python blocks that name no extra, in one namespace, with the extras' packages absent."""
    for extra in ("tetgen", "polyscope", "torch", "dask", "distributed", "zarr"):
        monkeypatch.setitem(sys.modules, extra, None)            # import fails as on the base install
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    base = [text for first, text in _readme_blocks("python") if "extra" not in first]
    assert len(base) >= 2
    for i, block in enumerate(base):
        exec(compile(block, f"README.md, base python block {i + 1}", "exec"), namespace)


def test_the_readme_command_lines_run_as_pasted(tmp_path):
    """The README's sh blocks through bash, from a directory laid out as the clone's root, with the
    installed ``warp-regdist`` first on the PATH (as after ``. .venv/bin/activate``)."""
    pytest.importorskip("tetgen")                               # one block is the [volume] extra's
    for name in ("warp_regdist", "examples"):
        os.symlink(os.path.join(ROOT, name), tmp_path / name)
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    blocks = _readme_blocks("sh")
    assert len(blocks) >= 2
    for first, block in blocks:
        done = subprocess.run(["bash", "-euo", "pipefail", "-c", block], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 0, f"{first}\n{done.stderr[-3000:]}"
    for written in ("u.npy", "u.png", "signed.npy", "U.npy", "run.npz", "D.npy", "depth.vtu", "cut.png"):
        assert (tmp_path / written).is_file(), written


def _sphere_files(folder):
    """A 642-vertex sphere and the same sphere with two holes, as OFF files."""
    s = trimesh.creation.icosphere(3)
    closed, holes = folder / "closed.off", folder / "holes.off"
    trimesh.Trimesh(s.vertices, s.faces, process=False).export(closed)
    centroids = s.vertices[s.faces].mean(axis=1)
    keep = (np.linalg.norm(centroids - [0.0, 0.0, 1.0], axis=1) > 0.3) & (np.linalg.norm(centroids - [1.0, 0.0, 0.0],
                                                                                      axis=1) > 0.3)
    used = np.unique(s.faces[keep])
    trimesh.Trimesh(s.vertices[used], np.searchsorted(used, s.faces[keep]), process=False).export(holes)
    return closed, holes


@pytest.mark.parametrize("script", sorted(f for f in os.listdir(os.path.join(ROOT, "examples")) if f.endswith(".py")))
def test_examples_run(script, tmp_path):
    closed, holes = _sphere_files(tmp_path)
    args = {"hessian_holes.py": [str(holes), str(closed), "--point", "0,0,-1", "--output", str(tmp_path / "out")],
            "knitting_rows.py": [str(closed), "--rows", "10", "--output", str(tmp_path / "out")]}.get(script, [])
    done = subprocess.run([sys.executable, os.path.join(ROOT, "examples", script), *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert any(f.endswith(".png") for _, _, files in os.walk(tmp_path) for f in files)


@pytest.fixture
def polyscope(tmp_path, monkeypatch):
    """polyscope, with this test's files (imgui.ini) in a temporary directory."""
    monkeypatch.chdir(tmp_path)
    return pytest.importorskip("polyscope")


def test_show_surface_tets_and_several_fields(polyscope):
    s = trimesh.creation.icosphere(2)
    mesh = wrd.Mesh(s.vertices, s.faces)
    u = wrd.DistanceSolver(mesh, 0.05).solve_many([[0], [5]]).distance
    wrd.show(mesh, u, sources=[0, 5], backend="openGL_mock", frames=1)
    assert polyscope.has_surface_mesh("distance 0") and polyscope.has_surface_mesh("distance 1")
    assert polyscope.has_point_cloud("distance 0 sources")
    wrd.show(mesh, {"near": u[:, 0], "far": np.where(u[:, 1] > 1, np.inf, u[:, 1])}, isolines=0,
             backend="openGL_mock", frames=1)
    assert polyscope.has_surface_mesh("near") and not polyscope.has_surface_mesh("distance 0")
    box = np.array(np.meshgrid(*[[0.0, 1.0]] * 3, indexing="ij")).reshape(3, -1).T
    tets = wrd.Mesh(box, [[0, 3, 1, 7], [0, 2, 3, 7], [0, 6, 2, 7], [0, 4, 6, 7], [0, 5, 4, 7], [0, 1, 5, 7]])
    wrd.show(tets, np.arange(8.0), backend="openGL_mock", frames=1)
    assert polyscope.has_volume_mesh("distance")
    cloud = wrd.PointCloud(s.vertices)
    wrd.show(cloud, wrd.DistanceSolver(cloud).solve([0]).distance, backend="openGL_mock", frames=1)
    assert polyscope.has_point_cloud("distance") and not polyscope.has_surface_mesh("distance")


def test_show_bad_input(polyscope):
    s = trimesh.creation.icosphere(1)
    mesh = wrd.Mesh(s.vertices, s.faces)
    for kwargs, message in (
        (dict(u=np.zeros(5)), r"expected u of shape \(42,\) or \(42, k\), got \(5,\)"),
        (dict(u=np.full(42, np.nan)), r"expected field 'distance' without NaN, got 42 NaN values"),
        (dict(u=np.zeros(42), isolines=-1), r"expected isolines as an integer >= 0, got -1"),
        (dict(u=np.zeros(42), sources=[42]), r"expected sources as vertex indices in \[0, 41\], got \[42\]"),
        (dict(u=np.zeros((42, 2)), names=["a"]), r"expected 2 names, got 1"),
    ):
        with pytest.raises(ValueError, match=message):
            wrd.show(mesh, backend="openGL_mock", frames=1, **kwargs)


def test_cli_view(polyscope, tmp_path, capsys):
    closed, _ = _sphere_files(tmp_path)
    values = tmp_path / "u.npy"
    np.save(values, np.linspace(0.0, 1.0, 642))
    assert main(["view", str(closed), str(values), "--sources", "0,3", "--backend", "openGL_mock", "--frames", "1"]) == 0
    assert polyscope.has_point_cloud("distance sources")
    np.save(values, np.zeros(7))
    assert main(["view", str(closed), str(values), "--backend", "openGL_mock", "--frames", "1"]) == 2
    assert "warp-regdist: error: expected u of shape (642,) or (642, k), got (7,)" in capsys.readouterr().err
    assert main(["view", str(closed), str(tmp_path / "none.npy")]) == 2
    assert "expected VALUES as an existing .npy file" in capsys.readouterr().err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="displays are looked up on Linux only")
def test_cli_view_without_a_display_is_one_line(polyscope, tmp_path, capsys, monkeypatch):
    closed, _ = _sphere_files(tmp_path)
    values = tmp_path / "u.npy"
    np.save(values, np.linspace(0.0, 1.0, 642))
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(closed), str(values)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == ("warp-regdist: error: expected a display for the viewer window, got none (DISPLAY "
                                 "and WAYLAND_DISPLAY are unset): run it on a desktop, or write a picture instead "
                                 "(warp-regdist distance --png)\n")
