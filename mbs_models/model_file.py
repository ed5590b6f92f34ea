"""Model files: bring your own Exudyn model.

A *model file* is a plain Python module with a function::

    def build(mbs, omega):
        '''Add the system to the empty exudyn MainSystem `mbs` (do not call
        Assemble) and return its drives.'''

* ``build`` adds nodes, bodies, ANCF elements, joints, rheonomic constraints
  (offset user functions), loads, gravity and dampers in Exudyn's own idiom.
  The state it sets up (reference + initial coordinates and velocities) is the
  guess of the periodic orbit at ``t = 0``.
* It returns a sequence of **drives**: :class:`Drive` objects or mappings with
  the keys ``name`` (str), ``markers`` (a pair ``(m0, m1)`` of
  ``MarkerNodeCoordinate`` numbers) and ``motion`` (a callable
  ``t -> (q, q_t, q_tt)``).  The driven coordinate is ``q[m1] - q[m0]``, read
  exactly as Exudyn's ``CoordinateConstraint`` / ``CoordinateSpringDamper``
  read their two markers (Exudyn's ODE2 coordinates, i.e. displacements from
  the node's reference coordinates), and ``motion`` is its T-periodic
  reference, ``T = 2 pi / omega`` -- or periodic up to whole turns,
  ``motion(t + T) = motion(t) + (2 pi k, 0, 0)`` with an integer ``k`` (a hub
  turning at constant speed: ``(omega t, omega, 0)``; :func:`drive_turns`).
  An optional key ``breakpoints`` lists the times in ``[0, T)`` where the
  motion is not smooth (``docs/accuracy.md``).  An empty sequence is valid (a
  system excited only by its own rheonomic constraints or periodic loads).
* Machines that turn: the orbit may be periodic up to whole turns of angle
  coordinates (``NodeRigidBody2D`` angles, ``NodeRigidBodyRxyz`` angles),
  ``q(t + T) = q(t) + 2 pi k``.  The turns are read off one simulated period
  of the model with its drives prescribed (drives, rheonomic constraints with
  an offset ``omega t``, free angles that follow them); nothing is declared in
  the file (see ``docs/rotating-machines.md``).
* The package, not the file, adds the control.  For the periodic orbit each
  drive's coordinate follows ``motion`` exactly (its constraint reaction is the
  feed-forward torque ``tau_ff``); for the closed loop the drive is released
  and driven by ``tau = tau_ff(t) - kp (q - q^R) - kd (q' - q^R')``, one
  ``(kp, kd)`` pair per drive.
* ``build`` may take further keyword options with defaults
  (``build(mbs, omega, elements=8)``); :func:`model_from_build` binds them.

Constraints must be position-level (Exudyn's default, ``velocityLevel=False``)
and the model must have no ODE1 coordinates.

Errors in a model file raise :class:`ModelFileError` with a one-line message
(the CLI prints it and exits with code 2).
"""
from __future__ import annotations

import functools
import importlib.util
import inspect
import logging
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

__all__ = [
    "BUILTIN_MODELS",
    "BuiltModel",
    "Drive",
    "ModelDefinition",
    "FileBuild",
    "ModelFileError",
    "PERIODICITY_TOLERANCE",
    "build_model",
    "check_derivatives",
    "DERIVATIVE_STEP",
    "DERIVATIVE_TOLERANCE",
    "builtin_model",
    "drive_turns",
    "load_model_file",
    "model_from_build",
    "resolve_model",
]

logger = logging.getLogger(__name__)

#: Built-in model files (name -> module file in ``mbs_models/builtin/``).
BUILTIN_MODELS = {
    "single-link": "single_link.py",
    "two-link": "two_link.py",
    "laval-rotor": "laval_rotor.py",
    "slider-crank": "slider_crank.py",
}

