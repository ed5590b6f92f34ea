"""Campbell diagrams of periodic systems: Floquet frequencies, their harmonics, and mode tracking.

Model-free numerics (no model is imported): given the monodromy matrix of a
``T``-periodic system ``x' = P(t) x`` at each of several rotation speeds, this
module chooses one frequency per Floquet mode, reads its harmonic content, and
follows the modes from one speed to the next.

**Which frequency.**  A Floquet multiplier ``rho = exp(lambda T)`` fixes the
exponent ``lambda`` only up to ``i k Omega`` (``Omega = 2 pi / T``, ``k`` any
integer): the solution ``x(t) = exp(lambda t) p(t)`` has a ``T``-periodic part
``p`` whose Fourier series contains every harmonic ``k Omega`` of the base
representative ``lambda_0 = log(rho) / T`` (principal logarithm).  The rule
here (:func:`harmonic_content`): the *principal* representative is
``lambda_0 + i k* Omega`` with ``k*`` the harmonic that carries the largest share
of ``sum_j |c_k|^2`` (the squared Fourier coefficients of the output
``y(t) = C(t) p(t)`` -- by default the state itself), i.e. the frequency at which
an observer of ``y`` sees the mode move most.  This is the choice of Bottasso &
Cacciola's participation factors and of Skjoldan & Hansen's comparison with the
Coleman transformation; the shares of the other harmonics ``(k - k*) Omega`` are
returned so that a user sees when two harmonics are nearly tied (an
anisotropic rotor's forward and backward whirl, a linearly polarised mode).
One mode is reported per complex-conjugate pair of multipliers (the member
whose principal frequency is positive); a real multiplier is its own mode
(frequency ``0`` or a multiple of ``Omega / 2``).  The damping ratio is
``zeta = -Re(lambda) / |lambda|`` of the principal representative.

**Which mode is which at the next speed.**  :func:`track_modes` compares the
mode shapes (Floquet vectors at ``t = 0``, e.g. the displacement rows) of
consecutive speeds by the modal assurance criterion
``MAC(a, b) = |a^H b|^2 / ((a^H a)(b^H b))`` and assigns them one-to-one by
maximising the total MAC (:func:`scipy.optimize.linear_sum_assignment` on
``1 - MAC``), as OpenFAST's ACDC Campbell tool does; a mode whose best MAC with
every earlier branch is below :data:`MIN_MAC` starts a new branch.  Sorting by
frequency instead swaps two branches wherever they cross.

References
----------
.. [1] C. L. Bottasso, S. Cacciola, "Model-independent periodic stability analysis of wind turbines",
   Wind Energy 18 (2015) 865-887.
.. [2] P. F. Skjoldan, M. H. Hansen, "On the similarity of the Coleman and Lyapunov-Floquet
   transformations for modal analysis of bladed rotor structures", J. Sound Vib. 327 (2009) 424-439.
.. [3] OpenFAST, ``ACDC`` (``modes.py``/``campbell.py``): MAC-based mode identification across operating points.
"""
from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np
import scipy.linalg
from scipy.optimize import linear_sum_assignment

from stability.periodic import PeriodicMatrixFunction

__all__ = [
    "CLOSURE_WARNING",
    "HARMONIC_SAMPLES",
    "MIN_MAC",
    "REAL_MULTIPLIER_TOLERANCE",
    "STEPS_PER_SAMPLE",
    "CampbellResult",
    "FloquetModes",
    "HarmonicContent",
    "Tracking",
    "campbell",
    "floquet_modes",
    "harmonic_content",
    "mac_matrix",
    "track_modes",
]

logger = logging.getLogger(__name__)

