"""The single settings object for numerical tolerances and ADMM defaults (cf. ``trimesh.tol``).

Change a value for the whole process (``warp_regdist.tolerances.eps_rel = 1e-3``) or for
one block with ``with warp_regdist.tolerances.override(eps_rel=1e-3): ...``.
"""

from __future__ import annotations

import contextlib
import dataclasses

__all__ = ["Tolerances", "tolerances"]


@dataclasses.dataclass
class Tolerances:
    """Tolerances and defaults; all are dimensionless (scale-invariant).

    Attributes
    ----------
    eps_abs, eps_rel, eps_rel_dual : float
        ADMM stopping test (SPEC section 4 with separate relative tolerances): stop when
        r < sqrt(3m) eps_abs sqrt(A) + eps_rel max(|G u|, |z|) and
        s < sqrt(n) eps_abs A + eps_rel_dual |D y| (norms weighted by the areas).
        The defaults (purely relative, tight on the primal, loose on the dual residual)
        keep the distance within 0.5% of the exact minimizer on the meshes we measured,
        where the authors' (5e-6, 1e-2, 1e-2) reached 1.9% on the bent pipe.
    max_iterations : int
        ADMM iteration cap.
    relaxation : float
        Over-relaxation a of the z- and y-steps (Boyd et al. 2011, sec. 3.4.3).
    rho0, rho_max, rho_doubling : float
        Penalty schedule, in units of the length scale L = sqrt(A):
        rho_k = L min(rho_max, rho0 2^((k - 1) / rho_doubling)) at iteration k = 1, 2, ...
        A changing penalty costs nothing here (the Dirichlet u-step matrix (alpha + rho) W_D
        is only rescaled), and this fixed schedule converged faster and more reliably
        than residual balancing.
    cg_fraction, cg_rtol : float
        Each u-step is solved inexactly by warm-started PCG, until its residual is below
        min(cg_fraction |D y|, eps_dual / 10) (|D y| is the scale of the dual residual s),
        or below cg_rtol times the right-hand side. 1e-3 keeps the iterates as with exact solves; looser
        (1e-1) saves 40% of the CG work but stalls on small meshes at tight primal tolerances.
    cg_primal_fraction : float
        The u-step's residual is also kept below cg_primal_fraction times the last primal
        residual r (times L^(d/2 - 1), in the units of (alpha + rho) W_D u, so that the rule
        is scale-invariant on tetrahedra too). Without it, a warm start
        that already meets the fixed tolerance leaves u unchanged and r can stall above
        its tolerance: 3 of 8 sources on a 42-vertex sphere with tolerances 10x tighter
        than the defaults, a 12 x 12 grid at alpha_hat 1 (10,000 iterations; 64 with it).
        At the defaults it changes little elsewhere (spot: 1,034 CG iterations instead of
        1,050, the same 179 ADMM iterations; Hessian +12% CG iterations).
    cg_max_iterations : int
        PCG iteration cap per ADMM iteration.
    degenerate_element : float
        An element whose area (volume) is <= this times its longest edge squared (cubed)
        is refused as degenerate.
    max_gradient : float
        A result whose gradient exceeds this on some element is reported as not converged,
        with a warning (the constraint is |G u| <= 1; converged results stayed below 1.01
        on spot, the bent pipe, cat and a tet cube). Caught: iterations that blew up on
        needle-like elements while their relative stopping test held.
    """

    eps_abs: float = 0.0
    eps_rel: float = 2.5e-4
    eps_rel_dual: float = 0.15
    max_iterations: int = 10_000
    relaxation: float = 1.7
    rho0: float = 0.5
    rho_max: float = 8.0
    rho_doubling: float = 30.0
    cg_fraction: float = 1e-3
    cg_primal_fraction: float = 0.01
    cg_rtol: float = 1e-10
    cg_max_iterations: int = 500
    degenerate_element: float = 1e-12
    max_gradient: float = 1.5

    @contextlib.contextmanager
    def override(self, **values):
        """Temporarily set some attributes (restored on exit, also after an exception)."""
        unknown = set(values) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f"expected tolerance names among {[f.name for f in dataclasses.fields(self)]}, got {sorted(unknown)}")
        old = {k: getattr(self, k) for k in values}
        for k, v in values.items():
            setattr(self, k, v)
        try:
            yield self
        finally:
            for k, v in old.items():
                setattr(self, k, v)


tolerances = Tolerances()
