"""Dominant Floquet multipliers of the reduced and the Exudyn models side by side.

For each Omega of the paper (2, 4, 6, 8 pi), uncontrolled and with the
printed Table 3 gains (p. 489):

* the paper's reduced one-mode model (printed constants);
* the Exudyn linearisation about the true periodic orbit;
* the Exudyn linearisation about the undeformed rigid motion;
* the direct monodromy of Exudyn's nonlinear model (optional, slow).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Callable, Optional

from mbs_models.paper_data import TABLE3_GAINS
from mbs_models.parameters import ManipulatorParameters

__all__ = ["TABLE3_GAINS", "ComparisonRow", "compare_models", "comparison_markdown"]

logger = logging.getLogger(__name__)



@dataclass(frozen=True)
class ComparisonRow:
    """One (Omega, gains) case; multipliers are moduli of the dominant multiplier."""

    omega_over_pi: int
    kp: float
    kd: float
    reduced: float
    exudyn_orbit: float
    exudyn_orbit_mode: str
    exudyn_rigid: float
    exudyn_rigid_mode: str
    direct: float
    direct_closed_loop_defect: float
    orbit_residual: float
    shooting_residual: float
    spectral_radius_exudyn: float
    undamped_multipliers: int
    seconds_linearisation_route: float
    seconds_direct: float

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in self.__dict__.items()}


def compare_models(
    params: Optional[ManipulatorParameters] = None,
    *,
    elements: int = 8,
    samples: int = 32,
    n_steps: int = 128,
    direct: bool = True,
    omegas: tuple = (2, 4, 6, 8),
    progress: Optional[Callable[[str], None]] = None,
) -> list:
    """Run the comparison; return a list of :class:`ComparisonRow`.

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default Table 1).
    elements, samples, n_steps : int
        Exudyn discretisation, orbit/linearisation samples, propagator steps.
    direct : bool
        Also compute the direct Exudyn monodromy (about 20 s per case at 8
        elements).
    omegas : tuple of int
        Omega / pi values (keys of :data:`TABLE3_GAINS`).
    progress : callable, optional
        Called with a short text before each case.
    """
    from _link_oracle.link_floquet import direct_monodromy, exudyn_floquet
    from _link_oracle.link_orbit import find_periodic_orbit, rigid_reference
    from _link_oracle.exudyn_link import ExudynLinkConfig
    from mbs_models.reduced import ReducedModel
    from stability import floquet

    params = ManipulatorParameters() if params is None else params
    rows = []
    for w in omegas:
        if w not in TABLE3_GAINS:
            raise ValueError(f"Omega/pi must be one of {sorted(TABLE3_GAINS)}, got {w!r}")
        omega = w * math.pi
        cfg = ExudynLinkConfig(elements=elements, omega=omega)
        tic = time.perf_counter()
        orbit = find_periodic_orbit(params, cfg, samples=samples)
        t_orbit = time.perf_counter() - tic
        rigid = rigid_reference(params, cfg, samples=samples)
        for kp, kd in ((0.0, 0.0), TABLE3_GAINS[w]):
            if progress:
                progress(f"Omega = {w} pi, kp = {kp}, kd = {kd}")
            red = floquet(ReducedModel(omega=omega, kp=kp, kd=kd, params=params, constants="paper"))
            tic = time.perf_counter()
            ex = exudyn_floquet(params, omega=omega, kp=kp, kd=kd, elements=elements, orbit=orbit, n_steps=n_steps)
            t_lin = time.perf_counter() - tic + t_orbit
            exr = exudyn_floquet(params, omega=omega, kp=kp, kd=kd, elements=elements, orbit=rigid, n_steps=n_steps)
            d_mod, d_defect, t_dir = math.nan, math.nan, math.nan
            if direct:
                tic = time.perf_counter()
                d = direct_monodromy(orbit, kp=kp, kd=kd)
                t_dir = time.perf_counter() - tic
                d_mod, d_defect = abs(d.dominant_multiplier), d.closed_loop_defect
            rows.append(
                ComparisonRow(
                    omega_over_pi=w,
                    kp=kp,
                    kd=kd,
                    reduced=float(red.spectral_radius),
                    exudyn_orbit=abs(ex.dominant_multiplier),
                    exudyn_orbit_mode=ex.dominant_mode,
                    exudyn_rigid=abs(exr.dominant_multiplier),
                    exudyn_rigid_mode=exr.dominant_mode,
                    direct=d_mod,
                    direct_closed_loop_defect=d_defect,
                    orbit_residual=orbit.residual,
                    shooting_residual=orbit.shooting_residual,
                    spectral_radius_exudyn=float(ex.floquet.spectral_radius),
                    undamped_multipliers=ex.undamped_count,
                    seconds_linearisation_route=t_lin,
                    seconds_direct=t_dir,
                )
            )
            logger.info("compare: %s", rows[-1])
    return rows


def comparison_markdown(rows: list, elements: int) -> str:
    """Markdown table of :func:`compare_models` rows."""

    def f(x: float) -> str:
        return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.6g}"

    lines = [
        f"# Dominant Floquet multiplier |rho_1|: reduced model vs Exudyn ({elements} ANCF elements)",
        "",
        "Reduced: the paper's one-mode model with its printed constants. Exudyn orbit / rigid:",
        "finite-difference linearisation about the true periodic orbit / the undeformed rigid motion",
        "(dominant = largest multiplier of the hub or first bending mode, undamped structural modes",
        "excluded and counted). Direct: monodromy of Exudyn's own integrator (2n+1 runs).",
        "",
        "| Omega | kp | kd | reduced | Exudyn orbit | mode | Exudyn rigid | direct | spectral radius (all modes) | undamped | t lin. route (s) | t direct (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d = r if isinstance(r, dict) else r.to_dict()
        lines.append(
            f"| {d['omega_over_pi']}pi | {d['kp']:g} | {d['kd']:g} | {f(d['reduced'])} | {f(d['exudyn_orbit'])} | "
            f"{d['exudyn_orbit_mode']} | {f(d['exudyn_rigid'])} | {f(d['direct'])} | {f(d['spectral_radius_exudyn'])} | "
            f"{d['undamped_multipliers']} | {f(d['seconds_linearisation_route'])} | {f(d['seconds_direct'])} |"
        )
    return "\n".join(lines) + "\n"
