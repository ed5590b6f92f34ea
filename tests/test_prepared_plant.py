"""The prepared Exudyn tuning plant equals the plant it prepares.

Oracle: :class:`ExudynPlant` builds each gain pair's system by writing the gains
into the sampled ``K, C`` and interpolating (an independent path to ``P(t)``);
the prepared plant applies them as rank-one terms on cached samples.  Same
scheme and nodes, so the tuning response agrees to rounding (1e-9 allowed:
the balancing differs, the exponentials of ``h ||P|| ~ 1e3`` lose ~1e-12).
"""
from __future__ import annotations

import pickle

import pytest

from _link_oracle.along_orbit import linearize_along_orbit
from _link_oracle.link_floquet import ExudynPlant, PreparedExudynPlant
from _link_oracle.exudyn_link import ExudynLinkConfig
from _link_oracle.link_orbit import find_periodic_orbit


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


def _richardson_magnus2(plant: ExudynPlant, kp: float, kd: float) -> float:
    """Error estimate of ``plant.spectral_measure`` (magnus2, order 2, ``N`` steps): ``|r_2N - r_N| / (2^2 - 1)``."""
    import dataclasses

    fine = dataclasses.replace(plant, n_steps=2 * plant.n_steps).spectral_measure(kp, kd)
    return abs(fine - plant.spectral_measure(kp, kd)) / 3.0


def test_tuning_on_the_prepared_plant_equals_the_plant(plant2):
    """Taguchi tuning through the prepared plant (what ``tune``/``chart``/``study`` use on the Exudyn
    model) ends at the plain plant's gains, and its multiplier agrees within the Floquet error estimate."""
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    cfg = TuningConfig(target=0.3, kp_range=(0.0, 60.0), kd_range=(0.0, 40.0), max_evaluations=20)
    plain = taguchi_tune(GainObjective(plant2), cfg)
    fast = taguchi_tune(GainObjective(plant2.prepared()), cfg)
    est = _richardson_magnus2(plant2, plain.kp, plain.kd)
    assert 0 < est < 1e-2  # a meaningful estimate at 64 steps (it is the tolerance below)
    # the responses agree to ~1e-12 << est, so every Taguchi decision (and the tuned gains) is the same
    assert (fast.kp, fast.kd) == pytest.approx((plain.kp, plain.kd), rel=1e-12, abs=1e-12)
    assert abs(fast.spectral_radius - plain.spectral_radius) <= est
    # rejects a wrong plant: gains off by 5 % move the multiplier by more than the estimate
    wrong = plant2.prepared().spectral_measure(1.05 * plain.kp, plain.kd)
    assert abs(wrong - plain.spectral_radius) > est


def test_cli_exudyn_plant_is_the_single_link_model_file(monkeypatch):
    """``tune --model exudyn`` builds the model-file plant of ``single-link`` with the configured manipulator
    and elements (the generic path), never the hand-derived link's plant."""
    import linearize.analysis as analysis
    from flexstab import tuning as tune
    from mbs_models.parameters import ManipulatorParameters

    seen = {}

    class FakePlant:
        drives = ("hub",)

    def fake(definition, omega, **options):
        seen.update(name=definition.name, omega=omega, **options)
        return FakePlant()

    monkeypatch.setattr(analysis, "model_plant", fake)
    p = ManipulatorParameters(tip_mass=0.2)

    class Cfg:
        manipulator = p
        elements = 2
        damping = None

    assert isinstance(tune.build_plant("exudyn", Cfg(), 1.0, "auto"), FakePlant)
    assert seen["name"] == "single-link" and seen["elements"] == 2 and seen["params"] is p and seen["omega"] == 1.0
    # rejects a wrong route: the reduced model's name does not reach the model-file plant
    seen.clear()
    assert not isinstance(tune.build_plant("reduced", Cfg(), 1.0, "auto"), FakePlant) and not seen


def test_workspace_built_once_per_process(plant2):
    """Unpickled copies (one per process-pool task) share the process's workspace."""
    fast = plant2.prepared()
    ws = fast.workspace
    copy = pickle.loads(pickle.dumps(fast))
    assert copy.workspace is ws
    other = plant2.prepared()  # a different plant object builds its own
    assert other.workspace is not ws