#: A drive's motion must satisfy ``|motion(t + T) - motion(t)| <=`` this times
#: ``1 + |motion(t)|`` at a few test times: the round-off of evaluating a
#: smooth periodic function at arguments of size ``T`` is ~1e-15 relative, so
#: 1e-9 only rejects motions that really are not T-periodic.
PERIODICITY_TOLERANCE = 1e-9
#: Test times (fractions of T) of the periodicity check.
_PERIODICITY_PHASES = (0.0, 0.137, 0.5, 0.771)

#: Step of the central differences that check a drive's ``q_t`` and ``q_tt`` (a fraction of T).
#: For a harmonic ``k omega`` of the motion the truncation error is ``(2 pi k h / T)^2 / 6`` relative,
#: 6.6e-9 for ``k = 1`` and below 1e-3 up to ``k ~ 120``; the rounding error ``eps / (2 pi h / T)``
#: is ~4e-13.
DERIVATIVE_STEP = 1e-4
#: A drive's ``q_t`` (``q_tt``) is rejected when it differs from the central difference of ``q``
#: (``q_t``) by more than this times the scale of the rate (``max |q_t|``, ``omega x`` the spread of
#: ``q``): far above the difference's own error (see :data:`DERIVATIVE_STEP`), far below any mistake
#: of sign, factor or formula.
DERIVATIVE_TOLERANCE = 1e-3
#: Test times (fractions of T) of the derivative check; ``t = 0`` is where a run starts.
_DERIVATIVE_PHASES = (0.0, 0.137, 0.389, 0.5, 0.771)


class ModelFileError(ValueError):
    """A model file (or ``build`` callable) cannot be used; the message is one line."""


# --------------------------------------------------------------------------- drives
@dataclass(frozen=True)
class Drive:
    """One actuated coordinate of a model.

    Attributes
    ----------
    name : str
        Label used in results (e.g. ``"hub"``, ``"shoulder"``).
    markers : tuple of int
        ``(m0, m1)``: ``MarkerNodeCoordinate`` numbers; the driven coordinate
        is ``q[m1] - q[m0]`` (Exudyn's ODE2 coordinates).
    motion : callable
        ``t -> (q, q_t, q_tt)``: the T-periodic reference of the driven
        coordinate and its first two time derivatives.
    breakpoints : tuple of float, optional
        Times in ``[0, T)`` where the motion is not smooth (the corners of a
        trapezoidal velocity profile, a cam law's acceleration jumps: there
        ``P(t)`` jumps).  Default: none (a smooth motion).  See
        ``docs/accuracy.md`` for what the analysis does with them.
    """

    name: str
    markers: tuple
    motion: Callable[[float], tuple]
    breakpoints: tuple = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ModelFileError(f"drive name must be a non-empty string, got {self.name!r}")
        try:
            markers = tuple(self.markers)
        except TypeError:
            raise ModelFileError(f"drive {self.name!r}: markers must be a pair (m0, m1), got {self.markers!r}") from None
        if len(markers) != 2 or not all(_is_index(m) for m in markers):
            raise ModelFileError(f"drive {self.name!r}: markers must be a pair of marker numbers, got {self.markers!r}")
        object.__setattr__(self, "markers", (int(markers[0]), int(markers[1])))
        if not callable(self.motion):
            raise ModelFileError(f"drive {self.name!r}: motion must be callable t -> (q, q_t, q_tt)")
        try:
            points = tuple(float(b) for b in self.breakpoints)
        except (TypeError, ValueError):
            raise ModelFileError(f"drive {self.name!r}: breakpoints must be a sequence of times, "
                                 f"got {self.breakpoints!r}") from None
        if not all(math.isfinite(b) and b >= 0.0 for b in points):
            raise ModelFileError(f"drive {self.name!r}: breakpoints must be finite times >= 0, got {self.breakpoints!r}")
        object.__setattr__(self, "breakpoints", points)

    @classmethod
    def coerce(cls, value: Any) -> "Drive":
        """A :class:`Drive` from a drive or a mapping with keys ``name, markers, motion``."""
        if isinstance(value, Drive):
            return value
        if isinstance(value, Mapping):
            missing = [k for k in ("name", "markers", "motion") if k not in value]
            extra = sorted(set(value) - {"name", "markers", "motion", "breakpoints"})
            if missing:
                raise ModelFileError(f"a drive misses the key(s) {', '.join(missing)} (needs name, markers, motion)")
            if extra:
                raise ModelFileError(f"a drive has unknown key(s) {', '.join(map(str, extra))} "
                                     f"(allowed: name, markers, motion, breakpoints)")
            return cls(name=value["name"], markers=value["markers"], motion=value["motion"],
                       breakpoints=value.get("breakpoints", ()))
        raise ModelFileError(
            f"a drive must be a mapping with keys name, markers, motion (or a Drive), got {type(value).__name__}"
        )

    def evaluate(self, t: float) -> tuple[float, float, float]:
        """``(q, q_t, q_tt)`` of the reference at ``t`` as floats (checked finite)."""
        try:
            value = self.motion(float(t))
            q, q_t, q_tt = (float(v) for v in value)
        except Exception as exc:  # noqa: BLE001 - the user's function: report, do not trace
            raise ModelFileError(
                f"drive {self.name!r}: motion(t) must return three numbers (q, q_t, q_tt): {_one_line(exc)}"
            ) from None
        if not all(math.isfinite(v) for v in (q, q_t, q_tt)):
            raise ModelFileError(f"drive {self.name!r}: motion({t:g}) is not finite")
        return q, q_t, q_tt