#: Samples per period at which the Floquet solutions are read for their harmonics (harmonics
#: ``-32 .. 31`` of ``Omega``; the share of the principal one is what is used, so aliasing of
#: harmonics beyond 32 only matters for modes that live there).
HARMONIC_SAMPLES = 64
#: Magnus-4 sub-steps between two samples: 512 steps per period by default.  The harmonic choice
#: only needs the periodic part to a few digits; :attr:`HarmonicContent.closure` measures how well
#: the propagation reproduced the engine's multiplier (``|x(T) - rho x(0)| / |x(0)|``).
STEPS_PER_SAMPLE = 8
#: :func:`harmonic_content` warns when a closure residual exceeds this: the shares may then be
#: blurred by the propagation error (raise ``steps_per_sample`` or propagate in a better frame).
CLOSURE_WARNING = 1e-3
#: ``|Im rho| <= this * |rho|``: a real multiplier (its own mode, real Floquet vector).
REAL_MULTIPLIER_TOLERANCE = 1e-9
#: A mode joins the branch it matches best only if their MAC is at least this; otherwise it starts
#: a new branch (ACDC's default threshold is of this size; 0.5 is the largest value below which two
#: orthogonal-ish shapes could both claim one branch).
MIN_MAC = 0.5

#: Gauss-Legendre nodes of the two-point Magnus-4 step.
_GAUSS = (0.5 - math.sqrt(3.0) / 6.0, 0.5 + math.sqrt(3.0) / 6.0)


@dataclass(frozen=True)
class HarmonicContent:
    """Fourier content of the periodic parts of Floquet solutions.

    Attributes
    ----------
    harmonics : ndarray of int, shape (S,)
        Harmonics ``j = k - k*`` (``-S/2 .. S/2 - 1``) relative to each vector's principal one: the
        columns of ``shares``.
    shares : ndarray, shape (r, S)
        Per vector, ``|c_k|^2 / sum_k |c_k|^2`` of the output's periodic part at ``k = k* + j``.
    principal : ndarray of int, shape (r,)
        ``k*``: the harmonic with the largest share, relative to the base exponent ``log(rho) / T`` (of its
        aliases ``k* + m S``, the one chosen by ``centre``).
    closure : ndarray, shape (r,)
        ``|x(T) - rho x(0)| / |x(0)|`` of this module's own propagation (a check on it).
    samples : int
    steps : int
        Magnus-4 steps per period.
    """

    harmonics: np.ndarray
    shares: np.ndarray
    principal: np.ndarray
    closure: np.ndarray
    samples: int
    steps: int


def _propagate(P: PeriodicMatrixFunction, Y0: np.ndarray, samples: int, steps_per_sample: int) -> np.ndarray:
    """``Y(t_j)``, ``t_j = j T / samples`` (``j = 0 .. samples``), of ``Y' = P Y`` by Magnus-4 steps."""
    T = P.period
    h = T / (samples * steps_per_sample)
    out = np.empty((samples + 1,) + Y0.shape, dtype=complex)
    out[0] = Y = Y0.astype(complex)
    base = np.arange(steps_per_sample) * h
    for j in range(samples):
        t0 = j * steps_per_sample * h + base
        A = P.evaluate(np.concatenate([t0 + _GAUSS[0] * h, t0 + _GAUSS[1] * h]))
        A1, A2 = A[:steps_per_sample], A[steps_per_sample:]
        Om = 0.5 * h * (A1 + A2) + (math.sqrt(3.0) / 12.0) * h * h * (A2 @ A1 - A1 @ A2)
        E = scipy.linalg.expm(Om)
        for k in range(steps_per_sample):
            Y = E[k] @ Y
        out[j + 1] = Y
    return out


