"""Finite-difference linearisation of the Exudyn link along a periodic motion."""
from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Optional

import numpy as np

from linearize.finite_difference import CENTRAL_DIFFERENCE_STEP, central_difference_jacobians
from linearize.fourier import sample_times
from linearize.system import LinearizedPeriodicSystem
from _link_oracle.exudyn_link import ExudynLinkModel, build_link_model

if TYPE_CHECKING:  # _link_oracle.link_orbit imports linearize helpers: avoid the cycle
    from _link_oracle.link_orbit import PeriodicOrbit

__all__ = ["linearize_along_orbit", "coordinate_names"]

logger = logging.getLogger(__name__)


def coordinate_names(elements: int, hub_free: bool = True) -> tuple:
    """Names of the independent coordinates (``q_a``, ``s0``, ``x1, y1, x1', y1'``, ...)."""
    names = ["q_a", "s0"]
    for j in range(1, elements + 1):
        names += [f"x{j}", f"y{j}", f"x{j}'", f"y{j}'"]
    return tuple(names if hub_free else names[1:])


def linearize_along_orbit(
    orbit: "PeriodicOrbit",
    *,
    hub: str = "free",
    kp: float = 0.0,
    kd: float = 0.0,
    samples: Optional[int] = None,
    step: float = CENTRAL_DIFFERENCE_STEP,
    gains_inside: bool = False,
) -> LinearizedPeriodicSystem:
    """Linearise the Exudyn link about ``orbit`` in independent coordinates.

    Parameters
    ----------
    orbit : PeriodicOrbit
        Reference motion (:func:`~_link_oracle.link_orbit.find_periodic_orbit`, or
        :func:`~_link_oracle.link_orbit.rigid_reference` for the undeformed motion).
    hub : {"free", "prescribed"}
        ``"free"``: the hub angle is coordinate 0 and the PD gains act on it;
        ``"prescribed"``: the hub follows ``q_a^R(t)`` exactly, only the beam
        coordinates remain.
    kp, kd : float
        PD gains (free hub only), added as constants to ``K[0, 0]`` and
        ``C[0, 0]`` (paper Eq. 32) unless ``gains_inside``.
    samples : int, optional
        Linearisation points per period (even); default: the orbit's samples.
        Other values take the orbit state by trigonometric interpolation.
    step : float
        Relative central-difference step.
    gains_inside : bool
        Build the Exudyn model *with* its PD spring-damper and differentiate
        through it instead of adding the gains afterwards (used by the test
        that both agree).

    Returns
    -------
    LinearizedPeriodicSystem

    Notes
    -----
    At each sample ``t_k`` the residual ``r(p, p', p'', t) = J^T (M q'' - f)``
    of :class:`~_link_oracle.exudyn_link.ExudynLinkModel` is differentiated by
    central differences: ``K = dr/dp``, ``C = dr/dp'``; ``M = J^T M J`` is
    exact.  The feed-forward torque depends on time only and drops out.
    """
    tic = time.perf_counter()
    if hub not in ("free", "prescribed"):
        raise ValueError(f"hub must be 'free' or 'prescribed', got {hub!r}")
    for name, v in (("kp", kp), ("kd", kd)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    if hub == "prescribed" and (kp or kd):
        raise ValueError("PD gains act on the hub angle: use hub='free'")
    cfg = replace(orbit.config, drive="free", kp=kp if gains_inside else 0.0, kd=kd if gains_inside else 0.0)
    model: ExudynLinkModel = build_link_model(orbit.params, cfg)
    T = orbit.period
    if samples is None or samples == orbit.samples:
        times = orbit.times
        P, V, A = orbit.positions, orbit.velocities, orbit.accelerations
    else:
        times = sample_times(T, samples)
        P, V, A = orbit.state(times)
    sel = slice(0, None) if hub == "free" else slice(1, None)
    Ms, Cs, Ks = [], [], []
    for k in range(times.size):
        K, C = central_difference_jacobians(model.residual, P[k], V[k], A[k], float(times[k]), step=step, columns=sel, rows=sel)
        Ms.append(model.reduced_mass(P[k])[sel, sel])
        Ks.append(K)
        Cs.append(C)
    K = np.array(Ks)
    C = np.array(Cs)
    if hub == "free" and not gains_inside:
        K[:, 0, 0] += kp
        C[:, 0, 0] += kd
    lin = LinearizedPeriodicSystem(
        period=T,
        times=np.asarray(times, dtype=float),
        M=np.array(Ms),
        C=C,
        K=K,
        kp=float(kp) if hub == "free" else 0.0,
        kd=float(kd) if hub == "free" else 0.0,
        coordinates=coordinate_names(orbit.config.elements, hub == "free"),
        hub_free=hub == "free",
        reference=orbit.kind,
        orbit_residual=orbit.residual,
        elements=orbit.config.elements,
        fd_step=step,
        wall_time=time.perf_counter() - tic,
    )
    logger.info("linearised %s orbit at %d samples in %.2f s", orbit.kind, times.size, lin.wall_time)
    return lin
