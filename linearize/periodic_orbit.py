"""Periodic orbit of a model file with its drives prescribed.

Equations (Exudyn's convention, see :mod:`linearize.exudyn_system`)::

    M(q) q'' - f(q, q', t) + C_q(q, t)^T lambda - B tau = 0     (n equations)
    C(q, t) = 0                                                 (m, the model's constraints)
    B^T q - r(t) = 0                                            (one per drive)

``B`` has one column per drive (+1 at marker m1's coordinate, -1 at m0's),
``r(t)`` are the drives' motions and ``tau`` the feed-forward torques (the
reactions of the drive constraints; positive ``tau`` pushes the driven
coordinate ``q[m1] - q[m0]`` up).

Method
------
Trigonometric collocation: all ODE2 coordinates ``q``, multipliers ``lambda``
and torques ``tau`` are unknown at ``K`` equispaced samples; rates and
accelerations are spectral derivatives (``D1 q``, ``D2 q``).  Newton's method
solves the ``K (n + m + d)`` equations at once: first with full steps (at most
:data:`FULL_STEP_ITERATIONS`; the Newton matrix is refreshed unless the last
step cut the residual :data:`CHORD_REUSE_FACTOR`-fold), and if that does not
reach the tolerance, damped with a natural monotonicity test from the same
guess, with the Jacobian blocks
``K_k delta_kj + C_k D1_kj + M_k D2_kj`` built from (Richardson-extrapolated)
central differences of
Exudyn's functions (:func:`tangent_blocks`; ``K_k`` contains the mass-matrix
dependence and the constraint-reaction stiffness, the latter by column-compressed
differences on the constraints' structural pattern).  The guess is one period of
Exudyn's own integrator from the model file's initial state with the drives
prescribed; if full steps from it fail, full steps from the quasi-static guess
(the drives on their motions, the model in static equilibrium at every sample,
:func:`_quasi_static_guess`) are tried before the damped Newton.  If all fail,
natural continuation in ``omega`` from ``omega/2`` (the model is rebuilt at each
``omega``; a start without an orbit is halved at most twice, to ``omega/8``, and a
step whose damped Newton does not halve the residual within a few iterations is
halved instead).  Measured on the single link (8 elements, 32 samples): full steps from
the simulated period converge at 1 to 8.5 pi and 10 pi, the quasi-static guess
rescues 9 pi, 9.5 pi and 12 pi; 11 pi still needs continuation.

Check in Exudyn itself (:attr:`PeriodicOrbit.shooting_residual`): one period of
Exudyn's generalised-alpha integrator (spectral radius 0.9) from the orbit's state at ``t = 0`` with the drives prescribed by
``CoordinateConstraint`` objects; the defect ``x(T) - x(0)`` is reported
relative to the variation of the state along the orbit.
"""
from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
import scipy.linalg

from linearize import collocation_solver as structured
from linearize.exudyn_system import (ExudynSystem, from_exudyn_state, lie_group_nodes, rotation_matrix,
                                     rotation_vector, to_exudyn_state, turning_chart)
from linearize.finite_difference import CENTRAL_DIFFERENCE_STEP, fd_steps
from linearize.fourier import (antiperiodic_differentiation_matrices, antiperiodic_interpolate, differentiation_matrices,
                               sample_times, trig_interpolate)
from linearize.piecewise import PiecewiseGrid
from mbs_models.model_file import BuiltModel, ModelDefinition, ModelFileError, build_model, resolve_model

__all__ = [
    "DEFAULT_SAMPLES",
    "DEFAULT_TOLERANCE",
    "SHOOTING_STEPS_PER_SAMPLE",
    "SHOOTING_TOLERANCE",
    "OrbitConvergenceError",
    "SOLVERS",
    "PeriodicOrbit",
    "TangentBlocks",
    "find_orbit",
    "tangent_blocks",
    "apply_map",
    "whole_turn_map",
    "whole_turn_shift",
]

logger = logging.getLogger(__name__)

#: Collocation samples per period (even).
DEFAULT_SAMPLES = 32
#: Newton stops when the relative residual (forces relative to the largest
#: applied / inertia force, constraint and drive residuals relative to the
#: largest coordinate, at least 1) is below this.  Attainable floor with stiff
#: ANCF elements is ~1e-7 (EA/l_e ~ 2.5e8 N/m times round-off of 1 m coordinates
#: against forces ~0.5 N).
DEFAULT_TOLERANCE = 1e-6
#: ... or when the Newton update is at round-off (this times the coordinate scale)
#: and the residual within 1e3 of the tolerance.
UPDATE_TOLERANCE = 1e-13
DEFAULT_MAX_ITERATIONS = 30
#: Newton gives up when after this many iterations the residual is above its start.
STAGNATION_ITERATIONS = 8
#: ... and when after this many iterations it has not halved.
EARLY_GIVE_UP_ITERATIONS = 5
EARLY_GIVE_UP_FACTOR = 0.5
MAX_STEP_HALVINGS = 12
#: Full-step Newton iterations tried before the damped Newton.  A full step from
#: the simulated guess typically first over-stretches the ANCF beams (their linearised
#: motion in absolute coordinates leaves the rotation's circle) and the next step
#: undoes it; the natural monotonicity test of the damped Newton rejects such steps,
#: which is why it failed on the single link at 6 pi and 8 pi (8 elements) and needed
#: a long continuation in omega.  Measured full Newton steps to 1e-6 from the simulated
#: period on the single link (8 elements, 32 samples): 2, 5, 5, 5 at 2, 4, 6, 8 pi;
#: two-link (default mesh) 2, 4 at 2, 4 pi.
FULL_STEP_ITERATIONS = 10
#: ... and continues beyond it (up to ``max_iterations``) only while every step at least
#: halves the residual (slow but steady convergence near a resonance, e.g. 12 pi).
FULL_STEP_CONTRACTION = 0.5
#: The full-step phase gives up early when after this many iterations the residual
#: has not fallen below :data:`FULL_STEP_PROGRESS` times its start.
FULL_STEP_CHECK = 5
FULL_STEP_PROGRESS = 0.1
#: The Newton matrix of the full-step phase is reused (chord step) only after a step
#: that cut the residual this much (the quadratic phase, where the old matrix still
#: contracts fast); otherwise it is rebuilt at the new iterate.
CHORD_REUSE_FACTOR = 0.01
#: An orbit found from the simulated guess is accepted only while every rotation coordinate
#: (:meth:`~linearize.exudyn_system.ExudynSystem.rotation_coordinates`) stays within this of the guess at
#: the same sample, up to whole turns (both in their periodic part, the whole turns of the orbit map
#: taken out): half of the half turn that separates a hanging from an inverted body, larger than the
#: difference between a transient swing and the orbit it decays to for the models the guess is meant for.
#: A Newton that lands further away has jumped to another orbit (e.g. the inverted pendulum).
NEAR_GUESS_ANGLE = 0.5 * math.pi
#: ... and every rigid-body node's position within this fraction of the model's size (the largest
#: distance of such a node from the origin or from another one along the guess, at least 1 as the
#: coordinate scale of the relative residual): a body turned over
#: about a pivot moves its centre of mass by twice its distance from the pivot; the forced swing about
#: the orbit a model file sets up, and a transient decaying to it, move it by a small part of that.
NEAR_GUESS_SIZE = 0.5
#: Continuation in omega: start factor, first increment, smallest increment, solves.
CONTINUATION_START = 0.5
CONTINUATION_STEP = 0.1
CONTINUATION_MIN_STEP = 1e-3
CONTINUATION_MAX_SOLVES = 40
#: When no orbit is found at the start factor, it is halved at most this often (starts at 1/2, 1/4 and
#: 1/8 of omega).  At omega/8 the inertia forces of the prescribed motion are 1/64 of those at omega: a
#: lower start is no better guess, it only lengthens the simulated guess period and Exudyn's run with it
#: (measured on a very soft single link, E = 2e7 N/m^2, 1 element, 32 samples: a failed start costs
#: 1.1 s at omega/2 and 19 s at omega/16384; halving down to the solve budget, omega/2^40, takes ~15 min).  Every
#: continuation measured on the single link (1, 4 and 8 elements at 11 pi) started at omega/2.
CONTINUATION_START_HALVINGS = 2
#: Integrator steps per collocation sample for the guess and the shooting check.
SHOOTING_STEPS_PER_SAMPLE = 16
#: The shooting check passes when the one-period defect, relative to the
#: variation of the state along the orbit, is below this.  Generalised-alpha
#: (second order) has a global error ~ (omega_max h)^2 / 12 for the
#: fastest resolved motion; with 16 steps per sample of a 32-sample orbit the
#: harmonics the orbit keeps (<= 16 omega) have omega h <= 2 pi / 32, i.e. an
#: error <= 3e-3 of their amplitude; 1e-2 leaves a factor of 3.
SHOOTING_TOLERANCE = 1e-2
#: The defect is relative to the orbit's variation, but to no less than this times the size of its
#: coordinates and rates: Exudyn's Newton tolerance in these runs (:data:`NEWTON_RELATIVE_TOLERANCE`)
#: resolves the state no better.
SHOOTING_FLOOR = 1e-6


#: Newton tolerances of Exudyn's integrator in the guess and shooting runs.  The
#: round-off floor of the residual grows with the mesh (axial stiffness EA/l_e);
#: measured on the single link, 1e-8 is below it from 32 elements on (Exudyn's
#: Newton then runs to its iteration limit at every step: 18679 iterations for
#: 128 steps, 6.4 s, against 256 iterations, 0.15 s, at 1e-6).  1e-6 is enough:
#: the step error it leaves is <= 1e-6 relative, over the 16 K = 512 steps of a
#: run <= 5e-4 of the state's variation (linear accumulation, worst case), 20x
#: below :data:`SHOOTING_TOLERANCE`; the guess is refined by the collocation
#: Newton, whose tolerance is unchanged.
NEWTON_RELATIVE_TOLERANCE = 1e-6
NEWTON_ABSOLUTE_TOLERANCE = 1e-10


#: Exudyn runs with more unknowns (ODE2 + AE) than this use Exudyn's sparse linear
#: solver (same integrator and Newton tolerance, only the factorisation differs):
#: measured on the single link, one period (512 steps) at 64 elements (272
#: unknowns) 0.83 s CPU sparse vs 2.44 s dense; at 32 elements (144) 0.03 vs 0.04 s
#: per 32 steps.
SPARSE_SIMULATION_SIZE = 100


#: Generalised-alpha spectral radius of the guess and shooting runs: index-3
#: constraints need some numerical damping (rho_inf = 1 failed on the single
#: link's clamp); 0.9 is the value the single-link simulations use.
SHOOTING_SPECTRAL_RADIUS = 0.9


class ExudynRunError(RuntimeError):
    """Exudyn's time integration failed."""


class OrbitConvergenceError(RuntimeError):
    """Newton did not find the periodic orbit; the message says how far it got.

    Attributes
    ----------
    residuals : list of float
        Relative residual after each Newton iteration.
    """

    def __init__(self, message: str, residuals: list) -> None:
        super().__init__(message)
        self.residuals = list(residuals)


@dataclass(frozen=True)
class TangentBlocks:
    """Finite-difference linearisation of the unconstrained-drive equations at the samples.

    For ``r(q, q', q'', lambda, t) = M(q) q'' - f(q, q', t) + C_q(q, t)^T lambda``:

    Attributes
    ----------
    M : ndarray, shape (K, n, n)
        ``M(q_k)``.
    K_force : ndarray, shape (K, n, n)
        ``d/dq [M(q) q_k'' - f(q, q_k', t_k)]`` (mass-matrix dependence included).
    K_reaction : ndarray, shape (K, n, n)
        ``d/dq [C_q(q, t_k)^T lambda_k]``, the constraint-reaction stiffness.
    C : ndarray, shape (K, n, n)
        ``-df/dq'``.
    Cq : ndarray, shape (K, m, n)
        ``C_q(q_k, t_k)``.
    exudyn_jacobian : bool
        Whether ``K_force`` and ``C`` are Exudyn's own (checked) Jacobians.
    """

    M: np.ndarray
    K_force: np.ndarray
    K_reaction: np.ndarray
    C: np.ndarray
    Cq: np.ndarray
    exudyn_jacobian: bool = False

    @property
    def K(self) -> np.ndarray:
        """``K_force + K_reaction``."""
        return self.K_force + self.K_reaction


