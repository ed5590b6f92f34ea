"""Constraint-correct linearisation of a model file along its periodic orbit.

Maths
-----
About the orbit ``q0(t), lambda0(t), tau0(t)`` (:func:`linearize.periodic_orbit.find_orbit`)
the drives are released and driven by feed-forward + PD,
``tau = tau0(t) - kp B^T dq - kd B^T dq'`` (``B`` column ``d``: +1 at marker
m1's coordinate, -1 at m0's).  With ``q = q0 + dq``, ``lambda = lambda0 + dlambda``::

    M dq'' + C_f dq' + K_f dq + C_q^T dlambda = B u,     C_q dq = 0,

    K_f = d/dq [M(q) q0'' - f(q, q0', t) + C_q(q, t)^T lambda0] + B kp B^T
    C_f = -df/dq' + B kd B^T

(every term: mass-matrix dependence, constraint-reaction stiffness, rheonomic
constraints through ``C_q(q0(t), t)``; the feed-forward ``tau0(t)`` is a
time-only load and drops out; the drive constraints are linear, so they have
no reaction stiffness).

Independent coordinates: ``dq = N(t) z`` with ``N(t)`` a smooth T-periodic
basis of ``null C_q(q0(t), t)`` whose first ``d`` coordinates are the driven
coordinates themselves (``B^T N = [I, 0]``, see :func:`null_space_basis`) and
whose other columns are orthonormal.  Premultiplying by ``N^T``
removes ``dlambda`` (``N^T C_q^T = 0``)::

    M_z = N^T M N
    C_z = N^T (2 M N' + C_f N)
    K_z = N^T (M N'' + C_f N' + K_f N)
    B_z = N^T B,   (B_z)_t = N'^T B   (driven coordinate B^T dq = B_z^T z, rate B_z^T z' + (B_z)_t^T z)

Construction of ``N`` at the Fourier samples (discrete parallel transport):
``N_0`` = an orthonormal null basis ``Q_0`` at ``t_0``;
``N_{k+1} = Q_{k+1} polar(Q_{k+1}^T N_k)`` (the orthonormal null basis at
``t_{k+1}`` closest to ``N_k``, independent of the choice of ``Q_{k+1}``);
after one lap ``N_K = N_0 H`` with ``H`` orthogonal (the holonomy).  With
``G = log H`` (real, skew) the samples ``N_k expm(-G t_k / T)`` are
T-periodic; the transport commutes with right multiplication by orthogonal
matrices, so they are samples of a smooth periodic function, and ``N'``,
``N''`` are their spectral derivatives.  The transport runs in a co-rotating
frame (:func:`corotating_frame`, ``N = F(t) N_hat``): any periodic basis gives
the same multipliers, but in the co-rotating one the axial stiffness of a
swinging beam does not rotate.  ``det H = -1`` (a non-orientable
tangent bundle along the orbit) has no real logarithm: it is reported as an
error.

Propagator convergence (measured, single link, Table 3 gains): no choice of
*configuration* coordinates makes the stiff part of the first-order ``P(t)``
constant.  In these coordinates and in the hand-derived hub frame alike the
frozen eigenvalues of ``P(t)`` are nearly constant (``|Im lambda|`` varies
< 1e-3 relative over the period at 8 pi), but the frozen eigenvectors turn with
the motion (the stiff block of ``P`` in the modal coordinates of its mean
varies by 0.4-1 of ``|lambda|`` at 8 pi in both), and the exponential midpoint
product converges erratically in both (2 elements, 8 pi, relative error of the
largest damped multiplier, 0.896, at 256 / 1024 / 4096 steps: 1.2e-4 / 1.3e-5 /
3e-7 here, 8e-3 / 2.9e-4 / 5.4e-6 in the hub frame; the hub multiplier itself,
0.395, is 1.1e-2 off at 512 steps here, while the step-doubling estimate reads
4.5e-4).  The cure is a *state-space* frame,
:mod:`stability.modal` (frozen-eigenvector basis ``x = V(t) y``), which
:func:`linearize.analysis.analyze` uses by default.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any, Sequence

import numpy as np
import scipy.linalg

from linearize.fourier import antiperiodic_differentiation_matrices, differentiation_matrices
from linearize.periodic_orbit import PeriodicOrbit
from linearize.system import LinearizedPeriodicSystem

__all__ = ["ConstraintBasisError", "RANK_TOLERANCE", "corotating_frame", "linearize_orbit", "null_space_basis"]

logger = logging.getLogger(__name__)

#: Singular values of ``C_q`` below this times the largest count as zero (rank).
RANK_TOLERANCE = 1e-10


class ConstraintBasisError(RuntimeError):
    """No smooth periodic basis of the constraint tangent space exists or the rank changes."""


def _null(Cq: np.ndarray, n: int) -> np.ndarray:
    if Cq.shape[0] == 0:
        return np.eye(n)
    _, s, vh = np.linalg.svd(Cq)
    rank = int(np.sum(s > RANK_TOLERANCE * max(s[0], 1e-300))) if s.size else 0
    return vh[rank:].T


def _row_space(Cq: np.ndarray) -> np.ndarray:
    """Orthonormal basis ``V`` (rows, shape ``(rank, n)``) of the row space of ``Cq``, rank by
    :data:`RANK_TOLERANCE` as in :func:`_null`: the projector onto ``null Cq`` is ``I - V^T V``
    (an economy SVD, ``O(m^2 n)``, instead of the full ``n x n`` null basis)."""
    if Cq.shape[0] == 0:
        return np.zeros((0, Cq.shape[1]))
    _, s, vh = np.linalg.svd(Cq, full_matrices=False)
    rank = int(np.sum(s > RANK_TOLERANCE * max(s[0], 1e-300))) if s.size else 0
    return vh[:rank]


def _project(V: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``(I - V^T V) X``: ``X`` projected onto the null space of the rows ``V`` (orthonormal)."""
    return X - V.T @ (V @ X)


