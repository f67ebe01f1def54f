"""Halpern anchoring and adaptive restarts in the eigenbasis engine (issue 41, a measurement).

    python research/all_pairs_halpern.py --cache /tmp/stopping
    python research/all_pairs_halpern.py --cache /tmp/stopping --accuracy 0.005 --variants none adaptive

The eigenbasis engine's iteration is a fixed-point map v <- T(v) of the element variable v
(Z = Proj(v), Y = rho (v - Z); over-relaxed Douglas-Rachford on the dual, nonexpansive while rho is
fixed). Halpern's iteration anchors it, v_k+1 = v_0 / (k + 1) + (1 - 1 / (k + 1)) T(v_k) (k counted
from the anchor), whose fixed-point residual |T v - v| decays like 1/k rather than 1/sqrt(k).
Every penalty change starts a new anchor (T changes with rho). Variants:

- ``none``: the package's engine as it is;
- ``halpern``: anchored, a new anchor only at a penalty change;
- ``adaptive``: also a new anchor at the current point when the residual r_k = |T v_k - v_k|_a has
  fallen to 0.2 r_0 (sufficient decay), or to 0.8 r_0 while rising (Lu and Yang's restarted Halpern
  PDHG, 2024), or after 36% of the iterations so far (artificial restart).

After the blend, D Z, D Y and the residual sums are recomputed on the host from the blended v with
the operators' sparse gradient (checked against the kernel's own on an unblended step). Runs
``AllPairsSolver(engine="eigenbasis").solve(accuracy=...)`` with the state class replaced, on the
decimations of benchmarks/all_pairs.py ``LARGER`` (intrinsic operators) against their
5,000-iteration references in ``--cache``. Writes benchmarks/results/all_pairs_halpern.csv and
prints a table.
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks")
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.append(os.path.join(HERE, "..", "tests"))

import all_pairs as bench  # noqa: E402
import warp_regdist as wrd  # noqa: E402
from report import markdown_table, write_csv  # noqa: E402
from warp_regdist.kernels.element_core import G2, R2, Z2  # noqa: E402
from warp_regdist.solvers.all_pairs import solver as all_pairs_admm  # noqa: E402
from warp_regdist.solvers.all_pairs.eigenbasis import EigenbasisADMM  # noqa: E402

RESULTS = os.path.join(HERE, "results", "all_pairs_halpern.csv")
VARIANTS = ("none", "halpern", "adaptive")


class HalpernADMM(EigenbasisADMM):
    """The eigenbasis engine with the module docstring's anchoring (``variant``, a class attribute)."""

    variant = "none"

    def __init__(self, ops, *args, **kwargs):
        super().__init__(ops, *args, **kwargs)
        self.G = ops.grad.tocsr()
        self.a3 = np.repeat(ops.element_volumes, 3)
        self.anchor, self.restarts, self.steps = None, 0, 0

    def _v(self):
        return self.view("v").reshape(self.m, 3, -1)[:, :, :self.n]

    def _residual(self, d):
        return float(np.sqrt(np.einsum("e,ecj,ecj->", self.a3[::3], d, d)))

    def _write_back(self, v, rho):
        """D Z, D Y and the sums R2, G2, Z2 of the blended v, as the element kernel writes them."""
        n, m = self.n, self.m
        norm = np.sqrt(np.einsum("ecj,ecj->ej", v, v))
        Z = v / np.maximum(norm, 1.0)[:, None, :]
        flat = lambda x: (self.a3[:, None] * x.reshape(3 * m, n))
        dz, dy = self.G.T @ flat(Z), rho * (self.G.T @ flat(v - Z))
        g = (self.G @ self._matrix("U").astype(np.float64)).reshape(m, 3, n)
        for name, value in (("DZ_acc", dz), ("DY_acc", dy)):
            self.view(name).reshape(n, -1)[:, :n] = value
        acc = self.view("acc").reshape(5, -1)
        a = self.a3[::3]
        acc[R2, :n] = np.einsum("e,ecj->j", a, (g - Z) ** 2)
        acc[G2, :n] = np.einsum("e,ecj->j", a, g * g)
        acc[Z2, :n] = np.einsum("e,ecj->j", a, Z * Z)
        return dz

    def x_and_element_steps(self, *args):
        before = self._v().copy()
        super().x_and_element_steps(*args)
        if self.variant == "none":
            return 0
        rho, self.steps = self.penalties[0], self.steps + 1
        Tv = self._v().copy()
        r = self._residual(Tv - before)
        if self.anchor is None or rho != self.anchor_rho:
            self._restart(Tv, r, rho)
            return 0
        self.k += 1
        if self.variant == "adaptive" and (r <= 0.2 * self.r0 or (r <= 0.8 * self.r0 and r > self.r_prev)
                                           or self.k >= 0.36 * self.steps):
            self._restart(Tv, r, rho)
            return 0
        self.r_prev = r
        lam = 1.0 / (self.k + 1)
        blended = lam * self.anchor + (1 - lam) * Tv
        self._v()[...] = blended
        self._write_back(blended, rho)
        return 0

    def _restart(self, v, r, rho):
        self.anchor, self.anchor_rho, self.k, self.r0, self.r_prev = v, rho, 0, r, r
        self.restarts += 1


