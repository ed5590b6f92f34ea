"""A model file's linearisation as a tuning plant whose response is measured by Hill's method.

Why: on finite-element models with stiff undamped modes (the two-link arm's axial
modes, 3.6-28 kHz against Omega / 2 pi = 1-2 Hz) the exponential-midpoint product
converges erratically in its step count (step-size resonances ``h omega ~ 2 pi m``):
the drive-mode multiplier of the two-link arm at 4 pi moves by 2e-3 between 1024 and
8192 steps and settles (to 1e-6) only beyond ~16384 steps.  Hill's method
(:mod:`stability.hill`) has no step count: with 16 harmonics it gives the same
multiplier to ~1e-9 in 0.05 s.

How an evaluation works (:meth:`HillModelPlant.measure`):

1. ``magnus2`` with a modest, fixed step count on a prepared
   :class:`stability.gains.FloquetWorkspace` (``P_0`` and the drive-gain terms
   sampled once): all multipliers, labelled by :func:`linearize.analysis.label_multipliers`;
2. every multiplier labelled as a drive mode or ``bending 1`` (the rule of
   :attr:`linearize.analysis.ModelFloquetResult.dominant_multiplier`) is refined by
   Hill's method on the same linearisation (its samples with the gains: the system
   ``stability.floquet`` integrates);
3. the response is the largest refined modulus that is a multiplier of the magnus2
   spectrum to the product's own accuracy (:func:`_in_spectrum`: the nearest multiplier at N/2 and N
   steps, whatever its label) and has a backward error below :data:`stability.hill.RESIDUAL_LIMIT`;
4. the response's own H vs H/2 change (:func:`stability.hill.pair_error_estimate`) must meet the run
   budget (:meth:`HillModelPlant.budget`, a quarter of the tuning tolerance), else the harmonics are
   doubled (up to :data:`MAX_HARMONICS`).

The step count of (1) only has to put each estimate nearer its own exponent than any
other (checked: the refined value must lie within :data:`MATCH_TOLERANCE` in
``log rho`` of its estimate, else the estimate is recomputed with twice the steps).
When Hill's value cannot be used (not confirmed at 4x the steps, not resolved at
:data:`MAX_HARMONICS`, or a :class:`stability.hill.HillError`), the response is the labelled dominant
of the frozen-modal magnus2 product (:meth:`HillModelPlant.modal_measure`), refined in its steps to
the run budget -- or a :class:`stability.hill.HillError` is raised, which the tuning records as a
failed run; :attr:`HillMeasure.method` says which.
"""
from __future__ import annotations

import functools
import logging
import math
import uuid
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np

from linearize.analysis import UNDAMPED_TOLERANCE, label_multipliers
from linearize.fourier import trig_interpolate
from linearize.periodic_orbit import PeriodicOrbit
from linearize.system import LinearizedPeriodicSystem
from stability.gains import GainArgument
from stability.hill import TAIL_LIMIT, HillError, pair_error_estimate

if TYPE_CHECKING:
    from stability.gains import GainParametrisedSystem

__all__ = [
    "HillModelPlant",
    "HillMeasure",
    "drive_gain_family",
    "LABEL_STEPS",
    "TUNING_HARMONICS",
    "MATCH_TOLERANCE",
    "DEFAULT_RTOL",
    "RUN_BUDGET",
    "HILL_FLOOR",
    "MAX_HARMONICS",
    "MAX_FALLBACK_STEPS",
    "select_harmonics",
    "HarmonicsChoice",
]

logger = logging.getLogger(__name__)