#: The closed-form transport step (:func:`_transport_step`) is used while the largest
#: squared sine of the principal angles between ``N_k`` and the next null space is below
#: this (the condition of ``(I - U)^(-1/2)`` is then <= 1.4); a larger turn (a coarse
#: sampling of a fast-turning constraint) takes the SVD polar factor.
TRANSPORT_CLOSED_FORM_LIMIT = 0.5


def _transport_step(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``polar(P W)`` with ``P = I - V^T V`` (``V``: orthonormal rows, ``W``: orthonormal columns).

    Maths: with ``G = V W`` (``rank x r``), ``(P W)^T (P W) = I - G^T G``, so the polar
    factor is ``P W (I - G^T G)^(-1/2) = P W (I + G^T E diag(phi(mu)) E^T G)`` where
    ``G G^T = E diag(mu) E^T`` and ``phi(mu) = ((1 - mu)^(-1/2) - 1) / mu
    = 1 / (sqrt(1 - mu) (1 + sqrt(1 - mu)))``: a ``rank x rank`` eigenproblem and
    ``O(n r rank)`` products instead of the SVD of an ``n x r`` matrix (64 elements: 263 x 258,
    ~15 ms per sample).  Falls back to the SVD beyond :data:`TRANSPORT_CLOSED_FORM_LIMIT`.
    """
    G = V @ W
    X = W - V.T @ G
    if G.shape[0] == 0:
        return X
    mu, E = np.linalg.eigh(G @ G.T)
    if not float(np.max(mu)) <= TRANSPORT_CLOSED_FORM_LIMIT:
        return _polar(X)
    root = np.sqrt(1.0 - mu)
    phi = 1.0 / (root * (1.0 + root))
    return X + (X @ G.T) @ ((E * phi) @ E.T) @ G


def _polar(W: np.ndarray) -> np.ndarray:
    """Orthonormal polar factor ``U V^T`` of ``W = U S V^T`` (thin SVD; ``W`` square or tall)."""
    u, _, vt = np.linalg.svd(W, full_matrices=False)
    return u @ vt


#: :func:`corotating_frame` co-rotates free planar points with their best-fit rotation about the origin only
#: when its samples are resolved about as well as the points' own (spectral tail, :func:`_spectral_tail`,
#: at most this factor above theirs).  The basis derivatives are spectral derivatives of ``F N_hat``: a
#: frame that the samples alias makes them wrong, not merely inaccurate (measured: an unbalanced rotor
#: whose whirl passes 5e-5 m from the origin, multipliers 0.55 off with the fit, 4e-10 without).
FRAME_RESOLUTION = 100.0


def _spectral_tail(z: np.ndarray) -> float:
    """Largest, over the columns of ``z`` (``(K, p)`` samples over one period), of the share of the upper
    half of the resolved harmonics (``K/4 <= |k| <= K/2``) in the sum of all harmonic amplitudes: ~eps for
    a function the samples resolve, O(1) for one they alias."""
    c = np.abs(np.fft.fft(np.asarray(z, dtype=complex), axis=0))
    k = np.abs(np.fft.fftfreq(c.shape[0], 1.0 / c.shape[0]))
    total = np.sum(c, axis=0)
    share = np.sum(c[k >= c.shape[0] / 4], axis=0) / np.maximum(total, 1e-300)
    return float(np.max(share)) if share.size else 0.0


def corotating_frame(orbit: PeriodicOrbit) -> np.ndarray:
    """Block rotations ``R(theta_i(t))`` of the planar vector coordinates, shape ``(K, n, n)``.

    Each planar vector (node position, ANCF slope) is rotated by the angle its
    node has turned since ``t = 0``: the slope direction of an ANCF node, the
    angle of a rigid body, else the mass-weighted best-fit (2D Kabsch)
    rotation of all planar vectors about the origin -- when the samples resolve it
    (:data:`FRAME_RESOLUTION`; a point whirling close round the origin turns its fit
    through half a turn between two samples), else the identity.  Coordinates that are not planar vectors
    keep the identity.  Any T-periodic orthogonal frame gives the same
    multipliers; in this one the stiff element stiffness of a swinging beam is
    nearly constant (it turns only with the beam's curvature), which the
    exponential-midpoint propagator needs for few steps.
    """
    Kn, n = orbit.q.shape
    F = np.broadcast_to(np.eye(n), (Kn, n, n)).copy()
    pairs = list(orbit.planar_pairs)
    if not pairs:
        return F
    Q = orbit.q
    ix = np.array([p[0] for p in pairs])
    iy = np.array([p[1] for p in pairs])
    rx = np.array([p[2] for p in pairs])
    ry = np.array([p[3] for p in pairs])
    mdiag = np.abs(np.diagonal(orbit.tangent.M[0]))
    w = mdiag[ix] + mdiag[iy]
    x = Q[:, ix] + rx
    y = Q[:, iy] + ry
    fit = np.arctan2(np.sum(w * (x[0] * y - y[0] * x), axis=1), np.sum(w * (x[0] * x + y[0] * y), axis=1))
    if any(ang[0] == "fit" for *_, ang in pairs):
        tail_fit, tail_points = _spectral_tail(np.exp(1j * fit)[:, None]), _spectral_tail(x + 1j * y)
        if tail_fit > FRAME_RESOLUTION * max(tail_points, 1e-14):
            # e.g. one point whirling on a circle that passes close to the origin: its best-fit rotation
            # about the origin is its polar angle, which swings through ~pi within a sample or two
            logger.info("the best-fit rotation of the planar points is not resolved by the %d samples (spectral "
                        "tail %.1e, the points' own %.1e): no co-rotation for them", Kn, tail_fit, tail_points)
            fit = np.zeros(Kn)
    for p_idx, (a, b, _, _, ang) in enumerate(pairs):
        if ang[0] == "slope":
            _, i_sx, i_sy, r_sx, r_sy = ang
            sx, sy = Q[:, i_sx] + r_sx, Q[:, i_sy] + r_sy
            theta = np.unwrap(np.arctan2(sy, sx) - math.atan2(sy[0], sx[0]))
        elif ang[0] == "rotation":
            theta = Q[:, ang[1]] - Q[0, ang[1]]
        else:
            theta = fit
        c, s_ = np.cos(theta), np.sin(theta)
        F[:, a, a] = c
        F[:, a, b] = -s_
        F[:, b, a] = s_
        F[:, b, b] = c
    return F


def _transport(C_all: np.ndarray, times: np.ndarray, period: float, signs: "np.ndarray | None" = None) -> np.ndarray:
    """Periodic, parallel-transported orthonormal bases of ``null C_all[k]`` (see the module notes).

    The step ``N_{k+1} = Q_{k+1} polar(Q_{k+1}^T N_k)`` is formed as the polar factor of the
    projection ``P_{k+1} N_k`` (``P = Q Q^T``, the same matrix: ``P N_k = Q_{k+1} (Q_{k+1}^T
    N_k)`` and the polar factor of ``Q A`` is ``Q polar(A)``), so only ``Q_0`` is formed, and
    in closed form (:func:`_transport_step`).  With ``signs`` (``S = diag(signs)``, the derivative of
    the orbit map ``g``: the null space at ``T`` is ``S`` times the one at 0) the holonomy is measured
    against ``S Q_0`` and the samples close up to ``S``: ``N(t + T) = S N(t)``.
    """
    Kn, _, n = C_all.shape
    Vs = [_row_space(C_all[k]) for k in range(Kn)]
    ranks = sorted({V.shape[0] for V in Vs})
    if len(ranks) > 1:
        raise ConstraintBasisError(f"the rank of the constraint Jacobian changes along the orbit ({ranks}): "
                                   f"a singular configuration, redundant constraints or a drive the "
                                   f"constraints lock")
    Q0 = _null(C_all[0], n)
    r = Q0.shape[1]
    W = np.empty((Kn, n, r))
    W[0] = Q0
    for k in range(Kn - 1):
        W[k + 1] = _transport_step(Vs[k + 1], W[k])
    if r:
        Q0T = Q0 if signs is None else signs[:, None] * Q0  # the basis one period on: S Q_0
        H = _polar(Q0T.T @ W[Kn - 1])  # W_K = S Q_0 H and W_0 = Q_0
        if np.linalg.det(H) < 0:
            raise ConstraintBasisError("the constraint tangent space is not orientable along the orbit "
                                       "(holonomy with det -1): no periodic basis")
        # the principal logarithm where it is real; half turns (eigenvalues -1, e.g. Euler parameters)
        # as +-pi rotations (real Schur form: no scipy.linalg.logm, whose import costs ~40 ms)
        G = _rotation_log(H)
        G = 0.5 * (G - G.T)
        if not np.allclose(scipy.linalg.expm(G), H, atol=1e-10):
            raise ConstraintBasisError("no real logarithm of the holonomy of the constraint tangent space")
        for k in range(Kn):
            W[k] = W[k] @ scipy.linalg.expm(-G * times[k] / period)
    return W


def _rotation_log(H: np.ndarray) -> np.ndarray:
    """A real skew logarithm of a rotation ``H`` (orthogonal, ``det H = 1``): the principal one
    (angles in ``(-pi, pi)``) where no eigenvalue is -1, and half turns for the eigenvalues -1 that
    the principal ``logm`` leaves complex.

    Maths: the real Schur form of the normal matrix ``H`` is ``Z T Z^T`` with ``T`` block diagonal, 2 x 2
    blocks ``[[c, s], [-s, c]] = expm(a [[0, 1], [-1, 0]])`` (``a = atan2(s, c)``) and 1 x 1 blocks
    ``+-1``; ``det H = 1`` makes the ``-1`` blocks even in number, and each pair of them is the half turn
    ``expm(pi [[0, 1], [-1, 0]])``.  Returns ``Z L Z^T`` (``L`` those logarithms); the caller checks it.
    """
    T, Z = scipy.linalg.schur(H, output="real")
    r = H.shape[0]
    L = np.zeros((r, r))
    halves = []
    i = 0
    while i < r:
        if i + 1 < r and abs(T[i + 1, i]) > 1e-12:
            a = math.atan2(T[i, i + 1], T[i, i])
            L[i, i + 1], L[i + 1, i] = a, -a
            i += 2
        else:
            if T[i, i] < 0.0:
                halves.append(i)
            i += 1
    for a, b in zip(halves[0::2], halves[1::2]):
        L[a, b], L[b, a] = math.pi, -math.pi
    return Z @ L @ Z.T


def null_space_basis(Cq: np.ndarray, times: np.ndarray, period: float, frame: "np.ndarray | None" = None,
                     drives: "np.ndarray | None" = None,
                     stiffness: "np.ndarray | None" = None,
                     signs: "np.ndarray | None" = None,
                     grid: "Any | None" = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth periodic basis ``N`` of ``null C_q`` and its derivatives at the samples.

    Parameters
    ----------
    Cq : ndarray, shape (K, m, n)
        Constraint Jacobians at the sample times.
    times : ndarray, shape (K,)
        ``k T / K``.
    period : float
    frame : ndarray, shape (K, n, n), optional
        T-periodic orthogonal matrices ``F(t)``: the construction runs on
        ``C_q F`` and the basis is ``N = F N_hat`` (see :func:`corotating_frame`).
    drives : ndarray, shape (n, d), optional
        ``B``.  The first ``d`` columns of ``N`` are then
        ``N_D = P B (B^T P B)^-1`` (``P`` the orthogonal projector onto
        ``null C_q``), the remaining ones an orthonormal transported basis of
        ``null [C_q; B^T]``: the first ``d`` independent coordinates *are* the
        driven coordinates (``B^T N = [I, 0]`` at every t), so the PD gains act
        on constant coordinates (no fast rotation of the stiff hub damping in
        ``z``-space, which the exponential-midpoint propagator would need tiny
        steps to follow).
    stiffness : ndarray, shape (K, n, n), optional
        With ``drives``: the drive columns become the *statically condensed*
        shapes ``N_D + W a`` with ``W^T K (N_D + W a) = 0`` (the motion the
        rest of the system makes under a unit drive displacement, e.g. the
        rigid rotation of a clamped beam), when ``W^T K W`` (symmetric part)
        is positive definite at every sample; otherwise the minimal-norm
        shapes are kept.  A drive coordinate then couples to the others
        through inertia only, not through the stiff elastic terms (measured
        on the single link: the propagator needs ~30 times fewer steps).
    signs : ndarray, shape (n,), optional
        ``S = diag(signs)``, the derivative of an orbit map ``g`` with sign flips (the Euler parameters
        of a body that turns, :attr:`linearize.periodic_orbit.PeriodicOrbit.signs`): the basis is then
        *S-periodic*, ``N(t + T) = S N(t)`` (rows with sign -1 antiperiodic, differentiated as such), so
        that the independent coordinates' matrices ``N^T M N``, ... are T-periodic (``M(t + T) = S M(t) S``)
        and their monodromy is the orbit map's ``S^-1 Phi(T)``.
    grid : PiecewiseGrid, optional
        The orbit's piecewise sampling (declared breakpoints, :attr:`PeriodicOrbit.grid`): the basis is
        differentiated with its matrices instead of the trigonometric ones.  Not combined with ``signs``.

    Returns
    -------
    N, N_t, N_tt : ndarray, shape (K, n, r)

    Raises
    ------
    ConstraintBasisError
        If the rank changes along the orbit, a drive is locked by the
        constraints, or the holonomy is a reflection.
    """
    Kn, m, n = Cq.shape
    F = frame if frame is not None else np.broadcast_to(np.eye(n), (Kn, n, n))
    Ch = Cq @ F
    flips = signs is not None and np.any(np.asarray(signs) < 0)
    sg = np.asarray(signs, dtype=float) if flips else None
    if flips and frame is not None:
        # the frame must leave the sign-flipping coordinates alone (then it commutes with S and
        # N = F N_hat is S-periodic with N_hat); the co-rotating frame turns planar vectors only
        a = np.asarray(sg) < 0
        if not (np.allclose(F[:, a][:, :, a], np.eye(int(a.sum()))) and np.allclose(F[:, a][:, :, ~a], 0.0)
                and np.allclose(F[:, ~a][:, :, a], 0.0)):
            raise ConstraintBasisError("a frame that turns the sign-flipping coordinates has no S-periodic basis")
    if drives is None or drives.shape[1] == 0:
        N = _transport(Ch, times, period, sg)
    else:
        d = drives.shape[1]
        Bh = np.transpose(F, (0, 2, 1)) @ drives  # (K, n, d)
        W = _transport(np.concatenate([Ch, np.transpose(Bh, (0, 2, 1))], axis=1), times, period, sg)
        ND = np.empty((Kn, n, d))
        for k in range(Kn):
            PB = _project(_row_space(Ch[k]), Bh[k])
            G = Bh[k].T @ PB
            if np.linalg.cond(G) > 1.0 / RANK_TOLERANCE:
                raise ConstraintBasisError("a drive's coordinate is fixed by the model's constraints "
                                           "(the drive cannot move it)")
            ND[k] = np.linalg.solve(G.T, PB.T).T
        if stiffness is not None and W.shape[2]:
            Kh = np.transpose(F, (0, 2, 1)) @ stiffness @ F
            Kh = 0.5 * (Kh + np.transpose(Kh, (0, 2, 1)))
            WKW = np.transpose(W, (0, 2, 1)) @ Kh @ W
            try:
                chol = [scipy.linalg.cho_factor(WKW[k]) for k in range(Kn)]
            except np.linalg.LinAlgError:
                chol = None
                logger.debug("locked-drive stiffness not positive definite: minimal-norm drive shapes kept")
            if chol is not None:
                for k in range(Kn):
                    a = scipy.linalg.cho_solve(chol[k], -(W[k].T @ Kh[k] @ ND[k]))
                    ND[k] = ND[k] + W[k] @ a
        N = np.concatenate([ND, W], axis=2)
    if frame is not None:
        N = F @ N
    D1, D2 = differentiation_matrices(period, Kn) if grid is None else (grid.D1, grid.D2)
    flat = N.reshape(Kn, -1)
    N_t = (D1 @ flat).reshape(N.shape)
    N_tt = (D2 @ flat).reshape(N.shape)
    if flips:  # rows that change sign over a period are antiperiodic in t
        A1, A2 = antiperiodic_differentiation_matrices(period, Kn)
        a = np.flatnonzero(sg < 0)
        rows = N[:, a, :].reshape(Kn, -1)
        N_t[:, a, :] = (A1 @ rows).reshape(Kn, a.size, N.shape[2])
        N_tt[:, a, :] = (A2 @ rows).reshape(Kn, a.size, N.shape[2])
    return N, N_t, N_tt


def _gains(value: "float | Sequence[float]", d: int, name: str) -> np.ndarray:
    v = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
    if v.size == 1:
        v = np.full(d, float(v[0]))
    if v.size != d:
        raise ValueError(f"{name}: one value per drive ({d}) or one for all, got {v.size}")
    if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return v


def linearize_orbit(
    orbit: PeriodicOrbit,
    kp: "float | Sequence[float]" = 0.0,
    kd: "float | Sequence[float]" = 0.0,
    *,
    reaction_stiffness: bool = True,
) -> LinearizedPeriodicSystem:
    """Linearise a model about its periodic orbit in independent coordinates, drives released.

    Parameters
    ----------
    orbit : PeriodicOrbit
    kp, kd : float or sequence of float
        PD gains, one per drive or one for all (>= 0).
    reaction_stiffness : bool
        Keep ``d(C_q^T lambda0)/dq`` (default).  ``False`` only exists to show
        in a test what dropping it gets wrong.

    Returns
    -------
    LinearizedPeriodicSystem
        ``M, C, K`` (K, r, r), ``B, B_t`` (K, r, d), ``basis, basis_t`` (K, n, r).
    """
    tic = time.perf_counter()
    tb = orbit.tangent
    d = orbit.drive_vectors.shape[1]
    kpv = _gains(kp, d, "kp") if d else np.zeros(0)
    kdv = _gains(kd, d, "kd") if d else np.zeros(0)
    signs = getattr(orbit, "signs", None)
    flips = signs is not None and np.any(np.asarray(signs) < 0)
    grid = getattr(orbit, "grid", None)
    N, N_t, N_tt = null_space_basis(tb.Cq, orbit.times, orbit.period, frame=corotating_frame(orbit),
                                    drives=orbit.drive_vectors, stiffness=tb.K, signs=signs if flips else None,
                                    grid=grid)
    B = orbit.drive_vectors
    Kf = tb.K if reaction_stiffness else tb.K_force
    Kf = Kf + (B * kpv) @ B.T
    Cf = tb.C + (B * kdv) @ B.T
    M = tb.M
    NT = np.transpose(N, (0, 2, 1))
    Mz = NT @ M @ N
    Cz = NT @ (2.0 * M @ N_t + Cf @ N)
    Kz = NT @ (M @ N_tt + Cf @ N_t + Kf @ N)
    Bz = NT @ B
    Bz_t = np.transpose(N_t, (0, 2, 1)) @ B
    lin = LinearizedPeriodicSystem(
        period=orbit.period,
        times=orbit.times,
        M=0.5 * (Mz + np.transpose(Mz, (0, 2, 1))),
        C=Cz,
        K=Kz,
        kp=tuple(float(x) for x in kpv),
        kd=tuple(float(x) for x in kdv),
        coordinates=tuple(list(orbit.drive_names) + [f"z{i}" for i in range(N.shape[2] - d)]),
        hub_free=False,
        reference="periodic",
        orbit_residual=orbit.residual,
        elements=0,
        wall_time=0.0,
        B=Bz,
        B_t=Bz_t,
        drive_names=orbit.drive_names,
        basis=N,
        basis_t=N_t,
        breakpoints=tuple(getattr(orbit, "breakpoints", ()) or ()),
    )
    from dataclasses import replace

    lin = replace(lin, wall_time=time.perf_counter() - tic)
    logger.info("linearised %s: %d -> %d independent coordinates, %d drives (%.2f s)", orbit.model.name,
                orbit.size, N.shape[2], d, lin.wall_time)
    return lin
