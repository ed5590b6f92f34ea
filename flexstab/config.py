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

Unknown sections or keys and invalid values raise ``ValueError`` naming them.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Optional, Union

from mbs_models.parameters import ManipulatorParameters
from taguchi.tuning import check_gain_range

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["StudyConfig", "load_config"]


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
    """

    manipulator: ManipulatorParameters = field(default_factory=ManipulatorParameters)
    omega: float = 2 * math.pi
    target: float = 0.3
    kp_range: tuple[float, float] = (0.0, 60.0)
    kd_range: tuple[float, float] = (0.0, 40.0)
    elements: int = 8

    def __post_init__(self) -> None:
        if not (math.isfinite(self.omega) and self.omega > 0):
            raise ValueError(f"omega must be finite and > 0, got {self.omega!r}")
        if not (math.isfinite(self.target) and self.target > 0):
            raise ValueError(f"target must be finite and > 0, got {self.target!r}")
        object.__setattr__(self, "kp_range", check_gain_range(self.kp_range, "kp_range"))
        object.__setattr__(self, "kd_range", check_gain_range(self.kd_range, "kd_range"))
        if isinstance(self.elements, bool) or not isinstance(self.elements, int) or self.elements < 1:
            raise ValueError(f"elements must be an integer >= 1, got {self.elements!r}")

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "StudyConfig":
        """Build from the parsed TOML mapping (see module docstring)."""
        from flexstab.options import parse_omega

        if not isinstance(data, Mapping):
            raise ValueError("config must be a TOML document with [manipulator] and/or [study] tables")
        for section in ("manipulator", "study"):
            if section in data and not isinstance(data[section], Mapping):
                raise ValueError(f"[{section}] must be a table of key = value pairs, got {type(data[section]).__name__}")
        unknown = sorted(set(data) - {"manipulator", "study"})
        if unknown:
            raise ValueError(f"unknown config section(s) {', '.join(unknown)}; allowed: manipulator, study")
        manip = ManipulatorParameters.from_mapping(data.get("manipulator", {}))
        study = dict(data.get("study", {}))
        allowed = {f.name for f in fields(cls)} - {"manipulator"}
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
        return cls(manipulator=manip, **study)

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
