"""The two-link flexible arm study: Floquet, mesh convergence, four-gain Taguchi, checks, figures.

Everything goes through the generic model-file path (``linearize.find_orbit``,
``linearize.linearize_orbit``, ``linearize.analyze``) with the built-in model
file ``mbs_models/builtin/two_link.py``; the independent checks are
:mod:`validation.direct_monodromy` (finite-difference monodromy of one-period
Exudyn runs) and a second Floquet method on the same linearisation.

Tuning response: like the single link's Exudyn plant, the dominant multiplier
*off the unit circle* (``| |rho| - 1 | >= UNDAMPED_TOLERANCE``): without
structural damping the axial and most bending modes of the FE model keep
``|rho| = 1`` whatever the gains.
"""
from __future__ import annotations

import functools
import logging
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Optional, Sequence

import numpy as np

from flexstab.plants import hill_plant  # the one copy of the harmonics-at-the-range-centre rule
from linearize.hill_plant import HillModelPlant
from stability.gains import Gains
from stability.refine import pair_estimate
from taguchi.tuning import GainObjective, TaguchiResult, TuningConfig, taguchi_tune

if TYPE_CHECKING:
    from linearize.periodic_orbit import PeriodicOrbit

__all__ = [
    "MODEL",
    "TUNING_RANGES",
    "TUNED_GAINS",
    "UNDAMPED_TOLERANCE",
    "TUNING_FLOQUET",
    "two_link_orbit",
    "dominant_damped",
    "tuning_objective",
    "tune_four_gains",
    "hill_plant",
    "compare_direct_methods",
    "TunedCheck",
    "TwoLinkFloquet",
    "TwoLinkNoisePlant",
    "two_link_noise_factors",
    "two_link_floquet",
    "check_multiplier",
    "CHECK_STEPS",
    "main_dominant",
    "LabelledPlant",
    "gain_slices_hill",
]

logger = logging.getLogger(__name__)

#: Name of the built-in model file.
MODEL = "two-link"
#: Multipliers with ``| |rho| - 1 |`` below this are undamped FE modes (as ``linearize.analysis``).
UNDAMPED_TOLERANCE = 2e-3
#: Floquet options inside the tuning loop: exponential midpoint (every factor an exact
#: matrix exponential: the stiff axial modes make higher-order Magnus overflow), fixed
#: steps.  Measured on the drive-mode multiplier at 2 elements (gains 20, 5, 5, 1):
#: 512 steps 0.0132875, 1024 0.0131898, 2048 0.0131911 -> about 1e-4 absolute at 512.
TUNING_FLOQUET = {"method": "magnus2", "n_steps": 512, "error_estimate": False}
#: Steps of the independent check (streamed magnus2): two resolutions, the finer converged
#: to ~1e-6 on the 2-element arm (measured: 2.0e-7 at 2 pi, 1.4e-6 at 4 pi against Hill).
CHECK_STEPS = (16384, 32768)
#: Four-gain Taguchi results (Hill response, ranges TUNING_RANGES, rho_d = 0.3, 2 elements per link;
#: measured with ``benchmarks/two_link_speed.py`` / ``scripts/two_link_study.py``): |rho| = 0.300132 (2 pi) and
#: 0.300027 (4 pi) by Hill, 0.300132 / 0.300025 by the streamed magnus2 product at 32768 steps.
#: Used by the study when the script's cached results are absent.
TUNED_GAINS = {
    2: (15.0, 8.935546875, 7.138671875, 1.4443359375),
    4: (21.6015625, 7.900390625, 5.888671875, 1.8779296875),
}
#: Initial gain ranges (kp1, kd1, kp2, kd2) of the four-gain tuning; see the 2-D slices
#: (``gain_slices_hill``) in the study for why they bracket rho_d = 0.3 at both Omega.
TUNING_RANGES = ((0.0, 40.0), (0.0, 10.0), (0.0, 10.0), (0.0, 3.0))


def two_link_orbit(omega: float, elements: Optional[int] = None, **options: Any) -> "PeriodicOrbit":
    """The periodic orbit of the built-in two-link arm (generic collocation path)."""
    from linearize.periodic_orbit import find_orbit
    from mbs_models.model_file import builtin_model

    opts = dict(options)
    if elements is not None:
        opts["elements"] = elements
    return find_orbit(builtin_model(MODEL, **opts), omega)


def dominant_damped(multipliers: Sequence[complex], tolerance: float = UNDAMPED_TOLERANCE) -> complex:
    """Largest multiplier off the unit circle (else the largest)."""
    mus = np.asarray(multipliers)
    order = np.argsort(-np.abs(mus), kind="stable")
    for j in order:
        if abs(abs(mus[j]) - 1.0) >= tolerance:
            return complex(mus[j])
    return complex(mus[order[0]])


