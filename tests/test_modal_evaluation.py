"""The frozen-modal ``P_hat(t)`` evaluation (``stability.modal``): real trigonometric tables, ``V`` and ``V'``
in one pass, and the LU path of ``first_order_matrix``.

Oracles, independent of the code under test: the complex-phase Fourier sum written out here, the
interpolation property (the interpolant reproduces its samples), the defining identity
``V P_hat = D^-1 P D V - V'`` (a residual, whatever the order of operations), the composite frame of
two nested levels formed here in one step (``U = D1 V1 D2 V2``, another association of the same maths),
and ``M (M^-1 K) = K``.  Each check is also shown to reject a wrong variant.
"""
from __future__ import annotations

import numpy as np
import pytest

EPS = np.finfo(float).eps


def _complex_sum(coef, period, t, derivative=False):
    """``Re sum_k c_k exp(i k w t)`` (times ``i k w`` for the derivative), written out independently."""
    k = np.arange(coef.shape[0])
    w = 2.0 * np.pi / period
    phase = np.exp(1j * w * np.outer(t, k))
    if derivative:
        phase = phase * (1j * w * k)
    return np.real(np.einsum("mk,k...->m...", phase, coef))


class _Turning:
    """``P(t) = Q(t) A Q(t)^T`` with ``Q(t) = G R(t) G^T`` orthogonal and T-periodic (``R`` rotations by
    ``2 pi k t / T``, ``k = 1, 2, ...``): the frozen eigenvalues are constant (those of ``A``) but the
    eigenvectors turn, so ``V' != 0`` matters.  10 states (above ``stability.floquet.SMALL_N``)."""

    period = 1.0

    def __init__(self) -> None:
        rng = np.random.default_rng(11)
        self.n = 10
        blocks = [(-0.1 * (j + 1), 3.0 * (j + 1) ** 1.5) for j in range(5)]
        A = np.zeros((10, 10))
        for j, (sig, om) in enumerate(blocks):
            A[2 * j:2 * j + 2, 2 * j:2 * j + 2] = [[sig, om], [-om, sig]]
        X = np.eye(10) + 0.3 * rng.standard_normal((10, 10))
        self.A = X @ A @ np.linalg.inv(X)
        self.G, _ = np.linalg.qr(rng.standard_normal((10, 10)))

    def Q(self, t: np.ndarray) -> np.ndarray:
        R = np.zeros((t.size, 10, 10))
        for j in range(5):
            a = 2 * np.pi * (j % 2 + 1) * t / self.period
            c, s = np.cos(a), np.sin(a)
            R[:, 2 * j, 2 * j], R[:, 2 * j, 2 * j + 1], R[:, 2 * j + 1, 2 * j], R[:, 2 * j + 1, 2 * j + 1] = c, -s, s, c
        return self.G @ R @ self.G.T

    def evaluate(self, times) -> np.ndarray:
        Q = self.Q(np.atleast_1d(np.asarray(times, dtype=float)))
        return Q @ self.A @ np.transpose(Q, (0, 2, 1))

    def __call__(self, t: float) -> np.ndarray:
        return self.evaluate(np.array([t]))[0]


@pytest.fixture(scope="module")
def nested():
    from stability.modal import modal_system

    system = modal_system(_Turning(), levels=2)
    assert isinstance(system.original, type(system))  # two levels
    return system


