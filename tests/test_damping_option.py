"""``--damping`` / ``[study] damping``: one option for structural damping, checked where it lands (Exudyn's
ANCF parameters), and refused with one line where it does not apply."""
from __future__ import annotations

import math
from pathlib import Path

import exudyn as exu
import pytest

from flexstab.cli import main as cli_main
from flexstab.config import StudyConfig
from flexstab.options import resolve_model_definition
from mbs_models.damping import DampingSpec, material_damping_values, parse_damping
from mbs_models.parameters import ManipulatorParameters

HERE = Path(__file__).parent


def test_parse_forms():
    assert parse_damping("1e-5") == DampingSpec(material=1e-5)
    assert parse_damping("beta=2e-6,axial=3") == DampingSpec(material=2e-6, axial=3.0)
    assert parse_damping(None) == DampingSpec() and not DampingSpec().given
    assert parse_damping(1e-4).material == 1e-4
    for bad in ("-1", "nan", "beta", "stiff=1", "beta=1,beta2=3", "bending=-2"):
        with pytest.raises(ValueError):
            parse_damping(bad)


def test_kelvin_voigt_values_are_beta_times_stiffness():
    p = ManipulatorParameters()
    EI = p.youngs_modulus * p.second_moment  # Table 1: E I, E A by hand
    EA = p.youngs_modulus * p.area
    b, a = material_damping_values(1e-5, p.bending_stiffness, p.axial_stiffness, 0.5, 0.0)
    assert b == pytest.approx(0.5 + 1e-5 * EI, rel=1e-14) and a == pytest.approx(1e-5 * EA, rel=1e-14)
    assert b != pytest.approx(1e-5 * EI, rel=1e-6)  # the raw value is added, not replaced


def test_damping_reaches_exudyn_ancf_parameters():
    """The built-in single link with ``material_damping``: Exudyn's own element parameters hold beta EI, beta EA."""
    definition, options = resolve_model_definition("single-link", StudyConfig(), 2, material_damping=1e-5)
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    definition.with_options(**options).call_build(mbs, 2 * math.pi)
    p = ManipulatorParameters()
    found = []
    for i in range(mbs.systemData.NumberOfObjects()):
        if mbs.GetObject(i)["objectType"] == "ANCFCable2D":
            found.append((mbs.GetObjectParameter(i, "bendingDamping"), mbs.GetObjectParameter(i, "axialDamping")))
    assert len(found) == 2
    for b, a in found:
        assert b == pytest.approx(1e-5 * p.youngs_modulus * p.second_moment, rel=1e-12)
        assert a == pytest.approx(1e-5 * p.youngs_modulus * p.area, rel=1e-12)


def test_config_field():
    cfg = StudyConfig.from_mapping({"study": {"damping": 1e-5}})
    assert cfg.damping == DampingSpec(material=1e-5)
    with pytest.raises(ValueError):
        StudyConfig.from_mapping({"study": {"damping": "beta=-1"}})


@pytest.mark.parametrize("argv, words", [
    (["floquet", "--damping", "1e-5"], "applies to --model exudyn only"),
    (["tune", "--damping", "1e-5"], "not to --model reduced"),
    (["floquet", "--model", str(HERE / "models" / "double_pendulum.py"), "--damping", "1e-5"],
     "takes no material damping"),
    (["floquet", "--model", "single-link", "--damping", "x=1"], "expected BETA"),
])
def test_refused_with_one_line(argv, words, capsys):
    rc = cli_main(argv)
    err = capsys.readouterr().err
    assert rc == 2 and words in err and err.count("\n") == 1