def _is_index(m: Any) -> bool:
    if isinstance(m, (bool, float, str)):
        return False
    try:
        return int(m) >= 0  # ints, numpy ints and Exudyn's MarkerIndex
    except (TypeError, ValueError):
        return False


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# --------------------------------------------------------------------------- definitions
@dataclass(frozen=True)
class ModelDefinition:
    """A model: a ``build(mbs, omega)`` callable and where it came from.

    Attributes
    ----------
    name : str
        Label (file stem, built-in name, or the callable's name).
    build : callable
        ``build(mbs, omega) -> drives`` (options already bound).
    source : str or None
        Path of the model file, ``None`` for a callable given directly.
    options : dict
        Keyword options bound to ``build``.

    Notes
    -----
    A definition loaded from a file pickles as its file's path, name and options, not as the function: a
    module loaded from a path is not importable by name in another process (a spawned or forkserver pool
    worker, a Dask worker), so the receiving process loads the file itself, on the first call of
    ``build`` and once per process (:class:`FileBuild`).  The options must be picklable; the file must be
    readable at the same path there.  A definition of a callable pickles the callable (by reference).
    """

    name: str
    build: Callable[..., Any] = field(repr=False)
    source: Optional[str] = None
    options: dict = field(default_factory=dict)

    def __reduce_ex__(self, protocol: int):
        if self.source is not None and _is_file_build(self.build, self.source):
            return (_definition_from_file, (self.name, self.source, dict(self.options)))
        return object.__reduce_ex__(self, protocol)

    def with_options(self, **options: Any) -> "ModelDefinition":
        """The same model with further keyword options for ``build``."""
        merged = {**self.options, **options}
        return ModelDefinition(name=self.name, build=self.build, source=self.source, options=merged)

    def call_build(self, mbs: Any, omega: float) -> Any:
        """Call ``build(mbs, omega, **options)``."""
        return self.build(mbs, omega, **self.options)


@dataclass(frozen=True)
class FileBuild:
    """The ``build`` function of the model file ``source``, loaded on the first call (once per process,
    :func:`load_model_file`); what an unpickled :class:`ModelDefinition` of a file calls.

    Attributes
    ----------
    source : str
        Path of the model file.
    """

    source: str

    def function(self) -> Callable[..., Any]:
        """The file's ``build`` (the file is loaded once per process and path)."""
        return _loaded_build(self.source)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.function()(*args, **kwargs)

    @property
    def __signature__(self) -> inspect.Signature:
        """The signature of the file's ``build`` (for the options checks)."""
        return inspect.signature(self.function())


