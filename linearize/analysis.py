"""One call from a model to labelled Floquet multipliers: orbit -> linearisation -> Floquet."""
from __future__ import annotations

import functools
import logging
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np
import scipy.linalg

from linearize.constrained import linearize_orbit
from linearize.periodic_orbit import DEFAULT_SAMPLES, PeriodicOrbit, StageClock, find_orbit
from linearize.system import LinearizedPeriodicSystem
from stability.floquet import CONTRACT_RTOL, recertify
from stability.frozen import frozen_result

__all__ = [
    "DEFAULT_PROPAGATOR_STEPS",
    "ModelPlant",
    "TUNING_PROPAGATOR_STEPS",
    "model_plant",
    "FrozenModes",
    "frozen_modes",
    "UNDAMPED_TOLERANCE",
    "DRIVE_SHARE_THRESHOLD",
    "drive_movable",
    "ModelFloquetResult",
    "analyze",
    "label_multipliers",
    "ModeLabel",
]

logger = logging.getLogger(__name__)

#: Sub-intervals of the exponential-midpoint (``magnus2``) product in the frozen-modal frame
#: (:mod:`stability.modal`, two nested frames, Richardson-extrapolated from 128, 64, 32 steps, a
#: 16-step solve checking the estimate's premise).  In the model's own coordinates 512 steps left
#: the single link's dominant multiplier 6.5e-5 (4 pi) .. 5.2e-3 (8 pi) off at 8 elements (and the
#: step-doubling estimate under-read that by up to 25x).  Here, measured at 8 elements in one run of
#: ``benchmarks/model_file_speed.py``: against the hand route converged 8.7e-10, 3.2e-9, 7.9e-8,
#: 3.3e-7 at 2, 4, 6, 8 pi; against the same linearisation converged (the propagator error)
#: 5.9e-13, 3.2e-9, 7.4e-8, 3.3e-7, estimates 1.8e-9, 4.6e-8, 1.3e-6, 4.9e-6; 0.8-0.9 s CPU
#: for the Floquet stage.
DEFAULT_PROPAGATOR_STEPS = 128
#: :func:`analyze` retries the frozen-modal propagation with one frame instead of two when the
#: dominant multiplier's estimate exceeds this (two frames win on the single link, one on the
#: two-link arm with gains).  The result with the smaller estimate is kept only if the two
#: dominant multipliers agree within the larger estimate (then both estimates are consistent
#: with the difference); otherwise the larger-estimate result is kept, its estimate raised to the
#: disagreement, and a ``RuntimeWarning`` names both values.
ONE_FRAME_RETRY = 1e-5
#: Propagation frames of :func:`analyze`: ``"modal"`` (frozen-eigenvector basis, default) or
#: ``"model"`` (the linearisation's own independent coordinates).
FRAMES = ("modal", "model")
#: Above this step-doubling estimate of the spectral radius or of the dominant multiplier
#: :func:`analyze` warns that the propagator is not converged.
PROPAGATOR_WARNING = 1e-4
#: :func:`_sampling_order`: a sampled linearisation whose trigonometric interpolant converges at an
#: order below this in the samples (between every fourth and every other sample) is not smooth: a
#: drive's acceleration jump makes ``P(t)`` jump and the interpolant converge like ``1/N`` (measured
#: ~0.2 on a bang-bang drive) where the smooth built-in models show 8 and more at 32 samples.
SAMPLING_MIN_ORDER = 2.0
#: Relative interpolation errors below this are rounding (no order information).
SAMPLING_NOISE = 1e-12
#: The structural multiplier of an autonomous orbit is 1 to within this at least (see
#: :attr:`ModelFloquetResult.structural`).
STRUCTURAL_TOLERANCE = 1e-6
#: ``| |rho| - 1 | <`` this: an undamped mode (on the unit circle within the propagator's accuracy).
UNDAMPED_TOLERANCE = 2e-3
#: A mode carries a drive's name, and counts as one the drives can move, only when that drive's share
#: in it (:func:`_drive_shares`: ``|c^T z|^2 / ((c^T M^-1 c)(z^H M z))`` in [0, 1], a squared cosine:
#: the fraction of the mode's kinetic-energy norm a unit generalised force on the drive coordinate can
#: reach) is at least this.  A mode decoupled from every drive (e.g. the lateral modes of a chain driven
#: axially) has a share at rounding level (<= 1e-20); a mode the drive moves through a heavy structure
#: can have a small one (the single link's hub mode at 2 ANCF elements: 1.7e-3, because the link's
#: nodal coordinates carry most of the kinetic energy), so the threshold separates "decoupled" from
#: "weakly coupled": a cosine of 1e-4.
DRIVE_SHARE_THRESHOLD = 1e-8


@dataclass(frozen=True)
class ModeLabel:
    """What one Floquet multiplier is (:func:`label_multipliers`).

    Attributes
    ----------
    modulus : float
        ``|rho|``.
    mode : str
        Label of the frozen-time mode with the largest modal energy in the Floquet vector
        (``"bending 1"``, ``"axial 2"``, a drive's name, ...).
    drive_shares : dict
        Per drive: its share in that frozen mode (open loop; :data:`DRIVE_SHARE_THRESHOLD`).
    group : str
        The Exudyn item holding most of the Floquet vector's energy.
    frequency_hz : float
        Frequency of that frozen-time mode.
    mac : float
        Fraction of the modal energy in that mode.
    shares : dict
        Energy fraction per Exudyn item and per drive coordinate (``"drive NAME"``).
    undamped : bool
        ``| |rho| - 1 | <`` :data:`UNDAMPED_TOLERANCE`.
    """

    modulus: float
    mode: str
    drive_shares: dict
    group: str
    frequency_hz: float
    mac: float
    shares: dict
    undamped: bool

    def to_dict(self) -> dict:
        """JSON-ready: the keys above, in that order (copies of the share dicts)."""
        return {"modulus": self.modulus, "mode": self.mode, "drive_shares": dict(self.drive_shares),
                "group": self.group, "frequency_hz": self.frequency_hz, "mac": self.mac,
                "shares": dict(self.shares), "undamped": self.undamped}


