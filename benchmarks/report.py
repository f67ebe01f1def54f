"""Plumbing shared by the benchmark scripts: one case per child process, CSV and markdown output."""

import csv
import json
import os
import subprocess
import sys


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


def print_result(row):
    """What a child process prints for :func:`run_child`."""
    print("RESULT " + json.dumps(row))


def write_csv(rows, path):
    """Rows (dicts) to a CSV whose columns are the union of their keys, in first-seen order."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def markdown_table(rows):
    """Rows (dicts) as a markdown table, floats with 4 significant digits."""
    cols = list(dict.fromkeys(k for r in rows for k in r))
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, ""))
                                       for c in cols) + " |")
    return "\n".join(lines)