@functools.lru_cache(maxsize=None)
def _loaded_build(source: str) -> Callable[..., Any]:
    return load_model_file(source).build


def _is_file_build(build: Any, source: str) -> bool:
    """Whether ``build`` is the ``build`` of the model file ``source`` (so that loading the file again gives it)."""
    if isinstance(build, FileBuild):
        return build.source == source
    module = sys.modules.get(getattr(build, "__module__", None) or "")
    path = getattr(module, "__file__", None)
    return (path is not None and getattr(build, "__name__", None) == "build"
            and os.path.realpath(path) == os.path.realpath(source))


def _definition_from_file(name: str, source: str, options: dict) -> "ModelDefinition":
    """The unpickled :class:`ModelDefinition` of a model file: its ``build`` loaded lazily (:class:`FileBuild`)."""
    return ModelDefinition(name=name, build=FileBuild(source), source=source, options=options)


def model_from_build(build: Callable[..., Any], name: Optional[str] = None, **options: Any) -> ModelDefinition:
    """A :class:`ModelDefinition` from a ``build(mbs, omega, **options)`` callable.

    Raises
    ------
    ModelFileError
        If ``build`` is not callable or does not accept ``(mbs, omega)`` and
        the given options.
    """
    if isinstance(build, ModelDefinition):
        return build.with_options(**options) if options else build
    if not callable(build):
        raise ModelFileError(f"build must be callable build(mbs, omega), got {type(build).__name__}")
    _check_signature(build, options, name or getattr(build, "__name__", "build"))
    return ModelDefinition(name=name or getattr(build, "__name__", "model"), build=build, source=None,
                           options=dict(options))


def _check_signature(build: Callable[..., Any], options: Mapping[str, Any], where: str) -> None:
    try:
        sig = inspect.signature(build)
    except (TypeError, ValueError):
        return
    try:
        sig.bind(None, 1.0, **options)
    except TypeError as exc:
        raise ModelFileError(f"{where}: build(mbs, omega{''.join(', ' + k + '=...' for k in options)}) "
                             f"does not match its signature {sig}: {exc}") from None


def load_model_file(path: str | os.PathLike, **options: Any) -> ModelDefinition:
    """Load a model file (a Python module with ``build(mbs, omega)``).

    Parameters
    ----------
    path : str or path-like
        The ``.py`` file.
    **options
        Keyword options bound to ``build``.

    Raises
    ------
    ModelFileError
        Missing file, not a ``.py`` file, import error (with its message), or
        no callable ``build``.
    """
    p = Path(path)
    if not p.is_file():
        raise ModelFileError(f"model file {str(path)!r} not found")
    if p.suffix != ".py":
        raise ModelFileError(f"model file {str(path)!r} must be a Python file (.py)")
    mod_name = f"flexstab_model_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, p)
    if spec is None or spec.loader is None:
        raise ModelFileError(f"model file {str(path)!r} cannot be imported")
    module = importlib.util.module_from_spec(spec)
    try:
        sys.modules[mod_name] = module  # dataclasses / pickling in the file need it
        spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's file: one line, no traceback
        sys.modules.pop(mod_name, None)
        raise ModelFileError(f"model file {p.name}: importing it failed: {_one_line(exc)}") from None
    build = getattr(module, "build", None)
    if build is None:
        raise ModelFileError(f"model file {p.name} defines no function build(mbs, omega)")
    if not callable(build):
        raise ModelFileError(f"model file {p.name}: build is not a function")
    _check_signature(build, options, f"model file {p.name}")
    return ModelDefinition(name=p.stem, build=build, source=str(p), options=dict(options))


def builtin_model(name: str, **options: Any) -> ModelDefinition:
    """A built-in model file by name (see :data:`BUILTIN_MODELS`)."""
    if name not in BUILTIN_MODELS:
        raise ModelFileError(f"unknown built-in model {name!r}; available: {', '.join(sorted(BUILTIN_MODELS))}")
    path = Path(__file__).with_name("builtin") / BUILTIN_MODELS[name]
    model = load_model_file(path, **options)
    return ModelDefinition(name=name, build=model.build, source=model.source, options=model.options)