#: magnus2 sub-intervals of the labelling pass (estimates and mode labels only).
LABEL_STEPS = 512
#: Hill harmonics in the tuning loop (two-link arm, 2 elements: relative change vs H/2 below 1e-8).
TUNING_HARMONICS = 16
#: Estimates below ``NOISE_FACTOR`` times the product's rounding floor are not refined.
NOISE_FACTOR = 1e3
#: Only estimates at least this fraction of the largest candidate are refined (the response is the max).
RELATIVE_CUTOFF = 1e-2
#: At most this many candidates are refined per evaluation.
MAX_REFINED = 4
#: Pairing of a main-mode estimate with its own refinement: ``|log(refined / estimate)| <= MATCH_TOLERANCE``
#: (a coarse test that the estimate was nearer its own exponent than any other; it does NOT decide whether a
#: refined value is a multiplier of the spectrum: :func:`_in_spectrum` does).
MATCH_TOLERANCE = 0.25
#: Response tolerance (relative to ``|rho|``) of a plant built without one (``tolerance=None``): the default
#: tuning tolerance ``1e-3 rho_d`` of :mod:`taguchi.tuning` at ``rho = rho_d``.
DEFAULT_RTOL = 1e-3
#: Per-run error budget as a fraction of the tuning tolerance: two responses each within ``tol / 4`` of the
#: truth differ from the true difference by at most ``tol / 2``, so a comparison at the tolerance keeps its sign.
RUN_BUDGET = 0.25
#: Relative floor of the per-run budget: Hill's H vs H/2 change does not fall below its round-off (measured
#: 9.3e-14 .. 9.7e-14 at H = 32 / 48 on the two-link arm, 1 element), so a budget below ``HILL_FLOOR |rho|``
#: (a tolerance near machine precision) is raised to it rather than made unreachable.
HILL_FLOOR = 1e-12
#: Most Hill harmonics a run may escalate to (doubling from the plant's count) to meet its budget.
MAX_HARMONICS = 64
#: Most steps of the frozen-modal fallback (doubling from ``TUNING_PROPAGATOR_STEPS``); the value of
#: ``flexstab.plants.MAX_TUNING_STEPS`` (linearize may not import flexstab).
MAX_FALLBACK_STEPS = 4096
#: Labelling workspaces (one per plant and step count) kept per process by :func:`_labelling_workspace`.
WORKSPACE_CACHE = 16


def _log_distance(z: complex, spectrum: np.ndarray) -> float:
    """``min_k |log(z / w_k)|`` over the (non-zero) multipliers ``w_k`` of ``spectrum`` (inf if empty)."""
    if spectrum.size == 0:
        return math.inf
    return float(np.min(np.abs(np.log(complex(z) / spectrum))))


def _in_spectrum(z: complex, coarse: np.ndarray, fine: np.ndarray, budget: float) -> bool:
    """Whether ``z`` is a multiplier of the magnus2 spectrum to the product's own accuracy.

    ``w_2N`` is the multiplier of ``fine`` (``2N`` steps: the labelling pass) nearest ``z`` and ``w_N`` the one
    of ``coarse`` (``N`` steps, half the labelling pass's) nearest ``w_2N``; accepted when
    ``|z - w_2N| <= 4/3 |w_N - w_2N| + budget``.  Derivation:
    second order in the step, ``|w_2N - rho| ~ |w_N - w_2N| / 3``, so for ``z`` within ``budget`` of the true
    ``rho`` (Hill's own error, bounded by the per-run budget) ``|z - w_2N| <= |w_N - w_2N| / 3 + budget``;
    the factor 4/3 (instead of 1/3) leaves room for a pre-asymptotic ratio, the rule of
    ``flexstab.plants.propagator_steps``.
    """
    if fine.size == 0 or coarse.size == 0:
        return False
    w2 = complex(fine[int(np.argmin(np.abs(fine - z)))])
    w1 = complex(coarse[int(np.argmin(np.abs(coarse - w2)))])
    return abs(complex(z) - w2) <= 4.0 / 3.0 * abs(w1 - w2) + budget


