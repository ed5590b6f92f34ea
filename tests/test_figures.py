"""Every figure the package draws, audited on the drawn figure (tests/_figure_audit.py): no text outside the
figure (clipped titles and labels), no overlapping text boxes or legends over text (overprinted labels), no text
below 8 pt (unreadable footnotes), every axis that shows tick labels labelled, with a unit.

One test per defect class; each draws the real plotting function on data shaped like the study's.  The audit
itself is checked on figures built with the defect (it must be able to fail).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from _figure_audit import audit, capture  # noqa: E402


# ----------------------------------------------------------------------------- the audit can fail
def test_the_audit_finds_each_defect_class():
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1])
    ax.set_title("a title much too long for a figure four inches wide, cut at both sides by the figure edge")
    ax.set_xlabel("time")  # no unit
    ax.annotate("h=0.001", (0.5, 0.5), fontsize=6)
    ax.annotate("h=0.0005", (0.5, 0.5), fontsize=6)  # overprinted
    kinds = {d.split(":")[0] for d in audit(fig)}
    assert {"outside", "small", "overlap", "no unit", "no label"} <= kinds  # y-axis has ticks and no label
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(4, 3), layout="constrained")
    ax.plot([0, 1], [0, 1])
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("Im ρ")
    assert audit(fig) == []
    plt.close(fig)


# ----------------------------------------------------------------------------- clipped titles and labels
@pytest.mark.slow
@pytest.mark.parametrize("figure", [6, 8])
def test_transient_figures_have_titles_and_labels_inside_and_no_footnote(tmp_path, figure):
    """Fig. 6's y-label '(rad)' was cut at the left edge beside the tick labels -0.0075, Fig. 8's one-line title
    at both edges; a 7-8 pt footnote of internals sat in the image.  Now the explanation is the report's caption
    (the case summary's ``caption``) and the figure has no figure-level text but its title."""
    from flexstab.transients import make_transients

    with capture() as saved:
        doc = make_transients(tmp_path, quick=True, figures=(figure,))
    (rec,) = saved
    assert rec.defects == [], rec.defects
    case = doc["cases"][0]
    assert case["caption"].startswith("Homogeneous response") and "ρ₁ =" in case["caption"]


@pytest.mark.slow
def test_transient_figure_draws_no_footnote(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from flexstab.transients import make_transients

    texts = []
    original = Figure.savefig

    def savefig(self, *a, **k):
        texts.extend(t.get_text() for t in self.texts if t is not self._suptitle)
        return original(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", savefig)
    make_transients(tmp_path, quick=True, figures=(2,))
    assert texts == []  # no figure-level text besides the title (a footnote would be one)


def _omega_chart(controlled):
    from flexstab.charts import OmegaChart

    w = np.linspace(math.pi, 3 * math.pi, 9)
    return OmegaChart(w, 2.0 + 0.1 * np.arange(9), np.asarray(controlled, dtype=float), [7.061, 0.0], [2.207, 0.0])


def test_omega_chart_of_a_model_keeps_its_title_inside(tmp_path):
    """The title 'dominant |ρ| (drive modes / bending 1) against the frequency Ω of the fundamental motion' with a
    model's label ran past both edges ('...fundamental motio')."""
    from flexstab.charts import plot_omega_chart

    label = "model two_link (dominant labelled multiplier, Hill's method, 16 harmonics)"
    with capture() as saved:
        plot_omega_chart(_omega_chart(np.full(9, 0.3)), tmp_path / "w.png", label=label,
                         ylabel="dominant |ρ| (drive modes / bending 1)")
    assert saved[0].defects == [], saved[0].defects


def test_a_curve_on_the_unit_circle_is_drawn_over_the_unit_line(tmp_path, monkeypatch):
    """A curve at |ρ| = 1 (an undamped mode) was hidden under the dashed |ρ| = 1 line drawn after it."""
    from matplotlib.figure import Figure

    from flexstab.charts import plot_omega_chart

    seen = {}
    original = Figure.savefig

    def savefig(self, *a, **k):
        ax = self.axes[0]
        order = {ln.get_label(): (ln.get_zorder(), i) for i, ln in enumerate(ax.lines)}
        seen.update(order)
        return original(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", savefig)
    plot_omega_chart(_omega_chart(np.ones(9)), tmp_path / "w.png")
    ref = seen.pop("|ρ| = 1")
    assert seen and all(z > ref for z in seen.values()), (ref, seen)  # every curve above the reference line


def test_a_rigid_model_is_not_labelled_with_a_bending_mode():
    from flexstab.charts import dominant_ylabel

    assert dominant_ylabel(SimpleNamespace(slope_nodes=())) == "dominant |ρ| (drive modes)"
    assert "bending 1" in dominant_ylabel(SimpleNamespace(slope_nodes=((np.arange(4), np.zeros(4)),)))


# ----------------------------------------------------------------------------- overprinted step labels, small text
def _validation(levels_spread: float, alternative_at: float):
    """A duck-typed MultiplierValidation: three step levels converging to 0.29983 (ratio 4), an alternative
    prediction ``alternative_at`` away (the zoom's window is set by it, the levels crowd into a label's width)."""
    z = 0.29983 + 0j
    lv = np.array([[z - levels_spread], [z - levels_spread / 4], [z - levels_spread / 16]])
    pred = SimpleNamespace(multipliers=np.array([z + 1e-8]), all_multipliers=np.exp(2j * np.pi * np.arange(12) / 12),
                           name="exudyn linearisation about the periodic orbit", labels=["hub"])
    alts = [SimpleNamespace(multipliers=np.array([z + alternative_at]), name="reduced model", consistent=False),
            SimpleNamespace(multipliers=np.array([z + 1.02 * alternative_at]),
                            name="exudyn linearisation about the rigid reference", consistent=False)]
    return SimpleNamespace(prediction=pred, measured=np.array([z]), errors=np.array([5e-7]), alternatives=alts,
                           diverged=False, agrees=True, agrees_all=True, step_converged=True, levels=lv,
                           config=SimpleNamespace(steps=(2e-3, 1e-3, 5e-4)), info={})


@pytest.mark.slow
def test_multiplier_plane_has_no_overprinted_step_labels_and_no_small_text(tmp_path):
    """In validation_multipliers.png the step labels 'h=0.002', 'h=0.001', 'h=0.0005' (6 pt) were printed on top
    of each other, with 6-pt legends and tick labels."""
    from validation.plots import plot_multiplier_plane

    with capture() as saved:
        plot_multiplier_plane([_validation(1.6e-6, 9.3e-4)], tmp_path / "v.png", titles=["Ω = 2π: kp = 9.727"],
                              suptitle="Multipliers measured from nonlinear Exudyn runs vs predicted")
    assert saved[0].defects == [], saved[0].defects


# ----------------------------------------------------------------------------- mode figures: labels, units, scale
@pytest.mark.slow
def test_two_link_mode_and_pose_figures_have_labelled_axes_with_units_and_a_stated_scale(tmp_path):
    """The Floquet-mode figure had no axis labels, no units and no deformation scale."""
    import types

    from flexstab.arm_figures import plot_floquet_mode, plot_poses
    from flexstab.two_link import two_link_floquet

    tl = two_link_floquet(2 * math.pi)
    res = types.SimpleNamespace(floquet=tl.floquet, modes=tl.modes, orbit=tl.orbit, linearization=tl.linearization,
                                dominant_multiplier=tl.measure.dominant)
    with capture() as saved:
        mf = plot_floquet_mode(res, tmp_path / "mode.png", measured=(tl.measure.dominant, "Hill's method"))
        plot_poses(tl.orbit, tmp_path / "poses.png")
    for rec in saved:
        assert rec.defects == [], (rec.path, rec.defects)
    assert 0.05 < mf.scale_m < 0.1  # 8 % of the arm's reach (0.9 m)
    assert any(f"drawn as {mf.scale_m:.3g} m" in t for t in saved[0].texts)  # the scale is on the figure
    assert sum(t == "x (m)" for t in saved[0].texts) >= 1 and sum(t == "y (m)" for t in saved[0].texts) >= 1


def test_two_link_gain_slices_keep_the_colour_bar_label_clear_of_the_title(tmp_path):
    """The colour-bar label '|rho| dominant (drive / bending-1 modes; clipped at 1.5)' ran into the title."""
    from flexstab.two_link import TUNING_RANGES, GainSlices, plot_gain_slices

    def grid(r):
        return tuple(np.linspace(*r, 9))

    x = np.add.outer(np.linspace(0, 1, 9), np.linspace(0, 1, 9))
    sl = GainSlices(kp_grid=(grid(TUNING_RANGES[0]), grid(TUNING_RANGES[2])),
                    kd_grid=(grid(TUNING_RANGES[1]), grid(TUNING_RANGES[3])), shoulder=x, elbow=0.5 * x,
                    fixed=(15.0, 8.9, 7.1, 1.4))
    with capture() as saved:
        plot_gain_slices(sl, tmp_path / "slices.png")
    assert saved[0].defects == [], saved[0].defects


def test_nonlinear_validation_figure_labels_every_time_axis_it_numbers(tmp_path):
    """The three rows of the linear-vs-nonlinear figure each numbered their time axis but only the bottom one was
    labelled (and its legends were 7 pt)."""
    from _link_oracle.decay_plots import plot_validation_figure

    def run(rho, T=1.0, periods=6):
        t = np.linspace(0, periods * T, 600)
        hub, tip = 0.01 * rho ** (t / T) * np.cos(7 * t), 1e-4 * rho ** (t / T) * np.sin(30 * t)
        strob = 0.01 * rho ** np.arange(periods + 1)
        r = SimpleNamespace(period=T, times=t, hub_error=hub, tip_error=tip, stroboscopic=strob, kp=9.727, kd=6.484,
                            linear_range_left_at=None, diverged=False, diverged_at=None,
                            measured_ratio_per_period=rho, predicted_multiplier_exudyn=rho,
                            predicted_multiplier_reduced=1.01 * rho, periods=periods, prediction=None, exudyn=None)
        lp = SimpleNamespace(t=t, hub_error=1.01 * hub, tip_error=tip, envelope=lambda s: 0.01 * rho ** (s / T),
                             envelope_constant=0.01, modulus=rho, stroboscopic=strob)
        return r, lp

    (r1, l1), (r2, l2) = run(0.3), run(1.4)
    with capture() as saved:
        plot_validation_figure([r1, r2], tmp_path / "vf.png", predictions=[l1, l2],
                               titles=["Ω = 2π: kp = 9.727, kd = 6.484", "Ω = 2π: no control"], suptitle="runs")
    assert saved[0].defects == [], saved[0].defects
