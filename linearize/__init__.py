"""Finite-difference linearisation of the Exudyn model along its periodic orbit."""
from linearize.along_orbit import coordinate_names, linearize_along_orbit
from linearize.finite_difference import CENTRAL_DIFFERENCE_STEP, central_difference_jacobians
from linearize.fourier import differentiation_matrices, sample_times, trig_interpolate
from linearize.system import LinearizedPeriodicSystem

__all__ = [
    "LinearizedPeriodicSystem",
    "linearize_along_orbit",
    "coordinate_names",
    "CENTRAL_DIFFERENCE_STEP",
    "central_difference_jacobians",
    "differentiation_matrices",
    "sample_times",
    "trig_interpolate",
]
