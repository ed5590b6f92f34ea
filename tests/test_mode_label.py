"""``linearize.analysis.ModeLabel``: frozen, and serialised to the keys of the JSON contract."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from linearize.analysis import ModeLabel

DOUBLE = str(Path(__file__).parent / "models" / "double_pendulum.py")
#: The per-multiplier keys of ``modes`` in the JSON of ``floquet --model`` (docs/cli.md, the floquet table).
CONTRACT_KEYS = {"modulus", "mode", "group", "frequency_hz", "mac", "shares", "drive_shares", "undamped"}


@pytest.fixture(scope="module")
def result():
    from linearize.analysis import analyze

    return analyze(DOUBLE, 2 * math.pi, kp=[5.0, 2.0], kd=[0.5, 0.2], samples=16)


def test_labels_are_frozen_mode_labels(result):
    assert result.modes and all(isinstance(m, ModeLabel) for m in result.modes)
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.modes[0].mode = "hub"


def test_to_dict_has_the_contract_keys_and_the_attribute_values(result):
    for m in result.modes:
        d = m.to_dict()
        assert set(d) == CONTRACT_KEYS
        assert list(d) == [f.name for f in dataclasses.fields(ModeLabel)]
        assert all(d[k] == getattr(m, k) for k in d)
    json.dumps(result.summary())  # the summary serialises (a ModeLabel itself would not)
    with pytest.raises(TypeError):
        json.dumps(result.modes[0])
    assert result.summary()["modes"] == [m.to_dict() for m in result.modes]


def test_to_dict_copies_the_shares():
    m = ModeLabel(modulus=0.5, mode="bending 1", drive_shares={"hub": 0.25}, group="link", frequency_hz=3.0,
                  mac=0.9, shares={"link": 1.0}, undamped=False)
    d = m.to_dict()
    d["drive_shares"]["hub"] = 1.0
    assert m.drive_shares == {"hub": 0.25}
