"""Figs. 2-9 of the paper: transient response of the linearised manipulator (library side).

From ``x(0) = [0, 0, pi/4, 0]`` (paper Eqs. 26 and 35) the linearised reduced
model (the paper's constants for the built-in link) is integrated for the four Table 2 cases without
control (Omega = 2pi, 4pi, 6pi, 8pi -> ``fig2`` .. ``fig5``) and with the PD
gains printed in Table 3 (``fig6`` .. ``fig9``).  Each PNG has four panels:
the hub-angle perturbation ``y1`` (rad) and the tip deflection ``X1 y2`` (m)
on linear axes (top) and ``|y1|``, ``|X1 y2|`` on log axes (bottom), with the
envelope ``+-C rho1^(t/T)`` of the dominant Floquet multiplier ``rho1``.

Response: by default the *homogeneous* one (Eq. 25 without, Eq. 33 with
control), whose growth is governed by the multipliers alone.  With
``--with-forcing`` the figures show the response including ``h_L`` (Eq. 24,
via ``f(t)`` of Eq. 5) and the homogeneous one in grey; the caption says which.

Envelope constant ``C``: ``max |y(t)| rho1^(-t/T)`` over the *last* simulated
period.  The dominant Floquet solution is ``p1(t) rho1^(t/T)`` with a
T-periodic ``p1``; once the other solutions have died out relative to it
(like ``|rho2/rho1|^k``), ``|y| rho1^(-t/T)`` is periodic and its maximum is
the height at which the envelope touches one peak per period.  (``y(0) = 0``
here, so ``t = 0`` cannot set ``C``; the first period is still dominated by
the other solutions.)

Measured growth, written to ``transients.json`` beside ``rho1``: the ratios
``||x((k+1)T)|| / ||x(kT)||`` of the homogeneous state, which tend to
``|rho1|`` like ``|rho2/rho1|^k`` (power method), their least-squares version
``exp(slope of ln||x(kT)|| against k)`` over the second half of the periods, and the ratios of the peak
``||x||`` over consecutive periods.  The uncontrolled cases are integrated over
``--measure-periods`` periods (more than the three plotted) so that the
ratios converge.

Entry point: :func:`make_transients`; ``scripts/transients.py`` is its
command-line wrapper.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mbs_models.parameters import ManipulatorParameters  # noqa: E402
from mbs_models.reduced import ReducedModel  # noqa: E402
from stability.engines import floquet  # noqa: E402
from stability.response import (  # noqa: E402
    LinearResponse,
    envelope_constant,
    linear_response,
    per_period_growth,
    points_per_period,
)

__all__ = ["Case", "CASES", "Settings", "FULL", "QUICK", "QUICK_FIGURES", "X0", "run_case", "plot_case", "make_transients"]

#: Initial state of paper Eqs. (26) and (35): ``[y1, y2, y1', y2']``.
X0 = (0.0, 0.0, 0.25 * math.pi, 0.0)

#: Table 2 (dominant modulus as printed) and Table 3 (printed gains, target).
TABLE2_RHO1 = {2: 13.7797, 4: 3.7506, 6: 2.4175, 8: 1.9396}
TABLE3 = {  # Omega/pi: (kp, kd, rho_d)
    2: (37.1617, 29.2410, 0.3),
    4: (28.7617, 11.7501, 0.3),
    6: (22.2666, 6.7208, 0.3),
    8: (23.0147, 6.8628, 0.4),
}


@dataclass(frozen=True)
class Case:
    """One transient case: a figure of the paper (``figure`` set) or a case of the user's study.

    ``printed`` is the paper's printed |rho1| of the case (Table 2 or 3), ``None`` when the case
    is not one of the paper's (another Omega, other gains or another manipulator).
    """

    figure: Optional[int]
    omega_over_pi: float
    kp: float = 0.0
    kd: float = 0.0
    printed: Optional[float] = None
    gains_source: str = ""

    @property
    def controlled(self) -> bool:
        return self.kp > 0 or self.kd > 0

    @property
    def name(self) -> str:
        kind = "controlled" if self.controlled else "uncontrolled"
        w = f"{self.omega_over_pi:.6g}".replace(".", "p")
        if self.figure is not None:
            return f"fig{self.figure}_{kind}_omega{w}pi"
        gains = f"_kp{self.kp:.6g}_kd{self.kd:.6g}".replace(".", "p") if self.controlled else ""
        return f"transient_{kind}_omega{w}pi{gains}"

    @property
    def printed_rho1(self) -> Optional[float]:
        return self.printed


def paper_case_pair(k: int) -> tuple[Case, Case]:
    """Figs. ``k/2 + 1`` (no control) and ``k/2 + 5`` (printed Table 3 gains) of the paper, Omega = k pi."""
    kp, kd, rho_d = TABLE3[k]
    return (Case(k // 2 + 1, k, printed=TABLE2_RHO1[k], gains_source="no control (Table 2)"),
            Case(k // 2 + 5, k, kp, kd, printed=rho_d, gains_source="paper Table 3 gains"))


CASES = tuple(paper_case_pair(k)[0] for k in (2, 4, 6, 8)) + tuple(paper_case_pair(k)[1] for k in (2, 4, 6, 8))
QUICK_FIGURES = (5, 9)


@dataclass(frozen=True)
class Settings:
    """Horizons and sampling (periods plotted / integrated, samples per cycle)."""

    plot_uncontrolled: int = 3
    plot_controlled: int = 5
    measure_uncontrolled: int = 8
    measure_controlled: int = 5
    per_cycle: int = 24
    min_points: int = 400


FULL = Settings()
QUICK = Settings(plot_uncontrolled=2, plot_controlled=4, measure_uncontrolled=3, measure_controlled=4,
                 per_cycle=8, min_points=100)


def run_case(case: Case, settings: Settings, with_forcing: bool,
             params: Optional[ManipulatorParameters] = None) -> dict:
    """Floquet analysis, homogeneous (and optionally forced) response of one case."""
    model = ReducedModel(omega=case.omega_over_pi * math.pi, kp=case.kp, kd=case.kd,
                         params=params or ManipulatorParameters())
    T = model.period
    fl = floquet(model, method="magnus").detail
    rho1 = complex(fl.multipliers[0])
    n_plot = settings.plot_controlled if case.controlled else settings.plot_uncontrolled
    n_meas = max(n_plot, settings.measure_controlled if case.controlled else settings.measure_uncontrolled)
    npp = points_per_period(model, T, per_cycle=settings.per_cycle, minimum=settings.min_points)
    hom = linear_response(model, X0, n_meas * T, n_per_period=npp)
    forced: Optional[LinearResponse] = None
    if with_forcing:
        forced = linear_response(model, X0, n_plot * T, forcing=model.forcing_first_order, n_per_period=npp)
    skip = max(1, n_meas // 2)
    growth = per_period_growth(hom, skip=skip)
    X1 = model.mode.X1
    last = (n_meas - 1) * T
    C_y1 = envelope_constant(hom.t, hom.x[:, 0], abs(rho1), T, t_from=last)
    C_tip = envelope_constant(hom.t, X1 * hom.x[:, 1], abs(rho1), T, t_from=last)
    moduli = fl.moduli
    return {
        "case": case,
        "model": model,
        "floquet": fl,
        "homogeneous": hom,
        "forced": forced,
        "growth": growth,
        "n_plot": n_plot,
        "C_y1": C_y1,
        "C_tip": C_tip,
        "summary": {
            "figure": case.figure,
            "name": case.name,
            "controlled": case.controlled,
            "omega": model.omega,
            "omega_over_pi": case.omega_over_pi,
            "period": T,
            "kp": case.kp,
            "constants": model.mode.source,
            "kd": case.kd,
            "gains_source": case.gains_source,
            "dominant_multiplier": [rho1.real, rho1.imag],
            "spectral_radius": float(fl.spectral_radius),
            "printed_spectral_radius": case.printed_rho1,
            "moduli": [float(m) for m in moduli],
            "subdominant_over_dominant": float(moduli[1] / moduli[0]),
            "subdominant_reliable": bool(fl.reliable_digits[1] > 0),
            "noise_floor": float(fl.noise_floor),
            "periods_plotted": n_plot,
            "periods_measured": n_meas,
            "ratios_state_norm": [float(r) for r in growth.ratios],
            "last_ratio": growth.last_ratio,
            "last_ratio_relative_error": growth.last_ratio / fl.spectral_radius - 1.0,
            "fit_from_period": skip,
            "fitted_ratio": growth.fitted,
            "fitted_ratio_relative_error": growth.fitted / fl.spectral_radius - 1.0,
            "peak_ratios_after_first_period": [float(r) for r in growth.peak_ratios],
            "envelope_C_y1_rad": C_y1,
            "envelope_C_tip_m": C_tip,
            "envelope_fit_window": [last, n_meas * T],
            "max_abs_y1_plotted_rad": float(np.max(np.abs(hom.x[: n_plot * npp + 1, 0]))),
            "max_abs_tip_plotted_m": float(np.max(np.abs(X1 * hom.x[: n_plot * npp + 1, 1]))),
            "integrator": hom.method,
            "rtol": hom.rtol,
            "atol": hom.atol,
            "nfev": hom.nfev,
            "points_per_period": npp,
            "figure_file": f"{case.name}{'_forced' if with_forcing else ''}.png",
        },
    }


def _ratio_text(s: dict) -> str:
    """|rho2/rho1|, or an upper bound when rho2 is below the rounding floor of the product (not a result)."""
    if s["subdominant_reliable"]:
        return f"|ρ₂/ρ₁| = {s['subdominant_over_dominant']:.3g}"
    return f"|ρ₂/ρ₁| < {max(s['noise_floor'] / s['spectral_radius'], 1e-16):.0e} (ρ₂ below the rounding floor)"


def _caption(case: Case, res: dict, with_forcing: bool) -> str:
    """The report's caption of the figure of ``case`` (what is drawn, the envelope, the measured growth)."""
    s = res["summary"]
    eq = "Eq. 33" if case.controlled else "Eq. 25"
    x0 = f"x(0) = [0, 0, π/4, 0] (Eq. {35 if case.controlled else 26})"
    if with_forcing:
        tail = ("the forced one tends to the T-periodic forced solution, not to 0"
                if s["spectral_radius"] < 1 else "the forced one grows at the same rate")
        what = (f"Response including h_L (Eq. {31 if case.controlled else 20} with Eq. 24, coloured) and the "
                f"homogeneous response ({eq}, grey) of the linearised reduced model from {x0}; {tail}.")
    else:
        what = f"Homogeneous response ({eq}, h_L omitted) of the linearised reduced model from {x0}."
    printed = "" if case.printed_rho1 is None else f", printed {case.printed_rho1}"
    n_plot, n_meas = s["periods_plotted"], s["periods_measured"]
    window = ("the last plotted period" if n_meas == n_plot
              else f"period {n_meas} of {n_meas} integrated (the first {n_plot} are plotted)")
    k_text = (f"k = {n_meas - 1}, the last plotted period" if n_meas == n_plot
              else f"k = {n_meas - 1}, integrated beyond the {n_plot} plotted periods")
    return (
        f"{what} Top: hub-angle perturbation y₁ and tip deflection X₁y₂; bottom: their magnitudes on a log scale; "
        f"thin vertical lines mark the periods. Dashed: the envelope ±C·ρ₁^(t/T) of the dominant Floquet multiplier "
        f"ρ₁ = {s['dominant_multiplier'][0]:.6g}{printed}, with C fitted over {window}. Measured growth per period "
        f"‖x((k+1)T)‖/‖x(kT)‖ = {s['last_ratio']:.6g} at {k_text} "
        f"({_signed_percent(s['last_ratio_relative_error'])} relative to ρ₁; it tends to ρ₁ like |ρ₂/ρ₁|^k, "
        f"{_ratio_text(s)})."
    )


