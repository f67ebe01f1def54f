"""The package's layout stays easy to see: no import circles between its modules, no module
over 600 lines, and ruff's and mypy's checks (pyproject.toml) clean."""

import ast
import os
import subprocess
import sys

import pytest

import warp_regdist

PACKAGE = os.path.dirname(warp_regdist.__file__)
KERNELS = os.path.dirname(warp_regdist.kernels.__file__)


def _modules():
    """{module name: path} of every module of warp_regdist and warp_regdist.kernels."""
    found = {}
    for root, prefix in ((PACKAGE, "warp_regdist"), (KERNELS, "warp_regdist.kernels")):
        for folder, _, files in os.walk(root):
            if "__pycache__" in folder or (root == PACKAGE and folder.startswith(KERNELS)):
                continue
            package = ".".join([prefix] + [p for p in os.path.relpath(folder, root).split(os.sep) if p != "."])
            for f in files:
                if f.endswith(".py"):
                    found[package if f == "__init__.py" else f"{package}.{f[:-3]}"] = os.path.join(folder, f)
    return found


def _imports(name, path, modules):
    """The package modules that ``name`` imports (relative imports, lazy ones too)."""
    package = name if path.endswith("__init__.py") else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(open(path).read())):
        if isinstance(node, ast.ImportFrom) and node.level:
            parts = package.split(".")
            base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            targets = [f"{base}.{a.name}" for a in node.names] if node.module is None else [base]
            out.update(t for t in targets if t in modules and t != name and t != "warp_regdist")
    return out


def test_no_import_circles():
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for nxt in graph[node]:
            if state.get(nxt) == "open":
                raise AssertionError("import circle: " + " -> ".join(stack[stack.index(nxt):] + [nxt]))
            if nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = "done"

    assert len(modules) > 40
    for name in graph:
        if name not in state:
            visit(name, [name])


def test_no_module_over_600_lines():
    """A few hundred lines is the norm; past 600 a module likely holds more than one concept."""
    long = {name: n for name, path in _modules().items() if (n := sum(1 for _ in open(path))) > 600}
    assert long == {}


def test_ruff_finds_nothing():
    pytest.importorskip("ruff")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=root, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]


def test_mypy_finds_nothing():
    pytest.importorskip("mypy")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run([sys.executable, "-m", "mypy", "--no-incremental"], cwd=root, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-1000:]
