"""Structured Newton matrix of the trigonometric collocation for large models.

The dense route of :mod:`linearize.periodic_orbit` differentiates Exudyn's
functions by one central difference per coordinate at every sample (``n``
columns, each a full right-hand side evaluation) and factorises the
``K s x K s`` Newton matrix (``s = n + m + d``) as a dense LU: ``O(K n^2)``
Exudyn work and ``O((K s)^3)`` flops, ``O((K s)^2)`` memory.  Both ignore that
a multibody model is sparse: a coordinate only enters the forces of the bodies,
connectors and loads that hold its node.

This module uses that structure, without changing what is solved:

1. **Coupling pattern** (:func:`coupling_pattern`): from Exudyn's
   local-to-global maps, ``f_i`` may depend on ``q_j`` / ``q_j'`` only if an
   object or load holds both coordinates; ``C_q^T lambda`` only couples the
   coordinates of the constraint objects.
2. **Column-compressed finite differences** (Curtis-Powell-Reid): columns that
   share no row (a greedy colouring of the column intersection graph) are
   perturbed together, so one difference gives all of them.  For ANCF chains
   the number of colours is the band width (~12 plus the hub), independent of
   the mesh.  Each difference uses the caller's rule and steps, so the blocks
   equal the dense ones up to round-off.
3. **A checked pattern**: at every sample one random directional derivative of
   the forces is compared with the compressed Jacobian times that direction;
   a dependence outside the pattern (a user function reading other
   coordinates) raises :class:`PatternError` instead of giving a wrong Newton
   matrix.
4. **Sparse Newton matrix** (:func:`sparse_newton_matrix`): the blocks
   ``K_k delta_kj + C_k D1_kj + M_k D2_kj`` (dense in time, sparse in the
   coordinates), ``C_q`` and the drive columns in compressed sparse columns,
   with the dense route's column equilibration, factorised by SuperLU
   (column ordering :data:`COLUMN_ORDERING`).

Maths
-----
Compressed differences: for a colour ``c`` (columns with disjoint row sets)
and steps ``h_j``, the directional derivative along ``e_c = sum_{j in c} h_j e_j``
is ``sum_{j in c} h_j J[:, j]``; row ``i`` has at most one ``j in c`` with
``J[i, j] != 0``, so ``J[i, j] = (J e_c)_i / h_j``.

References
----------
A. R. Curtis, M. J. D. Powell, J. K. Reid, "On the estimation of sparse
Jacobian matrices", J. Inst. Maths Applics 13 (1974) 117-119.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

__all__ = [
    "COLUMN_ORDERING",
    "PATTERN_CHECK_TOLERANCE",
    "STRUCTURED_THRESHOLD",
    "CouplingPattern",
    "NewtonAssembly",
    "PatternError",
    "StructuredBlocks",
    "directional_mismatch",
    "colour_columns",
    "compressed_blocks",
    "coupling_pattern",
    "sparse_newton_matrix",
    "sparse_solver",
]

logger = logging.getLogger(__name__)

#: Collocation unknowns ``K (n + m + d)`` from which :mod:`linearize.periodic_orbit`
#: uses this module: below, the dense Newton (one LU of the whole matrix per
#: factorisation) is as cheap as building the sparse one.  Measured (whole
#: ``find_orbit``, seconds, dense / structured, 32 samples, one core): single link 4
#: elements (928 unknowns) 0.27-0.40 / 0.29-0.46, 6 elements (1184) 0.45-0.52 /
#: 0.39-0.53, 8 elements (1440) 0.54-0.62 / 0.41-0.44, 12 elements 1.18-1.29 /
#: 0.51-0.64; the two-link robot (1536) 0.53-0.70 / 0.45-0.46.
STRUCTURED_THRESHOLD = 1200

#: SuperLU's column ordering of the Newton matrix.  Measured on the single link
#: (32 samples, CPU s per factorisation, same fill within 5 %): 32 elements (4512
#: unknowns) COLAMD 0.15, MMD on A^T + A 0.30, MMD on A^T A 0.63; 64 elements (8608)
#: 0.29, 0.55, 1.28.
COLUMN_ORDERING = "COLAMD"

#: The random directional derivative of the forces and the compressed Jacobian
#: times the same direction must agree to this, *row by row*, relative to
#: ``(|J| |e|)_i`` (the size of the terms summed in row ``i``; see
#: :func:`directional_mismatch`).  A correct pattern: ``J e`` differs from the exact
#: derivative by the column rule's error, for the Richardson / central rules with
#: ``eps^(1/4)`` / ``eps^(1/3)`` steps <= ~1e-9 of the row (measured <= 7e-10 per
#: row on the single link at 32 elements), and the refined reference by at most a
#: tenth of the tolerance; a coupling ``J_ij`` the pattern misses contributes
#: ``~|J_ij e_j|``, i.e. its weight in *its own row* (a normalisation by the largest
#: row would hide a coupling in a soft row behind the axial stiffness, 2.4e9 N/m at
#: 32 elements).  1e-6 separates the two by three decades on either side.
PATTERN_CHECK_TOLERANCE = 1e-6

#: The directional reference of :func:`directional_mismatch` is refined by halving
#: its step until, in every row, its estimated error is below this fraction of the
#: row's allowance (a correct Jacobian then passes with a margin of ~10) ...
CHECK_REFERENCE_FRACTION = 0.1
#: ... at most this often (a Richardson rule's truncation falls 16-fold per
#: halving, its round-off grows 2-fold; at 32 elements one halving suffices at a
#: generic state, 4 at strains of a few per cent).
CHECK_HALVINGS = 6
#: Round-off allowance of a difference rule in row ``i`` at step ``s``:
#: ``ROUNDOFF_FACTOR * eps / s * (|J| max(1, |x|))_i``.  The force terms summed
#: in row ``i`` are of size ``(|J| |x|)_i`` (coordinates O(1) in absolute
#: coordinates), so each evaluation is rounded by ~``eps`` times that; the
#: Richardson rule combines four evaluations with weights summing to ``3 / s``;
#: a factor 10 for the terms' own assembly round-off.  Relative to the row's
#: ``(|J| |e|)_i`` this is ~``30 eps / (s |e|) ~ 6e-11`` at the base step.
ROUNDOFF_FACTOR = 30.0


def directional_mismatch(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, e: np.ndarray,
                         J: np.ndarray, derivative: Derivative, *, tol: float, order: int,
                         step: float = 1.0, halvings: int = CHECK_HALVINGS,
                         fraction: float = CHECK_REFERENCE_FRACTION,
                         terms: Optional[np.ndarray] = None) -> Optional[float]:
    """Row-wise relative mismatch of ``J e`` against ``d/ds fun(x + s e)`` at 0, or ``None``.

    The reference is ``derivative(fun, x, e, s)`` at ``s = step/2, step/4, ...``, its
    error in row ``i`` estimated by ``|D(s) - D(2 s)|_i / (2^order - 1)`` (includes the
    round-off of both), refined until every row's estimate is below ``fraction`` of the
    row's allowance ``tol (|J| |e|)_i + r_i`` (``r_i``: the rule's round-off,
    :data:`ROUNDOFF_FACTOR`, on terms of size ``(|J| max(1, |x|))_i + max |f_i|`` over
    the evaluations, plus ``terms`` when the caller knows that ``f_i`` sums larger ones,
    e.g. ``|C_q|^T |lambda|`` for constraint reactions); ``None`` when ``halvings`` do not
    reach it (the caller must not accept).  Returns ``max_i |J e - ref|_i / ((|J| |e|)_i + r_i / tol)``:
    ``<= tol`` means every row agrees within its own scale.  A row that ``J`` claims
    to be independent of ``x`` (``(|J| |e|)_i = r_i = 0``) must then have an exactly
    zero reference (any change of ``f_i`` gives an infinite mismatch).
    """
    size = np.abs(J) @ np.abs(e)
    base = np.abs(J) @ np.maximum(1.0, np.abs(x)) + (0.0 if terms is None else terms)
    values = np.zeros(size.shape)

    def recorded(y: np.ndarray) -> np.ndarray:
        f = fun(y)
        np.maximum(values, np.abs(f), out=values)
        return f

    eps = float(np.finfo(float).eps)
    richardson_denominator = 2.0 ** order - 1.0
    s = float(step)
    prev = derivative(recorded, x, e, s)
    for _ in range(halvings):
        s *= 0.5
        cur = derivative(recorded, x, e, s)
        roundoff = ROUNDOFF_FACTOR * eps / s * (base + values)
        allowed = np.multiply(tol, size, out=np.zeros_like(size), where=size > 0.0) + roundoff
        if np.all(np.abs(cur - prev) / richardson_denominator <= fraction * allowed):
            r = np.abs(J @ e - cur)
            scale = size + roundoff / tol  # the row's allowance / tol
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.where(scale > 0.0, r / scale, np.where(r > 0.0, np.inf, 0.0))
            return float(np.max(rel, initial=0.0))
        prev = cur
    return None


class PatternError(RuntimeError):
    """The model's forces depend on coordinates outside the structural pattern."""


