"""The one adapter between the package and Exudyn's solver functions.

Conventions (written once, here)
--------------------------------
Exudyn's constrained equations of motion are::

    M(q) q'' = f(q, q', t) - C_q(q, t)^T lambda,      C(q, t) = 0

with ``q`` the ODE2 coordinates (displacements from the nodes' reference
coordinates), ``f`` Exudyn's ODE2 right-hand side (internal and applied forces,
ODE2 connectors such as spring-dampers; no constraint reactions) and ``C`` the
algebraic equations of its constraints (position level).  Linearised matrices
are written on the left-hand side: ``K = -df/dq``, ``C = -df/dq'``.

User functions see the time set by :meth:`ExudynSystem.set_state` (Exudyn's
current configuration time).

Rotation-vector (Lie group) nodes
---------------------------------
Exudyn's velocity coordinates of a ``RigidBodyRotVec*`` node's rotation are its body-fixed angular
velocity ``omega = T(nu) nu'`` (``nu`` the total rotation vector, :func:`tangent_operator`), its
equations are body-fixed torques and its constraint Jacobian is taken in body-fixed rotation
increments.  The adapter presents such a node in the rotation-vector chart, like any other node:
the package's velocity is ``q'`` (``nu'``), and with ``P(q) = blockdiag(I, T(nu))``::

    M = P^T M_ex P,    f = P^T (f_ex(q, P q') - M_ex P' q'),    C_q = C_q,ex P

(:meth:`ExudynSystem.exudyn_velocity` and :meth:`ExudynSystem.chart_velocity` convert states for
Exudyn's integrator).

A rotation-vector node that turns (whole turns per period) is presented in a Tait-Bryan chart instead
(:class:`TurningChart`, set by :meth:`ExudynSystem.set_turning_charts`): the package's coordinates are
three angles ``theta`` with ``R = C1 Rx(theta_1) Ry(theta_2) Rz(theta_3) C2`` (constant rotations ``C1``,
``C2`` chosen so that the body turns about the first axis, far from the chart's singularity
``theta_2 = +-pi/2``), Exudyn's coordinates are the rotation vector of ``R`` (less the node's reference
value) and ``P(q) = blockdiag(I, C2^T G(theta))`` with the body-fixed angular velocity
``omega = C2^T G(theta) theta'`` (:func:`tait_bryan_rate_matrix`); the same formulas for ``M``, ``f`` and
``C_q`` hold.  A whole turn advances ``theta_1`` by ``2 pi`` and leaves ``R`` unchanged, so such a node's
angles are rotation coordinates like those of a ``RigidBodyRxyz`` node.  Exudyn evaluates the node's
equations from ``R`` alone (any rotation vector of ``R`` gives the same forces, mass matrix and
constraints), so the rotation vector's branch (length ``<= pi``) does not matter.
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from mbs_models.model_file import BuiltModel, ModelFileError

__all__ = ["ExudynSystem", "MASS_CONSTANCY_TOLERANCE", "TurningChart", "from_exudyn_velocity", "lie_group_nodes",
           "from_exudyn_state", "rotation_matrix", "rotation_vector", "tait_bryan_rate_matrix", "tangent_operator", "to_exudyn_state", "to_exudyn_velocity",
           "turning_chart"]

logger = logging.getLogger(__name__)

#: Relative change of ``M`` under a configuration perturbation below which the
#: mass matrix is treated as constant (round-off level of the assembly).
MASS_CONSTANCY_TOLERANCE = 1e-13


#: Below this rotation angle the coefficients of :func:`tangent_operator` and :func:`rotation_matrix` are
#: their Taylor series (:data:`_SERIES_TERMS` terms: truncation below 1e-19 at the threshold); above it
#: the closed forms lose at most ``6 eps / a^2`` (5e-15) relative to the cancellation in ``a - sin a``.
TANGENT_SERIES_ANGLE = 0.5
_SERIES_TERMS = 8


def _rotation_coefficients(a2: Any) -> tuple[Any, Any, Any]:
    """``(sin a / a, (1 - cos a) / a^2, (a - sin a) / a^3)`` for ``a^2 = a2`` (complex accepted), without
    cancellation: the series ``sum (-a^2)^k / (2k + j)!`` (j = 1, 2, 3) below :data:`TANGENT_SERIES_ANGLE`,
    ``2 sin^2(a/2) / a^2`` for the second above it."""
    if abs(a2) < TANGENT_SERIES_ANGLE ** 2:
        c = [0.0 * a2, 0.0 * a2, 0.0 * a2]
        term = 1.0 + 0.0 * a2  # (-a^2)^k
        for k in range(_SERIES_TERMS):
            for j in range(3):
                c[j] = c[j] + term / math.factorial(2 * k + j + 1)
            term = -term * a2
        return c[0], c[1], c[2]
    a = np.sqrt(a2)
    sa = np.sin(a)
    return sa / a, 2.0 * np.sin(0.5 * a) ** 2 / a2, (a - sa) / (a2 * a)


def tangent_operator(nu: np.ndarray) -> np.ndarray:
    """``T(nu)`` with the body-fixed angular velocity ``omega = T(nu) nu'`` of ``R = exp(skew(nu))``::

        T = I - (1 - cos a) / a^2 skew(nu) + (a - sin a) / a^3 skew(nu)^2,   a = |nu|

    Complex arguments are accepted (complex-step differentiation); singular at ``a = 2 pi k``, k >= 1."""
    nu = np.asarray(nu)
    a2 = nu @ nu
    s = np.array([[0, -nu[2], nu[1]], [nu[2], 0, -nu[0]], [-nu[1], nu[0], 0]], dtype=nu.dtype)
    _, c1, c2 = _rotation_coefficients(a2)
    return np.eye(3, dtype=nu.dtype) - c1 * s + c2 * (s @ s)


def lie_group_nodes(mbs: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(ODE2 indices, reference rotation vector)`` of the rotation of every ``RigidBodyRotVec*`` node of
    an assembled system."""
    out = []
    for j in range(mbs.systemData.NumberOfNodes()):
        node = mbs.GetNode(j)
        ltg = np.array([int(i) for i in mbs.systemData.GetNodeLTGODE2(j)], dtype=int)
        if str(node.get("nodeType")).startswith("RigidBodyRotVec") and ltg.size == 6:
            out.append((ltg[3:6], np.asarray(node.get("referenceCoordinates", [0.0] * 6), dtype=float)[3:6]))
    return out


