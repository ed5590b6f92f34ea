"""Floquet analysis of the Exudyn link: linearisation route and direct Exudyn monodromy.

Hand-derived route (hub-frame coordinates of :mod:`_link_oracle.exudyn_link`): kept as the
independent check of the generic model-file path (``linearize.analyze("single-link", ...)``,
``tests/test_model_file.py``), which is the package's route for any model.

Pipeline (:func:`exudyn_floquet`): periodic orbit
(:func:`~_link_oracle.link_orbit.find_periodic_orbit`) -> finite-difference
linearisation in independent coordinates
(:func:`~linearize.linearize_along_orbit`) -> monodromy of
``x' = P(t) x`` -> multipliers, each classified by the structural mode its
Floquet vector lives in.

Independent check (:func:`direct_monodromy`): the nonlinear free-hub model
(feed-forward + PD inside Exudyn) is integrated over one period from the
orbit's state and from ``2 n`` perturbed states; the difference quotients form
the monodromy matrix of Exudyn's own discrete map.

Hazards and how they are handled
--------------------------------
* The link has no structural damping (paper), so modes that the hub hardly
  moves (the axial modes, 1.3-47 kHz at 8 elements, and -- with the strongly
  damped hub of the Table 3 gains, which acts almost as a clamp -- the bending
  modes) have multipliers on or next to the unit circle.  Each multiplier is
  reported with the structural mode its Floquet vector lives in;
  :attr:`ExudynFloquetResult.dominant_multiplier` is the largest multiplier of
  the modes the paper's 2-DOF model has (hub, first bending mode), while
  ``spectral_radius`` stays the honest max over all.
  Generalised-alpha damps these modes numerically, so the direct Exudyn
  monodromy sees them near 0.
* ``||P||`` reaches ~4e5 1/s (``kd/J1``).  The default propagator is the
  exponential midpoint product ``Phi = prod exp(h P(t_k + h/2))`` (every factor an
  exact matrix exponential, so the stiff, strongly damped hub mode cannot make it
  blow up) in the frozen-modal frame of :func:`stability.modal.modal_floquet`,
  Richardson-extrapolated -- the propagation of the generic route
  (:func:`linearize.analysis.analyze`).  In the hub-frame coordinates themselves
  (``frame="model"``) the product has *step-size resonances*: the stiff axial modes
  (1.3-47 kHz) rotate by ``omega h`` per step, and where that is near a multiple of
  ``pi`` the midpoint error of a mode does not fall with ``h``.  Measured at 8 pi, 8
  elements, Table 3 gains, on one linearisation: the spectral radius is 1.0022 (axial 6)
  at 512, 1024, 2048 and 4096 steps, 1.052 (axial 2) at 500 and 1000, 0.99989 at 600,
  1500, 3000, 6000, and 0.99996116 at 8192 steps -- the frozen-modal frame gives
  0.99996133 at 128-3456 steps (estimate 1.5e-11 adaptive) and the generic route
  (its own orbit and linearisation) 0.99996115.  A family of nested step counts
  shares the resonance, so step doubling cannot see it.  The other
  :func:`stability.floquet` methods can be selected by name.
"""
from __future__ import annotations

import logging
import math
import time
import uuid
from dataclasses import dataclass, field, replace
from typing import Any, Optional

import numpy as np
import scipy.linalg

from linearize.system import LinearizedPeriodicSystem
from _link_oracle.along_orbit import linearize_along_orbit
from _link_oracle.exudyn_link import ExudynLinkConfig, build_link_model
from _link_oracle.link_orbit import PeriodicOrbit, find_periodic_orbit, rigid_reference
from mbs_models.parameters import ManipulatorParameters
from stability.frozen import frozen_result

__all__ = [
    "DEFAULT_PROPAGATOR_STEPS",
    "DIRECT_EPSILON",
    "UNDAMPED_TOLERANCE",
    "DirectMonodromyResult",
    "ExudynFloquetResult",
    "classify_multipliers",
    "direct_monodromy",
    "exponential_midpoint_floquet",
    "exudyn_floquet",
    "exudyn_plant",
    "ExudynPlant",
    "PreparedExudynPlant",
    "TUNING_PROPAGATOR_STEPS",
    "PAPER_MODES",
]

