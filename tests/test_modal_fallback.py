"""The fallback of :func:`stability.modal.modal_floquet` when no frozen-modal basis exists.

System: a slow 1-DOF mode whose damping crosses critical within the period,
``x'' + c(t) x' + x = 0`` with ``c(t) = 2 + 1.8 sin 2 pi t`` (critical at ``c = 2``: the frozen
eigenvalue pair turns real and back), beside a stiff constant mode ``y'' + y' + 1e4 y = 0``, ``T = 1``.

Oracle, independent of ``stability``: the stiff block's multipliers in closed form,
``exp(lambda T)`` with ``lambda`` the roots of ``s^2 + s + 1e4``; the slow block's monodromy from
scipy's DOP853 at ``rtol = 1e-13`` (its multipliers then carry ~1e-12), checked itself by
Liouville's formula ``det = exp(-int_0^1 c dt) = exp(-2)``.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

K_STIFF, C_STIFF = 1e4, 1.0


def _P(t: float) -> np.ndarray:
    c = 2.0 + 1.8 * math.sin(2 * math.pi * t)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 0], A[2, 2] = -1.0, -c
    A[3, 1], A[3, 3] = -K_STIFF, -C_STIFF
    return A


@pytest.fixture(scope="module")
def exact():
    def slow(t, y):
        return [y[1], -y[0] - (2.0 + 1.8 * math.sin(2 * math.pi * t)) * y[1]]

    Y = np.column_stack([solve_ivp(slow, (0.0, 1.0), e, method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1]
                         for e in np.eye(2)])
    assert abs(np.linalg.det(Y) - math.exp(-2.0)) <= 1e-12
    return np.concatenate([np.linalg.eigvals(Y), np.exp(np.roots([1.0, C_STIFF, K_STIFF]))])


def _error(values, exact) -> float:
    """Largest relative distance of an exact multiplier from the computed ones."""
    return max(float(np.min(np.abs(np.asarray(values) - z)) / abs(z)) for z in exact)


def test_no_basis_for_a_damping_crossing_critical():
    from stability.modal import ModalBasisError, modal_system

    with pytest.raises(ModalBasisError):
        modal_system(_P, period=1.0)


@pytest.mark.parametrize("levels", [1, 2])  # 1: ModelPlant.floquet's call, 2: analyze's
def test_fallback_warns_records_the_frame_and_meets_the_oracle(exact, levels):
    """The fallback warns, says ``frame="model"`` and is the adaptive engine: error <= 1e-8
    (its target rtol = 1e-9 on the moduli, x10 because a Richardson estimate is an estimate; the
    oracle's 1e-12 is far below).  The former silent fallback (magnus2 at the caller's 128 steps in
    the model's coordinates) misses the oracle by more than that (measured 4e-6)."""
    from stability import floquet
    from stability.modal import modal_floquet

    with pytest.warns(RuntimeWarning, match="no frozen-modal basis"):
        res = modal_floquet(_P, period=1.0, method="magnus2", n_steps=128, accuracy="moduli", extrapolate=True,
                            levels=levels)
    assert res.frame == "model" and res.modal_levels == 0 and "90 degrees" in res.fallback_reason
    assert res.to_dict()["frame"] == "model"
    assert res.n_steps != 128 and res.method == "magnus6"
    assert _error(res.multipliers, exact) <= 1e-8
    old = floquet(_P, period=1.0, method="magnus2", n_steps=128)
    assert _error(old.multipliers, exact) > 1e-8


def test_modal_frame_is_recorded():
    """Constant coefficients have a basis: ``frame="modal"`` with the frames used."""
    from stability.modal import modal_floquet

    P = np.array([[0.0, 1.0], [-4.0, -0.5]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = modal_floquet(lambda t: P, period=1.0, method="magnus2", n_steps=8)
    assert res.frame == "modal" and res.modal_levels >= 1 and res.fallback_reason == ""


def test_one_frame_retry_keeps_the_smaller_estimate_only_when_both_agree():
    """``analyze``'s choice between one and two frozen-modal frames.  Picking the smaller
    estimate unconditionally would keep 0.5 +- 1e-9 below although the other frame reads 0.5 + 1e-6:
    rejected; the larger-estimate result is kept with its estimate raised to the 2e-6 disagreement."""
    from linearize.analysis import _pick_frame

    # agree within the larger estimate (1e-5): the smaller estimate (one frame) is kept
    assert _pick_frame(0.5, 1e-5, 0.5 + 1e-7, 1e-8) == (True, 1e-8, pytest.approx(2e-7), True)
    assert _pick_frame(0.5, 1e-8, 0.5 + 1e-7, 1e-5)[:2] == (False, 1e-8)
    # disagree: never the smaller estimate
    take_alt, est, gap, agree = _pick_frame(0.5 + 1e-6, 1e-7, 0.5, 1e-9)
    assert (take_alt, agree) == (False, False) and est == pytest.approx(2e-6, rel=1e-5)
    take_alt, est, _, agree = _pick_frame(0.5, 1e-9, 0.5 + 1e-6, 1e-7)
    assert (take_alt, agree) == (True, False) and est == pytest.approx(2e-6, rel=1e-5)