def to_exudyn_velocity(nodes: list, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Exudyn's velocity coordinates of the state ``(q, q')`` (``omega = T(nu) nu'`` on the rotation-vector
    nodes ``nodes``, :func:`lie_group_nodes`; unchanged elsewhere)."""
    w = np.array(v, dtype=float)
    for idx, ref in nodes:
        w[idx] = tangent_operator(np.asarray(q, dtype=float)[idx] + ref) @ w[idx]
    return w


def from_exudyn_velocity(nodes: list, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``q'`` from Exudyn's velocity coordinates ``w`` at ``q`` (inverse of :func:`to_exudyn_velocity`; at the
    chart's singular length ``|nu| = 2 pi`` the least-squares solution, finite)."""
    v = np.array(w, dtype=float)
    for idx, ref in nodes:
        v[idx] = np.linalg.lstsq(tangent_operator(np.asarray(q, dtype=float)[idx] + ref), v[idx], rcond=None)[0]
    return v


def tait_bryan_rate_matrix(theta: np.ndarray) -> np.ndarray:
    """``G(theta)`` with the body-fixed angular velocity ``omega = G(theta) theta'`` of
    ``R = Rx(theta_1) Ry(theta_2) Rz(theta_3)``::

        G = [[c2 c3, s3, 0], [-c2 s3, c3, 0], [s2, 0, 1]]

    Complex arguments are accepted (complex-step differentiation); singular at ``cos(theta_2) = 0``."""
    th = np.asarray(theta)
    c2, s2, c3, s3 = np.cos(th[1]), np.sin(th[1]), np.cos(th[2]), np.sin(th[2])
    zero = 0.0 * c2
    return np.array([[c2 * c3, s3, zero], [-c2 * s3, c3, zero], [s2, zero, zero + 1.0]])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _tait_bryan_rotation(theta: np.ndarray) -> np.ndarray:
    """``Rx(theta_1) Ry(theta_2) Rz(theta_3)``."""
    c1, c2, c3 = np.cos(theta)
    s1, s2, s3 = np.sin(theta)
    return np.array([[c2 * c3, -c2 * s3, s2],
                     [c1 * s3 + s1 * s2 * c3, c1 * c3 - s1 * s2 * s3, -s1 * c2],
                     [s1 * s3 - c1 * s2 * c3, s1 * c3 + c1 * s2 * s3, c1 * c2]])


def _tait_bryan_angles(R: np.ndarray) -> np.ndarray:
    """The angles of ``R = Rx Ry Rz`` with ``theta_2`` in ``[-pi/2, pi/2]``, the others in ``(-pi, pi]``."""
    return np.array([math.atan2(-R[1, 2], R[2, 2]), math.atan2(R[0, 2], math.hypot(R[0, 0], R[0, 1])),
                     math.atan2(-R[0, 1], R[0, 0])])


