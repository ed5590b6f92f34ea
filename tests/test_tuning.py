"""Iterative Taguchi tuning of the PD gains (paper Sec. 4, Table 3, Eq. 34)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flexstab.cli import main as cli_main
from mbs_models.reduced import ReducedModel
from stability import floquet
from stability.reference import ReferenceOptions
from taguchi.direct import direct_tune
from taguchi.tuning import STATUS_BUDGET, STATUS_CONVERGED, GainObjective, TuningConfig, taguchi_tune

# Table 3 of the paper (p. 489): Omega / pi and the target rho_d.
TABLE3_CASES = [(2, 0.3), (4, 0.3), (6, 0.3), (8, 0.4)]


@pytest.mark.parametrize("k, rho_d", TABLE3_CASES)
def test_tuned_gains_reach_target_checked_by_independent_method(k, rho_d):
    model = ReducedModel(omega=k * math.pi)
    res = taguchi_tune(GainObjective(model), TuningConfig(target=rho_d))
    assert res.status == STATUS_CONVERGED and res.converged
    # independent check: the paper's own procedure (solve_ivp from the unit vectors),
    # not the tuner's number; acceptance is 1 % of rho_d
    # (rtol 1e-8 is ample for a 1 % check and keeps the stiff Radau runs short)
    check = floquet(
        model.with_gains(res.kp, res.kd),
        method="paper",
        error_estimate=False,
        reference=ReferenceOptions(rtol=1e-8, atol=1e-10),
    )
    assert abs(check.spectral_radius / rho_d - 1) < 1e-2
    assert res.kp >= 0 and res.kd >= 0
    # the history is complete: every iteration has its array, responses and S/N
    assert res.evaluations == sum(len(it.responses) + 1 for it in res.iterations)
    for it in res.iterations:
        assert len(it.design) == len(it.responses) == len(it.sn_ratios) == 9


def test_confirmation_run_uses_best_levels():
    model = ReducedModel(omega=4 * math.pi)
    res = taguchi_tune(GainObjective(model), TuningConfig(target=0.3, max_evaluations=30))
    it = res.iterations[0]
    assert it.confirmation_gains == (it.kp_levels[it.best_levels[0]], it.kd_levels[it.best_levels[1]])
    # best level = largest mean S/N in the response table
    means = it.analysis.response_table.level_means
    assert it.best_levels == tuple(max(range(3), key=lambda j: m[j]) for m in means)


def test_unreachable_target_reports_best_and_status():
    model = ReducedModel(omega=2 * math.pi)
    cfg = TuningConfig(target=1e-6, kp_range=(0.0, 1.0), kd_range=(0.0, 1.0), max_evaluations=40)
    res = taguchi_tune(GainObjective(model), cfg)
    assert res.status == STATUS_BUDGET and not res.converged
    assert res.evaluations <= 40
    assert "not reached" in res.message
    assert math.isfinite(res.spectral_radius) and res.spectral_radius > 1e-6


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"kp_range": (5.0, 5.0)}, "kp_range"),
        ({"kd_range": (10.0, 1.0)}, "kd_range"),
        ({"kp_range": (-1.0, 10.0)}, "kp_range"),
        ({"target": 0.0}, "target"),
        ({"target": -0.3}, "target"),
        ({"target": float("nan")}, "target"),
        ({"max_evaluations": 0}, "max_evaluations"),
    ],
)
def test_bad_tuning_config(kwargs, word):
    with pytest.raises(ValueError, match=word):
        TuningConfig(**kwargs)


def test_unknown_array_name():
    with pytest.raises(ValueError, match="unknown orthogonal array"):
        TuningConfig(array="L7").orthogonal_array()


def test_budget_smaller_than_one_experiment():
    with pytest.raises(ValueError, match="max_evaluations"):
        taguchi_tune(GainObjective(ReducedModel()), TuningConfig(max_evaluations=5))


def test_direct_optimiser_reaches_target():
    model = ReducedModel(omega=8 * math.pi)
    res = direct_tune(GainObjective(model), TuningConfig(target=0.4), "nelder-mead")
    assert res.converged
    check = floquet(model.with_gains(res.kp, res.kd))
    assert abs(check.spectral_radius - 0.4) <= 4e-4 * 1.001


@pytest.mark.slow
def test_dask_cluster_gives_the_serial_result():
    distributed = pytest.importorskip("distributed")
    from flexstab.executor import make_executor

    model = ReducedModel(omega=6 * math.pi)
    cfg = TuningConfig(target=0.3, max_evaluations=40)
    serial = taguchi_tune(GainObjective(model), cfg)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        with make_executor("dask", scheduler=cluster.scheduler_address) as ex:
            remote = taguchi_tune(GainObjective(model), cfg, executor=ex)
    # The same experiments in the same order.  Bitwise equality is not owed: a Dask
    # worker runs BLAS with its own thread count (the nanny sets OMP/OPENBLAS threads),
    # so reductions are reordered; each response is a product of ~100 small matrix
    # exponentials, whose rounding is ~N n eps ||Phi|| <= 1e-12 relative here.
    assert len(remote.iterations) == len(serial.iterations)
    for r_it, s_it in zip(remote.iterations, serial.iterations):
        np.testing.assert_allclose(r_it.responses, s_it.responses, rtol=1e-12, atol=0)
    assert remote.kp == pytest.approx(serial.kp, rel=1e-12)
    assert remote.kd == pytest.approx(serial.kd, rel=1e-12)


def test_cli_tune_json(capsys):
    rc = cli_main(["tune", "--omega", "8pi", "--target", "0.4", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0
    for key in ("omega", "target", "kp", "kd", "spectral_radius", "evaluations", "iterations"):
        assert key in d
    assert d["omega"] == pytest.approx(8 * math.pi)
    assert abs(d["verified_spectral_radius"] - 0.4) <= 4e-4 * 1.001


@pytest.mark.parametrize(
    "argv",
    [
        ["tune", "--kp-range", "5", "1"],
        ["tune", "--kd-range", "0", "0"],
        ["tune", "--target", "0"],
        ["tune", "--array", "L7"],
        ["tune", "--kp-range", "-5", "10"],
    ],
)
def test_cli_tune_bad_input_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        rc = cli_main(argv)
        raise SystemExit(rc)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and "Traceback" not in "\n".join(err)