@dataclass(frozen=True)
class CouplingPattern:
    """Which coordinates each force and constraint reaction may depend on.

    Attributes
    ----------
    force : ndarray of bool, shape (n, n)
        ``force[i, j]``: ``f_i`` may depend on ``q_j`` and ``q_j'`` (and ``M(q) a`` row ``i`` on ``q_j``).
    reaction : ndarray of bool, shape (n, n)
        ``reaction[i, j]``: ``(C_q^T lambda)_i`` may depend on ``q_j``.
    force_colours : tuple of ndarray
        Structurally orthogonal column groups of ``force``.
    reaction_colours : tuple of ndarray
        Structurally orthogonal groups of the columns of ``reaction`` that have entries.
    """

    force: np.ndarray = field(repr=False)
    reaction: np.ndarray = field(repr=False)
    force_colours: tuple = field(repr=False)
    reaction_colours: tuple = field(repr=False)

    @property
    def size(self) -> int:
        return int(self.force.shape[0])

    def summary(self) -> dict:
        return {"ode2": self.size, "force_nonzeros": int(self.force.sum()),
                "force_colours": len(self.force_colours), "reaction_colours": len(self.reaction_colours)}


def colour_columns(pattern: np.ndarray, columns: Optional[np.ndarray] = None) -> tuple:
    """Greedy colouring of the columns of a boolean ``pattern`` so that no two
    columns of one colour have an entry in the same row.

    Parameters
    ----------
    pattern : ndarray of bool, shape (r, c)
    columns : ndarray of int, optional
        Columns to colour (default: all).

    Returns
    -------
    tuple of ndarray
        Column indices per colour (every given column in exactly one).
    """
    P = np.asarray(pattern, dtype=bool)
    cols = np.arange(P.shape[1]) if columns is None else np.asarray(columns, dtype=int)
    rows_used: list = []  # per colour: boolean row mask
    members: list = []
    for j in cols:
        rj = P[:, j]
        for c, used in enumerate(rows_used):
            if not np.any(used & rj):
                used |= rj
                members[c].append(int(j))
                break
        else:
            rows_used.append(rj.copy())
            members.append([int(j)])
    return tuple(np.array(m, dtype=int) for m in members)