def _signed_percent(x: float) -> str:
    from flexstab.report import relative

    return relative(x)


def plot_case(res: dict, path: Path, with_forcing: bool) -> None:
    """Write the four-panel figure of one case to ``path``."""
    case: Case = res["case"]
    hom: LinearResponse = res["homogeneous"]
    forced: Optional[LinearResponse] = res["forced"]
    T = hom.period
    X1 = res["model"].mode.X1
    rho = res["summary"]["spectral_radius"]
    n_plot = res["n_plot"]
    m = n_plot * hom.n_per_period + 1
    t = hom.t[:m]
    # (title, quantity, unit, data, envelope constant, forced data)
    series = [
        ("hub-angle perturbation", "$y_1$", "rad", hom.x[:m, 0], res["C_y1"],
         None if forced is None else forced.x[:, 0]),
        ("tip deflection", "$X_1 y_2$", "m", X1 * hom.x[:m, 1], res["C_tip"],
         None if forced is None else X1 * forced.x[:, 1]),
    ]
    env_t = np.linspace(0.0, t[-1], 400)
    # constrained layout: the margins follow the tick labels actually drawn (fixed margins clipped the
    # y-label beside wide tick labels such as -0.0075)
    fig, axes = plt.subplots(2, 2, figsize=(12, 7.4), sharex=True, layout="constrained")
    for j, (what, sym, unit, y, C, yf) in enumerate(series):
        env = C * rho ** (env_t / T)
        color = "C0" if j == 0 else "C2"
        ax, axl = axes[0, j], axes[1, j]
        if yf is None:
            ax.plot(t, y, color=color, lw=0.7, label="response (homogeneous)")
            axl.semilogy(t, np.abs(y), color=color, lw=0.7, label="|response|")
        else:
            ax.plot(t, y, color="0.6", lw=0.6, label="homogeneous")
            ax.plot(forced.t, yf, color=color, lw=0.7, label="with $h_L$")
            axl.semilogy(t, np.abs(y), color="0.6", lw=0.6, label="|homogeneous|")
            axl.semilogy(forced.t, np.abs(yf), color=color, lw=0.7, label="|with $h_L$|")
        ax.plot(env_t, env, "r--", lw=1.3, label=r"$\pm C\,\rho_1^{t/T}$")
        ax.plot(env_t, -env, "r--", lw=1.3)
        axl.semilogy(env_t, env, "r--", lw=1.3, label=r"$C\,\rho_1^{t/T}$")
        ax.set_title(f"{what} {sym}")
        axl.set_title(f"|{what} {sym}|, log scale")
        ax.set_ylabel(f"{sym} ({unit})")
        axl.set_ylabel(f"|{sym}| ({unit})")
        axl.set_xlabel("time t (s)")
        top = max(np.max(np.abs(y)), C * max(1.0, rho ** n_plot), 0.0 if yf is None else np.max(np.abs(yf)))
        bottom = min(C * min(1.0, rho ** n_plot), top) * 1e-3
        axl.set_ylim(bottom, top * 3)
        for a in (ax, axl):
            for k in range(1, n_plot):
                a.axvline(k * T, color="0.85", lw=0.6, zorder=0)
            a.grid(True, which="major", alpha=0.3)
        if yf is None:
            ax.legend(loc="upper left" if rho > 1 else "upper right", fontsize=9)
            axl.legend(loc="lower right" if rho > 1 else "upper right", fontsize=9)
        else:
            ax.legend(loc="best", fontsize=9, framealpha=0.9)
            axl.legend(loc="best", fontsize=9, framealpha=0.9)
    control = (f"PD control kp = {case.kp:.4f} N·m/rad, kd = {case.kd:.4f} N·m·s/rad ({case.gains_source or 'given'})"
               if case.controlled else "no control")
    title = f"Fig. {case.figure}: transient" if case.figure is not None else "Transient"
    kind = "with h_L" if with_forcing else "homogeneous"
    # two lines: the case, then the gains (one line was wider than the figure at 6 pi: cut at both sides);
    # the explanation (equations, envelope, measured ratio) is the report's caption (summary["caption"])
    fig.suptitle(f"{title} vibration ({kind}), Ω = {case.omega_over_pi:.4g}π rad/s (T = {T:.4g} s)\n{control}",
                 fontsize=12)
    fig.savefig(path, dpi=110)
    plt.close(fig)


