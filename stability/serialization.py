"""Conversion of results to JSON-ready Python objects (the one place that does it).

Used by every result's ``to_dict``, the command-line ``--json`` output and the
resumable sweep stores.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["json_ready"]


def json_ready(obj: Any, *, finite: bool = True) -> Any:
    """Return ``obj`` with numpy arrays/scalars as lists/Python numbers and tuples as lists.

    Parameters
    ----------
    obj : Any
        Nested dicts, lists, tuples, numpy arrays and scalars; other objects
        are returned unchanged.
    finite : bool
        Replace NaN and infinite floats by ``None`` (strict JSON has no
        NaN/Infinity tokens).  ``False`` keeps them (Python's ``json`` then
        writes ``NaN``, which round-trips through ``json.loads``).
    """
    if isinstance(obj, np.ndarray):
        return [json_ready(v, finite=finite) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if (not finite or math.isfinite(obj)) else None
    if isinstance(obj, dict):
        return {
            (k.item() if isinstance(k, np.generic) else k): json_ready(v, finite=finite) for k, v in obj.items()
        }
    if isinstance(obj, (list, tuple)):
        return [json_ready(v, finite=finite) for v in obj]
    return obj
