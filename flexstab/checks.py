"""The checks behind the exit codes: one function per kind of result, one line per failed check.

Exit code 0 means that every check passed; a command whose result fails one of
these checks prints each line on stderr and exits with code 1 (the study marks
the stage ``"check failed"``).  Every command and the study read the same
function, so a new condition is added here once.
"""
from __future__ import annotations

from typing import Mapping

__all__ = ["validation_failures", "exit_code"]


def validation_failures(d: Mapping) -> list[str]:
    """The failed checks of a nonlinear multiplier validation, one line each (empty: every check passed).

    ``d`` is :meth:`validation.multipliers.MultiplierValidation.to_dict` (what ``flexstab validate
    --json`` prints).  Failed: a nonlinear run diverged (the one-period map or the growth run), or the
    measured multipliers do not confirm the predicted ones (``agrees`` false: a disagreement beyond the
    measurement's error bar, a step refinement that does not converge, or no verdict at all).
    """
    failures: list[str] = []
    if d.get("diverged"):
        at = d.get("diverged_at")
        failures.append("the nonlinear run diverged" + (f" at t = {at:.4g} s" if at is not None else "")
                        + (f": {d['reason']}" if d.get("reason") else ""))
    growth = d.get("growth") or {}
    if growth.get("diverged"):
        failures.append("the growth run diverged" + (f": {growth['reason']}" if growth.get("reason") else ""))
    if not d.get("agrees"):
        why = "; the step refinement does not converge" if d.get("step_converged") is False else ""
        failures.append("the multipliers measured from the nonlinear runs do not confirm the predicted ones "
                        f"(agrees = false{why})")
    full = d.get("full_map") or {}
    if full.get("unmatched"):
        failures.append("the full one-period map has slow multipliers the prediction does not have (|mu| = "
                        + ", ".join(f"{u['modulus']:.6g}" for u in full["unmatched"]) + ")")
    return failures


def exit_code(failures) -> int:
    """``1`` if any check failed, else ``0``."""
    return 1 if failures else 0
