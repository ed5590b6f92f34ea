"""Frozen results that stay frozen: read-only arrays and short representations.

A frozen dataclass forbids ``res.multipliers = x`` but not ``res.multipliers[0] = 0``: numpy arrays
are mutable objects.  :func:`frozen_result` makes every array field of a result a read-only view when
the result is made (the caller's own array stays writable; copy a field, ``np.array(res.x)``, to
change it), and gives the class a short ``repr``: arrays by shape and dtype (a handful of numbers
shown), nested results by their own short ``repr``, long text cut, so that a result printed in a REPL
or a log is one readable line instead of a monodromy matrix.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np

__all__ = ["frozen_result", "freeze_arrays", "short_repr", "REPR_ITEMS", "REPR_TEXT"]

#: Arrays and sequences of at most this many items are shown in full by :func:`short_repr`.
REPR_ITEMS = 4
#: Longest text of one field in :func:`short_repr`.
REPR_TEXT = 60


@functools.lru_cache(maxsize=None)
def _field_names(klass: type) -> frozenset:
    """The dataclass field names of ``klass`` (cached: a class's fields do not change)."""
    return frozenset(f.name for f in dataclasses.fields(klass))


def freeze_arrays(obj: Any) -> None:
    """Replace every writable numpy array field of the dataclass ``obj`` by a read-only view."""
    ndarray, setattr_ = np.ndarray, object.__setattr__
    fields = _field_names(type(obj))
    values = getattr(obj, "__dict__", None)
    if values is None:  # slots
        values = {name: getattr(obj, name, None) for name in fields}
    for name, v in list(values.items()):
        if isinstance(v, ndarray) and v.flags.writeable and name in fields:
            view = v.view()
            view.flags.writeable = False
            setattr_(obj, name, view)


def _number(x: Any) -> str:
    if isinstance(x, complex):
        return f"{x.real:.6g}{x.imag:+.6g}j"
    return f"{x:.6g}" if isinstance(x, float) else repr(x)


def _short(v: Any) -> str:
    if isinstance(v, np.ndarray):
        if v.size <= REPR_ITEMS and v.ndim <= 1 and v.dtype.kind in "biufc":
            return "[" + ", ".join(_number(x) for x in v.tolist()) + "]"
        return f"<array {'x'.join(map(str, v.shape))} {v.dtype}>"
    if isinstance(v, float):
        return _number(v)
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        text = repr(v)
        return text if len(text) <= REPR_TEXT else f"{type(v).__name__}(...)"
    if isinstance(v, (list, tuple)) and len(v) > REPR_ITEMS:
        return f"<{type(v).__name__} of {len(v)}>"
    if isinstance(v, dict) and len(v) > REPR_ITEMS:
        return f"<dict of {len(v)}>"
    text = repr(v)
    return text if len(text) <= REPR_TEXT else text[: REPR_TEXT - 3] + "..."


def short_repr(obj: Any) -> str:
    """``Name(field=value, ...)`` of the dataclass ``obj`` with every value shortened (see module)."""
    parts = [f"{f.name}={_short(getattr(obj, f.name, None))}" for f in dataclasses.fields(obj) if f.repr]
    return f"{type(obj).__name__}({', '.join(parts)})"


def frozen_result(cls: Any = None, *, repr: bool = True) -> Any:  # noqa: A002 - dataclass's own keyword
    """Class decorator (outside ``@dataclass(frozen=True)``): read-only array fields and, with
    ``repr=True``, :func:`short_repr` as ``__repr__``."""
    def wrap(klass: Any) -> Any:
        init = klass.__init__

        @functools.wraps(init)
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            init(self, *args, **kwargs)
            freeze_arrays(self)

        klass.__init__ = __init__
        own_setstate = klass.__dict__.get("__setstate__")

        def __setstate__(self, state: Any) -> None:
            # unpickling (a result returned by a worker process) bypasses __init__: freeze here too
            if own_setstate is not None:
                own_setstate(self, state)
            else:
                slots = None
                if isinstance(state, tuple) and len(state) == 2:
                    state, slots = state
                for name, value in {**(state or {}), **(slots or {})}.items():
                    object.__setattr__(self, name, value)
            freeze_arrays(self)

        klass.__setstate__ = __setstate__
        if repr:
            klass.__repr__ = short_repr
        return klass

    return wrap if cls is None else wrap(cls)
