"""Model-file plants in worker processes: a model file's definition pickles as its path (loaded again,
lazily, once per process), so ``tune`` and ``chart`` of a model file run through the executor like the
reduced model; the runs are the same computations on the same arrays, so ``--workers 2`` gives what
``--workers 1`` gives."""
from __future__ import annotations

import concurrent.futures as cf
import json
import math
import multiprocessing
import pickle
from pathlib import Path

import pytest

from flexstab.cli import main as cli_main
from mbs_models.model_file import FileBuild, ModelDefinition, ModelFileError, load_model_file

HERE = Path(__file__).parent
DOUBLE = str(HERE / "models" / "double_pendulum.py")
TUNE = ["tune", "--model", DOUBLE, "--omega", "2pi", "--target", "0.5", "--kp-range", "0", "20", "--kd-range",
        "0", "5", "--max-evaluations", "60", "--json"]


def _measure(plant) -> float:
    return plant.spectral_measure([8.0, 1.0], [2.0, 0.5])


def not_a_model_build(mbs, omega):  # a module-level function: pickled by reference
    return []


def test_a_model_file_definition_pickles_as_its_path_and_loads_lazily(tmp_path):
    d = load_model_file(DOUBLE)
    back = pickle.loads(pickle.dumps(d))
    assert isinstance(back.build, FileBuild) and (back.name, back.source, back.options) == (d.name, d.source, d.options)
    assert back.build.function() is FileBuild(DOUBLE).function()  # loaded once per process
    assert list(back.build.__signature__.parameters)[:2] == ["mbs", "omega"]
    # lazily: a definition whose file is gone unpickles, and fails only when it is built
    gone = tmp_path / "gone.py"
    gone.write_text("def build(mbs, omega):\n    return []\n")
    blob = pickle.dumps(load_model_file(gone))
    gone.unlink()
    late = pickle.loads(blob)
    with pytest.raises(ModelFileError, match="not found"):
        late.build(None, 1.0)
    # a definition whose build is not its file's keeps its own function
    other = ModelDefinition(name="other", build=not_a_model_build, source=DOUBLE)
    assert pickle.loads(pickle.dumps(other)).build is not_a_model_build


def test_a_model_file_plant_evaluates_in_a_spawned_process_as_here():
    """A spawned worker imports nothing of this process: the model file's module is not there by name."""
    import os

    from flexstab.executor import worker_init
    from flexstab.threads import blas_threads
    from linearize.analysis import model_plant

    plant = model_plant(load_model_file(DOUBLE), 2 * math.pi)
    with cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init,
                                initargs=(os.getpid(), blas_threads())) as ex:
        there = ex.submit(_measure, plant).result()
    assert there == pytest.approx(_measure(plant), rel=1e-12)


def _tune(capsys, workers: int) -> dict:
    assert cli_main(TUNE + ["--workers", str(workers)]) == 0
    return json.loads(capsys.readouterr().out)


def test_tune_with_two_workers_gives_the_serial_result(capsys):
    serial, pooled = _tune(capsys, 1), _tune(capsys, 2)
    assert serial["converged"] and serial["evaluations"] == pooled["evaluations"]
    assert pooled["gains"] == serial["gains"]
    assert [it["responses"] for it in pooled["iterations"]] == [it["responses"] for it in serial["iterations"]]
    for key in ("tuned_response", "spectral_radius", "verified_spectral_radius"):
        assert pooled[key] == serial[key], key


@pytest.mark.slow  # ~4 s: two charts with their Taguchi paths
def test_chart_with_two_workers_gives_the_serial_chart(tmp_path, capsys):
    def chart(workers: int) -> dict:
        argv = ["chart", "--model", DOUBLE, "--omega", "2pi", "--target", "0.5", "--grid", "3", "--omega-points", "2",
                "--kp-range", "0", "20", "--kd-range", "0", "5", "--workers", str(workers),
                "--out", str(tmp_path / f"w{workers}"), "--json"]
        assert cli_main(argv) == 0
        return json.loads(capsys.readouterr().out)

    serial, pooled = chart(1), chart(2)
    assert pooled["gain_chart"]["n_computed"] == 9
    for key in ("gain_chart", "taguchi_path", "tuned", "omega_chart"):
        a, b = dict(serial[key]), dict(pooled[key])
        for x in (a, b):
            x.pop("n_loaded", None), x.pop("n_computed", None)
        assert b == a, key


def test_scheduler_address_is_checked_for_model_files(capsys):
    assert cli_main(TUNE + ["--scheduler", "tcp://nohost"]) == 2
    assert "has no port" in capsys.readouterr().err


@pytest.mark.slow  # starts a Dask cluster (~5 s)
def test_a_model_file_plant_tunes_on_a_dask_cluster_as_here():
    """A Dask worker is its own process (spawned by its nanny): the plant reaches it by value, the model file
    by its path.  Bitwise equality is not owed (the worker's BLAS thread count is the nanny's), the same
    experiments to rounding are."""
    distributed = pytest.importorskip("distributed")
    import numpy as np

    from flexstab.executor import make_executor
    from linearize.analysis import model_plant
    from taguchi.tuning import GainObjective, TuningConfig, taguchi_tune

    plant = model_plant(load_model_file(DOUBLE), 2 * math.pi)
    cfg = TuningConfig(target=0.5, ranges=((0.0, 20.0), (0.0, 5.0)) * 2, max_evaluations=30)
    serial = taguchi_tune(GainObjective(plant), cfg)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        with make_executor("dask", scheduler=cluster.scheduler_address) as ex:
            remote = taguchi_tune(GainObjective(plant), cfg, executor=ex)
    assert len(remote.iterations) == len(serial.iterations)
    for r_it, s_it in zip(remote.iterations, serial.iterations):
        np.testing.assert_allclose(r_it.responses, s_it.responses, rtol=1e-12, atol=0)
    assert remote.gains == pytest.approx(serial.gains, rel=1e-12)
