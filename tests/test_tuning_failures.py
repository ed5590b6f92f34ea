"""A run whose Floquet evaluation fails must not abort a Taguchi tuning.

Model-free: a known-optimum bowl (the oracle of test_taguchi_multi.py) that raises
``FloquetError`` / ``HillError`` at chosen gain points, on the four-factor ranges of the
two-link arm; the failing point is the L9 corner (20, 5, 10, 0) (kd2 = 0) where
``tune --model two-link`` died before 515b7e5.  Before the fix ``taguchi_tune`` re-raised
the error of that one run and the whole tuning ended with rc 1.
"""
from __future__ import annotations

import concurrent.futures as cf
import io
import json
import math

import numpy as np
import pytest

from flexstab.options import dump_json
from stability.floquet import FloquetError
from stability.hill import HillError
from taguchi.tuning import STATUS_FAILED, GainObjective, TuningConfig, taguchi_tune

RHO_D = 0.3
RANGES = ((0.0, 40.0), (0.0, 10.0), (0.0, 10.0), (0.0, 3.0))  # flexstab.two_link.TUNING_RANGES
CENTRE = np.array([13.0, 6.3, 3.7, 1.1])  # off the level grids
WEIGHTS = 1.0 / np.array([hi for _, hi in RANGES]) ** 2
BAD = (20.0, 5.0, 10.0, 0.0)  # run 5 of the first L9 experiment


def bowl(g) -> float:
    return RHO_D + float(np.sum(WEIGHTS * (np.asarray(g, dtype=float) - CENTRE) ** 2))


class FailingPlant:
    """``spectral_measure(kp, kd)`` of the bowl; raises ``HillError`` at :data:`BAD` (as the Hill plant did)."""

    def spectral_measure(self, kp, kd):
        g = tuple(v for pair in zip(kp, kd) for v in pair)
        if np.allclose(g, BAD):
            raise HillError("no main-mode multiplier confirmed by Hill's method")
        return bowl(g)


class FailAfter:
    """The bowl for the first ``n`` calls, then ``FloquetError`` at every call."""

    def __init__(self, n: int) -> None:
        self.n, self.calls = n, 0

    def __call__(self, g) -> float:
        self.calls += 1
        if self.calls > self.n:
            raise FloquetError("monodromy overflow")
        return bowl(g)


def _within(gains, tol) -> bool:
    # y - rho_d <= tol implies |g_i - c_i| <= sqrt(tol / a_i) (every term of the sum is <= the sum)
    return bool(np.all(np.abs(np.asarray(gains) - CENTRE) <= np.sqrt(tol / WEIGHTS)))


@pytest.mark.parametrize("executor", [None, "thread"])
def test_one_failing_run_is_recorded_and_the_tuning_goes_on(executor):
    cfg = TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=400)
    if executor:
        with cf.ThreadPoolExecutor(2) as ex:
            res = taguchi_tune(GainObjective(FailingPlant()), cfg, executor=ex)
    else:
        res = taguchi_tune(GainObjective(FailingPlant()), cfg)
    assert res.converged, res.message
    assert _within(res.gains, cfg.effective_tolerance)
    # the failure is reported, not hidden: which run, where, why
    assert len(res.failed_runs) == 1
    f = res.failed_runs[0]
    assert f["iteration"] == 0 and f["gains"] == list(BAD) and f["error"].startswith("HillError")
    assert "1 run(s) failed" in res.message
    it0 = res.iterations[0]
    k = it0.design.index(BAD)
    assert f["run"] == k and it0.failures == (f,)
    assert math.isnan(it0.responses[k])
    # scored as the worst run of its experiment (not as a good one: the S/N of a NaN would be NaN)
    others = [s for j, s in enumerate(it0.sn_ratios) if j != k]
    assert it0.sn_ratios[k] == min(others)
    # strict JSON: the failed response is null
    buf = io.StringIO()
    dump_json(res.to_dict(), buf)
    d = json.loads(buf.getvalue())
    assert d["iterations"][0]["responses"][k] is None and d["failed_runs"][0]["gains"] == list(BAD)


def test_every_run_failing_is_one_clear_error():
    cfg = TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=100)
    with pytest.raises(ArithmeticError, match=r"every run of the first Taguchi experiment failed \(9 runs\)") as e:
        taguchi_tune(FailAfter(0), cfg)
    assert "\n" not in str(e.value) and "FloquetError: monodromy overflow" in str(e.value)


