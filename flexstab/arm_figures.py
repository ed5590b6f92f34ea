"""Figures of flexible arms built from model files: poses on the orbit and Floquet mode pictures.

Works for any model whose flexible parts are ``ObjectANCFCable2D`` elements:
the centre line of every element is the cubic Hermite curve through its two
nodes' positions and slopes (the element's own interpolation), so a pose is
drawn exactly as Exudyn represents it.  Rigid-body nodes (hubs, elbows) and
mass points (tip masses) are drawn as dots.

* :func:`plot_poses` -- the arm at ``snapshots`` instants of one period on
  the periodic orbit, with the tip path;
* :func:`floquet_mode_shapes` / :func:`plot_floquet_mode` -- the Floquet
  vector of a multiplier mapped back to Exudyn's coordinates
  (``dq = N(t) z(t)``), propagated over the period with the periodic factor
  ``exp(-t ln(rho)/T)`` removed (the T-periodic Floquet mode), and drawn as a
  deformation of the pose at each instant.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import scipy.linalg

__all__ = ["ArmLayout", "ModeFigure", "arm_layout", "beam_centerlines", "plot_poses", "floquet_mode_shapes",
           "plot_floquet_mode", "mode_title"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ArmLayout:
    """Where the drawable parts of an assembled Exudyn system sit in its ODE2 vector.

    Attributes
    ----------
    elements : tuple
        Per ANCF cable element ``(i0, i1, ref0, ref1)``: ODE2 indices (4 each)
        and reference coordinates of its two nodes.
    points : tuple
        Per rigid-body / mass-point node ``(name, indices, reference)`` (2D position).
    """

    elements: tuple
    points: tuple


def arm_layout(mbs: Any) -> ArmLayout:
    """Read the ANCF elements and point-like nodes of an assembled system."""
    elements = []
    for i in range(mbs.systemData.NumberOfObjects()):
        obj = mbs.GetObject(i)
        if obj.get("objectType") != "ANCFCable2D":
            continue
        n0, n1 = (int(n) for n in obj["nodeNumbers"])
        elements.append(tuple(
            [np.array(mbs.systemData.GetNodeLTGODE2(n), dtype=int) for n in (n0, n1)]
            + [np.asarray(mbs.GetNode(n)["referenceCoordinates"], dtype=float) for n in (n0, n1)]
        ))
    points = []
    for n in range(mbs.systemData.NumberOfNodes()):
        node = mbs.GetNode(n)
        if node.get("nodeType") in ("RigidBody2D", "Point2D"):
            ltg = np.array(mbs.systemData.GetNodeLTGODE2(n), dtype=int)
            points.append((node.get("name", f"node{n}"), ltg[:2], np.asarray(node["referenceCoordinates"])[:2]))
    return ArmLayout(elements=tuple(elements), points=tuple(points))


def _hermite(r0, s0, r1, s1, L, xi):
    h00 = 2 * xi**3 - 3 * xi**2 + 1
    h10 = xi**3 - 2 * xi**2 + xi
    h01 = -2 * xi**3 + 3 * xi**2
    h11 = xi**3 - xi**2
    return np.outer(h00, r0) + np.outer(h10 * L, s0) + np.outer(h01, r1) + np.outer(h11 * L, s1)


def beam_centerlines(layout: ArmLayout, q: np.ndarray, points: int = 9) -> list[np.ndarray]:
    """Centre line of every ANCF element at ODE2 coordinates ``q`` (displacements), ``(points, 2)`` each."""
    q = np.asarray(q)
    xi = np.linspace(0.0, 1.0, points)
    out = []
    for i0, i1, ref0, ref1 in layout.elements:
        a0, a1 = ref0 + q[i0], ref1 + q[i1]
        L = float(np.hypot(*(ref1[:2] - ref0[:2])))  # reference length of the element
        out.append(_hermite(a0[:2], a0[2:4], a1[:2], a1[2:4], L, xi))
    return out


def _point_positions(layout: ArmLayout, q: np.ndarray) -> np.ndarray:
    return np.array([ref + q[idx] for _, idx, ref in layout.points]) if layout.points else np.zeros((0, 2))


def _built(orbit: Any):
    from mbs_models.model_file import build_model

    return build_model(orbit.model, orbit.omega)


def _save(fig: Any, path: "str | Path", *, dpi: int) -> Path:
    """Lay out, write (creating the folder) and close ``fig``; the path written."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out