logger = logging.getLogger(__name__)

#: Sub-intervals of the exponential-midpoint product (frozen-modal frame, extrapolated from
#: ``N``, ``N / 2``, ``N / 4``).  Measured at 8 elements, Table 3 gains: spectral radius
#: 0.99999769721 at 2 pi (estimate 3.7e-12) and 0.99996132787 at 8 pi (estimate 2.6e-8;
#: adaptive with the non-nested check: 0.99996132786, 1.5e-11), 0.7-0.9 s CPU.
DEFAULT_PROPAGATOR_STEPS = 512
#: Multipliers with ``| |rho| - 1 | <`` this are called undamped (on the unit
#: circle within the propagator's accuracy for the undamped structural modes).
UNDAMPED_TOLERANCE = 2e-3
#: Perturbation of the direct monodromy (m, rad, m/s, rad/s): large against the
#: Newton tolerance (1e-8 relative), small against the deformations (~1e-2 m).
DIRECT_EPSILON = 1e-6


# --------------------------------------------------------------------------- propagator
def exponential_midpoint_floquet(
    system: Any,
    *,
    n_steps: int = DEFAULT_PROPAGATOR_STEPS,
    error_estimate: bool = True,
    stability_tol: float = 1e-8,
):
    """Floquet multipliers by the exponential midpoint product (``stability.floquet``, ``"magnus2"``).

    The refinement estimate (``n_steps`` against ``n_steps // 2``) watches the
    moduli only: the phases of the undamped axial modes (up to 47 kHz) are
    irrelevant to stability and converge slowly.

    Returns
    -------
    stability.FloquetResult
    """
    from stability import floquet

    return floquet(
        system,
        method="magnus2",
        n_steps=n_steps,
        error_estimate=error_estimate,
        stability_tol=stability_tol,
        accuracy="moduli",
    )


def _structural_modes(lin: LinearizedPeriodicSystem) -> tuple[np.ndarray, np.ndarray, list]:
    """Mass-normalised modes of the time-averaged, uncontrolled system and their labels."""
    M = np.mean(lin.M, axis=0)
    K = np.mean(lin.K, axis=0)
    if lin.hub_free:
        K = K.copy()
        K[0, 0] -= lin.kp
    M = 0.5 * (M + M.T)
    K = 0.5 * (K + K.T)
    lam, V = scipy.linalg.eigh(K, M)
    order = np.argsort(np.abs(lam))
    lam, V = lam[order], V[:, order]
    names = list(lin.coordinates) if lin.coordinates else [f"y{i}" for i in range(lin.size)]
    # hub-frame coordinates: x_j, x_j' and s0 are axial, y_j, y_j' transverse
    axial_idx = [i for i, nm in enumerate(names) if nm == "s0" or nm.startswith("x")]
    labels = []
    n_axial = n_bending = 0
    for k in range(V.shape[1]):
        if lin.hub_free and k == 0:
            labels.append("hub")  # rigid-body mode of the pinned link (gravity-stiffened)
            continue
        w = V[:, k] ** 2 * np.diag(M)
        axial_share = float(np.sum(w[axial_idx]) / np.sum(w))
        if axial_share > 0.5:
            n_axial += 1
            labels.append(f"axial {n_axial}")
        else:
            n_bending += 1
            labels.append(f"bending {n_bending}")
    return lam, V, labels


