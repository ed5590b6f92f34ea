"""Physical parameters of the single-link flexible manipulator.

One frozen dataclass, :class:`ManipulatorParameters`, describes the hub, the
flexible aluminium link and the tip mass.  Its defaults are the values of
Table 1 of the reference paper (Dat, Khang, Hoang, Quyen, *Stability Control of
Dynamical Systems Described by Linear Differential Equations with
Time-Periodic Coefficients*, p. 489).  Both the paper's reduced one-mode model
(:mod:`mbs_models.reduced`) and the Exudyn ANCF model are built from it, so a
user describes a manipulator exactly once.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

__all__ = ["ManipulatorParameters"]

# Fields that must be strictly positive, and those that may be zero.
_POSITIVE = ("length", "area", "density", "second_moment", "youngs_modulus", "hub_inertia")
_NON_NEGATIVE = ("tip_mass", "joint_damping", "gravity")


@dataclass(frozen=True)
class ManipulatorParameters:
    """Hub, link and tip-mass data of a single-link flexible manipulator (SI units).

    Parameters
    ----------
    length : float
        Link length ``l`` in m (Table 1: 0.9).
    area : float
        Cross-section area ``A`` in m^2 (Table 1: 4e-4).
    density : float
        Mass density ``rho`` of the link in kg/m^3 (Table 1: 2700).
    second_moment : float
        Area moment of inertia ``I = b h^3 / 12`` in m^4 (Table 1: 1.3333e-8).
    youngs_modulus : float
        Young's modulus ``E`` in N/m^2 (Table 1: 7.11e10).
    hub_inertia : float
        Mass moment of inertia ``J1`` of the hub about O in kg m^2 (Table 1: 5.86e-5).
    tip_mass : float
        Point mass ``m_E`` at the free end E in kg (Table 1: 0.1).
    joint_damping : float
        Viscous damping ``alpha`` of the hub joint in N m s/rad (Table 1: 0.01).
    gravity : float
        Gravitational acceleration ``g`` in m/s^2, acting along ``-e_y`` of the
        vertical plane of motion (not printed in the paper; 9.81).

    Raises
    ------
    ValueError
        If a field is NaN or infinite, if a length, area, density, stiffness or
        inertia is not strictly positive, or if the tip mass, damping or gravity
        is negative.  The message names the field.

    Examples
    --------
    >>> p = ManipulatorParameters()
    >>> round(p.link_mass, 4)
    0.972
    >>> ManipulatorParameters(tip_mass=-1.0)
    Traceback (most recent call last):
    ...
    ValueError: tip_mass must be >= 0, got -1.0
    """

    length: float = 0.9
    area: float = 4e-4
    density: float = 2700.0
    second_moment: float = 1.3333e-8
    youngs_modulus: float = 7.11e10
    hub_inertia: float = 5.86e-5
    tip_mass: float = 0.1
    joint_damping: float = 0.01
    gravity: float = 9.81

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{f.name} must be a real number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{f.name} must be finite, got {value!r}")
            # normalise ints to floats so that equality and JSON are predictable
            object.__setattr__(self, f.name, float(value))
        for name in _POSITIVE:
            if getattr(self, name) <= 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in _NON_NEGATIVE:
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")

    # ------------------------------------------------------------------ derived
    @property
    def mass_per_length(self) -> float:
        """Mass per unit length ``mu = rho A`` of the link in kg/m."""
        return self.density * self.area

    @property
    def link_mass(self) -> float:
        """Mass ``m_OE = rho A l`` of the link in kg."""
        return self.mass_per_length * self.length

    @property
    def bending_stiffness(self) -> float:
        """Bending stiffness ``E I`` of the link in N m^2."""
        return self.youngs_modulus * self.second_moment

    @property
    def axial_stiffness(self) -> float:
        """Axial stiffness ``E A`` of the link in N."""
        return self.youngs_modulus * self.area

    # ------------------------------------------------------------------ I/O
    def to_dict(self) -> dict[str, float]:
        """Return the fields as a plain ``dict`` (JSON-serialisable)."""
        return asdict(self)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "ManipulatorParameters":
        """Build from a mapping, rejecting unknown keys with a clear message.

        Parameters
        ----------
        data : Mapping
            Keys are field names of this class; missing ones take the Table 1
            defaults.

        Raises
        ------
        ValueError
            On an unknown key (the message lists the allowed ones) or an
            invalid value.
        """
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ValueError(
                f"unknown manipulator parameter(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(sorted(allowed))}"
            )
        return cls(**dict(data))
