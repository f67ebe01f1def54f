"""Benchmark plumbing (one case per child process, stamped CSV and markdown output) and the
one command that writes every measured table of the README and the docs from CSVs.

    python benchmarks/report.py                      # re-render the tables from docs/data/*.csv
    python benchmarks/report.py --publish volumetric # copy benchmarks/results/volumetric.csv (and
                                                     # its stamp) to docs/data/, then re-render
    python benchmarks/report.py --check              # exit 1 if a rendered table differs from its CSV

Every benchmark writes ``results/NAME.csv`` and ``results/NAME.stamp.json`` (date, commit, CPU
model, core count, command). A page asks for a table with a marker and the renderer fills in
the lines up to ``<!-- end table -->``, with the stamp under the table::

    <!-- table volumetric: tets=tets, vertices=vertices, solve_s=solve (s); where case=a,b -->
    <!-- end table -->

``key=Header`` pairs choose and name the columns; ``where key=v1,v2`` keeps the rows whose
column equals one of the values. Floats get 4 significant digits, integers thousands separators.
"""

import argparse
import csv
import datetime
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(ROOT, "docs", "data")
MARKER = re.compile(r"<!-- table (?P<name>[\w.-]+): (?P<columns>[^;]*?)(?:; where (?P<where>.*?))? -->\n"
                    r"(?P<body>.*?)<!-- end table -->", re.S)


def run_child(script, case):
    """Run ``python script --case case`` and return the dict it printed as ``RESULT {json}``.

    Each case in its own process, so peak memory (ru_maxrss) is the case's own. None (and
    the child's output tails on stderr) when the child printed no result.
    """
    out = subprocess.run([sys.executable, script, "--case", str(case)], capture_output=True, text=True)
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    if not line:
        print(out.stdout[-2000:], out.stderr[-2000:], file=sys.stderr)
        return None
    row = json.loads(line[0][len("RESULT "):])
    print("  " + json.dumps(row), file=sys.stderr, flush=True)
    return row


def cached(cache, key, compute):
    """The array cached under ``key`` in the folder ``cache``, else compute() (None when compute is None),
    saved there."""
    path = os.path.join(cache, key.replace(" ", "_") + ".npy")
    if os.path.exists(path):
        return np.load(path)
    if compute is None:
        return None
    value = compute()
    os.makedirs(cache, exist_ok=True)
    np.save(path, value)
    return value


def print_result(row):
    """What a child process prints for :func:`run_child`."""
    print("RESULT " + json.dumps(row))


def stamp():
    """Where and when a measurement ran: date, commit (with "+changes" when the package, its kernels,
    or the benchmarks differ from it), CPU model, core count, command."""
    try:
        commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "--untracked-files=no", "--",
                                "warp_regdist", "kernels", "benchmarks"], capture_output=True, text=True).stdout.strip()
        commit += "+changes" if dirty else ""
    except OSError:
        commit = "unknown"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    command = "python " + shlex.join([os.path.relpath(os.path.abspath(sys.argv[0]), ROOT)] + sys.argv[1:])
    return dict(date=datetime.date.today().isoformat(), commit=commit or "unknown", cpu=cpu,
                cores=os.cpu_count(), command=command)


STARTED = stamp()
"""The stamp of the process when it imported this module, before any measurement."""