@frozen_result
@dataclass(frozen=True)
class ModelFloquetResult:
    """Floquet analysis of a model file about its periodic orbit.

    Attributes
    ----------
    floquet : stability.FloquetResult
    modes : list of ModeLabel
        Per multiplier (same order): what it is (:class:`ModeLabel`).
    dominant_multiplier : complex
        Largest multiplier of a drive mode or of ``bending 1`` (the modes a rigid or
        one-mode model has; for the single link the paper's hub / first bending mode)
        that is not on the unit circle; without such modes the largest one not on the
        unit circle.  ``floquet.spectral_radius`` stays the max over all.
    orbit : PeriodicOrbit
    linearization : LinearizedPeriodicSystem
    kp, kd : tuple of float
        Gains per drive.
    timings : dict
        Seconds per stage (wall clock).
    cpu_timings : dict
        CPU seconds per stage (same keys).
    dominant_error_estimate : float
        Step-doubling (Richardson) estimate of the relative error of the dominant
        multiplier's modulus (``floquet.error_estimate`` is the largest over all moduli
        above ``1e-6`` of the spectral radius); raised to the disagreement between one and
        two frozen-modal frames when :func:`analyze` ran both and they disagree.
    frame_check : tuple
        ``(dominant multiplier, its estimate)`` of the other frozen-modal frame count when
        :func:`analyze` ran both (:data:`ONE_FRAME_RETRY`), ``()`` otherwise.
    """

    floquet: Any
    modes: list
    dominant_multiplier: complex
    orbit: PeriodicOrbit = field(repr=False)
    linearization: LinearizedPeriodicSystem = field(repr=False)
    kp: tuple = ()
    kd: tuple = ()
    timings: dict = field(default_factory=dict)
    cpu_timings: dict = field(default_factory=dict)
    dominant_error_estimate: float = math.nan
    frame_check: tuple = ()

    @property
    def drives(self) -> tuple:
        return self.orbit.drive_names

    @property
    def frame(self) -> str:
        """Propagation frame actually used: ``"modal"`` or ``"model"`` (asked for, or the fallback of
        :func:`stability.modal.modal_floquet`)."""
        return str(getattr(self.floquet, "frame", "model"))

    @property
    def orbit_residual(self) -> float:
        return float(self.orbit.residual)

    @property
    def verdict(self) -> Any:
        """The closed loop's verdict (:func:`stability.verdict.judge_floquet`: every multiplier with its own
        error estimate, the practically undamped and growing ones counted with their mode labels; the
        :attr:`structural` multiplier of an autonomous orbit left out)."""
        from stability.verdict import judge_floquet

        return judge_floquet(self.floquet, labels=[m.mode for m in self.modes],
                             frequencies=[m.frequency_hz for m in self.modes], structural=self.structural)

    @functools.cached_property
    def structural(self) -> tuple:
        """Indices of the structural multipliers: on an autonomous orbit (its phase free), the multiplier
        nearest 1, which the verdict leaves out (the verdict is then one of orbital stability) -- only when
        it is 1 within ten times its own error estimate (at least :data:`STRUCTURAL_TOLERANCE`); a
        multiplier farther from 1 is no phase shift and nothing is left out."""
        if not self.orbit.autonomous:
            return ()
        mu = np.asarray(self.floquet.multipliers)
        i = int(np.argmin(np.abs(mu - 1.0)))
        digits = np.asarray(self.floquet.reliable_digits, dtype=float)
        error = 10.0 ** -float(digits[i]) if digits.size > i else math.inf
        if not abs(mu[i] - 1.0) <= max(10.0 * error, STRUCTURAL_TOLERANCE):
            logger.warning("autonomous orbit without a multiplier 1 (nearest %s, error estimate %.1e): no "
                           "multiplier is left out of the verdict", complex(mu[i]), error)
            return ()
        return (i,)

    @property
    def dominant_mode(self) -> str:
        """Mode label of :attr:`dominant_multiplier` (``"hub"``, ``"bending 1"``, ...)."""
        mu = np.asarray(self.floquet.multipliers)
        return str(self.modes[int(np.argmin(np.abs(mu - self.dominant_multiplier)))].mode)

    @property
    def undamped_count(self) -> int:
        """Number of practically undamped multipliers: the count of the verdict rule
        (:mod:`stability.verdict`: ``|rho| + error > exp(-1/1000)``, not growing)."""
        return len(self.verdict.undamped)

    def summary(self) -> dict:
        d = self.dominant_multiplier
        return {
            "model": self.orbit.model.name,
            "drives": list(self.drives),
            "orbit_residual": self.orbit_residual,
            "shooting_residual": float(self.orbit.shooting_residual),
            "turns": self.orbit.summary()["turns"],
            "sign_flips": self.orbit.summary()["sign_flips"],
            "structural_multipliers": len(self.structural),
            "structural_indices": [int(i) for i in self.structural],
            "samples": self.orbit.samples,
            "ode2": self.orbit.size,
            "independent_coordinates": self.linearization.size,
            "dominant_multiplier": [float(d.real), float(d.imag)],
            "dominant_modulus": float(abs(d)),
            "modes": [m.to_dict() for m in self.modes],
            "timings": dict(self.timings),
            "propagator_steps": int(self.floquet.n_steps),
            "error_estimate": float(self.floquet.error_estimate),
            "dominant_error_estimate": float(self.dominant_error_estimate),
            "frame": self.frame,
            "verdict_detail": self.verdict.to_dict(),
        }