def tuning_objective(lin: Any, floquet_options: Optional[dict] = None) -> GainObjective:
    """``(kp1, kd1, kp2, kd2) -> |rho|`` of the dominant damped multiplier of ``lin`` with those gains."""
    return GainObjective(lin, floquet_options or TUNING_FLOQUET, unit_circle_tolerance=UNDAMPED_TOLERANCE)


def main_dominant(multipliers: Sequence[complex], modes: Sequence[Any], drive_names: Sequence[str]) -> complex:
    """Largest multiplier of a drive mode or of ``bending 1`` off the unit circle.

    The rule of ``linearize.analysis`` (the modes a rigid or one-mode model
    has: the paper's hub and first bending mode for the single link); without
    such modes the largest one off the unit circle.
    """
    main = set(drive_names) | {"bending 1"}
    for mu, m in zip(multipliers, modes):
        if m.mode in main and not m.undamped:
            return complex(mu)
    return dominant_damped(multipliers)


@dataclass(frozen=True)
class LabelledPlant:
    """The linearisation as a :class:`stability.gains.MeasuredPlant` whose response is the dominant
    *labelled* multiplier (:func:`main_dominant`) of ``stability.floquet`` with ``floquet_options``.

    The lightly damped axial modes of the two-link arm's mesh (e.g. a 22 kHz pair with |rho| = 0.557
    at 2 elements per link, 0.860 at 4: mesh modes, not mesh-converged and hardly moved by the joint
    gains; see :func:`flexstab.plants.whole_spectrum`) make the spectral radius of the whole
    linearisation a property of the mesh, not the paper's quantity; the response is the multiplier of
    the drive modes / first bending mode, labelled by :func:`linearize.analysis.label_multipliers` at
    every evaluation (the whole spectrum is reported beside it, never hidden).
    """

    lin: Any
    orbit: Any
    floquet_options: Optional[dict] = None

    def with_gains(self, kp: Any, kd: Any) -> Any:
        return self.lin.with_gains(kp, kd)

    def spectral_measure(self, kp: Any, kd: Any) -> float:
        from linearize.analysis import label_multipliers
        from stability import floquet

        lg = self.with_gains(kp, kd)
        res = floquet(lg, **dict(self.floquet_options or TUNING_FLOQUET))
        modes = label_multipliers(lg, self.orbit, res)
        return abs(main_dominant(res.multipliers, modes, self.orbit.drive_names))


def tune_four_gains(lin: Any, target: float = 0.3, *, orbit: Any = None, ranges: Sequence = TUNING_RANGES,
                    executor: Any = None, max_evaluations: int = 2000,
                    floquet_options: Optional[dict] = None, response: str = "hill",
                    harmonics: Optional[int] = None) -> TaguchiResult:
    """Iterative Taguchi (L9, four factors) to ``|rho_dominant| = target`` on the linearisation ``lin``.

    ``response="hill"`` (default, needs ``orbit``): the dominant labelled multiplier
    measured by Hill's method (:class:`linearize.hill_plant.HillModelPlant`; its
    harmonic count chosen once at the centre of the ranges unless ``harmonics``
    is given).  ``response="magnus"``: :class:`LabelledPlant` with
    ``floquet_options`` (with ``orbit``), else the largest multiplier off the unit circle.
    """
    cfg = TuningConfig(target=target, ranges=tuple(ranges), max_evaluations=max_evaluations)
    if response == "hill":
        if orbit is None:
            raise ValueError("response='hill' needs the orbit (mode labels)")
        obj = GainObjective(hill_plant(lin, orbit, cfg, harmonics=harmonics))
    elif response == "magnus":
        obj = (GainObjective(LabelledPlant(lin, orbit, floquet_options)) if orbit is not None
               else tuning_objective(lin, floquet_options))
    else:
        raise ValueError(f"response must be 'hill' or 'magnus', got {response!r}")
    return taguchi_tune(obj, cfg, executor=executor)


