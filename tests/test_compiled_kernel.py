"""The compiled Magnus-6 kernel of small systems (:mod:`stability._compiled`).

Checked against an independent product of ``scipy.linalg.expm`` of the Magnus-6 exponents (the
``(N, n, n)`` path of :func:`stability.magnus.magnus_exponents`, a separate implementation of the
scheme), and against the numpy stacks it replaces; the analytic oracles of
``test_floquet_analytic.py`` run on both paths (the ``magnus_path`` fixture).
"""
from __future__ import annotations

import importlib
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import expm

from stability import FloquetError, floquet
from stability import _compiled
from stability.magnus import MAGNUS6, magnus_exponents

F = importlib.import_module("stability.floquet")
EPS = np.finfo(float).eps


def _random_stack(n: int, Ns: list[int], seed: int, scale: float = 1.0):
    """A smooth 1-periodic ``P`` (random Fourier coefficients), at the Gauss nodes of ``Ns`` equal
    sub-intervals of each level: ``(P (sum Ns, 3, n, n), h (sum Ns,), per-level (N, 3, n, n) stacks)``."""
    rng = np.random.default_rng(seed)
    C = scale * rng.standard_normal((3, n, n))

    def P(t):
        t = np.asarray(t)[..., None, None]
        return C[0] + C[1] * np.cos(2 * np.pi * t) + C[2] * np.sin(4 * np.pi * t)

    nodes = np.asarray(MAGNUS6.nodes)
    levels, hs = [], []
    for N in Ns:
        times = (np.arange(N)[:, None] + nodes[None, :]) / N
        levels.append(P(times))  # (N, 3, n, n)
        hs.append(np.full(N, 1.0 / N))
    stacked = np.concatenate(levels)  # (sum Ns, 3, n, n)
    return stacked, np.concatenate(hs), levels


def _reference_product(stack: np.ndarray, h: float) -> tuple[np.ndarray, float, float]:
    """``prod expm(Omega_k)`` by scipy, the trace sum and the largest commutator column sum, from
    the ``(N, q, n, n)`` implementation of the Magnus-6 exponent."""
    Om, C = magnus_exponents(MAGNUS6, stack, h, split=True)
    Phi = np.eye(stack.shape[-1])
    for O in Om:
        Phi = expm(O) @ Phi
    return Phi, float(np.trace(Om, axis1=1, axis2=2).sum()), float(np.abs(C).sum(axis=1).max())


def test_the_kernel_is_available():
    """numba is a dependency: the suite must exercise the kernel, not silently the numpy path."""
    assert _compiled.available()


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6, 8])
def test_kernel_equals_an_independent_scipy_product(n):
    Ns = [16, 32, 64]
    batch, h, levels = _random_stack(n, Ns, seed=n, scale=2.0)
    phis, stats = _compiled.magnus6_levels(batch, h, Ns)
    for i, (N, stack) in enumerate(zip(Ns, levels)):
        ref, trace, corr = _reference_product(stack, 1.0 / N)
        # two products of the same N well-conditioned factors: their difference is rounding,
        # ~ N n eps ||Phi|| (measured <= 2.2e-15 relative)
        assert np.linalg.norm(phis[i] - ref, 1) <= 100.0 * N * n * EPS * np.linalg.norm(ref, 1)
        assert stats[i, 0] == pytest.approx(trace, rel=1e-12, abs=1e-12)
        assert stats[i, 1] == pytest.approx(corr, rel=1e-12, abs=1e-15)


def test_levels_with_different_scalings_equal_the_scipy_product():
    """Each level squares as often as its own largest member needs (here 9, 5 and 3 times): every
    level equals the scipy product to the rounding of its squarings (~2^s N n eps)."""
    Ns = [4, 8, 16]
    batch, h, levels = _random_stack(4, Ns, seed=7, scale=20.0)
    phis, _ = _compiled.magnus6_levels(batch, h, Ns)
    for i, (N, stack) in enumerate(zip(Ns, levels)):
        ref, _, _ = _reference_product(stack, 1.0 / N)
        Om = magnus_exponents(MAGNUS6, stack, 1.0 / N)
        squarings = max(0, math.ceil(math.log2(np.abs(Om).sum(axis=1).max() / 0.82)))
        assert squarings >= 3  # the scaling is exercised
        tol = 10.0 * 2.0**squarings * N * 4 * EPS * np.linalg.norm(ref, 1)
        assert np.linalg.norm(phis[i] - ref, 1) <= tol