def _marker_coordinates(mbs: Any, marker: int) -> Optional[list]:
    sd = mbs.systemData
    mk = mbs.GetMarker(int(marker))
    if "bodyNumber" in mk:
        return list(sd.GetObjectLTGODE2(int(mk["bodyNumber"])))
    if "nodeNumber" in mk:
        return list(sd.GetNodeLTGODE2(int(mk["nodeNumber"])))
    return None


def coupling_pattern(system: Any) -> CouplingPattern:
    """Structural coupling of an assembled Exudyn model (see the module notes).

    Parameters
    ----------
    system : linearize.exudyn_system.ExudynSystem

    Returns
    -------
    CouplingPattern
        Objects couple the coordinates of their local-to-global map; objects with
        algebraic equations (constraints) also form the reaction pattern; a load
        couples the coordinates of its marker's body or node.  Anything this
        cannot resolve (a load on an unknown marker type) couples all coordinates.
    """
    mbs = system.mbs
    sd = mbs.systemData
    n = int(system.n)
    force = np.zeros((n, n), dtype=bool)
    reaction = np.zeros((n, n), dtype=bool)
    for i in range(sd.NumberOfObjects()):
        ltg = np.asarray(list(sd.GetObjectLTGODE2(i)), dtype=int)
        if ltg.size == 0:
            continue
        force[np.ix_(ltg, ltg)] = True
        if len(list(sd.GetObjectLTGAE(i))):
            reaction[np.ix_(ltg, ltg)] = True
    for i in range(sd.NumberOfLoads()):
        load = mbs.GetLoad(i)
        ltg = _marker_coordinates(mbs, load.get("markerNumber", -1)) if "markerNumber" in load else None
        if ltg is None:
            logger.debug("load %d: unknown marker type; coupling all coordinates", i)
            force[:] = True
            break
        idx = np.asarray(ltg, dtype=int)
        force[np.ix_(idx, idx)] = True
    np.fill_diagonal(force, True)
    force_colours = colour_columns(force)
    rcols = np.flatnonzero(np.any(reaction, axis=0))
    reaction_colours = colour_columns(reaction, rcols)
    pat = CouplingPattern(force=force, reaction=reaction, force_colours=force_colours,
                          reaction_colours=reaction_colours)
    logger.debug("coupling pattern: %s", pat.summary())
    return pat


