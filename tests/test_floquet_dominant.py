"""``accuracy="dominant"``: the error estimate covers the spectral radius and the multipliers that could be it.

Oracle, independent of ``stability``: ``P(t) = L' L^-1 + L A L^-1`` for ``x = L(t) z``, ``z' = A z``, with
``A`` block diagonal and ``L(t) = expm(S sin w t) D(t)`` (``S`` skew, coupling the blocks; ``D`` the
positive diagonal ``1 + 0.3 sin(w t + phi)``, ``w = 2 pi / T``): ``L`` is ``T``-periodic, so the
monodromy matrix is ``L(0) expm(A T) L(0)^-1`` and the multipliers are ``exp(lambda T)`` of ``A``'s
eigenvalues in closed form.  ``L`` couples the blocks, so no pair's modulus is fixed by a
determinant that the midpoint rule integrates spectrally (a decoupled 2x2 block's would be).  Each block is a slow pair (``|Im lambda| = 1``) or a stiff one
(``|Im lambda| = 80``: its midpoint error at a few dozen steps is large).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from stability import FloquetError, floquet
from stability.floquet import DOMINANT_BAND, DOMINANT_SAFETY, dominant_mask

T = 1.0


def _block(re, im, aniso):
    """Real 2x2 with eigenvalues ``re +- i im``, non-normal (``aniso != 1``)."""
    return np.array([[re, im * aniso], [-im / aniso, re]])


class _Blocks:
    """``P(t)`` of the module notes for 2x2 blocks ``A_j``, ``L(t) = Q(t) D(t)``."""

    period = T

    def __init__(self, blocks, seed=3, turn=0.4):
        self.blocks = blocks
        self.n = n = 2 * len(blocks)
        self.A = np.zeros((n, n))
        for j, A in enumerate(blocks):
            self.A[2 * j:2 * j + 2, 2 * j:2 * j + 2] = A
        self.w = 2 * math.pi / T
        self.phases = np.arange(n, dtype=float)
        # skew, coupling the blocks after the first (Q = expm(S sin wt) is orthogonal); the first
        # block stays decoupled, so its pair's modulus is fixed by its determinant (exact to rounding)
        S = np.zeros((n, n))
        S[2:, 2:] = np.random.default_rng(seed).standard_normal((n - 2, n - 2))
        self.S = turn * (S - S.T) / np.linalg.norm(S - S.T, 2)

    def L_and_dL(self, t):
        """``L = Q D`` with ``Q = expm(S sin w t)`` (couples the blocks) and ``D`` the positive diagonal."""
        from scipy.linalg import expm

        Q = expm(self.S * math.sin(self.w * t))
        d = 1.0 + 0.3 * np.sin(self.w * t + self.phases)
        dd = 0.3 * self.w * np.cos(self.w * t + self.phases)
        return Q * d, (self.w * math.cos(self.w * t) * self.S @ Q) * d + Q * dd

    def __call__(self, t):
        L, dL = self.L_and_dL(t)
        Linv = np.linalg.inv(L)
        return dL @ Linv + L @ self.A @ Linv

    def exact_moduli(self):
        """Sorted (descending) exact moduli ``exp(Re lambda T)``, each pair twice."""
        m = [math.exp(float(np.linalg.eigvals(A)[0].real) * T) for A in self.blocks]
        return np.sort(np.repeat(m, 2))[::-1]


#: A slow decoupled pair, dominant (modulus e^-0.05 = 0.951), and two coupled stiff pairs inside
#: (e^-0.7 = 0.497, e^-0.9 = 0.407) whose moduli the midpoint rule gets wrong at a few dozen steps.
STIFF_INSIDE = _Blocks([_block(-0.05, 1.0, 1.5), _block(-0.7, 80.0, 2.0), _block(-0.9, 50.0, 0.7)])
#: The first stiff pair is the dominant one (e^-0.02 = 0.980), the slow one inside (e^-0.5 = 0.607).
STIFF_DOMINANT = _Blocks([_block(-0.5, 1.0, 1.5), _block(-0.02, 80.0, 2.0), _block(-0.9, 50.0, 0.7)])


def _errors(res, system):
    """Relative error of every sorted modulus against the closed form."""
    exact = system.exact_moduli()
    got = np.sort(np.abs(res.multipliers))[::-1]
    return np.abs(got - exact) / exact


def test_dominant_estimate_bounds_the_spectral_radius_error_and_ignores_an_inaccurate_inner_pair():
    # magnus2 with N = 64, N / 2 = 32 for the Richardson pair (ratio 2, the 2nd-order midpoint rule)
    N, rtol = 64, 1e-4
    dom = floquet(STIFF_INSIDE, period=T, method="magnus2", n_steps=N, accuracy="dominant")
    mod = floquet(STIFF_INSIDE, period=T, method="magnus2", n_steps=N, accuracy="moduli")
    err = _errors(dom, STIFF_INSIDE)
    assert dom.accuracy == "dominant"
    # the two runs are the same solves: only what the estimate covers differs
    np.testing.assert_array_equal(dom.multipliers, mod.multipliers)
    # the estimate bounds the spectral radius' discretisation error; rounding adds <= N products
    # of ~noise_floor each (as in test_floquet_analytic): the slow pair here is exact to rounding
    assert err[0] <= dom.error_estimate + N * dom.noise_floor / dom.spectral_radius
    # the inner stiff pairs are inaccurate: "moduli" sees it, "dominant" passes rtol
    assert err[2] > rtol and mod.error_estimate > rtol
    assert dom.error_estimate <= rtol < mod.error_estimate
    # and the moduli estimate bounds that pair's error (the check is not vacuous)
    assert err.max() <= mod.error_estimate


def test_dominant_estimate_rejects_an_inaccurate_dominant_pair():
    N, rtol = 64, 1e-4
    res = floquet(STIFF_DOMINANT, period=T, method="magnus2", n_steps=N, accuracy="dominant")
    err = _errors(res, STIFF_DOMINANT)
    assert err[0] > rtol  # the stiff dominant pair is wrong at 64 steps
    assert res.error_estimate >= err[0] > rtol  # and the dominant estimate says so


def test_adaptive_dominant_refines_only_for_the_dominant_pair():
    rtol = 1e-6
    inside = floquet(STIFF_INSIDE, period=T, method="magnus4", accuracy="dominant", rtol=rtol)
    inside_all = floquet(STIFF_INSIDE, period=T, method="magnus4", accuracy="moduli", rtol=rtol)
    dominant = floquet(STIFF_DOMINANT, period=T, method="magnus4", accuracy="dominant", rtol=rtol)
    # the adaptive loop stops at estimate <= rtol; the true error of rho is within 10x the estimate
    # (the Richardson estimate of a p-th order method in its asymptotic range, as in
    # test_floquet_analytic) - i.e. <= 1e-5 - plus the rounding of the product of n_steps factors
    # (each exact to ~eps, relative errors add: <= 10 n_steps eps; an estimate that converged to
    # ~eps can be below the rounding it cannot see: measured 7e-16 error for a 4.7e-17 estimate on
    # one BLAS build)
    eps = np.finfo(float).eps
    for res, system in ((inside, STIFF_INSIDE), (dominant, STIFF_DOMINANT)):
        assert res.error_estimate <= rtol
        assert _errors(res, system)[0] <= 10 * res.error_estimate + 10 * res.n_steps * eps
    # the stiff inner pair costs the "moduli" run steps the "dominant" one does not spend ...
    assert inside.n_steps < inside_all.n_steps
    # ... while a stiff dominant pair is refined (more steps than the slow-dominant case)
    assert dominant.n_steps > inside.n_steps


def test_adaptive_dominant_refuses_at_the_step_limit():
    # the modal path raises at max_steps; the plain adaptive loop warns that rtol was not reached
    with pytest.warns(RuntimeWarning, match="error estimate"):
        res = floquet(STIFF_DOMINANT, period=T, method="magnus2", accuracy="dominant", rtol=1e-9, max_steps=64)
    assert res.error_estimate > 1e-9


def test_dominant_mask_covers_whatever_could_be_the_spectral_radius():
    logm = np.log(np.array([1.0, 1.0 - 0.5 * DOMINANT_BAND, 0.99999, 0.99999, 0.9, 0.5]))
    e = np.array([1e-12, 1e-12, 1e-5, 1e-9, 1e-6, 0.9])
    mask = dominant_mask(logm, e)
    # 0: rho; 1: in the band; 2: 0.99999 (1 + 10 * 1e-5) > 1; 5: 0.5 * (1 + 9) > 1
    # 3: 0.99999 (1 + 1e-8) < 1 - 1e-11; 4: 0.9 (1 + 1e-5) < 1
    np.testing.assert_array_equal(mask, [True, True, True, False, False, True])
    # a band-only rule would leave 2 and 5 out: an estimate over it (1e-12) would miss that a
    # multiplier with a 1e-5 (or 0.9) error could be the spectral radius
    assert DOMINANT_SAFETY * e[2] > 1e-5
    # rho's own uncertainty widens the set: with e_0 = 1e-3 the 0.9995 ... entries reach it
    assert dominant_mask(np.log(np.array([1.0, 0.9995])), np.array([1e-3, 1e-12])).all()
    # a non-finite estimate is always covered
    assert dominant_mask(np.log(np.array([1.0, 0.1])), np.array([0.0, np.inf])).all()


def test_bad_accuracy_is_one_clear_error():
    with pytest.raises(ValueError, match="accuracy must be one of"):
        floquet(STIFF_INSIDE, period=T, accuracy="spectral")


def test_modal_adaptive_dominant_raises_when_the_estimate_cannot_reach_rtol():
    from test_modal_clusters import CLOSE
    from stability.modal import modal_floquet

    # rtol below what any solve can certify (rounding ~1e-16 n): the adaptive extrapolated solve
    # refines from 72 steps and must refuse at max_steps instead of returning an uncertified value
    with pytest.raises(FloquetError, match="estimate"):
        modal_floquet(CLOSE, method="magnus2", extrapolate=True, n_steps=None, accuracy="dominant",
                      rtol=1e-20, max_steps=150)


class _Aliased:
    """``P(t) = A0 + c cos(2 pi 144 t) I`` (``T = 1``): the identity term commutes with ``A0`` and
    integrates to 0 over the period, so the multipliers are ``exp(-0.1 +- 5 i)`` in closed form.

    Every midpoint grid of 72 steps' nested family (72, 36, 18, 9, and 24, 8) samples the 144th
    harmonic at ``cos(2 pi k') = 1``: all of them integrate ``A0 + c I``, agree with each other and are
    all wrong by the factor ``e^c`` - an error no nested Richardson estimate can see.  The check's
    88 steps (and 44, 22, 11) sum the harmonic to 0 (144 / 88 is not an integer).
    """

    period = 1.0
    A0 = np.array([[-0.1, 5.0], [-5.0, -0.1]])

    def __init__(self, c=0.5, k=144):
        self.c, self.k = c, k

    def evaluate(self, times):
        t = np.atleast_1d(times)
        return self.A0[None] + (self.c * np.cos(2 * math.pi * self.k * t))[:, None, None] * np.eye(2)[None]

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]


def test_non_nested_check_sees_an_error_the_nested_family_shares():
    from stability.modal import modal_floquet

    P, exact = _Aliased(), math.exp(-0.1)
    plain = modal_floquet(P, method="magnus2", n_steps=72, extrapolate=True, accuracy="dominant")
    checked = modal_floquet(P, method="magnus2", n_steps=72, extrapolate=True, accuracy="dominant", check=True)
    err = abs(checked.spectral_radius - exact) / exact
    assert err == pytest.approx(math.expm1(P.c), rel=1e-6)  # the aliased answer e^c off (independent of N)
    assert plain.error_estimate < 1e-10 < err  # the nested estimate misses it
    # the checked one bounds it (rounding: the estimate is a difference of two moduli, ~ n eps)
    assert err <= checked.error_estimate + 1e-14
    assert checked.n_evaluations > plain.n_evaluations  # the 88-step solve is counted
    # the true system is stable (0.905): unchecked, the aliased 1.49 is called unstable; the checked
    # verdict band covers the error, so it can only say critical
    assert plain.verdict == "unstable"
    assert checked.verdict == "critical"


@pytest.mark.parametrize("N", [27, 54, 72, 144, 216, 288, 432])
def test_check_steps_leave_the_nested_family(N):
    from stability.modal import _check_steps

    for by_nine, div in ((True, 9), (False, 8)):
        M = _check_steps(N, by_nine)
        assert M % div == 0  # the extrapolation path of that system size applies to M
        assert 9 * N / 8 <= M < 9 * N / 8 + div
        # M is neither a multiple nor a divisor of N (not on the grid family N, N / 2, N / 3, ...)
        assert M % N != 0 and N % M != 0 and M != N