def resolve_model(model: Any, **options: Any) -> ModelDefinition:
    """A :class:`ModelDefinition` from a definition, a built-in name, a ``.py`` path or a callable."""
    if isinstance(model, ModelDefinition):
        return model.with_options(**options) if options else model
    if isinstance(model, (str, os.PathLike)):
        s = str(model)
        if s in BUILTIN_MODELS:
            return builtin_model(s, **options)
        return load_model_file(s, **options)
    return model_from_build(model, **options)


# --------------------------------------------------------------------------- building
@dataclass(frozen=True)
class BuiltModel:
    """An assembled Exudyn system with its checked drives.

    Attributes
    ----------
    definition : ModelDefinition
    omega : float
    system_container : exudyn.SystemContainer
        Keeps the system alive.
    mbs : exudyn.MainSystem
        The assembled system.
    drives : tuple of Drive
    drive_indices : ndarray, shape (n_drives, 2)
        ODE2 indices of each drive's markers ``(i0, i1)``; ``-1`` for a ground
        coordinate.
    drive_turns : tuple of int
        Whole turns ``k`` each drive's motion advances per period (0: T-periodic;
        :func:`drive_turns`).
    """

    definition: ModelDefinition
    omega: float
    system_container: Any = field(repr=False)
    mbs: Any = field(repr=False)
    drives: tuple
    drive_indices: np.ndarray
    drive_turns: tuple = ()

    @property
    def period(self) -> float:
        return 2.0 * math.pi / self.omega

    def drive_vectors(self) -> np.ndarray:
        """``B``, shape ``(n_ode2, n_drives)``: column ``d`` is ``+1`` at marker m1's
        coordinate and ``-1`` at m0's (ground coordinates have none)."""
        n = self.mbs.systemData.ODE2Size()
        B = np.zeros((n, len(self.drives)))
        for d, (i0, i1) in enumerate(self.drive_indices):
            if i1 >= 0:
                B[i1, d] += 1.0
            if i0 >= 0:
                B[i0, d] -= 1.0
        return B


def _marker_index(mbs: Any, marker: int, drive: str) -> int:
    try:
        info = mbs.GetMarker(int(marker))
    except Exception:  # noqa: BLE001
        raise ModelFileError(f"drive {drive!r}: marker {int(marker)} does not exist") from None
    if info.get("markerType") != "NodeCoordinate":
        raise ModelFileError(
            f"drive {drive!r}: marker {int(marker)} is a {info.get('markerType')} marker, "
            f"not a MarkerNodeCoordinate"
        )
    ltg = list(mbs.systemData.GetNodeLTGODE2(int(info["nodeNumber"])))
    if not ltg:
        return -1  # ground node: coordinate 0
    c = int(info["coordinate"])
    if c >= len(ltg):
        raise ModelFileError(f"drive {drive!r}: marker {int(marker)} addresses coordinate {c} of a node with {len(ltg)}")
    return int(ltg[c])