def classify_multipliers(lin: LinearizedPeriodicSystem, floquet_result: Any, modes: Optional[tuple] = None) -> list:
    """Mode label of each multiplier (by the modal energy of its Floquet vector at t = 0).

    ``modes`` may pass ``_structural_modes(lin)`` computed before (they do not
    depend on the gains).  Returns a list of dicts ``{"modulus", "mode",
    "frequency_hz", "undamped"}`` in the order of ``floquet_result.multipliers``.
    """
    lam, V, labels = modes if modes is not None else _structural_modes(lin)
    n = lin.size
    Phi = np.asarray(floquet_result.monodromy)
    w, X = np.linalg.eig(Phi)
    out = []
    Vinv = np.linalg.inv(V)
    for mu in floquet_result.multipliers:
        j = int(np.argmin(np.abs(w - mu)))
        x = X[:, j]
        eta = Vinv @ x[:n]
        eta_d = Vinv @ x[n:]
        energy = np.abs(eta_d) ** 2 + np.abs(lam) * np.abs(eta) ** 2
        k = int(np.argmax(energy))
        mod = float(abs(mu))
        out.append(
            {
                "modulus": mod,
                "mode": labels[k],
                "frequency_hz": float(math.sqrt(abs(lam[k])) / (2 * math.pi)),
                "undamped": bool(abs(mod - 1.0) < UNDAMPED_TOLERANCE),
            }
        )
    return out


# --------------------------------------------------------------------------- results
@frozen_result
@dataclass(frozen=True)
class ExudynFloquetResult:
    """Floquet analysis of the Exudyn link about a reference motion.

    Attributes
    ----------
    floquet : stability.FloquetResult
        Multipliers, monodromy, verdict of the full linearised system.
    dominant_multiplier : complex
        Largest multiplier whose Floquet vector lies mainly in the modes the
        paper's reduced model has (:data:`PAPER_MODES`: the hub mode and the
        first bending mode) and that is not on the unit circle; compare with
        the paper.  ``floquet.spectral_radius`` is the max over all modes
        (undamped axial and bending modes included).
    dominant_mode : str
        Mode label of ``dominant_multiplier`` (``"hub"``, ``"bending 1"``, ...).
    modes : list of dict
        Per multiplier: modulus, mode label, modal frequency, undamped flag.
    orbit : PeriodicOrbit
        Reference motion (true periodic orbit or rigid reference).
    linearization : LinearizedPeriodicSystem
    omega, kp, kd : float
    elements : int
    timings : dict
        Seconds per stage (``orbit``, ``linearization``, ``floquet``).
    """

    floquet: Any
    dominant_multiplier: complex
    dominant_mode: str
    modes: list
    orbit: PeriodicOrbit = field(repr=False)
    linearization: LinearizedPeriodicSystem = field(repr=False)
    omega: float = 2 * math.pi
    kp: float = 0.0
    kd: float = 0.0
    elements: int = 8
    timings: dict = field(default_factory=dict)

    @property
    def verdict(self) -> Any:
        """The closed loop's verdict (:func:`stability.verdict.judge_floquet`: every multiplier with its own
        error estimate, the practically undamped and growing ones counted with their mode labels)."""
        from stability.verdict import judge_floquet

        return judge_floquet(self.floquet, labels=[m["mode"] for m in self.modes],
                             frequencies=[m["frequency_hz"] for m in self.modes])

    @property
    def undamped_count(self) -> int:
        """Number of practically undamped multipliers: the count of the verdict rule
        (:mod:`stability.verdict`: ``|rho| + error > exp(-1/1000)``, not growing)."""
        return len(self.verdict.undamped)

    def summary(self) -> dict:
        """JSON-ready keys added to the Floquet output (CLI ``--model exudyn``)."""
        d = self.dominant_multiplier
        return {
            "model": "exudyn",
            "elements": self.elements,
            "reference": self.orbit.kind,
            "orbit_residual": float(self.orbit.residual),
            "shooting_residual": float(self.orbit.shooting_residual),
            "samples": self.linearization.samples,
            "dominant_multiplier": [float(d.real), float(d.imag)],
            "dominant_modulus": float(abs(d)),
            "dominant_mode": self.dominant_mode,
            "undamped_multipliers": self.undamped_count,
            "modes": self.modes,
            "timings": dict(self.timings),
            "verdict_detail": self.verdict.to_dict(),
        }