def test_the_balancing_ratio_scales_every_entry():
    """``ratio`` multiplies entry ``(i, j)`` of every ``P`` (the balancing ``D^-1 P D``): the kernel with
    it equals the kernel on the scaled stack, to the bit (the same products), and a wrong entry order
    (the transposed ratio) gives another monodromy matrix."""
    Ns = [8, 16]
    batch, h, _ = _random_stack(3, Ns, seed=5)
    d = np.array([1.0, 4.0, 0.25])
    ratio = d[None, :] / d[:, None]
    phis, stats = _compiled.magnus6_levels(batch, h, Ns, ratio)
    ref, ref_stats = _compiled.magnus6_levels(batch * ratio, h, Ns)
    np.testing.assert_array_equal(phis, ref)
    np.testing.assert_array_equal(stats, ref_stats)
    wrong, _ = _compiled.magnus6_levels(batch * ratio.T, h, Ns)
    assert np.abs(wrong - ref).max() > 1e-3 * np.abs(ref).max()


def test_the_4x4_specialisation_equals_the_general_loops():
    """The kernel's 4x4 paths (matrix products, the level product in registers) against its general
    loops: a 4x4 system padded with a decoupled zero state (n = 5, the general loops) gives the same
    4x4 block to the bit (the padding only adds exact zeros to every sum); a perturbed padding
    (coupling the fifth state) does not."""
    Ns = [16, 32]
    P4, h, _ = _random_stack(4, Ns, seed=11, scale=2.0)
    P5 = np.zeros(P4.shape[:2] + (5, 5))
    P5[..., :4, :4] = P4
    phi4, stats4 = _compiled.magnus6_levels(P4, h, Ns)
    phi5, stats5 = _compiled.magnus6_levels(P5, h, Ns)
    np.testing.assert_array_equal(phi5[:, :4, :4], phi4)
    np.testing.assert_array_equal(stats5, stats4)
    P5[..., 4, 0] = 1e-3
    P5[..., 0, 4] = 1e-3
    coupled, _ = _compiled.magnus6_levels(P5, h, Ns)
    assert np.abs(coupled[:, :4, :4] - phi4).max() > 1e-9


def test_a_nan_in_the_first_sub_interval_is_not_lost():
    """The running maxima keep a NaN (the commutator check must see it, wherever it is)."""
    Ns = [8]
    batch, h, _ = _random_stack(3, Ns, seed=2)
    batch[0, :, 0, 0] = np.nan
    _, stats = _compiled.magnus6_levels(batch, h, Ns)
    assert math.isnan(stats[0, 1]) and math.isnan(stats[0, 2])


def test_the_comparison_rejects_a_wrong_exponent():
    """The check above can fail: the kernel's product is far from the scipy product of the
    second-order (midpoint) exponents, which differ from Magnus-6 by the commutator terms."""
    Ns = [32]
    batch, h, levels = _random_stack(4, Ns, seed=4, scale=2.0)
    phis, _ = _compiled.magnus6_levels(batch, h, Ns)
    wrong = np.eye(4)
    for k in range(Ns[0]):
        wrong = expm(levels[0][k, 1] / Ns[0]) @ wrong
    assert np.linalg.norm(phis[0] - wrong, 1) > 1e-6 * np.linalg.norm(wrong, 1)


@pytest.mark.parametrize("n", [2, 4, 5])
def test_kernel_and_numpy_batches_agree(n, monkeypatch):
    """The batch as :func:`stability.floquet` runs it (balanced model-free P, three levels)."""
    rng = np.random.default_rng(10 + n)
    C = rng.standard_normal((3, n, n))

    class P:
        period = 1.0

        def evaluate(self, times):
            t = np.asarray(times)[:, None, None]
            return C[0] + C[1] * np.cos(2 * np.pi * t) + C[2] * np.sin(2 * np.pi * t)

        def __call__(self, t):
            return self.evaluate(np.array([t]))[0]

    results = {}
    for path in ("compiled", "numpy"):
        if path == "numpy":
            monkeypatch.setitem(_compiled._state, "kernel", None)
        results[path] = floquet(P(), n_steps=64)
    a, b = results["compiled"], results["numpy"]
    assert a.n_steps == b.n_steps == 64
    assert np.linalg.norm(a.monodromy - b.monodromy) <= 1e-12 * np.linalg.norm(b.monodromy)
    assert a.trace_integral == pytest.approx(b.trace_integral, rel=1e-13)
    assert a.error_estimate == pytest.approx(b.error_estimate, rel=1e-4)


