"""``stability.expm.expm_near_block_diagonal`` and its use in the Magnus factors.

Oracle: matrices ``A = Q D Q^-1`` built from a block-diagonal ``D`` of 2x2 rotation-damping
blocks ``[[a, b], [-b, a]]`` (exponential ``e^a [[cos b, sin b], [-sin b, cos b]]`` in closed
form), 1x1 blocks and 2x2 blocks with two real eigenvalues, and ``Q = I + K`` with a small
coupling ``K``: ``expm(A) = Q expm(D) Q^-1`` independently of the code under test.  The
tolerance: forming ``A`` in floating point perturbs it by ``dA <= 2 n u ||Q|| ||D|| ||Q^-1||``,
which moves ``expm`` by ``<= ||dA|| cond(Q)^2 M^2`` (``M = max_s ||expm(D s)|| = 1`` here: the
blocks are damped rotations), plus the method's own ``error_bound`` (derived in its docstring).
"""
from __future__ import annotations

import logging

import numpy as np
import pytest
import scipy.linalg

from stability.expm import expm_near_block_diagonal

U = np.finfo(float).eps / 2.0


def _n1(X: np.ndarray) -> float:
    return float(np.abs(X).sum(axis=0).max())


def _case(rng, n_rot: int, n_real2: int, n_one: int, spread: float, coupling: float, close: float = 0.0):
    """``(A, blocks, expm(A) exact, tol of the reference)``; ``close > 0``: the rotation frequencies come in
    pairs ``b, b (1 + close)`` (close clusters)."""
    blocks, mats, exps = [], [], []
    freqs = np.sort(rng.uniform(1.0, spread, n_rot))
    if close:
        freqs[1::2] = freqs[0::2] * (1.0 + close)
    for b in freqs:
        a = -rng.uniform(0.0, 0.05) * b
        mats.append(np.array([[a, b], [-b, a]]))
        exps.append(np.exp(a) * np.array([[np.cos(b), np.sin(b)], [-np.sin(b), np.cos(b)]]))
        blocks.append(2)
    for _ in range(n_real2):  # overdamped: two real eigenvalues, non-normal block
        l1, l2 = -rng.uniform(1.0, 50.0, 2)
        S = np.array([[1.0, 0.3], [0.2, 1.0]])
        mats.append(S @ np.diag([l1, l2]) @ np.linalg.inv(S))
        exps.append(S @ np.diag(np.exp([l1, l2])) @ np.linalg.inv(S))
        blocks.append(2)
    for _ in range(n_one):
        lam = -rng.uniform(0.0, 30.0)
        mats.append(np.array([[lam]]))
        exps.append(np.array([[np.exp(lam)]]))
        blocks.append(1)
    order = rng.permutation(len(blocks))  # mixed block sizes along the diagonal
    D = scipy.linalg.block_diag(*[mats[i] for i in order])
    eD = scipy.linalg.block_diag(*[exps[i] for i in order])
    blocks = [blocks[i] for i in order]
    n = D.shape[0]
    Q = np.eye(n) + coupling * rng.standard_normal((n, n))
    Qi = np.linalg.inv(Q)
    A = Q @ D @ Qi
    exact = Q @ eD @ Qi
    kq = _n1(Q) * _n1(Qi)
    m = max(1.0, max(_n1(e) for e in exps))  # the real 2x2 blocks are not normal
    ref_tol = 2 * n * U * kq * _n1(D) * kq**2 * m**2 + 2 * n * U * kq * m
    return A, blocks, exact, ref_tol


