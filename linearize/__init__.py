"""Periodic orbits and linearisations of model files."""
from linearize.finite_difference import CENTRAL_DIFFERENCE_STEP, central_difference_jacobians
from linearize.fourier import differentiation_matrices, sample_times, trig_interpolate
from linearize.system import LinearizedPeriodicSystem

#: The generic (model-file) path, imported on first use (it imports Exudyn).
_LAZY = {
    "PeriodicOrbit": "linearize.periodic_orbit",
    "OrbitConvergenceError": "linearize.periodic_orbit",
    "find_orbit": "linearize.periodic_orbit",
    "linearize_orbit": "linearize.constrained",
    "null_space_basis": "linearize.constrained",
    "ConstraintBasisError": "linearize.constrained",
    "analyze": "linearize.analysis",
    "ModelFloquetResult": "linearize.analysis",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'linearize' has no attribute {name!r}")


__all__ = [
    "LinearizedPeriodicSystem",
    "CENTRAL_DIFFERENCE_STEP",
    "central_difference_jacobians",
    "differentiation_matrices",
    "sample_times",
    "trig_interpolate",
    *sorted(_LAZY),
]