def test_a_later_experiment_failing_entirely_stops_with_the_best_point():
    cfg = TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=400)
    obj = FailAfter(10)  # the first experiment (9 runs + confirmation) succeeds
    res = taguchi_tune(obj, cfg)
    assert res.status == STATUS_FAILED and not res.converged
    assert len(res.iterations) == 1 and len(res.failed_runs) == 9
    assert {f["iteration"] for f in res.failed_runs} == {1}
    # the best point is the best run of the first experiment (array runs and confirmation)
    it = res.iterations[0]
    ys = list(it.responses) + [it.confirmation_response]
    assert res.spectral_radius == min(ys, key=lambda y: abs(y - RHO_D))
    assert res.evaluations == 10 + 9


def test_tune_text_output_lists_the_failed_run(monkeypatch, capsys):
    """The text output of ``flexstab tune`` names each failed run (iteration, run, gains, error)."""
    import argparse

    import flexstab.commands.tune as tune_cmd

    res = taguchi_tune(GainObjective(FailingPlant()), TuningConfig(target=RHO_D, ranges=RANGES,
                                                                     max_evaluations=400))
    d = res.to_dict()
    d.update(omega=2 * math.pi, period=1.0, verified_spectral_radius=res.spectral_radius, verified_method="test")
    monkeypatch.setattr(tune_cmd, "tune_report", lambda args: d)
    assert tune_cmd.run(argparse.Namespace(robust=False, json=False)) == 0
    out = capsys.readouterr().out
    k = res.iterations[0].design.index(BAD)
    assert (f"failed run (iteration 0, run {k}) at kp1 = 20, kd1 = 5, kp2 = 10, kd2 = 0: HillError: "
            in out)


class FailAt:
    """The bowl, except ``FloquetError`` at the calls numbered in ``calls`` (1-based)."""

    def __init__(self, *calls: int) -> None:
        self.fail, self.calls = set(calls), 0

    def __call__(self, g) -> float:
        self.calls += 1
        if self.calls in self.fail:
            raise FloquetError("monodromy overflow")
        return bowl(g)


def test_a_failed_confirmation_run_is_recorded_and_the_tuning_goes_on():
    """The confirmation run failing (call n_runs + 1 = 10 with L9) used to end the tuning
    with ``ValueError: sn_target: observations must be finite``."""
    cfg = TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=400)
    res = taguchi_tune(FailAt(10), cfg)  # serial: call 10 is the first experiment's confirmation
    assert res.converged, res.message
    assert _within(res.gains, cfg.effective_tolerance)
    assert len(res.failed_runs) == 1
    f = res.failed_runs[0]
    assert f["iteration"] == 0 and f["run"] == "confirmation" and f["error"].startswith("FloquetError")
    it0 = res.iterations[0]
    assert list(it0.confirmation_gains) == f["gains"] and it0.failures == (f,)
    assert math.isnan(it0.confirmation_response) and math.isnan(it0.confirmation_sn)
    buf = io.StringIO()
    dump_json(res.to_dict(), buf)
    d = json.loads(buf.getvalue())
    conf = d["iterations"][0]["confirmation"]
    assert conf["sn"] is None and conf["spectral_radius"] is None


@pytest.mark.parametrize("error", [ZeroDivisionError, OverflowError])
def test_a_programming_error_in_the_objective_propagates(error):
    """``RUN_FAILURES`` caught the ``ArithmeticError`` base, so a ``ZeroDivisionError`` bug
    became a "failed run" and the tuning reported ``converged``."""

    def obj(g):
        if g[3] == 0.0:
            raise error("float division by zero")
        return bowl(g)

    with pytest.raises(error):
        taguchi_tune(obj, TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=400))


@pytest.mark.parametrize("error", ["FloquetError", "HillError", "ModalBasisError", "LinAlgError",
                                   "FloatingPointError"])
def test_each_numerical_failure_of_the_engines_is_a_failed_run(error):
    from stability.modal import ModalBasisError

    exc = {"FloquetError": FloquetError, "HillError": HillError, "ModalBasisError": ModalBasisError,
           "LinAlgError": np.linalg.LinAlgError, "FloatingPointError": FloatingPointError}[error]

    def obj(g):
        if np.allclose(g, BAD):
            raise exc("engine failed")
        return bowl(g)

    res = taguchi_tune(obj, TuningConfig(target=RHO_D, ranges=RANGES, max_evaluations=400))
    assert res.converged and len(res.failed_runs) == 1 and res.failed_runs[0]["error"].startswith(error)