def test_real_table_equals_the_complex_sum_and_reproduces_samples():
    from stability.modal import _trig_coefficients, _trig_eval

    rng = np.random.default_rng(4)
    samples = rng.standard_normal((16, 3, 5))
    coef = _trig_coefficients(samples)
    t = rng.uniform(-2.0, 3.0, 7)
    # same sum in another arithmetic: |error| <= (2K) eps sum|c_k| (K = 9 terms, each a rounded product)
    bound = 4 * coef.shape[0] * EPS * np.abs(coef).sum(axis=0) * (1 + 2 * np.pi / 1.5 * coef.shape[0])
    for deriv in (False, True):
        got = _trig_eval(coef, 1.5, t, deriv)
        assert np.all(np.abs(got - _complex_sum(coef, 1.5, t, deriv)) <= bound)
    back = _trig_eval(coef, 1.5, np.arange(16) * 1.5 / 16)
    assert np.allclose(back, samples, rtol=0, atol=64 * EPS * np.abs(samples).max())
    # a wrong derivative (the sign of the sine rows flipped) is far outside the bound
    wrong = -_trig_eval(coef, 1.5, t, True)
    assert not np.all(np.abs(wrong - _complex_sum(coef, 1.5, t, True)) <= bound)


def test_basis_derivative_is_exact(nested):
    """``basis(t, derivative=True)`` is the time derivative of ``basis(t)``: central difference with
    h = 1e-4 (error h^2/6 max|d^3V/dt^3|; measured 3e-7 relative, 1e-5 allowed)."""
    t = np.array([0.013, 0.31, 0.77])
    Vt = nested.basis(t, derivative=True)
    h = 1e-4
    fd = (nested.basis(t + h) - nested.basis(t - h)) / (2 * h)
    assert np.allclose(fd, Vt, rtol=0, atol=1e-5 * np.abs(Vt).max())
    # the sign of the derivative flipped (a wrong V') is far off
    assert not np.allclose(fd, -Vt, rtol=0, atol=1e-5 * np.abs(Vt).max())


def _residual(system, t, P_hat, drop_derivative=False):
    """``|V P_hat - (D^-1 P D V - V')|`` over ``(|V| |P_hat| + |Pb| |V| + |V'|)`` (elementwise ratio)."""
    P = system._wrapped.evaluate(t) * (system.scale[None, :] / system.scale[:, None])
    V, Vt = system.basis(t), system.basis(t, derivative=True)
    rhs = P @ V - (0.0 if drop_derivative else Vt)
    scale = np.abs(V) @ np.abs(P_hat) + np.abs(P) @ np.abs(V) + np.abs(Vt)
    return float(np.max(np.abs(V @ P_hat - rhs) / scale))


def test_evaluate_solves_the_defining_identity(nested):
    """Backward stability of one LU solve and two products: residual <= ~3 n eps relative to the
    absolute values (Higham 2002, Thm 9.4 and Sec. 3.5); 10 n eps allowed."""
    t = np.array([0.0, 0.21, 0.5, 0.93])
    P_hat = nested.evaluate(t)
    assert _residual(nested, t, P_hat) <= 10 * nested.n * EPS
    # the same identity without the V' term: P_hat misses it by the size of V^-1 V' (a wrong frame)
    assert _residual(nested, t, P_hat, drop_derivative=True) > 1e-6


def test_nested_levels_equal_the_composite_frame(nested):
    """Two nested frames are one frame ``U = D1 V1 D2 V2`` of the base ``P``: ``P_hat = U^-1 (P U - U')``
    with ``U' = D1 (V1' D2 V2 + V1 D2 V2')``, computed here in one solve.  Both are backward stable for
    the same exact matrix, so they agree within ~cond(U) n eps ||P_hat|| (the forward error of a
    solve); a frame with the inner ``V1'`` dropped does not."""
    inner = nested.original
    base = inner._wrapped
    t = np.array([0.05, 0.4, 0.8])
    D1, D2 = np.diag(inner.scale), np.diag(nested.scale)
    V1, V1t = inner.basis(t), inner.basis(t, derivative=True)
    V2, V2t = nested.basis(t), nested.basis(t, derivative=True)
    U = D1 @ V1 @ D2 @ V2
    Ut = D1 @ (V1t @ D2 @ V2 + V1 @ D2 @ V2t)
    composite = np.linalg.solve(U, base.evaluate(t) @ U - Ut)
    got = nested.evaluate(t)
    cond = max(np.linalg.cond(u) for u in U)
    tol = 10 * cond * nested.n * EPS * np.abs(got).max()
    assert np.abs(got - composite).max() <= tol
    wrong = np.linalg.solve(U, base.evaluate(t) @ U - D1 @ V1 @ D2 @ V2t)
    assert np.abs(got - wrong).max() > 1e3 * tol