def write_csv(rows, path):
    """Rows (dicts) to a CSV whose columns are the union of their keys, in first-seen order, and
    its stamp (:data:`STARTED`, the code the run imported) to ``PATH`` with ``.stamp.json`` for ``.csv``."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    with open(_stamp_path(path), "w") as f:
        json.dump(STARTED, f, indent=1)


def markdown_table(rows):
    """Rows (dicts) as a markdown table, floats with 4 significant digits."""
    cols = list(dict.fromkeys(k for r in rows for k in r))
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, ""))
                                       for c in cols) + " |")
    return "\n".join(lines)


def _stamp_path(csv_path):
    return csv_path[:-len(".csv")] + ".stamp.json"


def _cell(text):
    """A CSV value as shown: integers with separators, floats with 4 significant digits."""
    try:
        value = float(text)
    except ValueError:
        return text
    if text.strip().lstrip("-").isdigit():
        return f"{int(text):,}"
    if value != value:
        return "-"
    return f"{value:.4g}"


def render_table(name, columns, where=None, data=DATA):
    """The markdown lines of table ``name`` (docs/data/NAME.csv): ``columns`` "key=Header, ...",
    ``where`` "key=v1,v2" (rows to keep); ValueError for a missing CSV, stamp or column."""
    path = os.path.join(data, f"{name}.csv")
    if not os.path.isfile(path) or not os.path.isfile(_stamp_path(path)):
        raise ValueError(f"expected {os.path.relpath(path, ROOT)} and its stamp, got none (run the benchmark, "
                         f"then python benchmarks/report.py --publish {name})")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    with open(_stamp_path(path)) as f:
        st = json.load(f)
    pairs = [c.split("=", 1) for c in (c.strip() for c in columns.split(",")) if c]
    if any(len(p) != 2 for p in pairs):
        raise ValueError(f"expected columns of table {name} as key=Header pairs, got {columns!r}")
    if where:
        key, values = where.split("=", 1)
        keep = [v.strip() for v in values.split(",")]
        rows = [r for r in rows if r.get(key.strip()) in keep]
    missing = [k for k, _ in pairs if rows and k not in rows[0]]
    if missing:
        raise ValueError(f"expected columns {missing} in {os.path.relpath(path, ROOT)}, got {list(rows[0])}")
    lines = ["| " + " | ".join(h for _, h in pairs) + " |", "|" + "---|" * len(pairs)]
    lines += ["| " + " | ".join(_cell(r[k]) for k, _ in pairs) + " |" for r in rows]
    lines.append("")
    lines.append(f"*Measured {st['date']}, commit {st['commit']}, {st['cpu']}, {st['cores']} cores: "
                 f"`{st['command']}`.*")
    return "\n".join(lines) + "\n"


def rendered_pages(root=ROOT):
    """{path: (old text, new text)} of every page with table markers (README.md, docs/**/*.md)."""
    pages = [os.path.join(root, "README.md")]
    for folder, _, files in os.walk(os.path.join(root, "docs")):
        pages += [os.path.join(folder, f) for f in sorted(files) if f.endswith(".md")]
    out = {}
    for page in pages:
        with open(page, encoding="utf-8") as f:
            old = f.read()
        new = MARKER.sub(lambda m: m.group(0)[:m.start("body") - m.start()] + render_table(
            m.group("name"), m.group("columns"), m.group("where"), os.path.join(root, "docs", "data"))
            + "<!-- end table -->", old)
        if MARKER.search(old):
            out[page] = (old, new)
    return out


def publish(names):
    """Copy benchmarks/results/NAME.csv and its stamp into docs/data/; a measurement of uncommitted code
    is refused."""
    os.makedirs(DATA, exist_ok=True)
    for name in names:
        source = os.path.join(HERE, "results", f"{name}.csv")
        for path in (source, _stamp_path(source)):
            if not os.path.isfile(path):
                raise SystemExit(f"report.py: expected {os.path.relpath(path, ROOT)}, got none (run the benchmark)")
        with open(_stamp_path(source)) as f:
            commit = json.load(f)["commit"]
        if commit.endswith("+changes") or commit == "unknown":
            raise SystemExit(f"report.py: expected {name} measured on a committed tree, got commit {commit} "
                             f"(commit, rerun the benchmark, then publish)")
        for path in (source, _stamp_path(source)):
            shutil.copy(path, DATA)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--publish", nargs="+", default=[], metavar="NAME", help="results to copy into docs/data")
    parser.add_argument("--check", action="store_true", help="only report pages whose tables are out of date")
    args = parser.parse_args()
    publish(args.publish)
    stale = []
    for page, (old, new) in rendered_pages().items():
        if old != new:
            stale.append(os.path.relpath(page, ROOT))
            if not args.check:
                with open(page, "w", encoding="utf-8") as f:
                    f.write(new)
    print(("out of date: " if args.check else "rendered: ") + (", ".join(stale) or "nothing changed"))
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