#: Modes that the paper's reduced model has (hub angle y1, first bending mode y2).
PAPER_MODES = ("hub", "bending 1")


def _dominant(floquet_result: Any, modes: list) -> tuple[complex, str]:
    """Largest multiplier of the paper's modes; else the largest not on the unit circle."""
    for mu, m in zip(floquet_result.multipliers, modes):
        if m["mode"] in PAPER_MODES and not m["undamped"]:
            return complex(mu), m["mode"]
    for mu, m in zip(floquet_result.multipliers, modes):
        if not m["undamped"]:
            return complex(mu), m["mode"]
    return complex(floquet_result.multipliers[0]), modes[0]["mode"]


def exudyn_floquet(
    params: Optional[ManipulatorParameters] = None,
    *,
    omega: float = 2 * math.pi,
    kp: float = 0.0,
    kd: float = 0.0,
    elements: int = 8,
    method: Optional[str] = None,
    samples: int = 32,
    reference: str = "periodic",
    n_steps: Optional[int] = None,
    bending_damping: float = 0.0,
    axial_damping: float = 0.0,
    orbit: Optional[PeriodicOrbit] = None,
    verify_orbit: bool = True,
    frame: str = "modal",
) -> ExudynFloquetResult:
    """Floquet multipliers of the Exudyn link linearised along its periodic orbit.

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default Table 1).
    omega : float
        Omega of the fundamental motion (rad/s).
    kp, kd : float
        PD gains on the hub angle.
    elements : int
        ANCF elements.
    method : str, optional
        ``None`` or ``"expmid"``: exponential midpoint product (default, see
        the module notes); otherwise a method of :func:`stability.floquet`.
    samples : int
        Collocation / linearisation samples per period (even).
    reference : {"periodic", "rigid"}
        Linearise about the true periodic orbit or the undeformed rigid motion.
    n_steps : int, optional
        Propagator sub-intervals.
    bending_damping, axial_damping : float
        Optional structural damping of the ANCF elements.
    orbit : PeriodicOrbit, optional
        Reuse an orbit computed before (must match ``omega`` and ``elements``).
    verify_orbit : bool
        Check the orbit by one Exudyn period (adds ~0.2 s).
    frame : {"modal", "model"}
        Coordinates of the exponential-midpoint product (``method`` None/``"magnus2"``):
        ``"modal"`` (default) the frozen-modal frame of :func:`stability.modal.modal_floquet`,
        Richardson-extrapolated with ``n_steps`` (default :data:`DEFAULT_PROPAGATOR_STEPS`),
        ``n_steps / 2`` and ``n_steps / 4``; ``"model"`` the plain product in the hub-frame
        coordinates (step-size resonances: module notes).

    Returns
    -------
    ExudynFloquetResult

    Raises
    ------
    ValueError
        On invalid arguments.
    _link_oracle.link_orbit.OrbitConvergenceError
        If the periodic orbit is not found.
    """
    if reference not in ("periodic", "rigid"):
        raise ValueError(f"reference must be 'periodic' or 'rigid', got {reference!r}")
    if frame not in ("modal", "model"):
        raise ValueError(f"frame must be 'modal' or 'model', got {frame!r}")
    params = ManipulatorParameters() if params is None else params
    cfg = ExudynLinkConfig(
        elements=elements, drive="free", omega=omega, kp=kp, kd=kd,
        bending_damping=bending_damping, axial_damping=axial_damping,
    )
    timings: dict = {}
    tic = time.perf_counter()
    if orbit is None:
        if reference == "periodic":
            orbit = find_periodic_orbit(params, cfg, samples=samples, verify=verify_orbit)
        else:
            orbit = rigid_reference(params, cfg, samples=samples)
    elif abs(orbit.config.omega - omega) > 1e-12 * omega or orbit.config.elements != elements:
        raise ValueError("the given orbit was computed for another omega or element count")
    timings["orbit"] = time.perf_counter() - tic
    tic = time.perf_counter()
    lin = linearize_along_orbit(orbit, hub="free", kp=kp, kd=kd)
    timings["linearization"] = time.perf_counter() - tic
    tic = time.perf_counter()
    if method in (None, "expmid", "magnus2") and frame == "modal":
        from stability.modal import modal_floquet

        # the frozen-modal frame (the propagation of linearize.analyze): in the hub-frame coordinates the
        # midpoint product has step-size resonances of the stiff axial modes (module notes)
        res = modal_floquet(lin, method="magnus2", n_steps=n_steps or DEFAULT_PROPAGATOR_STEPS, accuracy="moduli",
                            extrapolate=True)
    elif method in (None, "expmid", "magnus2"):
        res = exponential_midpoint_floquet(lin, n_steps=n_steps or DEFAULT_PROPAGATOR_STEPS)
    else:
        from stability import floquet

        try:
            res = floquet(lin, method=method, n_steps=n_steps)
        except (FloatingPointError, ValueError) as exc:
            raise ValueError(
                f"Floquet method {method!r} failed on the Exudyn linearisation ({exc}); "
                f"||P|| reaches ~4e5 1/s here: use method='magnus2' (the default for this model)"
            ) from exc
    timings["floquet"] = time.perf_counter() - tic
    modes = classify_multipliers(lin, res)
    dom, dom_mode = _dominant(res, modes)
    logger.info(
        "Exudyn Floquet (Omega=%.4g, kp=%g, kd=%g, %d el.): dominant |rho| = %.6f (%s), spectral radius %.6f",
        omega, kp, kd, elements, abs(dom), dom_mode, res.spectral_radius,
    )
    return ExudynFloquetResult(
        floquet=res,
        dominant_multiplier=dom,
        dominant_mode=dom_mode,
        modes=modes,
        orbit=orbit,
        linearization=lin,
        omega=float(omega),
        kp=float(kp),
        kd=float(kd),
        elements=int(elements),
        timings=timings,
    )


