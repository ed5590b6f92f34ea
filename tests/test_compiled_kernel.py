"""The optional compiled Magnus kernel (numba, ``stability._compiled``) and the numpy path.

Oracles: ``scipy.linalg.expm`` for constant ``P`` (Magnus is exact there: every
sub-interval propagator is ``expm(h A)``); the analytic Floquet tests of
``test_floquet_analytic`` (constant ``P``, Mathieu via ``scipy.special``) run on
both paths; the commutator measure / trace sum against the numpy formulas.
"""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from scipy.linalg import expm

from stability import _compiled
from stability.magnus import MAGNUS4, MAGNUS6, magnus_exponents

import test_floquet_analytic as analytic

FQ = sys.modules["stability.floquet"]
EPS = np.finfo(float).eps
needs_numba = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba not installed (optional extra 'fast')")


def _constant_stack(A, N, q):
    return np.broadcast_to(A, (N, q) + A.shape).copy()


def _kernel_bound(A, T, N):
    """Normwise bound on ``|Phi_kernel - expm(A T)|``.

    Each factor ``expm(h A)`` is the degree-16 Taylor polynomial (remainder <= eps at
    ||.|| <= 0.82) after s squarings: relative error <= (s + 2) n eps ||E||; N factors
    multiply to <= N (s + 2) n eps prod ||E_k|| <= N (s + 2) n eps exp(||A||_1 T).
    """
    n = A.shape[0]
    s = max(0, math.ceil(math.log2(max(np.abs(A).sum(axis=0).max() * T / N, 1e-300) / 0.82)))
    return N * (s + 2) * n * EPS * math.exp(np.abs(A).sum(axis=0).max() * T)


@needs_numba
@pytest.mark.parametrize("n", [4, 3])  # 4: the unrolled kernel; 3: the loop over a run-time n
@pytest.mark.parametrize("scheme", [MAGNUS6, MAGNUS4])
def test_kernel_constant_P_is_expm(n, scheme):
    rng = np.random.default_rng(n)
    A = rng.standard_normal((n, n))
    A *= 1.5 / np.abs(A).sum(axis=0).max()  # ||A||_1 = 1.5
    T, N = 2.0, 8  # h ||A|| = 0.375: no squaring; T ||A|| = 3: two squarings at N = 1
    for N in (1, 8, 64):
        phi, log_det, corr, om_max = _compiled.magnus_solve(_constant_stack(A, N, len(scheme.nodes)), T / N,
                                                            scheme.order)
        ref = expm(A * T)
        bound = _kernel_bound(A, T, N)
        assert np.abs(phi - ref).max() <= bound
        assert abs(log_det - T * np.trace(A)) <= N * n * EPS * np.abs(A).max() * T * 4
        assert corr <= 1e-14 * om_max  # constant P: the commutator terms vanish
        assert om_max == pytest.approx(np.abs(A).sum(axis=0).max() * T / N, rel=1e-14)
    # rejects a wrong step: h off by 1e-6 moves Phi far outside the bound
    phi, *_ = _compiled.magnus_solve(_constant_stack(A, 8, len(scheme.nodes)), (T / 8) * (1 + 1e-6), scheme.order)
    assert np.abs(phi - expm(A * T)).max() > 100 * _kernel_bound(A, T, 8)


@needs_numba
@pytest.mark.parametrize("n", [4, 3])
def test_kernel_commutator_part_and_trace_match_numpy(n):
    """The kernel's ``max ||Omega_k - h Pbar_k||_1`` and ``sum tr Omega_k`` equal the numpy formulas."""
    rng = np.random.default_rng(7)
    N, h = 16, 0.05
    for scheme in (MAGNUS6, MAGNUS4):
        q = len(scheme.nodes)
        Pg = rng.standard_normal((N, q, n, n))
        _, log_det, corr, om_max = _compiled.magnus_solve(Pg, h, scheme.order)
        Om = magnus_exponents(scheme, Pg, h)
        ref_corr = float(np.abs(Om - h * FQ._quadrature_mean(scheme, Pg)).sum(axis=1).max())
        assert corr == pytest.approx(ref_corr, rel=1e-12)
        assert log_det == pytest.approx(float(np.trace(Om, axis1=1, axis2=2).sum()), rel=1e-12, abs=1e-14)
        assert om_max == pytest.approx(float(np.abs(Om).sum(axis=1).max()), rel=1e-12)
        assert corr > 1e-6  # non-constant P: a real commutator part (the check above can fail)


@pytest.fixture(params=["compiled", "numpy"])
def path(request, monkeypatch):
    if request.param == "compiled" and not _compiled.AVAILABLE:
        pytest.skip("numba not installed (optional extra 'fast')")
    monkeypatch.setattr(FQ, "USE_COMPILED", request.param == "compiled")
    return request.param


def test_both_paths_constant_P(path):
    for case in sorted(analytic.CONSTANT_CASES):
        analytic.test_constant_P(case, "magnus6")
        analytic.test_constant_P(case, "magnus4")


def test_both_paths_mathieu(path):
    for q, a, verdict, sign in analytic._mathieu_points()[::3]:
        analytic.test_mathieu_verdicts(q, a, verdict, sign)


def test_compiled_path_is_used(monkeypatch):
    """With USE_COMPILED the small-system solves go through the kernel (and not without)."""
    calls = []
    real = _compiled.magnus_solve

    def spy(*args):
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(_compiled, "magnus_solve", spy)
    monkeypatch.setattr(FQ, "USE_COMPILED", _compiled.AVAILABLE)
    A = np.array([[0.0, 1.0], [-4.0, -0.2]])
    FQ.floquet(lambda t: A + 0.1 * math.cos(t) * np.eye(2), period=2 * math.pi)
    assert bool(calls) == _compiled.AVAILABLE
    calls.clear()
    monkeypatch.setattr(FQ, "USE_COMPILED", False)
    FQ.floquet(lambda t: A + 0.1 * math.cos(t) * np.eye(2), period=2 * math.pi)
    assert not calls