def compare_direct_methods(lin: Any, orbit: Any, target: float, *,
                           methods: Sequence[str] = ("nelder-mead", "differential-evolution"),
                           max_evaluations: int = 3000,
                           report: Optional[Callable[[str, dict], None]] = None) -> list:
    """The direct optimisers on the four-gain tuning problem, for comparison with Taguchi.

    Same objective (the Hill response of :func:`hill_plant`), same ranges (:data:`TUNING_RANGES`) and
    target; one :meth:`DirectResult.to_dict` per method with its CPU seconds (``cpu_s``, this
    process: the optimisers run serially).  ``report(method, row)`` is called after each method.
    """
    from taguchi.direct import direct_tune

    cfg = TuningConfig(target=target, ranges=TUNING_RANGES, max_evaluations=max_evaluations)
    obj = GainObjective(hill_plant(lin, orbit, cfg))
    rows = []
    for m in methods:
        c0 = time.process_time()
        d = direct_tune(obj, cfg, m).to_dict()
        d["cpu_s"] = time.process_time() - c0
        rows.append(d)
        if report is not None:
            report(m, d)
    return rows


@dataclass(frozen=True)
class GainSlices:
    """``|rho|`` over 2-D slices of the gain space (one drive's pair varied, the other fixed)."""

    kp_grid: tuple
    kd_grid: tuple
    shoulder: np.ndarray  # (kd, kp) with the elbow gains fixed
    elbow: np.ndarray
    fixed: tuple

    def to_dict(self) -> dict:
        return {"kp_grid": [list(g) for g in self.kp_grid], "kd_grid": [list(g) for g in self.kd_grid],
                "shoulder": self.shoulder.tolist(), "elbow": self.elbow.tolist(), "fixed": list(self.fixed)}


def _slices(obj: Any, fixed: Sequence[float], ranges: Sequence, points: int, executor: Any) -> GainSlices:
    """The two (kp, kd) slices of a four-gain response ``obj`` (one drive's pair varied, the other at ``fixed``)."""
    grids_p = [np.linspace(*ranges[0], points), np.linspace(*ranges[2], points)]
    grids_d = [np.linspace(*ranges[1], points), np.linspace(*ranges[3], points)]
    out = []
    for drive in (0, 1):
        pts = []
        for kd in grids_d[drive]:
            for kp in grids_p[drive]:
                g = list(fixed)
                g[2 * drive], g[2 * drive + 1] = float(kp), float(kd)
                pts.append(tuple(g))
        vals = list(executor.map(obj, pts)) if executor is not None else [obj(p) for p in pts]
        out.append(np.array(vals).reshape(points, points))
    return GainSlices(kp_grid=tuple(tuple(g) for g in grids_p), kd_grid=tuple(tuple(g) for g in grids_d),
                      shoulder=out[0], elbow=out[1], fixed=tuple(float(v) for v in fixed))


def gain_slices_hill(lin: Any, orbit: Any, fixed: Sequence[float], *, ranges: Sequence = TUNING_RANGES,
                     points: int = 9, executor: Any = None, harmonics: int = 12) -> GainSlices:
    """``|rho|`` of the tuning response (Hill's method, :class:`HillModelPlant`) on a ``points x points`` grid
    of (kp1, kd1) at fixed (kp2, kd2) and of (kp2, kd2) at fixed (kp1, kd1)."""
    obj = GainObjective(HillModelPlant(lin, orbit, harmonics=harmonics))
    return _slices(obj, fixed, ranges, points, executor)


def plot_gain_slices(sl: GainSlices, path, *, target: float = 0.3, title: str = "") -> None:
    """Contour plots of the two slices with the ``rho_d`` level."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), layout="constrained")
    for ax, data, name, d in ((axes[0], sl.shoulder, "shoulder", 0), (axes[1], sl.elbow, "elbow", 1)):
        X, Y = np.meshgrid(sl.kp_grid[d], sl.kd_grid[d])
        cs = ax.contourf(X, Y, np.minimum(data, 1.5), levels=20, cmap="viridis")
        fig.colorbar(cs, ax=ax, label="dominant |ρ| (clipped at 1.5)")
        ax.contour(X, Y, data, levels=[target], colors="r", linewidths=2)
        ax.set_xlabel(f"kp{d + 1} (N·m/rad)")
        ax.set_ylabel(f"kd{d + 1} (N·m·s/rad)")
        other = (sl.fixed[2], sl.fixed[3]) if d == 0 else (sl.fixed[0], sl.fixed[1])
        ax.set_title(f"{name} gains; other drive at kp = {other[0]:.3g}, kd = {other[1]:.3g}", fontsize=9)
    fig.suptitle(title or f"two-link: dominant |ρ| (drive modes / bending 1) over gain slices; red: ρ_d = {target:g}",
                 fontsize=10)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def timed(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    """``(fn(*args, **kwargs), wall seconds)``."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


