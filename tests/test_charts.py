"""Stability charts: serial vs Dask equality, resumable sweeps, bad input."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flexstab.charts import ReducedRadius, check_grid, gain_chart
from flexstab.cli import main as cli_main
from flexstab.executor import SerialExecutor, make_executor
from mbs_models.reduced import ReducedModel
from stability import floquet


def test_gain_chart_points_equal_direct_floquet(tmp_path):
    kp, kd = np.array([0.0, 20.0, 40.0]), np.array([0.0, 10.0])
    chart = gain_chart(ReducedRadius(), 4 * math.pi, kp, kd, SerialExecutor(), tmp_path / "s.jsonl")
    for i, b in enumerate(kd):
        for j, a in enumerate(kp):
            ref = floquet(ReducedModel(4 * math.pi, a, b)).spectral_radius  # adaptive, independent steps
            # two adaptive runs, each within 10x its estimate <= rtol = 1e-9 (test_floquet_analytic):
            # <= 2e-8 apart; 1e-7 leaves 5x
            assert chart.radius[i, j] == pytest.approx(ref, rel=1e-7)


@pytest.mark.slow
def test_chart_on_dask_cluster_equals_serial(tmp_path):
    distributed = pytest.importorskip("distributed")
    kp, kd = np.linspace(0, 40, 4), np.linspace(0, 20, 3)
    serial = gain_chart(ReducedRadius(), 2 * math.pi, kp, kd, SerialExecutor(), tmp_path / "a.jsonl")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        with make_executor("dask", scheduler=cluster.scheduler_address) as ex:
            remote = gain_chart(ReducedRadius(), 2 * math.pi, kp, kd, ex, tmp_path / "b.jsonl")
    np.testing.assert_array_equal(remote.radius, serial.radius)


def test_interrupted_chart_resumes_without_losing_points(tmp_path):
    store = tmp_path / "c.jsonl"
    kp, kd = np.linspace(0, 40, 5), np.linspace(0, 20, 4)
    full = gain_chart(ReducedRadius(), 2 * math.pi, kp, kd, SerialExecutor(), tmp_path / "ref.jsonl")
    # simulate a killed sweep: keep the first 7 finished lines and half of the 8th
    lines = (tmp_path / "ref.jsonl").read_text().splitlines(keepends=True)
    store.write_text("".join(lines[:7]) + lines[7][: len(lines[7]) // 2])
    resumed = gain_chart(ReducedRadius(), 2 * math.pi, kp, kd, SerialExecutor(), store)
    assert resumed.n_loaded == 7 and resumed.n_computed == 20 - 7
    np.testing.assert_array_equal(resumed.radius, full.radius)


@pytest.mark.parametrize("lo, hi, n", [(5.0, 1.0, 5), (1.0, 1.0, 5), (0.0, 1.0, 1), (0.0, float("nan"), 5)])
def test_bad_grid(lo, hi, n):
    with pytest.raises(ValueError, match="kp"):
        check_grid(lo, hi, n, "kp")


@pytest.mark.slow
def test_cli_chart_writes_figures(tmp_path, capsys):
    rc = cli_main(["chart", "--grid", "5", "--omega-points", "5", "--out", str(tmp_path), "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    for f in d["figures"]:
        assert (tmp_path / f.split("/")[-1]).stat().st_size > 10_000
    assert d["taguchi_path"]


def test_cli_chart_unwritable_out(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = cli_main(["chart", "--grid", "3", "--out", str(blocker / "sub"), "--no-taguchi"])
    assert rc == 2
    assert "cannot create output folder" in capsys.readouterr().err


def test_exudyn_gain_chart_points_equal_exudyn_floquet(tmp_path):
    """Chart points of the Exudyn plant equal an independent exudyn_floquet call (own orbit, own steps)."""
    from flexstab.charts import PlantRadius
    from _link_oracle.link_floquet import exudyn_floquet, exudyn_plant

    plant = exudyn_plant(omega=2 * math.pi, elements=2, samples=16)
    chart = gain_chart(PlantRadius(plant, 2 * math.pi), 2 * math.pi, np.array([10.0, 37.1617]),
                       np.array([29.2410]), SerialExecutor(), tmp_path / "e.jsonl")
    ref = exudyn_floquet(omega=2 * math.pi, kp=37.1617, kd=29.2410, elements=2, samples=16, verify_orbit=False)
    # 256 vs 512 exponential-midpoint steps: the dominant damped multiplier agrees to ~1e-6
    assert chart.radius[0, 1] == pytest.approx(abs(ref.dominant_multiplier), rel=1e-5)
    with pytest.raises(ValueError, match="linearised at omega"):
        PlantRadius(plant, 2 * math.pi)({"omega": 4 * math.pi, "kp": 1.0, "kd": 1.0})


@pytest.mark.slow
def test_chart_names_identify_grid_and_ranges(tmp_path, capsys):
    """A coarse chart into the same folder must not overwrite the finer one."""
    base = ["chart", "--omega-points", "3", "--out", str(tmp_path), "--json", "--no-taguchi"]
    assert cli_main(base + ["--grid", "4"]) == 0
    first = json.loads(capsys.readouterr().out)
    before = {f: (tmp_path / f.split("/")[-1]).read_bytes() for f in first["figures"] + [first["json"]]}
    assert cli_main(base + ["--grid", "3", "--kp-range", "0", "10"]) == 0
    second = json.loads(capsys.readouterr().out)
    assert not set(second["figures"]) & set(first["figures"]) and second["json"] != first["json"]
    for f, data in before.items():
        assert (tmp_path / f.split("/")[-1]).read_bytes() == data
    assert second["inputs"]["grid"] == [3, 3] and second["inputs"]["kp_range"] == [0.0, 10.0]


def test_every_unit_contour_region_is_labelled():
    """Two separate |rho| < 1 islands: each boundary gets its own '|rho| = 1' label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from flexstab.charts import _label_every_segment

    x, y = np.meshgrid(np.linspace(0, 10, 60), np.linspace(0, 10, 60))
    r = 0.2 + np.minimum((x - 2) ** 2 + (y - 2) ** 2, (x - 8) ** 2 + (y - 8) ** 2) / 4  # two wells, |rho| = 1 at radius ~1.8
    fig, ax = plt.subplots()
    cs = ax.contour(x, y, r, levels=[1.0])
    assert _label_every_segment(ax, cs, "|ρ| = 1", "k") == 2
    assert sum(t.get_text() == "|ρ| = 1" for t in ax.texts) == 2
    plt.close(fig)


def test_gain_chart_colour_scale_is_centred_at_one(tmp_path):
    """Blue below |rho| = 1, red above, white at the boundary (diverging scale centred at log10|rho| = 0)."""
    import matplotlib.image as mpimg

    from flexstab.charts import GainChart, plot_gain_chart

    kp, kd = np.linspace(0, 1, 30), np.linspace(0, 1, 30)
    radius = np.tile(10.0 ** np.linspace(-2.0, 0.5, 30), (30, 1))  # |rho| from 0.01 (left) to 3.2 (right)
    png = plot_gain_chart(GainChart(2 * math.pi, kp, kd, radius, None, 0, 900), tmp_path / "g.png")
    img = mpimg.imread(png)
    h, w = img.shape[:2]
    row = img[h // 2]
    # the plot area spans roughly 9-78 % of the width (kp = 0 .. 1, |rho| = 1 at kp = 0.8):
    # sample near kp = 0.05 and kp = 0.97
    left, right = row[int(0.12 * w)], row[int(0.76 * w)]
    assert left[2] > left[0] + 0.2, f"stable region not blue: {left}"
    assert right[0] > right[2] + 0.2, f"unstable region not red: {right}"
