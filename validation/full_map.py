"""The whole one-period map of a nonlinear closed loop, measured from generic perturbations.

Why a second measurement beside :mod:`validation.multipliers`: that one perturbs along the
*predicted* Floquet vectors and projects on the *predicted* left vectors, so a slow mode the
prediction does not have is invisible to it by construction.  Here the perturbations are
random, the map is fitted on the full independent-coordinate state, and every slow multiplier
the runs contain is reported, predicted or not.

Method
------
1. **Perturbations.**  ``p >= 2r`` random directions (Gaussian in the energy coordinates
   ``z = [Lk^T dq; Lm^T dq']`` of :class:`~validation.multipliers.EnergyNorm`, fixed seed), each
   scaled to the energy of a hub-velocity kick of ``a`` rad/s.  The model path maps them into
   Exudyn's coordinates through the null-space basis and projects the perturbed state on the
   position *and* velocity constraints (``_consistent_state``): every run starts on the
   constraint manifold.
2. **Runs.**  One period of the nonlinear closed loop from ``x0 + d_j`` and from ``x0``; the
   image is the difference of the end states (one-sided: the reference run's integration
   error cancels, the quadratic term of the map leaves an ``O(a)`` relative error, ~3e-5 at
   ``a = 1e-2`` on the single link, far below the step error bars here).  The runs are
   independent and go through an executor when one is given.
3. **Fit.**  ``A = Z1 Z0^+`` (least squares, energy coordinates): the estimate of the
   whole discrete one-period map.  Its eigenvalues at each step level are tracked across the
   levels by their eigenvectors (assignment on ``|<v, w>|``; the phase of an unresolved mode
   jumps between levels, its shape does not).
4. **Step refinement with the integrator's damping law.**  Exudyn's Newmark method with
   ``beta = 1/4, gamma = 1/2`` (trapezoidal) and index-2 constraints.  For a mode
   ``lambda = -sigma + i omega`` it maps one step by ``g(lambda h) = (1 + lambda h / 2) /
   (1 - lambda h / 2)``, so ``ln|g| = -sigma h / (1 + (omega h / 2)^2)`` to first order in
   ``sigma h``: over one period ``L_h = L / (1 + c h^2)`` with ``L = ln|mu|``.  The variable
   ``y = 1 / ln|mu_h| = (1 + c h^2) / L`` is therefore *linear in* ``h^2`` whether the step
   resolves the mode (``omega h << 1``) or not, and Richardson extrapolation on ``y`` with
   ratio 4 gives ``1 / ln|mu|``.  The observed ratio of the ``y`` changes shows whether the
   runs follow that law (4 for a constant-coefficient mode; a time-periodic one deviates by
   the modulation).  Error bar of the extrapolated ``y``: :data:`GCI_SAFETY` times the spread
   between the extrapolations with ratio 4 and with the observed ratio (and, from four levels
   on, the change of the extrapolation from the previous triple over 15, the Richardson
   estimate of the next, ``h^4``, term), mapped to the modulus.
   Measured on the two-link arm (2 elements per link, four-gain optimum at 2 pi; linear
   trapezoidal map of its linearisation): the 22 kHz axial pair has ``|mu_h|`` = 0.998005,
   0.991921, 0.969291, 0.898027 at T/4096 ... T/32768 (true 0.557307): ``y`` changes 377.5,
   91.2, 22.8, ratios 4.14, 4.006; extrapolated 0.5574.
5. **Resolved** multipliers: three or more levels, observed ratio in :data:`RATIO_BAND`, bar
   below :data:`~validation.multipliers.MEASURED_FRACTION` of the modulus.  Levels whose log
   moduli change by less than :data:`NOISE_LOG` are converged at the runs' resolution (e.g.
   an undamped mode at ``|mu| = 1``), bar ten times the largest change.
6. **Verdict** (:func:`compare_full_map`): every resolved measured multiplier above
   ``floor`` needs a predicted partner (optimal assignment on the moduli, within the sum of
   the two error bars); a resolved one without is *unmatched*: the prediction misses a slow
   mode.  Unresolved ones are listed, not judged.

Why not generalised-alpha: at ``rho_inf = 1`` (index 3) it does not stay on the unperturbed
periodic orbit of the two-link arm (velocity error x28 per period at T/2048 and T/8192,
measured); at ``rho_inf = 0.9`` it stays periodic but damps every mode the step does not
resolve by ``rho_inf`` per step -- the 22 kHz axial pair would vanish from the map at any
affordable step (``0.9^8192``) and a prediction that omits it would pass.  The trapezoidal
rule damps nothing numerically; unresolved modes keep ``L_h = L / (1 + c h^2)``, which step 4
undoes.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np

from stability.serialization import json_ready

__all__ = [
    "FULL_MAP_FLOOR",
    "NOISE_LOG",
    "RATIO_BAND",
    "FullMapConfig",
    "FullMapMultiplier",
    "FullMapResult",
    "FullMapComparison",
    "compare_full_map",
    "measure_full_map",
    "extrapolate_modulus",
    "full_map_from_maps",
    "full_map_report",
    "measure_model_full_map",
    "predicted_spectrum",
    "random_perturbations",
]

logger = logging.getLogger(__name__)

#: Multipliers whose measured modulus is below this are not reported (the runs resolve
#: ~1e-8 absolute; below 1e-3 nothing is slow).
FULL_MAP_FLOOR = 1e-3
#: Observed ratios of the ``y = 1/ln|mu_h|`` changes accepted as the trapezoidal law's 4.
RATIO_BAND = (3.0, 5.5)
#: Log moduli that change by less than this between all levels are converged at the resolution
#: of the runs (Newton increments 1e-10 over perturbations ~1e-2 give ~1e-8).
NOISE_LOG = 1e-7
#: Safety factor on the extrapolation spread (as Roache's GCI).
GCI_SAFETY = 1.25
#: Richardson ratio of the trapezoidal law (``h^2``) and of its next term (``h^4``).
LAW_RATIO = 4.0
NEXT_RATIO = 16.0


@dataclass(frozen=True)
class FullMapConfig:
    """Settings of the full-map measurement.

    Parameters
    ----------
    step : float or None
        Coarsest step (s); ``None``: chosen by the path.
    refinements : int
        Step halvings (>= 2 for a verdict: three levels show the law's ratio).
    amplitude : float or None
        Perturbation energy as a hub-velocity kick (rad/s).
    perturbations : int or None
        Number of random directions (``None``: the state dimension ``2r``; more gives an
        overdetermined least-squares fit).
    slowest : int
        Number of multipliers reported (largest moduli).
    seed : int
        Random generator seed of the directions.
    floor : float
        Moduli below this are not reported.
    amplitude_check : bool
        Repeat one level with half the amplitude: the one-sided images err by ``c a``, so
        the value at ``a`` is ``2 |mu(a) - mu(a/2)|`` off; that is added to each bar
        (``amplitude_error``).  Costs one more run of that level.
    amplitude_level : int
        Which level the half-amplitude run repeats (index into :attr:`steps`; ``-1``, the default,
        is the finest).  The amplitude error ``c a`` does not depend on the step to leading order,
        so ``0`` (the coarsest, cheapest level) measures it at a fraction of the cost.
    """

    step: Optional[float] = None
    refinements: int = 2
    amplitude: Optional[float] = None
    perturbations: Optional[int] = None
    slowest: int = 6
    seed: int = 0
    floor: float = FULL_MAP_FLOOR
    amplitude_check: bool = True
    amplitude_level: int = -1

    def __post_init__(self) -> None:
        for name in ("refinements", "slowest", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.refinements > 4:
            raise ValueError(f"refinements must be <= 4, got {self.refinements!r}")
        if self.slowest < 1:
            raise ValueError(f"slowest must be >= 1, got {self.slowest!r}")
        if self.perturbations is not None:
            if isinstance(self.perturbations, bool) or int(self.perturbations) != self.perturbations \
                    or self.perturbations < 1:
                raise ValueError(f"perturbations must be an integer >= 1, got {self.perturbations!r}")
            object.__setattr__(self, "perturbations", int(self.perturbations))
        for name in ("step", "amplitude"):
            v = getattr(self, name)
            if v is None:
                continue
            if not (math.isfinite(float(v)) and float(v) > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        if not (0.0 < float(self.floor) < 1.0):
            raise ValueError(f"floor must be in (0, 1), got {self.floor!r}")
        lv = self.amplitude_level
        if isinstance(lv, bool) or int(lv) != lv or not (-(self.refinements + 1) <= lv <= self.refinements):
            raise ValueError(f"amplitude_level must index one of the {self.refinements + 1} step levels, got {lv!r}")
        object.__setattr__(self, "amplitude_level", int(lv))

    @property
    def steps(self) -> tuple:
        """``h, h/2, ...`` (empty while ``step`` is None)."""
        from validation.multipliers import step_halvings

        return step_halvings(self.step, self.refinements)


@dataclass(frozen=True)
class FullMapMultiplier:
    """One measured multiplier of the full map.

    Attributes
    ----------
    modulus : float
        Extrapolated modulus (the finest level's when not extrapolated).
    error_bar : float
        Absolute bar of ``modulus`` (inf when the levels bound nothing).
    phase : float
        Argument at the finest level (rad; not extrapolated, not judged).
    levels : ndarray, complex
        The tracked eigenvalue per step level, coarse to fine.
    observed_ratio : float
        Ratio of the last two changes of ``1/ln|mu_h|`` (4: the trapezoidal law).
    resolved : bool
    amplitude_error : float
        Part of ``error_bar`` from the amplitude check (0 without one).
    """

    modulus: float
    error_bar: float
    phase: float
    levels: np.ndarray
    observed_ratio: float
    resolved: bool
    amplitude_error: float = 0.0

    def to_dict(self) -> dict:
        return json_ready({"modulus": self.modulus, "error_bar": self.error_bar, "phase": self.phase,
                           "amplitude_error": self.amplitude_error,
                           "levels": [[float(z.real), float(z.imag)] for z in self.levels],
                           "observed_ratio": self.observed_ratio, "resolved": self.resolved})


@dataclass(frozen=True)
class FullMapResult:
    """The measured full one-period map (see the module docstring).

    Attributes
    ----------
    multipliers : tuple of FullMapMultiplier
        The ``config.slowest`` largest moduli above ``config.floor``, descending.
    steps : tuple of float
    n_perturbations : int
    state_dimension : int
    maps : tuple of ndarray
        Fitted map per level (energy coordinates).
    fit_residual : tuple of float
        Relative least-squares residual per level (0 for a square fit).
    diverged : bool
    reason : str
    integrator : str
    config : FullMapConfig
    info : dict
    """

    multipliers: tuple
    steps: tuple
    n_perturbations: int
    state_dimension: int
    maps: tuple = field(repr=False)
    fit_residual: tuple
    diverged: bool
    reason: str
    integrator: str
    config: FullMapConfig
    info: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return json_ready({
            "multipliers": [m.modulus for m in self.multipliers],
            "error_bars": [m.error_bar for m in self.multipliers],
            "phases": [m.phase for m in self.multipliers],
            "resolved": [m.resolved for m in self.multipliers],
            "observed_ratio": [m.observed_ratio for m in self.multipliers],
            "amplitude_error": [m.amplitude_error for m in self.multipliers],
            "levels": [[[float(z.real), float(z.imag)] for z in m.levels] for m in self.multipliers],
            "n_perturbations": self.n_perturbations,
            "state_dimension": self.state_dimension,
            "steps": list(self.steps),
            "fit_residual": list(self.fit_residual),
            "diverged": self.diverged,
            "reason": self.reason,
            "integrator": self.integrator,
            "floor": self.config.floor,
            "amplitude": self.config.amplitude,
            **self.info,
        })


def random_perturbations(norm: Any, count: int, scale: float, seed: int = 0) -> np.ndarray:
    """``count`` random states (columns) of energy ``scale`` each: Gaussian in energy coordinates."""
    n = norm.Lm.shape[0]
    rng = np.random.default_rng(seed)
    Z = rng.standard_normal((2 * n, count))
    Z *= scale / np.linalg.norm(Z, axis=0)
    X = np.empty_like(Z)
    X[:n] = np.linalg.solve(norm.Lk.T, Z[:n])
    X[n:] = np.linalg.solve(norm.Lm.T, Z[n:])
    return X


def extrapolate_modulus(levels: Sequence[complex]) -> tuple[float, float, float, bool]:
    """Modulus of one tracked multiplier from its step levels (item 4 of the module docstring).

    Parameters
    ----------
    levels : sequence of complex
        The multiplier at ``h, h/2, h/4, ...``.

    Returns
    -------
    (modulus, error_bar, observed_ratio, resolved)
    """
    mu = np.asarray(levels, dtype=complex)
    m = mu.size
    finest = float(abs(mu[-1]))
    if m == 0 or not np.all(np.isfinite(mu)) or np.any(mu == 0):
        return finest if m else math.nan, math.inf, math.nan, False
    L = np.log(np.abs(mu))
    if m >= 2 and float(np.max(np.abs(np.diff(L)))) <= NOISE_LOG:
        # the levels agree to the runs' resolution (an undamped mode, or one the law leaves unchanged)
        bar = finest * max(10.0 * float(np.max(np.abs(np.diff(L)))), NOISE_LOG)
        return finest, bar, math.nan, m >= 3
    if m == 1 or np.any(L == 0):
        return finest, math.inf, math.nan, False
    y = 1.0 / L
    ext4 = y[-1] + (y[-1] - y[-2]) / (LAW_RATIO - 1.0)
    if m == 2:
        return _modulus_interval(ext4, abs(ext4 - y[-1])) + (math.nan, False)
    d0, d1 = y[-2] - y[-3], y[-1] - y[-2]
    q = d0 / d1 if d1 != 0 else math.inf
    spread = abs(ext4 - (y[-1] + d1 / (q - 1.0))) if math.isfinite(q) and q > 1.1 else abs(ext4 - y[-1])
    if m >= 4:
        prev = y[-2] + (y[-2] - y[-3]) / (LAW_RATIO - 1.0)
        spread = max(spread, abs(ext4 - prev) / (NEXT_RATIO - 1.0))
    value, bar = _modulus_interval(ext4, GCI_SAFETY * spread)
    from validation.multipliers import MEASURED_FRACTION

    ok = bool(RATIO_BAND[0] <= q <= RATIO_BAND[1] and bar <= MEASURED_FRACTION * max(value, 1e-300))
    return value, bar, float(q), ok


def _modulus_interval(y: float, b: float) -> tuple[float, float]:
    """``exp(1/y)`` and the largest modulus deviation over ``y +- b`` (inf if the interval holds 0)."""
    value = math.exp(1.0 / y) if y != 0 else (math.inf if y > 0 else 0.0)
    lo, hi = y - b, y + b
    if lo <= 0.0 <= hi:
        return value, math.inf
    ends = [math.exp(1.0 / e) if abs(1.0 / e) < 700 else (0.0 if e < 0 else math.inf) for e in (lo, hi)]
    return value, max(abs(e - value) for e in ends)


def _track(maps: Sequence[np.ndarray], floor: float, reference: int = -1) -> list:
    """Eigenvalues of ``maps[reference]`` (default the last, the finest) above ``floor`` and their partners
    in every other map (assignment on eigenvector overlaps), in the order of ``maps``."""
    from scipy.optimize import linear_sum_assignment

    eig = [np.linalg.eig(A) for A in maps]
    ref = reference % len(maps)
    vals_f, vecs_f = eig[ref]
    vecs_f = vecs_f / np.linalg.norm(vecs_f, axis=0)
    keep = [i for i in range(vals_f.size) if abs(vals_f[i]) >= floor]
    tracks = {i: [None] * len(maps) for i in keep}
    for i in keep:
        tracks[i][ref] = vals_f[i]
    for j, (vals, vecs) in enumerate(eig):
        if j == ref:
            continue
        vecs = vecs / np.linalg.norm(vecs, axis=0)
        mac = np.abs(vecs_f.conj().T @ vecs)
        r, c = linear_sum_assignment(-mac)
        partner = dict(zip(r, c))
        for i in keep:
            tracks[i][j] = vals[partner[i]]
    return [np.array(tracks[i], dtype=complex) for i in keep]


def measure_full_map(
    images: Callable[[float, np.ndarray], np.ndarray],
    norm: Any,
    config: FullMapConfig,
    *,
    integrator: str = "Newmark (beta = 1/4, gamma = 1/2, trapezoidal), index-2 constraints",
    info: Optional[dict] = None,
) -> FullMapResult:
    """Measure the slowest multipliers of the whole one-period map (model-independent core).

    Parameters
    ----------
    images : callable
        ``images(h, D) -> X1``: the one-period images (end state of the perturbed run minus
        that of the unperturbed one) of the perturbation columns ``D`` at step ``h``; may raise
        on a solver failure (reported as a divergence).
    norm : EnergyNorm
    config : FullMapConfig
        ``step`` and ``amplitude`` must be set.
    integrator : str
        Described in the result.
    info : dict, optional
        Copied into the JSON.

    Returns
    -------
    FullMapResult
        Never raises for a failing run (``diverged``).
    """
    if config.step is None or config.amplitude is None:
        raise ValueError("measure_full_map needs config.step and config.amplitude")
    tic = time.perf_counter()
    n2 = 2 * norm.Lm.shape[0]
    p = n2 if config.perturbations is None else config.perturbations
    if p < n2:
        raise ValueError(f"the full map of a {n2}-dimensional state needs >= {n2} perturbations, got {p}")
    scale = config.amplitude * math.sqrt(norm.hub_mass)
    D = random_perturbations(norm, p, scale, config.seed)
    Z0 = norm.transform(D)
    maps, resid, timings = [], [], {}
    diverged, reason = False, ""
    for h in config.steps:
        t1 = time.perf_counter()
        try:
            X1 = np.asarray(images(h, D), dtype=float)
        except Exception as exc:  # the simulator's own error types
            diverged, reason = True, f"one-period run at step {h:g} s failed: {exc}"
            break
        if X1.shape != D.shape or not np.all(np.isfinite(X1)):
            diverged, reason = True, f"non-finite or mis-shaped images at step {h:g} s"
            break
        Z1 = norm.transform(X1)
        At, res, *_ = np.linalg.lstsq(Z0.T, Z1.T, rcond=None)
        A = At.T
        maps.append(A)
        resid.append(float(np.linalg.norm(A @ Z0 - Z1) / max(np.linalg.norm(Z1), 1e-300)))
        timings[f"step {h:g}"] = time.perf_counter() - t1
    half = None
    if maps and not diverged and config.amplitude_check:
        t1 = time.perf_counter()
        try:
            X1h = 2.0 * np.asarray(images(config.steps[config.amplitude_level], 0.5 * D), dtype=float)
            At = np.linalg.lstsq(Z0.T, norm.transform(X1h).T, rcond=None)[0]
            half = At.T
        except Exception as exc:  # the simulator's own error types
            diverged, reason = True, f"half-amplitude run failed: {exc}"
        timings["amplitude check"] = time.perf_counter() - t1
    if diverged:
        logger.warning("full-map measurement diverged: %s", reason)
    info = dict(info or {})
    info["timings"] = {**info.get("timings", {}), **timings, "full_map": time.perf_counter() - tic}
    return full_map_from_maps(maps, config.steps[:len(maps)], config, p, n2, resid, diverged, reason, integrator,
                              info, half_amplitude_map=half, half_amplitude_level=config.amplitude_level)


def _amplitude_error(levels: Sequence[complex], half: complex, level: int, value: float) -> float:
    """Error of the extrapolated modulus ``value`` at the runs' amplitude ``a``, from the repeat ``half``
    of step level ``level`` at ``a/2``.  The one-sided error ``c a`` shifts every level by about the same
    ``delta``: the levels shifted by it and re-extrapolated move by the error's part at ``a`` (doubled:
    ``a -> 0`` from ``a`` and ``a/2``), and by at least ``2 |delta|``, the multiplier's own shift."""
    delta = abs(half) - abs(levels[level])
    shifted = [z * (abs(z) + delta) / abs(z) if z != 0 else z for z in levels]
    moved = extrapolate_modulus(shifted)[0]
    return 2.0 * max(abs(delta), abs(moved - value) if math.isfinite(moved) else 0.0)


def full_map_from_maps(maps: Sequence[np.ndarray], steps: Sequence[float], config: FullMapConfig,
                       n_perturbations: int, state_dimension: int, fit_residual: Sequence[float] = (),
                       diverged: bool = False, reason: str = "",
                       integrator: str = "Newmark (beta = 1/4, gamma = 1/2, trapezoidal), index-2 constraints",
                       info: Optional[dict] = None, half_amplitude_map: Optional[np.ndarray] = None,
                       half_amplitude_level: int = -1) -> FullMapResult:
    """Steps 3-5 of the module docstring on fitted maps (one per step level, coarse to fine): tracked,
    extrapolated, the ``config.slowest`` largest kept.  Lets a measurement made level by level (e.g. each
    level stored on disk as it finishes) be assembled without repeating the runs.
    ``half_amplitude_map`` repeats level ``half_amplitude_level`` (default the finest) at half the
    amplitude; the change, applied to every level, re-extrapolated and doubled, is added to each bar."""
    mults: list = []
    if maps and not diverged:
        from validation.multipliers import MEASURED_FRACTION

        tracks = _track(list(maps) + ([half_amplitude_map] if half_amplitude_map is not None else []), config.floor,
                        reference=len(maps) - 1)
        for lv in tracks:
            half = None
            if half_amplitude_map is not None:
                lv, half = lv[:-1], lv[-1]
            value, bar, q, ok = extrapolate_modulus(lv)
            amp_err = 0.0 if half is None else _amplitude_error(lv, half, half_amplitude_level, value)
            bar += amp_err
            ok = ok and bar <= MEASURED_FRACTION * max(value, 1e-300)
            mults.append(FullMapMultiplier(modulus=value, error_bar=bar, phase=float(np.angle(lv[-1])),
                                           levels=lv, observed_ratio=q, resolved=ok, amplitude_error=amp_err))
        # unresolved ones by the finest level (the trapezoidal law: an upper bound of the modulus)
        mults.sort(key=lambda m: -(m.modulus if m.resolved else abs(m.levels[-1])))
        mults = [m for m in mults if (m.modulus if m.resolved else abs(m.levels[-1])) >= config.floor]
        mults = mults[:config.slowest]
    return FullMapResult(multipliers=tuple(mults), steps=tuple(steps), n_perturbations=int(n_perturbations),
                         state_dimension=int(state_dimension), maps=tuple(maps), fit_residual=tuple(fit_residual),
                         diverged=diverged, reason=reason, integrator=integrator, config=config, info=dict(info or {}))


@dataclass(frozen=True)
class FullMapComparison:
    """A prediction's multipliers against the measured full map.

    Attributes
    ----------
    partners : list of dict
        Per measured multiplier: its modulus, bar, the predicted partner (modulus, label,
        error) and whether they agree.
    unmatched : list of dict
        Resolved measured multipliers with no predicted partner within the bars (the
        prediction misses these slow modes).
    unresolved : list of dict
        Measured multipliers whose step levels do not resolve them (no verdict).
    agrees : bool
        No unmatched multiplier and no divergence.
    """

    partners: list
    unmatched: list
    unresolved: list
    agrees: bool

    def to_dict(self) -> dict:
        return json_ready(dict(self.__dict__))


def compare_full_map(result: FullMapResult, predicted: Sequence[complex], labels: Sequence[str],
                     errors: Optional[Sequence[float]] = None) -> FullMapComparison:
    """Match the measured slow multipliers with a prediction (item 6 of the module docstring).

    Parameters
    ----------
    result : FullMapResult
    predicted : sequence of complex
        Every predicted multiplier (a prediction that omits a mode simply leaves it out).
    labels : sequence of str
        Mode label of each.
    errors : sequence of float, optional
        Absolute error estimate of each (default 0).
    """
    from scipy.optimize import linear_sum_assignment

    P = np.abs(np.asarray(predicted, dtype=complex))
    E = np.zeros(P.size) if errors is None else np.nan_to_num(np.asarray(errors, dtype=float), nan=0.0)
    ms = list(result.multipliers)
    partners, unmatched, unresolved = [], [], []
    if ms and P.size:
        M = np.array([m.modulus if m.resolved else abs(m.levels[-1]) for m in ms])
        B = np.array([m.error_bar for m in ms])
        diff = np.abs(M[:, None] - P[None, :])
        # as many partners within the bars as possible, then the closest ones
        outside = diff > B[:, None] + E[None, :]
        r, c = linear_sum_assignment(outside.astype(float) + 1e-3 * diff / (1.0 + diff))
        pair = dict(zip(r, c))
    else:
        pair = {}
    for i, m in enumerate(ms):
        row = {"modulus": m.modulus, "error_bar": m.error_bar, "resolved": m.resolved,
               "phase": m.phase, "finest_level": float(abs(m.levels[-1]))}
        k = pair.get(i)
        if k is not None:
            ok = bool(abs(m.modulus - P[k]) <= m.error_bar + E[k])
            row.update({"predicted": float(P[k]), "mode": labels[k], "prediction_error": float(E[k]), "agrees": ok})
        else:
            ok = False
            row.update({"predicted": None, "mode": None, "prediction_error": None, "agrees": False})
        partners.append(row)
        if not m.resolved:
            unresolved.append(row)
        elif not ok:
            unmatched.append(row)
    agrees = bool(not result.diverged and not unmatched and ms)
    return FullMapComparison(partners=partners, unmatched=unmatched, unresolved=unresolved, agrees=agrees)


# --------------------------------------------------------------------------- model files (generic path)
#: Exudyn settings of the runs: Newmark with these parameters (the trapezoidal rule) and index-2
#: constraints (see the module docstring for why).
NEWMARK_BETA = 0.25
NEWMARK_GAMMA = 0.5


def newmark_settings(t0: float, t1: float, h: float, integrator: str = "newmark") -> Any:
    """Exudyn settings of one run: :func:`validation.multipliers._run_settings` (fixed step, Newton on the
    increment, no silent step cut) switched to Newmark ``beta = 1/4, gamma = 1/2`` with index-2 constraints
    (``integrator="newmark"``), or generalised-alpha (index 3) at ``rho_inf = float(integrator)``."""
    from validation.multipliers import _run_settings

    if integrator != "newmark":
        return _run_settings(t0, t1, h, float(integrator))
    s = _run_settings(t0, t1, h, 1.0)
    ga = s.timeIntegration.generalizedAlpha
    ga.useNewmark = True
    ga.useIndex2Constraints = True
    ga.newmarkBeta = NEWMARK_BETA
    ga.newmarkGamma = NEWMARK_GAMMA
    return s


#: Generalised-alpha ``rho_inf`` of the runs when the model has rheonomic constraints (see
#: :func:`measure_model_full_map`).
RHEONOMIC_SPECTRAL_RADIUS = 0.9


def integrator_name(integrator: str) -> str:
    """Human-readable name of a :class:`ClosedLoopSpec` integrator."""
    if integrator == "newmark":
        return "Newmark (beta = 1/4, gamma = 1/2, trapezoidal), index-2 constraints"
    return f"generalised-alpha, spectralRadius = {float(integrator):g}, index-3 constraints"


@dataclass(frozen=True)
class ClosedLoopSpec:
    """What a worker needs to rebuild the closed loop (picklable when ``model`` is a name or a path)."""

    model: Any
    omega: float
    kp: tuple
    kd: tuple
    samples: int
    options: tuple = ()
    integrator: str = "newmark"


class ClosedLoopRunner:
    """The nonlinear closed loop of a model file about its orbit, ready for one-period runs.

    Built from a :class:`ClosedLoopSpec` (orbit, linearisation at the gains for the null-space
    basis and the energy norm, the Exudyn closed loop of :func:`validation.multipliers._closed_loop_built`).
    States are ``x = [z, z']`` in the linearisation's independent coordinates.
    """

    def __init__(self, spec: ClosedLoopSpec, orbit: Any = None) -> None:
        import exudyn as exu

        from linearize.constrained import linearize_orbit
        from linearize.exudyn_system import ExudynSystem
        from linearize.periodic_orbit import find_orbit
        from mbs_models.model_file import build_model, resolve_model
        from validation.multipliers import EnergyNorm, _closed_loop_built, energy_norm

        self.spec = spec
        definition = resolve_model(spec.model, **dict(spec.options))
        self.definition = definition
        self.orbit = orbit if orbit is not None else find_orbit(definition, spec.omega, samples=spec.samples)
        lin = linearize_orbit(self.orbit, list(spec.kp), list(spec.kd))
        self.linearization = lin
        self.period = 2 * math.pi / spec.omega
        self.r = lin.size
        self.N0, self.N0t = lin.basis[0], lin.basis_t[0]
        self.N0p = np.linalg.pinv(self.N0)
        self.q0, self.v0 = self.orbit.q[0].copy(), self.orbit.q_t[0].copy()
        norm = energy_norm(lin.M[0], lin.K[0])
        if lin.drives:
            b = lin.B[0][:, 0]
            norm = EnergyNorm(norm.Lk, norm.Lm, float(b @ np.linalg.solve(lin.M[0], b)) ** -1)
        self.norm = norm
        d = lin.drives
        kp = np.resize(np.asarray(lin.kp, dtype=float), d) if d else np.zeros(0)
        kd = np.resize(np.asarray(lin.kd, dtype=float), d) if d else np.zeros(0)
        self.built = _closed_loop_built(definition, spec.omega, self.orbit, kp, kd)
        self.constraints = ExudynSystem(build_model(definition, spec.omega))
        self._ini = exu.ConfigurationType.Initial

    @property
    def rheonomic(self) -> bool:
        """Whether a constraint depends on time explicitly: ``C(q0, t) != C(q0, 0)`` at some of eight times in
        the period (beyond round-off of coordinates of size ``max|q0|``)."""
        if not self.constraints.m:
            return False
        c0 = self.constraints.constraints(self.q0, 0.0)
        tol = 1e-12 * (1.0 + float(np.max(np.abs(self.q0))))
        return any(float(np.max(np.abs(self.constraints.constraints(self.q0, t) - c0))) > tol
                   for t in np.arange(1, 8) * self.period / 8.0)

    def run(self, x: np.ndarray, h: float) -> np.ndarray:
        """State at ``T`` of the run from the orbit state perturbed by ``x`` at ``t = 0`` (constraint-consistent)."""
        from linearize.exudyn_system import from_exudyn_velocity, lie_group_nodes, to_exudyn_velocity
        from validation.multipliers import _consistent_state

        r, T = self.r, self.period
        mbs, sd = self.built.mbs, self.built.mbs.systemData
        dz, dzt = x[:r], x[r:]
        q, v = _consistent_state(self.constraints, self.q0 + self.N0 @ dz, self.v0 + self.N0 @ dzt + self.N0t @ dz,
                                 0.0, T)
        lie = lie_group_nodes(mbs)  # rotation-vector nodes: Exudyn's velocities are angular velocities
        sd.SetODE2Coordinates(q, configuration=self._ini)
        sd.SetODE2Coordinates_t(to_exudyn_velocity(lie, q, v), configuration=self._ini)
        if mbs.SolveDynamic(newmark_settings(0.0, T, h, self.spec.integrator)) is False:
            raise RuntimeError("Exudyn time integration did not succeed")
        qT = np.array(sd.GetODE2Coordinates())
        vT = from_exudyn_velocity(lie, qT, np.array(sd.GetODE2Coordinates_t()))
        ez = self.N0p @ (qT - self.q0)
        return np.concatenate([ez, self.N0p @ (vT - self.v0 - self.N0t @ ez)])

    def images(self, h: float, D: np.ndarray) -> np.ndarray:
        """One-sided images ``x(T; x0 + d_j) - x(T; x0)`` of the columns of ``D``."""
        ref = self.run(np.zeros(2 * self.r), h)
        return np.array([self.run(D[:, j], h) - ref for j in range(D.shape[1])]).T


def _images_chunk(spec: ClosedLoopSpec, h: float, D: np.ndarray, quiet: bool = True) -> np.ndarray:
    """Worker: rebuild the closed loop from ``spec`` and return the images of ``D`` (module level: picklable)."""
    from mbs_models.console import exudyn_console

    with exudyn_console(quiet):
        return ClosedLoopRunner(spec).images(h, D)


def measure_model_full_map(
    model: Any,
    omega: float,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    *,
    samples: Optional[int] = None,
    config: FullMapConfig = FullMapConfig(),
    executor: Any = None,
    chunks: Optional[int] = None,
    quiet: bool = True,
    integrator: str = "auto",
    **options: Any,
) -> tuple[FullMapResult, Any]:
    """Measure the full one-period map of a model file's nonlinear closed loop.

    Parameters
    ----------
    model : str, path or ModelDefinition
        A built-in name or a model-file path when ``executor`` runs in other processes.
    omega : float
    kp, kd : float or sequence
        Gains per drive (or one for all).
    samples : int, optional
        Orbit samples (default :data:`validation.multipliers.MODEL_SAMPLES`).
    config : FullMapConfig
        ``step=None``: :func:`validation.multipliers.suggested_step` (trapezoidal rule, ``rho_inf = 1``);
        ``amplitude=None``: :data:`validation.multipliers.MODEL_AMPLITUDE`.
    executor : concurrent.futures.Executor, optional
        Runs chunks of perturbations (each rebuilds the closed loop); ``None``: in this process.
    chunks : int, optional
        Chunks per step level (default: 1 without an executor, else 2).
    quiet : bool
    integrator : {"auto", "newmark"} or a string holding a float
        ``"newmark"``: Newmark ``beta = 1/4, gamma = 1/2`` with index-2 constraints (no numerical damping);
        a number: generalised-alpha (index 3) at that ``rho_inf``.  ``"auto"`` (default): Newmark unless a
        constraint depends on time explicitly, then ``rho_inf =`` :data:`RHEONOMIC_SPECTRAL_RADIUS`.  Why:
        Exudyn's index-2 velocity constraint of a ``CoordinateConstraint`` takes its rate from
        ``offsetUserFunction_t``, which a model file need not define; without it the driven support of the
        Kapitza pendulum (``tests/models/vertical_pendulum.py``) stands still at velocity level and the
        measured map is that of the unstabilised pendulum (1.509 and 0.650 against Mathieu's pair of modulus
        0.990468), while generalised-alpha at 0.9 gives 0.9904676 (levels at T/128 ... T/512 converging
        with ratio 3.98, the O(h^2) of its numerical damping).
    **options
        Keyword options of the model's ``build``.

    Returns
    -------
    (FullMapResult, ClosedLoopRunner)
        The runner holds the orbit and the linearisation at the gains.
    """
    from dataclasses import replace

    from mbs_models.console import exudyn_console
    from validation.multipliers import MODEL_AMPLITUDE, MODEL_SAMPLES, suggested_step

    omega = float(omega)
    if not (math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be finite and > 0, got {omega!r}")
    samples = MODEL_SAMPLES if samples is None else int(samples)
    with exudyn_console(quiet):
        from linearize.periodic_orbit import find_orbit
        from mbs_models.model_file import build_model, resolve_model
        from validation.multipliers import refuse_lie_group_nodes

        definition = resolve_model(model, **options)
        refuse_lie_group_nodes(build_model(definition, omega))
        orbit = find_orbit(definition, omega, samples=samples)
        n_drives = len(orbit.drive_names)
        kp_t = tuple(np.resize(np.atleast_1d(np.asarray(kp, dtype=float)), n_drives).tolist()) if n_drives else ()
        kd_t = tuple(np.resize(np.atleast_1d(np.asarray(kd, dtype=float)), n_drives).tolist()) if n_drives else ()
        spec = ClosedLoopSpec(model, omega, kp_t, kd_t, samples, tuple(sorted(options.items())),
                              "newmark" if integrator == "auto" else integrator)
        runner = ClosedLoopRunner(spec, orbit=orbit)
        if integrator == "auto" and runner.rheonomic:
            spec = replace(spec, integrator=str(RHEONOMIC_SPECTRAL_RADIUS))
            runner = ClosedLoopRunner(spec, orbit=orbit)
        T = runner.period
        if config.amplitude is None:
            config = replace(config, amplitude=MODEL_AMPLITUDE)
        if config.step is None:
            config = replace(config, step=suggested_step(runner.linearization, T, 1.0))
        if config.step >= T:
            raise ValueError(f"step must be smaller than the period T = {T:.6g} s, got {config.step!r}")
        n_chunks = chunks if chunks is not None else (1 if executor is None else 2)

        def images(h: float, D: np.ndarray) -> np.ndarray:
            if executor is None:
                return runner.images(h, D)
            parts = np.array_split(np.arange(D.shape[1]), max(1, n_chunks))
            futs = [executor.submit(_images_chunk, spec, h, D[:, idx]) for idx in parts if idx.size]
            return np.concatenate([f.result() for f in futs], axis=1)

        info = {"model": runner.definition.name, "omega": omega, "period": T, "kp": list(kp_t), "kd": list(kd_t),
                "samples": samples}
        result = measure_full_map(images, runner.norm, config, info=info, integrator=integrator_name(spec.integrator))
    return result, runner


def predicted_spectrum(analysis: Any) -> tuple[np.ndarray, list, np.ndarray]:
    """Every predicted multiplier of a :class:`linearize.analysis.ModelFloquetResult` with its label and
    absolute error estimate (``|mu| 10^-reliable_digits``; 0 where the result has none)."""
    res = analysis.floquet
    mu = np.asarray(res.multipliers, dtype=complex)
    labels = [m.mode for m in analysis.modes]
    err = np.abs(mu) * 10.0 ** -np.asarray(res.reliable_digits, dtype=float)
    return mu, labels, np.nan_to_num(err, nan=0.0)


def full_map_report(result: FullMapResult, analysis: Any, *, omit: Sequence[str] = ()) -> dict:
    """JSON block ``full_map`` of ``flexstab validate``: the measurement and its comparison with ``analysis``
    (modes whose label is in ``omit`` removed from the prediction)."""
    mu, labels, err = predicted_spectrum(analysis)
    keep = [i for i, lab in enumerate(labels) if lab not in set(omit)]
    cmp = compare_full_map(result, mu[keep], [labels[i] for i in keep], err[keep])
    d = result.to_dict()
    d.update({"partners": cmp.partners, "unmatched": cmp.unmatched, "unresolved": cmp.unresolved,
              "agrees": cmp.agrees, "omitted_modes": list(omit)})
    return json_ready(d)