@pytest.mark.parametrize("spread, coupling, close", [(1e5, 1e-7, 0.0), (5e4, 1e-8, 0.0), (1e3, 1e-6, 1e-3)])
def test_equals_the_exact_exponential_within_its_bound(spread, coupling, close):
    rng = np.random.default_rng(7)
    A, blocks, exact, ref_tol = _case(rng, 40, 3, 5, spread, coupling, close)
    res = expm_near_block_diagonal(A, blocks)
    assert res.ok, res.reason
    assert res.residual <= 1e-15 and res.condition < 1.1
    err = _n1(res.matrix - exact)
    assert err <= res.error_bound + ref_tol, (err, res.error_bound, ref_tol)
    # scipy's expm, backward stable at ~ n u ||A|| (the same first-order argument): the two agree
    assert _n1(res.matrix - scipy.linalg.expm(A)) <= 2 * res.error_bound + ref_tol
    # the check can fail: the exponential of the unrefined block diagonal (Z = I) is off by ~ the coupling
    lone = expm_near_block_diagonal(A, blocks, max_sweeps=1)
    assert not lone.ok and "not converged" in lone.reason


def test_a_wrong_inverse_is_rejected(monkeypatch):
    """The variant ``Z expm(D') Z^T`` (``Z^-1`` replaced by ``Z^T``) misses the oracle by ~ the coupling."""
    rng = np.random.default_rng(3)
    A, blocks, exact, ref_tol = _case(rng, 30, 2, 4, 1e4, 1e-5)
    good = expm_near_block_diagonal(A, blocks)
    assert _n1(good.matrix - exact) <= good.error_bound + ref_tol
    captured = {}
    real_factor = scipy.linalg.lu_factor

    def factor(Z, **kw):
        captured["Z"] = Z.copy()
        return real_factor(Z, **kw)

    def wrong_solve(lu_piv, b, trans=0, **kw):  # E^T = Z^-T M^T  ->  E = M Z^T
        return captured["Z"] @ b

    monkeypatch.setattr(scipy.linalg, "lu_factor", factor)
    monkeypatch.setattr(scipy.linalg, "lu_solve", wrong_solve)
    bad = expm_near_block_diagonal(A, blocks)
    assert _n1(bad.matrix - exact) > 100 * (bad.error_bound + ref_tol)


def test_refuses_nearly_defective_close_or_strongly_coupled_blocks():
    rng = np.random.default_rng(5)
    A, blocks, _, _ = _case(rng, 10, 0, 2, 1e3, 1e-6)
    # a nearly defective (Jordan-like) 2x2 block
    J = A.copy()
    J[0:2, 0:2] = [[-1.0, 1.0], [-1e-14, -1.0]]
    J[2:, :2] = J[:2, 2:] = 1e-9
    bs = [2] + [1] * (A.shape[0] - 2)
    res = expm_near_block_diagonal(J, bs)
    assert not res.ok and "defective" in res.reason
    # two clusters with one eigenvalue, coupled
    S = scipy.linalg.block_diag([[0.0, 5.0], [-5.0, 0.0]], [[0.0, 5.0], [-5.0, 0.0]], [[-1.0]])
    S[0, 2] = 1e-3
    res = expm_near_block_diagonal(S, [2, 2, 1])
    assert not res.ok and "share an eigenvalue" in res.reason
    # clusters too close for their coupling (gap 1e-3, coupling 1e-2): the correction is large
    S = scipy.linalg.block_diag([[0.0, 5.0], [-5.0, 0.0]], [[0.0, 5.001], [-5.001, 0.0]])
    S[0, 2] = S[2, 0] = 1e-2
    res = expm_near_block_diagonal(S, [2, 2])
    assert not res.ok and "coupling too strong" in res.reason
    # blocks larger than 2x2 are not handled
    assert "size 3" in expm_near_block_diagonal(np.eye(4), [3, 1]).reason
    with pytest.raises(ValueError, match="summing to n"):
        expm_near_block_diagonal(np.eye(4), [2, 1])