def drive_turns(drive: Drive, period: float, tol: float = PERIODICITY_TOLERANCE) -> int:
    """The whole turns ``k`` by which ``drive.motion`` advances per period (0: T-periodic).

    A motion is accepted when ``motion(t + T) = motion(t) + (2 pi k, 0, 0)`` with an integer
    ``k`` at the test times (:data:`PERIODICITY_TOLERANCE`, relative to ``1 + |motion(t)|``):
    a coordinate that turns at constant mean speed (``(Omega t, Omega, 0)``) is periodic up to
    whole turns, its rate and acceleration periodic.

    Raises
    ------
    ModelFileError
        If the motion is neither T-periodic nor periodic up to the same whole number of turns
        at every test time.
    """
    turns = None
    for phase in _PERIODICITY_PHASES:
        t = phase * period
        a = np.array(drive.evaluate(t))
        b = np.array(drive.evaluate(t + period))
        k = int(round((b[0] - a[0]) / (2.0 * math.pi)))
        expected = a + np.array([2.0 * math.pi * k, 0.0, 0.0])
        if np.any(np.abs(b - expected) > tol * (1.0 + np.abs(a) + np.abs(b))) or (turns is not None and k != turns):
            raise ModelFileError(
                f"drive {drive.name!r}: motion is not T-periodic, nor periodic up to whole turns "
                f"(T = 2 pi/omega = {period:.6g} s; needs motion(t + T) = motion(t) + (2 pi k, 0, 0), k integer): "
                f"motion({t:.4g}) = {a.tolist()} but motion(t + T) = {b.tolist()}"
            )
        turns = k
    return int(turns or 0)


def _near_breakpoint(t: float, breakpoints: Sequence[float], period: float, margin: float) -> bool:
    for b in breakpoints:
        d = (float(t) - float(b)) % period
        if min(d, period - d) <= margin:
            return True
    return False


def check_derivatives(drive: Drive, period: float, tol: float = DERIVATIVE_TOLERANCE) -> None:
    """Raise :class:`ModelFileError` unless ``q_t`` and ``q_tt`` of ``drive.motion`` are the time
    derivatives of ``q`` (central differences at a few times of the period, :data:`DERIVATIVE_STEP`).

    Times within two difference steps of one of the drive's declared ``breakpoints`` (times where the
    motion is not smooth, taken modulo ``period``) are not tested.  Only local differences are used,
    so a motion that advances by whole turns per period is checked like a periodic one.
    """
    h = DERIVATIVE_STEP * period
    breakpoints = tuple(getattr(drive, "breakpoints", None) or ())
    times = [p * period for p in _DERIVATIVE_PHASES if not _near_breakpoint(p * period, breakpoints, period, 2 * h)]
    if not times:
        return
    rows = []
    for t in times:
        q, q_t, q_tt = drive.evaluate(t)
        qp, q_tp, _ = drive.evaluate(t + h)
        qm, q_tm, _ = drive.evaluate(t - h)
        rows.append((t, q, q_t, q_tt, (qp - qm) / (2 * h), (q_tp - q_tm) / (2 * h)))
    a = np.array(rows)
    omega = 2 * math.pi / period
    rate = max(float(np.max(np.abs(a[:, 2]))), float(np.max(np.abs(a[:, 4]))),
               omega * float(np.ptp(a[:, 1])), 1e-300)
    accel = max(float(np.max(np.abs(a[:, 3]))), float(np.max(np.abs(a[:, 5]))), omega * rate, 1e-300)
    for t, q, q_t, q_tt, d1, d2 in rows:
        if abs(q_t - d1) > tol * rate:
            raise ModelFileError(
                f"drive {drive.name!r}: motion at t = {t:.6g} s: q_t = {q_t:.6g} is not the time derivative of q "
                f"(central difference {d1:.6g}); motion must return (q, dq/dt, d2q/dt2)")
        if abs(q_tt - d2) > tol * accel:
            raise ModelFileError(
                f"drive {drive.name!r}: motion at t = {t:.6g} s: q_tt = {q_tt:.6g} is not the time derivative of "
                f"q_t (central difference {d2:.6g}); motion must return (q, dq/dt, d2q/dt2)")


