"""The prepared Exudyn tuning plant (issue 12.2) equals the plant it prepares.

Oracle: :class:`ExudynPlant` builds each gain pair's system by writing the gains
into the sampled ``K, C`` and interpolating (an independent path to ``P(t)``);
the prepared plant applies them as rank-one terms on cached samples.  Same
scheme and nodes, so the tuning response agrees to rounding (1e-9 allowed:
the balancing differs, the exponentials of ``h ||P|| ~ 1e3`` lose ~1e-12).
"""
from __future__ import annotations

import pickle

import pytest

from linearize import linearize_along_orbit
from mbs_models.exudyn_floquet import ExudynPlant, PreparedExudynPlant
from mbs_models.exudyn_link import ExudynLinkConfig
from mbs_models.orbit import find_periodic_orbit


@pytest.fixture(scope="module")
def plant2():
    orbit = find_periodic_orbit(config=ExudynLinkConfig(elements=2, drive="free"), samples=16, verify=False)
    return ExudynPlant(linearize_along_orbit(orbit, hub="free", kp=0.0, kd=0.0), n_steps=64)


def test_prepared_plant_equals_the_plant(plant2):
    fast = PreparedExudynPlant(plant2)
    for kp, kd in [(0.0, 0.0), (37.1617, 29.2410), (10.0, 5.0)]:
        assert fast.spectral_measure(kp, kd) == pytest.approx(plant2.spectral_measure(kp, kd), rel=1e-9)
    # a wrong gain would be seen: the response moves by far more than the tolerance
    assert abs(fast.spectral_measure(37.1617, 29.2410) / plant2.spectral_measure(37.0, 29.2410) - 1) > 1e-6
    # picklable for process pools (the workspace is rebuilt there)
    again = pickle.loads(pickle.dumps(fast))
    assert again.spectral_measure(10.0, 5.0) == pytest.approx(plant2.spectral_measure(10.0, 5.0), rel=1e-9)
    with pytest.raises(ValueError, match="kp"):
        fast.floquet(-1.0, 0.0)
