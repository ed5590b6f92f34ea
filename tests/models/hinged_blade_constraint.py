"""The hinged blade of hinged_blade.py with the hub held by a rheonomic ``CoordinateConstraint``
(offset ``Omega t``) instead of a drive: no drives, the hub turns one whole turn per period."""
import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location("hinged_blade_for_constraint", Path(__file__).with_name("hinged_blade.py"))
_blade = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_blade)


def build(mbs, omega):
    return _blade.build(mbs, omega, form="constraint")