# --------------------------------------------------------------------------- direct
@frozen_result
@dataclass(frozen=True)
class DirectMonodromyResult:
    """Monodromy of Exudyn's own discrete map, by finite differences of simulations.

    Attributes
    ----------
    monodromy : ndarray, shape (2n, 2n)
    multipliers : ndarray, complex
        Sorted by modulus, descending.
    dominant_multiplier : complex
        Largest multiplier not on the unit circle (as in :class:`ExudynFloquetResult`).
    epsilon : float
        Perturbation size.
    simulations : int
        Exudyn runs (``2 n + 1``).
    closed_loop_defect : float
        Periodicity defect of the unperturbed closed-loop run, relative to the
        elastic deformation (the orbit is also the closed-loop orbit).
    step_size : float
        Generalised-alpha step used.
    wall_time : float
    """

    monodromy: np.ndarray
    multipliers: np.ndarray
    dominant_multiplier: complex
    epsilon: float
    simulations: int
    closed_loop_defect: float
    step_size: float
    wall_time: float

    @property
    def moduli(self) -> np.ndarray:
        return np.abs(self.multipliers)


def direct_monodromy(
    orbit: PeriodicOrbit,
    *,
    kp: float = 0.0,
    kd: float = 0.0,
    epsilon: float = DIRECT_EPSILON,
    step_size: Optional[float] = None,
) -> DirectMonodromyResult:
    """Monodromy from ``2 n + 1`` one-period Exudyn runs of the closed loop.

    The free-hub model with feed-forward ``orbit.hub_torque`` and the PD
    spring-damper inside Exudyn is started from the orbit state at ``t = 0``
    and from each state perturbed by ``epsilon`` in one independent
    coordinate or rate; column ``i`` of the monodromy is
    ``(x_i(T) - x_0(T)) / epsilon`` (forward differences of Exudyn's
    discrete map; the perturbed initial states satisfy all constraints).

    Raises
    ------
    ExudynSolverError
        If a simulation fails.
    """
    tic = time.perf_counter()
    if not (math.isfinite(epsilon) and epsilon > 0):
        raise ValueError(f"epsilon must be finite and > 0, got {epsilon!r}")
    cfg = replace(orbit.config, drive="free", kp=kp, kd=kd)
    if step_size is not None:
        cfg = replace(cfg, step_size=step_size)
    model = build_link_model(orbit.params, cfg, feedforward=orbit.hub_torque)
    T = orbit.period
    p0, v0 = orbit.positions[0].copy(), orbit.velocities[0].copy()
    n = model.n
    base = model.simulate(p0, v0, T).final_state
    x0 = np.concatenate([p0, v0])
    pr, vr = model.rigid_configuration(float(p0[0]), float(v0[0]))
    elastic = float(np.max(np.abs(x0 - np.concatenate([pr, vr]))))
    defect = float(np.max(np.abs(base - x0)) / max(elastic, 1e-300))
    Phi = np.empty((2 * n, 2 * n))
    for i in range(2 * n):
        x = x0.copy()
        x[i] += epsilon
        Phi[:, i] = (model.simulate(x[:n], x[n:], T).final_state - base) / epsilon
    mu = np.linalg.eigvals(Phi)
    mu = mu[np.argsort(-np.abs(mu), kind="stable")]
    dom = next((complex(m) for m in mu if abs(abs(m) - 1.0) >= UNDAMPED_TOLERANCE), complex(mu[0]))
    wall = time.perf_counter() - tic
    logger.info("direct Exudyn monodromy: %d runs in %.1f s, dominant |rho| = %.6f", 2 * n + 1, wall, abs(dom))
    return DirectMonodromyResult(
        monodromy=Phi,
        multipliers=mu,
        dominant_multiplier=dom,
        epsilon=float(epsilon),
        simulations=2 * n + 1,
        closed_loop_defect=defect,
        step_size=cfg.step_size,
        wall_time=wall,
    )


