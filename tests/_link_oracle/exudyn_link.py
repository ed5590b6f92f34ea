"""Exudyn model of the single-link flexible manipulator (hub + ANCF beam + tip mass).

The model is built from the same :class:`~mbs_models.parameters.ManipulatorParameters`
as the paper's reduced model.  It consists of

* a rigid hub (``NodeRigidBody2D`` + ``ObjectRigidBody2D`` with inertia ``J1``)
  whose position is held at the origin O by two coordinate constraints;
* ``elements`` ``ObjectANCFCable2D`` elements for the link (generated with
  :func:`exudyn.beams.GenerateBeamElementsAlongLine` along the x-axis, the
  reference configuration), the first node clamped to the hub with an
  ``ObjectJointGeneric`` between two ``MarkerNodeRigid`` (position and slope
  angle follow the hub);
* the tip mass ``m_E`` as an ``ObjectMassPoint2D`` on the last beam node;
* gravity ``-g e_y`` on the beam and the tip mass (the hub rotates about O, so
  its own weight does no work): ``q_a = pi/2`` is the link pointing straight up;
* the joint damping ``alpha`` as a ``CoordinateSpringDamper`` on the hub angle.

Two drives (:attr:`ExudynLinkConfig.drive`):

``"prescribed"``
    The hub angle follows the fundamental motion ``q_a^R(t) = pi/2 + pi/2 sin(Omega t)``
    through a ``CoordinateConstraint`` with an offset user function; the joint
    reaction is the torque this motion needs.
``"free"``
    The hub is free and driven by ``tau = tau_ff(t) - kp (q_a - q_a^R) - kd (q_a' - q_a^R')``.
    The PD part is a ``CoordinateSpringDamper`` whose ``stiffness = kp`` and
    ``damping = kd`` are the values Exudyn's Jacobian uses, and whose spring
    force user function only shifts the spring's offset to ``q_a^R(t)`` (and
    the damper's to ``q_a^R'(t)``), so the implicit solver sees the exact
    derivative of the PD force.  The feed-forward ``tau_ff(t)`` depends on time
    only and is a ``LoadCoordinate`` with a user function.

Conventions (written once, here)
--------------------------------
* Exudyn's equations are ``M q'' = f(q, q', t) - C_q^T lambda``; ``f`` is the
  right-hand side (:meth:`ExudynLinkModel.rhs`), so linearised matrices on the
  left-hand side are ``K = -df/dq`` and ``C = -df/dq'``.
* Exudyn's ODE2 coordinates of nodes are displacements from the reference
  configuration; the *independent coordinates* used by this package are
  absolute (see :class:`ExudynLinkModel`).
* User functions see Exudyn's current simulation time ``t``; the fundamental
  motion starts at phase 0 at ``t = 0``.
* The matrices are small (about 40 x 40): set ``OPENBLAS_NUM_THREADS=1``
  before numpy is imported (the scripts and tests do); threads only slow
  them down.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from mbs_models.parameters import ManipulatorParameters

import exudyn as exu
from exudyn.beams import GenerateBeamElementsAlongLine
from exudyn.itemInterface import (
    CoordinateConstraint,
    CoordinateSpringDamper,
    LoadCoordinate,
    LoadMassProportional,
    MarkerBodyMass,
    MarkerNodeCoordinate,
    MarkerNodeRigid,
    NodePointGround,
    NodeRigidBody2D,
    ObjectANCFCable2D,
    ObjectGround,
    ObjectJointGeneric,
    ObjectMassPoint2D,
    ObjectRigidBody2D,
)

__all__ = [
    "DRIVES",
    "ExudynLinkConfig",
    "ExudynLinkModel",
    "ExudynSolverError",
    "FundamentalMotionSpec",
    "SimulationResult",
    "build_link_model",
    "fundamental_motion",
]

logger = logging.getLogger(__name__)

#: Hub drives understood by :func:`build_link_model`.
DRIVES = ("prescribed", "free")

#: Mass of the hub body.  The hub is held at O by constraints, so its mass never
#: enters the dynamics of the independent coordinates; Exudyn needs it > 0.
HUB_PLACEHOLDER_MASS = 1.0

#: Default generalised-alpha step and spectral radius (measured: h = 1e-3 and
#: rho_inf = 0.9 give the tip deflection to about 0.7 %).
DEFAULT_STEP = 1e-3
DEFAULT_SPECTRAL_RADIUS = 0.9

#: Newton tolerances used for simulations (tight, because the direct monodromy
#: differentiates simulated end states; 1e-10 relative made Newton stall and
#: cut the step 300-fold in our trials).
NEWTON_RELATIVE_TOLERANCE = 1e-8
NEWTON_ABSOLUTE_TOLERANCE = 1e-10


#: ``S`` with ``d/dphi R(phi) = R(phi) S`` for the 2D rotation matrix ``R``.
_SKEW = np.array([[0.0, -1.0], [1.0, 0.0]])


def _rotation(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


class ExudynSolverError(RuntimeError):
    """Exudyn's time integration failed (the message names the cause)."""


