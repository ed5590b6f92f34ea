"""Stability charts: max|rho| over a (kp, kd) grid, and against Omega.

The grid points are independent Floquet evaluations; they run through a
``concurrent.futures`` executor (:func:`flexstab.executor.make_executor`:
local processes by default, a Dask cluster with a scheduler address) and
are stored point by point (:func:`flexstab.executor.run_sweep`), so an
interrupted chart resumes where it stopped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from flexstab.executor import run_sweep
from mbs_models.parameters import ManipulatorParameters

__all__ = [
    "ReducedRadius",
    "PlantRadius",
    "ModelRadius",
    "ModelPlants",
    "GainChart",
    "OmegaChart",
    "gain_chart",
    "omega_chart",
    "dominant_ylabel",
    "plot_gain_chart",
    "plot_omega_chart",
    "check_grid",
]


@dataclass(frozen=True)
class ReducedRadius:
    """Picklable task: ``{"omega", "kp", "kd"} -> max|rho|`` of the reduced model."""

    params: ManipulatorParameters = field(default_factory=ManipulatorParameters)
    constants: str = "auto"
    n_steps: Optional[int] = 256

    def __call__(self, point: dict) -> float:
        from mbs_models.reduced import ReducedModel
        from stability.engines import floquet

        model = ReducedModel(point["omega"], point["kp"], point["kd"], self.params, self.constants)
        opts: dict[str, Any] = {"n_steps": self.n_steps, "error_estimate": False} if self.n_steps else {}
        return float(floquet(model, method="magnus", **opts).spectral_radius)


@dataclass(frozen=True)
class PlantRadius:
    """Picklable task for a plant at one Omega: ``{"kp", "kd"} -> response``.

    The response is ``plant.spectral_measure(kp, kd)`` (for a model file's plant: the dominant
    labelled multiplier).  ``point["omega"]`` must be the plant's own Omega.
    """

    plant: Any
    omega: float

    def __call__(self, point: dict) -> float:
        if abs(point["omega"] - self.omega) > 1e-12 * self.omega:
            raise ValueError(f"this plant was linearised at omega = {self.omega}, not {point['omega']}")
        return float(self.plant.spectral_measure(point["kp"], point["kd"]))


class ModelPlants:
    """Explicit cache of a model's orbits, linearisations and tuning plants per Omega (for the charts).

    The orbit at a new Omega starts Newton from the orbit at the nearest Omega computed so far
    (continuation along an Omega sweep), so the values depend on the order of evaluation only to the
    Newton tolerance.  The plant at an Omega is :func:`flexstab.plants.plant_for` (the rule of ``tune``
    and ``study --model``), cached per (Omega, tuning configuration, steps).  It pickles by value (orbits and
    linearisations as arrays, the model as its file's path, :class:`mbs_models.model_file.ModelDefinition`):
    a copy sent to a worker process evaluates the Omegas already in it exactly as this process does (the gain
    chart); an Omega sweep belongs in this process, where each orbit is continued from the nearest one.

    Parameters
    ----------
    model : ModelDefinition
    options : dict
        Keyword options of the model's ``build``.
    samples : int
        Collocation samples per period.
    """

    def __init__(self, model: Any, options: Optional[dict] = None, *, samples: int = 32) -> None:
        self.model = model
        self.options = dict(options or {})
        self.samples = int(samples)
        self._linearised: dict = {}
        self._plants: dict = {}

    def linearised(self, omega: float) -> tuple:
        """``(orbit, linearisation)`` at ``omega`` (gains 0; cached, orbit continued in Omega)."""
        from linearize.constrained import linearize_orbit
        from linearize.periodic_orbit import find_orbit

        omega = float(omega)
        hit = self._linearised.get(omega)
        if hit is None:
            near = min(self._linearised, key=lambda w: abs(w - omega), default=None)
            guess = self._linearised[near][0] if near is not None else None
            orbit = find_orbit(self.model, omega, samples=self.samples, verify=False, guess=guess, **self.options)
            hit = (orbit, linearize_orbit(orbit))
            self._linearised[omega] = hit
        return hit

    def plant(self, omega: float, config: Any = None, steps: Optional[int] = None) -> Any:
        """:func:`flexstab.plants.plant_for` at ``omega`` with ``config`` (a TuningConfig, or ``None``) and ``steps``."""
        return self.choice(omega, config, steps).plant

    def choice(self, omega: float, config: Any = None, steps: Optional[int] = None) -> Any:
        """:func:`flexstab.plants.plant_choice_for` at ``omega``: the plant and how its discretisation was chosen
        (cached as :meth:`plant`)."""
        from flexstab.plants import plant_choice_for

        key = (float(omega), repr(config), steps)
        hit = self._plants.get(key)
        if hit is None:
            orbit, lin = self.linearised(omega)
            hit = plant_choice_for(self.model, orbit, lin, config, steps=steps)
            self._plants[key] = hit
        return hit


@dataclass(frozen=True)
class ModelRadius:
    """Task for a model file: ``{"omega", "kp", "kd"} -> |rho|`` of its dominant labelled multiplier.

    The response is the ``spectral_measure`` of :func:`flexstab.plants.plant_for`'s plant (drive modes
    and the first bending mode; the tuning response of ``flexstab tune --model`` and ``study --model``,
    evaluated by the same method: Hill's for the built-in two-link, the frozen-modal product otherwise).
    A point's ``kp``/``kd`` are either numbers -- the gains of the charted drive ``drive`` (``None``: every
    drive), the other drives at ``fixed_kp``/``fixed_kd`` -- or lists with one value per drive.

    Attributes
    ----------
    plants : ModelPlants
        The explicit cache of orbits and plants per Omega (shared by copies of the task).
    config : TuningConfig or None
        Ranges and tolerance of the plant rule (``None``: a model without drives).
    steps : int, optional
        Fixed propagator steps (``chart --steps``); ``None``: the rule's choice.
    drive : int or None
        Index of the charted drive; ``None``: the same (kp, kd) on every drive.
    fixed_kp, fixed_kd : tuple of float
        Gains of every drive (the charted one's are replaced by the point's).
    """

    plants: ModelPlants
    config: Any = None
    steps: Optional[int] = None
    drive: Optional[int] = 0
    fixed_kp: tuple = ()
    fixed_kd: tuple = ()

    def plant(self, omega: float) -> Any:
        """The plant at ``omega`` (:meth:`ModelPlants.plant`)."""
        return self.plants.plant(omega, self.config, self.steps)

    def gains(self, kp: Any, kd: Any, n_drives: int) -> tuple[list, list]:
        """Per-drive gains of a point (see the class docstring)."""
        if isinstance(kp, (list, tuple)):
            return [float(v) for v in kp], [float(v) for v in kd]
        gp = [float(v) for v in self.fixed_kp] or [0.0] * n_drives
        gd = [float(v) for v in self.fixed_kd] or [0.0] * n_drives
        for j in (range(n_drives) if self.drive is None else (self.drive,)):
            gp[j], gd[j] = float(kp), float(kd)
        return gp, gd

    def __call__(self, point: dict) -> float:
        plant = self.plant(point["omega"])
        kp, kd = self.gains(point["kp"], point["kd"], len(plant.drives))
        return float(plant.spectral_measure(kp, kd) if plant.drives else plant.spectral_measure(0.0, 0.0))


#: Most points per chart axis (a 1001 x 1001 gain chart is already 1e6 Floquet evaluations,
#: ~1 h on 2 cores; more points cannot be told apart on a figure).
MAX_GRID_POINTS = 1001


def check_grid(lo: float, hi: float, n: int, name: str) -> np.ndarray:
    """``linspace(lo, hi, n)`` after validating the range (clear errors naming ``name``)."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{name} range must be finite, got [{lo}, {hi}]")
    if hi <= lo:
        raise ValueError(f"{name} range is empty or inverted: [{lo}, {hi}]")
    if isinstance(n, bool) or int(n) != n or n < 2:
        raise ValueError(f"{name} needs at least 2 grid points, got {n!r}")
    if n > MAX_GRID_POINTS:
        raise ValueError(f"{name}: {n} grid points is more than the {MAX_GRID_POINTS} a chart can resolve "
                         f"(a {n} x {n} gain chart would be {n * n:.3g} Floquet evaluations)")
    return np.linspace(lo, hi, int(n))