# --------------------------------------------------------------------------- tuning plant
#: Sub-intervals of the Floquet evaluations inside a tuning loop (the dominant
#: damped multiplier agrees to 3e-7 between 250 and 2000 steps at Omega = 2 pi).
TUNING_PROPAGATOR_STEPS = 256


@dataclass(frozen=True)
class ExudynPlant:
    """The Exudyn linearisation as a plant for PD-gain tuning.

    ``with_gains(kp, kd)`` gives the periodic system with the gains as constant
    terms on the hub coordinate (paper Eq. 32); :meth:`spectral_measure` is the
    tuning response: the modulus of the dominant multiplier of the modes the
    paper's model has (hub, first bending mode), because the multipliers of
    the undamped axial modes sit on the unit circle whatever the gains.
    Picklable, so it runs in process pools and on Dask workers.
    """

    linearization: LinearizedPeriodicSystem
    n_steps: int = TUNING_PROPAGATOR_STEPS

    def with_gains(self, kp: float, kd: float) -> LinearizedPeriodicSystem:
        return self.linearization.with_gains(kp, kd)

    def floquet(self, kp: float, kd: float, n_steps: Optional[int] = None):
        """Floquet result of the system with gains ``(kp, kd)`` (``magnus2``, moduli accuracy)."""
        from stability import floquet

        return floquet(self.with_gains(kp, kd), method="magnus2", n_steps=n_steps or self.n_steps,
                       error_estimate=False, accuracy="moduli")

    def spectral_measure(self, kp: float, kd: float) -> float:
        """``|rho|`` of the dominant multiplier of the hub / first bending mode."""
        lin = self.with_gains(kp, kd)
        res = self.floquet(kp, kd)
        dom, _ = _dominant(res, classify_multipliers(lin, res))
        return float(abs(dom))

    def prepared(self) -> "PreparedExudynPlant":
        """The same plant with the gain-independent work done once (for loops over gains)."""
        return PreparedExudynPlant(self)