@dataclass(frozen=True)
class TunedCheck:
    """The dominant multiplier at some gains by Hill (the loop's method) and by an independent product.

    Attributes
    ----------
    gains : tuple
    hill : complex
        Hill's value (``harmonics``), with ``hill_error_estimate`` (relative, H vs H/2).
    mode : str
    streamed : dict
        ``{n_steps: multiplier}`` of the streamed magnus2 product nearest Hill's value.
    magnus_error_estimate : float
        ``4/3 |rho_2n - rho_n|`` of the two finest products (second order), absolute.
    modal : dict, optional
        ``steps``, ``multiplier``, ``error_estimate`` of :func:`stability.modal.modal_floquet`
        (frozen-modal coordinates, Richardson-extrapolated).
    difference : float
        ``| |rho_hill| - |rho_magnus,finest| |``.
    seconds : dict
    """

    gains: tuple
    hill: complex
    hill_error_estimate: float
    harmonics: int
    mode: str
    streamed: dict
    magnus_error_estimate: float
    difference: float
    seconds: dict
    modal: Optional[dict] = None

    def to_dict(self) -> dict:
        c = lambda z: [float(np.real(z)), float(np.imag(z))]  # noqa: E731
        md = None if self.modal is None else {
            "steps": self.modal["steps"], "multiplier": c(self.modal["multiplier"]),
            "modulus": float(abs(self.modal["multiplier"])), "error_estimate": self.modal["error_estimate"],
            "difference": float(abs(abs(self.modal["multiplier"]) - abs(self.hill)))}
        return {"modal_magnus2": md, "gains": list(self.gains), "hill": c(self.hill), "hill_modulus": float(abs(self.hill)),
                "hill_error_estimate": self.hill_error_estimate, "harmonics": self.harmonics, "mode": self.mode,
                "streamed_magnus2": {str(k): c(v) for k, v in self.streamed.items()},
                "streamed_moduli": {str(k): float(abs(v)) for k, v in self.streamed.items()},
                "magnus_error_estimate": self.magnus_error_estimate, "difference": self.difference,
                "seconds": dict(self.seconds)}


def check_multiplier(lin: Any, orbit: Any, gains: Sequence[float], *, steps: Sequence[int] = CHECK_STEPS,
                     harmonics: int = 32, modal_steps: Optional[int] = 512) -> TunedCheck:
    """Dominant labelled multiplier at ``gains`` by Hill, by streamed magnus2 products at ``steps`` and
    (``modal_steps``) by the Richardson-extrapolated magnus2 product in frozen-modal coordinates."""
    from stability.engines import floquet

    gg = Gains.from_interleaved(gains)
    g = list(gg.interleaved())
    t0 = time.perf_counter()
    m = HillModelPlant(lin, orbit, harmonics=harmonics).measure(gg.kp, gg.kd, error_estimate=True)
    secs = {"hill": time.perf_counter() - t0}
    lg = lin.with_gains(gg.kp, gg.kd)
    streamed = {}
    for n in steps:
        t0 = time.perf_counter()
        # fixed step count: floquet() streams large products in chunks (memory O(n^2) in the steps)
        w = np.asarray(floquet(lg, method="magnus", order=2, n_steps=int(n), error_estimate=False).multipliers)
        streamed[int(n)] = complex(w[int(np.argmin(np.abs(w - m.dominant)))])
        secs[f"magnus2_{n}"] = time.perf_counter() - t0
    mods = [abs(streamed[int(n)]) for n in steps]
    est = pair_estimate(mods[-2], mods[-1]) if len(mods) > 1 else math.nan
    modal = None
    if modal_steps:
        # a third method: the exponential midpoint in frozen-modal coordinates (stability.modal), Richardson-
        # extrapolated from modal_steps and modal_steps / 2 (fourth order), with its own error estimate
        t0 = time.perf_counter()
        r = floquet(lg, method="modal", order=2, n_steps=int(modal_steps), extrapolate=True)
        w = np.asarray(r.multipliers)
        modal = {"steps": int(modal_steps), "multiplier": complex(w[int(np.argmin(np.abs(w - m.dominant)))]),
                 "error_estimate": float(r.error_estimate)}
        secs["modal_magnus2"] = time.perf_counter() - t0
    return TunedCheck(gains=tuple(g), hill=m.dominant, hill_error_estimate=m.hill_error_estimate, harmonics=harmonics,
                      mode=m.mode, streamed=streamed, magnus_error_estimate=est,
                      difference=abs(abs(m.dominant) - mods[-1]), seconds=secs, modal=modal)


@dataclass(frozen=True)
class TwoLinkFloquet:
    """Orbit, linearisation and the labelled multipliers of the two-link arm at one Omega and gains.

    ``labelled`` is the magnus2 pass (all multipliers, mode labels); ``measure`` the
    dominant drive-mode / bending-1 multiplier measured by Hill's method with ``harmonics``.
    """

    omega: float
    elements: int
    gains: tuple
    orbit: Any = field(repr=False)
    linearization: Any = field(repr=False)
    floquet: Any = field(repr=False)
    modes: list = field(repr=False)
    measure: Any = None
    cpu_seconds: dict = field(default_factory=dict)
    harmonics: int = 16


