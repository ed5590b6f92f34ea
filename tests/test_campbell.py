"""Campbell numerics (stability.campbell) against systems with known Floquet structure.

* Crossing branches: a Lyapunov-transformed pair of oscillators, ``x = L(t) y``, ``y' = A y`` with ``L`` periodic
  and ``L(0) = I``; the exact exponents are the eigenvalues of ``A`` (one frequency fixed, one growing with the
  speed: the branches cross) and the periodic part of each solution is ``L(t) v`` (harmonic 0 dominant), so the
  principal frequencies are ``Im eig(A)``.  MAC tracking follows each branch; sorting by frequency swaps them at
  the crossing, and the same check rejects it.
* The anisotropic rotor written in the inertial frame (hand-written ``P(t)``), against its closed form
  (tests/_laval_oracle.py): principal frequencies, damping ratios and harmonic shares.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from stability.campbell import (FloquetModes, campbell, floquet_modes, harmonic_content, mac_matrix, track_modes)
import _laval_oracle as oracle  # tests/ helper

RNG = np.random.default_rng(20261202)
B1 = RNG.standard_normal((4, 4)) / 4
B2 = RNG.standard_normal((4, 4)) / 4
EPS = 0.1


def _osc(w, z):
    return np.array([[0.0, 1.0], [-w * w, -2 * z * w]])


class Transformed:
    """``P = (L' + L A) L^-1``, ``L = I + eps (sin(W t) B1 + (1 - cos(2 W t)) B2)``; state ``(a1, a1', a2, a2')``."""

    def __init__(self, W, w1, w2, z1=0.01, z2=0.03):
        self.W, self.period = W, 2 * math.pi / W
        self.A = np.zeros((4, 4))
        self.A[:2, :2], self.A[2:, 2:] = _osc(w1, z1), _osc(w2, z2)

    def evaluate(self, t):
        t = np.atleast_1d(t)[:, None, None]
        W = self.W
        L = np.eye(4) + EPS * (np.sin(W * t) * B1 + (1 - np.cos(2 * W * t)) * B2)
        Lt = EPS * (W * np.cos(W * t) * B1 + 2 * W * np.sin(2 * W * t) * B2)
        return np.linalg.solve(np.transpose(L, (0, 2, 1)), np.transpose(Lt + L @ self.A, (0, 2, 1))).transpose(0, 2, 1)

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]

    def monodromy(self):
        import scipy.linalg

        return scipy.linalg.expm(self.A * self.period)  # L(T) = L(0) = I


W1 = 10.0


def w2_of(W):
    return 4.0 + 0.5 * W  # crosses W1 at W = 12


def _exact(W):
    """Exact branch frequencies (damped), branch 1 first."""
    return np.array([W1 * math.sqrt(1 - 0.01**2), w2_of(W) * math.sqrt(1 - 0.03**2)])


SPEEDS = np.linspace(6.3, 17.9, 15)  # no grid point at the crossing itself (a double multiplier there)
DISPLACEMENTS = np.eye(4)[[0, 2]]


@pytest.fixture(scope="module")
def crossing_points():
    pts = []
    for W in SPEEDS:
        P = Transformed(W, W1, w2_of(W))
        pts.append(floquet_modes(P, P.monodromy(), shape_map=DISPLACEMENTS))
    return pts


def _branch_error(freqs_per_branch):
    """Largest relative deviation of each branch from the exact branch it starts on."""
    worst = 0.0
    for f in freqs_per_branch:
        ok = np.isfinite(f)
        first = int(np.flatnonzero(ok)[0])
        ex = np.array([_exact(W) for W in SPEEDS])
        which = int(np.argmin(np.abs(ex[first] - f[first])))
        worst = max(worst, float(np.max(np.abs(f[ok] - ex[ok, which]) / ex[ok, which])))
    return worst


def test_principal_frequencies_are_the_exact_exponents(crossing_points):
    for W, p in zip(SPEEDS, crossing_points):
        assert len(p) == 2
        np.testing.assert_allclose(np.sort(p.frequencies), np.sort(_exact(W)), rtol=1e-10)
        assert set(np.round(p.damping_ratios, 10)) == {0.01, 0.03}
        # the propagation reproduces the exact multipliers (what the harmonic shares rest on)
        assert np.max(p.closure) < 1e-6
        for h in p.harmonics:
            assert max(h, key=h.get) == 0


def test_mac_tracking_follows_crossing_branches_and_rejects_sorting(crossing_points):
    res = campbell(SPEEDS, crossing_points)
    assert res.tracking.n_branches == 2
    tracked = [res.branch(b)["frequency"] for b in range(2)]
    assert _branch_error(tracked) < 1e-10
    # each branch keeps its damping ratio: the identity of the mode, not only its frequency
    for b in range(2):
        z = res.branch(b)["damping_ratio"]
        assert np.ptp(z) < 1e-10
    # sorting by frequency (the naive alternative) swaps the branches after the crossing: the same check fails
    by_rank = [np.array([np.sort(p.frequencies)[k] for p in crossing_points]) for k in range(2)]
    assert _branch_error(by_rank) > 0.1


def test_min_mac_starts_a_new_branch():
    a = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([[1.0, 0.0], [1.0, 1.0]])  # second shape: MAC 0.5 with e2, 0.5 with e1
    assert mac_matrix(a, b)[1, 1] == pytest.approx(0.5)
    t = track_modes([a, b], min_mac=0.6)
    assert t.n_branches == 3 and list(t.branches[1]) == [0, 2]
    t = track_modes([a, b], min_mac=0.4)
    assert t.n_branches == 2 and list(t.branches[1]) == [0, 1]