def rotation_matrix(nu: np.ndarray) -> np.ndarray:
    """``exp(skew(nu))`` (Rodrigues; series below :data:`TANGENT_SERIES_ANGLE`)."""
    nu = np.asarray(nu, dtype=float)
    a2 = float(nu @ nu)
    c0, c1, _ = (float(c) for c in _rotation_coefficients(a2))
    S = _skew(nu)
    return np.eye(3) + c0 * S + c1 * (S @ S)


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """The rotation vector (length ``<= pi``) of the rotation matrix ``R``, through its unit quaternion
    (Shepperd's choice of the largest component, accurate also near the angle pi)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (4.0 * w)
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        vi = 0.5 * math.sqrt(max(1.0 + 2.0 * R[i, i] - tr, 0.0))
        v = np.empty(3)
        v[i] = vi
        v[j] = (R[j, i] + R[i, j]) / (4.0 * vi)
        v[m] = (R[m, i] + R[i, m]) / (4.0 * vi)
        w = (R[m, j] - R[j, m]) / (4.0 * vi)
    if w < 0.0:
        w, v = -w, -v
    sv = float(np.linalg.norm(v))
    if sv < 1e-300:
        return np.zeros(3)
    return (2.0 * math.atan2(sv, w) / sv) * v


@dataclass(frozen=True)
class TurningChart:
    """The Tait-Bryan chart ``R = outer Rx(theta_1) Ry(theta_2) Rz(theta_3) inner`` of a rotation-vector
    node that turns (see the module docstring).

    Attributes
    ----------
    indices : ndarray, shape (3,)
        ODE2 indices of the node's rotation.
    reference : ndarray, shape (3,)
        The node's reference rotation vector (Exudyn's total rotation vector is reference + ODE2 coordinates).
    outer, inner : ndarray, shape (3, 3)
        ``C1`` and ``C2``.
    """

    indices: np.ndarray
    reference: np.ndarray
    outer: np.ndarray
    inner: np.ndarray

    def rotation(self, theta: np.ndarray) -> np.ndarray:
        """``R(theta)``."""
        return self.outer @ _tait_bryan_rotation(np.asarray(theta, dtype=float)) @ self.inner

    def exudyn_coordinates(self, theta: np.ndarray) -> np.ndarray:
        """Exudyn's ODE2 coordinates of the rotation: the rotation vector of ``R(theta)`` (length
        ``<= pi``) less the reference."""
        return rotation_vector(self.rotation(theta)) - self.reference

    def angles(self, coordinates: np.ndarray, near: np.ndarray) -> np.ndarray:
        """The angles of the rotation of Exudyn's coordinates (``exp(reference + coordinates)``) nearest
        to ``near`` (each angle up to whole turns, the tilt ``theta_2`` within ``[-pi/2, pi/2]``)."""
        R = rotation_matrix(np.asarray(coordinates, dtype=float) + self.reference)
        theta = _tait_bryan_angles(self.outer.T @ R @ self.inner.T)
        return theta + 2.0 * math.pi * np.round((np.asarray(near, dtype=float) - theta) / (2.0 * math.pi))

    def rate_map(self, theta: np.ndarray) -> np.ndarray:
        """``C2^T G(theta)``: the body-fixed angular velocity is ``rate_map(theta) theta'`` (complex-safe)."""
        return self.inner.T @ tait_bryan_rate_matrix(theta)


def turning_chart(indices: np.ndarray, reference: np.ndarray, axis: np.ndarray,
                  start: np.ndarray) -> TurningChart:
    """The chart of a node that turns about the (inertial) ``axis`` from the rotation ``start``: ``C1``
    takes the x axis to ``axis``, ``C2 = C1^T start`` (so ``theta = 0`` at ``start`` and a spin about
    ``axis`` advances ``theta_1`` alone)."""
    a = np.asarray(axis, dtype=float) / float(np.linalg.norm(axis))
    ex = np.array([1.0, 0.0, 0.0])
    cross = np.cross(ex, a)
    sin, cos = float(np.linalg.norm(cross)), float(ex @ a)
    if sin < 1e-14:
        outer = np.eye(3) if cos > 0 else np.diag([-1.0, 1.0, -1.0])  # (a half turn about y when axis = -x)
    else:
        outer = rotation_matrix(cross / sin * math.atan2(sin, cos))
    return TurningChart(np.asarray(indices, dtype=int), np.asarray(reference, dtype=float), outer,
                        outer.T @ np.asarray(start, dtype=float))


def _chart_free(nodes: list, charts: tuple) -> list:
    first = {int(c.indices[0]) for c in charts}
    return [(idx, ref) for idx, ref in nodes if int(idx[0]) not in first]


def _exudyn_coordinates(charts: tuple, q: np.ndarray) -> np.ndarray:
    """Exudyn's ODE2 coordinates of the package's ``q``: the same but for the nodes of ``charts``."""
    out = np.array(q, dtype=float)
    for c in charts:
        out[c.indices] = c.exudyn_coordinates(out[c.indices])
    return out


