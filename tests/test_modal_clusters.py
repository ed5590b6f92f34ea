"""Clusters and first-order bases of the frozen-modal frames (stability/modal.py), on systems with known multipliers.

Oracle, independent of ``stability``: ``P(t) = Q A(t) Q^T + Q' Q^T`` with ``Q(t) = expm(S sin 2 pi t)``
(``S`` skew, so ``Q`` is orthogonal, periodic, ``Q(0) = I`` and ``Q' Q^T = 2 pi cos(2 pi t) S``) and
``A(t)`` a block diagonal of damped oscillators ``[[-s, w_j(t)], [-w_j(t), -s]]`` (blocks of the form
``a I + b J``: they commute at different times).  ``x = Q y`` turns it into ``y' = A y``, so
``Phi(T) = Q(T) expm(int_0^T A) Q(0)^T = expm(int_0^T A)``: the multipliers are
``exp(-s T +- i int_0^T w_j)`` in closed form, while the frozen eigenvectors of ``P`` turn with ``Q``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

SIGMA = 0.5


class RotatingOscillators:
    """``P(t)`` of the module notes, ``T = 1``; ``w(t)`` returns the frequencies, ``W`` their integrals."""

    period = 1.0

    def __init__(self, w, W, seed=0, turn=0.03):
        self.w, self.W = w, W
        rng = np.random.default_rng(seed)
        n = 2 * len(W)
        S = rng.standard_normal((n, n))
        self.S = turn * (S - S.T) / np.linalg.norm(S - S.T, 2)
        self.n = n

    def _A(self, t):
        A = -SIGMA * np.eye(self.n)
        for j, wj in enumerate(self.w(t)):
            A[2 * j, 2 * j + 1], A[2 * j + 1, 2 * j] = wj, -wj
        return A

    def evaluate(self, times):
        out = []
        for t in np.atleast_1d(times):
            Q = scipy.linalg.expm(self.S * math.sin(2 * math.pi * t))
            out.append(Q @ self._A(t) @ Q.T + 2 * math.pi * math.cos(2 * math.pi * t) * self.S)
        return np.array(out)

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]

    def exact(self):
        W = np.asarray(self.W)
        return np.concatenate([np.exp(-SIGMA + 1j * W), np.exp(-SIGMA - 1j * W)])


#: Two close pairs: 300 / 310 and 620 / 640 rad/s lie 3.3 % and 3.2 % apart (the former fixed 5 %
#: relative gap merged them) but 10 and 20 rad/s > Omega = 2 pi apart, and vary by << 1 rad/s.
CLOSE = RotatingOscillators(lambda t: (300.0, 310.0, 620.0, 640.0), (300.0, 310.0, 620.0, 640.0))
#: A real crossing: 300 + 15 sin 2 pi t passes 305 twice per period (int_0^1 = 300).
CROSSING = RotatingOscillators(lambda t: (300.0 + 15.0 * math.sin(2 * math.pi * t), 305.0, 620.0),
                               (300.0, 305.0, 620.0), seed=1)


def _error(values, exact):
    """Largest relative distance of an exact multiplier from the computed ones."""
    return max(float(np.min(np.abs(np.asarray(values) - z)) / abs(z)) for z in exact)


def _estimates_bound(res, exact):
    """Every exact multiplier within the result's error estimate (relative) of the nearest computed one."""
    assert _error(res.multipliers, exact) <= res.error_estimate, (_error(res.multipliers, exact), res.error_estimate)


def _converges(system, basis):
    """32 and 64 extrapolated midpoint steps: every exact multiplier within the estimate at 32 steps,
    and the 64-step error below a quarter of the 32-step estimate (the raw midpoint rule is of order 2,
    the extrapolated one higher, so halving h divides an error bounded by the estimate by >= 4)."""
    from stability.modal import modal_floquet

    exact = system.exact()
    coarse, fine = (modal_floquet(system, basis=basis, method="magnus2", n_steps=n, accuracy="moduli",
                                  extrapolate=True) for n in (32, 64))
    _estimates_bound(coarse, exact)
    assert _error(fine.multipliers, exact) <= coarse.error_estimate / 4.0
    return coarse, fine