def test_floquet_falls_back_per_factor_and_says_so(caplog, monkeypatch):
    """Blocks the method does not handle (a 3x3 block): every factor falls back to scipy, the
    count is logged, and the multipliers are those of the default path (the same factors)."""
    import importlib

    from stability import floquet

    monkeypatch.setattr(importlib.import_module("stability.floquet"), "BLOCK_EXPM_MIN_N", 0)

    n = 20
    rng = np.random.default_rng(11)
    B = np.diag(-np.linspace(1.0, 20.0, n))
    C = 1e-4 * rng.standard_normal((n, n))

    def P(t):
        return B + np.cos(2 * np.pi * t) * C

    ref = floquet(P, period=1.0, method="magnus2", n_steps=40, error_estimate=False)
    with caplog.at_level(logging.INFO, logger="stability.floquet"):
        res = floquet(P, period=1.0, method="magnus2", n_steps=40, error_estimate=False,
                      expm_blocks=[3] + [1] * (n - 3))
    msgs = [r.getMessage() for r in caplog.records if "fell back" in r.getMessage()]
    assert msgs and msgs[0].startswith("floquet(magnus2): 40 of 40 factors fell back"), msgs
    assert np.abs(res.multipliers - ref.multipliers).max() <= 1e-15
    # the same system over 1x1 blocks (well separated diagonal, small coupling): no fallback, and
    # the multipliers agree with the scipy path within both methods' rounding (n u ||h P|| per factor)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="stability.floquet"):
        ok = floquet(P, period=1.0, method="magnus2", n_steps=40, error_estimate=False, expm_blocks=[1] * n)
    assert not [r for r in caplog.records if "fell back" in r.getMessage()]
    assert np.abs(ok.multipliers - ref.multipliers).max() <= 40 * 2 * n * U * 2.0
    with pytest.raises(ValueError, match="expm_blocks"):
        floquet(P, period=1.0, method="magnus2", n_steps=40, expm_blocks=[2, 2])


def _matched(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance from a multiplier of ``a`` to the nearest of ``b`` (and back)."""
    d = np.abs(a[:, None] - b[None, :])
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


@pytest.mark.slow
@pytest.mark.parametrize("elements", [8, 16])
def test_single_link_multipliers_agree_with_an_independent_exponential(monkeypatch, elements):
    """8 and 16 elements, frozen-modal frame, 144 extrapolated magnus2 steps (as ``linearize.analysis``):
    the multipliers with block-diagonalised factors agree within their Richardson estimate with
    those of an independent exponential, LAPACK's ``eig`` (``V exp(Lambda) V^-1``, ``cond(V) ~ 2``
    here), and at 8 elements with ``scipy.linalg.expm``'s; the wrong variant ``Z^T`` moves them
    beyond it.  (At 16 elements, ``||h P||_1 = 4e3``, scipy's factors put the multipliers 7.5e-9
    from both the block and the eig ones, ten times the estimate: the rounding of its 10
    squarings, which no step-count estimate sees; measured, not asserted.)"""
    import importlib
    import math

    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from stability.modal import modal_floquet, modal_system

    fl = importlib.import_module("stability.floquet")
    monkeypatch.setattr(fl, "BLOCK_EXPM_MIN_N", 0)  # 68 / 132 states: below the size where it pays
    orbit = find_orbit("single-link", 2.0 * math.pi, samples=16, elements=elements)
    lin = linearize_orbit(orbit, 37.1617, 29.2410)
    system = modal_system(lin)

    def run(**kw):
        return modal_floquet(lin, basis=system, method="magnus2", n_steps=144, extrapolate=True, **kw)

    block = run()
    est = block.error_estimate
    assert 0 < est < 1e-8
    if elements == 8:
        assert _matched(block.multipliers, run(expm_blocks=None).multipliers) <= est

    def eig_factors(Om, wrapped):
        lam, V = np.linalg.eig(Om)
        return np.real((V * np.exp(lam)[:, None, :]) @ np.linalg.inv(V))

    with monkeypatch.context() as m:
        m.setattr(fl, "_factors", eig_factors)
        assert _matched(block.multipliers, run(expm_blocks=None).multipliers) <= est
    captured = {}
    real_factor = scipy.linalg.lu_factor

    def factor(Z, **kw):
        captured["Z"] = Z.copy()
        return real_factor(Z, **kw)

    monkeypatch.setattr(scipy.linalg, "lu_factor", factor)
    monkeypatch.setattr(scipy.linalg, "lu_solve", lambda lu_piv, b, trans=0, **kw: captured["Z"] @ b)
    assert _matched(block.multipliers, run().multipliers) > est
