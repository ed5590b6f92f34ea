"""Mode labels that mean what they say: a multiplier carries a drive's name only when the drive moves
its mode, and the tuned (dominant) multiplier is one the drives can move.

Model: ``tests/models/spring_chain.py``, three masses in a line joined by Cartesian spring-dampers, the
lateral stiffness of the last spring periodic, a drive moving mass 1 along x.  Oracle: the lateral (y)
motion is an exact linear 3-dof system decoupled from x, ``M y'' + C_y y' + K_y(t) y = 0``, whose
monodromy scipy integrates (DOP853, rtol 1e-12); the drive (an x coordinate) has no share in it.
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from linearize.analysis import DRIVE_SHARE_THRESHOLD, analyze, drive_movable

MODEL = Path(__file__).with_name("models") / "spring_chain.py"
OMEGA = 5.6  # near twice the lowest lateral frequency: that mode is pumped, |rho| ~ 0.997


def _constants():
    spec = importlib.util.spec_from_file_location("spring_chain_constants", MODEL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _lateral_multipliers(omega: float, modulated: int = 2) -> np.ndarray:
    """Multipliers of the lateral chain ``M y'' + C y' + K(t) y = 0`` (hand-assembled spring matrices;
    spring ``modulated`` -- 0 ground-m1, 1 m1-m2, 2 m2-m3 -- has the periodic stiffness)."""
    c = _constants()

    def chain(k1, k2, k3):  # ground -- 1 -- 2 -- 3
        return np.array([[k1 + k2, -k2, 0.0], [-k2, k2 + k3, -k3], [0.0, -k3, k3]])

    Cy = chain(c.CY, c.CY, c.CY) / c.MASS

    def f(t, y):
        k = [c.KY, c.KY, c.KY]
        k[modulated] *= 1 + c.EPS * math.cos(omega * t)
        K = chain(*k) / c.MASS
        A = np.block([[np.zeros((3, 3)), np.eye(3)], [-K, -Cy]])
        return (A @ y.reshape(6, 6)).ravel()

    sol = scipy.integrate.solve_ivp(f, (0, 2 * math.pi / omega), np.eye(6).ravel(), method="DOP853",
                                    rtol=1e-12, atol=1e-14)
    return np.linalg.eigvals(sol.y[:, -1].reshape(6, 6))


@pytest.fixture(scope="module")
def chain():
    return analyze(str(MODEL), OMEGA, n_steps=None)


def test_the_lateral_dominant_multiplier_is_not_named_after_the_axial_drive(chain):
    """The largest multiplier is the pumped lateral mode (the hand-assembled lateral chain's largest, to
    1e-8); the drive has no share in it, so it must not carry the drive's name."""
    lateral = _lateral_multipliers(OMEGA)
    top = chain.modes[0]
    assert abs(abs(chain.floquet.multipliers[0]) - np.max(np.abs(lateral))) <= 1e-8
    assert top.mode != "drive1"
    assert top.drive_shares["drive1"] <= 1e-8 and top.shares["drive drive1"] <= 1e-8
    assert not drive_movable(top)
    # the check can fail: the lateral chain with the periodic stiffness on another spring has another |rho|
    assert abs(abs(chain.floquet.multipliers[0]) - np.max(np.abs(_lateral_multipliers(OMEGA, 1)))) > 1e-4


def test_the_drive_name_goes_to_a_mode_the_drive_moves(chain):
    """Every multiplier named after the drive belongs to a frozen mode whose drive share reaches the
    threshold, and one such mode exists (the axial motion the drive moves)."""
    named = [m for m in chain.modes if m.mode == "drive1"]
    assert named
    assert all(m.drive_shares["drive1"] >= DRIVE_SHARE_THRESHOLD for m in named)
    # every lateral multiplier (the hand chain's six) is unnamed by the drive
    lateral = _lateral_multipliers(OMEGA)
    for mu, m in zip(chain.floquet.multipliers, chain.modes):
        if np.min(np.abs(lateral - mu)) <= 1e-7:
            assert m.mode != "drive1" and not drive_movable(m)


def test_the_dominant_multiplier_is_one_the_drive_moves(chain):
    """``dominant_multiplier`` (the tuned quantity) is the largest multiplier of a mode the drive moves,
    not the lateral 0.997 no gain can change."""
    lateral = _lateral_multipliers(OMEGA)
    dom = chain.dominant_multiplier
    assert np.min(np.abs(lateral - dom)) > 1e-3
    j = int(np.argmin(np.abs(np.asarray(chain.floquet.multipliers) - dom)))
    assert drive_movable(chain.modes[j])
    bigger = [m for mu, m in zip(chain.floquet.multipliers, chain.modes) if abs(mu) > abs(dom) + 1e-12]
    assert bigger and not any(drive_movable(m) and not m.undamped for m in bigger)


def test_tune_names_the_unreachable_mode_before_any_array(monkeypatch):
    """``unreachable_mode`` at the range centre names the lateral mode with its label and zero drive
    share; ``tune`` prints it before the first orthogonal array runs."""
    from flexstab import tuning as tune
    from linearize.analysis import model_plant
    from taguchi.tuning import TuningConfig

    plant = model_plant(str(MODEL), OMEGA)
    tcfg = TuningConfig(target=0.5, kp_range=(0.0, 60.0), kd_range=(0.0, 40.0))
    info = tune.unreachable_mode(plant.orbit, OMEGA, tcfg)
    assert info is not None
    assert info["mode"] != "drive1" and info["drive_shares"] == {"drive1": 0.0}
    assert abs(info["modulus"] - np.max(np.abs(_lateral_multipliers(OMEGA)))) <= 1e-6
    assert len(info["message"].splitlines()) == 1 and f"'{info['mode']}'" in info["message"]


@pytest.mark.slow
def test_tune_reaches_the_target_on_the_movable_modes_and_says_so_first(capsys):
    """``flexstab tune --target 0.5``: the note comes before the tuning's output and the tuning
    converges (it chased the unreachable lateral mode for 600 evaluations before)."""
    import json

    from flexstab.cli import main

    rc = main(["tune", "--model", str(MODEL), "--omega", str(OMEGA), "--target", "0.5", "--json"])
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert rc == 0 and d["converged"] and d["evaluations"] < 600
    assert "a mode no drive moves" in cap.err and d["unreachable_mode"]["mode"] == d["spectral_radius_all_mode"]