@dataclass(frozen=True)
class FrozenModes:
    """Frozen-time structural modes at ``t = 0`` (drive gains removed), with labels.

    Attributes
    ----------
    eigenvalues : ndarray, shape (r,)
        ``omega_j^2`` of ``K_z(0) phi = omega^2 M_z(0) phi`` (symmetric parts), ascending ``|.|``.
    shapes : ndarray, shape (r, r)
        Columns ``phi_j``.
    labels : list of str
        A drive's name for the mode each drive moves (among the ``d`` lowest modes, the motions
        the ``d`` released drives control, e.g. ``hub``, the one with the drive's largest
        participation; if that drive's share in it is below :data:`DRIVE_SHARE_THRESHOLD`, the
        mode of any order with the drive's largest share, if that reaches the threshold; else no
        mode carries the drive's name), ``bending k`` /
        ``axial k`` for modes of ANCF beams (by the tangential share of the beam-node
        motion), else ``<Exudyn item> k``.
    item_labels : list of str
        The label each mode would carry without the drives (``bending k``, ``<item> k``; a
        drive mode's numbered after the others).
    drive_shares : ndarray, shape (d, r)
        Share of each drive in each mode (:func:`_drive_shares`).
    """

    eigenvalues: np.ndarray
    shapes: np.ndarray
    labels: list
    item_labels: list = field(default_factory=list)
    drive_shares: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def _drive_shares(lin: LinearizedPeriodicSystem, Mz: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Per drive, ``|c^T z|^2 / ((c^T M^-1 c) (z^H M z))`` in [0, 1] (Cauchy-Schwarz), ``c = B_z(0)``."""
    if lin.B is None or lin.B.shape[2] == 0:
        return np.zeros(0)
    c = lin.B[0]
    Minv_c = np.linalg.solve(Mz, c)
    denom = np.einsum("id,id->d", c, Minv_c) * max(float(np.real(np.conj(z) @ Mz @ z)), 1e-300)
    return np.abs(c.T @ z) ** 2 / np.maximum(denom, 1e-300)


def frozen_modes(lin: LinearizedPeriodicSystem, orbit: PeriodicOrbit) -> FrozenModes:
    """Frozen-time modes of ``(K_z(0), M_z(0))`` without the PD gains, labelled."""
    Mz = 0.5 * (lin.M[0] + lin.M[0].T)
    K = lin.K[0].copy()
    if lin.B is not None and lin.B.shape[2]:
        kp = np.asarray(lin.kp, dtype=float)
        kd = np.asarray(lin.kd, dtype=float)
        K -= (lin.B[0] * kp) @ lin.B[0].T + (lin.B[0] * kd) @ lin.B_t[0].T
    K = 0.5 * (K + K.T)
    lam, Phi = scipy.linalg.eigh(K, Mz)
    order = np.argsort(np.abs(lam), kind="stable")
    lam, Phi = lam[order], Phi[:, order]
    N0 = lin.basis[0]
    labels_item = orbit.coordinate_labels
    slope_nodes = _slope_nodes(orbit)
    counts: dict = {}
    labels = []
    n_drives = 0 if lin.B is None else lin.B.shape[2]
    drive_modes: dict = {}
    shares = np.zeros((n_drives, Phi.shape[1]))
    if n_drives:
        # the n_drives lowest frozen modes without PD are the motions the drives control
        # (rigid-body modes about the released drives, possibly gravity-stiffened); each
        # is named after the drive with the largest participation (c_d^T phi)^2 -- if that
        # drive's share says it moves the mode; else the mode of the drive's largest share
        c = lin.B[0]
        for j in range(Phi.shape[1]):
            shares[:, j] = _drive_shares(lin, Mz, Phi[:, j])
        free = list(range(min(n_drives, Phi.shape[1])))
        for name_idx in range(n_drives):
            part = [(float((c[:, name_idx] @ Phi[:, j]) ** 2), j) for j in free if j not in drive_modes]
            pick = max(part)[1] if part else None
            if pick is None or not shares[name_idx, pick] >= DRIVE_SHARE_THRESHOLD:
                rest = [j for j in range(Phi.shape[1]) if j not in drive_modes]
                pick = max(rest, key=lambda j: shares[name_idx, j]) if rest else None
                if pick is not None and not shares[name_idx, pick] >= DRIVE_SHARE_THRESHOLD:
                    pick = None
            if pick is not None:
                drive_modes[pick] = orbit.drive_names[name_idx]
    kinds: list = []
    for j in range(Phi.shape[1]):
        phi = Phi[:, j]
        dq = N0 @ phi
        kind = None
        if slope_nodes:
            axial = transverse = 0.0
            beam_energy = 0.0
            for idx, ref in slope_nodes:
                qn = orbit.q[0, idx] + ref
                t_hat = qn[2:4] / max(float(np.hypot(*qn[2:4])), 1e-300)
                for a, b in ((0, 2), (2, 4)):
                    d = dq[idx[a:b]]
                    axial += float(d @ t_hat) ** 2
                    transverse += float(d[0] * t_hat[1] - d[1] * t_hat[0]) ** 2
                beam_energy += float(dq[idx] @ dq[idx])
            if beam_energy > 0.5 * float(dq @ dq):
                kind = "axial" if axial > transverse else "bending"
        if kind is None:
            groups: dict = {}
            for i, g in enumerate(labels_item):
                groups[g] = groups.get(g, 0.0) + float(dq[i] ** 2)
            kind = max(groups, key=groups.get) if groups else "mode"
        kinds.append(kind)
        if j in drive_modes:
            labels.append(drive_modes[j])
            continue
        counts[kind] = counts.get(kind, 0) + 1
        labels.append(f"{kind} {counts[kind]}")
    item_labels = list(labels)
    for j in sorted(drive_modes):  # numbered after the others, so the others keep their numbers
        counts[kinds[j]] = counts.get(kinds[j], 0) + 1
        item_labels[j] = f"{kinds[j]} {counts[kinds[j]]}"
    return FrozenModes(eigenvalues=lam, shapes=Phi, labels=labels, item_labels=item_labels, drive_shares=shares)


def _slope_nodes(orbit: PeriodicOrbit) -> list:
    return list(orbit.slope_nodes)


def label_multipliers(lin: LinearizedPeriodicSystem, orbit: PeriodicOrbit, floquet_result: Any) -> list:
    """Label each multiplier by where its Floquet vector lives: one :class:`ModeLabel` per multiplier.

    The Floquet vector ``x = [z; z']`` at ``t = 0`` (eigenvector of the
    monodromy) is mapped back to Exudyn's coordinates, ``dq = N(0) z``,
    ``dq' = N(0) z' + N'(0) z``; ``shares`` are the fractions of
    ``|dq'|_M^2 + |dq|^2_{|K|}``-like weights per Exudyn item (diagonal
    weights ``M_ii`` and ``|K_ii|`` of the full-coordinate matrices) and per
    drive coordinate; ``mode`` is the label of the frozen-time mode with the
    largest modal energy ``|eta_j'|^2 + |omega_j^2| |eta_j|^2``.
    """
    fm = frozen_modes(lin, orbit)
    r = lin.size
    Phi = np.asarray(floquet_result.monodromy)
    w, X = np.linalg.eig(Phi)
    Vinv = np.linalg.inv(fm.shapes)
    Mz = 0.5 * (lin.M[0] + lin.M[0].T)
    N0, N0t = lin.basis[0], lin.basis_t[0]
    tb = orbit.tangent
    m_diag = np.abs(np.diag(tb.M[0]))
    k_diag = np.abs(np.diag(tb.K[0]))
    items = orbit.coordinate_labels
    out = []
    used: set = set()
    for mu in floquet_result.multipliers:
        dist = np.abs(w - mu)
        if len(used) < w.size:
            dist[list(used)] = np.inf
        j = int(np.argmin(dist))
        used.add(j)
        x = X[:, j]
        z, zt = x[:r], x[r:]
        eta, eta_t = Vinv @ z, Vinv @ zt
        energy = np.abs(eta_t) ** 2 + np.abs(fm.eigenvalues) * np.abs(eta) ** 2
        k = int(np.argmax(energy))
        dq = N0 @ z
        dqt = N0 @ zt + N0t @ z
        weight = m_diag * np.abs(dqt) ** 2 + k_diag * np.abs(dq) ** 2
        total = float(np.sum(weight)) or 1.0
        shares: dict = {}
        for i, g in enumerate(items):
            shares[g] = shares.get(g, 0.0) + float(weight[i]) / total
        group = max(shares, key=shares.get) if shares else ""
        drive_sh = _drive_shares(lin, Mz, z)
        for name, v in zip(orbit.drive_names, drive_sh):
            shares[f"drive {name}"] = float(v)
        mod = float(abs(mu))
        mac = float(energy[k] / max(float(np.sum(energy)), 1e-300))
        out.append(ModeLabel(
            modulus=mod,
            mode=fm.labels[k],
            # the drives' shares in the frozen mode the multiplier is labelled by (open loop, no PD: the
            # closed loop's own vector hardly moves a stiffly controlled drive coordinate)
            drive_shares={n: round(float(fm.drive_shares[i, k]), 6) for i, n in enumerate(orbit.drive_names)},
            group=group,
            frequency_hz=float(math.sqrt(abs(fm.eigenvalues[k])) / (2 * math.pi)),
            mac=mac,
            shares={g: round(v, 6) for g, v in shares.items()},
            undamped=bool(abs(mod - 1.0) < UNDAMPED_TOLERANCE),
        ))
    return out


def drive_movable(mode: ModeLabel, drive_names: Sequence[str] = ()) -> bool:
    """Whether some drive's share in the frozen mode of a labelled multiplier (:attr:`ModeLabel.drive_shares`,
    :func:`label_multipliers`) is at least :data:`DRIVE_SHARE_THRESHOLD`: a mode the PD gains on the
    drives can move."""
    return any(float(v) >= DRIVE_SHARE_THRESHOLD for v in mode.drive_shares.values())


def _dominant(floquet_result: Any, modes: list, drive_names: tuple) -> complex:
    """Largest multiplier not on the unit circle of a mode the drives can move: a drive mode, the
    first bending mode (the modes a rigid / one-mode model has, e.g. the paper's hub and bending 1)
    or any mode a drive's share says it moves (:func:`drive_movable`); without such modes the
    largest one not on the unit circle."""
    main = set(drive_names) | {"bending 1"}
    for mu, m in zip(floquet_result.multipliers, modes):
        if not m.undamped and (m.mode in main or (drive_names and drive_movable(m, drive_names))):
            return complex(mu)
    for mu, m in zip(floquet_result.multipliers, modes):
        if not m.undamped:
            return complex(mu)
    return complex(floquet_result.multipliers[0])


def analyze(
    model: Any,
    omega: float,
    *,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    samples: int = DEFAULT_SAMPLES,
    method: str = "magnus2",
    n_steps: Optional[int] = DEFAULT_PROPAGATOR_STEPS,
    orbit: Optional[PeriodicOrbit] = None,
    verify_orbit: bool = True,
    small_multipliers: str = "flag",
    frame: str = "modal",
    rtol: float = CONTRACT_RTOL,
    refine: bool = True,
    **options: Any,
) -> ModelFloquetResult:
    """Orbit, constraint-correct linearisation and labelled Floquet multipliers of a model.

    Parameters
    ----------
    model : ModelDefinition, str, path or callable
        Built-in name, model file path, :class:`~mbs_models.model_file.ModelDefinition`
        or a ``build(mbs, omega)`` callable.
    omega : float
    kp, kd : float or sequence
        PD gains per drive (or one for all).
    samples : int
        Collocation / linearisation samples per period.
    method, n_steps :
        :func:`stability.floquet` method and sub-intervals.  ``n_steps=None``: adaptive -- in the
        frozen-modal frame with ``magnus2`` the extrapolated solve at 72, 144/216/288, ... steps until
        its estimate meets ``rtol`` (:func:`stability.modal.modal_floquet`), *with* the non-nested check
        solve (``check=True``: a step family shares errors its own nested estimate cannot see, measured
        on the single link at 8-16 elements); otherwise :func:`stability.floquet`'s adaptive engine.
        The default ``magnus2`` (exponential midpoint) keeps every factor an exact
        matrix exponential, robust for the stiff, strongly damped modes of PD-controlled
        flexible models; its step-doubling estimate watches the moduli.
    frame : {"modal", "model"}
        Coordinates the propagator runs in (same multipliers): ``"modal"`` (default)
        the frozen-eigenvector basis of :class:`stability.modal.FrozenModalSystem`, in
        which the stiff part of ``P(t)`` is nearly constant (the midpoint product then
        converges with a few dozen steps, at order 2, and with ``magnus2`` and a fixed
        ``n_steps`` the multipliers are Richardson-extrapolated from ``n_steps``,
        ``n_steps/2`` and ``n_steps/4``: 4th order, see :func:`stability.modal.modal_floquet`;
        when no smooth basis exists it warns and falls back to the adaptive engine in the model's
        coordinates, :data:`stability.modal.FALLBACK_METHOD`; ``ModelFloquetResult.frame`` says which
        frame was used); ``"model"`` the
        linearisation's own coordinates (needs thousands of steps for stiff flexible models).
    orbit : PeriodicOrbit, optional
        Reuse an orbit (must be for ``omega``).
    verify_orbit : bool
        Shooting check of the orbit in Exudyn.
    small_multipliers : {"flag", "qr"}
        Passed to :func:`stability.floquet`.
    rtol : float
        The accuracy contract (``docs/accuracy.md``): every multiplier with modulus
        ``>= 1e-6`` of the largest is certified to this relative error
        (:attr:`~stability.floquet.FloquetResult.certified`), or reported with the reason.
    refine : bool
        When the fixed-step solve misses ``rtol`` on a covered multiplier: solve again
        adaptively to ``rtol`` (:func:`_refine_to_contract`) and keep the better-certified result.
    **options
        Keyword options of the model's ``build``.

    Returns
    -------
    ModelFloquetResult

    Raises
    ------
    mbs_models.model_file.ModelFileError
        Bad model file.
    linearize.periodic_orbit.OrbitConvergenceError
        No periodic orbit.
    """
    from stability import floquet
    from stability.modal import modal_floquet

    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {FRAMES}, got {frame!r}")
    clock = StageClock()
    timings, cpu_timings, lap = clock.timings, clock.cpu_timings, clock.lap

    if orbit is None:
        orbit = find_orbit(model, omega, samples=samples, verify=verify_orbit, **options)
    elif abs(orbit.omega - float(omega)) > 1e-12 * float(omega):
        raise ValueError(f"the given orbit is for omega = {orbit.omega}, not {omega}")
    lap("orbit")
    lin = linearize_orbit(orbit, kp, kd)
    lap("linearization")
    sm = small_multipliers if method != "paper" else "flag"
    basis = _modal_basis(lin) if frame == "modal" and method != "paper" else None
    if frame == "modal" and method == "magnus2":
        res = modal_floquet(lin, method="magnus2", n_steps=n_steps, accuracy=_certified_accuracy(lin),
                            small_multipliers=sm, check=n_steps is None, extrapolate=True, basis=basis)
    elif frame == "modal" and method != "paper":
        res = modal_floquet(lin, method=method, n_steps=n_steps, small_multipliers=sm, basis=basis)
    elif method == "magnus2":
        res = floquet(lin, method="magnus2", n_steps=n_steps, accuracy=_certified_accuracy(lin), small_multipliers=sm)
    elif method != "paper":
        res = floquet(lin, method=method, n_steps=n_steps, accuracy=_certified_accuracy(lin), small_multipliers=sm)
    else:
        res = floquet(lin, method=method, n_steps=n_steps, small_multipliers=sm)
    res = recertify(res, rtol)
    if refine and method != "paper" and not res.all_certified:
        res = _refine_to_contract(lin, res, rtol, sm, basis)
    res = _declared_breakpoints(orbit, res)
    res = _check_sampling(lin, res, rtol)
    lap("floquet")
    modes = label_multipliers(lin, orbit, res)
    lap("labels")
    dom = _dominant(res, modes, orbit.drive_names)
    dom_est = _multiplier_estimate(res, dom)
    if (frame == "modal" and method == "magnus2" and n_steps is not None and dom_est > ONE_FRAME_RETRY
            and getattr(res, "frame", "model") == "modal"):
        # two nested frozen-modal frames are not always the better basis (measured: the two-link arm
        # at 4 pi with gains); one frame costs the same again (rule: ONE_FRAME_RETRY)
        alt = modal_floquet(lin, method="magnus2", n_steps=n_steps, accuracy="moduli", small_multipliers=sm,
                            extrapolate=True, levels=1)
        alt_modes = label_multipliers(lin, orbit, alt)
        alt_dom = _dominant(alt, alt_modes, orbit.drive_names)
        alt_est = _multiplier_estimate(alt, alt_dom)
        logger.info("one frozen-modal frame: dominant estimate %.1e (two frames: %.1e)", alt_est, dom_est)
        two_frames = (dom, dom_est)
        take_alt, dom_est_new, gap, agree = _pick_frame(dom, dom_est, alt_dom, alt_est)
        if take_alt:
            res, modes, dom = alt, alt_modes, alt_dom
        if not agree:
            warnings.warn(f"one and two frozen-modal frames disagree on the dominant multiplier by {gap:.1e} "
                          f"(relative), more than their estimates ({alt_est:.1e}, {two_frames[1]:.1e}): one frame "
                          f"{alt_dom:.8g}, two frames {two_frames[0]:.8g}; keeping the larger-estimate result with "
                          f"the estimate raised to the disagreement", RuntimeWarning, stacklevel=2)
        dom_est = dom_est_new
        frame_check = (alt_dom, alt_est) if res is not alt else two_frames
        lap("floquet")  # the retry counts as Floquet time
    else:
        frame_check = ()
    worst = max(_multiplier_estimate(res, res.multipliers[0]), dom_est)
    if math.isfinite(worst) and worst > PROPAGATOR_WARNING:
        msg = (f"Floquet step-doubling estimate {worst:.1e} (relative, spectral radius / dominant multiplier) "
               f"with {res.n_steps} {res.method} steps: the multipliers are not converged; increase n_steps "
               f"(--method/adaptive n_steps=None)")
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    est = float(res.error_estimate)
    if math.isfinite(est) and est > PROPAGATOR_WARNING:
        logger.info("secondary multipliers less accurate: step-doubling estimate %.1e over all moduli", est)
    logger.info("Floquet of %s at omega=%.4g: spectral radius %.6f, dominant |rho| %.6f", orbit.model.name, omega,
                res.spectral_radius, abs(dom))
    return ModelFloquetResult(floquet=res, modes=modes, dominant_multiplier=dom, orbit=orbit, linearization=lin,
                              kp=tuple(lin.kp), kd=tuple(lin.kd), timings=timings,
                              cpu_timings=cpu_timings, dominant_error_estimate=dom_est, frame_check=frame_check)


#: Extrapolated frozen-modal passes of :func:`_refine_to_contract` on a large system: the first asks the
#: 4th-order error model of the estimates for its step count (:func:`_contract_steps`), the second
#: (when the first was still pre-asymptotic) asks it again from the first pass's estimate.
REFINE_MODAL_PASSES = 2
#: Largest step count of those passes (the frozen-modal budget of the engine rule).
MODAL_MAX_STEPS = 4096
#: Largest first-order system refined by the adaptive Magnus-6 engine in the model's own coordinates
#: (:func:`_refine_to_contract`); larger (stiff, flexible) ones by the adaptive frozen-modal solve.
REFINE_MAGNUS6_MAX_N = 16


def _certified_accuracy(lin: Any) -> str:
    """What the estimates of a solve in the linearisation's own coordinates certify: the multipliers
    (moduli *and* phases) of a small system (``<= REFINE_MAGNUS6_MAX_N`` states, where the extra steps
    cost little), the moduli of a larger one.

    Why: a step-doubling estimate of the moduli alone sees nothing when the moduli do not depend on the
    step.  Measured on the anisotropic Laval rotor at 30 rad/s: its external damping is uniform, so every
    multiplier has the modulus ``exp(-c T / 2 m)`` that the trace fixes and every Magnus product keeps
    exactly; adaptive Magnus-6 stopped at its 32-step pilot with a moduli estimate of 2.5e-14 while the
    multipliers (their phases, the whirl frequencies) were 1.6e-6 off, beyond the contract's 1e-6.
    """
    return "multipliers" if 2 * lin.size <= REFINE_MAGNUS6_MAX_N else "moduli"


def _modal_basis(lin: Any) -> Any:
    """The frozen-modal frames of ``lin`` (:func:`stability.modal.modal_system`), built once for every
    frozen-modal solve of one analysis; ``None`` when no basis exists (each solve then warns and falls
    back, :func:`stability.modal.modal_floquet`)."""
    from stability.modal import ModalBasisError, modal_system

    try:
        return modal_system(lin)
    except ModalBasisError:
        return None


def _refine_to_contract(lin: Any, res: Any, rtol: float, small_multipliers: str, basis: Any = None) -> Any:
    """A result that meets the accuracy contract ``rtol`` where ``res`` does not, or the better one.

    Small systems (``<= REFINE_MAGNUS6_MAX_N`` states): :func:`stability.floquet` adaptive, 6th order,
    in the linearisation's coordinates, to ``rtol / 10`` (its estimate is order-checked and carries a
    safety factor; the margin keeps the refinement off the boundary).  Larger ones: one more
    extrapolated frozen-modal solve (:func:`stability.modal.modal_floquet`) with the step count the
    4th-order error model of its estimate asks for (:func:`_contract_steps`), at most
    :data:`REFINE_MODAL_PASSES` passes within :data:`MODAL_MAX_STEPS`, so that the cost stays bounded
    (the 8-element single link at 8 pi: 128 -> 432 steps).  The new result replaces ``res`` when it certifies at least as many multipliers;
    a ``FloquetError`` of the refinement keeps ``res`` (logged).
    """
    from stability import floquet
    from stability.floquet import FloquetError
    from stability.modal import modal_floquet

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # the kept result's own warnings follow
            if 2 * lin.size <= REFINE_MAGNUS6_MAX_N:
                new = floquet(lin, method="magnus6", rtol=0.1 * rtol, accuracy=_certified_accuracy(lin),
                              small_multipliers=small_multipliers)
            else:
                new = res
                for _ in range(REFINE_MODAL_PASSES):  # the error model is asymptotic: a second look if needed
                    n = _contract_steps(new, rtol)
                    if n > MODAL_MAX_STEPS:
                        break
                    new = recertify(modal_floquet(lin, method="magnus2", n_steps=n, accuracy="moduli",
                                                  small_multipliers=small_multipliers, extrapolate=True,
                                                  basis=basis), rtol)
                    if new.all_certified:
                        break
    except FloquetError as exc:
        logger.info("refinement to the accuracy contract failed: %s", exc)
        return res
    new = recertify(new, rtol)
    if int(np.sum(new.certified)) >= int(np.sum(res.certified)):
        logger.info("refined to the accuracy contract: %d -> %d steps (%s), %d of %d certified", res.n_steps,
                    new.n_steps, new.method, int(np.sum(new.certified)), len(new.certified))
        res = new
    if not res.all_certified:
        missed = [f"{i + 1}: {r}" for i, r in enumerate(res.uncertified_reasons)
                  if r and "outside the accuracy contract" not in r]
        if missed:
            warnings.warn(f"multipliers not certified to rtol {rtol:.0e}: " + "; ".join(missed), RuntimeWarning,
                          stacklevel=3)
    return res


def _contract_steps(res: Any, rtol: float) -> int:
    """Steps of the next extrapolated frozen-modal solve (4th order: error ``e_N ~ C N^-4``) that
    bring the largest estimate over the covered multipliers of ``res`` to ``rtol`` with a margin of
    1.2 in ``N``; a multiple of 72, so that the next solve extrapolates with ratio 3 (its coarser
    levels from its own factors on a large system).

    The estimate of a ratio-``r`` extrapolation is the *undivided* change from the coarser level
    (:func:`stability.modal._extrapolated`), asymptotically ``(r^4 - 1) e_N``: 15 ``e_N`` for
    ratio 2, 80 ``e_N`` for ratio 3.  So a ratio-2 estimate ``est`` at ``N`` asks for
    ``N (80 / 15 est / rtol)^(1/4)`` steps at ratio 3, not ``N (est / rtol)^(1/4)``.  Measured on the
    8-element single link at 8 pi (Table 3 gains): 128 steps (ratio 2) estimate 6.5e-6, true error
    4.2e-7; the rule asks for 432 steps, whose estimate is 5.8e-7 (true error 7.7e-9); without the
    factor it asked for 288 (estimate 3.0e-6) and a third solve at 504.
    """
    logs = np.asarray(res.log_moduli, float)
    covered = logs >= logs[0] + math.log(1e-6)
    est = float(np.max(10.0 ** -np.asarray(res.reliable_digits, float)[covered]))
    ratio = 3 if len(res.companion_steps) == 2 else 2
    amplification = (3**4 - 1) / (ratio**4 - 1)  # the next solve's estimate over this one's, same N
    grow = 1.2 * (amplification * est / rtol) ** 0.25 if math.isfinite(est) and est > rtol else 2.0
    return int(72 * math.ceil(res.n_steps * min(grow, 8.0) / 72))


def _declared_breakpoints(orbit: PeriodicOrbit, res: Any) -> Any:
    """``res`` uncertified, with the reason, when a drive of the model declares breakpoints that the
    orbit was not sampled on.

    :func:`~linearize.periodic_orbit.find_orbit` samples piece by piece when a drive declares
    breakpoints (:mod:`linearize.piecewise`; ``orbit.breakpoints``), and the linearisation then jumps
    where the motion does.  An orbit sampled on the equispaced grid (given by the caller) is
    interpolated trigonometrically: a smooth ``P(t)`` whatever the motion, so a declared non-smooth
    motion is not represented to the accuracy the estimates speak of (they see the propagator's error
    on the interpolant, not the interpolant's).  Warns (``RuntimeWarning``).
    """
    from dataclasses import replace

    from mbs_models.model_file import build_model

    drives = build_model(orbit.model, orbit.omega).drives
    T = orbit.period
    sampled = {round(float(b) % T / T, 9) for b in (getattr(orbit, "breakpoints", ()) or ())}
    declared = {d.name: d.breakpoints for d in drives
                if d.breakpoints and not all(round(float(b) % T / T, 9) in sampled | {0.0, 1.0} for b in d.breakpoints)}
    if not declared:
        return res
    which = ", ".join(f"{name} at t = {', '.join(f'{b:.4g}' for b in bps)}" for name, bps in declared.items())
    reason = (f"the drive motion is non-smooth ({which}); the orbit was not sampled on these times and its "
              f"linearisation (trigonometric interpolation) is smooth: it does not represent the motion")
    warnings.warn(f"multipliers not certified: {reason}", RuntimeWarning, stacklevel=3)
    return replace(res, certified=np.zeros(len(res.certified), bool),
                   uncertified_reasons=tuple(r or reason for r in res.uncertified_reasons))


def _sampling_order(lin: LinearizedPeriodicSystem) -> tuple[float, float, str]:
    """``(q, e, name)``: the lowest order of convergence in the samples among ``M, C, K`` of ``lin``
    whose interpolation error ``e`` is above :data:`SAMPLING_NOISE`, with that error and the matrix.

    ``e`` is the largest error, relative to the matrix's largest entry (for ``C`` at least the critical
    damping scale ``sqrt(max|K| max|M|)``), of the trigonometric interpolant
    of every other sample at the samples in between (the interpolant of half the samples: the samples
    are nested, so no new evaluation); ``e0`` the same for every fourth sample; ``q = log2(e0 / e)``.
    ``(inf, 0, "")`` when no matrix is informative or there are too few samples (fewer than 16, or not a
    multiple of 4)."""
    from linearize.fourier import trig_interpolate

    N, T = lin.samples, lin.period
    if N < 16 or N % 4:
        return math.inf, 0.0, ""
    worst = (math.inf, 0.0, "")
    # C is measured against the critical damping scale sqrt(|K| |M|) too: an undamped model's C is
    # rounding (1e-15 of it), whose interpolation error relative to C's own size is O(1)
    critical = math.sqrt(float(np.max(np.abs(lin.K))) * float(np.max(np.abs(lin.M))))
    for name, S in (("M", lin.M), ("C", lin.C), ("K", lin.K)):
        scale = max(float(np.max(np.abs(S))), critical if name == "C" else 0.0) or 1.0
        e = float(np.max(np.abs(trig_interpolate(S[0::2], T, lin.times[1::2]) - S[1::2]))) / scale
        e0 = float(np.max(np.abs(trig_interpolate(S[0::4], T, lin.times[2::4]) - S[2::4]))) / scale
        if not e > SAMPLING_NOISE:
            continue
        q = math.log2(e0 / e) if e0 > e else 0.0
        if q < worst[0]:
            worst = (q, e, name)
    return worst


def _check_sampling(lin: LinearizedPeriodicSystem, res: Any, rtol: float) -> Any:
    """``res`` uncertified, with the reason, when the equispaced samples do not resolve a smooth ``P``.

    The propagator's estimates see the error of the propagation of the interpolated ``P``, not the
    interpolant's own error; a smooth linearisation makes the latter negligible (spectral), a
    non-smooth one (an undeclared acceleration jump of a drive) does not: the interpolant's order in
    the samples (:func:`_sampling_order`) is then below :data:`SAMPLING_MIN_ORDER` while its error
    from half the samples is above ``rtol``.  Warns (``RuntimeWarning``).  A piecewise-sampled
    linearisation (declared breakpoints) is left alone.
    """
    from dataclasses import replace

    if lin.breakpoints:
        return res
    q, e, name = _sampling_order(lin)
    if not (q < SAMPLING_MIN_ORDER and e > rtol):
        return res
    reason = (f"the sampled linearisation is not smooth: its {name} converges at order {q:.2g} in the samples "
              f"(interpolation error {e:.1e} from every other sample); a drive's motion is probably "
              f"non-smooth -- declare its breakpoints (docs/accuracy.md)")
    warnings.warn(f"multipliers not certified: {reason}", RuntimeWarning, stacklevel=3)
    return replace(res, certified=np.zeros(len(res.certified), bool),
                   uncertified_reasons=tuple(r or reason for r in res.uncertified_reasons))


def _pick_frame(dom: complex, est: float, alt_dom: complex, alt_est: float) -> tuple:
    """The rule of :data:`ONE_FRAME_RETRY`: ``(take_alt, estimate, gap, agree)`` for two results (dominant
    multiplier and its relative estimate each).  ``gap`` = their relative distance; ``agree``: ``gap`` within
    the larger estimate (a non-finite estimate counts as infinite).  Agreeing: the smaller-estimate result,
    its own estimate.  Otherwise: the larger-estimate result, its estimate raised to ``gap``."""
    gap = abs(alt_dom - dom) / abs(dom) if abs(dom) > 0 else math.inf
    a = alt_est if math.isfinite(alt_est) else math.inf
    b = est if math.isfinite(est) else math.inf
    if gap <= max(a, b):
        return (True, alt_est, gap, True) if a < b else (False, est, gap, True)
    if a > b:
        return True, max(alt_est, gap), gap, False
    return False, max(est, gap), gap, False


def _multiplier_estimate(res: Any, mu: complex) -> float:
    """Step-doubling estimate of one multiplier's relative error (from ``reliable_digits``;
    NaN when the result has none)."""
    if not math.isfinite(float(res.error_estimate)):
        return math.nan
    i = int(np.argmin(np.abs(np.asarray(res.multipliers) - mu)))
    return float(10.0 ** -float(res.reliable_digits[i]))


#: Sub-intervals of the Floquet evaluations inside a tuning loop (frozen-modal frame built at each
#: evaluation's gains, one frame, Richardson-extrapolated with 32 and 16, premise check at 8; see
#: :class:`ModelPlant`).
#: A basis built once at gains 0 and reused is not good enough: 6.6e-4 off on the double pendulum
#: test model (1e-7 with its own basis).  Measured on the 8-element single link at the Table 3
#: gains: 1e-8 .. 4e-5 (2-8 pi), ~0.4 s CPU per evaluation (the former 256 plain steps: up to ~1e-2
#: at ~2 s); the two-link arm 2.5e-6 (0.12 s), the double pendulum test model 4e-8.
TUNING_PROPAGATOR_STEPS = 64


@dataclass(frozen=True)
class ModelPlant:
    """A model file's linearisation as a plant for PD-gain tuning.

    ``with_gains(kp, kd)`` (one value per drive or one for all) gives the periodic
    system; :meth:`spectral_measure` is the tuning response: the modulus of
    :attr:`ModelFloquetResult.dominant_multiplier` (drive modes and the first
    bending mode; undamped structural modes sit on the unit circle whatever the
    gains).  Holds the orbit (its model may come from a file loaded at run time),
    so it is meant for in-process (serial) executors.
    """

    linearization: LinearizedPeriodicSystem = field(repr=False)
    orbit: PeriodicOrbit = field(repr=False)
    n_steps: int = TUNING_PROPAGATOR_STEPS

    @property
    def drives(self) -> tuple:
        return self.orbit.drive_names

    def with_gains(self, kp, kd) -> LinearizedPeriodicSystem:
        return self.linearization.with_gains(kp, kd)

    def floquet(self, kp, kd, n_steps: Optional[int] = None):
        """Floquet multipliers at ``(kp, kd)``: exponential midpoint in the frozen-modal frame of the
        system *at these gains* (one frame, Richardson-extrapolated; see :data:`TUNING_PROPAGATOR_STEPS`)."""
        from stability.engines import floquet

        lin = self.with_gains(kp, kd)
        steps = n_steps or self.n_steps
        # without a frozen-modal basis: the modal engine's one fallback policy (warns, adaptive engine)
        return floquet(lin, method="modal", levels=1, order=2, n_steps=steps, error_estimate=False,
                       accuracy="moduli", extrapolate=True).detail

    def spectral_measure(self, kp, kd) -> float:
        lin = self.with_gains(kp, kd)
        res = self.floquet(kp, kd)
        return float(abs(_dominant(res, label_multipliers(lin, self.orbit, res), self.orbit.drive_names)))


def model_plant(model: Any, omega: float, *, samples: int = DEFAULT_SAMPLES, **options: Any) -> ModelPlant:
    """Orbit + linearisation (gains 0) of a model, packaged for :func:`taguchi.taguchi_tune`."""
    orbit = find_orbit(model, omega, samples=samples, verify=False, **options)
    return ModelPlant(linearize_orbit(orbit), orbit)