def build_model(model: ModelDefinition, omega: float, *, prescribe_drives: bool = False) -> BuiltModel:
    """Build and assemble ``model`` at ``omega`` in a fresh Exudyn system; check its drives.

    With ``prescribe_drives`` each drive's coordinate is held on its motion by a
    ``CoordinateConstraint`` with an offset user function (added after the
    model's own items, so the model's algebraic equations come first and the
    drives' multipliers -- the feed-forward torques with Exudyn's sign -- last).

    Raises
    ------
    ModelFileError
        ``build`` raised (its message is shown), returned ``None`` or something
        that is not a sequence of drives, called ``mbs.Assemble()`` itself, a
        drive is malformed, a marker is not a ``MarkerNodeCoordinate``, two
        drives have the same name, a motion is not T-periodic or its ``q_t``,
        ``q_tt`` are not the derivatives of ``q`` (:func:`check_derivatives`),
        ``Assemble`` failed, or the model has ODE1 coordinates.
    ValueError
        If ``omega`` is not finite and positive.
    """
    import exudyn as exu

    omega = float(omega)
    if not (math.isfinite(omega) and omega > 0):
        raise ValueError(f"omega must be finite and > 0, got {omega!r}")
    where = f"model {model.name}"
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    try:
        raw = model.call_build(mbs, omega)
    except ModelFileError as exc:
        raise ModelFileError(f"{where}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - the user's code: one line
        raise ModelFileError(f"{where}: build(mbs, omega) raised {_one_line(exc)}") from None
    if raw is None:
        raise ModelFileError(f"{where}: build returned None; it must return the list of drives ([] for a model "
                             "without drives)")
    if mbs.systemData.ODE2Size() > 0 or mbs.systemIsConsistent:
        raise ModelFileError(f"{where}: build called mbs.Assemble(); leave that to flexstab (it adds the drives' "
                             "constraints or controllers first)")
    if isinstance(raw, (Mapping, Drive, str)) or not isinstance(raw, Sequence):
        raise ModelFileError(f"{where}: build must return a sequence of drives (list of mappings), got {type(raw).__name__}")
    try:
        drives = tuple(Drive.coerce(d) for d in raw)
    except ModelFileError as exc:
        raise ModelFileError(f"{where}: {exc}") from None
    names = [d.name for d in drives]
    if len(set(names)) != len(names):
        raise ModelFileError(f"{where}: drive names must be unique, got {names}")
    if prescribe_drives:
        from exudyn.itemInterface import CoordinateConstraint

        for d in drives:
            def offset(mbs_, t, item, value, _motion=d.motion):  # noqa: ARG001
                return float(_motion(t)[0])

            try:
                mbs.AddObject(CoordinateConstraint(markerNumbers=list(d.markers), offset=0.0,
                                                   offsetUserFunction=offset, name=f"drive {d.name}"))
            except Exception as exc:  # noqa: BLE001
                raise ModelFileError(f"{where}: drive {d.name!r}: {_one_line(exc)}") from None
    try:
        mbs.Assemble()
    except Exception as exc:  # noqa: BLE001
        raise ModelFileError(f"{where}: Exudyn's Assemble failed: {_one_line(exc)}") from None
    if mbs.systemData.ODE1Size() != 0:
        raise ModelFileError(f"{where}: ODE1 coordinates are not supported (the model has {mbs.systemData.ODE1Size()})")
    if mbs.systemData.ODE2Size() == 0:
        raise ModelFileError(f"{where}: the model has no ODE2 coordinates")
    idx = np.array([[_marker_index(mbs, d.markers[0], d.name), _marker_index(mbs, d.markers[1], d.name)]
                    for d in drives], dtype=int).reshape(len(drives), 2)
    for d, (i0, i1) in zip(drives, idx):
        if i0 == i1:
            raise ModelFileError(f"{where}: drive {d.name!r}: both markers address the same coordinate")
    period = 2.0 * math.pi / omega
    turns = []
    for d in drives:
        try:
            turns.append(drive_turns(d, period))
            check_derivatives(d, period)
        except ModelFileError as exc:
            raise ModelFileError(f"{where}: {exc}") from None
    logger.debug("built %s at omega=%g: %d ODE2, %d AE, drives %s", model.name, omega,
                 mbs.systemData.ODE2Size(), mbs.systemData.AEsize(), names)
    return BuiltModel(definition=model, omega=omega, system_container=sc, mbs=mbs, drives=drives,
                      drive_indices=idx, drive_turns=tuple(turns))