def test_close_frequencies_stay_separate_and_give_the_exact_multipliers():
    """The gap rule keeps the 3 % apart pairs in their own 2x2 clusters (first frame and the nested,
    first-order one), and the extrapolated midpoint rule converges to ``exp(-s +- i w)`` (measured
    errors 2e-9 / 3e-10 at 32 / 64 steps, estimate 3e-6 at 32)."""
    from stability.modal import modal_system

    system = modal_system(CLOSE)
    assert system.clusters == (2, 2, 2, 2) and system.original.clusters == (2, 2, 2, 2)
    assert system.method == "perturbation" and system.original.method == "perturbation"
    coarse, _ = _converges(CLOSE, system)
    assert coarse.error_estimate <= 1e-5


def test_a_crossing_is_never_cut_and_still_exact():
    """Frequencies that cross (300 + 15 sin 2 pi t against 305) share one 4x4 cluster; the multipliers
    still converge to the closed form (measured errors 1.5e-5 / 4.8e-6 at 32 / 64 steps)."""
    from stability.modal import modal_system

    system = modal_system(CROSSING)
    assert system.original.clusters == (4, 2) and system.clusters == (4, 2)
    _converges(CROSSING, system)


def test_a_cut_through_the_crossing_is_refused(monkeypatch):
    """Forcing every cut (the rule switched off) splits the crossing pair: the sorted eigenvectors swap at
    the crossing and no smooth periodic basis exists, which the construction must refuse (both the Newton
    continuation and the per-sample eig path) rather than return a basis."""
    import stability.modal as sm

    monkeypatch.setattr(sm, "_separated", lambda lo, hi, omega: np.ones(lo.size - 1, bool))
    with pytest.raises(sm.ModalBasisError):
        sm.FrozenModalSystem(CROSSING)


def test_cluster_rule_against_spread_and_orbit_frequency():
    """``_cluster_bounds`` on hand-made moduli: a clean gap is cut; a gap below 10x the spread (and < 5 %
    relative), below Omega, or a crossing (negative gap) is not; a gap of many times the moduli is cut
    whatever their spread."""
    from stability.modal import _cluster_bounds

    t = np.linspace(0.0, 1.0, 16, endpoint=False)[:, None]
    omega = 2 * math.pi

    def mods(a, b, da, db):
        return np.hstack([a + da * np.sin(2 * math.pi * t), b + db * np.cos(2 * math.pi * t)])

    assert _cluster_bounds(mods(300, 310, 0.1, 0.1), omega) == [(0, 1), (1, 2)]   # gap 9.8 > 2, > 2 pi
    assert _cluster_bounds(mods(300, 310, 0.5, 0.5), omega) == [(0, 2)]           # gap 9 < 10 x spread 1
    assert _cluster_bounds(mods(300, 305, 0.01, 0.01), omega) == [(0, 2)]         # gap 5 < 2 pi
    assert _cluster_bounds(mods(300, 305, 15.0, 0.0), omega) == [(0, 2)]          # crossing
    # slow moduli varying by tens of % far below a stiff one: gap 1237 < 10 x spread 500 but 7x relative
    assert _cluster_bounds(mods(160, 1692, 44.6, 250.0), omega) == [(0, 1), (1, 2)]


def test_first_order_basis_leaves_a_second_order_residual():
    """``_first_order`` on ``M = D + eps E`` (``D`` 2x2 blocks with distinct eigenvalues): the off-block
    part of ``(I + X)^-1 M (I + X)`` is ``O(eps^2)`` (``E X`` with ``X = O(eps)``): it falls 100x when
    eps falls 10x (asserted >= 50x; a first-order error would fall 10x)."""
    from stability.modal import _first_order, _size_groups

    rng = np.random.default_rng(3)
    m = 6
    bounds = [(2 * j, 2 * j + 2) for j in range(m)]
    D = np.zeros((2 * m, 2 * m))
    for j in range(m):
        D[2 * j:2 * j + 2, 2 * j:2 * j + 2] = [[-1.0, 50.0 * (j + 1)], [-50.0 * (j + 1), -1.0]] + 0.5 * rng.standard_normal((2, 2))
    labels = np.repeat(np.arange(m), 2)
    E = np.where(labels[:, None] == labels[None, :], 0.0, rng.standard_normal(D.shape))

    def residual(eps):
        M = D + eps * E
        X, _ = _first_order(M, _size_groups(bounds), labels)
        R = np.linalg.solve(np.eye(2 * m) + X, M @ (np.eye(2 * m) + X))
        return np.abs(np.where(labels[:, None] == labels[None, :], 0.0, R)).max()

    r1, r2 = residual(1.0), residual(0.1)
    assert r1 / r2 >= 50.0, (r1, r2)