def drive_gain_family(lin: LinearizedPeriodicSystem) -> "GainParametrisedSystem":
    """:class:`stability.gains.GainParametrisedSystem` of the drive gains ``(kp1, kd1, kp2, kd2, ...)``.

    With ``K += B kp B^T + B kd B_t^T`` and ``C += B kd B^T`` (see
    :class:`~linearize.system.LinearizedPeriodicSystem`), ``P = [[0, I], [-M^-1 K, -M^-1 C]]``
    changes by ``sum_d kp_d u_d [b_d^T, 0] + kd_d u_d [b_t,d^T, b_d^T]`` with
    ``u_d = [0; -M^-1 b_d]``: time-dependent rank-one terms.  ``M``, ``b``, ``b_t`` are the
    trigonometric interpolants of their samples.
    """
    from stability.gains import GainParametrisedSystem

    if lin.B is None:
        raise ValueError("the linearisation has no drive input map B (not a model file's)")
    if lin.breakpoints:
        raise ValueError("the linearisation is sampled piece by piece (declared breakpoints): its matrices "
                         "have no trigonometric interpolant, so Hill's method does not apply")
    base = lin.with_gains(0.0, 0.0)
    T = float(lin.period)
    d, n = lin.B.shape[2], lin.size
    Bs, Bts = lin.B, lin.B_t

    def inputs(times: np.ndarray) -> np.ndarray:
        M = trig_interpolate(base.M, T, times)
        B = trig_interpolate(Bs, T, times)
        u = -np.linalg.solve(M, B)  # (m, n, d)
        out = np.zeros((len(times), 2 * n, 2 * d))
        out[:, n:, 0::2] = u
        out[:, n:, 1::2] = u
        return out

    def outputs(times: np.ndarray) -> np.ndarray:
        B = trig_interpolate(Bs, T, times)
        Bt = trig_interpolate(Bts, T, times)
        out = np.zeros((len(times), 2 * d, 2 * n))
        out[:, 0::2, :n] = np.swapaxes(B, 1, 2)
        out[:, 1::2, :n] = np.swapaxes(Bt, 1, 2)
        out[:, 1::2, n:] = np.swapaxes(B, 1, 2)
        return out

    names = tuple(f"{k}{j + 1}" for j in range(d) for k in ("kp", "kd"))
    return GainParametrisedSystem(base, inputs, outputs, names=names, period=T)


class _PlantKey:
    """Hashable handle of a plant's linearisation and orbit for the per-process caches below: equal iff
    the token is (a token is drawn once per :class:`HillModelPlant` and kept by its copies and pickles)."""

    __slots__ = ("token", "linearization", "orbit")

    def __init__(self, token: str, linearization: LinearizedPeriodicSystem, orbit: PeriodicOrbit) -> None:
        self.token, self.linearization, self.orbit = token, linearization, orbit

    def __hash__(self) -> int:
        return hash(self.token)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _PlantKey) and other.token == self.token


@functools.lru_cache(maxsize=WORKSPACE_CACHE)
def _labelling_workspace(key: _PlantKey, steps: int) -> Any:
    """The prepared magnus2 workspace of the drive-gain family at ``steps`` (built once per process: a
    process pool unpickles the plant once per task)."""
    return drive_gain_family(key.linearization).workspace(steps, method="magnus2")


@functools.lru_cache(maxsize=WORKSPACE_CACHE)
def _frozen_modes(key: _PlantKey) -> tuple[Any, np.ndarray]:
    """Frozen-time modes of the linearisation (gain-independent) and the inverse of their shape matrix."""
    from linearize.analysis import frozen_modes

    fm = frozen_modes(key.linearization, key.orbit)
    return fm, np.linalg.inv(fm.shapes)


@dataclass(frozen=True)
class HillMeasure:
    """One evaluation of :meth:`HillModelPlant.measure`.

    Attributes
    ----------
    dominant : complex
        The largest refined multiplier (drive modes / ``bending 1``).
    mode : str
        Its label.
    estimate : complex
        The magnus2 estimate it was refined from.
    refined : list of (label, complex)
        Every refined multiplier (upper half plane of each conjugate pair).
    hill_error_estimate : float
        Hill's relative H vs H/2 change of the dominant (NaN when not computed).
    label_steps : int
    confirmed : bool
        False when Hill's labels and the magnus2 estimates did not agree at any step
        count tried (the value is then the best candidate, see :meth:`HillModelPlant.measure`).
    method : str
        Where ``dominant`` comes from: ``"hill"``; ``"modal-magnus2"`` (the frozen-modal product,
        :meth:`HillModelPlant.modal_measure`: Hill's value was truncated or not in the magnus2
        spectrum); ``"magnus2-unrefined"`` (nothing to refine: the labelling pass's largest multiplier).
    tail, residual : float
        :attr:`stability.hill.HillResult.tail` / ``residual`` of the Hill pair behind the value (NaN without one).
    modal_error_estimate : float
        Step-doubling estimate (relative) of the frozen-modal value (``method="modal-magnus2"``; else NaN).
    harmonics : int
        Hill harmonics of the value (a run escalates from the plant's count when its budget is not met).
    run_error_estimate : float
        Absolute error estimate of ``|dominant|`` that was checked against the run budget
        (:attr:`HillModelPlant.budget`): Hill's H vs H/2 change, or the frozen-modal step-doubling estimate.
    modal_steps : int
        Steps of the frozen-modal value (0 for Hill).
    """

    dominant: complex
    mode: str
    estimate: complex
    refined: list = field(default_factory=list)
    hill_error_estimate: float = math.nan
    label_steps: int = LABEL_STEPS
    confirmed: bool = True
    method: str = "hill"
    tail: float = math.nan
    residual: float = math.nan
    modal_error_estimate: float = math.nan
    harmonics: int = TUNING_HARMONICS
    run_error_estimate: float = math.nan
    modal_steps: int = 0

    @property
    def truncated(self) -> bool:
        """Hill's Floquet vector of the response kept more than :data:`stability.hill.TAIL_LIMIT` of its
        energy in the outer quarter of the harmonics (too few harmonics)."""
        return bool(self.tail > TAIL_LIMIT)


