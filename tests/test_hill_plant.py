"""The two-link tuning response by Hill's method against an independent time-stepping product.

Coarse setting (1 element per link, Omega = 2 pi, gains near the tuned ones): the response of
:class:`linearize.hill_plant.HillModelPlant` (magnus2 labels, Hill value) is compared with the
streamed exponential-midpoint product at 8192 and 16384 steps, which shares no code with Hill.
Tolerance: the product is second order, so its error at 2n steps is ~ |rho_2n - rho_n| / 3; we allow
4/3 |rho_2n - rho_n| (the Richardson bound of the n-step value, which over-states the 2n one) plus
Hill's own H vs H/2 estimate.  The loop's 512-step labelling pass is off by far more than that, so the
comparison can fail.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from linearize.constrained import linearize_orbit
from linearize.hill_plant import HillGainObjective, HillModelPlant, drive_gain_family
from linearize.periodic_orbit import find_orbit
from mbs_models.model_file import builtin_model
from stability import floquet

GAINS = (15.0, 9.0, 7.0, 1.5)


@pytest.fixture(scope="module")
def arm():
    orbit = find_orbit(builtin_model("two-link", elements=1), 2 * math.pi)
    return orbit, linearize_orbit(orbit, 0.0, 0.0)


def test_hill_response_matches_streamed_magnus2(arm):
    orbit, lin = arm
    g = GAINS
    m = HillModelPlant(lin, orbit, harmonics=16).measure(g[0::2], g[1::2], error_estimate=True)
    assert m.mode in ("shoulder", "elbow")
    lg = lin.with_gains(g[0::2], g[1::2])
    def nearest(n):
        w = np.asarray(floquet(lg, method="magnus2", n_steps=n, error_estimate=False).multipliers)
        return abs(w[int(np.argmin(np.abs(w - m.dominant)))])

    r8, r16 = nearest(8192), nearest(16384)
    tol = 4.0 / 3.0 * abs(r16 - r8) + m.hill_error_estimate * abs(m.dominant)
    assert abs(abs(m.dominant) - r16) <= tol, (abs(m.dominant), r8, r16, tol)
    # the labelling pass alone (512 steps) misses by far more than that: the check can fail
    assert abs(abs(m.estimate) - r16) > 10 * tol


def test_drive_gain_workspace_equals_floquet_on_with_gains(arm):
    """The prepared workspace (gain terms as time-dependent rank-one updates) against floquet()
    on ``with_gains`` (gains added to the samples, then interpolated): same scheme, same nodes;
    they differ only by the interpolation of products vs products of interpolants (spectral: ~1e-12)."""
    orbit, lin = arm
    g = GAINS
    ws = drive_gain_family(lin).workspace(256)
    a = np.sort_complex(ws.floquet(g).multipliers)
    b = np.sort_complex(floquet(lin.with_gains(g[0::2], g[1::2]), method="magnus2", n_steps=256,
                                error_estimate=False).multipliers)
    big = np.abs(b) > 1e-8
    assert np.max(np.abs(a[big] - b[big]) / np.abs(b[big])) < 1e-8
    # a wrong gain (kd2 doubled) is visible at that tolerance
    c = np.sort_complex(ws.floquet((g[0], g[1], g[2], 2 * g[3])).multipliers)
    assert np.max(np.abs(c[big] - b[big]) / np.abs(b[big])) > 1e-4


def test_objective_pickles_and_checks_input(arm):
    import pickle

    orbit, lin = arm
    obj = HillGainObjective(HillModelPlant(lin, orbit, harmonics=12))
    clone = pickle.loads(pickle.dumps(obj))
    assert clone(GAINS) == pytest.approx(obj(GAINS), rel=1e-12)
    with pytest.raises(ValueError, match="pairs"):
        obj((1.0, 2.0, 3.0))