@dataclass(frozen=True)
class StructuredBlocks:
    """Per-sample blocks (same meaning as :class:`linearize.periodic_orbit.TangentBlocks`).

    Attributes
    ----------
    M, K_force, K_reaction, C : ndarray, shape (K, n, n)
    Cq : ndarray, shape (K, m, n)
    pattern_mismatch : float
        Largest row-wise relative mismatch of the directional check
        (:func:`directional_mismatch`, :data:`PATTERN_CHECK_TOLERANCE`).
    evaluations : int
        Exudyn function evaluations spent on the differences.
    """

    M: np.ndarray
    K_force: np.ndarray
    K_reaction: np.ndarray
    C: np.ndarray
    Cq: np.ndarray
    pattern_mismatch: float
    evaluations: int


Derivative = Callable[[Callable[[np.ndarray], np.ndarray], np.ndarray, np.ndarray, float], np.ndarray]


class _Counter:
    def __init__(self, fun: Callable[[np.ndarray], np.ndarray]) -> None:
        self.fun, self.calls = fun, 0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.calls += 1
        return self.fun(x)


def _compressed(fun: Callable, x: np.ndarray, h: np.ndarray, colours: tuple, pattern: np.ndarray,
                derivative: Derivative, out: np.ndarray) -> None:
    """Fill ``out[:, j]`` (rows of ``pattern[:, j]``) for every coloured column ``j``."""
    n = x.size
    for cols in colours:
        e = np.zeros(n)
        e[cols] = h[cols]
        dcol = derivative(fun, x, e, 1.0)
        for j in cols:
            rows = pattern[:, j]
            out[rows, j] = dcol[rows] / h[j]