@dataclass(frozen=True)
class _CaseTask:
    """Picklable: compute and plot one case, return its summary."""

    settings: Settings
    with_forcing: bool
    params: Optional[ManipulatorParameters]
    out: Path

    def __call__(self, case: Case) -> dict:
        res = run_case(case, self.settings, self.with_forcing, self.params)
        plot_case(res, self.out / res["summary"]["figure_file"], self.with_forcing)
        res["summary"]["caption"] = _caption(case, res, self.with_forcing)  # the report's, not drawn in the image
        return res["summary"]


def make_transients(
    out: Path,
    *,
    quick: bool = False,
    with_forcing: bool = False,
    figures: Optional[Iterable[int]] = None,
    settings: Optional[Settings] = None,
    params: Optional[ManipulatorParameters] = None,
    cases: Optional[Iterable[Case]] = None,
    executor: Optional[Any] = None,
) -> dict:
    """Compute and plot the transient figures; write ``transients.json`` (or ``transients_forced.json``).

    ``cases`` replaces the paper's Figs. 2-9 (:data:`CASES`, selected by ``figures``) with the given cases.
    ``executor`` (a :class:`concurrent.futures.Executor`) computes and plots the cases in parallel
    (each case is independent; the results are the same as in one process).

    Returns
    -------
    dict
        The JSON document written (``cases`` holds one summary per figure).
    """
    settings = settings or (QUICK if quick else FULL)
    figures = tuple(figures) if figures else (QUICK_FIGURES if quick else tuple(c.figure for c in CASES))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    selected = tuple(cases) if cases is not None else tuple(c for c in CASES if c.figure in figures)
    task = _CaseTask(settings, with_forcing, params, out)
    if executor is None or len(selected) < 2:
        rows = [task(c) for c in selected]
    else:
        rows = list(executor.map(task, selected))
    doc = {
        "description": (
            "Transient response from x(0) = [0, 0, pi/4, 0] (paper Eqs. 26/35) of the linearised reduced "
            "model, paper mode constants. Growth measured on the homogeneous response (Eq. 25/33): "
            "ratios ||x((k+1)T)||/||x(kT)|| (Euclidean norm of the state), least-squares fit of "
            "ln||x(kT)|| for k >= fit_from_period, and peak ||x|| ratios over consecutive periods after the first; "
            "compare with spectral_radius = |rho1| of the dominant Floquet multiplier (magnus6)."
        ),
        "x0": list(X0),
        "figures_include_forcing": bool(with_forcing),
        "quick": bool(quick),
        "elapsed": time.perf_counter() - t0,
        "cases": rows,
    }
    name = "transients_forced.json" if with_forcing else "transients.json"
    (out / name).write_text(json.dumps(doc, indent=2))
    return doc
