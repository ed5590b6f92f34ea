"""Shared fixtures of the test suite."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def load_benchmark():
    """``load_benchmark(name)``: ``benchmarks/<name>.py`` imported as module ``<name>_benchmark``
    (registered in ``sys.modules`` while the test module runs, for dataclasses and pickling;
    removed afterwards)."""
    loaded = []

    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"{name}_benchmark", BENCHMARKS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        loaded.append(spec.name)
        spec.loader.exec_module(mod)
        return mod

    yield load
    for name in loaded:
        sys.modules.pop(name, None)


@pytest.fixture(params=["compiled", "numpy"])
def magnus_path(request, monkeypatch):
    """Runs a test on both implementations of the small-system Magnus-6 batch: the compiled kernel
    (:mod:`stability._compiled`) and the numpy stacks (the kernel switched off for the test)."""
    from stability import _compiled

    if request.param == "compiled":
        if not _compiled.available():
            pytest.fail("the compiled Magnus kernel is not available (numba is a dependency)")
    else:
        monkeypatch.setitem(_compiled._state, "kernel", None)
    return request.param
