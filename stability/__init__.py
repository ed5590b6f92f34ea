"""Floquet stability analysis of linear T-periodic systems.

The engines the package uses: :func:`floquet` (Magnus methods and the paper's procedure),
:func:`modal_floquet` (the frozen-modal frame of stiff linearised models) and
:func:`hill_multipliers` (Hill's method); :func:`stability.implicit.implicit_floquet` computes the
dominant multipliers of large systems matrix-free.
"""
from stability.floquet import DEFAULT_METHOD, METHODS, FloquetError, FloquetResult, floquet
from stability.gains import Gains, MeasuredPlant, Plant
from stability.hill import HillError, HillResult, hill_multipliers
from stability.modal import ModalBasisError, ModalFloquetResult, modal_floquet
from stability.periodic import SecondOrderPeriodicSystem, first_order_matrix
from stability.response import LinearResponse, linear_response

__all__ = [
    "floquet",
    "FloquetResult",
    "FloquetError",
    "METHODS",
    "DEFAULT_METHOD",
    "modal_floquet",
    "ModalFloquetResult",
    "ModalBasisError",
    "hill_multipliers",
    "HillResult",
    "HillError",
    "SecondOrderPeriodicSystem",
    "first_order_matrix",
    "linear_response",
    "LinearResponse",
    "Gains",
    "Plant",
    "MeasuredPlant",
]