@dataclass(frozen=True)
class GainChart:
    """max|rho| on a (kp, kd) grid at one Omega (``radius[i, j]`` at ``kd[i], kp[j]``)."""

    omega: float
    kp: np.ndarray
    kd: np.ndarray
    radius: np.ndarray
    target: Optional[float]
    n_loaded: int
    n_computed: int

    def to_dict(self) -> dict:
        return {
            "omega": self.omega,
            "kp": self.kp.tolist(),
            "kd": self.kd.tolist(),
            "spectral_radius": self.radius.tolist(),
            "target": self.target,
            "n_loaded": self.n_loaded,
            "n_computed": self.n_computed,
        }


@dataclass(frozen=True)
class OmegaChart:
    """max|rho| against Omega, uncontrolled and with fixed gains."""

    omega: np.ndarray
    radius_uncontrolled: np.ndarray
    radius_controlled: np.ndarray
    kp: Any  # float, or one value per drive (model files)
    kd: Any

    def to_dict(self) -> dict:
        return {
            "omega": self.omega.tolist(),
            "spectral_radius_uncontrolled": self.radius_uncontrolled.tolist(),
            "spectral_radius_controlled": self.radius_controlled.tolist(),
            "kp": self.kp,
            "kd": self.kd,
        }


def gain_chart(
    task: Any,
    omega: float,
    kp: Sequence[float],
    kd: Sequence[float],
    executor,
    store: Path,
    *,
    target: Optional[float] = None,
    progress: Any = False,
) -> GainChart:
    """Evaluate ``task({"omega", "kp", "kd"})`` on the grid ``kd x kp`` (resumable via ``store``)."""
    kp = np.asarray(kp, dtype=float)
    kd = np.asarray(kd, dtype=float)
    points = [{"omega": float(omega), "kp": float(a), "kd": float(b)} for b in kd for a in kp]
    sweep = run_sweep(task, points, executor, store, progress=progress, desc="gain chart")
    radius = np.asarray(sweep.results, dtype=float).reshape(kd.size, kp.size)
    return GainChart(float(omega), kp, kd, radius, target, sweep.n_loaded, sweep.n_computed)