def two_link_floquet(omega: float, elements: Optional[int] = None, gains: Sequence[float] = (0.0, 0.0, 0.0, 0.0), *,
                     orbit: Any = None, lin: Any = None, harmonics: int = 16,
                     label_steps: int = 512, **options: Any) -> TwoLinkFloquet:
    """Orbit + linearisation + labelled Floquet (magnus2 labels, Hill value) of the two-link arm.

    CPU seconds per stage in ``cpu_seconds`` (``time.process_time``, this process).
    """
    from linearize.constrained import linearize_orbit

    cpu: dict = {}
    c0 = time.process_time()
    if orbit is None:
        orbit = two_link_orbit(omega, elements, **options)
    cpu["orbit"] = time.process_time() - c0
    c0 = time.process_time()
    if lin is None:
        lin = linearize_orbit(orbit, 0.0, 0.0)
    cpu["linearization"] = time.process_time() - c0
    gg = Gains.from_interleaved(gains)
    g = list(gg.interleaved())
    plant = HillModelPlant(lin, orbit, label_steps=label_steps, harmonics=harmonics)
    c0 = time.process_time()
    _, res, modes = plant.labelled(gg.kp, gg.kd)
    cpu["floquet_labels"] = time.process_time() - c0
    c0 = time.process_time()
    m = plant.measure(gg.kp, gg.kd, error_estimate=True)
    cpu["hill"] = time.process_time() - c0
    n_el = elements
    if n_el is None:
        from mbs_models.builtin.two_link import DEFAULT_ELEMENTS

        n_el = DEFAULT_ELEMENTS
    return TwoLinkFloquet(omega=float(omega), elements=int(n_el), gains=tuple(g), orbit=orbit, linearization=lin,
                          floquet=res, modes=modes, measure=m, cpu_seconds=cpu, harmonics=int(harmonics))


#: Most noise values whose plant :func:`_noise_plant` keeps per process (an outer array of a robust
#: design has 9 runs; the worst-case grid ``grid^3``, e.g. 64).
NOISE_PLANT_CACHE = 400


@functools.lru_cache(maxsize=NOISE_PLANT_CACHE)
def _noise_plant(omega: float, elements: Optional[int], harmonics: int, tip_mass: float, omega_scale: float,
                 youngs_modulus_scale: float) -> HillModelPlant:
    """Orbit + linearisation of the two-link arm at one noise value, as a Hill plant.

    A pure function of hashable keys, cached per process (``lru_cache``): the outer runs of a
    crossed array recur in every experiment of the robust design.
    """
    from linearize.constrained import linearize_orbit
    from mbs_models.builtin.two_link import TwoLinkParameters

    orbit = two_link_orbit(omega * omega_scale, elements, tip_mass=tip_mass,
                           youngs_modulus=TwoLinkParameters.youngs_modulus * youngs_modulus_scale)
    return HillModelPlant(linearize_orbit(orbit, 0.0, 0.0), orbit, harmonics=harmonics)


@dataclass(frozen=True)
class TwoLinkNoisePlant:
    """``noise -> plant`` of the two-link arm for the robust design (picklable).

    ``noise`` may hold ``tip_mass`` (kg), ``omega_scale`` and ``youngs_modulus_scale``
    (missing: nominal).  Each noise value gets its own periodic orbit and
    linearisation (payload, frequency and stiffness change the orbit), cached per
    process (:func:`_noise_plant`); :class:`taguchi.robust.PlantNoiseObjective` calls the plant's
    ``spectral_measure`` with the gains of the run.
    """

    omega: float
    elements: Optional[int] = None
    harmonics: int = 12

    def __call__(self, noise: Any) -> HillModelPlant:
        from mbs_models.builtin.two_link import TwoLinkParameters

        tip = float(noise.get("tip_mass", TwoLinkParameters.tip_mass))
        w = float(noise.get("omega_scale", 1.0))
        e = float(noise.get("youngs_modulus_scale", 1.0))
        return _noise_plant(float(self.omega), self.elements, int(self.harmonics), tip, w, e)


def two_link_noise_factors(settings: Any) -> tuple:
    """Noise factors of the ``[robust]`` settings about the two-link arm's nominal tip mass."""
    from mbs_models.builtin.two_link import TwoLinkParameters

    return settings.noise_factors(TwoLinkParameters.tip_mass)