def plot_poses(orbit: Any, path: "str | Path", *, snapshots: int = 12, title: Optional[str] = None) -> Path:
    """The arm at ``snapshots`` instants of one period on ``orbit`` (a :class:`~linearize.periodic_orbit.PeriodicOrbit`)."""
    import matplotlib.pyplot as plt

    layout = arm_layout(_built(orbit).mbs)
    T = orbit.period
    fig, ax = plt.subplots(figsize=(7.6, 5.0))
    cmap = plt.get_cmap("viridis")
    fine = np.linspace(0.0, T, 201)
    tips = []
    for t in fine:
        q = orbit.state(float(t))[0]
        tips.append(beam_centerlines(layout, q, points=2)[-1][-1])
    tips = np.array(tips)
    ax.plot(tips[:, 0], tips[:, 1], ":", color="0.4", lw=1, label="tip path")
    for j, t in enumerate(np.linspace(0.0, T, snapshots, endpoint=False)):
        q = orbit.state(float(t))[0]
        c = cmap(j / snapshots)
        for k, line in enumerate(beam_centerlines(layout, q)):
            ax.plot(line[:, 0], line[:, 1], "-", color=c, lw=2, label=f"t = {t / T:.2f} T" if k == 0 else None)
        pts = _point_positions(layout, q)
        if pts.size:
            ax.plot(pts[:, 0], pts[:, 1], "o", color=c, ms=3)
    ax.plot([0], [0], "ks", ms=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.set_title(title or f"{orbit.model.name}: poses over one period, Ω = {orbit.omega / math.pi:.4g}π rad/s",
                 fontsize=11)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="time", title_fontsize=8)
    return _save(fig, path, dpi=130)


def floquet_mode_shapes(result: Any, index: int = 0, *, substeps: int = 16) -> tuple[np.ndarray, np.ndarray, complex]:
    """The T-periodic Floquet mode of multiplier ``index`` in Exudyn coordinates at the orbit samples.

    Parameters
    ----------
    result : linearize.analysis.ModelFloquetResult
    index : int
        Multiplier index (in ``result.floquet.multipliers`` order).
    substeps : int
        Exponential-midpoint steps per sample interval used to propagate the
        Floquet vector (each factor an exact matrix exponential, as the
        ``magnus2`` method).

    Returns
    -------
    times : ndarray, shape (K,)
    dq : ndarray, shape (K, n_ode2)
        Real part of ``N(t_k) z(t_k) exp(-t_k ln(rho) / T)``, scaled to unit max.
    rho : complex
    """
    lin = result.linearization
    res = result.floquet
    rho = complex(res.multipliers[index])
    w, V = np.linalg.eig(np.asarray(res.monodromy))
    v = V[:, int(np.argmin(np.abs(w - rho)))]
    times = np.asarray(result.orbit.times, dtype=float)
    T = float(result.orbit.period)
    r = lin.size
    h = T / (times.size * substeps)
    x = v.astype(complex)
    log_rho = complex(np.log(rho))
    dq = np.empty((times.size, lin.basis.shape[1]))
    for k in range(times.size):
        z = x[:r] * np.exp(-log_rho * times[k] / T)
        dq[k] = np.real(lin.basis[k] @ z)
        for j in range(substeps):
            tm = times[k] + (j + 0.5) * h
            x = scipy.linalg.expm(h * np.asarray(lin(tm))) @ x
    dq /= max(float(np.max(np.abs(dq))), 1e-300)
    return times, dq, rho


