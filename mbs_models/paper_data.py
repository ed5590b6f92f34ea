"""Numbers printed in the reference paper that belong to the model definition.

Kept in ``mbs_models`` (the first stage of the data path) so that the
validation stage and the application can both read them without importing
each other.

References
----------
.. [1] Dat, D. C., Khang, N. V., Hoang, N. Q., Quyen, N. V., *Stability
   Control of Dynamical Systems Described by Linear Differential Equations
   with Time-Periodic Coefficients*, Table 3 (p. 489).
"""
from __future__ import annotations

__all__ = ["TABLE3_PRINTED", "TABLE3_GAINS", "table3_gains"]

#: Table 3 of the paper (p. 489 of the proceedings): Omega/pi, rho_d, kp, kd, printed |rho_1|.
TABLE3_PRINTED = [
    (2, 0.3, 37.1617, 29.2410, 0.3),
    (4, 0.3, 28.7617, 11.7501, 0.3),
    (6, 0.3, 22.2666, 6.7208, 0.3),
    (8, 0.4, 23.0147, 6.8628, 0.4),
]

#: Omega / pi -> printed (kp, kd) of Table 3.
TABLE3_GAINS = {k: (kp, kd) for k, _rho_d, kp, kd, _rho in TABLE3_PRINTED}


def table3_gains(omega: float, rtol: float = 1e-9):
    """Printed ``(Omega/pi, kp, kd)`` of the Table 3 case at ``omega`` (rad/s), or ``None``."""
    import math

    for k, _rho_d, kp, kd, _rho in TABLE3_PRINTED:
        if abs(omega - k * math.pi) <= rtol * abs(omega):
            return k, kp, kd
    return None