def harmonic_content(P: Any, vectors: np.ndarray, multipliers: np.ndarray, *, period: Optional[float] = None,
                     samples: int = HARMONIC_SAMPLES, steps_per_sample: int = STEPS_PER_SAMPLE,
                     basis: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                     output: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                     centre: Optional[np.ndarray] = None) -> HarmonicContent:
    """Fourier content of each Floquet solution's periodic part (the rule of the module docstring).

    Parameters
    ----------
    P : periodic matrix
        ``t -> (n, n)`` (or an object with ``period`` and ``evaluate(times)``), the system the
        solutions are propagated in.
    vectors : ndarray, shape (N, r)
        Floquet vectors (eigenvectors of the monodromy matrix) in the *state* coordinates.
    multipliers : ndarray, shape (r,)
        Their multipliers.
    period : float, optional
        When ``P`` carries none.
    samples : int
        Even number of samples per period.
    steps_per_sample : int
        Magnus-4 steps between samples.
    basis : callable, optional
        ``times -> (m, N, n)``: state ``x = V(t) w`` of the propagated coordinates ``w`` of ``P``
        (e.g. a frozen-modal frame, in which a stiff ``P`` is nearly constant); default identity.
    output : callable, optional
        ``times -> (m, p, N)``: the output ``y = C(t) x`` whose harmonics are counted (e.g. the
        displacements in the model's coordinates); default the state.
    centre : ndarray, shape (r,), optional
        A prior frequency magnitude per vector (rad/s, e.g. the frozen-time modal frequency).  ``S``
        samples determine the harmonic only modulo ``S`` (aliasing): of the aliases ``k* + m S`` of the
        largest share, the one whose frequency ``Im log(rho)/T + k Omega`` lies nearest ``+centre`` or
        ``-centre`` is taken (a stiff structural mode of a slowly turning machine lies far above
        ``S Omega / 2``; which sign the vector turns with is not known beforehand).  Without it the alias
        in ``-S/2 .. S/2 - 1``.

    Returns
    -------
    HarmonicContent

    Raises
    ------
    ValueError
        Bad ``samples``/``steps_per_sample``, shapes that do not match, a zero multiplier.
    """
    Pw = PeriodicMatrixFunction(P, period)
    S = int(samples)
    if S < 4 or S % 2:
        raise ValueError(f"samples must be an even integer >= 4, got {samples!r}")
    if int(steps_per_sample) < 1:
        raise ValueError(f"steps_per_sample must be >= 1, got {steps_per_sample!r}")
    X0 = np.atleast_2d(np.asarray(vectors, dtype=complex))
    mu = np.atleast_1d(np.asarray(multipliers, dtype=complex))
    if X0.shape[1] != mu.size:
        raise ValueError(f"{X0.shape[1]} vectors but {mu.size} multipliers")
    if np.any(mu == 0):
        raise ValueError("a zero multiplier has no Floquet exponent")
    T = Pw.period
    times = np.arange(S + 1) * (T / S)
    if basis is not None:
        V = np.asarray(basis(times))
        W0 = np.linalg.solve(V[0], X0)
    else:
        V, W0 = None, X0
    if W0.shape[0] != Pw.n:
        raise ValueError(f"vectors have {W0.shape[0]} rows in the propagated coordinates, P is {Pw.n} x {Pw.n}")
    W = _propagate(Pw, W0, S, int(steps_per_sample))
    X = W if V is None else np.einsum("mij,mjr->mir", V, W)
    norm0 = np.linalg.norm(X[0], axis=0)
    closure = np.linalg.norm(X[S] - X[0] * mu[None, :], axis=0) / np.where(norm0 > 0, norm0, 1.0)
    Y = X if output is None else np.einsum("mpi,mir->mpr", np.asarray(output(times)), X)
    lam0 = np.log(mu) / T
    Om = 2.0 * math.pi / T
    periodic = Y[:S] * np.exp(-np.outer(times[:S], lam0))[:, None, :]
    c = np.fft.fft(periodic, axis=0) / S  # (S, p, r); row m: harmonic m (mod S)
    power = np.sum(np.abs(c) ** 2, axis=1).T  # (r, S)
    total = power.sum(axis=1, keepdims=True)
    power = power / np.where(total > 0, total, 1.0)
    top = np.argmax(power, axis=1)  # (mod S)
    principal = ((top + S // 2) % S) - S // 2
    if centre is not None:
        prior = np.abs(np.asarray(centre, dtype=float))
        for i in range(mu.size):
            # the aliases k = top + m S around +-prior; keep the one nearest either
            cand = []
            for target in (prior[i], -prior[i]):
                m = math.floor((target - lam0[i].imag) / Om - top[i]) // S
                cand += [top[i] + (m + d) * S for d in (0, 1)]
            principal[i] = min(cand, key=lambda k: min(abs(lam0[i].imag + k * Om - prior[i]),
                                                        abs(lam0[i].imag + k * Om + prior[i])))
    rel = np.arange(-(S // 2), S // 2)
    shares = np.take_along_axis(power, (top[:, None] + rel[None, :]) % S, axis=1)
    worst = float(np.max(closure)) if closure.size else 0.0
    if worst > CLOSURE_WARNING:
        warnings.warn(f"harmonic content: the propagation reproduces the multipliers only to {worst:.1e} "
                      f"(relative); the harmonic shares may be blurred (raise steps_per_sample or propagate "
                      f"in a frozen-modal frame)", RuntimeWarning, stacklevel=2)
    return HarmonicContent(harmonics=rel, shares=shares, principal=principal, closure=closure, samples=S,
                           steps=S * int(steps_per_sample))


@dataclass(frozen=True)
class FloquetModes:
    """One point of a Campbell diagram: one mode per conjugate pair of multipliers, with its principal frequency.

    Attributes
    ----------
    period : float
        ``T``; ``omega = 2 pi / T``.
    multipliers : ndarray, shape (r,)
        The multiplier of each mode (the member of a conjugate pair whose principal frequency is >= 0).
    exponents : ndarray, shape (r,)
        Principal Floquet exponents ``log(rho) / T + i k* Omega``.
    frequencies : ndarray, shape (r,)
        ``Im`` of the principal exponents (rad/s, >= 0).
    damping_ratios : ndarray, shape (r,)
        ``-Re(lambda) / |lambda|``.
    shapes : ndarray, shape (r, p)
        Mode shapes for tracking (``shape_map`` applied to the Floquet vector at ``t = 0``).
    harmonics : tuple of dict
        Per mode ``{k - k*: share}`` of the harmonics with share >= ``min_share``: the mode is seen at
        ``frequency + (k - k*) Omega`` with that share of its output's power.
    closure : ndarray, shape (r,)
        :attr:`HarmonicContent.closure` of each mode.
    labels : tuple of str
        Optional names (e.g. the frozen-mode labels of the model), ``""`` where none.
    """

    period: float
    multipliers: np.ndarray
    exponents: np.ndarray
    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray = field(repr=False)
    harmonics: tuple = ()
    closure: np.ndarray = field(default_factory=lambda: np.zeros(0))
    labels: tuple = ()

    @property
    def omega(self) -> float:
        return 2.0 * math.pi / self.period

    def __len__(self) -> int:
        return int(self.multipliers.size)


def _conjugate_pairs(mu: np.ndarray) -> tuple[list, list]:
    """``(real indices, [(i, j) pairs with Im mu_i > 0 and mu_j ~ conj(mu_i)])``."""
    real = [i for i, m in enumerate(mu) if abs(m.imag) <= REAL_MULTIPLIER_TOLERANCE * abs(m)]
    upper = [i for i, m in enumerate(mu) if i not in real and m.imag > 0]
    lower = [i for i, m in enumerate(mu) if i not in real and m.imag < 0]
    pairs = []
    if upper:
        if len(lower) != len(upper):
            raise ValueError("the multipliers of a real system come in conjugate pairs; these do not")
        cost = np.abs(mu[upper][:, None] - np.conj(mu[lower])[None, :])
        r, c = linear_sum_assignment(cost)
        pairs = [(upper[a], lower[b]) for a, b in zip(r, c)]
    return real, pairs


def floquet_modes(P: Any, monodromy: np.ndarray, *, period: Optional[float] = None,
                  shape_map: Optional[np.ndarray] = None, labels: Optional[Sequence[str]] = None,
                  centres: Optional[Sequence[float]] = None, min_share: float = 0.01,
                  **harmonic_options: Any) -> FloquetModes:
    """Modes of one Campbell point from a monodromy matrix (rules in the module docstring).

    Parameters
    ----------
    P : periodic matrix
        The system (or a frame of it, with ``basis=`` in ``harmonic_options``) for
        :func:`harmonic_content`.
    monodromy : ndarray, shape (N, N)
        ``Phi(T)`` in the state coordinates.
    period : float, optional
    shape_map : ndarray, shape (p, N), optional
        Maps a Floquet vector at ``t = 0`` to the shape used for tracking (e.g. the displacement
        rows in the model's coordinates); default the whole vector.
    labels : sequence of str, optional
        One name per eigenvalue of ``monodromy`` in ``numpy.linalg.eig`` order (kept per mode).
    centres : sequence of float, optional
        A prior frequency (rad/s, >= 0) per eigenvalue in the same order, e.g. the frozen-time modal
        frequency the mode resembles: the ``centre`` of :func:`harmonic_content` (for the member of a
        conjugate pair with ``Im rho > 0``; see there).
    min_share : float
        Harmonics with a smaller share are left out of :attr:`FloquetModes.harmonics`.
    **harmonic_options
        ``samples``, ``steps_per_sample``, ``basis``, ``output`` of :func:`harmonic_content`.
    """
    Pw = PeriodicMatrixFunction(P, period)
    T = Pw.period
    Om = 2.0 * math.pi / T
    Phi = np.asarray(monodromy, dtype=float)
    mu, X = np.linalg.eig(Phi)
    real, pairs = _conjugate_pairs(mu)
    keep = list(real) + [i for i, _ in pairs]
    Xk = X[:, keep].astype(complex)
    for col, i in enumerate(keep):
        if i in real:  # a real eigenvector (eig may return it with a complex phase)
            v = Xk[:, col]
            v = v * np.exp(-1j * np.angle(v[np.argmax(np.abs(v))]))
            Xk[:, col] = v.real
    prior = None if centres is None else np.abs(np.asarray(centres, dtype=float))[keep]
    hc = harmonic_content(P, Xk, mu[keep], period=T, centre=prior, **harmonic_options)
    lam = np.log(mu[keep]) / T + 1j * Om * hc.principal
    shapes = Xk.T if shape_map is None else (np.asarray(shape_map) @ Xk).T
    harmonics = []
    for col, i in enumerate(keep):
        share = {int(j): float(s) for j, s in zip(hc.harmonics, hc.shares[col]) if s >= min_share}
        if lam[col].imag < 0:  # report the conjugate: its principal frequency is the positive one
            lam[col] = np.conj(lam[col])
            shapes[col] = np.conj(shapes[col])
            share = {-k: s for k, s in share.items()}
            if i not in real:
                mu[i] = np.conj(mu[i])
        harmonics.append(dict(sorted(share.items(), key=lambda kv: -kv[1])))
    freq = lam.imag.copy()
    absl = np.abs(lam)
    zeta = np.where(absl > 0, -lam.real / np.where(absl > 0, absl, 1.0), 0.0)
    names = tuple(labels[i] if labels is not None else "" for i in keep)
    order = np.argsort(freq, kind="stable")
    return FloquetModes(period=T, multipliers=mu[keep][order], exponents=lam[order], frequencies=freq[order],
                        damping_ratios=zeta[order], shapes=shapes[order],
                        harmonics=tuple(harmonics[i] for i in order), closure=hc.closure[order],
                        labels=tuple(names[i] for i in order))


def mac_matrix(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``MAC[i, j] = |a_i^H b_j|^2 / ((a_i^H a_i)(b_j^H b_j))`` for shapes in the rows of ``A`` and ``B``."""
    A = np.atleast_2d(np.asarray(A, dtype=complex))
    B = np.atleast_2d(np.asarray(B, dtype=complex))
    num = np.abs(np.conj(A) @ B.T) ** 2
    na = np.real(np.sum(np.conj(A) * A, axis=1))
    nb = np.real(np.sum(np.conj(B) * B, axis=1))
    den = np.outer(na, nb)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


@dataclass(frozen=True)
class Tracking:
    """Branches of a Campbell diagram.

    Attributes
    ----------
    branches : tuple of ndarray
        Per point, the branch number of each of its modes (in the point's order).
    macs : tuple of ndarray
        Per point, each mode's MAC with the branch's shape at its previous appearance (``nan`` for the
        first point of a branch).
    n_branches : int
    min_mac : float
    """

    branches: tuple
    macs: tuple
    n_branches: int
    min_mac: float

    def index(self, point: int, branch: int) -> Optional[int]:
        """The mode of ``point`` on ``branch`` (``None`` where the branch is absent)."""
        hit = np.flatnonzero(self.branches[point] == branch)
        return int(hit[0]) if hit.size else None


def track_modes(shapes: Sequence[np.ndarray], *, min_mac: float = MIN_MAC) -> Tracking:
    """Follow modes from point to point by MAC and an optimal one-to-one assignment.

    Parameters
    ----------
    shapes : sequence of ndarray, shape (r_i, p)
        Mode shapes at each point (rows), the points in the order of the sweep.
    min_mac : float
        Smallest MAC with which a mode continues a branch (:data:`MIN_MAC`).

    Returns
    -------
    Tracking

    Notes
    -----
    Each branch remembers its last shape; a point's modes are assigned to all branches seen so far
    (so a branch that is absent for some points -- two real multipliers inside an instability band
    replacing one conjugate pair -- can be continued after it) by
    :func:`scipy.optimize.linear_sum_assignment` on ``1 - MAC``.  Assigned pairs with a MAC below
    ``min_mac`` and unassigned modes start new branches, numbered in order of appearance (within a
    point by the order of its modes).
    """
    if not (0.0 <= float(min_mac) <= 1.0):
        raise ValueError(f"min_mac must lie in [0, 1], got {min_mac!r}")
    last: list = []  # shape of each branch at its last appearance
    branches, macs = [], []
    for i, S in enumerate(shapes):
        S = np.atleast_2d(np.asarray(S, dtype=complex)) if len(S) else np.zeros((0, 1), dtype=complex)
        ids = np.full(S.shape[0], -1, dtype=int)
        mac = np.full(S.shape[0], np.nan)
        if last and S.shape[0]:
            M = mac_matrix(np.array(last), S)
            rows, cols = linear_sum_assignment(1.0 - M)
            for b, j in zip(rows, cols):
                if M[b, j] >= min_mac:
                    ids[j], mac[j] = b, M[b, j]
        for j in range(S.shape[0]):
            if ids[j] < 0:
                ids[j] = len(last)
                last.append(S[j])
            else:
                last[ids[j]] = S[j]
        branches.append(ids)
        macs.append(mac)
    return Tracking(branches=tuple(branches), macs=tuple(macs), n_branches=len(last), min_mac=float(min_mac))


@dataclass(frozen=True)
class CampbellResult:
    """A Campbell diagram: modes at each speed and their branches.

    Attributes
    ----------
    omegas : ndarray, shape (m,)
        Rotation speeds (rad/s), in sweep order.
    points : tuple of FloquetModes
    tracking : Tracking
    """

    omegas: np.ndarray
    points: tuple
    tracking: Tracking

    def branch(self, b: int) -> dict:
        """Arrays over the speeds (``nan`` where the branch is absent): ``frequency`` (rad/s),
        ``damping_ratio``, ``modulus``, ``mac`` and the first non-empty ``label``."""
        m = len(self.points)
        f, z, r, mac = (np.full(m, np.nan) for _ in range(4))
        label = ""
        for i, pt in enumerate(self.points):
            j = self.tracking.index(i, b)
            if j is None:
                continue
            f[i], z[i], r[i] = pt.frequencies[j], pt.damping_ratios[j], abs(pt.multipliers[j])
            mac[i] = self.tracking.macs[i][j]
            if not label and pt.labels:
                label = pt.labels[j]
        return {"frequency": f, "damping_ratio": z, "modulus": r, "mac": mac, "label": label}


def campbell(omegas: Sequence[float], points: Sequence[FloquetModes], *, min_mac: float = MIN_MAC) -> CampbellResult:
    """Track the modes of a sweep (:func:`track_modes` on each point's shapes).

    Raises
    ------
    ValueError
        ``omegas`` and ``points`` of different lengths, or a point whose period is not ``2 pi / omega``.
    """
    w = np.asarray(omegas, dtype=float)
    pts = tuple(points)
    if w.size != len(pts):
        raise ValueError(f"{w.size} speeds but {len(pts)} points")
    for wi, p in zip(w, pts):
        if abs(p.omega - wi) > 1e-9 * wi:
            raise ValueError(f"a point's period {p.period!r} is not 2 pi / {wi!r}")
    return CampbellResult(omegas=w, points=pts, tracking=track_modes([p.shapes for p in pts], min_mac=min_mac))