def test_unresolved_coarse_level_is_dropped_and_an_unresolved_batch_raises():
    """The commutator test on the kernel's statistics: the coarsest of three levels is dropped where
    it does not resolve ``P`` (``optional_first``), and a batch whose finer levels do not either raises."""
    w = 40.0  # ||P|| ~ 40: at h = 1/2 the commutator part is far beyond the limit

    class P:
        period = 1.0
        n = 2

        def evaluate(self, times):
            t = np.asarray(times)
            out = np.zeros((t.size, 2, 2))
            out[:, 0, 1] = w * (1.0 + 0.5 * np.cos(2 * np.pi * t))
            out[:, 1, 0] = -w
            return out

        def __call__(self, t):
            return self.evaluate(np.array([t]))[0]

    from stability.periodic import PeriodicMatrixFunction

    wrapped = PeriodicMatrixFunction(P(), 1.0)
    solves = F._magnus_solves_small(MAGNUS6, wrapped, 1.0, [2, 64, 128], False, True, optional_first=True)
    assert [s.n_steps for s in solves] == [64, 128]
    with pytest.raises(F._Unresolved, match="commutator terms"):
        F._magnus_solves_small(MAGNUS6, wrapped, 1.0, [2, 4, 8], False, True, optional_first=True)


def test_overflow_is_one_clear_error():
    A = np.diag([800.0, -1.0])  # exp(800 T) beyond double precision
    with pytest.raises(FloquetError, match="beyond double precision|overflow"):
        floquet(lambda t: A, period=1.0, n_steps=4)


def test_huge_scaling_keeps_the_exponential_finite():
    """alpha beyond 2^32 THETA: the powers are scaled instead of the Taylor coefficients (whose
    c_16 2^-16 s would underflow).  A rotation by w = 5e9 rad in one step: the kernel and the numpy
    exponential stay on the rotation to the rounding of ~33 squarings (2^33 eps ~ 2e-6; measured 1.8e-7)."""
    from stability.expm import expm_soa

    w = 5.0e9
    A = np.array([[0.0, w], [-w, 0.0]])
    exact = np.array([[math.cos(w), math.sin(w)], [-math.sin(w), math.cos(w)]])
    batch = np.repeat(A[None, None], 3, axis=1)
    phis, stats = _compiled.magnus6_levels(batch, np.ones(1), [1])
    assert np.all(np.isfinite(phis))
    assert np.abs(phis[0] - exact).max() <= 1e-5
    assert np.abs(expm_soa(A[:, :, None])[:, :, 0] - exact).max() <= 1e-5
    assert stats[0, 2] == pytest.approx(w)


def test_switching_the_kernel_off():
    """``FLEXSTAB_NUMBA=0`` runs the numpy path (same answer)."""
    code = ("import numpy as np; from stability import floquet, _compiled; "
            "r = floquet(lambda t: np.array([[0.0, 1.0], [-4.0, -0.1]]), period=1.0); "
            "print(_compiled.available(), r.spectral_radius)")
    env = dict(os.environ, FLEXSTAB_NUMBA="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    flag, rho = out.stdout.split()
    assert flag == "False"
    assert float(rho) == pytest.approx(math.exp(-0.05), rel=1e-9)


def test_start_probe_commutator_size_equals_the_numpy_rule(monkeypatch):
    """The start rule's commutator size (:func:`stability.floquet._commutator_size`) from the kernel
    equals the ``(m, q, n, n)`` numpy computation of the same quantity."""
    _, _, levels = _random_stack(4, [8], seed=3, scale=3.0)
    probe = levels[0]
    compiled = F._commutator_size(MAGNUS6, probe, 0.125)
    monkeypatch.setitem(_compiled._state, "kernel", None)
    plain = F._commutator_size(MAGNUS6, probe, 0.125)
    assert compiled == pytest.approx(plain, rel=1e-12)
    assert compiled > 0.0
