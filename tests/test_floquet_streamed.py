"""Streamed (chunked, O(n^2)-memory) Magnus propagation against the stored-factor product.

Oracle: the same sub-interval propagators ``E_k`` multiplied in one stored
stack (pairwise reduction).  Both are the product ``E_N ... E_1`` of identical
factors, associated differently, so they may differ only by rounding: a
product of ``N`` real ``n x n`` factors evaluated in any order satisfies
``|fl(Phi) - Phi| <= gamma_m |E_N| ... |E_1|`` elementwise with
``m = (N - 1) n``, ``gamma_m = m u / (1 - m u)``, ``u = eps / 2`` (Higham,
*Accuracy and Stability of Numerical Algorithms*, 2nd ed., Sec. 3.5), so two
evaluations differ by at most ``2 gamma_m`` times the product of the absolute
factors.  The check rejects a product with one pair of factors swapped and one
with a factor left out (the errors a chunk boundary would make).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import importlib
import sys
from pathlib import Path

fq = importlib.import_module("stability.floquet")
from stability import floquet
from stability.expm import expm_stack
from stability.magnus import MAGNUS2, MAGNUS4, magnus_exponents, ordered_product
from stability.periodic import PeriodicMatrixFunction

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the known system of test_implicit_floquet

N_STATES = 20  # > SMALL_N (matrix-major small path) and > expm.SCIPY_N (per-matrix exponentials)


def _system(seed: int = 5):
    """A lightly damped mechanical-like periodic system, 10 DOF (20 states), T = 1."""
    rng = np.random.default_rng(seed)
    f = N_STATES // 2
    K0 = rng.standard_normal((f, f))
    K0 = K0 @ K0.T + f * np.eye(f)
    K1 = 0.3 * rng.standard_normal((f, f))
    C0 = 0.05 * np.eye(f)

    def P(t):
        K = K0 + math.sin(2 * math.pi * t) * (K1 + K1.T)
        return np.block([[np.zeros((f, f)), np.eye(f)], [-K, -C0]])

    return PeriodicMatrixFunction(P, 1.0)


def _factors(wrapped, scheme, N):
    h = 1.0 / N
    times = (np.arange(N)[:, None] + np.asarray(scheme.nodes)[None, :]) * h
    Pg = wrapped.evaluate(times.ravel()).reshape(N, len(scheme.nodes), wrapped.n, wrapped.n)
    return expm_stack(magnus_exponents(scheme, Pg, h))


def _factors_chunk(wrapped, scheme, N, start, stop):
    h = 1.0 / N
    times = (np.arange(start, stop)[:, None] + np.asarray(scheme.nodes)[None, :]) * h
    Pg = wrapped.evaluate(times.ravel()).reshape(stop - start, len(scheme.nodes), wrapped.n, wrapped.n)
    return expm_stack(magnus_exponents(scheme, Pg, h))


def _rounding_bound(E: np.ndarray) -> np.ndarray:
    """``2 gamma_m |E_N| ... |E_1|`` with ``m = (N - 1) n`` (see the module notes)."""
    N, n = E.shape[0], E.shape[-1]
    u = np.finfo(float).eps / 2
    m = (N - 1) * n
    absprod = np.eye(n)
    for Ek in E:
        absprod = np.abs(Ek) @ absprod
    return 2.0 * (m * u / (1.0 - m * u)) * absprod


@pytest.mark.parametrize("scheme, N, chunk", [(MAGNUS2, 37, 5), (MAGNUS2, 64, 64), (MAGNUS4, 40, 7)])
def test_streamed_product_equals_stored_within_rounding(scheme, N, chunk):
    wrapped = _system()
    E = _factors(wrapped, scheme, N)
    # the factors of a chunk are the same numbers as those of the full stack (per-matrix expm)
    np.testing.assert_array_equal(_factors_chunk(wrapped, scheme, N, 3, min(N, 3 + chunk)), E[3:3 + chunk])
    streamed = fq._magnus_solve_streamed(scheme, wrapped, 1.0, N, False, chunk)
    stored = fq._magnus_solve(scheme, wrapped, 1.0, N, keep_factors=True, strict=False)
    np.testing.assert_array_equal(stored.factors, E)
    bound = _rounding_bound(E)
    assert np.all(np.abs(streamed.monodromy - stored.monodromy) <= bound)
    # log det from the traces of the exponents: the same sums, chunked
    assert abs(streamed.log_abs_det - stored.log_abs_det) <= 1e-12 * max(1.0, abs(stored.log_abs_det))


def test_rounding_bound_rejects_a_wrong_product():
    """A swapped pair of factors or a dropped factor (chunk-boundary errors) exceeds the bound."""
    wrapped = _system()
    N = 37
    E = _factors(wrapped, MAGNUS2, N)
    bound = _rounding_bound(E)
    ref = ordered_product(E)
    swapped = E.copy()
    swapped[[10, 11]] = swapped[[11, 10]]
    assert np.any(np.abs(ordered_product(swapped) - ref) > bound)
    dropped = np.delete(E, 5, axis=0)
    assert np.any(np.abs(ordered_product(dropped) - ref) > bound)


def test_floquet_streams_large_systems_with_the_same_result(monkeypatch):
    """``floquet()`` switches to chunks when the work arrays exceed CHUNK_MEMORY; same monodromy."""
    wrapped = _system()
    N = 48
    ref = floquet(wrapped, method="magnus2", n_steps=N, error_estimate=False, balance=False)
    per_step = fq.WORK_ARRAYS * N_STATES**2 * 8.0
    monkeypatch.setattr(fq, "CHUNK_MEMORY", 6.5 * per_step)  # chunks of 6 sub-intervals
    assert fq._stream_chunk(MAGNUS2, N_STATES) == 6
    calls = []
    real = fq._magnus_solve_streamed
    monkeypatch.setattr(fq, "_magnus_solve_streamed", lambda *a: calls.append(a[5]) or real(*a))
    res = floquet(wrapped, method="magnus2", n_steps=N, error_estimate=False, balance=False)
    assert calls == [6]
    assert np.all(np.abs(res.monodromy - ref.monodromy) <= _rounding_bound(_factors(wrapped, MAGNUS2, N)))
    assert res.liouville_residual <= 1e-10


# --------------------------------------------------------------------------- the N/3 companion solve
def _known_system():
    """32 states with known multipliers exp(lambda_i T) (a periodic Lyapunov transform of a constant system)."""
    from test_implicit_floquet import _block_system

    P, exact = _block_system(16, 1.0, seed=3)
    return PeriodicMatrixFunction(P, 1.0), exact


def _multiplier_error(values, exact) -> float:
    return max(float(np.min(np.abs(exact - z)) / abs(z)) for z in values)


#: magnus2 is symmetric: its global error is C h^2 (1 + O(h^2)), so the N/3 solve's error is
#: 9 times the N solve's up to the O(h^2) correction; 20 % covers it at h = 1/96, ||P|| ~ 7
#: (measured correction 0.4 %), and a first-order rule (ratio 3) is far outside.
RATIO_TOLERANCE = 0.2

from stability.floquet import ESTIMATE_SAFETY  # noqa: E402


def test_third_companion_is_the_n_over_3_solve():
    wrapped, exact = _known_system()
    N = 96
    fine = fq._magnus_solve(MAGNUS2, wrapped, 1.0, N, False, False, 1)
    direct = fq._magnus_solve(MAGNUS2, wrapped, 1.0, N // 3, True, False)
    assert fine.third is not None and fine.third.n_steps == N // 3
    # the cubes expm(h P)^3 are expm(3 h P) to rounding: N/3 factors, each within ~3 n eps of
    # its direct exponential (||3 h P|| < 1: no squaring), products as in the bound above
    absprod = np.eye(wrapped.n)
    for Ek in direct.factors:
        absprod = np.abs(Ek) @ absprod
    tol = (N // 3) * 3 * wrapped.n * np.finfo(float).eps * absprod + _rounding_bound(direct.factors)
    assert np.all(np.abs(fine.third.monodromy - direct.monodromy) <= tol)
    e_fine = _multiplier_error(fine.spectrum.values, exact)
    e_third = _multiplier_error(fine.third.spectrum.values, exact)
    assert abs(e_third / e_fine - 9.0) <= 9.0 * RATIO_TOLERANCE


def test_third_companion_ratio_rejects_misaligned_chunks():
    """Triples cut by chunk boundaries (chunks of 5: middles 1, 4 of each chunk) are caught by the ratio test.

    (A grid shifted by whole fine steps is *not* an error: for a periodic ``P`` it gives the
    monodromy at another base point, the same multipliers to O(h^2).)
    """
    wrapped, exact = _known_system()
    N = 96
    E = _factors(wrapped, MAGNUS2, N)
    mids = np.concatenate([E[start:start + 5][1::3] for start in range(0, N, 5)])
    wrong = ordered_product(mids @ mids @ mids)
    e_fine = _multiplier_error(np.linalg.eigvals(ordered_product(E)), exact)
    e_wrong = _multiplier_error(np.linalg.eigvals(wrong), exact)
    assert abs(e_wrong / e_fine - 9.0) > 9.0 * RATIO_TOLERANCE


def test_floquet_fixed_steps_uses_the_companion_and_its_estimate_is_the_error():
    wrapped, exact = _known_system()
    N = 96
    res = floquet(wrapped, method="magnus2", n_steps=N, accuracy="multipliers")
    assert res.n_evaluations == N  # one solve: no N/2 solve was run
    true = _multiplier_error(res.multipliers, exact)
    # Richardson with ratio 3 over the levels N/9, N/3, N, times the safety factor: the estimate
    # covers the error and exceeds it by at most that factor (within the O(h^2) correction)
    assert 1.0 <= res.error_estimate / true <= ESTIMATE_SAFETY * (1.0 + RATIO_TOLERANCE)
    # the old, unguarded Richardson value (change / (3^2 - 1)) is the error to within the O(h^2)
    # correction, i.e. it under-reads it about half of the time: the factor is what makes a bound
    assert res.error_estimate / ESTIMATE_SAFETY < true * (1.0 + RATIO_TOLERANCE)
    # N not a multiple of 3: the N/4 and N/2 solves (three levels: the order is observed)
    res2 = floquet(wrapped, method="magnus2", n_steps=64, accuracy="multipliers")
    assert res2.n_evaluations == 64 + 32 + 16
    assert 1.0 <= res2.error_estimate / _multiplier_error(res2.multipliers, exact) \
        <= ESTIMATE_SAFETY * (1.0 + RATIO_TOLERANCE)


def test_streamed_companion_equals_stored_companion():
    """Chunks of 5 are cut to whole triples (3): the streamed N/3 product equals the stored one."""
    wrapped, _ = _known_system()
    N = 48
    streamed = fq._magnus_solve_streamed(MAGNUS2, wrapped, 1.0, N, False, 5, 1)
    stored = fq._magnus_solve(MAGNUS2, wrapped, 1.0, N, False, False, 1)
    E = _factors(wrapped, MAGNUS2, N)[1::3]
    assert np.all(np.abs(streamed.third.monodromy - stored.third.monodromy) <= _rounding_bound(E @ E @ E))
    assert np.all(np.abs(streamed.monodromy - stored.monodromy) <= _rounding_bound(_factors(wrapped, MAGNUS2, N)))


# --------------------------------------------------------------------------- the nested trace rule
class _Counting:
    """``P(t) = diag(f(t), 0)`` counting its evaluation times."""

    def __init__(self, f):
        self.f, self.times, self.period = f, 0, 1.0

    def evaluate(self, t):
        t = np.atleast_1d(t)
        self.times += t.size
        P = np.zeros((t.size, 2, 2))
        P[:, 0, 0] = self.f(t)
        return P

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]


def test_trace_rule_stops_when_converged():
    """Smooth integrand: int_0^1 exp(sin 2 pi t) dt = I0(1); the nested rule stops at 64 points,
    within TRACE_RTOL of the integral of |tr P| (= the integral here)."""
    from scipy.special import i0

    P = _Counting(lambda t: np.exp(np.sin(2 * np.pi * t)))
    value = fq._trace_integral(P, PeriodicMatrixFunction(P, 1.0), 1.0)
    assert abs(value - i0(1.0)) <= fq.TRACE_RTOL * i0(1.0)
    assert P.times - 1 <= fq.TRACE_MIN_POINTS  # (one evaluation at t = 0 checks P's shape)


def test_trace_rule_refines_a_kinked_integrand():
    """|sin pi t| has a kink: the trapezoidal error falls only like K^-2, successive sums never agree
    to 1e-13, so the rule refines to its limit of TRACE_POINTS (no early stop on a wrong value)."""
    P = _Counting(lambda t: np.abs(np.sin(np.pi * t)))
    value = fq._trace_integral(P, PeriodicMatrixFunction(P, 1.0), 1.0)
    assert P.times - 1 == fq.TRACE_POINTS
    # Euler-Maclaurin: the K-point error is h^2 / 12 times the jump 2 pi of the derivative at the kink,
    # pi / (6 K^2) absolute; a factor 2 for the higher terms
    assert abs(value - 2 / np.pi) <= 2.0 * np.pi / (6 * fq.TRACE_POINTS**2)


# --------------------------------------------------------------------------- ratio-3 Richardson extrapolation
def test_companions_give_fourth_order_extrapolation():
    """(9 Phi_N - Phi_{N/3}) / 8 cancels the h^2 term of the symmetric midpoint rule: its error is
    O(h^4), far below the N-step error; the wrong weights of ratio 2, (4 Phi_N - Phi_{N/3}) / 3,
    do not cancel it (rejected)."""
    wrapped, exact = _known_system()
    N = 144
    res = floquet(wrapped, method="magnus2", n_steps=N, balance=False)
    assert res.companion_steps == (48, 16) and res.n_evaluations == N
    e_fine = _multiplier_error(res.multipliers, exact)
    mid = res.companion_monodromies[0]
    good = (9.0 * res.monodromy - mid) / 8.0
    wrong = (4.0 * res.monodromy - mid) / 3.0
    e_good = _multiplier_error(np.linalg.eigvals(good), exact)
    e_wrong = _multiplier_error(np.linalg.eigvals(wrong), exact)
    # e_fine = C h^2 ~ 1.4e-5 at h = 1/144 (measured at 96: 3.5e-5); the h^4 term with ratio 3 is
    # 9 C4 h^4: with C4 ~ C ||P||^2 / 10 this is ~1e-3 of e_fine; 1e-2 leaves room
    assert e_good <= 1e-2 * e_fine
    # ratio-2 weights leave (4 - 9) / 3 C h^2 = -5/3 e_fine of the h^2 term
    assert e_wrong >= 0.5 * e_fine


@pytest.mark.slow
def test_modal_floquet_ratio_three_uses_one_set_of_exponentials():
    """modal_floquet(extrapolate=True) with N divisible by 9 extrapolates from the companions of the
    N-step solve (no N/2, N/4 solves), and its undivided estimate bounds the true error."""
    from stability.modal import modal_floquet

    wrapped, exact = _known_system()
    res = modal_floquet(wrapped, method="magnus2", n_steps=72, accuracy="multipliers", extrapolate=True)
    assert res.n_evaluations == 72
    true = _multiplier_error(res.multipliers, exact)
    assert true <= res.error_estimate
