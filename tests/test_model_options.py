"""One ``--model`` rule for every command (``flexstab.options.resolve_model_definition``).

Regression: ``flexstab floquet --model two-link`` built the two-link arm with the single link's
configured ``elements`` (8) instead of the two-link model's own default mesh (2 elements).
"""
from __future__ import annotations

import json

import pytest

import linearize.analysis
from flexstab.cli import main as cli_main
from flexstab.config import StudyConfig
from flexstab.options import resolve_model_definition
from mbs_models.builtin.two_link import DEFAULT_ELEMENTS


class _Captured(Exception):
    """Raised by the stubs below after recording what the command asked for (no Exudyn run)."""


def _capture(monkeypatch, name):
    seen = {}

    def stub(model, omega, **kwargs):
        seen.update(kwargs, model=model, omega=omega)
        raise _Captured

    monkeypatch.setattr(linearize.analysis, name, stub)
    return seen


@pytest.mark.parametrize("argv, stub", [
    (["floquet", "--model", "two-link"], "analyze"),
    (["tune", "--model", "two-link"], "model_plant"),
])
def test_two_link_keeps_its_own_mesh(monkeypatch, argv, stub):
    """The configured ``elements`` (8, the single link's) must not reach the two-link's build."""
    seen = _capture(monkeypatch, stub)
    with pytest.raises(_Captured):
        cli_main(argv)
    assert seen["model"].name == "two-link"
    assert seen.get("elements", DEFAULT_ELEMENTS) == DEFAULT_ELEMENTS != StudyConfig().elements


@pytest.mark.parametrize("argv, stub", [
    (["floquet", "--model", "two-link", "--elements", "3"], "analyze"),
    (["tune", "--model", "two-link", "--elements", "3"], "model_plant"),
])
def test_elements_option_reaches_the_built_in(monkeypatch, argv, stub):
    seen = _capture(monkeypatch, stub)
    with pytest.raises(_Captured):
        cli_main(argv)
    assert seen["elements"] == 3


def test_single_link_takes_the_configured_link(tmp_path):
    cfg = StudyConfig(elements=5)
    definition, options = resolve_model_definition("single-link", cfg, None)
    assert definition.name == "single-link" and options["elements"] == 5 and options["params"] == cfg.manipulator
    assert resolve_model_definition("single-link", cfg, 3)[1]["elements"] == 3


def test_model_file_rejects_built_in_options(tmp_path, capsys):
    f = tmp_path / "m.py"
    f.write_text("def build(mbs, omega):\n    return []\n")
    assert resolve_model_definition(str(f), StudyConfig(), None)[1] == {}
    rc = cli_main(["floquet", "--model", str(f), "--elements", "3"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "--elements" in err and "built-in models only" in err
    with pytest.raises(ValueError, match="unknown model 'nope'"):
        resolve_model_definition("nope", StudyConfig(), None)