def compressed_blocks(
    system: Any,
    times: np.ndarray,
    Q: np.ndarray,
    V: np.ndarray,
    A: np.ndarray,
    L: np.ndarray,
    pattern: CouplingPattern,
    *,
    derivative: Derivative,
    steps: Callable[[np.ndarray], np.ndarray],
    check: bool = True,
    seed: int = 20261127,
    order: int = 4,
) -> StructuredBlocks:
    """Per-sample linearisation by column-compressed finite differences.

    Parameters
    ----------
    system : linearize.exudyn_system.ExudynSystem
    times, Q, V, A, L :
        Sample times, coordinates, rates, accelerations and multipliers (as in
        :func:`linearize.periodic_orbit.tangent_blocks`).
    pattern : CouplingPattern
    derivative : callable
        ``derivative(fun, x, e, s)``: the finite-difference rule for
        ``d/ds fun(x + s e)`` at 0 (the dense route's rule, so both give the same blocks).
    steps : callable
        ``steps(x)``: per-coordinate steps of the rule.
    check : bool
        Run the directional pattern check at every sample (default).
    seed : int
        Seed of the random check directions.
    order : int
        Order of ``derivative``'s truncation error (4: Richardson-extrapolated central
        differences), for the error estimate of the check's reference.

    Raises
    ------
    PatternError
        If a directional derivative disagrees with the compressed Jacobian in some row
        by more than :data:`PATTERN_CHECK_TOLERANCE` of that row's scale
        (:func:`directional_mismatch`: the forces depend on coordinates outside the
        pattern), or the check's reference cannot be made accurate enough to decide.
    """
    Kn, n, m = times.size, system.n, system.m
    Ms = np.empty((Kn, n, n))
    Kf = np.zeros((Kn, n, n))
    Kr = np.zeros((Kn, n, n))
    Cd = np.zeros((Kn, n, n))
    Cqs = np.empty((Kn, m, n))
    const_mass = system.mass_is_constant(Q[0])
    rng = np.random.default_rng(seed)
    worst = 0.0
    calls = 0
    for k in range(Kn):
        q, v, a, lam, t = Q[k], V[k], A[k], L[k], float(times[k])
        Ms[k] = system.mass(q, t)
        Cqs[k] = system.constraint_jacobian(q, t)
        hq, hv = steps(q), steps(v)

        def force_raw(x, v=v, a=a, t=t):
            r = -system.rhs(x, v, t)
            if not const_mass:
                r = r + system.mass(x, t) @ a
            return r

        def damping_raw(y, q=q, t=t):
            return -system.rhs(q, y, t)

        force, damping = _Counter(force_raw), _Counter(damping_raw)
        _compressed(force, q, hq, pattern.force_colours, pattern.force, derivative, Kf[k])
        _compressed(damping, v, hv, pattern.force_colours, pattern.force, derivative, Cd[k])
        if m and pattern.reaction_colours:
            def reaction_raw(x, lam=lam, t=t):
                return system.constraint_jacobian(x, t).T @ lam

            reaction = _Counter(reaction_raw)
            _compressed(reaction, q, hq, pattern.reaction_colours, pattern.reaction, derivative, Kr[k])
            calls += reaction.calls
        if check:
            for fun, x, h, J in ((force, q, hq, Kf[k]), (damping, v, hv, Cd[k])):
                e = h * rng.uniform(-1.0, 1.0, n)
                mismatch = directional_mismatch(fun, x, e, J, derivative, tol=PATTERN_CHECK_TOLERANCE, order=order)
                if mismatch is None:
                    raise PatternError(
                        f"the directional check of the force pattern at t = {t:.6g} could not be resolved "
                        f"(its reference does not reach {CHECK_REFERENCE_FRACTION:g} of the tolerance in "
                        f"{CHECK_HALVINGS} halvings); use the dense collocation")
                worst = max(worst, mismatch)
                if not mismatch <= PATTERN_CHECK_TOLERANCE:
                    raise PatternError(
                        f"the forces at t = {t:.6g} depend on coordinates outside the structural pattern "
                        f"(directional check: row-wise relative mismatch {mismatch:.1e} > "
                        f"{PATTERN_CHECK_TOLERANCE:.0e}); use the dense collocation")
        calls += force.calls + damping.calls
    return StructuredBlocks(M=Ms, K_force=Kf, K_reaction=Kr, C=Cd, Cq=Cqs, pattern_mismatch=worst,
                            evaluations=calls)