@pytest.mark.parametrize("frame", ["first", "nested"])
def test_each_frame_needs_its_basis_derivative(frame):
    """Both new constructions (the Newton-continued first frame, the first-order nested frame) are exact
    similarities only with their ``V'``: the raw midpoint rule at 128 steps meets the closed form within
    the 32-step estimate / 16 (order 2: (32 / 128)^2; measured 2e-9 against 3e-6 / 16), while dropping
    ``V'`` from either frame leaves an answer outside the 32-step estimate (measured 1.2e-4 and 1.1e-5)."""
    from stability import floquet
    from stability.modal import modal_floquet, modal_system

    system = modal_system(CLOSE)
    exact = CLOSE.exact()
    est = modal_floquet(CLOSE, basis=system, method="magnus2", n_steps=32, accuracy="moduli",
                        extrapolate=True).error_estimate
    good = floquet(system, method="magnus2", n_steps=128, error_estimate=False)
    assert _error(good.multipliers, exact) <= est / 16.0
    target = system.original if frame == "first" else system
    basis = target.basis
    target.basis = lambda t, derivative=False: basis(t, derivative) * (0.0 if derivative else 1.0)
    bad = floquet(system, method="magnus2", n_steps=128, error_estimate=False)
    assert _error(bad.multipliers, exact) > est


def test_eig_and_first_order_bases_agree_and_bad_methods_are_refused():
    """Both basis constructions (a full eig per sample, the Newton continuation + first-order nested frame)
    converge to the closed-form multipliers; an unknown method is one clear ValueError."""
    from stability.modal import FrozenModalSystem

    for method in ("eig", "auto"):
        inner = FrozenModalSystem(CLOSE, method=method)
        system = FrozenModalSystem(inner, method=method)
        assert system.method == ("eig" if method == "eig" else "perturbation")
        _converges(CLOSE, system)
    with pytest.raises(ValueError, match="method"):
        FrozenModalSystem(CLOSE, method="qr")


def test_small_sylvester_solutions_satisfy_their_equation():
    """``_sylvester`` (closed forms for blocks of size <= 2, the Kronecker form otherwise) against its own
    equation ``A X - X B = C`` for random blocks of every size pair up to 3: residual at rounding
    (``<= 1e-10 (|A| + |B|) |X|``, conditioning of these random cases ~1e2: measured 1e-14)."""
    from stability.modal import _sylvester

    rng = np.random.default_rng(5)
    for p in (1, 2, 3):
        for q in (1, 2, 3):
            A = rng.standard_normal((4, 1, p, p)) + 3.0 * np.eye(p)
            B = rng.standard_normal((1, 5, q, q)) - 3.0 * np.eye(q)
            C = rng.standard_normal((4, 5, p, q))
            X = _sylvester(A, B, C)
            res = np.abs(A @ X - X @ B - C).max()
            assert res <= 1e-10 * (np.abs(A).max() + np.abs(B).max()) * np.abs(X).max(), (p, q, res)
    # a common eigenvalue has no solution: refused as non-finite, never a silent number
    assert not np.all(np.isfinite(_sylvester(np.eye(2)[None], np.eye(2)[None], np.ones((1, 2, 2)))))


def test_nested_frame_reads_its_parent_samples_exactly():
    """A nested frame takes ``P_hat`` at the shared sample times from its parent's samples (spectral
    ``V'``) instead of evaluating it: equal to the parent's own ``evaluate`` at those times to rounding
    (``|V^-1| |P| |V| eps`` with ``|P| ~ 640``: <= 1e-10 relative; measured ~1e-14), also for a divisor
    of the sample count; read once; a frame re-based on another ``P`` (``with_system``) carries no
    samples, nor does a sample count that does not divide the parent's."""
    from stability.modal import FrozenModalSystem, _samples_of

    frame = FrozenModalSystem(CLOSE, samples=16)
    times = np.arange(16) * (frame.period / 16)
    direct = frame.evaluate(times)
    assert _samples_of(frame, 6) is None  # 6 does not divide 16
    assert _samples_of(frame.with_system(CROSSING.__class__(CLOSE.w, CLOSE.W, seed=4)), 16) is None
    cached = _samples_of(frame, 16)
    assert np.abs(cached - direct).max() <= 1e-10 * np.abs(direct).max()
    assert _samples_of(frame, 16) is None
    # every second sample: the 8 times of a coarser nested frame
    frame = FrozenModalSystem(CLOSE, samples=16)
    sub = _samples_of(frame, 8)
    assert np.abs(sub - direct[::2]).max() <= 1e-10 * np.abs(direct).max()
