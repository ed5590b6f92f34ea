"""The Floquet front door (``stability.engines.floquet``), its registry and the engine rule.

Oracles: ``expm(A T)`` for constant ``A`` (every engine must reproduce its eigenvalues); for a
constant second-order system ``M y'' + C y' + K y = 0`` the same through its first-order matrix
(Hill's method); the rule's properties in closed form for ``y'' + w(t)^2 y = 0`` with
``w(t) = W (1 + a sin(2 pi t / T))``.  Each check is shown to reject a wrong answer.
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import expm

from stability.engines import ENGINES, FloquetSolution, choose_method, floquet, system_properties
from stability.engines.rule import MODAL_MAX_STEPS, SystemProperties

T = 1.0
# a damped block-diagonal system with well separated moduli (oscillator pairs + decays)
A = np.zeros((6, 6))
A[0:2, 0:2] = [[-0.1, 3.0], [-3.0, -0.1]]
A[2:4, 2:4] = [[-0.7, 1.3], [-1.3, -0.7]]
A[4, 4], A[5, 5] = -1.5, -2.5


def _exact(A_, T_=T):
    rho = np.linalg.eigvals(expm(A_ * T_))
    return rho[np.argsort(-np.abs(rho))]


def _close(got, ref, tol):
    """Every multiplier of ``got`` is within ``tol`` (relative to the spectral radius) of one of ``ref``."""
    scale = np.abs(ref).max()
    return all(np.min(np.abs(ref - z)) <= tol * scale for z in got)


class _Constant:
    """``P(t) = A`` with its period, and as a second-order system ``y'' + C y' + K y = 0``."""

    def __init__(self, A_, samples=8):
        self.A, self.period = A_, T
        n = A_.shape[0]
        self.n = n

    def __call__(self, t):
        return self.A

    def evaluate(self, times):
        return np.broadcast_to(self.A, (len(np.atleast_1d(times)),) + self.A.shape).copy()


@pytest.mark.parametrize("method, options, tol", [
    ("magnus", {}, 1e-8),
    ("magnus", {"order": 4}, 1e-8),
    ("magnus", {"order": 2, "n_steps": 64}, 1e-8),  # exact for constant P: every factor is expm(h A)
    ("modal", {}, 1e-8),
    ("paper", {}, 1e-7),
])
def test_complete_engines_reproduce_expm(method, options, tol):
    sol = floquet(_Constant(A), method=method, rtol=1e-10, **options)
    assert isinstance(sol, FloquetSolution) and sol.complete and sol.method == method
    ref = _exact(A)
    assert sol.multipliers.shape == ref.shape and _close(sol.multipliers, ref, tol)
    assert sol.spectral_radius == pytest.approx(abs(ref[0]), rel=tol)
    # the check rejects a wrong answer: the multipliers of a 1e-3 longer period are far outside tol
    assert not _close(sol.multipliers, _exact(A, T * 1.001), tol)


def test_implicit_engine_gives_the_largest_certified_multipliers():
    sol = floquet(_Constant(A), method="implicit", k=2, n_steps=64)
    ref = _exact(A)
    assert not sol.complete and len(sol.multipliers) >= 1
    assert _close(sol.multipliers, ref[:2], 1e-8)
    assert sol.spectral_radius == pytest.approx(abs(ref[0]), rel=1e-8)
    assert not _close(sol.multipliers, ref[4:], 1e-8)  # not the smallest ones


def test_hill_engine_refines_targets_of_a_second_order_system():
    # y'' + C y' + K y = 0, constant: the first-order matrix gives the exact multipliers
    C = np.diag([0.2, 0.5])
    K = np.array([[9.0, 1.0], [1.0, 4.0]])
    N = 8
    system = SimpleNamespace(M=np.broadcast_to(np.eye(2), (N, 2, 2)).copy(), C=np.broadcast_to(C, (N, 2, 2)).copy(),
                             K=np.broadcast_to(K, (N, 2, 2)).copy(), period=T)
    first = np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -C]])
    ref = _exact(first)
    targets = ref * (1 + 1e-3)  # approximate targets, as a time-stepping engine would give
    sol = floquet(system, method="hill", targets=targets, harmonics=8)
    assert not sol.complete and sol.method == "hill"
    assert _close(sol.multipliers, ref, 1e-10) and len(sol.multipliers) == len(ref)
    assert not _close(sol.multipliers, _exact(first, T * 1.001), 1e-10)
    with pytest.raises(ValueError, match="targets"):
        floquet(system, method="hill")


def test_unknown_methods_and_options_are_rejected():
    with pytest.raises(ValueError, match="unknown Floquet method 'magnus7'.*hill, implicit, magnus, modal, paper"):
        floquet(_Constant(A), method="magnus7")
    with pytest.raises(TypeError, match="'magnus' does not accept samples"):
        floquet(_Constant(A), method="magnus", samples=16)
    with pytest.raises(TypeError, match="'paper' does not accept n_steps"):
        floquet(_Constant(A), method="paper", n_steps=64)
    assert set(ENGINES) == {"magnus", "modal", "hill", "implicit", "paper"}