def sparse_newton_matrix(
    M: np.ndarray,
    K: np.ndarray,
    C: np.ndarray,
    Cq: np.ndarray,
    B: np.ndarray,
    D1: np.ndarray,
    D2: np.ndarray,
) -> scipy.sparse.csc_matrix:
    """The collocation Newton matrix in compressed sparse columns.

    Unknowns and equations are ordered by sample, then ``(q, lambda, tau)``
    (the dense route's order).  Row block ``k``::

        q-rows:      K_k dq_k + sum_j (D1_kj C_k + D2_kj M_k) dq_j + C_q,k^T dlambda_k - B dtau_k
        lambda-rows: C_q,k dq_k
        tau-rows:    B^T dq_k

    Parameters
    ----------
    M, K, C : ndarray, shape (K, n, n)
    Cq : ndarray, shape (K, m, n)
    B : ndarray, shape (n, d)
    D1, D2 : ndarray, shape (K, K)
    """
    Kn, n, _ = M.shape
    m, d = Cq.shape[1], B.shape[1]
    s = n + m + d
    ks = np.arange(Kn)
    rows: list = []
    cols: list = []
    vals: list = []
    # time-coupled blocks D1 C + D2 M on the union of their nonzero patterns
    a, b = np.nonzero(np.any(C != 0.0, axis=0) | np.any(M != 0.0, axis=0))
    if a.size:
        v = D1[:, :, None] * C[:, a, b][:, None, :] + D2[:, :, None] * M[:, a, b][:, None, :]
        rows.append(np.broadcast_to(ks[:, None, None] * s + a[None, None, :], v.shape).ravel())
        cols.append(np.broadcast_to(ks[None, :, None] * s + b[None, None, :], v.shape).ravel())
        vals.append(v.ravel())
    a, b = np.nonzero(np.any(K != 0.0, axis=0))
    if a.size:
        rows.append((ks[:, None] * s + a[None, :]).ravel())
        cols.append((ks[:, None] * s + b[None, :]).ravel())
        vals.append(K[:, a, b].ravel())
    if m:
        i, j = np.nonzero(np.any(Cq != 0.0, axis=0))
        w = Cq[:, i, j].ravel()
        r_l = (ks[:, None] * s + n + i[None, :]).ravel()
        c_q = (ks[:, None] * s + j[None, :]).ravel()
        rows += [r_l, c_q]
        cols += [c_q, r_l]
        vals += [w, w]
    if d:
        i, j = np.nonzero(B)
        w = np.tile(B[i, j], Kn)
        r_q = (ks[:, None] * s + i[None, :]).ravel()
        c_t = (ks[:, None] * s + n + m + j[None, :]).ravel()
        rows += [r_q, c_t]
        cols += [c_t, r_q]
        vals += [-w, w]
    N = Kn * s
    J = scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(N, N))
    return J.tocsc()