def check_write_back(mesh, alpha_hat):
    """max |D Z (host) - D Z (kernel)| / max |D Z (kernel)| on one unblended step."""
    solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation="intrinsic",
                                options=wrd.AllPairsOptions(engine="eigenbasis", max_iterations=3))
    seen = []

    class Check(HalpernADMM):
        def x_and_element_steps(self, *args):
            EigenbasisADMM.x_and_element_steps(self, *args)
            kernel = self.view("DZ_acc").reshape(self.n, -1)[:, :self.n].astype(np.float64).copy()
            host = self._write_back(self._v().astype(np.float64), self.penalties[0])
            seen.append(np.abs(host - kernel).max() / np.abs(kernel).max())
            return 0

    all_pairs_admm.EigenbasisADMM = Check
    try:
        solver.solve()
    finally:
        all_pairs_admm.EigenbasisADMM = EigenbasisADMM
    return max(seen)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", required=True, help="folder of the 5,000-iteration references")
    ap.add_argument("--accuracy", type=float, nargs="+", default=[0.01])
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    import warp as wp
    wp.config.quiet = True
    rows = []
    for k, (name, mesh, alpha_hat, reference, _) in enumerate(bench.larger_cases(args.cache, "intrinsic")):
        if k == 0:
            print(f"write-back check: {check_write_back(mesh, alpha_hat):.2e}", flush=True)
        solver = wrd.AllPairsSolver(mesh, alpha_hat, device="cpu", workers=1, triangulation="intrinsic",
                                    options=wrd.AllPairsOptions(engine="eigenbasis"))
        for accuracy in args.accuracy:
            for variant in args.variants:
                HalpernADMM.variant = variant
                states = []

                class Recorded(HalpernADMM):
                    def __init__(self, *a, **kw):
                        super().__init__(*a, **kw)
                        states.append(self)

                all_pairs_admm.EigenbasisADMM = Recorded
                t0 = time.perf_counter()
                try:
                    res = solver.solve(accuracy=accuracy)
                finally:
                    all_pairs_admm.EigenbasisADMM = EigenbasisADMM
                row = dict(mesh=name, n=mesh.n_vertices, alpha_hat=alpha_hat, accuracy=accuracy, variant=variant,
                           **bench._run_columns(res, reference), restarts=states[0].restarts,
                           seconds=round(time.perf_counter() - t0, 1))
                rows.append(row)
                print(row, flush=True)
                write_csv(rows, args.out)
    print(markdown_table(rows))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
