"""Natural frequencies of the Exudyn ANCF link against Euler-Bernoulli theory.

Oracle: the frequency equations with tip mass, solved here with brentq
(independently of ``mbs_models.modes``), and the O(h^4) mesh convergence of
cubic Hermite elements.
"""
import json
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest
from scipy.optimize import brentq

from mbs_models.modes import analytic_beta_l, exudyn_frequencies
from mbs_models.parameters import ManipulatorParameters

P = ManipulatorParameters()
MU = P.tip_mass / P.link_mass


def _clamped(b):
    # 1 + cos b cosh b + mu b (cos b sinh b - sin b cosh b) = 0 (tip mass, no rotary inertia)
    return 1 + math.cos(b) * math.cosh(b) + MU * b * (math.cos(b) * math.sinh(b) - math.sin(b) * math.cosh(b))


def _pinned(b):
    """Hub pinned at O with inertia J1, beam clamped to it, tip mass.

    W = A (cos - cosh) + B sin + D sinh satisfies W(0) = 0; the remaining
    conditions W''(0) = -j b^4 W'(0) and W''(1) = 0, W'''(1) = -mu b^4 W(1)
    give a 3x3 determinant (derivatives in xi = x / l, divided by powers of b).
    """
    j = P.hub_inertia / (P.mass_per_length * P.length**3)
    c, s, ch, sh = math.cos(b), math.sin(b), math.cosh(b), math.sinh(b)
    # columns: A (cos - cosh), B sin, D sinh
    row0 = [-2.0, j * b**3, j * b**3]  # W''(0)/b^2 + j b^3 W'(0)/b
    row1 = [-c - ch, -s, sh]  # W''(1)/b^2
    w = [c - ch, s, sh]
    w3 = [s - sh, -c, ch]  # W'''(1)/b^3
    row2 = [w3[i] + MU * b * w[i] for i in range(3)]
    return np.linalg.det(np.array([row0, row1, row2])) / ch**2


def _roots(f, count, lo=0.05, step=0.01):
    out, a, fa = [], lo, f(lo)
    while len(out) < count:
        b, fb = a + step, f(a + step)
        if fa * fb < 0:
            out.append(brentq(f, a, b, xtol=1e-14))
        a, fa = b, fb
    return np.array(out)


def _hz(bl):
    return bl**2 / (2 * math.pi * P.length**2) * math.sqrt(P.bending_stiffness / P.mass_per_length)


CLAMPED_HZ = _hz(_roots(_clamped, 2))
PINNED_HZ = _hz(_roots(_pinned, 2))


def test_frequency_equations_match_issue_values():
    # Euler-Bernoulli: beta l = 1.71917, 4.39430 -> 17.2052 Hz, 112.409 Hz; pinned f1 ~ 77.896 Hz
    assert _roots(_clamped, 2) == pytest.approx([1.71917, 4.39430], abs=1e-5)
    assert CLAMPED_HZ == pytest.approx([17.2052, 112.409], rel=1e-5)
    assert PINNED_HZ[0] == pytest.approx(77.896, rel=1e-5)
    # the library's own determinant agrees with this independent formulation
    assert analytic_beta_l(P, "clamped", 2) == pytest.approx(_roots(_clamped, 2), rel=1e-10)
    assert analytic_beta_l(P, "pinned", 2) == pytest.approx(_roots(_pinned, 2), rel=1e-10)


def test_clamped_frequencies_at_8_elements():
    res = exudyn_frequencies(P, elements=8, hub="clamped", count=2)
    f1, f2 = res.frequencies_hz
    assert abs(f1 - CLAMPED_HZ[0]) / CLAMPED_HZ[0] < 1e-5
    assert abs(f2 - CLAMPED_HZ[1]) / CLAMPED_HZ[1] < 1e-4
    assert res.rigid_modes == 0


def test_pinned_hub_frequencies():
    res = exudyn_frequencies(P, elements=8, hub="pinned", count=2)
    assert res.rigid_modes == 1  # the hub rotation
    assert abs(res.frequencies_hz[0] - PINNED_HZ[0]) / PINNED_HZ[0] < 1e-4
    assert abs(res.frequencies_hz[1] - PINNED_HZ[1]) / PINNED_HZ[1] < 1e-3


@pytest.mark.parametrize("hub,ref", [("clamped", CLAMPED_HZ[0]), ("pinned", PINNED_HZ[0])])
def test_mesh_convergence_is_fourth_order(hub, ref):
    errs = [abs(exudyn_frequencies(P, elements=N, hub=hub, count=1).frequencies_hz[0] - ref) / ref for N in (4, 8, 16)]
    orders = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(3.7 < q < 4.3 for q in orders), orders


def test_other_parameters_follow_theory():
    p = ManipulatorParameters(tip_mass=0.3, length=0.7)
    global MU
    mu_saved, MU = MU, p.tip_mass / p.link_mass
    try:
        b1 = _roots(_clamped, 1)[0]
    finally:
        MU = mu_saved
    ref = b1**2 / (2 * math.pi * p.length**2) * math.sqrt(p.bending_stiffness / p.mass_per_length)
    f1 = exudyn_frequencies(p, elements=8, hub="clamped", count=1).frequencies_hz[0]
    assert abs(f1 - ref) / ref < 1e-5


@pytest.mark.parametrize(
    "kwargs,match",
    [({"elements": 0}, "elements"), ({"hub": "welded"}, "hub"), ({"count": 0}, "count")],
)
def test_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        exudyn_frequencies(P, **kwargs)


def test_cli_modes_json(capsys):
    from flexstab.cli import main

    assert main(["modes", "--elements", "8", "--hub", "clamped", "--count", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frequencies_hz"][0] == pytest.approx(CLAMPED_HZ[0], rel=1e-5)
    assert out["analytic_hz"][:2] == pytest.approx(list(CLAMPED_HZ), rel=1e-9)
    assert len(out["frequencies_hz"]) == 3


def test_cli_modes_rejects_zero_elements(capsys):
    from flexstab.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["modes", "--elements", "0"])
    assert exc.value.code == 2
