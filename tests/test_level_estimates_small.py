"""The plain-Python estimate of small systems gives the numbers of the general (numpy) rules.

:func:`stability.floquet._level_estimates` takes a plain-Python path for a handful of multipliers on
a three-level ladder; the general path is the reference here (forced by switching the fast path
off).  Both must agree to rounding on every field, on systems with real, complex, unstable and
rounding-level multipliers, for the moduli and the multipliers accuracies.
"""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from mbs_models.reduced import ReducedModel

F = importlib.import_module("stability.floquet")


def _mathieu(a: float, q: float, zeta: float = 0.0):
    def P(t):
        return np.array([[0.0, 1.0], [-(a - 2.0 * q * math.cos(2.0 * t)), -2.0 * zeta]])
    return P


def _random_system(seed: int, n: int):
    rng = np.random.default_rng(seed)
    A0, A1, B1 = (rng.standard_normal((n, n)) for _ in range(3))
    A0 -= (0.5 + rng.random()) * np.eye(n) * rng.choice([-1.0, 1.0])

    def P(t):
        return A0 + A1 * math.cos(2.0 * math.pi * t) + 0.5 * B1 * math.sin(4.0 * math.pi * t)
    return P


CASES = (
    [(f"paper {k}pi {kp}", ReducedModel(k * math.pi, kp, kd), None) for k, kp, kd in
     [(2, 0.0, 0.0), (4, 0.0, 0.0), (8, 0.0, 0.0), (2, 37.1617, 29.2410), (4, 28.7617, 11.7501),
      (8, 23.0147, 6.8628)]]
    + [(f"mathieu {a},{q}", _mathieu(a, q, z), math.pi) for a, q, z in
       [(1.0, 0.2, 0.0), (2.5, 1.0, 0.05), (4.0, 3.0, 0.1), (0.3, 0.1, 0.0)]]
    + [(f"random {s} n={n}", _random_system(s, n), 1.0) for s, n in [(1, 2), (2, 3), (3, 4), (4, 6), (5, 8)]]
)


def _levels(P, period, N):
    wrapped = F.PeriodicMatrixFunction(P, period)
    T = wrapped.period
    scheme = F._SCHEMES["magnus6"]
    _, samples = F._probe_and_samples(wrapped, T, scheme)
    scale = F._balancing_scale(samples)
    target = wrapped if scale is None else F._Balanced(wrapped, scale)
    with np.errstate(all="ignore"):
        return F._magnus_solves_small(scheme, target, T, [N // 4, N // 2, N], False, False)


def _general(levels, accuracy, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(F, "_level_estimates_small", lambda *a, **k: None)
        return F._level_estimates(levels, 6, accuracy)


def _close(a, b, noise):
    """Equal to rounding: 1e-9 relative, or 1 % of the multiplier's rounding level (a change that is
    itself rounding noise differs in its last bits between ``math`` and numpy's complex arithmetic)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    noise = np.broadcast_to(np.asarray(noise, float), a.shape)
    same = (np.isinf(a) == np.isinf(b)) & (np.isnan(a) == np.isnan(b))
    fin = np.isfinite(a) & np.isfinite(b)
    ok = np.abs(a - b) <= 1e-9 * np.abs(b) + 1e-2 * noise
    return bool(np.all(same) and np.all(ok[fin]))


@pytest.mark.parametrize("accuracy", ["moduli", "multipliers"])
def test_plain_python_estimates_equal_the_general_rules(accuracy, monkeypatch):
    taken = 0
    for label, P, period in CASES:
        for N in (16, 32, 64, 128, 256):
            try:
                levels = _levels(P, period, N)
            except F._Unresolved:  # the coarsest level overflows: no estimate to compare
                continue
            fast = F._level_estimates_small(levels, 6, accuracy)
            ref = _general(levels, accuracy, monkeypatch)
            if fast is None:
                continue
            taken += 1
            for name in ("estimates", "phase_estimates", "noise", "error", "phase_error", "observed_order"):
                noise = ref.noise if np.ndim(getattr(ref, name)) else float(np.min(ref.noise))
                if name == "observed_order":
                    # log(d1 / d2) / log 2: changes near their rounding level carry ~1e-7 relative
                    # rounding, i.e. ~1e-7 in the order (which only meets thresholds 3 and p + 4)
                    assert abs(fast.observed_order - ref.observed_order) <= 1e-6 or \
                        (math.isnan(fast.observed_order) and math.isnan(ref.observed_order)), (label, N)
                    continue
                assert _close(getattr(fast, name), getattr(ref, name), noise), (label, N, name, getattr(fast, name),
                                                                         getattr(ref, name))
            assert (fast.order_checked, fast.clusters, fast.rounding_limited) == \
                (ref.order_checked, ref.clusters, ref.rounding_limited), (label, N)
            # the default entry point takes the fast path for these and returns its numbers
            assert F._level_estimates(levels, 6, accuracy).error == fast.error
    # not vacuous: the fast path decides most of these cases
    assert taken >= 0.6 * 5 * len(CASES), taken


def test_plain_python_estimates_leave_defective_groups_to_the_general_rules(monkeypatch):
    """A Jordan block (damped Mathieu equation on a transition curve): the group's Henrici bound comes
    from the general path, whichever path is asked."""
    from scipy.special import mathieu_a

    q, zeta = 1.0, 0.0
    a = float(mathieu_a(1, q))
    levels = _levels(_mathieu(a, q, zeta), math.pi, 128)
    ref = _general(levels, "moduli", monkeypatch)
    got = F._level_estimates(levels, 6, "moduli")
    assert ref.clusters and got.clusters == ref.clusters
    assert F._level_estimates_small(levels, 6, "moduli") is None