# --------------------------------------------------------------------------- the rule
class _Oscillator:
    """``y'' + w(t)^2 y = 0``, ``w(t) = W (1 + a sin(2 pi t / T))``, with sampled M, C, K."""

    def __init__(self, W, a, samples=16):
        self.W, self.a, self.period = W, a, T
        t = T * np.arange(samples) / samples
        w2 = (W * (1 + a * np.sin(2 * np.pi * t / T))) ** 2
        self.M, self.C, self.K = np.ones((samples, 1, 1)), np.zeros((samples, 1, 1)), w2.reshape(-1, 1, 1)

    def __call__(self, t):
        w = self.W * (1 + self.a * math.sin(2 * math.pi * t / T))
        return np.array([[0.0, 1.0], [-w * w, 0.0]])


def test_properties_in_closed_form():
    W, a = 1e5, 0.1
    p = system_properties(_Oscillator(W, a))
    # 16 samples of |sin|: mean 2/pi * ... exactly sum|sin(2 pi k/16)|/16 = cot(pi/16)/8
    mean_abs_sin = 1 / (8 * math.tan(math.pi / 16))
    assert p.stiffness == pytest.approx(W * (1 + a) * T, rel=1e-12)
    assert p.frozen_rotation == pytest.approx(W * a * T * mean_abs_sin, rel=1e-12)
    assert p.trigonometric and p.size == 2
    assert p.frozen_rotation != pytest.approx(W * a * T * 2 / math.pi, rel=1e-6)  # the sampled mean, not the integral


def test_rule_from_properties_never_from_a_name():
    rtol = 2.5e-4
    slow = _Oscillator(10.0, 0.3)
    steady = _Oscillator(1e5, 1e-5)   # stiff, frozen frequency nearly constant
    varying = _Oscillator(1e5, 0.1)   # stiff, frozen frequency changes by 10 % along the period
    assert choose_method(system_properties(slow), rtol=rtol) == "magnus"
    assert choose_method(system_properties(steady), rtol=rtol) == "modal"
    assert choose_method(system_properties(varying), rtol=rtol) == "hill"
    # without sampled M, C, K Hill's method does not apply: the best time-stepping engine
    assert choose_method(system_properties(lambda t: varying(t), T), rtol=rtol) == "modal"
    # the threshold is the step budget at the requested accuracy: rotation / sqrt(rtol) vs MODAL_MAX_STEPS
    edge = MODAL_MAX_STEPS * math.sqrt(rtol)
    below = SystemProperties(size=2, period=T, stiffness=1e9, frozen_rotation=0.99 * edge, trigonometric=True)
    above = SystemProperties(size=2, period=T, stiffness=1e9, frozen_rotation=1.01 * edge, trigonometric=True)
    assert choose_method(below, rtol=rtol) == "modal" and choose_method(above, rtol=rtol) == "hill"
    assert choose_method(below, rtol=rtol / 4) == "hill"  # a stricter accuracy needs more steps


def test_auto_picks_magnus_for_the_reduced_model_with_the_same_number():
    from mbs_models import ReducedModel
    from stability import floquet as magnus_floquet

    model = ReducedModel(omega=2 * math.pi, kp=37.1617, kd=29.2410)
    sol = floquet(model)
    ref = magnus_floquet(model)
    known = np.asarray(ref.phase_known)
    assert sol.method == "magnus"
    tol = max(sol.error_estimate, ref.error_estimate)  # the same engine, each result within its own estimate
    np.testing.assert_allclose(sol.multipliers[known], ref.multipliers[known], rtol=tol, atol=0)
    # below the rounding floor of the formed product only the order of magnitude is data (phase unknown)
    floor = 1e-12 * abs(ref.multipliers[0])
    assert np.all(np.abs(sol.multipliers[~known]) < floor) and np.all(np.abs(ref.multipliers[~known]) < floor)
    assert abs(sol.spectral_radius - 0.3) < 1e-3  # Table 3 (Omega = 2 pi): the printed gains give rho_d = 0.3


@pytest.mark.slow
def test_plant_rule_gives_hill_to_an_arm_by_its_matrices_not_its_name(tmp_path):
    """The two-link arm's file under another name gets Hill's method; the single link gets the
    time-stepping plant (the rule reads the linearisation, not the model's name)."""
    from flexstab.plants import response_method, uses_hill
    from linearize.constrained import linearize_orbit
    from linearize.periodic_orbit import find_orbit
    from taguchi.tuning import TuningConfig

    import mbs_models.model_file as mf

    arm = tmp_path / "my_arm.py"
    shutil.copy(Path(mf.__file__).with_name("builtin") / mf.BUILTIN_MODELS["two-link"], arm)
    cfg = TuningConfig(target=0.3, ranges=((0.0, 30.0), (0.0, 10.0)) * 2)
    lin = linearize_orbit(find_orbit(str(arm), 2 * math.pi, elements=1), 0.0, 0.0)
    assert response_method(lin, cfg) == "hill" and uses_hill(lin, cfg)
    link = linearize_orbit(find_orbit("single-link", 2 * math.pi, elements=2), 0.0, 0.0)
    assert response_method(link, TuningConfig(target=0.3)) == "modal"
    assert not uses_hill(link, TuningConfig(target=0.3))