# --------------------------------------------------------------------------- config
@dataclass(frozen=True)
class ExudynLinkConfig:
    """Configuration of the Exudyn flexible-link model.

    Parameters
    ----------
    elements : int
        Number of ``ANCFCable2D`` elements of the link (default 8), >= 1.
    drive : {"prescribed", "free"}
        Hub drive, see the module docstring.
    omega : float
        Angular frequency ``Omega`` of the fundamental motion in rad/s (> 0).
    kp, kd : float
        PD gains on the hub angle (N m/rad, N m s/rad), >= 0; used by the
        ``"free"`` drive.
    bending_damping, axial_damping : float
        Optional structural damping of the ANCF elements (Exudyn's
        ``bendingDamping`` in N m^2 s and ``axialDamping`` in N s), >= 0.
        Default 0: the paper's link is undamped.
    mean_angle, amplitude : float
        Fundamental motion ``q_a^R(t) = mean_angle + amplitude sin(omega t)``
        (paper: pi/2 and pi/2).
    gravity : bool
        Whether gravity ``-g e_y`` acts (``g`` from the parameters).
    step_size : float
        Generalised-alpha step size in s for simulations (> 0).
    spectral_radius : float
        Generalised-alpha spectral radius at infinity, in [0, 1].

    Raises
    ------
    ValueError
        On a non-integer or non-positive element count, an unknown drive, or a
        negative / non-finite gain, damping, frequency or step.
    """

    elements: int = 8
    drive: str = "prescribed"
    omega: float = 2.0 * math.pi
    kp: float = 0.0
    kd: float = 0.0
    bending_damping: float = 0.0
    axial_damping: float = 0.0
    mean_angle: float = 0.5 * math.pi
    amplitude: float = 0.5 * math.pi
    gravity: bool = True
    step_size: float = DEFAULT_STEP
    spectral_radius: float = DEFAULT_SPECTRAL_RADIUS

    def __post_init__(self) -> None:
        if isinstance(self.elements, bool) or int(self.elements) != self.elements or self.elements < 1:
            raise ValueError(f"elements must be a positive integer, got {self.elements!r}")
        object.__setattr__(self, "elements", int(self.elements))
        if self.drive not in DRIVES:
            raise ValueError(f"drive must be one of {', '.join(DRIVES)}, got {self.drive!r}")
        for name in ("omega", "step_size"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0.0:
                raise ValueError(f"{name} must be finite and > 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        for name in ("kp", "kd", "bending_damping", "axial_damping"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0:
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        for name in ("mean_angle", "amplitude"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        if not (0.0 <= float(self.spectral_radius) <= 1.0):
            raise ValueError(f"spectral_radius must be in [0, 1], got {self.spectral_radius!r}")

    @property
    def period(self) -> float:
        """Period ``T = 2 pi / omega`` of the fundamental motion in s."""
        return 2.0 * math.pi / self.omega


@dataclass(frozen=True)
class FundamentalMotionSpec:
    """The rigid fundamental motion ``q_a^R(t) = mean + amplitude sin(omega t)``."""

    omega: float
    mean_angle: float
    amplitude: float

    def __call__(self, t: float | np.ndarray) -> tuple:
        """Return ``(q, q', q'')`` of the fundamental motion at ``t``."""
        s = np.sin(self.omega * np.asarray(t, dtype=float))
        c = np.cos(self.omega * np.asarray(t, dtype=float))
        return (
            self.mean_angle + self.amplitude * s,
            self.amplitude * self.omega * c,
            -self.amplitude * self.omega**2 * s,
        )


def fundamental_motion(config: ExudynLinkConfig) -> FundamentalMotionSpec:
    """The fundamental motion described by ``config``."""
    return FundamentalMotionSpec(config.omega, config.mean_angle, config.amplitude)


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class SimulationResult:
    """Result of one Exudyn time integration.

    Attributes
    ----------
    times : ndarray, shape (m,)
        Output times (every solver step, including the initial time).
    positions, velocities : ndarray, shape (m, n)
        Independent coordinates and their rates at ``times`` (see
        :class:`ExudynLinkModel`); only the first and last rows unless
        ``record=True`` was requested.
    hub_angle : ndarray, shape (m,)
        Hub angle ``q_a`` in rad.
    tip_deflection : ndarray, shape (m,)
        Tip displacement normal to the rigid line through O at the hub angle
        (m), positive in the direction of increasing ``q_a``.
    config : ExudynLinkConfig
        Configuration of the simulated model.
    t_start, t_end : float
        Simulated interval.
    wall_time : float
        Wall-clock time of the solve in s.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    hub_angle: np.ndarray
    tip_deflection: np.ndarray
    config: ExudynLinkConfig
    t_start: float
    t_end: float
    wall_time: float

    @property
    def final_state(self) -> np.ndarray:
        """``[p(t_end), p'(t_end)]`` in independent coordinates."""
        return np.concatenate([self.positions[-1], self.velocities[-1]])


# --------------------------------------------------------------------------- model
class ExudynLinkModel:
    """A built Exudyn flexible-link system with its independent-coordinate map.

    Use :func:`build_link_model` to create one.

    Independent coordinates
    -----------------------
    The clamped hub is parametrised explicitly (no null space of the
    constraint Jacobian is used), with ``n = 4 N + 2`` coordinates for ``N``
    elements::

        p = [q_a, s, u_1, u_1', ..., u_N, u_N']

    ``q_a`` is the hub angle, ``s = |r_0'|`` the stretch of the root slope
    (its direction is fixed to the hub's by the clamp, its position to O), and
    ``u_j = R(q_a)^T r_j``, ``u_j' = R(q_a)^T r_j'`` are the position and slope
    of beam node ``j`` in the hub frame (floating-frame coordinates; the
    undeformed link is ``u_j = (j l/N, 0)``, ``u_j' = (1, 0)`` at any hub
    angle).  A change of ``q_a`` alone rotates the whole link rigidly, as the
    paper's ``y_1``; the stiff parts of the linearised matrices (axial
    stiffness, ``kd/J1``) are then nearly constant along the orbit.  With the
    hub prescribed, ``q_a`` is given and ``p[1:]`` are the degrees of freedom.

    The map ``q = g(p)`` to Exudyn's ODE2 coordinates satisfies all
    constraints identically; with ``J = dg/dp`` the projected equations are
    ``J^T (M (J p'' + J' p') - f(g(p), J p', t)) = tau e_0`` (:meth:`residual`),
    where ``tau`` is an external torque on the hub (zero for the free hub with
    its drive modelled inside Exudyn).
    """

    def __init__(
        self,
        params: ManipulatorParameters,
        config: ExudynLinkConfig,
        feedforward: Optional[Callable[[float], float]],
    ) -> None:
        self.params = params
        self.config = config
        self.motion = fundamental_motion(config)
        self.feedforward = feedforward
        self._evaluator: Optional[exu.MainSolverImplicitSecondOrder] = None
        self._build()

    # ----------------------------------------------------------------- building
    def _build(self) -> None:
        p, cfg = self.params, self.config
        N = cfg.elements
        self.system_container = exu.SystemContainer()
        mbs = self.system_container.AddSystem()
        self.mbs = mbs
        ground = mbs.AddObject(ObjectGround())
        ground_node = mbs.AddNode(NodePointGround())
        m_ground = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground_node, coordinate=0))

        self.hub_node = mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, 0.0, 0.0]))
        mbs.AddObject(
            ObjectRigidBody2D(mass=HUB_PLACEHOLDER_MASS, inertia=p.hub_inertia, nodeNumber=self.hub_node)
        )
        hub_markers = [
            mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=self.hub_node, coordinate=c)) for c in range(3)
        ]
        for c in range(2):  # hub centre fixed at O
            mbs.AddObject(CoordinateConstraint(markerNumbers=[m_ground, hub_markers[c]]))

        template = ObjectANCFCable2D(
            massPerLength=p.mass_per_length,
            bendingStiffness=p.bending_stiffness,
            axialStiffness=p.axial_stiffness,
            bendingDamping=cfg.bending_damping,
            axialDamping=cfg.axial_damping,
        )
        beam = GenerateBeamElementsAlongLine(mbs, [0.0, 0.0, 0.0], [p.length, 0.0, 0.0], N, template)
        self.beam_nodes: list = list(beam["nodes"])
        self.beam_elements: list = list(beam["elements"])
        if len(self.beam_nodes) != N + 1:
            raise RuntimeError(f"expected {N + 1} beam nodes, Exudyn generated {len(self.beam_nodes)}")
        self.tip_body = mbs.AddObject(ObjectMassPoint2D(mass=p.tip_mass, nodeNumber=self.beam_nodes[-1]))

        # clamp: node 0 position and slope angle follow the hub (x, y, rot_z)
        m_hub_rigid = mbs.AddMarker(MarkerNodeRigid(nodeNumber=self.hub_node))
        m_root = mbs.AddMarker(MarkerNodeRigid(nodeNumber=self.beam_nodes[0]))
        mbs.AddObject(ObjectJointGeneric(markerNumbers=[m_hub_rigid, m_root], constrainedAxes=[1, 1, 0, 0, 0, 1]))

        if cfg.gravity and p.gravity > 0.0:
            for body in self.beam_elements + [self.tip_body]:
                mb = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
                mbs.AddLoad(LoadMassProportional(markerNumber=mb, loadVector=[0.0, -p.gravity, 0.0]))

        m_angle = hub_markers[2]
        if p.joint_damping > 0.0:
            mbs.AddObject(CoordinateSpringDamper(markerNumbers=[m_ground, m_angle], damping=p.joint_damping))

        motion = self.motion
        if cfg.drive == "prescribed":

            def offset(mbs_, t, item, value):  # noqa: ARG001  (Exudyn signature)
                return float(motion(t)[0])

            def offset_t(mbs_, t, item, value):  # noqa: ARG001
                return float(motion(t)[1])

            mbs.AddObject(
                CoordinateConstraint(
                    markerNumbers=[m_ground, m_angle],
                    offsetUserFunction=offset,
                    offsetUserFunction_t=offset_t,
                )
            )
        else:
            kp, kd = cfg.kp, cfg.kd
            if kp > 0.0 or kd > 0.0:

                def pd_force(mbs_, t, item, u, v, k, d, off):  # noqa: ARG001
                    qr, qr_t, _ = motion(t)
                    return k * (u - float(qr)) + d * (v - float(qr_t))

                mbs.AddObject(
                    CoordinateSpringDamper(
                        markerNumbers=[m_ground, m_angle],
                        stiffness=kp,
                        damping=kd,
                        springForceUserFunction=pd_force,
                    )
                )
            if self.feedforward is not None:
                ff = self.feedforward

                def load(mbs_, t, value):  # noqa: ARG001
                    return float(ff(t))

                mbs.AddLoad(LoadCoordinate(markerNumber=m_angle, load=0.0, loadUserFunction=load))
        mbs.Assemble()

        # index bookkeeping
        self.n_ode2 = mbs.systemData.ODE2Size()
        self.hub_index = mbs.GetNodeODE2Index(self.hub_node)
        self.node_index = np.array([mbs.GetNodeODE2Index(n) for n in self.beam_nodes], dtype=int)
        self.n = 4 * N + 2
        le = p.length / N
        self.reference_nodes = np.array([[j * le, 0.0, 1.0, 0.0] for j in range(N + 1)])
        # rows of q that equal independent coordinates one-to-one
        self._free_rows = np.concatenate([np.arange(i, i + 4) for i in self.node_index[1:]])
        self._reference_free = self.reference_nodes[1:].ravel()
        self._mass: Optional[np.ndarray] = None

    # ----------------------------------------------------------------- coordinate map
    def coordinates(self, p: np.ndarray) -> np.ndarray:
        """Exudyn ODE2 coordinates ``q = g(p)`` (displacements from the reference)."""
        p = np.asarray(p, dtype=float)
        th, s = float(p[0]), float(p[1])
        R = _rotation(th)
        q = np.zeros(self.n_ode2)
        q[self.hub_index + 2] = th
        r0 = self.node_index[0]
        q[r0 + 2] = s * R[0, 0] - 1.0
        q[r0 + 3] = s * R[1, 0]
        local = p[2:].reshape(-1, 2)  # rows: (x, y) of positions and slopes, hub frame
        q[self._free_rows] = (local @ R.T).ravel() - self._reference_free
        return q

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """``J = dg/dp``, shape ``(n_ode2, n)``."""
        p = np.asarray(p, dtype=float)
        th, s = float(p[0]), float(p[1])
        R = _rotation(th)
        RS = R @ _SKEW
        J = np.zeros((self.n_ode2, self.n))
        J[self.hub_index + 2, 0] = 1.0
        r0 = self.node_index[0]
        J[r0 + 2: r0 + 4, 0] = s * RS[:, 0]
        J[r0 + 2: r0 + 4, 1] = R[:, 0]
        local = p[2:].reshape(-1, 2)
        J[self._free_rows, 0] = (local @ RS.T).ravel()
        rows = self._free_rows.reshape(-1, 2)
        for k in range(rows.shape[0]):
            J[rows[k, 0]: rows[k, 0] + 2, 2 + 2 * k: 4 + 2 * k] = R
        return J

    def convective(self, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``J'(p, p') p'`` (the part of ``q''`` not proportional to ``p''``).

        For a hub-frame vector ``u`` the absolute vector is ``R u``; its second
        derivative is ``R u'' + q_a'' R S u + 2 q_a' R S u' - q_a'^2 R u``.
        """
        p = np.asarray(p, dtype=float)
        v = np.asarray(v, dtype=float)
        th, w = float(p[0]), float(v[0])
        R = _rotation(th)
        RS = R @ _SKEW
        a = np.zeros(self.n_ode2)
        r0 = self.node_index[0]
        u0 = np.array([p[1], 0.0])
        u0d = np.array([v[1], 0.0])
        a[r0 + 2: r0 + 4] = 2.0 * w * (RS @ u0d) - w * w * (R @ u0)
        local = p[2:].reshape(-1, 2)
        local_d = v[2:].reshape(-1, 2)
        a[self._free_rows] = (2.0 * w * (local_d @ RS.T) - w * w * (local @ R.T)).ravel()
        return a

    def independent(self, q: np.ndarray, q_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Independent coordinates and rates from Exudyn's ``(q, q')`` (inverse of ``g``)."""
        q = np.asarray(q, dtype=float)
        q_t = np.asarray(q_t, dtype=float)
        r0 = self.node_index[0]
        th = float(q[self.hub_index + 2])
        w = float(q_t[self.hub_index + 2])
        R = _rotation(th)
        sx, sy = q[r0 + 2] + 1.0, q[r0 + 3]
        s = math.hypot(sx, sy)
        p = np.empty(self.n)
        v = np.empty(self.n)
        p[0], p[1] = th, s
        v[0] = w
        v[1] = (sx * q_t[r0 + 2] + sy * q_t[r0 + 3]) / s
        absolute = (q[self._free_rows] + self._reference_free).reshape(-1, 2)
        absolute_d = q_t[self._free_rows].reshape(-1, 2)
        local = absolute @ R  # R^T applied to each row vector
        p[2:] = local.ravel()
        # d/dt (R u) = R u' + w R S u  =>  u' = R^T a' - w S u
        v[2:] = (absolute_d @ R - w * (local @ _SKEW.T)).ravel()
        return p, v

    def rigid_configuration(self, angle: float, rate: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Independent coordinates of the undeformed link at hub angle ``angle`` (and rate)."""
        N = self.config.elements
        le = self.params.length / N
        p = np.empty(self.n)
        v = np.zeros(self.n)
        p[0], p[1] = angle, 1.0
        v[0] = rate
        for j in range(1, N + 1):
            p[2 + 4 * (j - 1): 6 + 4 * (j - 1)] = [j * le, 0.0, 1.0, 0.0]
        return p, v
    def _solver(self) -> exu.MainSolverImplicitSecondOrder:
        if self._evaluator is None:
            solver = exu.MainSolverImplicitSecondOrder()
            settings = self._settings(end_time=1.0, record=False)
            solver.InitializeSolver(self.mbs, settings)
            self._evaluator = solver
            self._evaluator_settings = settings
        return self._evaluator

    def mass_matrix(self) -> np.ndarray:
        """Exudyn's ODE2 mass matrix (constant for this model), shape ``(n_ode2, n_ode2)``."""
        if self._mass is None:
            solver = self._solver()
            solver.ComputeMassMatrix(self.mbs)
            self._mass = np.array(solver.GetSystemMassMatrix(), dtype=float)
        return self._mass

    def rhs(self, q: np.ndarray, q_t: np.ndarray, t: float) -> np.ndarray:
        """Exudyn's ODE2 right-hand side ``f(q, q', t)`` (without constraint reactions)."""
        solver = self._solver()
        sd = self.mbs.systemData
        cur = exu.ConfigurationType.Current
        sd.SetODE2Coordinates(q, configuration=cur)
        sd.SetODE2Coordinates_t(q_t, configuration=cur)
        sd.SetTime(float(t), cur)
        solver.ComputeODE2RHS(self.mbs)
        return np.array(solver.GetSystemResidual()[: self.n_ode2], dtype=float)

    def stiffness_matrix(self, q: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Exudyn's own ``K = -df/dq`` at ``(q, q' = 0, t)``, shape ``(n_ode2, n_ode2)``."""
        solver = self._solver()
        sd = self.mbs.systemData
        cur = exu.ConfigurationType.Current
        sd.SetODE2Coordinates(q, configuration=cur)
        sd.SetODE2Coordinates_t(np.zeros(self.n_ode2), configuration=cur)
        sd.SetTime(float(t), cur)
        solver.ComputeJacobianODE2RHS(self.mbs, scalarFactor_ODE2=-1.0, scalarFactor_ODE2_t=0.0)
        return np.array(solver.GetSystemJacobian(), dtype=float)[: self.n_ode2, : self.n_ode2]

    def residual(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, t: float) -> np.ndarray:
        """Projected residual ``J^T (M q'' - f)`` in independent coordinates.

        Parameters
        ----------
        p, v, a : ndarray, shape (n,)
            Independent coordinates, rates and accelerations.
        t : float
            Time (user functions of the model see it).

        Returns
        -------
        ndarray, shape (n,)
            Zero on a motion of the model; entry 0 is the external hub torque
            the motion needs beyond the drive modelled inside Exudyn.
        """
        J = self.jacobian(p)
        q = self.coordinates(p)
        q_t = J @ v
        q_tt = J @ a + self.convective(p, v)
        return J.T @ (self.mass_matrix() @ q_tt - self.rhs(q, q_t, t))

    def reduced_mass(self, p: np.ndarray) -> np.ndarray:
        """``J^T M J`` at ``p``."""
        J = self.jacobian(p)
        return J.T @ self.mass_matrix() @ J

    # ----------------------------------------------------------------- simulation
    def _settings(self, end_time: float, record: bool, step: Optional[float] = None) -> exu.SimulationSettings:
        cfg = self.config
        h = cfg.step_size if step is None else float(step)
        s = exu.SimulationSettings()
        s.timeIntegration.endTime = float(end_time)
        s.timeIntegration.numberOfSteps = max(1, int(round(end_time / h)))
        s.timeIntegration.generalizedAlpha.spectralRadius = cfg.spectral_radius
        s.timeIntegration.verboseMode = 0
        s.timeIntegration.automaticStepSize = False  # fixed steps: a reproducible discrete map
        s.timeIntegration.newton.relativeTolerance = NEWTON_RELATIVE_TOLERANCE
        s.timeIntegration.newton.absoluteTolerance = NEWTON_ABSOLUTE_TOLERANCE
        s.show.statistics = False
        s.show.computationTime = False
        s.solution.file.write = False
        s.solution.file.writeInitialValues = False
        s.solution.sensors.writePeriod = h
        s.linearSolver.solverType = exu.LinearSolverType.EigenDense
        return s

    def simulate(
        self,
        p0: np.ndarray,
        v0: np.ndarray,
        t_end: float,
        *,
        t_start: float = 0.0,
        record: bool = False,
        step: Optional[float] = None,
    ) -> SimulationResult:
        """Integrate the nonlinear model with Exudyn's generalised-alpha solver.

        Parameters
        ----------
        p0, v0 : ndarray, shape (n,)
            Initial independent coordinates and rates (they are mapped through
            ``g`` and so satisfy the constraints).  With the prescribed drive
            ``p0[0], v0[0]`` must equal the fundamental motion at ``t_start``.
        t_end : float
            End time in s (> ``t_start``).
        t_start : float
            Start time in s (the user functions see absolute time).
        record : bool
            Record the state after every step (else only start and end).
        step : float, optional
            Step size; default ``config.step_size``.

        Returns
        -------
        SimulationResult

        Raises
        ------
        ExudynSolverError
            If Exudyn's solver reports a failure (Newton divergence, step
            reduction limit, ...).
        ValueError
            On non-finite initial states or ``t_end <= t_start``.
        """
        import time as _time

        p0 = np.asarray(p0, dtype=float)
        v0 = np.asarray(v0, dtype=float)
        if p0.shape != (self.n,) or v0.shape != (self.n,):
            raise ValueError(f"initial state must have shape ({self.n},), got {p0.shape}, {v0.shape}")
        if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(v0))):
            raise ValueError("initial state contains NaN or inf")
        if not t_end > t_start:
            raise ValueError(f"t_end must be > t_start, got {t_end!r} <= {t_start!r}")
        mbs = self.mbs
        sd = mbs.systemData
        ini = exu.ConfigurationType.Initial
        sd.SetODE2Coordinates(self.coordinates(p0), configuration=ini)
        sd.SetODE2Coordinates_t(self.jacobian(p0) @ v0, configuration=ini)
        settings = self._settings(t_end - t_start, record, step)
        settings.timeIntegration.startTime = float(t_start)
        settings.timeIntegration.endTime = float(t_end)
        times: list = []
        rows_q: list = []
        rows_v: list = []
        if record:
            def post_step(mbs_, t):
                times.append(t)
                rows_q.append(np.array(mbs_.systemData.GetODE2Coordinates()))
                rows_v.append(np.array(mbs_.systemData.GetODE2Coordinates_t()))
                return True

            mbs.SetPostStepUserFunction(post_step)
        else:
            mbs.SetPostStepUserFunction(0)
        tic = _time.perf_counter()
        try:
            ok = mbs.SolveDynamic(settings)
        except Exception as exc:  # Exudyn raises its own error types
            raise ExudynSolverError(
                f"Exudyn time integration failed on [{t_start:g}, {t_end:g}] s with "
                f"{self.config.elements} elements: {exc}"
            ) from exc
        finally:
            mbs.SetPostStepUserFunction(0)
        wall = _time.perf_counter() - tic
        if ok is False:
            raise ExudynSolverError(
                f"Exudyn time integration did not succeed on [{t_start:g}, {t_end:g}] s "
                f"(step {settings.timeIntegration.endTime / settings.timeIntegration.numberOfSteps:g} s)"
            )
        q_end = np.array(sd.GetODE2Coordinates())
        v_end = np.array(sd.GetODE2Coordinates_t())
        if not (np.all(np.isfinite(q_end)) and np.all(np.isfinite(v_end))):
            raise ExudynSolverError("Exudyn time integration returned NaN or inf (diverged)")
        if record:
            # Exudyn may call the post-step function for the initial state too
            keep = [i for i, ti in enumerate(times) if ti > t_start + 1e-12 * max(1.0, abs(t_start))]
            t_all = np.concatenate([[t_start], np.asarray(times)[keep]])
            qs = [self.coordinates(p0)] + [rows_q[i] for i in keep]
            vs = [self.jacobian(p0) @ v0] + [rows_v[i] for i in keep]
        else:
            t_all = np.array([t_start, t_end])
            qs = [self.coordinates(p0), q_end]
            vs = [self.jacobian(p0) @ v0, v_end]
        P = np.empty((len(qs), self.n))
        V = np.empty((len(qs), self.n))
        for i, (q, qt) in enumerate(zip(qs, vs)):
            P[i], V[i] = self.independent(q, qt)
        return SimulationResult(
            times=t_all,
            positions=P,
            velocities=V,
            hub_angle=P[:, 0].copy(),
            tip_deflection=self.tip_deflection(P),
            config=self.config,
            t_start=float(t_start),
            t_end=float(t_end),
            wall_time=wall,
        )

    def tip_deflection(self, positions: np.ndarray) -> np.ndarray:
        """Tip displacement normal to the rigid line at the hub angle, shape ``(m,)``."""
        P = np.atleast_2d(positions)
        return P[:, -3].copy()  # y of the tip in the hub frame


def build_link_model(
    params: Optional[ManipulatorParameters] = None,
    config: Optional[ExudynLinkConfig] = None,
    *,
    feedforward: Optional[Callable[[float], float]] = None,
) -> ExudynLinkModel:
    """Build the Exudyn flexible-link model.

    Parameters
    ----------
    params : ManipulatorParameters, optional
        Physical data (default: the paper's Table 1).
    config : ExudynLinkConfig, optional
        Discretisation, drive and gains (default: 8 elements, prescribed hub,
        Omega = 2 pi).
    feedforward : callable, optional
        ``t -> tau_ff(t)`` hub torque for the ``"free"`` drive (N m), e.g.
        :attr:`_link_oracle.link_orbit.PeriodicOrbit.hub_torque`.  Ignored by the
        prescribed drive.

    Returns
    -------
    ExudynLinkModel

    Raises
    ------
    ValueError
        On invalid parameters or configuration (e.g. zero elements).
    """
    params = ManipulatorParameters() if params is None else params
    config = ExudynLinkConfig() if config is None else config
    if not isinstance(params, ManipulatorParameters):
        raise ValueError(f"params must be ManipulatorParameters, got {type(params).__name__}")
    if not isinstance(config, ExudynLinkConfig):
        raise ValueError(f"config must be ExudynLinkConfig, got {type(config).__name__}")
    logger.debug("building Exudyn link: %s", config)
    return ExudynLinkModel(params, config, feedforward)