def _chart_coordinates(charts: tuple, q_ex: np.ndarray, near: np.ndarray) -> np.ndarray:
    """The package's ``q`` of Exudyn's ODE2 coordinates, the angles of ``charts`` nearest to ``near``'s."""
    out = np.array(q_ex, dtype=float)
    for c in charts:
        out[c.indices] = c.angles(out[c.indices], np.asarray(near, dtype=float)[c.indices])
    return out


def _exudyn_rates(nodes: list, charts: tuple, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Exudyn's velocity coordinates of ``(q, q')``: the rotation-vector nodes ``nodes`` in the
    rotation-vector chart but those of ``charts``."""
    w = to_exudyn_velocity(_chart_free(nodes, charts), q, v)
    for c in charts:
        w[c.indices] = c.rate_map(np.asarray(q, dtype=float)[c.indices]) @ np.asarray(v, dtype=float)[c.indices]
    return w


def _chart_rates(nodes: list, charts: tuple, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``q'`` from Exudyn's velocity coordinates ``w`` at the package's ``q`` (inverse of :func:`_exudyn_rates`)."""
    v = from_exudyn_velocity(_chart_free(nodes, charts), q, w)
    for c in charts:
        v[c.indices] = np.linalg.solve(c.rate_map(np.asarray(q, dtype=float)[c.indices]),
                                       np.asarray(w, dtype=float)[c.indices])
    return v


