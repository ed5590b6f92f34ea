"""User configuration: a TOML file describing the user's own manipulator.

Example (every key optional; missing ones take the paper's values)::

    [manipulator]            # ManipulatorParameters fields (SI units), Table 1 defaults
    length = 0.9
    tip_mass = 0.1

    [study]
    omega = "2pi"            # rad/s or a multiple of pi
    target = 0.3             # rho_d of Eq. (34)
    kp_range = [0.0, 60.0]
    kd_range = [0.0, 40.0]
    elements = 8             # ANCF elements of the Exudyn model
    damping = 1e-5           # structural damping of the beams (as --damping: BETA in s, or "beta=..,bending=..,axial=..")

    [robust]                 # robust design (tune --robust): noise factors of the outer array
    tip_mass = [0.05, 0.2]   # payload range in kg (nominal: [manipulator] tip_mass)
    omega_scale = [0.9, 1.1] # Omega x factor (nominal 1)
    youngs_modulus_scale = [0.95, 1.05]
    levels = 3               # levels per noise factor (outer array: L9 for three factors)
    outer_array = "L9"       # optional; default the smallest array that fits
    sn = "target"            # S/N over the outer runs: "target" (about rho_d) or "smaller"
    grid = 7                 # points per noise factor of the worst-case check (7^3 = 343)

Unknown sections or keys and invalid values raise ``ValueError`` naming them.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Optional, Union

from mbs_models.parameters import ManipulatorParameters

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["RobustSettings", "StudyConfig", "load_config"]


def _range(value: Any, name: str, positive: bool) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"[robust] {name} must be a pair [low, high], got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or (lo <= 0 if positive else lo < 0) or not lo < hi:
        raise ValueError(f"[robust] {name} must be finite, {'> 0' if positive else '>= 0'} and low < high, "
                         f"got {value!r}")
    return (lo, hi)


@dataclass(frozen=True)
class RobustSettings:
    """The ``[robust]`` section: noise ranges, outer array and S/N of the robust design.

    Attributes
    ----------
    tip_mass : (float, float)
        Payload range in kg; its nominal value is the manipulator's tip mass.
    omega_scale, youngs_modulus_scale : (float, float)
        Ranges of the factors on ``Omega`` and ``E`` (nominal 1).
    levels : int
        Levels per noise factor in the outer array.
    outer_array : str, optional
        Outer array name (default: the smallest that fits).
    sn : {"target", "smaller"}
        S/N ratio over the outer runs (see :mod:`taguchi.robust`).
    grid : int
        Points per noise factor of the fine worst-case grid.
    max_iterations : int
        Crossed-array experiments at most.
    """

    tip_mass: tuple[float, float] = (0.05, 0.2)
    omega_scale: tuple[float, float] = (0.9, 1.1)
    youngs_modulus_scale: tuple[float, float] = (0.95, 1.05)
    levels: int = 3
    outer_array: Optional[str] = None
    sn: str = "target"
    grid: int = 7
    max_iterations: int = 12

    def __post_init__(self) -> None:
        from taguchi.robust import ROBUST_SN

        object.__setattr__(self, "tip_mass", _range(self.tip_mass, "tip_mass", positive=False))
        for name in ("omega_scale", "youngs_modulus_scale"):
            object.__setattr__(self, name, _range(getattr(self, name), name, positive=True))
        for name, low in (("levels", 2), ("grid", 2), ("max_iterations", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"[robust] {name} must be an integer >= {low}, got {v!r}")
        if self.sn not in ROBUST_SN:
            raise ValueError(f"[robust] sn must be one of {', '.join(ROBUST_SN)}, got {self.sn!r}")
        if self.outer_array is not None and not isinstance(self.outer_array, str):
            raise ValueError(f"[robust] outer_array must be an array name like \"L9\", got {self.outer_array!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "RobustSettings":
        """Build from the parsed ``[robust]`` table, rejecting unknown keys."""
        allowed = {f.name for f in fields(cls)}
        bad = sorted(set(data) - allowed)
        if bad:
            raise ValueError(f"unknown [robust] key(s) {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")
        return cls(**dict(data))

    def noise_factors(self, nominal_tip_mass: float) -> tuple:
        """The :class:`taguchi.robust.NoiseFactor` triple (tip mass, Omega scale, E scale)."""
        from taguchi.robust import NoiseFactor

        lo, hi = self.tip_mass
        if not lo <= nominal_tip_mass <= hi:
            raise ValueError(f"[robust] tip_mass range [{lo}, {hi}] must contain the nominal tip mass "
                             f"{nominal_tip_mass}")
        return (
            NoiseFactor("tip_mass", lo, hi, float(nominal_tip_mass), self.levels),
            NoiseFactor("omega_scale", *self.omega_scale, 1.0, self.levels),
            NoiseFactor("youngs_modulus_scale", *self.youngs_modulus_scale, 1.0, self.levels),
        )


@dataclass(frozen=True)
class StudyConfig:
    """Everything a study needs besides the numerical options.

    Attributes
    ----------
    manipulator : ManipulatorParameters
    omega : float
        Frequency of the fundamental motion in rad/s.
    target : float
        Target spectral radius ``rho_d`` (0 < target < 1 for stabilisation).
    kp_range, kd_range : (float, float)
        Initial search ranges of the PD gains (non-negative, low < high).
    elements : int
        ANCF elements of the Exudyn model (>= 1).
    damping : mbs_models.damping.DampingSpec
        Structural damping of the beam elements (``--damping``; default none).
    rtol : float
        The accuracy contract of printed multipliers (``docs/accuracy.md``): every multiplier with
        modulus ``>= 1e-6`` of the largest is certified to this relative error or reported with the
        reason (``--rtol`` overrides it; default 1e-6).
    """

    manipulator: ManipulatorParameters = field(default_factory=ManipulatorParameters)
    omega: float = 2 * math.pi
    target: float = 0.3
    kp_range: tuple[float, float] = (0.0, 60.0)
    kd_range: tuple[float, float] = (0.0, 40.0)
    elements: int = 8
    robust: RobustSettings = field(default_factory=RobustSettings)
    damping: Any = None
    rtol: float = 1e-6

    def __post_init__(self) -> None:
        if not (math.isfinite(self.omega) and self.omega > 0):
            raise ValueError(f"omega must be finite and > 0, got {self.omega!r}")
        if not (math.isfinite(self.target) and self.target > 0):
            raise ValueError(f"target must be finite and > 0, got {self.target!r}")
        from taguchi.tuning import check_gain_range  # here: parsing the command line imports no numpy

        object.__setattr__(self, "kp_range", check_gain_range(self.kp_range, "kp_range"))
        object.__setattr__(self, "kd_range", check_gain_range(self.kd_range, "kd_range"))
        if isinstance(self.elements, bool) or not isinstance(self.elements, int) or self.elements < 1:
            raise ValueError(f"elements must be an integer >= 1, got {self.elements!r}")
        from mbs_models.damping import DampingSpec, parse_damping

        if not isinstance(self.damping, DampingSpec):
            object.__setattr__(self, "damping", parse_damping(self.damping))
        if isinstance(self.rtol, bool) or not isinstance(self.rtol, (int, float)) \
                or not (math.isfinite(self.rtol) and 0.0 < self.rtol < 1.0):
            raise ValueError(f"rtol must be a number in (0, 1), got {self.rtol!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "StudyConfig":
        """Build from the parsed TOML mapping (see module docstring)."""
        from flexstab.options import parse_omega

        if not isinstance(data, Mapping):
            raise ValueError("config must be a TOML document with [manipulator] and/or [study] tables")
        for section in ("manipulator", "study", "robust"):
            if section in data and not isinstance(data[section], Mapping):
                raise ValueError(f"[{section}] must be a table of key = value pairs, got {type(data[section]).__name__}")
        unknown = sorted(set(data) - {"manipulator", "study", "robust"})
        if unknown:
            raise ValueError(f"unknown config section(s) {', '.join(unknown)}; allowed: manipulator, study, robust")
        manip = ManipulatorParameters.from_mapping(data.get("manipulator", {}))
        study = dict(data.get("study", {}))
        allowed = {f.name for f in fields(cls)} - {"manipulator", "robust"}
        bad = sorted(set(study) - allowed)
        if bad:
            raise ValueError(f"unknown [study] key(s) {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")
        if "omega" in study:
            study["omega"] = parse_omega(str(study["omega"]))
        if "target" in study:
            try:
                study["target"] = float(study["target"])
            except (TypeError, ValueError):
                raise ValueError(f"target must be a number, got {study['target']!r}") from None
        robust = RobustSettings.from_mapping(data.get("robust", {}))
        return cls(manipulator=manip, robust=robust, **study)

    def with_overrides(self, **changes: Any) -> "StudyConfig":
        """A copy with the given fields replaced (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


def load_config(path: Optional[Union[str, Path]]) -> StudyConfig:
    """Read a TOML configuration file (``None`` gives the paper's defaults).

    Raises
    ------
    ValueError
        If the file cannot be read or parsed, or holds unknown keys or invalid values.
    """
    if path is None:
        return StudyConfig()
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read config file {str(p)!r}: {exc.strerror}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"config file {str(p)!r} is not valid TOML: {exc}") from None
    return StudyConfig.from_mapping(data)
