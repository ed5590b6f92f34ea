"""Floquet stability analysis of linear T-periodic systems."""
from stability.floquet import DEFAULT_METHOD, METHODS, FloquetError, FloquetResult, floquet
from stability.implicit import ImplicitFloquetResult, implicit_floquet
from stability.periodic import SecondOrderPeriodicSystem, first_order_matrix
from stability.response import LinearResponse, linear_response

__all__ = [
    "floquet",
    "FloquetResult",
    "FloquetError",
    "implicit_floquet",
    "ImplicitFloquetResult",
    "METHODS",
    "DEFAULT_METHOD",
    "SecondOrderPeriodicSystem",
    "first_order_matrix",
    "linear_response",
    "LinearResponse",
]
