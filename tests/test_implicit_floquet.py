"""Implicit (matrix-free, Arnoldi) Floquet multipliers against known multipliers and the dense engine.

Oracles: a block system whose multipliers are known in closed form (a periodic
Lyapunov transform ``x = L(t) z`` of a constant block-diagonal system:
multipliers ``exp(lambda_i T)``), and the dense monodromy of
:func:`stability.floquet` on a random stable periodic system (a different
algorithm on the same propagators: products and a dense eigensolver).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from stability import floquet
from stability.implicit import RESIDUAL_TOL, implicit_floquet, propagators
from stability.magnus import MAGNUS6
from stability.periodic import PeriodicMatrixFunction


def _block_system(n_blocks: int, T: float, seed: int):
    """P = L' L^-1 + L A L^-1 with block-diagonal A (2x2 blocks a_j +- i w_j) and periodic L."""
    rng = np.random.default_rng(seed)
    a = -np.linspace(0.05, 3.0, n_blocks)          # distinct decay rates: distinct moduli
    w = rng.uniform(1.0, 6.0, n_blocks)
    n = 2 * n_blocks
    A = np.zeros((n, n))
    for j in range(n_blocks):
        A[2 * j:2 * j + 2, 2 * j:2 * j + 2] = [[a[j], w[j]], [-w[j], a[j]]]
    B = rng.standard_normal((n, n)) * (0.3 / math.sqrt(n))
    om = 2 * math.pi / T

    def P(t):
        L = np.eye(n) + math.sin(om * t) * B
        Ld = om * math.cos(om * t) * B
        Li = np.linalg.inv(L)
        return Ld @ Li + L @ A @ Li

    exact = np.exp((a[:, None] + 1j * np.array([1, -1])[None, :] * w[:, None]) * T).ravel()
    exact = exact[np.lexsort((-exact.imag, -np.abs(exact)))]
    return P, exact


def _match_error(got, ref):
    """Largest relative distance from each computed multiplier to the nearest reference one."""
    return max(float(np.min(np.abs(ref - z)) / abs(z)) for z in got)


def test_block_system_known_multipliers():
    T = 1.0
    P, exact = _block_system(16, T, seed=3)  # n = 32
    res = implicit_floquet(P, period=T, k=6, n_steps=128, method="magnus6")
    assert np.all(res.certified) and np.all(res.residuals <= RESIDUAL_TOL)
    # the six of largest modulus, to the discretisation accuracy (magnus6, h = 1/128,
    # ||P|| ~ 7: ~1e-11) -- well inside 1e-8
    np.testing.assert_allclose(np.sort(res.moduli)[::-1], np.abs(exact[:6]), rtol=1e-8)
    assert _match_error(res.multipliers, exact[:6]) <= 1e-8
    assert res.error_estimate <= 1e-8


def test_random_stable_periodic_system_agrees_with_dense():
    rng = np.random.default_rng(11)
    n = 24
    A = rng.standard_normal((n, n)) / math.sqrt(n) - 1.2 * np.eye(n)
    B = rng.standard_normal((n, n)) / math.sqrt(n)

    def P(t):
        return A + 2.0 * math.sin(2 * math.pi * t) * B + 0.5 * math.cos(4 * math.pi * t) * B.T

    dense = floquet(P, period=1.0)  # default adaptive magnus6, certified moduli <= 1e-9
    assert dense.spectral_radius < 1.0  # a stable system
    res = implicit_floquet(P, period=1.0, k=5, n_steps=256, method="magnus6")
    assert np.all(res.certified)
    # both ~1e-10 accurate: agreement to 1e-8 on every multiplier found
    assert _match_error(res.multipliers, dense.multipliers) <= 1e-8
    np.testing.assert_allclose(res.moduli, dense.moduli[:5], rtol=1e-8)


def test_residual_check_rejects_a_wrong_multiplier():
    """The certificate: rho + 1e-6 with the right vector has a residual far above the tolerance."""
    P, exact = _block_system(6, 1.0, seed=1)
    wrapped = PeriodicMatrixFunction(P, 1.0)
    E = propagators(wrapped, 1.0, 64, MAGNUS6)
    Phi = np.eye(12)
    for Ek in E:
        Phi = Ek @ Phi
    vals, vecs = np.linalg.eig(Phi)
    i = int(np.argmax(np.abs(vals)))
    v, rho = vecs[:, i], vals[i]

    def residual(r):
        x = v.copy()
        for Ek in E:
            x = Ek @ x
        return np.linalg.norm(x - r * v) / (abs(r) * np.linalg.norm(v))

    assert residual(rho) <= RESIDUAL_TOL
    assert residual(rho * (1 + 1e-6)) > 1e3 * RESIDUAL_TOL


@pytest.mark.parametrize("kwargs, pattern", [({"k": 0}, "k must"), ({"k": 11}, "k must"),
                                             ({"method": "rk4"}, "method"), ({"n_steps": 1}, "n_steps")])
def test_bad_arguments(kwargs, pattern):
    P, _ = _block_system(6, 1.0, seed=1)
    with pytest.raises(ValueError, match=pattern):
        implicit_floquet(P, period=1.0, **kwargs)


def test_residuals_reject_the_ritz_pairs_of_a_wrong_operator():
    """Eigenpairs of a map with one propagator wrong (step 20 used twice) fail the certificate
    of the true map, while they pass that of the map they belong to."""
    from stability.implicit import residuals
    from stability.magnus import ordered_product

    P, _ = _block_system(6, 1.0, seed=1)
    E = propagators(PeriodicMatrixFunction(P, 1.0), 1.0, 64, MAGNUS6)
    wrong = E.copy()
    wrong[5] = E[20]
    vals, vecs = np.linalg.eig(ordered_product(wrong))
    top = np.argsort(-np.abs(vals))[:4]
    assert np.all(residuals(wrong, vals[top], vecs[:, top]) <= RESIDUAL_TOL)
    assert np.all(residuals(E, vals[top], vecs[:, top]) > 1e3 * RESIDUAL_TOL)
    # and the true pairs pass the true map
    tv, tvec = np.linalg.eig(ordered_product(E))
    ttop = np.argsort(-np.abs(tv))[:4]
    assert np.all(residuals(E, tv[ttop], tvec[:, ttop]) <= RESIDUAL_TOL)


def test_magnus2_step_tripling_estimate_is_the_error():
    """magnus2 with n_steps a multiple of 3: the estimate from the cubes of every third factor
    (the N/3 midpoint rule, no new propagators) is the true error of the moduli within the
    O(h^2) correction of Richardson's model (20 %, as in test_floquet_streamed)."""
    P, exact = _block_system(16, 1.0, seed=3)
    res = implicit_floquet(P, period=1.0, k=6, n_steps=96, method="magnus2")
    assert np.all(res.certified)
    true = max(abs(abs(z) / np.abs(exact[np.argmin(np.abs(exact - z))]) - 1.0) for z in res.multipliers)
    assert abs(res.error_estimate / true - 1.0) <= 0.2