def mode_title(orbit: Any, rho: complex, label: str, measured: Optional[tuple[complex, str]] = None) -> str:
    """Title of :func:`plot_floquet_mode` (two lines): the model, Omega and the multiplier's modulus --
    ``measured`` = ``(value, method)`` when the value reported elsewhere comes from another method than
    the product whose eigenvector gives the shape (e.g. Hill's method in the two-link table), else the
    product's ``rho``."""
    if measured is not None:
        value = f"|ρ| = {abs(measured[0]):.6f} ({label}; {measured[1]})"
    else:
        value = f"|ρ| = {abs(rho):.4f} ({label})"
    k = f"{orbit.omega / math.pi:.4g}"
    return f"{orbit.model.name}, Ω = {'' if k == '1' else k}π rad/s: Floquet mode of {value}"


@dataclass(frozen=True)
class ModeFigure:
    """What :func:`plot_floquet_mode` drew.

    Attributes
    ----------
    path : Path
        The PNG written.
    multiplier : complex
        The multiplier of the product whose eigenvector gives the shape.
    mode : str
        Its label.
    scale_m : float
        The drawn deformation: the largest displacement coordinate of the mode is ``scale_m`` metres
        (``amplitude`` times the arm's reach; a mode has no amplitude of its own).
    """

    path: Path
    multiplier: complex
    mode: str
    scale_m: float

    @property
    def name(self) -> str:
        """File name of :attr:`path`."""
        return self.path.name


def plot_floquet_mode(result: Any, path: "str | Path", *, index: Optional[int] = None, snapshots: int = 8,
                      amplitude: float = 0.08, title: Optional[str] = None,
                      measured: Optional[tuple[complex, str]] = None) -> ModeFigure:
    """Snapshots of the Floquet mode of multiplier ``index`` (default: the dominant damped one) on the pose.

    The deformation ``dq`` is scaled so that its largest coordinate is
    ``amplitude`` times the arm's reach (the scale is written on the figure and returned); the
    undeformed orbit pose is grey.  ``measured`` (``(value, method)``): the title shows that value of
    the multiplier (see :func:`mode_title`).
    """
    import matplotlib.pyplot as plt

    if index is None:
        mus = np.asarray(result.floquet.multipliers)
        index = int(np.argmin(np.abs(mus - result.dominant_multiplier)))
    times, dq, rho = floquet_mode_shapes(result, index)
    orbit = result.orbit
    layout = arm_layout(_built(orbit).mbs)
    reach = max(float(np.max(np.abs(np.concatenate(beam_centerlines(layout, orbit.q[0]))))), 1e-3)
    scale = amplitude * reach
    label = result.modes[index].mode if index < len(result.modes) else ""
    cols = min(snapshots, 4)
    rows = int(math.ceil(snapshots / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.1 * cols, 2.6 * rows + 0.9), squeeze=False,
                             sharex=True, sharey=True)
    picks = np.linspace(0, times.size, snapshots, endpoint=False).astype(int)
    for ax, k in zip(axes.ravel(), picks):
        q = orbit.q[k]
        for j, line in enumerate(beam_centerlines(layout, q)):
            ax.plot(line[:, 0], line[:, 1], "-", color="0.7", lw=2, label="orbit pose" if j == 0 else None)
        for j, line in enumerate(beam_centerlines(layout, q + scale * dq[k])):
            ax.plot(line[:, 0], line[:, 1], "-", color="C3", lw=1.8, label="pose + mode" if j == 0 else None)
        ax.plot([0], [0], "ks", ms=4)
        ax.set_aspect("equal")
        ax.set_xlim(-1.15 * reach, 1.15 * reach)
        ax.set_ylim(-0.4 * reach, 1.15 * reach)
        ax.set_title(f"t = {times[k] / orbit.period:.3f} T", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3)
    for ax in axes[-1, :]:
        ax.set_xlabel("x (m)", fontsize=9)
    for ax in axes[:, 0]:
        ax.set_ylabel("y (m)", fontsize=9)
    for ax in axes.ravel()[len(picks):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=8, loc="lower left")
    fig.suptitle((title or mode_title(orbit, rho, label, measured))
                 + f"\nlargest displacement of the mode drawn as {scale:.3g} m ({100 * amplitude:.0f} % of the "
                   f"reach {reach:.3g} m)", fontsize=10)
    return ModeFigure(path=_save(fig, path, dpi=120), multiplier=complex(rho), mode=str(label), scale_m=float(scale))