def omega_chart(
    task: Any,
    omegas: Sequence[float],
    kp: float,
    kd: float,
    executor,
    store: Path,
    *,
    progress: Any = False,
) -> OmegaChart:
    """max|rho| against Omega with zero gains and with ``(kp, kd)`` (resumable via ``store``).

    ``kp``, ``kd``: numbers, or one value per drive (lists; the zero gains are then lists too).
    The points run in the order of ``omegas``, uncontrolled first.
    """
    omegas = np.asarray(omegas, dtype=float)
    if isinstance(kp, (list, tuple)):
        kp, kd = [float(v) for v in kp], [float(v) for v in kd]
        zero: tuple = ([0.0] * len(kp), [0.0] * len(kd))
    else:
        kp, kd = float(kp), float(kd)
        zero = (0.0, 0.0)
    points = [{"omega": float(w), "kp": g[0], "kd": g[1]} for g in (zero, (kp, kd)) for w in omegas]
    sweep = run_sweep(task, points, executor, store, progress=progress, desc="omega chart")
    r = np.asarray(sweep.results, dtype=float).reshape(2, omegas.size)
    return OmegaChart(omegas, r[0], r[1], kp, kd)


def _label_every_segment(ax, cs, text: str, color: str) -> int:
    """Write ``text`` at the middle of every drawn segment of the single-level contour ``cs``.

    ``clabel`` drops labels on segments shorter than the label; a small closed |rho| = 1 island
    would then stay unnamed.  Returns the number of labels written.
    """
    n = 0
    segments = cs.allsegs[0] if cs.allsegs else []
    for seg in segments:
        if len(seg) < 2:
            continue
        x, y = seg[len(seg) // 2]
        ax.text(x, y, text, color=color, fontsize=8, ha="center", va="center",
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": color, "alpha": 0.85})
        n += 1
    return n


def plot_gain_chart(chart: GainChart, path: Path, taguchi_path: Optional[Sequence[Sequence[float]]] = None,
                    label: str = "linearised manipulator", drive: str = "") -> Path:
    """log10 max|rho| on a diverging colour scale centred at |rho| = 1 (blue stable, red unstable).

    The |rho| = 1 boundary is drawn in black and labelled on every segment, the rho_d contour
    dashed, and the Taguchi path (incumbent after each iteration) in orange.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    fig, ax = plt.subplots(figsize=(7.5, 5.8))
    KP, KD = np.meshgrid(chart.kp, chart.kd)
    L = np.log10(chart.radius)
    data_lo, hi = float(np.nanmin(L)), float(np.nanmax(L))
    # centre the colour scale at log10|rho| = 0; keep both halves even if the chart lies on one side.
    # Resolve |rho| down to FLOOR (everything smaller is "very stable", the darkest blue), so that
    # the range around rho_d is not washed out by a deep minimum of 1e-6.
    floor = min(-2.0, math.log10(chart.target) - 1.0) if chart.target else -2.0
    lo, hi = min(max(data_lo, floor), -1e-3), max(hi, 1e-3)
    norm = TwoSlopeNorm(vmin=lo, vcenter=0.0, vmax=hi)
    levels = np.unique(np.concatenate([np.linspace(lo, 0.0, 16), np.linspace(0.0, hi, 16)]))
    cf_ = ax.contourf(KP, KD, L, levels=levels, cmap="RdBu_r", norm=norm,
                      extend="min" if data_lo < lo else "neither")
    cb = fig.colorbar(cf_, ax=ax)
    # ticks at readable |rho| values (1, 3, 10, 30, ... and 0.3, 0.1, ...), labelled as |rho|, not its log
    cands = [m * 10.0 ** e for e in range(int(math.floor(lo)) - 1, int(math.ceil(hi)) + 1) for m in (1.0, 3.0)]
    ticks = [math.log10(c) for c in cands if lo <= math.log10(c) <= hi]
    cb.set_ticks(ticks)
    cb.set_ticklabels([f"{10.0 ** t:.3g}" for t in ticks])
    cb.set_label("max|ρ| (log scale; blue: < 1 stable, red: > 1 unstable)")
    cb.ax.axhline(0.0, color="k", lw=2)
    if np.nanmin(L) < 0 < np.nanmax(L):
        cs = ax.contour(KP, KD, chart.radius, levels=[1.0], colors="k", linewidths=2)
        _label_every_segment(ax, cs, "|ρ| = 1", "k")
    if chart.target is not None and np.nanmin(chart.radius) < chart.target < np.nanmax(chart.radius):
        ct = ax.contour(KP, KD, chart.radius, levels=[chart.target], colors="0.15", linewidths=1.3, linestyles="--")
        _label_every_segment(ax, ct, f"ρ_d = {chart.target:g}", "0.15")
    if taguchi_path:
        p = np.asarray(taguchi_path, dtype=float)
        ax.plot(p[:, 0], p[:, 1], "o-", color="orange", ms=4, lw=1.2, mec="k", mew=0.4, label="Taguchi incumbents")
        ax.plot(p[-1, 0], p[-1, 1], "*", color="orange", ms=14, mec="k", label="tuned gains")
        ax.legend(loc="upper right", framealpha=0.9)
    of = f" of drive {drive}" if drive else ""
    ax.set_xlabel(f"kp{of} (N·m/rad)")
    ax.set_ylabel(f"kd{of} (N·m·s/rad)")
    import textwrap

    ax.set_title(textwrap.fill(f"max|ρ|, {label}", 80)
                 + f"\nΩ = {chart.omega / math.pi:.3g}π rad/s, {chart.kp.size} × {chart.kd.size} grid", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _gain_text(g) -> str:
    """``"12.5"`` for one gain, ``"(12.5, 3)"`` for one per drive."""
    if isinstance(g, (list, tuple)):
        return "(" + ", ".join(f"{v:.4g}" for v in g) + ")"
    return f"{g:.4g}"


def dominant_ylabel(orbit) -> str:
    """Axis label of a model's dominant multiplier: the drive modes, and the first bending mode only when
    the model has beams (ANCF slope nodes; a rigid arm has no bending mode)."""
    return f"dominant |ρ| ({'drive modes / bending 1' if orbit.slope_nodes else 'drive modes'})"


def plot_omega_chart(chart: OmegaChart, path: Path, label: str = "linearised reduced model",
                     ylabel: str = "max|ρ| (spectral radius)") -> Path:
    """The plotted multiplier (``ylabel``) against Omega (log scale), uncontrolled and controlled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import textwrap

    fig, ax = plt.subplots(figsize=(7, 4.8), layout="constrained")
    x = chart.omega / math.pi
    # the |rho| = 1 line is drawn below the curves (zorder), thin: a curve on the unit circle (an undamped
    # mode) stays visible on top of it instead of hidden under it
    ax.axhline(1.0, color="red", lw=0.9, ls="--", label="|ρ| = 1", zorder=1)
    ax.semilogy(x, chart.radius_uncontrolled, "-", lw=1.8, label="uncontrolled (kp = kd = 0)", zorder=3)
    ax.semilogy(x, chart.radius_controlled, "-", lw=1.8, zorder=3,
                label=f"kp = {_gain_text(chart.kp)} N·m/rad, kd = {_gain_text(chart.kd)} N·m·s/rad")
    ax.set_xlabel("Ω / π (Ω in rad/s)")
    ax.set_ylabel(ylabel)
    # wrapped to the figure's width (a model's label ran past both edges)
    ax.set_title(textwrap.fill(f"{ylabel} against the frequency Ω of the fundamental motion; {label}", 80),
                 fontsize=10)
    ax.legend(fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