@dataclass(frozen=True)
class PeriodicOrbit:
    """A T-periodic motion of a model with its drives on their motions.

    Attributes
    ----------
    model : ModelDefinition
    omega, period : float
    times : ndarray, shape (K,)
        Sample times ``k T / K``.
    q, q_t, q_tt : ndarray, shape (K, n)
        Exudyn ODE2 coordinates and their spectral time derivatives.
    lambdas : ndarray, shape (K, m)
        Multipliers of the model's own constraints (``M q'' = f - C_q^T lambda + B tau``).
    torques : ndarray, shape (K, d)
        Feed-forward torque of each drive.
    drive_names : tuple of str
    drive_vectors : ndarray, shape (n, d)
        ``B``.
    residual : float
        Relative collocation residual reached (see :data:`DEFAULT_TOLERANCE`).
    tolerance : float
        The tolerance it had to reach.
    shooting_residual : float
        Relative one-period defect of Exudyn's integrator from the orbit state
        (NaN when not checked); must be below :data:`SHOOTING_TOLERANCE`.
    iterations : int
        Newton iterations (continuation included).
    tangent : TangentBlocks
        The linearisation at the converged samples (reused by
        :func:`linearize.constrained.linearize_orbit`).
    coordinate_labels : tuple of str
        Exudyn item name per ODE2 coordinate.
    slope_nodes : tuple
        ANCF slope nodes ``(ODE2 indices, reference coordinates)`` (for mode labels).
    planar_pairs : tuple
        Planar vector coordinates ``(i_x, i_y, ref_x, ref_y)`` (for the co-rotating basis).
    shift : ndarray, shape (n,)
        Whole turns per period: ``q(t + T) = q(t) + shift`` (zero for a T-periodic orbit;
        :func:`whole_turn_shift`).  ``q`` holds the coordinates themselves (with the turns);
        ``q_t``, ``q_tt``, the multipliers and torques are T-periodic.
    signs, references : ndarray, shape (n,)
        The rest of the orbit map ``q(t + T) = g(q(t))`` (:func:`apply_map`): ``signs`` is -1 on the
        Euler parameters of a body that turns an odd number of times per period (their absolute values
        ``q + references`` change sign), +1 elsewhere.  The rates map by ``S = diag(signs)``.
    charts : tuple of TurningChart
        The Tait-Bryan charts of the rotation-vector nodes that turn (:class:`~linearize.exudyn_system.TurningChart`):
        ``q`` holds their angles, not Exudyn's coordinates (empty when none turns).
    autonomous : bool
        The model has no drives and does not depend on time: the orbit is one of a family of time
        shifts (e.g. a free spin turned about its axis), its phase was fixed by a phase condition, and
        one multiplier 1 is structural (the family's direction), not a property of the motion's
        stability.
    wall_time : float
    timings, cpu_timings : dict
        Wall-clock and CPU seconds per stage: ``build`` (model and collocation set-up),
        ``guess`` (the simulated period), ``newton`` (continuation included),
        ``tangent`` (the accurate linearisation blocks at the converged samples) and
        ``shooting`` (the check in Exudyn, 0 when not run).
    """

    model: ModelDefinition = field(repr=False)
    omega: float
    period: float
    times: np.ndarray = field(repr=False)
    q: np.ndarray = field(repr=False)
    q_t: np.ndarray = field(repr=False)
    q_tt: np.ndarray = field(repr=False)
    lambdas: np.ndarray = field(repr=False)
    torques: np.ndarray = field(repr=False)
    drive_names: tuple
    drive_vectors: np.ndarray = field(repr=False)
    residual: float
    tolerance: float
    shooting_residual: float
    iterations: int
    tangent: TangentBlocks = field(repr=False)
    coordinate_labels: tuple = field(repr=False, default=())
    slope_nodes: tuple = field(repr=False, default=())
    planar_pairs: tuple = field(repr=False, default=())
    wall_time: float = 0.0
    timings: dict = field(default_factory=dict, repr=False)
    cpu_timings: dict = field(default_factory=dict, repr=False)
    shift: Optional[np.ndarray] = field(default=None, repr=False)
    signs: Optional[np.ndarray] = field(default=None, repr=False)
    references: Optional[np.ndarray] = field(default=None, repr=False)
    autonomous: bool = False
    breakpoints: tuple = ()
    charts: tuple = ()

    def __post_init__(self) -> None:
        n = self.q.shape[1]
        for name, default in (("shift", 0.0), ("signs", 1.0), ("references", 0.0)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(n, default))

    @property
    def antiperiodic(self) -> np.ndarray:
        """Indices of the coordinates whose absolute value changes sign over a period (the Euler
        parameters of a body that turns): ``q(t + T) + ref = -(q(t) + ref)``."""
        return np.flatnonzero(self.signs < 0)

    def map_state(self, q: np.ndarray, v: np.ndarray, periods: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The orbit map applied ``periods`` times to a state: ``(g^j(q), S^j v)``
        (:func:`apply_map`; ``S = diag(signs)``)."""
        j = int(periods)
        return apply_map(q, self.shift, self.signs, self.references, j), self.signs ** j * np.asarray(v, dtype=float)

    @property
    def grid(self) -> Optional[PiecewiseGrid]:
        """The piecewise sampling (:class:`~linearize.piecewise.PiecewiseGrid`) when the drives declare
        breakpoints; ``None`` for the equispaced trigonometric one."""
        if not self.breakpoints:
            return None
        grid = self.__dict__.get("_grid")
        if grid is None:
            grid = PiecewiseGrid(self.period, self.breakpoints, self.samples)
            object.__setattr__(self, "_grid", grid)  # a cache, not a field
        return grid

    @property
    def samples(self) -> int:
        return int(self.times.size)

    @property
    def q_periodic(self) -> np.ndarray:
        """The periodic part ``q(t_k) - shift t_k / T`` of the samples, shape ``(K, n)``."""
        return self.q - self.times[:, None] * (self.shift[None, :] / self.period)

    def reference(self, t: float) -> np.ndarray:
        """``q0(t)`` at a whole number of periods ``t = j T`` (``q[0] + j shift``); other times
        by :meth:`state`."""
        j = round(float(t) / self.period)
        if abs(float(t) - j * self.period) > 1e-9 * self.period * max(1, abs(j)) or self.breakpoints:
            return self.state(float(t))[0]  # (piecewise sampling has no node at t = 0)
        return self.map_state(self.q[0], self.q_t[0], j)[0]

    @property
    def size(self) -> int:
        """ODE2 coordinates ``n``."""
        return int(self.q.shape[1])

    def state(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, q', q'')`` at ``t`` by trigonometric interpolation (piecewise sampling: the ``C^1``
        piecewise polynomial the collocation solved for and its derivatives, :attr:`grid`)."""
        ramp = np.multiply.outer(np.asarray(t, dtype=float), self.shift / self.period)
        grid = self.grid
        if grid is not None:  # (no sign flips with breakpoints: refused by the collocation)
            p = self.q_periodic
            return (grid.smooth(p, t) + ramp, grid.smooth(p, t, 1) + self.shift / self.period, grid.smooth(p, t, 2))
        out = [trig_interpolate(self.q_periodic, self.period, t) + ramp, trig_interpolate(self.q_t, self.period, t),
               trig_interpolate(self.q_tt, self.period, t)]
        a = self.antiperiodic
        if a.size:  # Euler parameters of a turning body: antiperiodic (absolute values)
            for k, (samples, offset) in enumerate(((self.q[:, a], self.references[a]), (self.q_t[:, a], 0.0),
                                                   (self.q_tt[:, a], 0.0))):
                out[k][..., a] = antiperiodic_interpolate(samples + offset, self.period, t) - offset
        return tuple(out)

    def torque(self, t: float | np.ndarray) -> np.ndarray:
        """Feed-forward torques at ``t`` (shape ``(d,)`` or ``(m, d)``)."""
        grid = self.grid
        if grid is not None:
            return grid.interpolate(self.torques, t)
        return trig_interpolate(self.torques, self.period, t)

    def summary(self) -> dict:
        return {
            "model": self.model.name,
            "omega": self.omega,
            "samples": self.samples,
            "ode2": self.size,
            "constraints": int(self.lambdas.shape[1]),
            "drives": list(self.drive_names),
            "orbit_residual": float(self.residual),
            "shooting_residual": float(self.shooting_residual),
            "iterations": self.iterations,
            "turns": {f"{self.coordinate_labels[i] if self.coordinate_labels else 'q'}[{int(i)}]":
                      int(round(float(self.shift[i]) / (2 * math.pi))) for i in np.flatnonzero(self.shift)},
            "sign_flips": [f"{self.coordinate_labels[i] if self.coordinate_labels else 'q'}[{int(i)}]"
                           for i in self.antiperiodic],
            "autonomous": bool(self.autonomous),
            "torque_max": [float(v) for v in np.max(np.abs(self.torques), axis=0)] if self.torques.size else [],
        }


# --------------------------------------------------------------------------- tangent
#: Base step of the Richardson-extrapolated central differences of
#: :func:`tangent_blocks`: the error of ``(4 D(h/2) - D(h)) / 3`` is
#: ``O(h^4)`` truncation plus ``O(eps / h)`` round-off, balanced at
#: ``h ~ eps^(1/5)`` for unit-size derivatives; the stiff beams have large
#: higher derivatives, so the step is ``eps^(1/4)`` (1.2e-4, relative, times
#: ``max(1, |q_j|)``): measured on the single link (2 elements), the hub
#: multiplier moves by 4e-8 between eps^(1/5) and eps^(1/5)/4 and by 1e-10
#: between eps^(1/5)/4 and eps^(1/5)/16.  Plain central
#: differences (``O(h^2)``, step ``eps^(1/3)``) are not enough for stiff beams
#: in absolute coordinates: the cubic axial-strain terms (EA/l_e^3 ~ 1e8) give
#: a truncation error ~1e-3 N/m in the soft (rigid-rotation) directions, which
#: moved the single link's hub multiplier by 1.4e-5 (measured).
RICHARDSON_STEP = float(np.finfo(float).eps ** 0.25)


def _richardson(fun, x: np.ndarray, e: np.ndarray, h: float) -> np.ndarray:
    """``d/ds fun(x + s e)`` at 0 by Richardson-extrapolated central differences."""
    d1 = (fun(x + h * e) - fun(x - h * e)) / (2 * h)
    d2 = (fun(x + 0.5 * h * e) - fun(x - 0.5 * h * e)) / h
    return (4.0 * d2 - d1) / 3.0


#: Exudyn's force Jacobians are accepted when Richardson differences along random
#: directions ``e`` agree with ``J e`` to this *in every row*, relative to that row's
#: ``(|J| |e|)_i`` plus the differences' round-off
#: (:func:`~linearize.collocation_solver.directional_mismatch`).  Per row, because the
#: rows differ by eight decades (32 elements: axial rows 2.4e9 N/m, the hub's row 0,
#: the softest nonzero rows ~1e5 with entries down to 10 N/m): normalised by the largest
#: row, a wrong entry of 24 N/m in the hub's row passed, where 1e-3 N/m in the soft
#: directions moves the hub multiplier by 1.4e-5 (:data:`RICHARDSON_STEP`).  Derivation:
#: an exact Jacobian differs from the refined reference by the reference's error only,
#: kept below :data:`JACOBIAN_REFERENCE_FRACTION` of this (measured <= 7e-10 of the row at
#: the first accepted halving, 32 elements); a forward-difference Jacobian with Exudyn's
#: default step 1e-7 is off by ~1e-7 of the row.  So a wrong entry is seen when it exceeds
#: 1e-8 of its row's summed magnitude: below that, no difference check at double
#: precision can tell it from the reference's own error (the per-column differences that
#: replace a rejected Jacobian carry errors of the same order).
JACOBIAN_CHECK_TOLERANCE = 1e-8
JACOBIAN_CHECK_DIRECTIONS = 2
#: The reference directional derivative must have an estimated error below this
#: fraction of each row's allowance (so that a correct Jacobian passes with a margin of
#: 10 and one off by more than 1.1x the tolerance fails) ...
JACOBIAN_REFERENCE_FRACTION = 0.1
#: ... reached by halving the step at most this often (the truncation error of the
#: Richardson rule falls 16-fold per halving, its round-off grows 2-fold).  Measured on
#: the single link at 32 elements, the estimate equals the true error (against Exudyn's
#: Jacobian) down to a round-off floor of ~1e-11 relative at ``RICHARDSON_STEP / 16``;
#: at a strongly distorted state (random 1e-2 m coordinate perturbations) 1e-9 needs 4
#: halvings, 6 leave a margin.
JACOBIAN_REFERENCE_HALVINGS = 6


def _force_functions(system: ExudynSystem, q, v, a, t, const_mass):
    """``(force, damping)``: ``x -> M(x) a - f(x, v, t)`` (``-f`` when ``M`` is constant)
    and ``y -> -f(q, y, t)``, whose Jacobians are ``K`` and ``C``."""

    def force(x):
        r = -system.rhs(x, v, t)
        return r if const_mass else r + system.mass(x, t) @ a

    def damping(y):
        return -system.rhs(q, y, t)

    return force, damping


def _force_fd(system: ExudynSystem, q, v, a, t, step, const_mass):
    n = system.n
    hq = fd_steps(q, step)
    hv = fd_steps(v, step)
    force, damping = _force_functions(system, q, v, a, t, const_mass)
    K = np.empty((n, n))
    C = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        K[:, j] = _richardson(force, q, e, hq[j])
        C[:, j] = _richardson(damping, v, e, hv[j])
    return K, C


_FORCE_CHECK_SEED = 20261128


def _force_compressed(system: ExudynSystem, q, v, a, t, step, const_mass, pattern, rng):
    """``(K, C)`` of :func:`_force_fd` by column-compressed differences on the structural
    force pattern (:func:`linearize.collocation_solver.coupling_pattern`), or ``None`` when
    the pattern fails its check.

    Same rule (:func:`_richardson`) and steps as :func:`_force_fd`; a row depends on at most
    one column of a colour, so every entry is the same difference of the same function values
    (only the division by the step is ordered differently: round-off).  Check: a random
    directional derivative, refined to a tenth of each row's tolerance, against ``J e``
    row by row (:func:`~linearize.collocation_solver.directional_mismatch`); a coupling the
    pattern misses contributes its weight in its own row, the rule's own error <= 1e-9 of
    the row (see :data:`~linearize.collocation_solver.PATTERN_CHECK_TOLERANCE`).
    """
    n = system.n
    hq, hv = fd_steps(q, step), fd_steps(v, step)
    force, damping = _force_functions(system, q, v, a, t, const_mass)
    K = np.zeros((n, n))
    C = np.zeros((n, n))
    tol = structured.PATTERN_CHECK_TOLERANCE
    for J, fun, x, h in ((K, force, q, hq), (C, damping, v, hv)):
        structured._compressed(fun, x, h, pattern.force_colours, pattern.force, _richardson, J)
        e = h * rng.uniform(-1.0, 1.0, n)
        mismatch = structured.directional_mismatch(fun, x, e, J, _richardson, tol=tol, order=4,
                                                   halvings=JACOBIAN_REFERENCE_HALVINGS,
                                                   fraction=JACOBIAN_REFERENCE_FRACTION)
        if mismatch is None or not mismatch <= tol:
            return None
    return K, C


def _exudyn_jacobians_ok(system: ExudynSystem, q, v, a, t, step, const_mass) -> bool:
    """Check Exudyn's K, C against Richardson differences along random directions, row by
    row (:data:`JACOBIAN_CHECK_TOLERANCE`).

    The reference is refined until its estimated error is below
    :data:`JACOBIAN_REFERENCE_FRACTION` of every row's allowance; if it cannot be,
    Exudyn's Jacobians are not accepted (differences everywhere, the safe side).
    """
    if not const_mass or system.has_lie_group_nodes:
        return False  # the M(q) q'' term (or the rotation-vector chart) is not in Exudyn's Jacobian
    K, C = system.force_jacobians(q, v, t)
    force, damping = _force_functions(system, q, v, a, t, const_mass)
    rng = np.random.default_rng(11)
    hq = fd_steps(q, step)
    hv = fd_steps(v, step)
    for _ in range(JACOBIAN_CHECK_DIRECTIONS):
        d = rng.standard_normal(system.n)
        for J, fun, x, h in ((K, force, q, hq), (C, damping, v, hv)):
            mismatch = structured.directional_mismatch(
                fun, x, d * h / step, J, _richardson, tol=JACOBIAN_CHECK_TOLERANCE, order=4, step=step,
                halvings=JACOBIAN_REFERENCE_HALVINGS, fraction=JACOBIAN_REFERENCE_FRACTION)
            if mismatch is None:
                logger.info("Exudyn's force Jacobian not checked (the differences do not reach %.0e of the "
                            "tolerance): using Richardson differences", JACOBIAN_REFERENCE_FRACTION)
                return False
            if not mismatch <= JACOBIAN_CHECK_TOLERANCE:
                logger.info("Exudyn's force Jacobian disagrees with differences (%.1e of a row): "
                            "using Richardson differences", mismatch)
                return False
    return True


def _reaction_stiffness(system: ExudynSystem, q: np.ndarray, lam: np.ndarray, t: float, step: float,
                        accurate: bool, pattern) -> np.ndarray:
    """``d(C_q(q, t)^T lambda)/dq`` by column-compressed differences (Curtis-Powell-Reid).

    Columns of the constraint objects' coordinates that share no row of the structural
    reaction pattern (:func:`linearize.collocation_solver.coupling_pattern`) are perturbed
    together: row ``i`` depends on at most one column of a colour, so every entry is the
    same difference (rule and step) as with one column at a time, for a fraction of the
    evaluations (two-link arm: 10 colours for 21 columns).  One random directional
    difference checks the pattern; a mismatch beyond
    :data:`~linearize.collocation_solver.PATTERN_CHECK_TOLERANCE` (a constraint reading
    coordinates outside its object) falls back to one column at a time on
    :meth:`ExudynSystem.reaction_columns`.
    """
    n = q.size
    hq = fd_steps(q, step)

    def reaction(x):
        return system.constraint_jacobian(x, t).T @ lam

    def rule(fun, x, e, s):  # d/ds fun(x + s e) at 0
        if accurate:
            return _richardson(fun, x, e, s)
        return 0.5 * (fun(x + s * e) - fun(x - s * e)) / s

    def derivative(e):
        return rule(reaction, q, e, 1.0)

    Kr = np.zeros((n, n))
    for cols in pattern.reaction_colours:
        e = np.zeros(n)
        e[cols] = hq[cols]
        dcol = derivative(e)
        for j in cols:
            rows = pattern.reaction[:, j]
            Kr[rows, j] = dcol[rows] / hq[j]
    rng = np.random.default_rng(_REACTION_CHECK_SEED)
    e = hq * rng.uniform(-1.0, 1.0, n)
    if np.any(Kr != 0.0):
        # round-off of C_q^T lambda: an entry of constraint k's row of C_q is computed from
        # quantities of that row's size (an analytic zero comes out as eps x that), times |lambda_k|
        Cq = system.constraint_jacobian(q, t)
        terms = np.full(n, float(np.max(np.abs(Cq), axis=1, initial=0.0) @ np.abs(lam)))
        mismatch = structured.directional_mismatch(reaction, q, e, Kr, rule, tol=structured.PATTERN_CHECK_TOLERANCE,
                                                   order=4 if accurate else 2, terms=terms)
        if mismatch is None or not mismatch <= structured.PATTERN_CHECK_TOLERANCE:
            logger.info("constraint reactions depend on coordinates outside their objects (directional check "
                        "%s): one difference per column", "unresolved" if mismatch is None else f"{mismatch:.1e}")
            Kr[:] = 0.0
            for j in system.reaction_columns():
                e = np.zeros(n)
                e[j] = hq[j]
                Kr[:, j] = derivative(e) / hq[j]
    return Kr


_REACTION_CHECK_SEED = 20261127


def tangent_blocks(system: ExudynSystem, times: np.ndarray, Q: np.ndarray, V: np.ndarray, A: np.ndarray,
                   L: np.ndarray, *, step: float = RICHARDSON_STEP, use_exudyn_jacobian: Optional[bool] = None,
                   accurate: bool = True) -> TangentBlocks:
    """Linearisation at the samples (see :class:`TangentBlocks`).

    ``K_force`` and ``C`` are Exudyn's own Jacobians when they pass a check
    against Richardson-extrapolated central differences along random
    directions (:data:`JACOBIAN_CHECK_TOLERANCE`) and the mass matrix is
    constant; otherwise Richardson differences of ``M(q) q'' - f``, column-compressed on
    the model's structural force pattern (:func:`_force_compressed`: ~12 colours for an
    ANCF chain of any length instead of ``n`` columns), one column at a time from the
    first sample where the pattern fails its check.  The
    reaction stiffness ``d(C_q^T lambda)/dq`` is always Richardson differences
    of Exudyn's ``C_q``, on the coordinates ``C_q`` depends on.  Step of
    coordinate ``j``: ``step * max(1, |q_j|)`` (:data:`RICHARDSON_STEP`).
    ``accurate=False`` (Newton matrices only) uses plain central differences
    with step ``eps^(1/3)`` for the reaction stiffness: half the cost.
    """
    Kn, n, m = times.size, system.n, system.m
    Ms = np.empty((Kn, n, n))
    Kf = np.empty((Kn, n, n))
    Kr = np.zeros((Kn, n, n))
    Cd = np.empty((Kn, n, n))
    Cqs = np.empty((Kn, m, n))
    const_mass = system.mass_is_constant(Q[0])
    if use_exudyn_jacobian is None:
        use_exudyn_jacobian = _exudyn_jacobians_ok(system, Q[0], V[0], A[0], float(times[0]), step, const_mass)
    pattern = system.coupling_pattern() if m or not use_exudyn_jacobian else None
    rng = np.random.default_rng(_FORCE_CHECK_SEED)
    compressed = not use_exudyn_jacobian
    for k in range(Kn):
        q, v, a, lam, t = Q[k], V[k], A[k], L[k], float(times[k])
        Ms[k] = system.mass(q, t)
        Cqs[k] = system.constraint_jacobian(q, t)
        if use_exudyn_jacobian:
            Kf[k], Cd[k] = system.force_jacobians(q, v, t)
        else:
            KC = _force_compressed(system, q, v, a, t, step, const_mass, pattern, rng) if compressed else None
            if KC is None:
                if compressed:
                    logger.info("forces depend on coordinates outside the structural pattern at t = %.4g: "
                                "one difference per column from here on", t)
                compressed = False
                KC = _force_fd(system, q, v, a, t, step, const_mass)
            Kf[k], Cd[k] = KC
        if m and np.any(lam != 0.0):  # C_q(x)^T 0 = 0 for every x: no reaction stiffness
            Kr[k] = _reaction_stiffness(system, q, lam, t, step if accurate else CENTRAL_DIFFERENCE_STEP,
                                        accurate, pattern)
    return TangentBlocks(M=Ms, K_force=Kf, K_reaction=Kr, C=Cd, Cq=Cqs, exudyn_jacobian=bool(use_exudyn_jacobian))


# --------------------------------------------------------------------------- collocation
#: Newton-matrix strategies of :func:`find_orbit`.
SOLVERS = ("auto", "dense", "structured")


class _Collocation:
    """Residual and Newton matrix of the collocation equations at one omega."""

    def __init__(self, built: BuiltModel, samples: int, solver: str = "auto") -> None:
        self.built = built
        self.system = ExudynSystem(built)
        self.T = built.period
        self.K = int(samples)
        breakpoints = sorted({float(b) for dr in built.drives for b in (getattr(dr, "breakpoints", None) or ())})
        #: piecewise sampling when a drive declares breakpoints (:mod:`linearize.piecewise`), else None
        self.grid: Optional[PiecewiseGrid] = PiecewiseGrid(self.T, breakpoints, self.K) if breakpoints else None
        if self.grid is not None:
            self.times, self.D1, self.D2 = self.grid.times, self.grid.D1, self.grid.D2
        else:
            self.times = sample_times(self.T, self.K)
            self.D1, self.D2 = differentiation_matrices(self.T, self.K)
        self.B = built.drive_vectors()
        self.n, self.m, self.d = self.system.n, self.system.m, len(built.drives)
        self.s = self.n + self.m + self.d
        self.exudyn_jacobian: Optional[bool] = None  # decided (checked) at the first tangent
        self.R = np.array([[dr.evaluate(t)[0] for dr in built.drives] for t in self.times]).reshape(self.K, self.d)
        #: ODE2 indices of Euler parameters / rotation vectors: their inertia terms cancel structurally on a
        #: steady spin (``G p = 0`` for Euler parameters: ``M p'' = 0`` when ``p'' || p``), so the force scale
        #: of the residual takes their terms' sizes ``|M| |q''|`` (else a force-free spinning orbit's relative
        #: residual is 0 / 0)
        self.parameter_rows = np.array(sorted(int(i) for _, idx, _ in self.system.rotation_parameters()
                                              for i in idx), dtype=int)
        self.autonomous = False  # set_autonomous
        self.set_shift(np.zeros(self.n))
        #: drift ``q(T) - q(0) - shift`` of the simulated guess period and its samples' periodic
        #: part (None before the guess)
        self.guess_drift: Optional[np.ndarray] = None
        self._guess_samples: Optional[np.ndarray] = None
        #: why the last orbit Newton converged to was rejected as away from the guess (:func:`_far_from_guess`)
        self.far_orbit = ""
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if solver == "auto":
            solver = "structured" if self.K * self.s > structured.STRUCTURED_THRESHOLD else "dense"
        self.solver = solver
        self.pattern = self.system.coupling_pattern() if solver == "structured" else None
        self._exudyn_jacobians: Optional[bool] = None
        self._assembly: Optional[structured.NewtonAssembly] = None
        if _is_autonomous(self.system, built):
            self.set_autonomous()

    def set_charts(self, charts: tuple) -> None:
        """Present the turning rotation-vector nodes of ``charts`` in their Tait-Bryan charts
        (:meth:`ExudynSystem.set_turning_charts`); their angles are no rotation parameters."""
        if not charts:
            return
        self.system.set_turning_charts(charts)
        self.parameter_rows = np.array(sorted(int(i) for _, idx, _ in self.system.rotation_parameters()
                                              for i in idx), dtype=int)

    def set_shift(self, shift: np.ndarray, signs: Optional[np.ndarray] = None,
                  references: Optional[np.ndarray] = None) -> None:
        """The map ``g`` of the orbit, ``q(t + T) = g(q(t))``: a whole-turn shift ``s`` of angles and, for
        coordinates with ``signs = -1`` (the Euler parameters of a body that turns), a sign flip of the
        absolute value ``q + references``.  The unknowns are the periodic part ``p = q - s t / T``, and for
        sign-flipping rows ``q`` itself, differentiated as a T-antiperiodic function (see :func:`find_orbit`)."""
        self.shift = np.asarray(shift, dtype=float).copy()
        self.ramp = self.times[:, None] * (self.shift[None, :] / self.T)
        self.signs = np.ones(self.n) if signs is None else np.asarray(signs, dtype=float).copy()
        self.references = np.zeros(self.n) if references is None else np.asarray(references, dtype=float).copy()
        self.anti = np.flatnonzero(self.signs < 0)
        if self.anti.size and self.grid is not None:
            raise ModelFileError("declared breakpoints on a model whose Euler parameters change sign over a "
                                 "period are not supported: declare no breakpoints, or use NodeRigidBodyRxyz")
        if self.anti.size:
            self.D1a, self.D2a = antiperiodic_differentiation_matrices(self.T, self.K)
            self.solver, self.pattern = "dense", None  # per-coordinate derivative matrices: dense Newton

    def coords(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, q', q'')`` at the samples from the unknowns ``X`` (periodic part plus the ramp; the
        sign-flipping rows antiperiodic in their absolute value)."""
        P = X[:, :self.n]
        Q, V, A = P + self.ramp, self.D1 @ P + self.shift / self.T, self.D2 @ P
        if self.anti.size:
            Pa = P[:, self.anti] + self.references[self.anti]
            V[:, self.anti] = self.D1a @ Pa
            A[:, self.anti] = self.D2a @ Pa
        return Q, V, A

    def tangent(self, X: np.ndarray) -> TangentBlocks:
        """Per-sample blocks at ``X`` (:func:`tangent_blocks`).  Structured: where
        :func:`tangent_blocks` would difference every column (Exudyn's force Jacobians
        fail their check or ``M`` depends on ``q``), column-compressed differences with
        the same rule and steps (:mod:`linearize.collocation_solver`)."""
        _, L, _ = self.split(X)
        Q, V, A = self.coords(X)
        if self.pattern is None:
            tb = tangent_blocks(self.system, self.times, Q, V, A, L, use_exudyn_jacobian=self.exudyn_jacobian,
                                accurate=False)
            self.exudyn_jacobian = tb.exudyn_jacobian
            return tb
        if self._exudyn_jacobians is None:
            self._exudyn_jacobians = _exudyn_jacobians_ok(self.system, Q[0], V[0], A[0], float(self.times[0]),
                                                          RICHARDSON_STEP, self.system.mass_is_constant(Q[0]))
        if self._exudyn_jacobians:
            return tangent_blocks(self.system, self.times, Q, V, A, L, use_exudyn_jacobian=True, accurate=False)
        sb = structured.compressed_blocks(self.system, self.times, Q, V, A, L, self.pattern,
                                          derivative=_richardson, steps=lambda x: fd_steps(x, RICHARDSON_STEP))
        return TangentBlocks(M=sb.M, K_force=sb.K_force, K_reaction=sb.K_reaction, C=sb.C, Cq=sb.Cq)

    def newton_solver(self, X: np.ndarray):
        """``(solve, tangent)``: the factorised Newton matrix at ``X`` and its blocks."""
        if self.pattern is None:
            J, tb = self.jacobian(X)
            if self.autonomous:
                w = self.phase_direction(X)
                qscale = max(1.0, float(np.max(np.abs(X[:, :self.n]))))
                if float(np.max(np.abs(w[:self.K * self.s].reshape(self.K, self.s)[:, :self.n]))) > \
                        PHASE_MOTION * qscale / self.T:  # an equilibrium has no phase to fix
                    return _solve_with_phase(J, w), tb
            return _solve(J), tb
        tb = self.tangent(X)
        if self._assembly is None:
            self._assembly = structured.NewtonAssembly(self.B, self.D1, self.D2,
                                                       stiffness_pattern=self.pattern.force | self.pattern.reaction)
        J = self._assembly(tb.M, tb.K, tb.C, tb.Cq)  # sparse_newton_matrix, structure kept between calls
        return structured.sparse_solver(J), tb

    def set_autonomous(self) -> None:
        """Fix the phase of an orbit of an autonomous model (:func:`_is_autonomous`): the orbit is one of a
        family (any time shift of it is another, e.g. a free spin turned about its axis), the collocation
        Newton matrix is singular along the family, and each Newton step is made orthogonal to it (AUTO's
        phase condition in its incremental form, :func:`_solve_with_phase`).  With the dense Newton matrix
        (the structured one is left without it); an equilibrium (no motion) has no phase to fix."""
        self.autonomous = True

    def phase_direction(self, X: np.ndarray) -> np.ndarray:
        """``d X(t + delta) / d delta`` at ``delta = 0`` (the tangent of the family of time-shifted orbits)
        in the unknowns: the coordinates' rates, and ``D1`` of the multipliers and torques."""
        _, V, _ = self.coords(X)
        return np.hstack([V, self.D1 @ X[:, self.n:]]).reshape(-1)

    def split(self, X: np.ndarray):
        n, m = self.n, self.m
        return X[:, :n], X[:, n:n + m], X[:, n + m:]

    def residual(self, X: np.ndarray) -> tuple[np.ndarray, float]:
        _, L, U = self.split(X)
        Q, V, A = self.coords(X)
        sys_ = self.system
        out = np.empty((self.K, self.s))
        fscale = 0.0
        for k in range(self.K):
            t = float(self.times[k])
            f = sys_.rhs(Q[k], V[k], t)
            Mk = sys_.mass(Q[k], t)
            Ma = Mk @ A[k]
            if self.parameter_rows.size:  # see _Collocation.parameter_rows
                r_ = self.parameter_rows
                fscale = max(fscale, float(np.max(np.abs(Mk[:, r_]) @ np.abs(A[k, r_]))))
            r = Ma - f - self.B @ U[k]
            if self.m:
                r += sys_.constraint_jacobian(Q[k], t).T @ L[k]
                out[k, self.n:self.n + self.m] = sys_.constraints(Q[k], t)
            out[k, :self.n] = r
            out[k, self.n + self.m:] = self.B.T @ Q[k] - self.R[k]
            # the forces on the orbit, and the force that changes the orbit's momentum by itself within a
            # period: the scale stays meaningful when the orbit needs no force (a steady free spin)
            fscale = max(fscale, float(np.max(np.abs(f))), float(np.max(np.abs(Ma))),
                         float(np.max(np.abs(Mk) @ np.abs(V[k]))) / self.T)
        return out, fscale

    def relative(self, out: np.ndarray, fscale: float, qscale: float) -> float:
        force = float(np.max(np.abs(out[:, :self.n]))) / max(fscale, 1e-300)
        geo = float(np.max(np.abs(out[:, self.n:]))) / qscale if self.m + self.d else 0.0
        return max(force, geo)

    def jacobian(self, X: np.ndarray) -> tuple[np.ndarray, TangentBlocks]:
        _, L, _ = self.split(X)
        Q, V, A = self.coords(X)
        tb = tangent_blocks(self.system, self.times, Q, V, A, L, use_exudyn_jacobian=self.exudyn_jacobian,
                            accurate=False)
        self.exudyn_jacobian = tb.exudyn_jacobian
        Kn, n, m, s = self.K, self.n, self.m, self.s
        J = np.zeros((Kn, s, Kn, s))
        # row block k, column block j: D1_kj C_k + D2_kj M_k (+ K_k on the diagonal)
        J[:, :n, :, :n] = self.D1[:, None, :, None] * tb.C[:, :, None, :]
        J[:, :n, :, :n] += self.D2[:, None, :, None] * tb.M[:, :, None, :]
        if self.anti.size:  # columns of sign-flipping coordinates: the antiperiodic derivatives
            a = self.anti
            J[:, :n, :, a] = (self.D1a[:, None, :, None] * tb.C[:, :, None, a]
                              + self.D2a[:, None, :, None] * tb.M[:, :, None, a])
        k = np.arange(Kn)
        J[k, :n, k, :n] += tb.K
        if m:
            J[k, :n, k, n:n + m] = np.transpose(tb.Cq, (0, 2, 1))
            J[k, n:n + m, k, :n] = tb.Cq
        J[k, :n, k, n + m:] = -self.B
        J[k, n + m:, k, :n] = self.B.T
        return J.reshape(Kn * s, Kn * s), tb


def _solve(J: np.ndarray):
    """Factorise the Newton matrix (dense LU; one place to swap in a sparse solver)."""
    # column scaling equilibrates metres, radians and newtons (J is scaled in place: it is
    # built for this factorisation only); a NaN or inf entry makes its column's maximum NaN / inf
    scale = np.maximum(np.max(J, axis=0), -np.min(J, axis=0))
    if not np.all(np.isfinite(scale)):
        raise OrbitConvergenceError("the collocation Newton matrix contains NaN or inf (the model's forces "
                                    "are not finite along the guess)", [])
    scale[scale == 0] = 1.0
    J /= scale
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        lu = scipy.linalg.lu_factor(J, overwrite_a=True, check_finite=False)
    pivots = np.abs(np.diagonal(lu[0]))
    if not np.all(pivots > 0.0):
        raise OrbitConvergenceError(
            "the collocation Newton matrix is singular: redundant constraints, or a drive on a coordinate "
            "the model's constraints already fix", [])
    return lambda r: scipy.linalg.lu_solve(lu, r, check_finite=False) / scale


#: An autonomous orbit whose coordinates' rates stay below this times (coordinate scale / T) is an
#: equilibrium: no family of time shifts, no phase condition.
PHASE_MOTION = 1e-9


def _solve_with_phase(J: np.ndarray, w: np.ndarray):
    """Newton steps ``dX`` of a singular collocation matrix ``J`` whose null space is the family
    direction ``w`` (an autonomous model): ``[J; w^T] dX = [-r; 0]`` in least squares (column-scaled as
    :func:`_solve`).  The stacked matrix has full column rank when ``null J = span(w)``, also when the
    multiplier 1 of the family is defective (a conserved quantity: then ``w`` lies in the range of ``J``
    and the bordered square system would be singular); at an orbit of the family the system is
    consistent, so the steps converge as Newton's do."""
    scale = np.maximum(np.max(J, axis=0), -np.min(J, axis=0))
    if not np.all(np.isfinite(scale)):
        raise OrbitConvergenceError("the collocation Newton matrix contains NaN or inf (the model's forces "
                                    "are not finite along the guess)", [])
    scale[scale == 0] = 1.0
    row = w / scale
    big = float(np.max(np.abs(row)))
    A = np.vstack([J / scale, (row / big)[None, :] if big > 0 else row[None, :]])
    Qf, Rf = np.linalg.qr(A)
    diag = np.abs(np.diagonal(Rf))
    if not np.all(diag > 1e-14 * max(float(np.max(diag)), 1e-300)):
        raise OrbitConvergenceError(
            "the collocation Newton matrix is singular beyond the phase of the orbit: redundant constraints, "
            "or a family of orbits with more than one parameter", [])

    def solve(r: np.ndarray) -> np.ndarray:
        b = np.concatenate([r, [0.0]])
        return scipy.linalg.solve_triangular(Rf, Qf.T @ b, check_finite=False) / scale

    return solve


#: :func:`_is_autonomous` compares the model at this many times of the period (equispaced, offset by an
#: irrational fraction of a step): a load or constraint that varies on a time scale of at least
#: ``T / AUTONOMY_TIMES`` differs between some two of them (two times would miss e.g. a load equal at
#: both, or a blow between them).
AUTONOMY_TIMES = 32


def _is_autonomous(system: ExudynSystem, built: BuiltModel) -> bool:
    """True when the model has no drives and its forces and constraints do not depend on time (compared
    at two generic states at :data:`AUTONOMY_TIMES` times of the period): its periodic orbits then come
    in families of time shifts."""
    if built.drives:
        return False
    T = built.period
    rng = np.random.default_rng(5)
    times = (np.arange(AUTONOMY_TIMES) + 0.381966) * (T / AUTONOMY_TIMES)
    for _ in range(2):
        q = np.asarray(system.q_initial, dtype=float) + 1e-2 * rng.standard_normal(system.n)
        v = np.asarray(system.v_initial, dtype=float) + 1e-2 * rng.standard_normal(system.n)
        f0 = system.rhs(q, v, float(times[0]))
        c0 = system.constraints(q, float(times[0])) if system.m else None
        for t in times[1:]:
            if np.any(np.abs(system.rhs(q, v, float(t)) - f0) > INVARIANCE_TOLERANCE * (1.0 + np.max(np.abs(f0)))):
                return False
            if c0 is not None and np.any(np.abs(system.constraints(q, float(t)) - c0)
                                         > INVARIANCE_TOLERANCE * (1.0 + np.max(np.abs(q)))):
                return False
    return True


def _weights(col: _Collocation, X: np.ndarray, qscale: float) -> np.ndarray:
    """Per-unknown weights of the Newton norm: coordinates by their scale, multipliers and
    torques by the largest of their kind (so a correction of each kind counts alike)."""
    n, m = col.n, col.m
    w = np.empty(X.shape[1])
    w[:n] = 1.0 / qscale
    for sl in (slice(n, n + m), slice(n + m, None)):
        if X[:, sl].size:
            w[sl] = 1.0 / max(float(np.max(np.abs(X[:, sl]))), 1e-300)
    return w


#: Chord steps after convergence (reusing the last factorisation) while each
#: lowers the residual tenfold: the orbit then sits near the round-off floor,
#: not just below the tolerance, for the cost of a few residual evaluations.
POLISH_STEPS = 3


def _polish(col: _Collocation, X: np.ndarray, solve, res: float, qscale: float, history: list) -> np.ndarray:
    if solve is None:
        return X
    for _ in range(POLISH_STEPS):
        out, _ = col.residual(X)
        trial = X + solve(-out.reshape(-1)).reshape(X.shape)
        out_t, fscale = col.residual(trial)
        res_t = col.relative(out_t, fscale, qscale)
        if not (res_t <= 0.1 * res):
            break
        X, res = trial, res_t
        history.append(res)
    return X


def _iteration_head(col: _Collocation, X: np.ndarray, qscale: float, tol: float, history: list, solve, tb,
                    label: str, it: int):
    """The start of every Newton iteration (full-step and damped): residual of ``X`` appended to
    ``history`` and logged, and the two exits.  Returns ``(out, done)``: ``out`` the residual array,
    ``done`` the final ``(X, history, ok, tangent)`` when the residual is not finite (failed) or
    ``<= tol`` (converged, polished), else ``None``."""
    out, fscale = col.residual(X)
    res = col.relative(out, fscale, qscale)
    history.append(res)
    logger.debug("%s %d: relative residual %.3e", label, it, res)
    if not math.isfinite(res):
        return out, (X, history, False, tb)
    if res <= tol:
        return out, (_polish(col, X, solve, res, qscale, history), history, True, tb)
    return out, None


def _full_step_newton(col: _Collocation, X: np.ndarray, tol: float, max_iterations: int):
    """Undamped Newton (see :data:`FULL_STEP_ITERATIONS`); returns ``(X, history, ok, tangent)``."""
    history: list = []
    qscale = max(1.0, float(np.max(np.abs(X[:, :col.n]))))
    solve = tb = None
    for it in range(1, max_iterations + 1):
        out, done = _iteration_head(col, X, qscale, tol, history, solve, tb, "orbit full-step Newton", it)
        if done is not None:
            return done
        if it > FULL_STEP_CHECK and min(history) > FULL_STEP_PROGRESS * history[0]:
            break
        if it > FULL_STEP_ITERATIONS and (it == 1 or not history[-1] <= FULL_STEP_CONTRACTION * history[-2]):
            break  # past the budget and no longer contracting
        if solve is None or not history[-1] <= CHORD_REUSE_FACTOR * history[-2]:
            try:
                solve, tb = col.newton_solver(X)
            except (OrbitConvergenceError, np.linalg.LinAlgError):
                if it == 1:
                    raise
                break  # a singular matrix away from the guess: leave it to the damped Newton
        X = X + solve(-out.reshape(-1)).reshape(X.shape)
    return X, history, False, tb


def _newton(col: _Collocation, X: np.ndarray, tol: float, max_iterations: int, early_give_up: bool = False,
            second_guess=None, abandoned: Optional[list] = None):
    """Full-step Newton from ``X``, then (if given and it fails) from ``second_guess(col)``,
    then damped Newton from ``X``; returns ``(X, history, ok, tangent)``.  An orbit that converges away
    from the simulated guess (:func:`_far_from_guess`) counts as a failure.  ``abandoned``: see
    :func:`_damped_newton`."""
    Xf, history, ok, tb = _full_step_newton(col, X, tol, max_iterations)
    far = _far_from_guess(col, Xf) if ok else ""
    if far:
        col.far_orbit = far
        logger.info("orbit: full-step Newton converged to an orbit away from the simulated guess (%s); "
                    "damped Newton", col.far_orbit)
        ok = False
    if ok:
        return Xf, history, True, tb
    if second_guess is not None:
        logger.debug("orbit: full-step Newton from the simulated guess stopped at %.2e; quasi-static guess",
                     history[-1] if history else math.nan)
        X2 = second_guess(col)
        if X2 is not None:
            Xf, h2, ok, tb = _full_step_newton(col, X2, tol, max_iterations)
            history += h2
            if ok and not _far_from_guess(col, Xf):
                return Xf, history, True, tb
    logger.debug("orbit: full-step Newton stopped at %.2e; damped Newton from the guess",
                 history[-1] if history else math.nan)
    X, h2, ok, tb = _damped_newton(col, X, tol, max_iterations, early_give_up, abandoned)
    far = _far_from_guess(col, X) if ok else ""
    if far:
        col.far_orbit = far
        logger.info("orbit: damped Newton converged to an orbit away from the simulated guess (%s)",
                    col.far_orbit)
        ok = False
    return X, history + h2, ok, tb


def _far_from_guess(col: _Collocation, X: np.ndarray) -> str:
    """``""``, or a phrase naming the rotation coordinate whose periodic part at some sample differs from
    the simulated guess's (:func:`_guess`) by more than :data:`NEAR_GUESS_ANGLE` beyond whole turns
    (``""`` also when there is no simulated guess)."""
    G = col._guess_samples
    if G is None or G.shape != X[:, :col.n].shape:
        return ""
    labels = col.system.coordinate_labels()
    rot = col.system.rotation_coordinates()
    if rot.size:
        d = X[:, rot] - G[:, rot]
        d = np.abs(d - 2.0 * math.pi * np.round(d / (2.0 * math.pi)))
        k, j = np.unravel_index(int(np.argmax(d)), d.shape)
        if d[k, j] > NEAR_GUESS_ANGLE:
            return (f"{labels[rot[j]]}[{int(rot[j])}] at t = {float(col.times[k]):.4g} differs from the simulated "
                    f"period of the model's initial state by {float(d[k, j]):.3g} rad beyond whole turns")
    pos, size = _rigid_positions(col.system.mbs, G)
    size = max(1.0, size)  # (as the coordinate scale of the relative residual: a model near the origin)
    if pos.size:
        d = np.abs(X[:, pos] - G[:, pos])
        k, j = np.unravel_index(int(np.argmax(d)), d.shape)
        if d[k, j] > NEAR_GUESS_SIZE * size:
            return (f"{labels[pos[j]]}[{int(pos[j])}] at t = {float(col.times[k]):.4g} differs from the simulated "
                    f"period of the model's initial state by {float(d[k, j]):.3g}, more than {NEAR_GUESS_SIZE:g} "
                    f"of the model's size {size:.3g}")
    return ""


def _rigid_positions(mbs, G: np.ndarray) -> tuple[np.ndarray, float]:
    """ODE2 indices of the rigid-body nodes' position coordinates and the model's size: the largest
    distance of such a node from the origin or from another one over the samples ``G`` (the positions
    are the reference values plus the displacement coordinates)."""
    idx, refs = [], []
    for j in range(mbs.systemData.NumberOfNodes()):
        node = mbs.GetNode(j)
        kind = str(node.get("nodeType"))
        if not kind.startswith("RigidBody"):
            continue
        dim = 2 if kind == "RigidBody2D" else 3
        ltg = [int(i) for i in mbs.systemData.GetNodeLTGODE2(j)][:dim]
        ref = np.asarray(node.get("referenceCoordinates"), dtype=float)[:dim]
        if len(ltg) == dim and ref.size == dim:
            idx.append(ltg)
            refs.append(ref)
    if not idx:
        return np.zeros(0, dtype=int), 0.0
    P = np.stack([G[:, i] + r for i, r in zip(idx, refs)], axis=1)  # samples x nodes x dim
    size = float(np.max(np.linalg.norm(P, axis=2)))
    if P.shape[1] > 1:
        size = max(size, float(np.max(np.linalg.norm(P[:, :, None, :] - P[:, None, :, :], axis=3))))
    return np.array([i for ii in idx for i in ii], dtype=int), size


def _whole_turns_to_guess(col: _Collocation, X: np.ndarray) -> np.ndarray:
    """``X`` with each rotation coordinate moved by the whole turns ``2 pi k`` that bring it nearest to the
    simulated guess (the same configurations: the model depends on these angles through sines and cosines
    only)."""
    G = col._guess_samples
    rot = col.system.rotation_coordinates()
    if G is None or not rot.size or G.shape != X[:, :col.n].shape:
        return X
    k = np.round(np.median(X[:, rot] - G[:, rot], axis=0) / (2.0 * math.pi))
    if not np.any(k):
        return X
    X = X.copy()
    X[:, rot] -= 2.0 * math.pi * k[None, :]
    return X


def _damped_newton(col: _Collocation, X: np.ndarray, tol: float, max_iterations: int, early_give_up: bool = False,
                   abandoned: Optional[list] = None):
    """Damped Newton (natural monotonicity test); returns ``(X, history, ok, tangent)``.  When it stops
    by the early give-up (:data:`EARLY_GIVE_UP_ITERATIONS`), ``(X, iterations)`` is appended to
    ``abandoned`` (if given) so that the caller can resume it."""
    history: list = []
    qscale = max(1.0, float(np.max(np.abs(X[:, :col.n]))))
    solve = None
    tb = None
    for it in range(1, max_iterations + 1):
        out, done = _iteration_head(col, X, qscale, tol, history, solve, tb, "orbit Newton", it)
        if done is not None:
            return done
        res = history[-1]
        if it > STAGNATION_ITERATIONS and res > history[0]:
            return X, history, False, tb
        if early_give_up and it > EARLY_GIVE_UP_ITERATIONS and res > EARLY_GIVE_UP_FACTOR * history[0]:
            if abandoned is not None:
                abandoned.append((X.copy(), it))
            return X, history, False, tb  # no progress from this guess: continuation may do better
        if solve is None or len(history) < 2 or history[-1] > 0.5 * history[-2]:
            solve, tb = col.newton_solver(X)
        dX = solve(-out.reshape(-1)).reshape(X.shape)
        weights = _weights(col, X + dX, qscale)
        step_norm = float(np.max(np.abs(dX) * weights))
        lam = 1.0
        trial = X
        for _ in range(MAX_STEP_HALVINGS):
            trial = X + lam * dX
            out_t, _ = col.residual(trial)
            if np.all(np.isfinite(out_t)):
                simplified = solve(-out_t.reshape(-1)).reshape(X.shape)
                # Deuflhard's natural monotonicity test in a scaled max norm
                if float(np.max(np.abs(simplified) * weights)) <= (1.0 - 0.25 * lam) * step_norm:
                    break
            lam *= 0.5
        X = trial
        if float(np.max(np.abs(lam * dX) * weights)) <= UPDATE_TOLERANCE and res <= 1e3 * tol:
            out, fscale = col.residual(X)
            history.append(col.relative(out, fscale, qscale))
            return X, history, True, tb
    return X, history, False, tb


# --------------------------------------------------------------------------- Exudyn runs
def _simulate(built: BuiltModel, q0: np.ndarray, v0: np.ndarray, t_end: float, steps: int,
              record_times: Optional[np.ndarray] = None,
              charts: tuple = (), rate: Optional[float] = None) -> tuple[np.ndarray, np.ndarray, Optional[np.ndarray]]:
    """One Exudyn generalised-alpha run (rho_inf = 1) of a model with prescribed drives, from and to the
    package's coordinates (``charts``: the turning rotation-vector nodes' Tait-Bryan charts,
    :class:`~linearize.exudyn_system.TurningChart`; their angles are followed step by step, and the run is
    cut into :func:`_rechart_segments` that each start from the rotation vector of length ``<= pi``; ``rate``:
    the largest rate of their angles in the run, default the initial one)."""
    import exudyn as exu

    mbs = built.mbs
    sd = mbs.systemData
    ini = exu.ConfigurationType.Initial
    lie = lie_group_nodes(mbs)  # rotation-vector nodes: Exudyn's velocities are angular velocities
    segments = _rechart_segments(charts, v0, t_end, rate)
    per_segment = -(-int(steps) // segments)
    steps = segments * per_segment
    s = exu.SimulationSettings()
    s.timeIntegration.numberOfSteps = per_segment
    s.timeIntegration.generalizedAlpha.spectralRadius = SHOOTING_SPECTRAL_RADIUS
    s.timeIntegration.verboseMode = 0
    s.timeIntegration.automaticStepSize = False
    s.timeIntegration.newton.relativeTolerance = NEWTON_RELATIVE_TOLERANCE
    s.timeIntegration.newton.absoluteTolerance = NEWTON_ABSOLUTE_TOLERANCE
    s.solution.file.write = False
    s.solution.file.writeInitialValues = False
    s.show.statistics = False
    s.show.computationTime = False
    sparse = int(sd.ODE2Size()) + int(sd.AEsize()) > SPARSE_SIMULATION_SIZE
    s.linearSolver.solverType = exu.LinearSolverType.EigenSparse if sparse else exu.LinearSolverType.EigenDense
    rows: list = []
    h = t_end / steps
    wanted = set() if record_times is None else {int(round(t / h)) for t in record_times}
    last = {"q": np.array(q0, dtype=float)}  # the package's coordinates at the last step (charts: followed)

    def post(mbs_, t):
        q = np.array(mbs_.systemData.GetODE2Coordinates())
        if charts:
            last["q"] = q = from_exudyn_state([], charts, q, np.zeros_like(q), last["q"])[0]
        i = int(round(t / h))
        if i in wanted and i not in {r[0] for r in rows}:
            rows.append((i, q))
        return True

    hooked = record_times is not None or bool(charts)
    if hooked:
        mbs.SetPostStepUserFunction(post)
    qT, vT, ok = np.asarray(q0, dtype=float), np.asarray(v0, dtype=float), True
    try:
        for j in range(segments):
            q_ex, w = to_exudyn_state(lie, charts, qT, vT)
            sd.SetODE2Coordinates(q_ex, configuration=ini)
            sd.SetODE2Coordinates_t(w, configuration=ini)
            s.timeIntegration.startTime = float(t_end) * j / segments
            s.timeIntegration.endTime = float(t_end) * (j + 1) / segments
            ok = mbs.SolveDynamic(s)
            qT, vT = from_exudyn_state(lie, charts, np.array(sd.GetODE2Coordinates()),
                                       np.array(sd.GetODE2Coordinates_t()), last["q"])
            if ok is False:
                break
    except Exception as exc:  # noqa: BLE001 - Exudyn raises its own error types
        raise ExudynRunError(f"Exudyn's integrator failed ({' '.join(str(exc).split())})") from None
    finally:
        if hooked:
            mbs.SetPostStepUserFunction(0)
    if ok is False or not (np.all(np.isfinite(qT)) and np.all(np.isfinite(vT))):
        raise ExudynRunError("Exudyn's integrator did not complete the period")
    rec = None
    if record_times is not None:
        got = dict(rows)
        rec = np.array([q0 if int(round(t / h)) == 0 else got.get(int(round(t / h)), qT) for t in record_times])
    return qT, vT, rec


#: A run with turning rotation-vector nodes is cut into segments in which each such node turns by at most
#: this angle (at its initial rate): each segment starts from the rotation vector of length <= pi, so the
#: vector stays below 1.5 pi, away from the length 2 pi where the tangent operator of Exudyn's Lie-group
#: integrator is singular.  Measured on the hub rotor (one turn per period, 512 steps): one uncut period ends
#: at length 2 pi with a state 1e-6 off (a relative shooting defect 4e-2); cut in quarter turns, 1e-11.
RECHART_ANGLE = 0.5 * math.pi


def _rechart_segments(charts: tuple, v0: np.ndarray, t_end: float, rate: Optional[float] = None) -> int:
    """Segments of a run (:data:`RECHART_ANGLE`) at the angles' largest ``rate`` (default: their initial
    rate in ``v0``): one without turning rotation-vector nodes."""
    if not charts:
        return 1
    if rate is None:
        rate = max(float(np.linalg.norm(np.asarray(v0, dtype=float)[c.indices])) for c in charts)
    return max(2, int(math.ceil(rate * float(t_end) / RECHART_ANGLE - 1e-9)))


def _guess(col: _Collocation, model: ModelDefinition) -> np.ndarray:
    """One Exudyn period from the model file's initial state, drives prescribed, sampled.

    Also fixes the whole-turn shift of ``col`` (:func:`whole_turn_shift`) from that period
    (unless it is set already) and records the drift the shift leaves (:attr:`_Collocation.guess_drift`).
    """
    sysm = col.system
    built_p = build_model(model, col.built.omega, prescribe_drives=True)
    X = np.zeros((col.K, col.s))
    q0 = np.asarray(sysm.q_initial, dtype=float)
    try:
        qT, _, Qs = _simulate(built_p, sysm.q_initial, sysm.v_initial, col.T, SHOOTING_STEPS_PER_SAMPLE * col.K,
                              record_times=col.times, charts=sysm.charts)
    except ExudynRunError as exc:
        logger.info("orbit guess: %s; starting from the initial state at every sample", exc)
        qT, Qs = None, np.broadcast_to(q0, (col.K, col.n))
    if not np.any(col.shift) and not col.anti.size:
        if qT is not None and not sysm.charts:
            charts = _turning_charts(sysm, np.vstack([Qs, qT[None, :]]))
            if charts:  # the samples in the new charts, each angle followed from the previous sample
                col.set_charts(charts)
                rows = [sysm.q_initial]
                for row in np.vstack([Qs[1:], qT[None, :]]):
                    rows.append(sysm.chart_coordinates(row, rows[-1]))
                Qs, qT, q0 = np.array(rows[:-1]), rows[-1], np.asarray(sysm.q_initial, dtype=float)
        col.set_shift(*whole_turn_map(col.system, col.built, None if qT is None else qT - q0))
    if qT is not None:
        col.guess_drift = qT - apply_map(q0, col.shift, col.signs, col.references)
    X[:, :col.n] = Qs - col.ramp
    col._guess_samples = X[:, :col.n].copy()
    return X


#: :func:`whole_turn_shift` takes an angle's advance over the simulated period for ``k`` whole turns
#: when it is within this of ``2 pi k`` (a quarter turn: the transient swing of a hinged part about
#: its orbit is smaller; an advance of 1.5 turns is no whole turn and is left to the growth check).
WHOLE_TURN_WINDOW = 0.5 * math.pi


def apply_map(q: np.ndarray, shift: np.ndarray, signs: np.ndarray, references: np.ndarray, times: int = 1) -> np.ndarray:
    """``g^times(q)`` for the orbit map ``g(q) = signs (q + references) - references + shift`` (ODE2
    coordinates; ``signs`` is -1 on the Euler parameters of a turning body, +1 elsewhere; the rates map
    as ``v -> signs v``)."""
    q = np.asarray(q, dtype=float)
    for _ in range(int(times)):
        q = signs * (q + references) - references + shift
    return q


#: A rotation-vector node turns when the rotation it accumulates over the simulated guess period (the sum of
#: its increments from sample to sample, in the inertial frame) is at least this angle: half a turn, far
#: above the swing of a pendulum-like part (swinging back and forth accumulates nearly nothing) and far
#: below the whole turn of a spinning one.
TURNING_ANGLE = math.pi


def _turning_charts(system: ExudynSystem, rows: np.ndarray) -> tuple:
    """Tait-Bryan charts (:func:`~linearize.exudyn_system.turning_chart`) of the rotation-vector nodes that
    turn over the simulated guess period, ``rows`` its samples and end state in Exudyn's coordinates: the
    accumulated rotation is at least :data:`TURNING_ANGLE`; the chart's axis is the accumulated rotation's,
    its start the node's rotation at the first sample.  Samples must be less than half a turn apart."""
    charts = []
    for idx, ref in lie_group_nodes(system.mbs):
        R = [rotation_matrix(row[idx] + ref) for row in rows]
        turned = sum(rotation_vector(b @ a.T) for a, b in zip(R[:-1], R[1:]))  # R_{k+1} R_k^T: inertial increments
        if float(np.linalg.norm(turned)) >= TURNING_ANGLE:
            charts.append(turning_chart(idx, ref, turned, R[0]))
            logger.info("rotation-vector node at %s turns by %.3g turns per period: Tait-Bryan chart about %s",
                        idx.tolist(), float(np.linalg.norm(turned)) / (2 * math.pi),
                        np.round(turned / np.linalg.norm(turned), 6).tolist())
    return tuple(charts)


def whole_turn_map(system: ExudynSystem, built: BuiltModel,
                   advance: Optional[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(shift, signs, references)`` of the orbit map ``q(t + T) = g(q(t))`` (:func:`apply_map`): the
    whole turns of angles (:func:`whole_turn_shift`) and the sign flips of the Euler parameters of
    bodies that turn (``NodeRigidBodyEP``: after a whole turn the parameters come back as ``-p``).  A
    rotation-vector node that turns is in its Tait-Bryan chart by then (:func:`_turning_charts`): its angles
    are rotation coordinates.

    Raises
    ------
    mbs_models.model_file.ModelFileError
        A rotation-vector node still in the rotation-vector chart turns, or as :func:`whole_turn_shift`.
    """
    signs, refs = np.ones(system.n), np.zeros(system.n)
    if advance is not None:
        signs, refs = _rotation_parameter_flips(system, built, np.asarray(advance, dtype=float))
    return whole_turn_shift(system, built, advance, signs, refs), signs, refs


def whole_turn_shift(system: ExudynSystem, built: BuiltModel, advance: Optional[np.ndarray],
                     signs: Optional[np.ndarray] = None, references: Optional[np.ndarray] = None) -> np.ndarray:
    """The shift ``s`` of an orbit periodic up to whole turns, ``q(t + T) = q(t) + s``.

    Rule (the model-file contract): ``s_i = 2 pi k_i``, ``k_i = round(advance_i / 2 pi)`` when
    ``advance_i`` is within :data:`WHOLE_TURN_WINDOW` of ``2 pi k_i``, for the rotation coordinates (:meth:`ExudynSystem.rotation_coordinates`: planar rigid-body angles, Tait-Bryan
    angles) where ``advance = q(T) - q(0)`` over one simulated period of the model with its drives
    prescribed, ``0`` elsewhere; the drives' own whole turns (:attr:`BuiltModel.drive_turns`) must
    come out of it (a drive turning a coordinate of a non-rotation node, or a simulation that failed,
    takes the drive's turns on its marker m1's coordinate, else minus them on m0's).  ``s`` is then
    checked: the model's forces and constraints must be the same at ``(q + s, t + T)`` as at ``(q, t)``.

    Raises
    ------
    mbs_models.model_file.ModelFileError
        If the drives' turns cannot be placed or the model is not invariant under the shift.
    """
    n = system.n
    s = np.zeros(n)
    signs = np.ones(n) if signs is None else np.asarray(signs, dtype=float)
    references = np.zeros(n) if references is None else np.asarray(references, dtype=float)
    rot = system.rotation_coordinates()
    if advance is not None and rot.size:
        a = np.asarray(advance, dtype=float)[rot]
        k = np.round(a / (2.0 * math.pi))
        near = np.abs(a - 2.0 * math.pi * k) <= WHOLE_TURN_WINDOW
        s[rot] = np.where(near, 2.0 * math.pi * k, 0.0)
    B = built.drive_vectors()
    turns = 2.0 * math.pi * np.asarray(built.drive_turns or [0] * B.shape[1], dtype=float)
    if B.shape[1] and not np.allclose(B.T @ s, turns, atol=1e-9):
        s = np.zeros(n)
        for (i0, i1), k in zip(built.drive_indices, turns):
            if k == 0:
                continue
            if i1 >= 0 and s[i1] == 0:
                s[i1] = k
            elif i0 >= 0 and s[i0] == 0:
                s[i0] = -k
        if not np.allclose(B.T @ s, turns, atol=1e-9):
            raise ModelFileError(f"model {built.definition.name}: the drives' whole turns per period "
                                 f"({', '.join(str(int(round(k / (2 * math.pi)))) for k in turns)}) cannot be "
                                 f"placed on their coordinates")
    if np.any(s) or np.any(signs < 0):
        _check_invariance(system, built, s, signs, references)
        logger.info("orbit periodic up to whole turns: %s", {system.coordinate_labels()[i] + f"[{i}]":
                                                              int(round(s[i] / (2 * math.pi))) for i in np.flatnonzero(s)})
    return s


def _rotation_parameter_flips(system: ExudynSystem, built: BuiltModel, advance: np.ndarray) -> tuple:
    """``(signs, references)``: -1 and the reference values on the Euler parameters of every
    ``NodeRigidBodyEP`` node whose parameters come back with the opposite sign over the simulated period
    (``advance = q(T) - q(0)``; a body making an odd number of whole turns), +1 and 0 elsewhere.

    Raises :class:`ModelFileError` when a rotation-vector node left in the rotation-vector chart turns
    (:func:`_turning_charts` puts a turning node in a Tait-Bryan chart first): its vector passes the singular
    length 2 pi, so no smooth orbit periodic up to whole turns exists in its coordinates (Newton would
    otherwise settle on another orbit, e.g. the body at rest)."""
    q0 = np.asarray(system.q_initial, dtype=float)
    signs, refs = np.ones(system.n), np.zeros(system.n)
    for kind, idx, ref in system.rotation_parameters():
        p0, pT = q0[idx] + ref, q0[idx] + advance[idx] + ref
        if kind == "RigidBodyEP":
            if float(np.linalg.norm(pT + p0)) <= 0.5 * float(np.linalg.norm(p0)):
                signs[idx], refs[idx] = -1.0, ref
        elif float(np.linalg.norm(pT - p0)) >= math.pi:
            raise ModelFileError(
                f"model {built.definition.name}: a Node{kind} turns by a whole turn per period (its rotation "
                f"vector reaches the singular length 2 pi, where no smooth orbit continues): give the turning body "
                f"a NodeRigidBodyEP (its Euler parameters change sign, handled) or a NodeRigidBodyRxyz (its angles "
                f"advance by 2 pi k)")
    return signs, refs


#: :func:`whole_turn_shift` accepts a shift when the forces and constraint residuals after it differ
#: by at most this, relative to their size plus one (round-off of sin/cos at arguments ~2 pi k:
#: ~1e-15; 1e-8 rejects only a model that really changes after a turn, e.g. a spring to ground).
INVARIANCE_TOLERANCE = 1e-8


def _check_invariance(system: ExudynSystem, built: BuiltModel, s: np.ndarray, signs: np.ndarray,
                      references: np.ndarray) -> None:
    """The model must be the same after the map: ``f(g(q), S v, t + T) = S f(q, v, t)`` and
    ``C(g(q), t + T) = C(q, t)`` (``S = diag(signs)``) at a generic state."""
    T = built.period
    rng = np.random.default_rng(3)
    q = np.asarray(system.q_initial, dtype=float) + 1e-2 * rng.standard_normal(system.n)
    v = np.asarray(system.v_initial, dtype=float) + 1e-2 * rng.standard_normal(system.n)
    t = 0.37 * T
    gq = apply_map(q, s, signs, references)
    f0, f1 = signs * system.rhs(q, v, t), system.rhs(gq, signs * v, t + T)
    bad = np.abs(f1 - f0) > INVARIANCE_TOLERANCE * (1.0 + np.max(np.abs(f0)))
    what = "forces"
    if not np.any(bad) and system.m:
        c0, c1 = system.constraints(q, t), system.constraints(gq, t + T)
        bad = np.abs(c1 - c0) > INVARIANCE_TOLERANCE * (1.0 + np.max(np.abs(q)))
        what = "constraints"
    if np.any(bad):
        labels = system.coordinate_labels()
        turned = ", ".join(f"{labels[i]}[{i}] by {int(round(s[i] / (2 * math.pi)))}" for i in np.flatnonzero(s))
        raise ModelFileError(f"model {built.definition.name}: coordinates turn by whole turns per period "
                             f"({turned}), but the model's {what} are not the same after those turns "
                             f"(e.g. a spring to ground on a turning angle): no orbit periodic up to whole turns")


#: Quasi-static guess: Newton iterations per static solve, the relative residual they must
#: reach, and how often the step from one sample time to the next may be halved.
QUASI_STATIC_ITERATIONS = 10
QUASI_STATIC_TOLERANCE = 1e-8
QUASI_STATIC_HALVINGS = 6


def _static_solve(col: _Collocation, y: np.ndarray, t: float, use: Optional[bool]):
    """Newton for the static equilibrium at time ``t`` with the drives at ``r(t)`` from
    ``y = (q, lambda, tau)``; returns ``(y, use)`` or ``(None, use)``."""
    sysm = col.system
    n, m = col.n, col.m
    zero = np.zeros(n)
    r_t = np.array([dr.evaluate(t)[0] for dr in col.built.drives], dtype=float)
    J = np.zeros((col.s, col.s))
    J[:n, n + m:] = -col.B
    J[n + m:, :n] = col.B.T
    y = y.copy()
    for _ in range(QUASI_STATIC_ITERATIONS):
        q, lam, tau = y[:n], y[n:n + m], y[n + m:]
        f = sysm.rhs(q, zero, t)
        r = -f - col.B @ tau
        g = np.zeros(0)
        if m:
            r = r + sysm.constraint_jacobian(q, t).T @ lam
            g = sysm.constraints(q, t)
        geo = np.concatenate([g, col.B.T @ q - r_t])
        res = max(float(np.max(np.abs(r))) / max(float(np.max(np.abs(f))), 1e-300),
                  float(np.max(np.abs(geo), initial=0.0)) / max(1.0, float(np.max(np.abs(q)))))
        if not math.isfinite(res):
            return None, use
        if res <= QUASI_STATIC_TOLERANCE:
            return y, use
        tb = tangent_blocks(sysm, np.array([t]), q[None], zero[None], zero[None], lam[None],
                            use_exudyn_jacobian=use, accurate=False)
        use = tb.exudyn_jacobian
        J[:n, :n] = tb.K[0]
        J[:n, n:n + m] = tb.Cq[0].T
        J[n:n + m, :n] = tb.Cq[0]
        y = y + np.linalg.solve(J, -np.concatenate([r, geo]))
    return None, use


def _quasi_static_guess(col: _Collocation) -> Optional[np.ndarray]:
    """The drives' motions with the model in static equilibrium at every sample (no inertia).

    At each sample ``t_k`` Newton solves ``-f(q, 0, t_k) + C_q^T lambda - B tau = 0``,
    ``C(q, t_k) = 0``, ``B^T q = r(t_k)``, marching in time from the model file's initial
    state (natural continuation: each solve starts from the previous one; a step that
    does not converge is halved, at most :data:`QUASI_STATIC_HALVINGS` times).  For a
    driven flexible arm this is the rigid motion with the static (gravity) deflection, a
    guess in the right configuration at every sample, which the simulated period (with
    the free vibration its start excites) need not be.  Returns ``None`` when no
    equilibrium is found (e.g. a model without a static equilibrium).
    """
    n, m, d = col.n, col.m, col.d
    use = col.exudyn_jacobian if col.exudyn_jacobian is not None else col._exudyn_jacobians
    y = np.concatenate([np.asarray(col.system.q_initial, dtype=float), np.zeros(m + d)])
    X = np.empty((col.K, col.s))
    t_now = 0.0
    try:
        for k in range(col.K):
            t_k = float(col.times[k])
            h = t_k - t_now
            halvings = 0
            while True:
                t_try = t_k if t_now + h >= t_k else t_now + h
                y_new, use = _static_solve(col, y, t_try, use)
                if y_new is None:
                    halvings += 1
                    if halvings > QUASI_STATIC_HALVINGS or k == 0:
                        logger.debug("quasi-static guess: no equilibrium at t = %.4g", t_try)
                        return None
                    h *= 0.5
                    continue
                y, t_now = y_new, t_try
                if t_now >= t_k:
                    break
            X[k] = y
    except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
        logger.debug("quasi-static guess failed: %s", exc)
        return None
    X[:, :n] -= col.ramp
    return X if np.all(np.isfinite(X)) else None


def _shooting_defect(model: ModelDefinition, omega: float, Q: np.ndarray, V: np.ndarray, samples: int,
                     shift: Optional[np.ndarray] = None, signs: Optional[np.ndarray] = None,
                     references: Optional[np.ndarray] = None, grid: Optional[PiecewiseGrid] = None,
                     charts: tuple = ()) -> float:
    built_p = build_model(model, omega, prescribe_drives=True)
    T = 2 * math.pi / omega
    n = Q.shape[1]
    s = np.zeros(n) if shift is None else np.asarray(shift, dtype=float)
    sg = np.ones(n) if signs is None else np.asarray(signs, dtype=float)
    refs = np.zeros(n) if references is None else np.asarray(references, dtype=float)
    if grid is None:
        P = Q - np.arange(Q.shape[0])[:, None] * (s[None, :] / Q.shape[0])  # the periodic part
        q0, v0 = Q[0], V[0]
    else:  # piecewise sampling: no node at t = 0, the state there from the collocation polynomial
        P = Q - grid.times[:, None] * (s[None, :] / T)
        q0, v0 = grid.smooth(P, 0.0), grid.smooth(P, 0.0, 1) + s / T
    try:
        rate = max((float(np.max(np.linalg.norm(V[:, c.indices], axis=1))) for c in charts), default=None)
        qT, vT, _ = _simulate(built_p, q0, v0, T, SHOOTING_STEPS_PER_SAMPLE * samples, charts=charts, rate=rate)
    except ExudynRunError:
        return math.inf
    x0 = np.concatenate([apply_map(q0, s, sg, refs), sg * v0])
    xT = np.concatenate([qT, vT])
    # ... at least the integrator's own resolution of the state (an orbit at rest in its periodic
    # part, e.g. a rotor spinning steadily, has no variation to compare with)
    floor = SHOOTING_FLOOR * max(1.0, float(np.max(np.abs(Q))), float(np.max(np.abs(V))))
    variation = max(float(np.max(np.abs(P - P[0]))), float(np.max(np.abs(V - V[0]))), floor)
    # coordinates and rates are compared in their own units: the defect relative to
    # the largest excursion of either along the orbit
    return float(np.max(np.abs(xT - x0)) / variation)


# --------------------------------------------------------------------------- driver
class StageClock:
    """Wall and CPU seconds per named stage: :meth:`lap` adds the time since the previous lap
    (or since construction) to ``stage`` in :attr:`timings` / :attr:`cpu_timings`."""

    def __init__(self) -> None:
        self.timings: dict = {}
        self.cpu_timings: dict = {}
        self._last = (time.perf_counter(), time.process_time())

    def lap(self, stage: str) -> None:
        w, c = time.perf_counter(), time.process_time()
        self.timings[stage] = self.timings.get(stage, 0.0) + w - self._last[0]
        self.cpu_timings[stage] = self.cpu_timings.get(stage, 0.0) + c - self._last[1]
        self._last = (w, c)


def find_orbit(
    model: Any,
    omega: float,
    *,
    samples: int = DEFAULT_SAMPLES,
    tol: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    verify: bool = True,
    continuation: bool = True,
    solver: str = "auto",
    guess: Optional[PeriodicOrbit] = None,
    **options: Any,
) -> PeriodicOrbit:
    """The T-periodic orbit of ``model`` with its drives prescribed.

    Periodic up to the orbit map ``q(t + T) = g(q(t))`` read off one simulated period
    (:func:`whole_turn_map`): whole turns of angles (the unknowns are the periodic part
    ``q - s t / T``) and the sign flip of the Euler parameters of a body that turns an odd number of times
    (those rows are T-antiperiodic, differentiated by the antiperiodic spectral matrices).  An autonomous
    model (no drives, nothing depends on time: a free spin) has a family of time-shifted orbits; its phase
    is fixed by a phase condition (:meth:`_Collocation.set_autonomous`) and
    :attr:`PeriodicOrbit.autonomous` says that one multiplier 1 is structural.

    Parameters
    ----------
    model : ModelDefinition, str, path or callable
        A model definition, a built-in name (``"single-link"``), a model file
        path or a ``build(mbs, omega)`` callable.
    omega : float
        Angular frequency; ``T = 2 pi / omega``.
    samples : int
        Collocation samples per period (even, >= 4).
    tol : float
        Relative residual Newton must reach (never loosened).
    max_iterations : int
        Newton iterations (per continuation step).
    verify : bool
        Run the one-period shooting check in Exudyn.
    continuation : bool
        Continue in omega from omega/2 when Newton fails from both guesses.
    solver : {"auto", "dense", "structured"}
        Newton matrix: dense differences and LU, or column-compressed differences
        and a sparse LU (:mod:`linearize.collocation_solver`); ``"auto"`` takes the
        structured one above :data:`~linearize.collocation_solver.STRUCTURED_THRESHOLD`
        unknowns.  Both solve the same equations to the same tolerance.
    guess : PeriodicOrbit, optional
        Start Newton from this orbit's samples (same model, ``samples`` and sample phases ``t / T``, usually a
        nearby omega: continuation along an omega sweep) instead of one simulated
        period; if Newton fails from it, the usual guess and continuation follow.
    **options
        Keyword options for ``build``.

    Returns
    -------
    PeriodicOrbit

    Raises
    ------
    OrbitConvergenceError
        Newton did not reach ``tol`` (the message gives the residuals reached)
        or the shooting check failed.
    mbs_models.model_file.ModelFileError
        On a bad model.
    """
    tic = time.perf_counter()
    clock = StageClock()
    timings, cpu_timings, lap = clock.timings, clock.cpu_timings, clock.lap

    if not (isinstance(tol, float) or isinstance(tol, int)) or not (math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be finite and > 0, got {tol!r}")
    definition = resolve_model(model, **options)
    built = build_model(definition, omega)
    col = _Collocation(built, samples, solver)
    lap("build")
    history: list = []
    ok = False
    if guess is not None and guess.samples == col.K and guess.q.shape[1] == col.n and \
            guess.lambdas.shape[1] == col.m and guess.torques.shape[1] == col.d and \
            np.allclose(guess.times / guess.period, col.times / col.T, rtol=0.0, atol=1e-12):
        col.set_charts(guess.charts)
        col.set_shift(guess.shift, guess.signs, guess.references)
        X = np.hstack([guess.q - col.ramp, guess.lambdas, guess.torques])
        X, history, ok, tb = _newton(col, X, tol, max_iterations, early_give_up=True)
        if not ok:
            logger.info("orbit: Newton from the given guess failed (%.2e); simulated guess", history[-1])
        lap("newton")
    if not ok:
        X = _guess(col, definition)
    lap("guess")
    at_target = list(history)  # residuals at omega itself (continuation steps at other omegas apart)
    abandoned: list = []
    col_target = col
    if not ok:
        X, h1, ok, tb = _newton(col, X, tol, max_iterations, early_give_up=continuation,
                                second_guess=_quasi_static_guess, abandoned=abandoned)
        history += h1
        at_target += h1
    if not ok:
        growing = _growing_coordinates(col)
        if growing:
            lap("newton")
            raise OrbitConvergenceError(
                f"periodic orbit of {definition.name} at omega = {float(omega):.6g}: no periodic orbit, "
                f"{growing}; every coordinate must come back after T = 2 pi/omega, up to whole turns "
                f"2 pi k of an angle (see the model-file contract)", history)
    reached = None
    if not ok and continuation:
        logger.info("orbit: Newton from the simulated guess failed (%.2e); continuation in omega", history[-1])
        shift = (col.shift, col.signs, col.references)
        X, h2, ok, col, tb, reached, h_target = _continuation(definition, float(omega), samples, tol,
                                                              max_iterations, X, solver, shift, col.system.charts)
        history += h2
        at_target += h_target
    if not ok and abandoned:
        # the damped Newton given up early for the continuation, resumed where it stopped, without the
        # give-up, for the rest of its iteration limit
        X0, used = abandoned[0]
        logger.info("orbit: continuation failed; the damped Newton from the simulated guess resumed")
        X1, h3, ok1, tb1 = _damped_newton(col_target, X0, tol, max(1, max_iterations - used))
        history += h3
        at_target += h3
        if ok1:
            X, ok, col, tb = X1, True, col_target, tb1
    lap("newton")
    if ok:  # (continuation ends at omega on the same samples: compared with the guess at omega)
        X = _whole_turns_to_guess(col_target, X)
        far = _far_from_guess(col_target, X)
    else:
        far = col_target.far_orbit
    if far:  # an orbit far from the one the model file sets up answers another question
        raise OrbitConvergenceError(
            f"periodic orbit of {definition.name} at omega = {float(omega):.6g}: Newton found no orbit near "
            f"the model's initial state, only one where {far}", history)
    if not ok:
        best = min(at_target) if at_target else math.nan
        cont = ""
        if continuation:
            lowest = CONTINUATION_START * 0.5 ** CONTINUATION_START_HALVINGS
            cont = (f"; continuation in omega converged up to {reached:.4g} omega only" if reached is not None
                    else f"; continuation in omega found no orbit to start from at {CONTINUATION_START:g} down to "
                         f"{lowest:g} omega")
        raise OrbitConvergenceError(
            f"periodic orbit of {definition.name} at omega = {float(omega):.6g} did not converge: relative residual "
            f"{at_target[-1] if at_target else math.nan:.2e} after {len(history)} Newton iterations "
            f"(best at this omega {best:.2e}, tolerance {tol:.1e}){cont}"
            "; try more samples, damping, or an omega away from resonances",
            history,
        )
    _, L, U = col.split(X)
    L, U = L.copy(), U.copy()
    Q, V, A = (a.copy() for a in col.coords(X))
    out, fscale = col.residual(X)
    residual = col.relative(out, fscale, max(1.0, float(np.max(np.abs(Q)))))
    # linearisation at the converged samples (Newton's last matrix is at the previous iterate)
    # the linearisation is always the accurate one (Exudyn's checked Jacobians, Richardson reaction
    # stiffness); the structured solver's compressed blocks serve Newton only
    tb = tangent_blocks(col.system, col.times, Q, V, A, L, use_exudyn_jacobian=(col.exudyn_jacobian if col.exudyn_jacobian is not None else col._exudyn_jacobians))
    lap("tangent")
    shooting = math.nan
    if verify:
        shooting = _shooting_defect(definition, float(omega), Q, V, samples, col.shift, col.signs, col.references,
                                    col.grid, col.system.charts)
    lap("shooting")
    if verify:
        if not shooting <= SHOOTING_TOLERANCE:
            raise OrbitConvergenceError(
                f"periodic orbit of {definition.name} at omega = {float(omega):.6g}: collocation residual "
                f"{residual:.1e}, but one period in Exudyn from its state returns with a relative defect "
                f"{shooting:.2e} > {SHOOTING_TOLERANCE:.0e}; try more samples",
                history,
            )
    orbit = PeriodicOrbit(
        model=definition, omega=float(omega), period=col.T, times=col.times, q=Q, q_t=V, q_tt=A, lambdas=L,
        torques=U, drive_names=tuple(d.name for d in built.drives), drive_vectors=col.B, residual=residual,
        tolerance=float(tol), shooting_residual=shooting, iterations=len(history), tangent=tb,
        coordinate_labels=tuple(col.system.coordinate_labels()),
        slope_nodes=tuple(col.system.slope_nodes()), planar_pairs=tuple(col.system.planar_pairs()), wall_time=time.perf_counter() - tic,
        timings=timings, cpu_timings=cpu_timings, shift=col.shift.copy(), signs=col.signs.copy(),
        references=col.references.copy(), autonomous=bool(col.autonomous) and float(np.max(np.abs(V))) >
        PHASE_MOTION * max(1.0, float(np.max(np.abs(Q)))) / col.T,
        breakpoints=() if col.grid is None else col.grid.boundaries, charts=col.system.charts,
    )
    logger.info("orbit of %s at omega=%.4g: residual %.1e after %d iterations, shooting defect %.1e (%.2f s)",
                definition.name, omega, residual, len(history), shooting, orbit.wall_time)
    return orbit


def _continuation(definition: ModelDefinition, omega: float, samples: int, tol: float, max_iterations: int,
                  X_fail: np.ndarray, solver: str = "auto", shift: Optional[tuple] = None, charts: tuple = ()):
    """Natural continuation in omega from :data:`CONTINUATION_START` omega (halved at most
    :data:`CONTINUATION_START_HALVINGS` times while no orbit is found to start from).  Returns ``(X, history, ok,
    col, tangent, reached, at_target)``: ``reached`` the largest omega factor at which an orbit
    converged (``None``: none), ``at_target`` the residuals of the solves at omega itself (an
    orbit at a lower omega is no answer at omega)."""
    f, step, X, history, at_target = CONTINUATION_START, CONTINUATION_STEP, None, [], []
    col = tb = reached = None
    starts = 0
    for _ in range(CONTINUATION_MAX_SOLVES):
        target = min(1.0, f)
        col = _Collocation(build_model(definition, omega * target), samples, solver)
        col.set_charts(charts)  # (the model's initial rotation and the axis of its turn do not depend on omega)
        if shift is not None:
            col.set_shift(*shift)  # whole turns per period do not depend on omega
        guess = _guess(col, definition) if X is None else X.copy()
        Xn, hist, ok, tb = _newton(col, guess, tol, max_iterations, early_give_up=True)
        history += hist
        if target >= 1.0:
            at_target += hist
        logger.debug("orbit continuation: omega factor %.4f %s", target, "converged" if ok else "failed")
        if ok:
            X, reached = Xn, target
            if target >= 1.0:
                return X, history, True, col, tb, reached, at_target
            step *= 1.5
            f = target + step
        elif X is None:
            starts += 1
            if starts > CONTINUATION_START_HALVINGS:
                break
            f *= 0.5
        else:
            step *= 0.5
            f -= step
            if step < CONTINUATION_MIN_STEP:
                break
    return (X if X is not None else X_fail), history, False, col, tb, reached, at_target


#: :func:`_growing_coordinates`: a coordinate grows when its drift over the simulated guess period
#: (after the whole-turn shift) is at least this fraction of its whole excursion in that period
#: (a monotone advance; an oscillation ends inside its range) ...
GROWTH_FRACTION = 0.9
#: ... and larger than this, relative to ``1 + |q(0)|`` (a tenth of a radian or metre: far above the
#: drift of a slow transient vibration of a structure, far below a fraction of a turn).
GROWTH_MINIMUM = 0.1
#: ... and advances again over the next period, in the same direction, by at least this fraction of its
#: first advance (a coordinate that grows keeps growing).  The transient of a very flexible structure can
#: swing a bounded coordinate (an ANCF slope) monotonically through most of its range in one period and not
#: in the next: measured on the single link with E = 2e7 N/m^2, 8 elements, a slope coordinate advanced by
#: -1.97 in the first period and by -0.015 in the second; the rheonomic 1.5 turns per period advance by
#: 9.42 in both.
GROWTH_REPEAT = 0.5


def _second_period_drift(col: _Collocation) -> Optional[np.ndarray]:
    """``q(2T) - g(q(T))`` of the simulated guess run continued for a second period (the same steps, so
    ``q(T)`` is the guess's), or ``None`` when Exudyn's integrator fails on it."""
    built_p = build_model(col.built.definition, col.built.omega, prescribe_drives=True)
    steps = SHOOTING_STEPS_PER_SAMPLE * col.K
    try:
        q2, _, rec = _simulate(built_p, col.system.q_initial, col.system.v_initial, 2.0 * col.T, 2 * steps,
                               record_times=np.array([col.T]), charts=col.system.charts)
    except ExudynRunError:
        return None
    return q2 - apply_map(rec[0], col.shift, col.signs, col.references)


def _growing_coordinates(col: _Collocation) -> str:
    """``""``, or a phrase naming the coordinates that advanced monotonically over the simulated guess
    period by something that is not whole turns, and advanced again over a second period
    (:data:`GROWTH_REPEAT`; consulted only after Newton failed from that guess: then no continuation
    in omega can help, and the user is told at once)."""
    drift = col.guess_drift
    if drift is None:
        return ""
    q0 = np.asarray(col.system.q_initial, dtype=float)
    # the sampled periodic part of the guess run: q(t_k) - ramp, plus its end q(T) - shift
    start = col._guess_samples if col._guess_samples is not None else q0[None, :]
    P = np.vstack([start, (q0 + drift)[None, :]])
    excursion = np.max(P, axis=0) - np.min(P, axis=0)
    grows = (np.abs(drift) >= GROWTH_FRACTION * excursion) & (np.abs(drift) > GROWTH_MINIMUM * (1.0 + np.abs(q0)))
    idx = np.flatnonzero(grows)
    if not idx.size:
        return ""
    again = _second_period_drift(col)
    if again is not None:  # (a failed second period leaves the first period's verdict)
        keeps = (np.sign(again[idx]) == np.sign(drift[idx])) & \
            (np.abs(again[idx]) >= GROWTH_REPEAT * np.abs(drift[idx]))
        if not np.all(keeps):
            logger.info("orbit: %d coordinate(s) advanced over the guess period but not again over the next: "
                        "a transient, not growth", int(np.sum(~keeps)))
        idx = idx[keeps]
        if not idx.size:
            return ""
    labels = col.system.coordinate_labels()
    rot = set(int(i) for i in col.system.rotation_coordinates())
    parts = []
    for i in idx[:3]:
        turn = f" ({(drift[i] + col.shift[i]) / (2 * math.pi):.3g} turns)" if i in rot else ""
        parts.append(f"{labels[i]}[{int(i)}] advances by {drift[i] + col.shift[i]:.4g}{turn}")
    more = f" and {idx.size - 3} more" if idx.size > 3 else ""
    return ("in one simulated period " + ", ".join(parts) + more
            + " -- neither periodic nor a whole number of turns")