class NewtonAssembly:
    """:func:`sparse_newton_matrix` with the sparsity structure kept between calls.

    Newton rebuilds the matrix at every refreshed iterate with the same structural
    pattern; the index arrays and the sort into compressed columns (most of the assembly
    time at 64 elements, 8608 unknowns) are done once per pattern.  The coordinate
    blocks hold ``D1_kj C_k + D2_kj M_k`` on the union of the patterns of ``C`` and ``M``
    (plus ``K_k`` on the diagonal blocks) and ``K_k`` alone where only ``K`` has entries
    (no duplicate entries, so the values are only gathered into the cached order: the
    structure of :func:`sparse_newton_matrix`).  Values inside the cached structure are
    stored as explicit zeros where a block has none; an entry outside it (e.g. the
    constraint-reaction stiffness once the multipliers leave their zero guess) rebuilds
    the structure on the union.  ``stiffness_pattern`` (the structural pattern of ``K``,
    e.g. forces and reactions of :func:`coupling_pattern`) includes such entries from the
    first build.

    Parameters
    ----------
    B : ndarray, shape (n, d)
    D1, D2 : ndarray, shape (K, K)
    stiffness_pattern : ndarray of bool, shape (n, n), optional
    """

    def __init__(self, B: np.ndarray, D1: np.ndarray, D2: np.ndarray,
                 stiffness_pattern: Optional[np.ndarray] = None) -> None:
        self.B, self.D1, self.D2 = np.asarray(B, dtype=float), np.asarray(D1), np.asarray(D2)
        self._key: Optional[tuple] = None
        self._hint = None if stiffness_pattern is None else np.asarray(stiffness_pattern, dtype=bool)
        self.builds = 0

    def _structure(self, qq: np.ndarray, kk: np.ndarray, cq: np.ndarray, Kn: int, n: int, m: int) -> None:
        d = self.B.shape[1]
        s = n + m + d
        ks = np.arange(Kn)
        a, b = np.nonzero(qq)
        ka, kb = np.nonzero(kk & ~qq)  # stiffness entries outside the time-coupled pattern: diagonal blocks
        rows = [np.broadcast_to(ks[:, None, None] * s + a[None, None, :], (Kn, Kn, a.size)).ravel(),
                (ks[:, None] * s + ka[None, :]).ravel()]
        cols = [np.broadcast_to(ks[None, :, None] * s + b[None, None, :], (Kn, Kn, a.size)).ravel(),
                (ks[:, None] * s + kb[None, :]).ravel()]
        i, j = np.nonzero(cq)
        r_l = (ks[:, None] * s + n + i[None, :]).ravel()
        c_q = (ks[:, None] * s + j[None, :]).ravel()
        rows += [r_l, c_q]
        cols += [c_q, r_l]
        bi, bj = np.nonzero(self.B)
        r_q = (ks[:, None] * s + bi[None, :]).ravel()
        c_t = (ks[:, None] * s + n + m + bj[None, :]).ravel()
        rows += [r_q, c_t]
        cols += [c_t, r_q]
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        order = np.lexsort((rows, cols))  # by column, then row: compressed sparse columns
        N = Kn * s
        self._order = order
        self._indices = rows[order]
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=N))])
        self._shape = (N, N)
        self._ab, self._kab, self._ij, self._bij = (a, b), (ka, kb), (i, j), (bi, bj)
        self.builds += 1

    def __call__(self, M: np.ndarray, K: np.ndarray, C: np.ndarray, Cq: np.ndarray) -> scipy.sparse.csc_matrix:
        """The Newton matrix of :func:`sparse_newton_matrix` (same arguments but ``B``, ``D1``, ``D2``)."""
        Kn, n, _ = M.shape
        m = Cq.shape[1]
        kk = np.any(K != 0.0, axis=0)
        if self._hint is not None and self._hint.shape == kk.shape:
            kk = kk | self._hint
        key = (np.any(C != 0.0, axis=0) | np.any(M != 0.0, axis=0), kk, np.any(Cq != 0.0, axis=0))
        if self._key is not None and all(x.shape == y.shape for x, y in zip(key, self._key)):
            if all(np.all(y | ~x) for x, y in zip(key, self._key)):
                key = self._key  # within the cached structure (its other entries are explicit zeros)
            else:
                key = tuple(x | y for x, y in zip(key, self._key))  # grown: rebuild on the union
        if key is not self._key:
            self._structure(*key, Kn, n, m)
            self._key = key
        a, b = self._ab
        ka, kb = self._kab
        i, j = self._ij
        bi, bj = self._bij
        ks = np.arange(Kn)
        v = self.D1[:, :, None] * C[:, a, b][:, None, :] + self.D2[:, :, None] * M[:, a, b][:, None, :]
        v[ks, ks, :] += K[:, a, b]
        w = Cq[:, i, j].ravel()
        wb = np.tile(self.B[bi, bj], Kn)
        vals = np.concatenate([v.ravel(), K[:, ka, kb].ravel(), w, w, -wb, wb])
        return scipy.sparse.csc_matrix((vals[self._order], self._indices, self._indptr), shape=self._shape)


def sparse_solver(J: scipy.sparse.spmatrix) -> Callable[[np.ndarray], np.ndarray]:
    """Factorise the sparse Newton matrix (column equilibration as the dense route, SuperLU).

    Returns
    -------
    callable
        ``solve(r)`` returning ``J^-1 r``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the matrix is singular.
    """
    J = scipy.sparse.csc_matrix(J)
    scale = np.asarray(abs(J).max(axis=0).todense()).ravel()
    scale[scale == 0] = 1.0
    Js = J @ scipy.sparse.diags(1.0 / scale)
    try:
        lu = scipy.sparse.linalg.splu(scipy.sparse.csc_matrix(Js), permc_spec=COLUMN_ORDERING)
    except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
        raise np.linalg.LinAlgError(f"singular collocation Newton matrix ({exc})") from None
    return lambda r: lu.solve(np.asarray(r, dtype=float)) / scale