class HillModelPlant:
    """Tuning plant: ``spectral_measure(kp, kd)`` = dominant labelled multiplier by Hill's method.

    Parameters
    ----------
    linearization : LinearizedPeriodicSystem
        A model file's linearisation (``B`` present).
    orbit : PeriodicOrbit
    label_steps : int
        magnus2 steps of the labelling pass.
    harmonics : int
        Hill harmonics.
    tolerance : float, optional
        Absolute tuning tolerance on ``|rho|``; every response must meet :attr:`budget` (``RUN_BUDGET`` of it)
        by its own error estimate, else the run refines (harmonics, fallback steps) or raises
        :class:`stability.hill.HillError` (a failed tuning run).  None: ``DEFAULT_RTOL |rho|``.

    Picklable (the workspace is rebuilt once per process).
    """

    def __init__(self, linearization: LinearizedPeriodicSystem, orbit: PeriodicOrbit, *,
                 label_steps: int = LABEL_STEPS, harmonics: int = TUNING_HARMONICS,
                 tolerance: Optional[float] = None, _token: Optional[str] = None) -> None:
        if linearization.B is None:
            raise ValueError("HillModelPlant needs a model file's linearisation (with drives)")
        if linearization.breakpoints:
            raise ValueError("HillModelPlant: the linearisation is sampled piece by piece (declared breakpoints), "
                             "so Hill's method does not apply; use the time-stepping plant")
        if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
            raise ValueError(f"tolerance must be finite and > 0, got {tolerance!r}")
        self.tolerance = None if tolerance is None else float(tolerance)
        self.linearization = linearization
        self.orbit = orbit
        self.label_steps = int(label_steps)
        self.harmonics = int(harmonics)
        self._token = uuid.uuid4().hex if _token is None else _token
        # key of the per-process caches (workspaces per step count, frozen modes), shared by every copy
        # of this plant (replace, pickles) in one process
        self._key = _PlantKey(self._token, linearization, orbit)
        #: One dict per :meth:`spectral_measure` call of this object whose response is not Hill's value
        #: (``gains``, ``method``, ``error_estimate`` (absolute), ``modal_steps``); not pickled (a worker's copy
        #: starts empty; ``flexstab tune`` collects the workers' records per run).
        self.fallback_runs: list = []

    def __getstate__(self) -> dict:
        return {"linearization": self.linearization, "orbit": self.orbit, "label_steps": self.label_steps,
                "harmonics": self.harmonics, "tolerance": self.tolerance, "token": self._token}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["linearization"], state["orbit"], label_steps=state["label_steps"],
                      harmonics=state["harmonics"], tolerance=state.get("tolerance"), _token=state["token"])

    def replace(self, **changes: Any) -> "HillModelPlant":
        kw = {"label_steps": self.label_steps, "harmonics": self.harmonics, "tolerance": self.tolerance, **changes}
        return HillModelPlant(self.linearization, self.orbit, _token=self._token, **kw)

    @property
    def drives(self) -> tuple:
        return self.orbit.drive_names

    @property
    def n_steps(self) -> int:  # the tune command reports it
        return self.label_steps

    def with_gains(self, kp: GainArgument, kd: GainArgument) -> LinearizedPeriodicSystem:
        return self.linearization.with_gains(kp, kd)

    def _per_drive(self, values: GainArgument, name: str) -> list:
        """One float per drive (a float: the same for every drive; checked by the linearisation)."""
        return [float(v) for v in self.linearization.gains(values, name)]

    def budget(self, rho: float) -> float:
        """Absolute error allowed in one run's response ``|rho|``: ``RUN_BUDGET`` times the tolerance, at least
        ``HILL_FLOOR |rho|``."""
        tol = self.tolerance if self.tolerance is not None else DEFAULT_RTOL * abs(rho)
        return max(RUN_BUDGET * tol, HILL_FLOOR * abs(rho))

    def _workspace(self, steps: int) -> Any:
        return _labelling_workspace(self._key, int(steps))

    def labelled(self, kp: GainArgument, kd: GainArgument,
                 steps: Optional[int] = None) -> tuple[LinearizedPeriodicSystem, Any, list]:
        """``(lin, floquet_result, modes)`` of the labelling pass."""
        lin = self.with_gains(kp, kd)
        g = [v for pair in zip(lin.kp, lin.kd) for v in pair]
        res = self._workspace(steps or self.label_steps).floquet(g)
        return lin, res, label_multipliers(lin, self.orbit, res)

    def frozen(self) -> Any:
        """Frozen-time modes (gain-independent), computed once per process."""
        return _frozen_modes(self._key)[0]

    def hill_label(self, state: np.ndarray) -> str:
        """Label of a Floquet state ``[z; z']`` at t = 0: the frozen mode of largest modal energy
        (the rule of :func:`linearize.analysis.label_multipliers`)."""
        fm, Vinv = _frozen_modes(self._key)
        r = self.linearization.size
        eta, eta_t = Vinv @ state[:r], Vinv @ state[r:]
        energy = np.abs(eta_t) ** 2 + np.abs(fm.eigenvalues) * np.abs(eta) ** 2
        return fm.labels[int(np.argmax(energy))]

    def measure(self, kp: GainArgument, kd: GainArgument, *, error_estimate: bool = False, guard: bool = True) -> HillMeasure:
        """Dominant drive-mode / ``bending 1`` multiplier, measured and labelled by Hill.

        Candidates: every magnus2 multiplier labelled as a main mode, and every other
        one off the unit circle at least as large as the largest main one (a coarse
        product can mislabel the slow mode on a fine mesh); each is refined by Hill and
        labelled again from Hill's Floquet vector.  A refined value is *accepted* when its
        Hill label is a main mode, it is off the unit circle, its backward error is below
        :data:`stability.hill.RESIDUAL_LIMIT` and it is a magnus2 multiplier (any label) to the product's
        own accuracy (:func:`_in_spectrum`: a refinement that lands on a main mode "from afar" must be a
        multiplier of the time-stepping spectrum, not a truncation eigenvalue of Hill's matrices).  The
        response is the largest accepted one.

        Confirmed when every refined main-mode estimate lies within :data:`MATCH_TOLERANCE` of
        its refinement and no rejected refinement is larger than the response; else the
        labelling pass is repeated with twice the steps (up to 4x).  Not confirmed then: the
        labelled dominant of the frozen-modal magnus2 product (:meth:`modal_measure`) when no value
        was accepted or a rejected main-mode value is larger than the accepted ones, else the largest
        accepted value (only a main-mode estimate mismatched) -- ``confirmed=False``, logged.
        Per-run guard (``guard=True``): a response that is truncated (:data:`stability.hill.TAIL_LIMIT`, an
        indicator) or whose H vs H/2 change exceeds :meth:`budget` is measured again with twice the harmonics
        (:attr:`HillMeasure.harmonics`); beyond :data:`MAX_HARMONICS` the frozen-modal value is used, with a
        warning.  The frozen-modal value (also after a :class:`stability.hill.HillError`, logged) is refined to
        the budget or raises :class:`stability.hill.HillError`.  Without any candidate the unrefined magnus2
        multiplier is returned, ``method="magnus2-unrefined"``, with a warning.  ``guard=False`` (used by
        :func:`select_harmonics`, which judges a count by its own stricter rule): no harmonic escalation, a
        truncated response is replaced by a one-pass frozen-modal value.
        """
        from stability.engines import floquet
        from stability.hill import RESIDUAL_LIMIT

        kp, kd = self._per_drive(kp, "kp"), self._per_drive(kd, "kd")
        steps = self.label_steps
        main = set(self.orbit.drive_names) | {"bending 1"}
        for _ in range(3):
            lin, res, modes = self.labelled(kp, kd, steps)
            floor = max(NOISE_FACTOR * float(res.noise_floor), 1e-300)
            upper = [(m.mode, complex(mu)) for mu, m in zip(res.multipliers, modes)
                     if not m.undamped and np.imag(mu) >= 0 and abs(mu) > floor]
            mains = sorted((p for p in upper if p[0] in main), key=lambda p: -abs(p[1]))
            top = abs(mains[0][1]) if mains else 0.0
            picks = [p for p in mains if abs(p[1]) >= RELATIVE_CUTOFF * top][:MAX_REFINED]
            picks += [p for p in upper if p[0] not in main and abs(p[1]) >= top]
            if not picks:
                mu = complex(res.multipliers[0])
                warnings.warn(f"Hill plant: no multiplier to refine at kp={list(kp)} kd={list(kd)} (all undamped or "
                              f"below the rounding floor): the unrefined magnus2 multiplier |rho| = {abs(mu):.6g} "
                              f"({modes[0].mode}, {steps} steps) is returned", RuntimeWarning, stacklevel=2)
                return HillMeasure(dominant=mu, mode=modes[0].mode, estimate=mu, label_steps=steps,
                                   confirmed=False, method="magnus2-unrefined")
            try:
                h = floquet(lin, method="hill", targets=[p[1] for p in picks], harmonics=self.harmonics,
                            error_estimate=error_estimate).detail
            except HillError as exc:  # no eigenvalue near a candidate / singular shift: the tuning run goes on
                logger.warning("Hill's method failed at gains kp=%s kd=%s (%s); using the frozen-modal magnus2 "
                               "product", kp, kd, exc)
                return self.modal_measure(kp, kd, label_steps=steps, refine=guard)
            labels = [self.hill_label(x) for x in h.states]
            main_off = [j for j, (z, lab) in enumerate(zip(h.multipliers, labels))
                        if lab in main and abs(abs(z) - 1.0) >= UNDAMPED_TOLERANCE]
            ok = [j for j in main_off if h.residual[j] <= RESIDUAL_LIMIT]
            fine = np.asarray(res.multipliers)
            gains = [v for pair in zip(lin.kp, lin.kd) for v in pair]
            coarse = np.asarray(self._workspace(max(2, steps // 2)).floquet(gains).multipliers)
            accepted = [j for j in ok if _in_spectrum(h.multipliers[j], coarse, fine,
                                                      self.budget(abs(h.multipliers[j])))]
            # a magnus2 main-mode estimate must be near its refined value (the refinement of another
            # candidate may land on a main mode from afar: accepted above only if it is in the magnus2 spectrum)
            both = [j for j in ok if picks[j][0] in main]
            mismatch = (np.abs(np.log(h.multipliers[both] / np.array([picks[j][1] for j in both])))
                        if both else np.array([]))
            best = max((abs(h.multipliers[j]) for j in accepted), default=0.0)
            hidden = [j for j in main_off if j not in accepted and abs(h.multipliers[j]) > best]  # rejected, above
            if accepted and np.all(mismatch <= MATCH_TOLERANCE) and not hidden:
                break
            logger.info("Hill refinement: %d accepted main-mode values, log mismatch %.3g, %d rejected above them: "
                        "labelling again with %d steps", len(accepted),
                        float(np.max(mismatch)) if mismatch.size else math.nan, len(hidden), 2 * steps)
            steps *= 2
        else:
            steps //= 2
            if not accepted or hidden:
                logger.warning("Hill's method gave %s at gains kp=%s kd=%s (up to %d steps); using the frozen-modal "
                               "magnus2 product", "a main-mode value outside the magnus2 spectrum above the accepted "
                               "ones" if accepted else "no main-mode multiplier of the magnus2 spectrum", kp, kd, steps)
                return self.modal_measure(kp, kd, label_steps=steps, refine=guard)
            # not confirmed at any step count: the largest accepted Hill value (mismatch ignored) -- flagged, logged
            logger.warning("Hill's method did not confirm the magnus2 labels at gains kp=%s kd=%s (up to %d steps); "
                           "using the largest accepted Hill-labelled main mode", kp, kd, steps)
        j = max(accepted, key=lambda i: abs(h.multipliers[i]))
        confirmed = bool(np.all(mismatch <= MATCH_TOLERANCE) and not hidden)
        mu = complex(h.multipliers[j])
        # the per-run bound (the tail is only an indicator, stability.hill.TAIL_LIMIT): H vs H/2 of the response
        rel = (float(h.error_estimate[j]) if error_estimate else
               float(pair_error_estimate(lin.M, lin.C, lin.K, lin.period, [mu], self.harmonics)[0]))
        est = rel * abs(mu) if math.isfinite(rel) else math.inf
        if h.truncated[j] or (guard and not est <= self.budget(abs(mu))):
            why = (f"tail {h.tail[j]:.1e} > {TAIL_LIMIT:.0e}" if h.truncated[j] else
                   f"H vs H/2 estimate {est:.1e} > budget {self.budget(abs(mu)):.1e}")
            if guard and 2 * self.harmonics <= MAX_HARMONICS:
                logger.info("Hill plant: %d harmonics at kp=%s kd=%s: %s; trying %d", self.harmonics, kp, kd, why,
                            2 * self.harmonics)
                return self.replace(harmonics=2 * self.harmonics).measure(kp, kd, error_estimate=error_estimate)
            warnings.warn(f"Hill plant: {self.harmonics} harmonics do not resolve the response at kp={list(kp)} "
                          f"kd={list(kd)} ({why}): the frozen-modal magnus2 value is used", RuntimeWarning,
                          stacklevel=2)
            return self.modal_measure(kp, kd, label_steps=steps, tail=float(h.tail[j]),
                                      residual=float(h.residual[j]), refine=guard)
        distinct: list = []  # two candidates refined onto the same exponent are listed once
        for i in accepted:
            z = complex(h.multipliers[i])
            if all(abs(z - w) > 1e-9 * max(abs(z), 1e-300) for _, w in distinct):
                distinct.append((labels[i], z))
        return HillMeasure(dominant=complex(h.multipliers[j]), mode=labels[j], estimate=picks[j][1],
                           refined=distinct, hill_error_estimate=float(h.error_estimate[j]), label_steps=steps,
                           confirmed=confirmed, tail=float(h.tail[j]), residual=float(h.residual[j]),
                           harmonics=self.harmonics, run_error_estimate=est)

    def modal_measure(self, kp, kd, *, label_steps: int = LABEL_STEPS, tail: float = math.nan,
                      residual: float = math.nan, refine: bool = True) -> HillMeasure:
        """The fallback of :meth:`measure`: the labelled dominant multiplier (drive modes / ``bending 1``, the rule
        of :class:`linearize.analysis.ModelFloquetResult`) of the exponential-midpoint product in the frozen-modal
        frame (:meth:`linearize.analysis.ModelPlant.floquet`, Richardson-extrapolated), ``method="modal-magnus2"``,
        ``confirmed=False``; ``tail``/``residual`` are those of the rejected Hill value.

        The step count doubles from ``TUNING_PROPAGATOR_STEPS`` until the value's step-doubling estimate meets
        the run budget (:meth:`budget`); beyond :data:`MAX_FALLBACK_STEPS` a :class:`stability.hill.HillError` is
        raised (the tuning records a failed run) rather than a response of unknown accuracy returned.
        ``refine=False``: one pass at ``TUNING_PROPAGATOR_STEPS``, whatever its estimate (diagnostics only).
        """
        from linearize.analysis import TUNING_PROPAGATOR_STEPS, ModelPlant, _dominant, _multiplier_estimate

        kp, kd = self._per_drive(kp, "kp"), self._per_drive(kd, "kd")
        plant = ModelPlant(self.linearization, self.orbit)
        steps = TUNING_PROPAGATOR_STEPS
        while True:
            res = plant.floquet(kp, kd, n_steps=steps)
            modes = label_multipliers(self.with_gains(kp, kd), self.orbit, res)
            mu = _dominant(res, modes, self.orbit.drive_names)
            rel = _multiplier_estimate(res, mu)
            est = rel * abs(mu) if math.isfinite(rel) else math.inf
            if not refine or est <= self.budget(abs(mu)):
                break
            if 2 * steps > MAX_FALLBACK_STEPS:
                raise HillError(f"frozen-modal fallback at kp={list(kp)} kd={list(kd)}: |rho| = {abs(mu):.6g} with "
                                f"estimate {est:.1e} > budget {self.budget(abs(mu)):.1e} at {steps} steps")
            steps *= 2
        i = int(np.argmin(np.abs(np.asarray(res.multipliers) - mu)))
        return HillMeasure(dominant=mu, mode=modes[i].mode, estimate=mu, label_steps=label_steps,
                           confirmed=False, method="modal-magnus2", tail=tail, residual=residual,
                           modal_error_estimate=rel, harmonics=self.harmonics, run_error_estimate=est,
                           modal_steps=steps)

    def spectral_measure(self, kp: GainArgument, kd: GainArgument) -> float:
        """``|rho|`` of the dominant labelled multiplier (Hill); a response from another method is recorded in
        :attr:`fallback_runs`."""
        m = self.measure(kp, kd)
        if m.method != "hill":
            g = [v for pair in zip(self._per_drive(kp, "kp"), self._per_drive(kd, "kd")) for v in pair]
            self.fallback_runs.append({"gains": g, "method": m.method, "error_estimate": m.run_error_estimate,
                                       "modal_steps": m.modal_steps, "spectral_radius": float(abs(m.dominant))})
        return float(abs(m.dominant))


@dataclass(frozen=True)
class HarmonicsChoice:
    """Outcome of :func:`select_harmonics`.

    Attributes
    ----------
    plant : HillModelPlant
        The plant with the chosen harmonics (the last candidate when none met the tolerance).
    harmonics : int
    converged : bool
        Whether the chosen count met ``tolerance / 20`` (Hill's value, not truncated).
    error_estimate : float
        Absolute H vs H/2 estimate of the response at the chosen count (NaN when Hill gave no value).
    tolerance : float
        The tuning tolerance it was chosen for.
    """

    plant: HillModelPlant
    harmonics: int
    converged: bool
    error_estimate: float
    tolerance: float


def select_harmonics(plant: HillModelPlant, kp: Sequence[float], kd: Sequence[float], tolerance: float,
                     candidates: Sequence[int] = (8, 12, 16, 24, 32)) -> HarmonicsChoice:
    """The fewest Hill harmonics whose H vs H/2 estimate of the response is below ``tolerance / 20``.

    Decided once, at one gain point (e.g. the centre of the initial ranges): the
    estimate is the relative change from ``H/2`` to ``H`` (spectral convergence: it
    bounds the error of ``H/2``, so over-states that of ``H``).  A count whose response is
    not Hill's own value (``method != "hill"``) or whose Floquet vector is truncated
    (:attr:`HillMeasure.truncated`) does not qualify.  When no candidate qualifies, the last
    is returned with ``converged=False`` and a ``RuntimeWarning``.
    """
    if not candidates:
        raise ValueError("candidates: need at least one harmonic count")
    for H in candidates:
        p = plant.replace(harmonics=H, tolerance=tolerance)
        m = p.measure(kp, kd, error_estimate=True, guard=False)  # judged here, at H itself (tolerance / 20)
        at_h = m.method == "hill" and m.harmonics == H  # not escalated by the per-run guard
        est = m.hill_error_estimate * abs(m.dominant) if at_h else math.nan
        if at_h and not m.truncated and est <= tolerance / 20:
            return HarmonicsChoice(plant=p, harmonics=H, converged=True, error_estimate=est, tolerance=tolerance)
    warnings.warn(f"Hill harmonics: none of {list(candidates)} meets the estimate tolerance {tolerance / 20:.2e} "
                  f"(tolerance / 20) at kp={list(kp)} kd={list(kd)}; using {H} (estimate {est:.2e}, method "
                  f"{m.method}{', truncated' if m.truncated else ''})", RuntimeWarning, stacklevel=2)
    return HarmonicsChoice(plant=p, harmonics=H, converged=False, error_estimate=est, tolerance=tolerance)