def _frames_by_hand(nested, t):
    """``V1, V1', D2, V2, V2'`` of the two frames from their own tables (not the composite one)."""
    inner = nested.original
    return (inner.basis(t), inner.basis(t, derivative=True), np.diag(nested.scale), nested.basis(t),
            nested.basis(t, derivative=True))


def test_collapsed_table_is_the_product_of_the_frames(nested):
    """The composite table (``N = K1 + K2`` samples of ``V1 D2 V2``) reproduces the product of the two
    interpolants and its derivative ``V1' D2 V2 + V1 D2 V2'`` at times off its grid: a product of
    trigonometric polynomials is one of the summed degree, so only rounding remains: each sample
    ``<= n eps |V1| |D2| |V2|`` (a matrix product), the FFT and the sum over the ``K`` harmonics a
    factor ``~ K`` (``K w`` more for the derivative); 10x margin.  Dropping ``V1' D2 V2`` from the
    derivative (a wrong composite ``U'``) is far outside."""
    collapsed = nested.collapsed()
    t = np.array([0.013, 0.3717, 0.77, 0.9951])
    V1, V1t, D2, V2, V2t = _frames_by_hand(nested, t)
    K, w = collapsed._K, 2 * np.pi / nested.period
    size = (np.abs(V1) @ np.abs(D2) @ np.abs(V2)).max()
    tol = 10 * (nested.n + K) * EPS * size
    assert np.abs(collapsed.basis(t) - V1 @ D2 @ V2).max() <= tol
    exact_t = V1t @ D2 @ V2 + V1 @ D2 @ V2t
    assert np.abs(collapsed.basis(t, derivative=True) - exact_t).max() <= tol * K * w
    assert np.abs(collapsed.basis(t, derivative=True) - V1 @ D2 @ V2t).max() > 1e3 * tol * K * w


def test_collapsed_evaluation_equals_the_nested_one(nested):
    """One solve in the composite basis equals the frame-by-frame ``evaluate`` (two solves): both are
    backward stable for the same exact ``P_hat``, so they differ by ``<~ cond(U) n eps |P_hat|`` (the
    forward error of a solve, ``U`` the composite basis); 10x margin.  A composite ``U'`` without
    ``V1' D2 V2`` is rejected."""
    collapsed = nested.collapsed()
    assert collapsed.clusters == nested.clusters and collapsed.trace_integral() == nested.trace_integral()
    t = np.array([0.05, 0.4, 0.8])
    got, ref = collapsed.evaluate(t), nested.evaluate(t)
    U = collapsed.basis(t)
    cond = max(np.linalg.cond(u) for u in U)
    tol = 10 * cond * nested.n * EPS * np.abs(ref).max()
    assert np.abs(got - ref).max() <= tol
    V1, _, D2, _, V2t = _frames_by_hand(nested, t)
    Pb = collapsed._wrapped.evaluate(t) * collapsed._ratio
    wrong = np.linalg.solve(U, Pb @ U - V1 @ D2 @ V2t)
    assert np.abs(wrong - ref).max() > 1e3 * tol
    # a first frame has nothing to collapse
    assert nested.original.collapsed() is nested.original


