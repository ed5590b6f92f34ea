"""The stage runner and the provenance records, on stand-in stages (no numerics).

Rules (``flexstab.stages``): a stage whose record has the inputs hash of this run and whose files are
the ones it wrote is reused, not run; anything else runs it.  Each test counts the calls of the stage
function, so a runner that reuses a stage it must run (or runs one it may reuse) fails it.
"""
from __future__ import annotations

import json
import sys

import pytest

from flexstab import provenance as pv
from flexstab.stages import Stage, StageOutput, StageRunner


class Counting:
    """A stage function writing ``<name>.json`` (and optionally failing a check, or raising)."""

    def __init__(self, out, name, value=1.0, check=None, exc=None):
        self.out, self.name, self.value, self.check, self.exc, self.calls = out, name, value, check, exc, 0

    def __call__(self):
        self.calls += 1
        if self.exc is not None:
            raise self.exc
        (self.out / f"{self.name}.json").write_text(json.dumps({"value": self.value}))
        return StageOutput(json=f"{self.name}.json", blocks=[], check_failures=(self.check,) if self.check else ())


def run_once(out, fn, inputs, name="a", **kw):
    runner = StageRunner(out, {"what": "test"}, order=(name,), **kw)
    return runner, runner.run_stage(Stage(name, fn, inputs, "A"))


def test_unchanged_inputs_reuse_and_changed_inputs_rerun(tmp_path):
    fn = Counting(tmp_path, "a")
    _, first = run_once(tmp_path, fn, {"x": 1})
    assert first.status == "computed" and not first.reused and fn.calls == 1
    _, again = run_once(tmp_path, fn, {"x": 1})
    assert again.status == "reused" and again.reused and fn.calls == 1  # not run again
    assert again.inputs_hash == first.inputs_hash
    _, changed = run_once(tmp_path, fn, {"x": 2})
    assert changed.status == "computed" and fn.calls == 2 and changed.inputs_hash != first.inputs_hash
    _, no_resume = run_once(tmp_path, fn, {"x": 2}, resume=False)
    assert no_resume.status == "computed" and fn.calls == 3


def test_a_changed_or_missing_output_reruns_the_stage(tmp_path):
    fn = Counting(tmp_path, "a")
    run_once(tmp_path, fn, {"x": 1})
    (tmp_path / "a.json").write_text("{}")  # edited after the stage wrote it
    _, r = run_once(tmp_path, fn, {"x": 1})
    assert r.status == "computed" and fn.calls == 2
    (tmp_path / "a.json").unlink()
    _, r = run_once(tmp_path, fn, {"x": 1})
    assert r.status == "computed" and fn.calls == 3


def test_record_fields_must_match_to_reuse(tmp_path):
    fn = Counting(tmp_path, "a")
    run_once(tmp_path, fn, {"x": 1}, record_fields={"config_hash": "c1"})
    _, r = run_once(tmp_path, fn, {"x": 1}, record_fields={"config_hash": "c2"})
    assert r.status == "computed" and fn.calls == 2


def test_failed_stage_has_no_record_and_runs_again(tmp_path):
    bad = Counting(tmp_path, "a", exc=RuntimeError("no orbit\n  at all"))
    runner, r = run_once(tmp_path, bad, {"x": 1}, one_line_errors=True)
    assert r.status == "failed" and r.error == "RuntimeError: no orbit at all" and r.record is None
    assert not pv.record_path(tmp_path, "a").exists()
    assert runner.manifest["stages"]["a"]["status"] == "failed"
    good = Counting(tmp_path, "a")
    _, r = run_once(tmp_path, good, {"x": 1})
    assert r.status == "computed" and good.calls == 1


def test_a_stage_naming_a_file_it_did_not_write_fails(tmp_path):
    def stage():
        (tmp_path / "a.json").write_text("{}")
        return StageOutput(json="a.json", blocks=[], files=("missing.png",))

    _, r = run_once(tmp_path, stage, {})
    assert r.status == "failed" and "missing.png" in r.error


def test_reraised_exceptions_pass_through(tmp_path):
    with pytest.raises(KeyError):
        run_once(tmp_path, Counting(tmp_path, "a", exc=KeyError("bad file")), {}, reraise=(KeyError,))


def test_failed_checks_survive_reuse(tmp_path):
    fn = Counting(tmp_path, "a", check="not converged")
    _, r = run_once(tmp_path, fn, {"x": 1})
    assert r.status == "check failed" and r.summary()["error"] == "not converged"
    _, r = run_once(tmp_path, fn, {"x": 1})
    assert r.reused and fn.calls == 1 and r.status == "check failed" and r.summary()["error"] == "not converged"
    assert r.manifest_entry()["status"] == "reused"


def test_inputs_evaluated_when_the_stage_starts(tmp_path):
    """A later stage's inputs may depend on what an earlier one wrote (e.g. tuned gains)."""
    first = Counting(tmp_path, "a", value=3.0)
    second = Counting(tmp_path, "b")
    runner = StageRunner(tmp_path, {}, order=("a", "b"))

    def gains():
        return {"gains": json.loads((tmp_path / "a.json").read_text())["value"]}

    runner.run([Stage("a", first, {"x": 1}), Stage("b", second, gains)])
    assert runner.runs["b"].record["inputs"] == {"gains": 3.0}
    first.value = 4.0  # the earlier stage now produces other gains: the later one must run again
    runner = StageRunner(tmp_path, {}, order=("a", "b"), resume=True)
    runner.run([Stage("a", first, {"x": 2}), Stage("b", second, gains)])
    assert runner.runs["b"].status == "computed" and second.calls == 2


def test_interrupted_run_says_so_in_the_manifest(tmp_path):
    fn = Counting(tmp_path, "a")
    stop = Counting(tmp_path, "b", exc=KeyboardInterrupt())
    runner = StageRunner(tmp_path, {"what": "test"}, order=("a", "b"))
    with pytest.raises(KeyboardInterrupt):
        runner.run([Stage("a", fn, {}), Stage("b", stop, {})])
    m = pv.read_manifest(tmp_path)
    assert m["status"] == "interrupted" and m["stages"]["a"]["status"] == "computed" and "b" not in m["stages"]
    runner = StageRunner(tmp_path, {"what": "test"}, order=("a", "b"))
    runner.run([Stage("a", fn, {}), Stage("b", Counting(tmp_path, "b"), {})])
    runner.finish(elapsed=0.0)
    m = pv.read_manifest(tmp_path)
    assert m["status"] == "finished" and m["stages"]["a"]["status"] == "reused" and fn.calls == 1


def test_code_hash_follows_the_source(tmp_path, monkeypatch):
    pkg = tmp_path / "toy_pkg_for_hash"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "m.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("toy_pkg_for_hash", None)
    h1 = pv.code_hash(("toy_pkg_for_hash",))
    assert pv.code_hash(("toy_pkg_for_hash",)) == h1
    (pkg / "m.py").write_text("X = 2\n")
    assert pv.code_hash(("toy_pkg_for_hash",)) != h1


def test_inputs_hash_ignores_key_order_only():
    assert pv.inputs_hash({"a": 1, "b": [1, 2]}) == pv.inputs_hash({"b": [1, 2], "a": 1})
    assert pv.inputs_hash({"a": 1, "b": [1, 2]}) != pv.inputs_hash({"a": 1, "b": [2, 1]})
    assert pv.inputs_hash({"a": 1.0}) != pv.inputs_hash({"a": 1.0 + 1e-15})