def to_exudyn_state(nodes: list, charts: tuple, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exudyn's ODE2 coordinates and velocity coordinates of the package's state ``(q, q')``: the
    rotation-vector nodes ``nodes`` (:func:`lie_group_nodes`) in the rotation-vector chart but those of
    ``charts`` (:class:`TurningChart`)."""
    return _exudyn_coordinates(charts, q), _exudyn_rates(nodes, charts, q, v)


def from_exudyn_state(nodes: list, charts: tuple, q_ex: np.ndarray, w: np.ndarray,
                      near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The package's ``(q, q')`` of Exudyn's state (inverse of :func:`to_exudyn_state`; the angles of
    ``charts`` nearest to those of ``near``)."""
    q = _chart_coordinates(charts, q_ex, near)
    return q, _chart_rates(nodes, charts, q, w)


class ExudynSystem:
    """Evaluate ``M(q)``, ``f(q, q', t)``, ``C(q, t)`` and ``C_q(q, t)`` of a built model.

    Parameters
    ----------
    built : BuiltModel
        Assembled model (:func:`mbs_models.model_file.build_model`).

    Attributes
    ----------
    n : int
        ODE2 coordinates.
    m : int
        Active algebraic equations (constraints of the model file; the package's
        drive constraints are not part of the system; Exudyn's "lambda = 0" rows
        of free joint axes are dropped).
    m_exudyn : int
        Exudyn's number of algebraic equations.
    q_initial, v_initial : ndarray
        The model file's initial ODE2 coordinates and rates (orbit guess at t = 0).
    """

    def __init__(self, built: BuiltModel) -> None:
        import exudyn as exu

        self._exu = exu
        self.built = built
        self.mbs = built.mbs
        sd = self.mbs.systemData
        self.n = int(sd.ODE2Size())
        self.m_exudyn = int(sd.AEsize())
        self.m = self.m_exudyn
        ini = exu.ConfigurationType.Initial
        self.q_initial = np.array(sd.GetODE2Coordinates(configuration=ini), dtype=float)
        #: ``(ODE2 indices, reference rotation vector)`` of the rotation-vector (Lie group) nodes
        self._lie = lie_group_nodes(self.mbs)
        #: Tait-Bryan charts of the rotation-vector nodes that turn (:meth:`set_turning_charts`)
        self.charts: tuple[TurningChart, ...] = ()
        self.v_initial = self.chart_velocity(self.q_initial,
                                             np.array(sd.GetODE2Coordinates_t(configuration=ini), dtype=float))
        self._cur = exu.ConfigurationType.Current
        self._solver = exu.MainSolverImplicitSecondOrder()
        settings = exu.SimulationSettings()
        settings.timeIntegration.verboseMode = 0
        settings.linearSolver.solverType = exu.LinearSolverType.EigenDense
        settings.solution.file.write = False
        self._solver.InitializeSolver(self.mbs, settings)
        self._zero_lambda = np.zeros(self.m_exudyn)
        self._zero_jacobian = np.zeros((self.n + self.m_exudyn, self.n + self.m_exudyn))
        self._mass_constant: bool | None = None
        self._mass0: np.ndarray | None = None
        self._coupling_pattern = None
        self.active = np.arange(self.m_exudyn)
        if self.m_exudyn:
            # Exudyn keeps an equation "lambda_i = 0" for each axis a joint leaves free
            # (e.g. ObjectJointGeneric's constrainedAxes = 0): such rows have no
            # coordinate dependence; they are dropped (their multiplier is zero).
            rng = np.random.default_rng(2024)
            J0 = self._ae_jacobian_full(self.q_initial, 0.0)
            J1 = self._ae_jacobian_full(self.q_initial + 1e-3 * rng.standard_normal(self.n), 0.0)
            live = np.any(J0 != 0.0, axis=1) | np.any(J1 != 0.0, axis=1)
            self.active = np.flatnonzero(live)
            self.m = int(self.active.size)
            if self.m < self.m_exudyn:
                logger.debug("%d of %d algebraic equations are free axes (lambda = 0)", self.m_exudyn - self.m,
                             self.m_exudyn)
        self._check_massless_free_nodes()

    def _check_massless_free_nodes(self) -> None:
        """Raise :class:`ModelFileError` naming the first node whose coordinates have no mass and on
        which no constraint acts: its equations of motion are ``0 = f`` (a singular mass matrix that
        Exudyn's solver reports only as a failed step).  A massless node that a constraint (joint)
        holds is fine: the constrained system can still be regular."""
        M = self._mass_raw(self.q_initial, 0.0)
        massless = ~np.any(M != 0.0, axis=0) & ~np.any(M != 0.0, axis=1)
        if not np.any(massless):
            return
        if self.m:
            Cq = self._ae_jacobian_full(self.q_initial, 0.0)[self.active]
            massless &= ~np.any(Cq != 0.0, axis=0)
        if not np.any(massless):
            return
        sd = self.mbs.systemData
        for j in range(sd.NumberOfNodes()):
            ltg = [int(i) for i in sd.GetNodeLTGODE2(j)]
            if ltg and all(massless[i] for i in ltg):
                node = self.mbs.GetNode(j)
                name = node.get("name") or f"node{j}"
                raise ModelFileError(
                    f"model {self.built.definition.name}: node {j} ({name!r}, {node.get('nodeType', 'node')}) is a "
                    "massless free node: no body gives its coordinates mass and no constraint acts on them "
                    "(add a body with mass on it, or constrain it)")
        idx = np.flatnonzero(massless)
        raise ModelFileError(f"model {self.built.definition.name}: ODE2 coordinates {idx.tolist()} have no mass and "
                             "no constraint acts on them (a singular mass matrix)")

    # ----------------------------------------------------------------- rotation-vector chart
    @property
    def has_lie_group_nodes(self) -> bool:
        """The model has rotation-vector (Lie group) nodes (see the module docstring)."""
        return bool(self._lie or self.charts)

    def set_turning_charts(self, charts: tuple[TurningChart, ...]) -> None:
        """Present the rotation-vector nodes of ``charts`` in their Tait-Bryan charts (see the module
        docstring; the other rotation-vector nodes stay in the rotation-vector chart).  The initial state
        (:attr:`q_initial`, :attr:`v_initial`) is re-read in the new coordinates, the angles nearest to
        zero."""
        import exudyn as exu

        charts = tuple(charts)
        first = {int(c.indices[0]) for c in charts}
        self.charts = charts
        self._lie = [(idx, ref) for idx, ref in lie_group_nodes(self.mbs) if int(idx[0]) not in first]
        sd = self.mbs.systemData
        ini = exu.ConfigurationType.Initial
        q_ex = np.array(sd.GetODE2Coordinates(configuration=ini), dtype=float)
        self.q_initial = self.chart_coordinates(q_ex, np.zeros(self.n))
        self.v_initial = self.chart_velocity(self.q_initial,
                                             np.array(sd.GetODE2Coordinates_t(configuration=ini), dtype=float))
        self._mass_constant, self._mass0, self._coupling_pattern = None, None, None

    def velocity_map(self, q: np.ndarray) -> np.ndarray:
        """``P(q)``: Exudyn's velocity coordinates are ``P(q) q'`` (identity but for rotation-vector nodes)."""
        P = np.eye(self.n)
        q = np.asarray(q, dtype=float)
        for idx, ref in self._lie:
            P[np.ix_(idx, idx)] = tangent_operator(q[idx] + ref)
        for c in self.charts:
            P[np.ix_(c.indices, c.indices)] = c.rate_map(q[c.indices])
        return P

    def exudyn_coordinates(self, q: np.ndarray) -> np.ndarray:
        """Exudyn's ODE2 coordinates of the package's ``q`` (the same but for turning rotation-vector
        nodes, :meth:`TurningChart.exudyn_coordinates`)."""
        return _exudyn_coordinates(self.charts, q) if self.charts else q

    def chart_coordinates(self, q_exudyn: np.ndarray, near: np.ndarray) -> np.ndarray:
        """The package's ``q`` of Exudyn's ODE2 coordinates, the angles of turning rotation-vector nodes
        nearest to those of ``near`` (:meth:`TurningChart.angles`)."""
        return _chart_coordinates(self.charts, q_exudyn, near)

    def exudyn_velocity(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Exudyn's velocity coordinates of the state ``(q, q')`` (:func:`to_exudyn_velocity`)."""
        return _exudyn_rates(self._lie, self.charts, q, v)

    def chart_velocity(self, q: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``q'`` from Exudyn's velocity coordinates ``w`` at ``q`` (:func:`from_exudyn_velocity`)."""
        return _chart_rates(self._lie, self.charts, q, w)

    def _velocity_map_rate(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``P'(q, q') q'`` (complex-step derivative of :func:`tangent_operator` or
        :meth:`TurningChart.rate_map` along ``q'``)."""
        out = np.zeros(self.n)
        h = 1e-30
        q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
        for idx, ref in self._lie:
            nu, rate = q[idx] + ref, v[idx]
            out[idx] = (tangent_operator(nu + 1j * h * rate).imag / h) @ rate
        for c in self.charts:
            theta, rate = q[c.indices], v[c.indices]
            out[c.indices] = (c.rate_map(theta + 1j * h * rate).imag / h) @ rate
        return out

    # ----------------------------------------------------------------- state
    def set_state(self, q: np.ndarray, v: np.ndarray, t: float) -> None:
        """Write ``(q, q', t)`` into Exudyn's current configuration (``q'`` as Exudyn's velocity
        coordinates, :meth:`exudyn_velocity`)."""
        sd = self.mbs.systemData
        sd.SetODE2Coordinates(self.exudyn_coordinates(q), configuration=self._cur)
        sd.SetODE2Coordinates_t(self.exudyn_velocity(q, v) if self.has_lie_group_nodes else v,
                                configuration=self._cur)
        if self.m_exudyn:
            sd.SetAECoordinates(self._zero_lambda, configuration=self._cur)
        sd.SetTime(float(t), self._cur)

    # ----------------------------------------------------------------- evaluations
    def rhs(self, q: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
        """``f(q, q', t)``, shape ``(n,)``."""
        self.set_state(q, v, t)
        self._solver.ComputeODE2RHS(self.mbs)
        f = np.array(self._solver.GetSystemResidual(), dtype=float)[: self.n]
        if not self.has_lie_group_nodes:
            return f
        P = self.velocity_map(q)
        return P.T @ (f - self._mass_exudyn(q, t) @ self._velocity_map_rate(q, v))

    def _mass_exudyn(self, q: np.ndarray, t: float) -> np.ndarray:
        self.set_state(q, np.zeros(self.n), t)
        self._solver.ComputeMassMatrix(self.mbs)
        return np.array(self._solver.GetSystemMassMatrix(), dtype=float)[: self.n, : self.n]

    def _mass_raw(self, q: np.ndarray, t: float) -> np.ndarray:
        M = self._mass_exudyn(q, t)
        if not self.has_lie_group_nodes:
            return M
        P = self.velocity_map(q)
        return P.T @ M @ P

    def mass(self, q: np.ndarray, t: float = 0.0) -> np.ndarray:
        """``M(q)``, shape ``(n, n)`` (cached when the mass matrix is constant)."""
        if self.mass_is_constant(q):
            return self._mass0
        return self._mass_raw(q, t)

    def force_jacobians(self, q: np.ndarray, v: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Exudyn's own ``K = -df/dq`` and ``C = -df/dq'`` (loads included), each ``(n, n)``.

        Exudyn differentiates its items analytically where they implement it
        and numerically otherwise; :func:`linearize.periodic_orbit.tangent_blocks`
        checks the result against Richardson differences once per model.  With rotation-vector nodes
        Exudyn's Jacobians are in its own velocity coordinates, not the adapter's: NaN (never accepted).
        """
        if self.has_lie_group_nodes:
            return np.full((self.n, self.n), np.nan), np.full((self.n, self.n), np.nan)
        self.set_state(q, v, t)
        self._solver.ComputeJacobianODE2RHS(self.mbs, scalarFactor_ODE2=-1.0, scalarFactor_ODE2_t=0.0,
                                            scalarFactor_ODE1=0.0, computeLoadsJacobian=2)
        K = np.array(self._solver.GetSystemJacobian(), dtype=float)[: self.n, : self.n]
        self.set_state(q, v, t)
        self._solver.ComputeJacobianODE2RHS(self.mbs, scalarFactor_ODE2=0.0, scalarFactor_ODE2_t=-1.0,
                                            scalarFactor_ODE1=0.0, computeLoadsJacobian=2)
        C = np.array(self._solver.GetSystemJacobian(), dtype=float)[: self.n, : self.n]
        return K, C

    def reaction_columns(self) -> np.ndarray:
        """Coordinates on which ``C_q`` can depend: the columns of ``C_q`` that are nonzero at the
        initial state or at a generic perturbation of it (a joint's Jacobian depends only on the
        coordinates of the nodes it connects)."""
        if not self.m:
            return np.zeros(0, dtype=int)
        rng = np.random.default_rng(7)
        J0 = self.constraint_jacobian(self.q_initial, 0.0)
        J1 = self.constraint_jacobian(self.q_initial + 1e-3 * rng.standard_normal(self.n), 0.0)
        return np.flatnonzero(np.any(J0 != 0.0, axis=0) | np.any(J1 != 0.0, axis=0))

    def coupling_pattern(self):
        """Structural coupling of the forces and constraint reactions
        (:func:`linearize.collocation_solver.coupling_pattern`), computed once."""
        if self._coupling_pattern is None:
            from linearize.collocation_solver import coupling_pattern

            self._coupling_pattern = coupling_pattern(self)
        return self._coupling_pattern

    def mass_is_constant(self, q: np.ndarray) -> bool:
        """Whether ``M`` does not depend on ``q`` (tested once with a generic perturbation)."""
        if self._mass_constant is None:
            m0 = self._mass_raw(q, 0.0)
            rng = np.random.default_rng(12345)
            m1 = self._mass_raw(q + 0.1 * rng.standard_normal(self.n), 0.0)
            scale = max(float(np.max(np.abs(m0))), 1e-300)
            self._mass_constant = bool(np.max(np.abs(m1 - m0)) <= MASS_CONSTANCY_TOLERANCE * scale)
            self._mass0 = m0
            logger.debug("mass matrix %s", "constant" if self._mass_constant else "configuration dependent")
        return self._mass_constant

    def constraints(self, q: np.ndarray, t: float) -> np.ndarray:
        """``C(q, t)``, shape ``(m,)``."""
        if not self.m:
            return np.zeros(0)
        self.set_state(q, np.zeros(self.n), t)
        self._solver.ComputeAlgebraicEquations(self.mbs, velocityLevel=False)
        return np.array(self._solver.GetSystemResidual(), dtype=float)[self.n + self.active]

    def constraint_jacobian(self, q: np.ndarray, t: float) -> np.ndarray:
        """``C_q(q, t)``, shape ``(m, n)``."""
        if not self.m:
            return np.zeros((0, self.n))
        J = self._ae_jacobian_full(q, t)[self.active]
        return J @ self.velocity_map(q) if self.has_lie_group_nodes else J

    def _ae_jacobian_full(self, q: np.ndarray, t: float) -> np.ndarray:
        """All of Exudyn's algebraic equations differentiated by ``q``, shape ``(m_exudyn, n)``."""
        self.set_state(q, np.zeros(self.n), t)
        self._solver.SetSystemJacobian(self._zero_jacobian)  # ComputeJacobianAE adds to it
        self._solver.ComputeJacobianAE(self.mbs, scalarFactor_ODE2=1.0, scalarFactor_ODE2_t=0.0,
                                       scalarFactor_ODE1=1.0, velocityLevel=False)
        J = np.array(self._solver.GetSystemJacobian(), dtype=float)
        return J[self.n: self.n + self.m_exudyn, : self.n].copy()

    # ----------------------------------------------------------------- labels
    def coordinate_labels(self) -> list[str]:
        """Per ODE2 coordinate, the name of its node's item (object name if one object
        owns the node, else the node name), e.g. ``"hub"`` or ``"beam3"``."""
        mbs = self.mbs
        sd = mbs.systemData
        labels = [""] * self.n
        owner: dict = {}
        for i in range(sd.NumberOfObjects()):
            obj = mbs.GetObject(i)
            for node in obj.get("nodeNumbers", [obj["nodeNumber"]] if "nodeNumber" in obj else []):
                owner.setdefault(int(node), []).append(obj.get("name", f"object{i}"))
        for j in range(sd.NumberOfNodes()):
            ltg = list(sd.GetNodeLTGODE2(j))
            if not ltg:
                continue
            names = owner.get(j, [])
            bases = {re.sub(r"[\s_]*\d+$", "", nm) for nm in names}
            if len(names) == 1:
                label = names[0]
            elif len(bases) == 1 and not names[0].startswith("object"):
                label = bases.pop()  # e.g. the elements "link 0", "link 1" of one beam share "link"
            else:
                label = mbs.GetNode(j).get("name", f"node{j}")
            for i in ltg:
                labels[int(i)] = label
        return labels

    def slope_nodes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """ANCF ``NodePoint2DSlope1`` nodes: ``(ODE2 indices (x, y, x', y'), reference coordinates)``."""
        mbs = self.mbs
        out = []
        for j in range(mbs.systemData.NumberOfNodes()):
            node = mbs.GetNode(j)
            if node.get("nodeType") == "Point2DSlope1":
                ltg = np.array(list(mbs.systemData.GetNodeLTGODE2(j)), dtype=int)
                out.append((ltg, np.asarray(node["referenceCoordinates"], dtype=float)))
        return out

    def planar_pairs(self) -> list[tuple]:
        """Coordinate pairs that are planar vectors, with the angle that orients them.

        Returns tuples ``(i_x, i_y, ref_x, ref_y, angle)``: positions of
        ``Point2D``, ``Point2DSlope1`` and ``RigidBody2D`` nodes and the slope
        vectors of ``Point2DSlope1`` nodes (ANCF cables); ``angle`` is
        ``("slope", i_sx, i_sy, ref_sx, ref_sy)`` (the node's slope direction),
        ``("rotation", i_phi)`` (a rigid body's angle) or ``("fit",)`` (the
        best-fit rotation of the whole system).  Used to co-rotate the
        independent-coordinate basis node by node.
        """
        mbs = self.mbs
        out = []
        for j in range(mbs.systemData.NumberOfNodes()):
            node = mbs.GetNode(j)
            kind = node.get("nodeType")
            ltg = [int(i) for i in mbs.systemData.GetNodeLTGODE2(j)]
            ref = np.asarray(node.get("referenceCoordinates", []), dtype=float)
            if kind == "Point2DSlope1" and len(ltg) == 4:
                ang = ("slope", ltg[2], ltg[3], float(ref[2]), float(ref[3]))
                out.append((ltg[0], ltg[1], float(ref[0]), float(ref[1]), ang))
                out.append((ltg[2], ltg[3], float(ref[2]), float(ref[3]), ang))
            elif kind == "RigidBody2D" and len(ltg) == 3:
                out.append((ltg[0], ltg[1], float(ref[0]), float(ref[1]), ("rotation", ltg[2])))
            elif kind == "Point2D" and len(ltg) == 2:
                out.append((ltg[0], ltg[1], float(ref[0]), float(ref[1]), ("fit",)))
        return out

    def rotation_coordinates(self) -> np.ndarray:
        """ODE2 indices of the angles a whole turn (2 pi) leaves the configuration unchanged for:
        the angle of ``RigidBody2D`` nodes and the three Tait-Bryan angles of ``RigidBodyRxyz`` nodes
        and of turning rotation-vector nodes (:attr:`charts`; they enter the kinematics through sines and
        cosines only).  The candidates for an orbit periodic up to whole turns
        (:func:`linearize.periodic_orbit.whole_turn_shift`)."""
        mbs = self.mbs
        out = []
        for j in range(mbs.systemData.NumberOfNodes()):
            kind = mbs.GetNode(j).get("nodeType")
            ltg = [int(i) for i in mbs.systemData.GetNodeLTGODE2(j)]
            if kind == "RigidBody2D" and len(ltg) == 3:
                out.append(ltg[2])
            elif kind == "RigidBodyRxyz" and len(ltg) == 6:
                out.extend(ltg[3:6])
        for c in self.charts:
            out.extend(int(i) for i in c.indices)
        return np.array(sorted(out), dtype=int)

    def rotation_parameters(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """3D nodes whose rotation coordinates are not angles: ``(node type, ODE2 indices, reference
        values)`` of the Euler parameters of ``RigidBodyEP`` nodes and the rotation vectors of
        ``RigidBodyRotVec*`` nodes.  After a whole turn Euler parameters come back with the opposite
        sign (the orbit map's sign flip, :func:`linearize.periodic_orbit.whole_turn_map`); a rotation-vector
        node that turns is presented in a Tait-Bryan chart instead (:meth:`set_turning_charts`; listed by
        :meth:`rotation_coordinates`, not here).  A rotation-vector node's velocity coordinates are Exudyn's
        body-fixed angular velocity, not the vector's rate (converted by the adapter, see the module
        docstring)."""
        mbs = self.mbs
        out = []
        for j in range(mbs.systemData.NumberOfNodes()):
            node = mbs.GetNode(j)
            kind = str(node.get("nodeType"))
            ltg = np.array([int(i) for i in mbs.systemData.GetNodeLTGODE2(j)], dtype=int)
            ref = np.asarray(node.get("referenceCoordinates", []), dtype=float)
            if kind == "RigidBodyEP" and ltg.size == 7:
                out.append((kind, ltg[3:7], ref[3:7]))
            elif kind.startswith("RigidBodyRotVec") and ltg.size == 6 and \
                    not any(int(c.indices[0]) == int(ltg[3]) for c in self.charts):
                out.append((kind, ltg[3:6], ref[3:6]))
        return out

    def describe(self) -> dict[str, Any]:
        return {"ode2": self.n, "constraints": self.m, "drives": [d.name for d in self.built.drives]}