#: Workspaces of the prepared plants, per process and keyed by the plant's token: a process
#: pool unpickles the plant once per task, and the workspace (0.15 s for 8 elements) is
#: then built once per worker instead of once per task.  A few plants at most are alive.
_WORKSPACES: "dict[str, Any]" = {}
_WORKSPACE_CACHE_SIZE = 4


class PreparedExudynPlant:
    """:class:`ExudynPlant` with the gain-independent work done once.

    The gains enter ``P(t)`` as two rank-one terms (paper Eq. 32), so the
    linearisation is interpolated, the mass matrices solved and the system
    balanced once, at the Gauss points of the plant's step count
    (:class:`stability.gains.FloquetWorkspace`); each evaluation then costs the
    exponentials, the product and the eigenvalues.  It evaluates the same
    scheme at the same nodes as :meth:`ExudynPlant.floquet`.  Picklable: the
    workspace is not pickled but rebuilt once per process (cached by a token
    that travels with the plant), so process pools pay for it once per worker.
    """

    def __init__(self, plant: ExudynPlant) -> None:
        if not isinstance(plant, ExudynPlant):
            raise TypeError(f"PreparedExudynPlant wraps an ExudynPlant, got {type(plant).__name__}")
        self.plant = plant
        self._token = uuid.uuid4().hex
        self._workspace = None
        self._modes = None

    def __getstate__(self) -> dict:
        return {"plant": self.plant, "_token": self._token, "_workspace": None, "_modes": None}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    @property
    def linearization(self) -> LinearizedPeriodicSystem:
        return self.plant.linearization

    @property
    def n_steps(self) -> int:
        return self.plant.n_steps

    @property
    def workspace(self):
        if self._workspace is None:
            ws = _WORKSPACES.get(self._token)
            if ws is None:
                from stability.gains import FloquetWorkspace, pd_gain_family

                base = self.plant.linearization.with_gains(0.0, 0.0)
                ws = FloquetWorkspace(pd_gain_family(base, 0), self.plant.n_steps, method="magnus2")
                while len(_WORKSPACES) >= _WORKSPACE_CACHE_SIZE:
                    _WORKSPACES.pop(next(iter(_WORKSPACES)))
                _WORKSPACES[self._token] = ws
            self._workspace = ws
        return self._workspace

    def with_gains(self, kp: float, kd: float) -> LinearizedPeriodicSystem:
        return self.plant.with_gains(kp, kd)

    def floquet(self, kp: float, kd: float):
        """Floquet result with gains ``(kp, kd)`` (``magnus2``, the plant's step count)."""
        for name, v in (("kp", kp), ("kd", kd)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        return self.workspace.floquet((kp, kd))

    def spectral_measure(self, kp: float, kd: float) -> float:
        """``|rho|`` of the dominant multiplier of the hub / first bending mode (as :class:`ExudynPlant`)."""
        res = self.floquet(kp, kd)
        lin = self.plant.linearization
        if self._modes is None:
            self._modes = _structural_modes(lin)  # of the uncontrolled mean system: gain-independent
        dom, _ = _dominant(res, classify_multipliers(lin, res, modes=self._modes))
        return float(abs(dom))


def exudyn_plant(
    params: Optional[ManipulatorParameters] = None,
    *,
    omega: float = 2 * math.pi,
    elements: int = 8,
    samples: int = 32,
    prepared: bool = False,
) -> "ExudynPlant | PreparedExudynPlant":
    """Orbit + linearisation of the Exudyn link, packaged for :func:`taguchi.taguchi_tune`.

    With ``prepared=True`` the plant comes as a :class:`PreparedExudynPlant`
    (same responses, about half the time per evaluation inside a gain loop).
    """
    params = params or ManipulatorParameters()
    cfg = ExudynLinkConfig(elements=elements, drive="free", omega=omega)
    orbit = find_periodic_orbit(params, cfg, samples=samples, verify=False)
    plant = ExudynPlant(linearize_along_orbit(orbit, hub="free", kp=0.0, kd=0.0))
    return plant.prepared() if prepared else plant