def test_first_order_matrix_lu_path():
    """Mass matrices of ``LU_MIN_SIZE`` and more: ``M (M^-1 K) = K`` to the backward error of one LU
    solve (<= 3 f eps |M| |X| elementwise up to growth, Higham 2002 Thm 9.4; 10 f eps allowed)."""
    from stability.periodic import LU_MIN_SIZE, first_order_matrix

    f = LU_MIN_SIZE + 3
    rng = np.random.default_rng(7)
    M = rng.standard_normal((4, f, f)) + 2 * np.sqrt(f) * np.eye(f)
    K, C = rng.standard_normal((2, 4, f, f))
    P = first_order_matrix(M, C, K)
    assert np.array_equal(P[:, :f, f:], np.broadcast_to(np.eye(f), (4, f, f)))
    assert not P[:, :f, :f].any()
    for X, Y in ((-P[:, f:, :f], K), (-P[:, f:, f:], C)):
        assert np.all(np.abs(M @ X - Y) <= 10 * f * EPS * (np.abs(M) @ np.abs(X) + np.abs(Y)))
    single = first_order_matrix(M[1], C[1], K[1])
    assert np.array_equal(single, P[1])


@pytest.mark.parametrize("kind", ["rank_deficient", "near_singular", "vanishing"])
def test_first_order_matrix_lu_path_rejects_singular_mass(kind):
    from stability.periodic import LU_MIN_SIZE, first_order_matrix

    f = LU_MIN_SIZE
    rng = np.random.default_rng(1)
    M = np.repeat((rng.standard_normal((f, f)) + 2 * np.sqrt(f) * np.eye(f))[None], 3, axis=0)
    if kind == "rank_deficient":
        M[1, :, -1] = M[1, :, 0]  # two equal columns
    elif kind == "near_singular":
        M[1, :, -1] = M[1, :, 0] * (1 + 1e-15)  # condition ~1e16
    else:
        M[2] *= 1e-15  # regular in itself, but vanishing against the other samples
    K = C = np.ones_like(M)
    with pytest.raises(ValueError, match=r"mass matrix.*singular"):
        first_order_matrix(M, C, K)
    # a moderately conditioned mass matrix (condition ~1e6) is accepted
    ok = np.repeat((rng.standard_normal((f, f)) + 2 * np.sqrt(f) * np.eye(f))[None], 3, axis=0)
    ok[:, 0] *= 1e-6
    first_order_matrix(ok, C, K)


def test_linearized_system_matrices_equal_trig_interpolate():
    """``LinearizedPeriodicSystem.matrices`` (one cached real table for M, C, K) against
    ``trig_interpolate`` of each (complex phases, FFT per call): the same sums of ``N/2 + 1`` terms,
    <= 4 (N/2 + 1) eps sum|c_k| apart; the samples are reproduced at the sample times; a system
    with other gains (``with_gains``) does not reuse the old table."""
    from linearize.fourier import trig_interpolate
    from linearize.system import LinearizedPeriodicSystem

    rng = np.random.default_rng(3)
    N, n, T = 16, 4, 0.7
    M = rng.standard_normal((N, n, n)) + 4 * np.eye(n)
    C, K = rng.standard_normal((2, N, n, n))
    lin = LinearizedPeriodicSystem(T, np.arange(N) * T / N, M, C, K)
    t = rng.uniform(0, 2 * T, 5)
    got = lin.matrices(t)
    for X, Y in zip(got, (M, C, K)):
        bound = 4 * (N // 2 + 1) * EPS * np.abs(np.fft.rfft(Y, axis=0) / N * 2).sum(axis=0)
        assert np.all(np.abs(X - trig_interpolate(Y, T, t)) <= bound)
    for X, Y in zip(lin.matrices(np.arange(N) * T / N), (M, C, K)):
        assert np.allclose(X, Y, rtol=0, atol=64 * EPS * np.abs(Y).max())
    other = lin.with_gains(5.0, 2.0)
    # kd = 2 adds 2 to C[0, 0] at every sample, hence to its interpolant (up to the rounding bound)
    assert np.allclose(other.matrices(t)[1][:, 0, 0], got[1][:, 0, 0] + 2.0, rtol=0, atol=1e-13)
    Kg = other.matrices(t)[2]
    assert np.all(np.abs(Kg - trig_interpolate(other.K, T, t)) <= 4 * (N // 2 + 1) * EPS
                  * np.abs(np.fft.rfft(other.K, axis=0) / N * 2).sum(axis=0))
    assert not np.allclose(Kg, got[2])