class InertialRotor:
    """``P(t)`` of ``m u'' + c u' + R diag(k) R^T u = 0``, written by hand."""

    def __init__(self, W, **rotor):
        r = {**oracle.ROTOR, **rotor}
        self.W, self.period, self.r = W, 2 * math.pi / W, r

    def evaluate(self, t):
        t = np.atleast_1d(t)
        cs, sn = np.cos(self.W * t), np.sin(self.W * t)
        kx, ky, m, c = self.r["stiffness_xi"], self.r["stiffness_eta"], self.r["mass"], self.r["damping"]
        out = np.zeros((t.size, 4, 4))
        out[:, 0, 2] = out[:, 1, 3] = 1.0
        out[:, 2, 0] = -(kx * cs**2 + ky * sn**2) / m
        out[:, 3, 1] = -(kx * sn**2 + ky * cs**2) / m
        out[:, 2, 1] = out[:, 3, 0] = -(kx - ky) * cs * sn / m
        out[:, 2, 2] = out[:, 3, 3] = -c / m
        return out

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]


@pytest.mark.parametrize("W", [30.0, 80.0, 107.0, 150.0])
def test_anisotropic_rotor_frequencies_damping_and_shares(W):
    P = InertialRotor(W)
    fm = floquet_modes(P, oracle.monodromy(W), shape_map=np.eye(4)[:2],
                       output=lambda t: np.broadcast_to(np.eye(4)[:2], (np.size(t), 2, 4)))
    exact = oracle.principal_modes(W)
    got = sorted(zip(fm.frequencies, fm.damping_ratios, [h[0] for h in fm.harmonics]))
    assert len(got) == len(exact)
    for (f, z, s), (fe, ze, se) in zip(got, exact):
        assert f == pytest.approx(fe, rel=1e-9)
        assert z == pytest.approx(ze, rel=1e-7, abs=1e-12)
        assert s == pytest.approx(se, abs=1e-6)  # the share of the principal harmonic: Magnus-4 at 512 steps
    # the other representative of each mode (lambda_r -+ i W instead of +-) is 2 W away: the check rejects it
    for (f, _, _), (fe, _, se) in zip(got, exact):
        if se < 0.5 + 1e-6:
            continue  # a tie (a real multiplier inside the instability band): both give |f| = W
        assert min(abs(f - abs(fe - 2 * W)), abs(f - (fe + 2 * W))) > 1e-3 * fe  # >> the 1e-9 match above


def test_isotropic_rotor_frequency_does_not_depend_on_speed():
    # isotropic shaft: time-invariant in the inertial frame, so every speed shows sqrt(k/m - (c/2m)^2)
    for W in (20.0, 95.0, 240.0):
        rot = {"stiffness_xi": 2.3e4, "stiffness_eta": 2.3e4}
        fm = floquet_modes(InertialRotor(W, **rot), oracle.monodromy(W, **{**oracle.ROTOR, **rot}))
        wd = math.sqrt(2.3e4 / 2.0 - (2.0 / 4.0) ** 2)
        np.testing.assert_allclose(fm.frequencies, [wd, wd], rtol=1e-9)
        for h in fm.harmonics:
            assert h[0] > 1 - 1e-9


def test_harmonic_content_rejects_bad_input():
    P = InertialRotor(50.0)
    with pytest.raises(ValueError, match="even"):
        harmonic_content(P, np.eye(4)[:, :1], np.ones(1), samples=5)
    with pytest.raises(ValueError, match="zero multiplier"):
        harmonic_content(P, np.eye(4)[:, :1], np.zeros(1))
    with pytest.raises(ValueError, match="speeds but"):
        campbell([1.0, 2.0], [])


def test_a_mode_far_above_the_sampled_harmonics_is_found_by_its_prior():
    """A 403 rad/s oscillator at Omega = 10 rad/s: 64 samples fix its harmonic only modulo 64 (403 = 3 + 40 Omega;
    the alias in -32..31 reads 237 rad/s).  With the frozen frequency as the prior (even 10 % off, and whichever
    way the kept vector turns) the rule gives the exact frequency; without it, the wrong one."""
    W, w_hi, w_lo = 10.0, 403.0, 5.0
    P = Transformed(W, w_hi, w_lo, z1=0.001, z2=0.02)
    Phi = P.monodromy()
    exact_hi = w_hi * math.sqrt(1 - 0.001**2)
    for scale in (1.0, 1.1, 0.9):
        fm = floquet_modes(P, Phi, centres=_priors(P, Phi, w_hi * scale, w_lo), steps_per_sample=32)
        assert np.max(fm.closure) < 1e-4
        assert np.min(np.abs(fm.frequencies - exact_hi)) < 1e-8 * exact_hi
    fm = floquet_modes(P, Phi, steps_per_sample=32)
    assert np.min(np.abs(fm.frequencies - exact_hi)) > 100.0  # aliased without the prior


def _priors(P, Phi, hi, lo):
    """The prior of each eigenvalue (eig order): the damping tells the two oscillators apart."""
    mu = np.linalg.eigvals(Phi)
    decay = -np.log(np.abs(mu)) / P.period  # zeta * w: 0.403 for the fast one, 0.1 for the slow one
    return [hi if d > 0.25 else lo for d in decay]
