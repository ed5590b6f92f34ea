"""Structural (material) damping of the beam elements: the one rule behind ``--damping``.

Kelvin-Voigt material: the stress follows the strain and its rate, ``sigma = E (eps + beta eps')``
with the loss time ``beta`` (s).  On Exudyn's ANCF cable elements that is

    ``bendingDamping = beta EI`` (N m^2 s, bending moment per curvature rate),
    ``axialDamping  = beta EA`` (N s, axial force per axial strain rate),

i.e. stiffness-proportional (Rayleigh ``C = beta K``) damping of the elastic forces: an elastic
mode of circular frequency ``omega`` gets the damping ratio ``zeta = beta omega / 2`` and decays
per period ``T`` of the fundamental motion by about ``exp(-beta omega^2 T / 2)``.  Metals have
``zeta ~ 1e-4 .. 1e-3`` in their lowest modes; ``beta = 1e-5 s`` gives ``zeta = 1.3e-3`` at
40 Hz and heavily damps the kHz mesh modes.  Exudyn's raw values can be given instead
(``bending=...,axial=...``); both add to the ``bending_damping`` / ``axial_damping`` options.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

__all__ = ["DampingSpec", "parse_damping", "material_damping_values"]


@dataclass(frozen=True)
class DampingSpec:
    """Parsed ``--damping``: a loss time ``beta`` (s) and/or Exudyn's raw ANCF values."""

    material: float = 0.0
    bending: float = 0.0
    axial: float = 0.0

    @property
    def given(self) -> bool:
        return bool(self.material or self.bending or self.axial)

    def build_options(self) -> dict:
        """Keyword options of a built-in model's ``build`` (only those set)."""
        out = {}
        if self.material:
            out["material_damping"] = self.material
        if self.bending:
            out["bending_damping"] = self.bending
        if self.axial:
            out["axial_damping"] = self.axial
        return out

    def describe(self) -> str:
        """Words for reports: ``"none (undamped beams)"`` or the values."""
        if not self.given:
            return "none (undamped beams)"
        parts = []
        if self.material:
            parts.append(f"Kelvin-Voigt beta = {self.material:g} s (bendingDamping = beta EI, axialDamping = beta EA)")
        if self.bending:
            parts.append(f"bendingDamping += {self.bending:g} N m^2 s")
        if self.axial:
            parts.append(f"axialDamping += {self.axial:g} N s")
        return "; ".join(parts)

    def to_dict(self) -> dict:
        return {"material_damping": self.material, "bending_damping": self.bending, "axial_damping": self.axial}


def _value(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"--damping: {what} must be a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"--damping: {what} must be finite and >= 0, got {text!r}")
    return v


def parse_damping(text: Optional[str]) -> DampingSpec:
    """``--damping`` / ``[model] damping``: ``BETA`` (s), or ``beta=B,bending=X,axial=Y`` (any subset).

    Raises
    ------
    ValueError
        A key other than beta/bending/axial, a negative or non-finite value.
    """
    if text is None or str(text).strip() == "":
        return DampingSpec()
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return DampingSpec(material=_value(str(text), "beta"))
    s = str(text).strip()
    if "=" not in s:
        return DampingSpec(material=_value(s, "beta (the Kelvin-Voigt loss time in s)"))
    values = {"beta": 0.0, "bending": 0.0, "axial": 0.0}
    for part in s.split(","):
        key, sep, val = part.partition("=")
        key = key.strip().lower()
        if not sep or key not in values:
            raise ValueError(f"--damping: expected BETA or beta=B,bending=X,axial=Y, got {text!r}")
        values[key] = _value(val.strip(), key)
    return DampingSpec(material=values["beta"], bending=values["bending"], axial=values["axial"])


def material_damping_values(beta: float, bending_stiffness: float, axial_stiffness: float,
                            bending_damping: float = 0.0, axial_damping: float = 0.0) -> tuple[float, float]:
    """Exudyn's ``(bendingDamping, axialDamping)`` of a beam with loss time ``beta`` (module notes), added to
    the raw values given.

    Raises
    ------
    ValueError
        A negative or non-finite value.
    """
    for name, v in (("material_damping", beta), ("bending_damping", bending_damping),
                    ("axial_damping", axial_damping)):
        if not (math.isfinite(float(v)) and float(v) >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    return (float(bending_damping) + float(beta) * float(bending_stiffness),
            float(axial_damping) + float(beta) * float(axial_stiffness))
