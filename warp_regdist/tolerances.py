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
    eps_abs, eps_rel : float
        ADMM stopping tolerances (SPEC section 4): stop when
        r < sqrt(3m) eps_abs sqrt(A) + eps_rel max(|G u|, |z|) and s < sqrt(n) eps_abs A + eps_rel |D y|.
    max_iterations : int
        ADMM iteration cap.
    relaxation : float
        Over-relaxation a_k of the dual step (Boyd et al. 2011, sec. 3.4.3).
    rho0 : float
        Initial penalty in units of the mesh length scale: rho_0 = rho0 * sqrt(A).
    penalty_ratio, penalty_factor : float
        Residual balancing: rho *= factor when r > ratio s, rho /= factor when s > ratio r.
    cg_fraction, cg_rtol : float
        Each u-step is solved inexactly by warm-started PCG until its residual (in the units
        of the dual residual s) is below cg_fraction times the dual tolerance eps_dual of
        the previous iteration, or below cg_rtol times the right-hand side.
    cg_max_iterations : int
        PCG iteration cap per ADMM iteration.
    degenerate_element : float
        An element whose area (volume) is <= this times its longest edge squared (cubed)
        is refused as degenerate.
    """

    eps_abs: float = 5e-6
    eps_rel: float = 1e-2
    max_iterations: int = 10_000
    relaxation: float = 1.7
    rho0: float = 2.0
    penalty_ratio: float = 10.0
    penalty_factor: float = 2.0
    cg_fraction: float = 0.1
    cg_rtol: float = 1e-10
    cg_max_iterations: int = 500
    degenerate_element: float = 1e-12

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
